"""The oscillator: its closed-form response against independent references, its faults, its
extension and catalogue, and the errors it gives for values it cannot simulate."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.integrate
import scipy.signal
from typer.testing import CliRunner

from bayesdoor.cli import app
from bayesdoor.io import load_campaign, validate_campaign
from bayesdoor.oscillator import (
    BASE_BAND_HZ,
    Oscillator,
    SecondMode,
    base_velocity_psd,
    mass_acceleration,
)
from bayesdoor.systems import get_system

FS = 512.0
#: the oscillator's parameters of these tests: its natural frequency on a line of the 4 s
#: record's DFT grid (0.25 Hz apart), so that the periodogram reads the resonance exactly
VALUES = {"natural_frequency_hz": 27.0, "damping_ratio": 0.02, "roughness": 64.0}
SPEED = 15.0


def periodogram(signals) -> tuple[np.ndarray, np.ndarray]:
    """One-sided periodogram (rectangular window) of each run's channel ``A``: a multisine on
    the record's own DFT grid has no leakage, so every line is read exactly."""
    return scipy.signal.periodogram(np.asarray(signals)[:, 0], FS, window="boxcar")


def welch_peak_hz(signals) -> np.ndarray:
    """The frequency of each run's largest Welch PSD bin (1 Hz bins, as the fit's)."""
    f, psd = scipy.signal.welch(np.asarray(signals)[:, 0], FS, nperseg=512)
    return f[np.argmax(psd, axis=-1)]


def test_the_closed_form_is_the_steady_state_of_the_equation_of_motion():
    # x'' = -c (x' - y') - k (x - y) integrated from rest by DOP853 under the same multisine
    # base motion; after 1.5 s the transient has decayed by exp(-zeta w_n t) = exp(-28), so
    # the last period is the steady state that the closed form gives; DOP853 at rtol 1e-10
    # leaves errors near 1e-8 of the signal's amplitude: 1e-6 of it
    n, fn, zeta, psd = 256, 30.0, 0.1, 1e-3
    k, c = (2 * np.pi * fn) ** 2, 2 * zeta * 2 * np.pi * fn
    phases = np.random.default_rng(0).uniform(0, 2 * np.pi, n // 2 + 1)
    closed = np.asarray(
        mass_acceleration(np.array([k]), np.array([c]), np.array([psd]), phases, FS, n)
    )[0]
    f = np.fft.rfftfreq(n, 1 / FS)
    lines = (f >= BASE_BAND_HZ[0]) & (f <= BASE_BAND_HZ[1])
    w, phi = 2 * np.pi * f[lines], phases[lines]
    amplitude = 2.0 / n * np.sqrt(psd * n * FS / 2)  # irfft's scaling of one line

    def rhs(t, state):
        x, dx = state
        y = amplitude * np.sum(np.sin(w * t + phi) / w)
        dy = amplitude * np.sum(np.cos(w * t + phi))
        return [dx, -c * (dx - dy) - k * (x - y)]

    period = n / FS
    t = 3 * period + np.arange(n) / FS
    sol = scipy.integrate.solve_ivp(
        rhs, (0.0, t[-1]), [0.0, 0.0], method="DOP853", t_eval=t, rtol=1e-10, atol=1e-12
    )
    dy = amplitude * np.cos(np.outer(t, w) + phi).sum(axis=1)
    y = amplitude * (np.sin(np.outer(t, w) + phi) / w).sum(axis=1)
    reference = -c * (sol.y[1] - dy) - k * (sol.y[0] - y)
    np.testing.assert_allclose(closed, reference, atol=1e-6 * np.abs(reference).max())


def test_the_base_velocity_psd_is_iso_8608s_road_driven_over():
    # ISO 8608: G(n) = G(n0) (n / n0)^-2; at speed v the base's velocity PSD is
    # (2 pi f)^2 G(f / v) / v, the same at every f
    g0, v = 64e-6, 20.0
    for f in (3.0, 30.0, 150.0):
        expected = (2 * np.pi * f) ** 2 * g0 * (f / v / 0.1) ** -2 / v
        assert float(base_velocity_psd(np.float64(64.0), np.float64(v))) == pytest.approx(
            expected, rel=1e-12
        )
    # and a rigid mount (T = 1) carries it to the mass: the acceleration's PSD is w^2 S
    n = 2048
    rigid = mass_acceleration(
        np.array([1e16]), np.array([0.0]), np.array([2.5e-4]), np.zeros(n // 2 + 1), FS, n
    )
    f, p = scipy.signal.periodogram(np.asarray(rigid)[0], FS, window="boxcar")
    band = (f >= BASE_BAND_HZ[0]) & (f <= BASE_BAND_HZ[1])
    np.testing.assert_allclose(p[band], (2 * np.pi * f[band]) ** 2 * 2.5e-4, rtol=1e-8)
    assert np.all(p[f > BASE_BAND_HZ[1] + 1] < 1e-20)


@pytest.mark.parametrize("fn", [12.0, 27.3, 44.0])
def test_the_spectrum_peaks_at_the_natural_frequency(fn):
    # within one 1 Hz bin: the acceleration's PSD w^2 |T|^2 S peaks a fraction zeta^2 above
    # f_n, under 0.01 Hz at zeta = 0.02
    run = Oscillator().simulate_values({**VALUES, "natural_frequency_hz": fn}, SPEED)
    assert abs(welch_peak_hz(run.signals)[0] - fn) <= 1.0


def test_the_resonance_has_the_analytic_height():
    # at w_n the absolute transmissibility is |T|^2 = (1 + 4 zeta^2) / (4 zeta^2) (Inman,
    # "Engineering Vibration", sec. 2.4): the periodogram's line there is w_n^2 |T|^2 S
    run = Oscillator().simulate_values(VALUES, SPEED)
    f, p = periodogram(run.signals)
    zeta, wn = VALUES["damping_ratio"], 2 * np.pi * VALUES["natural_frequency_hz"]
    psd = float(base_velocity_psd(np.float64(VALUES["roughness"]), np.float64(SPEED)))
    line = np.flatnonzero(f == VALUES["natural_frequency_hz"])
    expected = wn**2 * (1 + 4 * zeta**2) / (4 * zeta**2) * psd
    assert p[0, line] == pytest.approx(expected, rel=1e-9)


def test_a_stiffness_loss_lowers_the_natural_frequency_by_its_stated_factor():
    # k falls by the loss, c stays: f_n sqrt(1 - loss), 27 Hz x 0.8 = 21.6 Hz at a loss of 0.36
    oscillator = Oscillator()
    loss = 0.36
    faulty = oscillator.simulate_values(
        VALUES, SPEED, state="stiffness_loss", severity={"stiffness_loss": loss}
    )
    expected = VALUES["natural_frequency_hz"] * np.sqrt(1 - loss)
    assert abs(welch_peak_hz(faulty.signals)[0] - expected) <= 1.0
    assert abs(welch_peak_hz(oscillator.simulate_values(VALUES, SPEED).signals)[0] - 27.0) <= 1.0
    # the severity's range sets how far: 11 % to 29 % lower
    low, high = oscillator.states["stiffness_loss"].severity["stiffness_loss"]
    assert 1 - np.sqrt(1 - low) > 0.1 and 1 - np.sqrt(1 - high) < 0.3


def test_a_loose_mount_adds_damping_and_keeps_the_frequency():
    added = 0.08
    run = Oscillator().simulate_values(
        VALUES, SPEED, state="loose_mount", severity={"added_damping": added}
    )
    assert abs(welch_peak_hz(run.signals)[0] - VALUES["natural_frequency_hz"]) <= 1.0
    f, p = periodogram(run.signals)
    zeta, wn = VALUES["damping_ratio"] + added, 2 * np.pi * VALUES["natural_frequency_hz"]
    psd = float(base_velocity_psd(np.float64(VALUES["roughness"]), np.float64(SPEED)))
    line = np.flatnonzero(f == VALUES["natural_frequency_hz"])
    assert p[0, line] == pytest.approx(wn**2 * (1 + 4 * zeta**2) / (4 * zeta**2) * psd, rel=1e-9)


def test_runs_are_a_function_of_their_inputs_and_broadcast():
    oscillator = Oscillator()
    speeds = np.array([10.0, 20.0, 30.0])
    batch = oscillator.simulate_values(
        {**VALUES, "damping_ratio": np.array([0.02, 0.05, 0.1])}, speeds
    )
    assert batch.signals.shape == (3, 1, round(4.0 * FS)) and np.all(np.asarray(batch.ok))
    single = oscillator.simulate_values({**VALUES, "damping_ratio": 0.05}, 20.0)
    # the same run, to the FFT's round-off
    scale = float(np.abs(single.signals).max())
    np.testing.assert_allclose(batch.signals[1], single.signals[0], atol=1e-12 * scale)
    # the level grows with the speed as sqrt(v): the road's velocity PSD is proportional to v
    rms = np.asarray(oscillator.simulate_values(VALUES, speeds).signals).std(axis=-1)[:, 0]
    np.testing.assert_allclose(rms / rms[0], np.sqrt(speeds / speeds[0]), rtol=1e-12)
    # another seed, other phases, the same spectrum
    seed_0 = oscillator.simulate_values(VALUES, SPEED)
    other = Oscillator(seed=1).simulate_values(VALUES, SPEED)
    assert not np.allclose(other.signals, seed_0.signals)
    f, p_other = periodogram(other.signals)
    band = (f >= BASE_BAND_HZ[0]) & (f <= BASE_BAND_HZ[1])
    np.testing.assert_allclose(p_other[:, band], periodogram(seed_0.signals)[1][:, band])


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (
            {"values": {**VALUES, "natural_frequency_hz": 60.0}},
            r"natural_frequency_hz=60\.0 Hz is outside its allowed range \[10\.0, 50\.0\] Hz",
        ),
        (
            {"values": {**VALUES, "damping_ratio": float("nan")}},
            r"damping_ratio=nan is outside its allowed range",
        ),
        (
            {"values": {"natural_frequency_hz": 27.0, "roughness": 64.0}},
            r"missing \['damping_ratio'\], unknown none",
        ),
        ({"values": {**VALUES, "mass": 1.0}}, r"missing none, unknown \['mass'\]"),
        ({"state": "cracked"}, r"unknown state 'cracked' for system oscillator: allowed healthy"),
        (
            {"state": "stiffness_loss", "severity": {"added_damping": 0.1}},
            r"unknown severity \['added_damping'\] for state 'stiffness_loss'",
        ),
        (
            {"state": "stiffness_loss", "severity": {"stiffness_loss": 0.9}},
            r"stiffness_loss=\[0\.9\] is outside its range \[0\.2, 0\.5\]",
        ),
        (
            {"operating": 50.0},
            r"speed=50\.0 m/s is outside the range the model simulates, \[2, 40\] m/s",
        ),
    ],
)
def test_values_it_cannot_simulate_are_refused_by_name(change, match):
    call = {"values": VALUES, "operating": SPEED, **change}
    with pytest.raises(ValueError, match=match):
        Oscillator().simulate_values(call.pop("values"), call.pop("operating"), **call)


def test_unchecked_values_are_simulated_as_given():
    # the generic layers pass check=False inside jitted code, where no host check can run
    run = Oscillator().simulate_values({**VALUES, "natural_frequency_hz": 60.0}, SPEED, check=False)
    assert abs(welch_peak_hz(run.signals)[0] - 60.0) <= 1.0


def test_the_second_mode_raises_the_spectrum_at_its_frequency():
    base = Oscillator()
    extended = base.with_extensions("second_mode")
    assert extended.extension_names == ("second_mode",)
    assert extended.parameter_names()[3:] == (
        "second_mode.frequency_hz",
        "second_mode.damping_ratio",
        "second_mode.gain",
    )
    assert extended.without_output_extensions() == base
    off = extended.simulate_values({**VALUES, **SecondMode().nominal()}, SPEED)
    np.testing.assert_allclose(off.signals, base.simulate_values(VALUES, SPEED).signals)
    # unit gain and zero phase at its frequency: the line rises by (1 + g)^2 exactly
    mode = {"second_mode.frequency_hz": 100.0, "second_mode.damping_ratio": 0.02}
    on = extended.simulate_values({**VALUES, **mode, "second_mode.gain": 3.0}, SPEED)
    f, p_on = periodogram(on.signals)
    _, p_off = periodogram(off.signals)
    at_mode, at_first = np.flatnonzero(f == 100.0), np.flatnonzero(f == 27.0)
    assert p_on[0, at_mode] / p_off[0, at_mode] == pytest.approx(16.0, rel=1e-9)
    # a band-pass of half-power width 2 zeta f = 4 Hz: at the first mode, 73 Hz away, little
    assert p_on[0, at_first] / p_off[0, at_first] == pytest.approx(1.0, abs=0.05)


def test_only_the_catalogues_extensions_switch_on():
    with pytest.raises(ValueError, match=r"unknown model extension 'wheel'.*second_mode"):
        Oscillator().with_extensions("wheel")
    with pytest.raises(ValueError, match=r"'none' is the base model"):
        Oscillator().with_extensions("none")
    with pytest.raises(ValueError, match="at most one of each"):
        Oscillator().with_extensions("second_mode", "second_mode")


def test_the_catalogue_holds_one_cause_and_proposes_its_refit_from_the_residual():
    catalogue = Oscillator().catalogue
    assert catalogue.names == ("second_mode", "none")
    recipe = catalogue.candidates[0].refit
    estimate = {"frequency_hz": 150.0, "damping_ratio": 0.02, "excess_db": 9.5}
    (proposal,) = recipe.propose({**estimate, "band_hz": (143.0, 154.0)}, band=(5.0, 200.0))
    assert proposal.bounds["second_mode.frequency_hz"] == (143.0, 155.0)
    # (1 + g)^2 = 10^(9.5 / 10): g = 1.99
    assert proposal.start["second_mode.gain"] == pytest.approx(10 ** (9.5 / 20) - 1)
    # a residual outside the band a second mode may lie in proposes nothing
    assert recipe.propose({**estimate, "frequency_hz": 20.0}, band=(5.0, 200.0)) == ()


def test_the_oscillator_is_found_by_name_and_simulated_from_the_command_line(tmp_path):
    assert isinstance(get_system("oscillator"), Oscillator)
    out = tmp_path / "runs.nc"
    states = ["--state", "healthy", "--state", "stiffness_loss", "--state", "loose_mount"]
    result = CliRunner().invoke(
        app,
        [
            "simulate",
            "--system",
            "oscillator",
            *states,
            "--condition",
            "speed=15",
            "--out",
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    campaign = load_campaign(out)
    oscillator = Oscillator()
    assert validate_campaign(campaign, system=oscillator) == []
    assert list(campaign["state"].values) == ["healthy", "stiffness_loss", "loose_mount"]
    peaks = welch_peak_hz(campaign["acceleration"].values)
    # the reference values (the nominal 25 Hz); the stiffness loss drawn from its prior
    loss = float(campaign["stiffness_loss"].values[1])
    assert abs(peaks[0] - 25.0) <= 1.0 and abs(peaks[2] - 25.0) <= 1.0
    assert abs(peaks[1] - 25.0 * np.sqrt(1 - loss)) <= 1.0
    json.dumps(oscillator.describe())


def test_the_demo_campaign_is_recorded_once_by_the_rig_and_valid(tmp_path, monkeypatch):
    from bayesdoor.io import validate_campaign
    from bayesdoor.oscillator.datasets import CALIBRATION_RUNS, TEST_RUNS_PER_STATE
    from bayesdoor.systems import available_demos, get_demo

    monkeypatch.setenv("BAYESDOOR_DATA", str(tmp_path))
    assert "oscillator" in available_demos()
    demo = get_demo("oscillator")
    assert not demo.cached_path().exists()
    campaign = demo.load(show_progress=False)
    assert demo.cached_path().parent == tmp_path and demo.cached_path().exists()
    assert validate_campaign(campaign, system=Oscillator()) == []
    states = campaign["state"].values.astype(str)
    split = campaign["split"].values.astype(str)
    assert list(split).count("calibration") == CALIBRATION_RUNS
    assert set(states[split == "calibration"]) == {"healthy"}
    test_states = list(states[split == "test"])
    assert all(test_states.count(s) == TEST_RUNS_PER_STATE for s in Oscillator().states)
    # the second load reads the cached file: the same runs
    again = demo.load(show_progress=False)
    assert (again["acceleration"].values == campaign["acceleration"].values).all()
