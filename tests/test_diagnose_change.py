"""Tests of the held-out judgement split by the bins where an extension changes the prediction.

:func:`changed_bins` marks, per run and channel, where two models' log10 spectra differ by more
than a fraction of the run's Welch standard deviation, widened by the Hann main lobe;
:func:`estimate_change_discrepancy` estimates each model's scatter separately in those bins and
elsewhere. Checked against references written out by hand, and for the property the split is
for: a run's gain comes from the extension's bins, not from its misfit elsewhere.
"""

from __future__ import annotations

import numpy as np
import pytest

from bayesdoor.diagnose import LOCAL_BINS
from bayesdoor.diagnose._gain import (
    CHANGE_FRACTION,
    SIGMA_FLOOR,
    changed_bins,
    estimate_change_discrepancy,
    estimate_discrepancy,
    log_predictive,
)
from bayesdoor.diagnose._residual import smooth_discrepancy

N_F = 90


def _tone_case(seed=4, n_runs=6):
    """One channel, 1 Hz bins: a tone the base model lacks at a bin that moves with the run
    (a tone tracking the speed: bin 30 + 4 r in run r), on a broadband misfit whose size
    differs between runs (0.05-0.3 decades); the extension adds the tone."""
    rng = np.random.default_rng(seed)
    scale = np.linspace(0.05, 0.3, n_runs)[:, None, None]
    measured = -3.0 + scale * rng.standard_normal((n_runs, 1, N_F))
    tone = 30 + 4 * np.arange(n_runs)
    measured[np.arange(n_runs), 0, tone] += 1.5
    base = np.full_like(measured, -3.0)
    extended = base.copy()
    extended[np.arange(n_runs), 0, tone] += 1.5
    return measured, base, extended, np.full(n_runs, 0.04), tone


def test_changed_bins_follow_a_tracking_tone_and_widen_by_the_main_lobe():
    _, base, extended, lv, tone = _tone_case()
    # a change of 0.8 of the threshold (0.25 x 0.2 decades) is not marked
    extended = extended.copy()
    extended[:, 0, 80] += 0.8 * CHANGE_FRACTION * np.sqrt(lv[0])
    mask = changed_bins(base, extended, lv)
    assert LOCAL_BINS == 2
    for r, k in enumerate(tone):
        assert set(np.flatnonzero(mask[r, 0])) == set(range(k - 2, k + 3))
    # the same mask whichever model is called the base: neither chooses where it is judged
    np.testing.assert_array_equal(mask, changed_bins(extended, base, lv))
    # a larger Welch scatter in one run raises its threshold above the tone
    quiet = lv.copy()
    quiet[2] = (1.5 / CHANGE_FRACTION) ** 2 * 1.01
    assert not changed_bins(base, extended, quiet)[2].any()
    assert set(np.flatnonzero(changed_bins(base, extended, lv, margin=0)[0, 0])) == {30}


def test_changed_bins_refuse_bad_arguments_with_their_names():
    _, base, extended, lv, _ = _tone_case()
    with pytest.raises(ValueError, match="fraction"):
        changed_bins(base, extended, lv, fraction=0.0)
    with pytest.raises(ValueError, match="margin"):
        changed_bins(base, extended, lv, margin=-1)
    with pytest.raises(ValueError, match="log_variance"):
        changed_bins(base, extended[:, :, :10], lv)
    with pytest.raises(ValueError, match="log_variance"):
        changed_bins(base, extended, lv[:2])


def test_change_discrepancy_matches_a_reference_by_hand():
    rng = np.random.default_rng(7)
    model = rng.normal(-3.0, 0.1, (4, 2, 40))
    measured = model + rng.normal(0.0, 0.3, model.shape)
    lv = np.array([0.01, 0.02, 0.015, 0.012])
    changed = np.zeros(model.shape, dtype=bool)
    changed[0, 0, 10:15] = changed[1, 0, 12:17] = changed[2, 0, 30:33] = True
    # channel 1: every bin changed in every run (no unchanged bin to estimate from)
    changed[:, 1] = True
    disc = estimate_change_discrepancy(model, measured, lv, 5, changed)
    resid = measured - model
    e = (resid - smooth_discrepancy(resid.mean(axis=0), 5)) ** 2
    welch = lv.mean()

    def floor(v):
        return max(v - welch, SIGMA_FLOOR**2)

    inside = e[:, 0][changed[:, 0]].mean()
    assert disc.unchanged[0] == pytest.approx(floor(e[:, 0][~changed[:, 0]].mean()), rel=1e-12)
    for k in range(40):
        near = [(r, j) for r in range(4) for j in range(k - 2, k + 3) if 0 <= j < 40]
        near = [(r, j) for r, j in near if changed[r, 0, j]]
        expected = np.mean([e[r, 0, j] for r, j in near]) if near else inside
        assert disc.changed[0, k] == pytest.approx(floor(expected), rel=1e-12), k
    # no unchanged pair: the changed pairs' value serves both
    assert disc.unchanged[1] == pytest.approx(floor(e[:, 1].mean()), rel=1e-12)
    # a held-out run gets the changed value in its changed bins, the channel's value elsewhere
    test = np.zeros((1, 2, 40), dtype=bool)
    test[0, 0, 20] = True
    var = disc.at(test).variance
    assert var.shape == (1, 2, 40)
    assert var[0, 0, 20] == disc.changed[0, 20] and var[0, 0, 21] == disc.unchanged[0]
    with pytest.raises(ValueError, match="changed has shape"):
        estimate_change_discrepancy(model, measured, lv, 5, changed[:, :, :10])
    with pytest.raises(ValueError, match="mask has shape"):
        disc.at(test[:, :, :10])


def _gains(measured, base, extended, lv, train, test, how):
    """Each held-out run's log predictive density, extended less base."""
    changed = changed_bins(base, extended, lv)
    lpd = []
    for m in (base, extended):
        if how == "changed":
            disc = estimate_change_discrepancy(
                m[train], measured[train], lv[train], 15, changed[train]
            ).at(changed[test])
        else:
            disc = estimate_discrepancy(m[train], measured[train], lv[train], 15)
        lpd.append(log_predictive(m[test], measured[test], lv[test], disc))
    return lpd[1] - lpd[0]


def test_a_runs_misfit_elsewhere_barely_moves_its_gain_for_a_tracking_tone():
    """Two models that differ only at a tone in a different bin in every run; the held-out
    runs' misfit away from their tones is tripled. With one variance per channel each run's
    gain moves by tens to hundreds; with the scatter split by the changed bins the models'
    terms outside them differ only through the smooth part's shift (the tone moves the
    31-bin running median by about one rank), so the gain moves by a tenth of that at most.
    A variance local at fixed frequencies could not do this: the tone's bin differs between
    the training and the held-out runs."""
    train, test = np.arange(0, 6, 2), np.arange(1, 6, 2)
    for seed in range(4, 9):
        measured, base, extended, lv, tone = _tone_case(seed=seed)
        worse = measured.copy()
        for r in test:
            away = np.r_[0 : tone[r] - 8, tone[r] + 9 : N_F]
            worse[r, 0, away] = -3.0 + 3.0 * (measured[r, 0, away] + 3.0)
        moved = {
            how: np.max(
                np.abs(
                    _gains(worse, base, extended, lv, train, test, how)
                    - _gains(measured, base, extended, lv, train, test, how)
                )
            )
            for how in ("changed", "pooled")
        }
        assert moved["pooled"] > 10.0, moved
        assert moved["changed"] < 0.1 * moved["pooled"], moved
        assert np.all(_gains(measured, base, extended, lv, train, test, "changed") > 0)


def test_identical_models_gain_nothing_and_a_wrong_tone_loses():
    measured, base, _, lv, _ = _tone_case()
    train, test = np.arange(0, 6, 2), np.arange(1, 6, 2)
    np.testing.assert_array_equal(_gains(measured, base, base, lv, train, test, "changed"), 0.0)
    # an extension whose tone is where the measured spectra have none loses in every run
    wrong = base.copy()
    wrong[:, 0, 70] += 1.5
    assert np.all(_gains(measured, base, wrong, lv, train, test, "changed") < 0)
