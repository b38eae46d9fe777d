"""The refit's pieces: the proposal a cause keeps, the held-out folds, exact held-out spectra."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_diagnosis_gain import stand_in

from bayesdoor.diagnose import (
    ExtensionProposal,
    SizeProbe,
    Transmission,
    read_transmission,
    verdict_extension,
)
from bayesdoor.diagnose._held_out import held_out_folds
from bayesdoor.diagnose._limits import size_spectra
from bayesdoor.diagnose._refit import RefitSetup, Spectra, box_ends, exact_spectra, refit_extension
from bayesdoor.door import DoorParameters, ElevatorDoor, SensorCrossAxis


def test_a_cause_carries_the_proposal_its_refit_chose():
    # the stored proposal's configuration is one the recipe would not propose from the
    # signature (the recipe is not asked again), so only the stored one can give this answer
    proposal = ExtensionProposal(
        extension=SensorCrossAxis(sensor="A1", into="X"),
        start={"sensor_cross_axis.fraction": 0.05},
        free=("sensor_cross_axis.fraction",),
        label="made up for the test",
    )
    diagnosis = stand_in(
        "sensor_cross_axis", 1, label=proposal.label, values={"sensor_cross_axis.fraction": 0.07}
    )
    verdict = diagnosis.cause(diagnosis.verdict)
    causes = tuple(
        dataclasses.replace(c, proposal=proposal) if c is verdict else c for c in diagnosis.causes
    )
    found = verdict_extension(ElevatorDoor(), dataclasses.replace(diagnosis, causes=causes))
    assert found is not None
    assert found.proposal is proposal
    assert found.values == {"sensor_cross_axis.fraction": 0.07}
    # without the stored proposal the recipe is asked again, and it never proposes this label
    with pytest.raises(ValueError, match="made up for the test"):
        verdict_extension(ElevatorDoor(), diagnosis)


@pytest.mark.parametrize("k", [2, 3, 4, 8])
def test_held_out_folds_hold_every_run_out_once_across_the_speed_range(k):
    speeds = np.array([0.45, 0.30, 0.50, 0.35, 0.40, 0.33, 0.48, 0.38])
    folds = held_out_folds(speeds, k)
    assert len(folds) == k
    tests = np.concatenate([test for _, test in folds])
    assert sorted(tests.tolist()) == list(range(8))
    for train, test in folds:
        assert set(train.tolist()) | set(test.tolist()) == set(range(8))
        assert not set(train.tolist()) & set(test.tolist())
    # dealt in turn by speed: the i-th slowest run is in test set i mod k
    order = np.argsort(speeds)
    for i, run in enumerate(order):
        assert run in folds[i % k][1]


def test_held_out_folds_refuse_too_few_runs():
    assert held_out_folds(np.array([0.3, 0.4, 0.5]), 2) == []
    assert len(held_out_folds(np.array([0.3, 0.4, 0.5, 0.6]), 2)) == 2
    with pytest.raises(ValueError, match="k=1"):
        held_out_folds(np.array([0.3, 0.4, 0.5, 0.6]), 1)


def _door_setup(speeds, leak: float = 0.0, source_gain: float = 1.0) -> RefitSetup:
    """The paper's door simulated for 2 s at ``speeds``, its spectra of the motion window
    (0.25-1.9 s, 4-96 Hz) as the measurement, A2Z reading ``leak`` times A2X in it; the
    measured A2X is ``source_gain`` times the model's (the model's error in the source)."""
    door = ElevatorDoor()
    values = DoorParameters.paper_optimum().to_dict()
    result = door.simulate_values(values, np.asarray(speeds), duration=2.0)
    assert np.all(np.asarray(result.status) == 0)
    signals = np.asarray(result.signals)
    measured = signals.copy()
    measured[:, 2] *= source_gain
    measured[:, 3] += leak * measured[:, 2]
    fs = door.sampling_rate_hz
    window = np.full(len(speeds), 0.25), np.full(len(speeds), 1.9)
    return RefitSetup(
        system=door,
        point=values,
        operating=np.asarray(speeds),
        duration=2.0,
        time=np.asarray(result.time),
        base_signals=signals,
        spectra=Spectra.of_measured(measured, fs, *window, (4.0, 96.0), nperseg=int(fs)),
        measured_signals=measured,
    )


def _leak(on_measured: bool, **kwargs) -> ExtensionProposal:
    """A2Z reads a fraction of A2X, searched within +-0.3."""
    name = "sensor_cross_axis.fraction"
    return ExtensionProposal(
        extension=SensorCrossAxis(sensor="A2", into="Z"),
        start={name: 0.0},
        free=(name,),
        bounds={name: (-0.3, 0.3)},
        on_measured=on_measured,
        **kwargs,
    )


def _leak_probe(on_measured: bool) -> SizeProbe:
    name = "sensor_cross_axis.fraction"
    return SizeProbe("A2Z reads A2X", _leak(on_measured), {name: 1.0}, reference=0.05)


def test_a_leak_is_sized_on_the_measured_signals_as_it_is_tested():
    # the limit's spectra of a leak tested on the measured signals: the base model's plus
    # the change the leak would make to what was measured (A2X measured 0.4 times the model's)
    setup = _door_setup(np.array([0.3, 0.35, 0.45, 0.5]), source_gain=0.4)
    runs = np.arange(4)
    leaked = np.array(setup.measured_signals)
    leaked[:, 3] += 0.08 * leaked[:, 2]
    change = setup.spectra.model(leaked, runs) - setup.spectra.measured
    at = size_spectra(setup, _leak_probe(True))
    np.testing.assert_allclose(at(0.0), setup.base_spectra, atol=1e-9)
    np.testing.assert_allclose(at(0.08) - at(0.0), change, atol=1e-6)
    # sized on the model's signals the same leak changes A2Z by more (its A2X is 2.5 times)
    model = size_spectra(setup, _leak_probe(False))
    assert np.abs(model(0.08) - model(0.0))[:, 3].mean() > 1.5 * np.abs(change[:, 3]).mean()
    # without measured signals a leak is sized on the model's
    bare = dataclasses.replace(setup, measured_signals=None)
    np.testing.assert_allclose(size_spectra(bare, _leak_probe(True))(0.08), model(0.08))


def test_the_transmission_of_a_machine_is_the_model_size_that_makes_its_change():
    # a machine whose A2X is 0.4 times the model's, with A2Z reading 8 % of it: on the model's
    # signals its change is the model's at 0.4 x 8 %, the same shape; on the measured ones 8 %
    setup = _door_setup(np.array([0.3, 0.35, 0.45, 0.5]), source_gain=0.4)
    runs = np.arange(4)
    leaked = np.array(setup.measured_signals)
    leaked[:, 3] += 0.08 * leaked[:, 2]
    machine = setup.spectra.model(leaked, runs)
    on_model = read_transmission(setup, _leak_probe(False), machine, 0.08, high=3.0)
    assert abs(on_model.ratio - 0.4) < 0.04 and on_model.explained > 0.95, on_model
    on_measured = read_transmission(setup, _leak_probe(True), machine, 0.08, high=3.0)
    assert abs(on_measured.ratio - 1.0) < 0.04 and on_measured.explained > 0.99, on_measured
    # a change the leak cannot make (a line on A1X, which the leak never touches) is not
    # explained, and a family of such machines does not transmit the cause
    other = np.array(setup.spectra.measured)
    other[:, 0, 30:33] += 0.5
    miss = read_transmission(setup, _leak_probe(True), other, 0.08, high=3.0)
    assert miss.explained < 0.05 and miss.ratio < 0.01, miss
    assert not Transmission(miss.ratio, on_measured.ratio, miss.explained, 2).reliable
    with pytest.raises(ValueError, match="shape"):
        read_transmission(setup, _leak_probe(True), machine[:2], 0.08, high=3.0)


def test_a_leak_tested_on_the_measured_signals_is_blind_to_the_models_error_in_its_source():
    # the door's A2X is 0.4 times the model's and A2Z reads 8 % of it: mixing the model's
    # A2X reads the leak as 0.4 x 8 %, taking the measured A2X out reads it as it is
    setup = _door_setup(np.array([0.3, 0.35, 0.45, 0.5]), leak=0.08, source_gain=0.4)
    runs = np.arange(4)
    name = "sensor_cross_axis.fraction"
    on_measured = refit_extension(setup, _leak(True), runs, seed=1, max_evals=24)
    on_model = refit_extension(setup, _leak(False), runs, seed=1, max_evals=24)
    assert abs(on_measured.values[name] - 0.08) < 0.004
    assert abs(on_model.values[name] - 0.4 * 0.08) < 0.008
    # at the true fraction the receiver's spectra are the measured ones: the leak explains
    # every bin of it, and the other channels stay the base model's
    at_truth = exact_spectra(setup, _leak(True), {name: np.full(4, 0.08)}, runs)
    np.testing.assert_allclose(at_truth[:, 3], setup.spectra.measured[:, 3], atol=1e-9)
    np.testing.assert_array_equal(
        np.delete(at_truth, 3, axis=1), np.delete(setup.base_spectra, 3, axis=1)
    )
    # and on a measurement without a leak the fraction found is none
    clean = _door_setup(np.array([0.3, 0.35, 0.45, 0.5]), source_gain=0.4)
    assert abs(refit_extension(clean, _leak(True), runs, seed=1, max_evals=24).values[name]) < 1e-3


def test_a_leak_on_the_measured_signals_needs_them_and_an_output_extension():
    setup = _door_setup([0.3, 0.5])
    without = dataclasses.replace(setup, measured_signals=None)
    with pytest.raises(ValueError, match="no measured signals"):
        refit_extension(without, _leak(True), np.arange(2), seed=1, max_evals=8)
    solved = dataclasses.replace(
        _leak(True),
        extension="rail_waviness",
        start={},
        free=("rail_waviness.amplitude_m",),
        bounds={},
    )
    with pytest.raises(ValueError, match="outputs only"):
        refit_extension(setup, solved, np.arange(2), seed=1, max_evals=8)


def test_exact_spectra_give_each_run_its_own_values():
    # an output extension (A2Z reads a fraction of A2X) at a different fraction per run,
    # against the leak mixed into the base signals by hand and the same Welch spectra
    setup = _door_setup([0.3, 0.5])
    signals, fs = setup.base_signals, setup.spectra.fs
    t_start, t_stop = setup.spectra.t_start, setup.spectra.t_stop
    proposal = ExtensionProposal(
        extension=SensorCrossAxis(sensor="A2", into="Z"),
        start={"sensor_cross_axis.fraction": 0.0},
        free=("sensor_cross_axis.fraction",),
    )
    fractions = np.array([0.1, -0.2])
    got = exact_spectra(setup, proposal, {"sensor_cross_axis.fraction": fractions}, [1, 0])
    mixed = signals.copy()
    mixed[:, 3] += fractions[::-1, None] * signals[:, 2]
    expected = Spectra.of_measured(mixed, fs, t_start, t_stop, (4.0, 96.0), nperseg=int(fs))
    np.testing.assert_allclose(got, expected.measured[[1, 0]], rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match=r"sensor_cross_axis\.fraction"):
        exact_spectra(setup, proposal, {}, [0])


# 64 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): held-
# out refits of every fold, twice; in the long tier, which CI runs after the default suite
@pytest.mark.long
def test_folds_refitted_at_once_give_the_fits_of_one_at_a_time():
    # four runs whose A2Z carries 8 % of A2X; the leak refitted on two folds in two threads
    # and in one: every fold has its own seed, so the fits and the judgement are the same
    from bayesdoor.diagnose import DiagnosisSettings
    from bayesdoor.diagnose._held_out import _cross_validate

    speeds = np.array([0.3, 0.35, 0.45, 0.5])
    setup = _door_setup(speeds, leak=0.08)
    proposal = ExtensionProposal(
        extension=SensorCrossAxis(sensor="A2", into="Z"),
        start={"sensor_cross_axis.fraction": 0.0},
        free=("sensor_cross_axis.fraction",),
        bounds={"sensor_cross_axis.fraction": (-0.3, 0.3)},
    )
    folds = held_out_folds(speeds, 2)
    runs = [
        _cross_validate(setup, proposal, folds, seed=3, max_evals=24, tracking=False, workers=w)
        for w in (1, 2)
    ]
    (fits_1, gain_1), (fits_2, gain_2) = runs
    assert [f.values for f in fits_1] == [f.values for f in fits_2]
    assert gain_1 == gain_2
    assert all(abs(f.values["sensor_cross_axis.fraction"] - 0.08) < 0.02 for f in fits_1)
    with pytest.raises(ValueError, match="workers"):
        DiagnosisSettings(workers=0)
    with pytest.raises(ValueError, match="folds"):
        DiagnosisSettings(folds=1)


def test_a_refit_pushed_against_its_box_says_which_end():
    # A2Z carries 8 % of A2X; a box that stops at 5 % leaves the fit at its upper end, a box
    # that holds 8 % does not
    speeds = np.array([0.3, 0.35, 0.45, 0.5])
    setup = _door_setup(speeds, leak=0.08)
    name = "sensor_cross_axis.fraction"

    def refit(box: tuple[float, float]):
        proposal = ExtensionProposal(
            extension=SensorCrossAxis(sensor="A2", into="Z"),
            start={name: 0.0},
            free=(name,),
            bounds={name: box},
        )
        return refit_extension(setup, proposal, np.arange(4), seed=1, max_evals=24)

    narrow, wide = refit((-0.05, 0.05)), refit((-0.3, 0.3))
    assert narrow.box == {name: (-0.05, 0.05)} and wide.box == {name: (-0.3, 0.3)}
    assert narrow.at_bound() == {name: "upper"}
    assert wide.at_bound() == {} and abs(wide.values[name] - 0.08) < 0.02
    # the rule itself: within a thousandth of the box's width of an end, finite boxes only
    box = {"a": (0.0, 1.0), "b": (0.0, 1.0), "c": (-np.inf, 1.0), "d": (0.0, 1.0)}
    assert box_ends({"a": 0.0005, "b": 0.9995, "c": 1.0, "d": 0.5}, box) == {
        "a": "lower",
        "b": "upper",
    }


def test_the_rail_reports_each_wheels_amplitude_with_its_first_order_sd():
    from bayesdoor.door._catalogue import RailRefit

    recipe = RailRefit(independent=True)
    (proposal,) = recipe.propose({"period": 0.03}, band=(4.0, 200.0))
    values = {
        "rail_waviness.sin_left_m": 3e-6,
        "rail_waviness.cos_left_m": 4e-6,
        "rail_waviness.sin_right_m": 1e-7,
        "rail_waviness.cos_right_m": 0.0,
    }
    sd = {
        "rail_waviness.sin_left_m": 0.6e-6,
        "rail_waviness.cos_left_m": 0.2e-6,
        "rail_waviness.sin_right_m": 1e-6,
        "rail_waviness.cos_right_m": 1e-6,
    }
    door = ElevatorDoor().with_extensions(proposal.extension)
    amplitude = recipe.derived(proposal, door, values)
    assert amplitude["rail_waviness.amplitude_left_m"] == pytest.approx(5e-6)
    spread = recipe.derived_sd(proposal, values, sd)
    # (3 * 0.6, 4 * 0.2) um^2 over 5 um: sqrt(1.8^2 + 0.8^2) / 5 um
    assert spread["rail_waviness.amplitude_left_m"] == pytest.approx(np.hypot(1.8, 0.8) / 5 * 1e-6)
    # an amplitude under two of its own sds has none (the first order fails near zero)
    assert "rail_waviness.amplitude_right_m" not in spread
    # a rail at one phase has neither
    (common,) = RailRefit().propose({"period": 0.03}, band=(4.0, 200.0))
    assert recipe.derived_sd(common, {}, {}) == {}


def test_a_rail_at_a_wheel_harmonic_has_the_wheel_as_an_alternative():
    from bayesdoor.door._catalogue import RailRefit

    recipe = RailRefit(independent=True)
    # three times the rig's wheel seed 1 (left wheel) is named a rail at
    # 31.28 mm, 0.4 % from the sixth harmonic's 2 pi R / 6 = 31.42 mm
    parameters = {
        "period": 0.03128,
        "rail_waviness.wavelength_m": {"mean": 0.03128, "sd": 1e-5},
        "rail_waviness.amplitude_left_m": {"mean": 4e-6, "sd": 0.5e-6},
        "rail_waviness.amplitude_right_m": {"mean": 0.2e-6, "sd": None},
    }
    (words,) = recipe.alternatives(parameters)
    assert words.startswith("wheel_eccentricity:")
    assert "harmonic 6" in words and "31.42 mm" in words and "0.4 %" in words
    assert "left 4.00 um, right 0.20 um" in words
    # the signature's estimate alone (no refit) is enough to say it, without the heights
    (bare,) = recipe.alternatives({"period": 0.03128})
    assert "harmonic 6" in bare and "heights" not in bare
    # the rig's rail seeds 0 and 3 (34.68 and 9.74 mm) lie 8 % and more from any harmonic
    assert recipe.alternatives({"period": 0.03468}) == ()
    assert recipe.alternatives({"period": 0.00974}) == ()
    # 4 % is the signatures' match: 37.70 mm (fifth harmonic) x 1.039 is one, x 1.041 is not
    fifth = 2 * np.pi * 0.03 / 5
    assert len(recipe.alternatives({"period": fifth * 1.039})) == 1
    assert recipe.alternatives({"period": fifth * 1.041}) == ()
    assert recipe.alternatives({}) == ()


def test_a_wheel_of_one_tone_has_the_rail_as_an_alternative_and_a_comb_has_none():
    from bayesdoor.door._catalogue import WheelRefit

    recipe = WheelRefit()
    (words,) = recipe.alternatives({"label": 6, "labels_found": (6,)})
    assert words.startswith("rail_waviness:") and "2 pi R / 6 = 31.42 mm" in words
    assert recipe.alternatives({"label": 2, "labels_found": (2, 4)}) == ()
    assert recipe.alternatives({"label": 2}) != ()


@pytest.mark.parametrize("with_local", [False, True])
def test_a_gains_profile_grid_scored_at_once_equals_one_point_at_a_time(with_local):
    """The gain's profile grid is scored in one pass (:func:`_channel_lpds`): every point's
    density must be the one :func:`estimate_discrepancy` and :func:`log_predictive` give it
    alone, to the last digit, so that the refit does not depend on how it is batched."""
    from bayesdoor.diagnose._gain import estimate_discrepancy, log_predictive
    from bayesdoor.diagnose._refit import SMOOTH_BINS, Spectra, _channel_lpds

    rng = np.random.default_rng(3)
    runs, channels, freqs = 5, 4, 90
    local = None
    if with_local:
        local = np.zeros((channels, freqs), dtype=bool)
        local[:, 40:47] = True
        local[2] = True  # a channel local everywhere
    spectra = Spectra(
        fs=2048.0,
        t_start=np.zeros(runs),
        t_stop=np.ones(runs),
        nperseg=2048,
        keep=np.arange(freqs),
        freqs=np.arange(freqs, dtype=float),
        measured=rng.normal(-4.0, 0.5, (runs + 2, channels, freqs)),
        log_variance=rng.uniform(0.005, 0.02, runs + 2),
        local=local,
    )
    train = np.array([0, 2, 3, 5, 6])
    models = rng.normal(-4.0, 0.5, (11, runs, freqs))
    for channel in (0, 2):
        batched = _channel_lpds(spectra, models, train, channel)
        y = spectra.measured[train][:, channel : channel + 1]
        lv = spectra.log_variance[train]
        near = None if local is None else local[channel : channel + 1]
        for row, model in enumerate(models):
            m = model[:, None, :]
            disc = estimate_discrepancy(m, y, lv, SMOOTH_BINS, local=near)
            assert batched[row] == float(log_predictive(m, y, lv, disc).sum())


def test_two_extended_models_are_judged_against_each_other_on_the_held_out_runs():
    # A2Z reads 8 % of A2X: the model with the whole leak predicts the held-out runs better
    # than the one with a quarter of it, decisively, and not the other way round
    from bayesdoor.diagnose._held_out import contest, held_out_folds

    speeds = np.linspace(0.3, 0.5, 8)
    setup = _door_setup(speeds, leak=0.08)
    folds = held_out_folds(speeds, 2)
    name = "sensor_cross_axis.fraction"

    def models(fraction):
        return [
            exact_spectra(setup, _leak(False), {name: np.full(8, fraction)}, np.arange(8))
            for _ in folds
        ]

    whole, quarter = ("whole", models(0.08), False), ("quarter", models(0.02), False)
    won, lost = contest(setup, folds, whole, quarter), contest(setup, folds, quarter, whole)
    assert (won.challenger, won.holder) == ("whole", "quarter")
    assert won.gain.decisive and won.gain.elpd_difference > 0
    assert not lost.gain.decisive and lost.gain.elpd_difference < 0
    assert won.to_json()["evidence_se"] > 0


def test_a_limit_is_scanned_only_as_far_as_the_refit_reaches():
    # the leak's fraction is bounded at 0.3, the hum's amplitudes at 0.1 m/s^2: a cause
    # larger than that cannot be refitted at its size, so no limit lies beyond it
    from types import SimpleNamespace

    from bayesdoor.diagnose._limits import reachable
    from bayesdoor.door import DOOR_CATALOGUE

    door = SimpleNamespace(system=ElevatorDoor())
    sizes = {
        c.name: c.refit.size(band=(4.0, 96.0))
        for c in DOOR_CATALOGUE.candidates
        if c.name in ("sensor_cross_axis", "mains_hum")
    }
    assert reachable(door, _leak_probe(True)) == pytest.approx(0.3)
    assert reachable(door, sizes["sensor_cross_axis"].probes[0]) == pytest.approx(0.3)
    assert reachable(door, sizes["mains_hum"].probes[0]) == pytest.approx(0.1)
    assert sizes["sensor_cross_axis"].high > 0.3  # the declared range is cut, not trusted
