"""Tests of the held-out judgement of an extension that tracks the speed.

:func:`estimate_tracking_change_discrepancy` estimates a model's scatter in the changed bins
of each held-out run as the local mean of the training runs' squared residual at the same
wavenumber ``f / v`` (instead of the same frequency). Checked against a
reference written out bin by bin, against :func:`estimate_change_discrepancy` where the two
must agree (equal speeds), and for the property it is for: a tone at a fixed wavenumber is
judged against the training runs' error at that tone whatever the speeds.
"""

from __future__ import annotations

import numpy as np
import pytest

from bayesdoor.diagnose import LOCAL_BINS, FirstOf, FixedFrequency, HarmonicComb, SpeedTracking
from bayesdoor.diagnose._gain import (
    SIGMA_FLOOR,
    estimate_change_discrepancy,
    estimate_tracking_change_discrepancy,
    log_predictive,
)
from bayesdoor.diagnose._held_out import tracks_speed
from bayesdoor.diagnose._residual import smooth_discrepancy
from bayesdoor.door import DOOR_CATALOGUE

FREQS = 4.0 + np.arange(40.0)


def _random_case(seed=0, n_train=5, n_test=3, n_channels=2):
    rng = np.random.default_rng(seed)
    shape = (n_train, n_channels, FREQS.size)
    measured = rng.normal(-3.0, 0.3, shape)
    model = rng.normal(-3.0, 0.3, shape)
    lv = rng.uniform(0.005, 0.02, n_train)
    changed = rng.random(shape) < 0.3
    mask = rng.random((n_test, n_channels, FREQS.size)) < 0.5
    return measured, model, lv, changed, mask


def _reference(measured, model, lv, changed, mask, train_speeds, test_speeds, half_width):
    """The scatter bin by bin, in loops: the definition written out."""
    resid = measured - model
    smooth = smooth_discrepancy(resid.mean(axis=0), half_width)
    square = (resid - smooth) ** 2
    welch = lv.mean()
    out = np.zeros(mask.shape)
    for c in range(mask.shape[1]):
        inside = square[:, c][changed[:, c]]
        outside = square[:, c][~changed[:, c]]
        everywhere = max(inside.mean() - welch, SIGMA_FLOOR**2)
        unchanged = max(outside.mean() - welch, SIGMA_FLOOR**2)
        for r, v in enumerate(test_speeds):
            for j, f in enumerate(FREQS):
                if not mask[r, c, j]:
                    out[r, c, j] = unchanged
                    continue
                vals = [
                    square[t, c, i]
                    for t, vt in enumerate(train_speeds)
                    for i, fi in enumerate(FREQS)
                    if changed[t, c, i] and abs(fi - f * vt / v) <= LOCAL_BINS + 1e-12
                ]
                out[r, c, j] = max(np.mean(vals) - welch, SIGMA_FLOOR**2) if vals else everywhere
    return out


def test_tracking_discrepancy_matches_a_reference_written_bin_by_bin():
    measured, model, lv, changed, mask = _random_case()
    train_speeds = np.array([0.30, 0.34, 0.41, 0.45, 0.50])
    test_speeds = np.array([0.32, 0.38, 0.47])
    got = estimate_tracking_change_discrepancy(
        model, measured, lv, 5, changed, FREQS, train_speeds
    ).at(mask, test_speeds)
    expected = _reference(measured, model, lv, changed, mask, train_speeds, test_speeds, 5)
    # the same sums in another order (running sums differenced against direct sums of at
    # most 25 terms of order 1): agreement to a few units of float64 rounding
    np.testing.assert_allclose(got.variance, expected, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(
        got.smooth, smooth_discrepancy((measured - model).mean(axis=0), 5), rtol=1e-12
    )


def test_at_equal_speeds_it_is_the_frequency_local_scatter():
    """The window at the same wavenumber is the one at the same frequency when every run has
    the same speed."""
    measured, model, lv, changed, mask = _random_case(seed=1)
    tracking = estimate_tracking_change_discrepancy(
        model, measured, lv, 5, changed, FREQS, np.full(5, 0.4)
    ).at(mask, np.full(3, 0.4))
    fixed = estimate_change_discrepancy(model, measured, lv, 5, changed).at(mask)
    np.testing.assert_allclose(tracking.variance, fixed.variance, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(tracking.smooth, fixed.smooth, rtol=1e-12)


def _tone_runs(speeds, kappa=100.0, size=1.2, skirt=6, seed=5):
    """One channel, 1 Hz bins: a tone at ``kappa v`` in every run (cycles per metre times the
    run's speed, on a bin) that the base model lacks and the extension has, over a small
    broadband misfit; the changed bins are the tone's and ``skirt`` bins either side (as on
    the rig, where a rail's extension changes most of the band by more than the threshold)."""
    rng = np.random.default_rng(seed)
    n = len(speeds)
    freqs = np.arange(10.0, 80.0)
    measured = -3.0 + 0.05 * rng.standard_normal((n, 1, freqs.size))
    tone = np.searchsorted(freqs, kappa * np.asarray(speeds))
    measured[np.arange(n), 0, tone] += size
    base = np.full_like(measured, -3.0)
    extended = base.copy()
    extended[np.arange(n), 0, tone] += size
    changed = np.zeros(measured.shape, dtype=bool)
    for r, k in enumerate(tone):
        changed[r, 0, k - skirt : k + skirt + 1] = True
    return freqs, measured, base, extended, changed, tone


def test_a_held_out_tone_is_judged_against_the_training_tones_whatever_the_speeds():
    """Training tones at 30, 40, 50, 60 Hz; held-out tones at 31 Hz (next to a training
    tone) and 45 Hz (five bins from any). Local in frequency alone, the base model's
    variance at the first holds the 30 Hz run's missing tone and at the second only the
    training runs' skirts between their tones: the two runs are judged differently. With the
    window at the same wavenumber both get the training runs' error at the tone."""
    train_speeds = np.array([0.30, 0.40, 0.50, 0.60])
    test_speeds = np.array([0.31, 0.45])
    speeds = np.concatenate([train_speeds, test_speeds])
    freqs, measured, base, _, changed, tone = _tone_runs(speeds)
    train, test = np.arange(4), np.arange(4, 6)
    lv = np.full(6, 1e-4)
    at_tone = (np.arange(2), 0, tone[test])
    fixed = estimate_change_discrepancy(
        base[train], measured[train], lv[train], 15, changed[train]
    ).at(changed[test])
    v_fixed = fixed.variance[at_tone]
    assert v_fixed[0] > 10.0 * v_fixed[1], v_fixed
    tracking = estimate_tracking_change_discrepancy(
        base[train], measured[train], lv[train], 15, changed[train], freqs, train_speeds
    ).at(changed[test], test_speeds)
    v_track = tracking.variance[at_tone]
    # independent: the training runs' squared residual at their own tone bins and the two
    # bins either side (the window in each training run), less the Welch variance
    resid = measured[train] - base[train]
    square = (resid - smooth_discrepancy(resid.mean(axis=0), 15)) ** 2
    window = [square[t, 0, tone[t] - 2 : tone[t] + 3] for t in range(4)]
    expected = np.mean(np.concatenate(window)) - 1e-4
    np.testing.assert_allclose(v_track, expected, rtol=1e-12)
    # so the base model's density of the two held-out runs, alike but for their speed, is
    # alike; local in frequency alone it differs by hundreds (the 45 Hz run's missing tone
    # judged against the skirts' variance)
    lpd = [log_predictive(base[test], measured[test], lv[test], d) for d in (tracking, fixed)]
    assert np.ptp(lpd[1]) > 100.0, lpd
    assert np.ptp(lpd[0]) < 0.05 * np.ptp(lpd[1]), lpd


def test_tracking_discrepancy_refuses_bad_arguments_with_their_names():
    measured, model, lv, changed, mask = _random_case()
    speeds = np.full(5, 0.4)
    with pytest.raises(ValueError, match="changed has shape"):
        estimate_tracking_change_discrepancy(model, measured, lv, 5, changed[:2], FREQS, speeds)
    with pytest.raises(ValueError, match="freqs"):
        estimate_tracking_change_discrepancy(model, measured, lv, 5, changed, FREQS[:-1], speeds)
    with pytest.raises(ValueError, match="equally spaced"):
        estimate_tracking_change_discrepancy(model, measured, lv, 5, changed, FREQS**1.01, speeds)
    with pytest.raises(ValueError, match="speeds"):
        estimate_tracking_change_discrepancy(
            model, measured, lv, 5, changed, FREQS, np.array([0.4, 0.4, 0.0, 0.4, 0.4])
        )
    disc = estimate_tracking_change_discrepancy(model, measured, lv, 5, changed, FREQS, speeds)
    with pytest.raises(ValueError, match="mask has shape"):
        disc.at(mask[:, :1], np.full(3, 0.4))
    with pytest.raises(ValueError, match="speeds must be positive"):
        disc.at(mask, np.array([0.4, -0.1, 0.4]))


def test_which_signatures_track_the_speed():
    assert tracks_speed(SpeedTracking())
    assert tracks_speed(HarmonicComb(period_m=0.2, harmonics=(1, 2)))
    assert tracks_speed(FirstOf((HarmonicComb(period_m=0.2, harmonics=(1, 2)), SpeedTracking())))
    assert not tracks_speed(FixedFrequency(band=(10.0, 90.0)))
    assert not tracks_speed(FirstOf((FixedFrequency(band=(10.0, 90.0)), SpeedTracking())))
    # the door: the rail's and the wheel's extensions track the speed, nothing else does
    tracking = {c.name for c in DOOR_CATALOGUE.candidates if tracks_speed(c.signature)}
    assert tracking == {"rail_waviness", "wheel_eccentricity"}


def test_the_excluded_check_says_how_near_the_nearest_excluded_period_is():
    from bayesdoor.diagnose._signatures import _excluded_detail

    wheel = tuple(2 * np.pi * 0.03 / k for k in range(1, 9))  # 2 pi R / k, R = 30 mm
    detail = _excluded_detail(0.03128, wheel, "m")
    # the 6th harmonic, 31.42 mm, is the nearest: 0.4 % away
    assert "0.03142 m" in detail and "0.4 % away" in detail, detail
    assert _excluded_detail(float("nan"), wheel, "rev") == "nan rev"
