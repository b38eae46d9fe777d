"""Tests of the diagnosis job on virtual-rig data with one catalogue effect hidden in it.

The rig (``bayesdoor.door.rig.VirtualRig``) is a separate, higher-fidelity simulator of the
door; each test records a few healthy runs at several speeds with one effect drawn by its
``from_seed`` (parameters drawn from a seed, not chosen to suit the detector) or with none, and asks
:func:`diagnose_campaign` for the cause. The base model is fitted once, by CMA-ES, on a
campaign of the same rig with nothing hidden (the cheap path: the effect campaigns are
diagnosed under that fit, as a model calibrated earlier would be); under ``slow`` every
campaign is larger and fitted on its own.
"""

from __future__ import annotations

import dataclasses
import types

import jax
import numpy as np
import pytest
import scipy.stats

from bayesdoor.diagnose import (
    LOCAL_BINS,
    NONE,
    ExtensionProposal,
    capped_t,
    diagnose_campaign,
    residual_map,
    rule_passes,
    rule_thresholds,
)
from bayesdoor.diagnose._gain import (
    CAPPED_THRESHOLDS,
    DECISIVE_SE,
    UNION_SCALE,
    compare_held_out,
    estimate_discrepancy,
    feature_bins,
    held_out_evidence,
    log_predictive,
)
from bayesdoor.diagnose._held_out import extension_gain, verdict_order
from bayesdoor.diagnose._job import base_fit_notes
from bayesdoor.diagnose._residual import smooth_discrepancy
from bayesdoor.door import DOOR_CATALOGUE, WHEEL_CIRCUMFERENCE, CoupledFrameMode, ElevatorDoor
from bayesdoor.door import FrameMode as FrameModeExtension
from bayesdoor.door.rig import (
    Effects,
    FrameMode,
    MainsHum,
    RailWaviness,
    SensorCrossAxis,
    VirtualRig,
    WheelEccentricity,
)
from bayesdoor.inference import FitSettings, fit_campaign

DOOR = ElevatorDoor()
EFFECTS = {
    "frame_mode": FrameMode,
    "wheel_eccentricity": WheelEccentricity,
    "rail_waviness": RailWaviness,
    "sensor_cross_axis": SensorCrossAxis,
    "mains_hum": MainsHum,
}
#: default suite: eight runs over 0.3-0.5 m/s (four per half; with four runs in all, two per
#: half, a frame mode measured +47 +- 47 and a rail irregularity +54 +- 20 in held-out log
#: predictive density: too few held-out runs to be decisive)
SPEEDS = tuple(np.round(np.linspace(0.30, 0.50, 8), 3))
#: slow suite: twelve runs over the whole speed range
SPEEDS_SLOW = tuple(np.round(np.linspace(0.25, 0.50, 12), 3))
#: a quick CMA-ES fit of the base model (the effects are judged against it, not tuned to it)
FIT = FitSettings(max_motion_s=1.0, cmaes_max_evals=80, cmaes_restarts=0)


def record(name: str, seed: int, speeds=SPEEDS):
    """A campaign of healthy runs with the effect ``name`` (or none) drawn from ``seed``."""
    effects = Effects() if name == NONE else Effects(**{name: EFFECTS[name].from_seed(seed)})
    rig = VirtualRig(effects=effects)
    return rig.run(["healthy"] * len(speeds), list(speeds), key=jax.random.key(1000 + seed)), rig


@pytest.fixture(scope="module")
def base_fit():
    recording, _ = record(NONE, 99)
    return fit_campaign(DOOR, recording.campaign, settings=FIT, seed=0, progress=False)


def diagnose(campaign, fit, seed=0):
    return diagnose_campaign(
        DOOR, campaign, fit=fit, seed=seed, quick=True, progress=False, catalogue=DOOR_CATALOGUE
    )


def _mean(parameters, name):
    value = parameters[name]
    return float(value["mean"] if isinstance(value, dict) else value)


def check_parameters(name: str, cause, recording, rig) -> None:
    """The named cause's key parameter against the truth, with the tolerance's reason."""
    truth = recording.truth["effects"][name]
    p = cause.parameters
    if name == "frame_mode":
        # the rig's mode is coupled to the door through the rail lift: its installed frequency
        # (the linearised rig at rest) is the reference; 1 Hz is one bin of the spectra
        installed = rig.rest_state().frequencies_hz
        reference = installed[np.argmin(np.abs(installed - truth["frequency_hz"]))]
        if isinstance(cause.proposal.extension, CoupledFrameMode):
            # a mode that carries the rail is fitted by its bare frequency, as the rig's is
            # defined (modal mass 20 kg, lifting the rail under both wheels); the installed
            # frequency it reports is compared with the rig's (measured: 42.69 / 23.87 Hz
            # for seeds 2 / 3, the rig's 42.12 / 23.86)
            installed_fit = _mean(p, "frame_mode.installed_frequency_hz")
            assert abs(installed_fit - reference) < 1.0, (p, reference)
            reference = truth["frequency_hz"]
        assert abs(_mean(p, "frame_mode.frequency_hz") - reference) < 1.0, (p, reference)
    elif name == "rail_waviness":
        # a tone at 4-60 Hz refined to a fraction of a 1 Hz bin over runs 0.3-0.5 m/s
        got = _mean(p, "rail_waviness.wavelength_m")
        assert got == pytest.approx(truth["wavelength_m"], rel=0.02), p
    elif name == "wheel_eccentricity":
        # every tone named is a harmonic of the rig's wheel (it has harmonics 1-6), and the
        # wavelength is the wheel circumference over that harmonic (the signature's 4 %)
        k = int(p["label"])
        assert 1 <= k <= len(truth["amplitudes"]), p
        assert _mean(p, "period") == pytest.approx(WHEEL_CIRCUMFERENCE / k, rel=0.04), p
    elif name == "sensor_cross_axis":
        # the extension is the rig's leak exactly (same definition): the right channel and
        # the fraction within 20 % (the reported fraction is measured from the transfer
        # function between the pair; its standard error was 0.01 at 8 runs)
        receiver = f"{truth['sensor']}{truth['into']}"
        assert cause.label.startswith(receiver), (cause.label, truth)
        got = _mean(p, "sensor_cross_axis.fraction")
        assert abs(got) == pytest.approx(truth["fraction"], rel=0.2), (p, truth)
    elif name == "mains_hum":
        # 50 or 60 Hz is the cause's identity; its line must be within one bin of it
        assert _mean(p, "frequency_hz") == truth["frequency_hz"], p
        assert abs(_mean(p, "line_frequency_hz") - truth["frequency_hz"]) <= 1.0, p


#: cases measured to fail at this size (8 runs, under this file's shared base fit): the rig's
#: wheel eccentricity leaves no residual feature in 1 Hz spectra (results/diagnosis_strength.md)
_MEASURED_FAILING = {
    ("wheel_eccentricity", 0): "wheel tones about 20 dB under the vibration: no feature",
    # verdict none, the refits' held-out gain not decisive at this size
    ("wheel_eccentricity", 1): "verdict none at 8 runs",
    ("rail_waviness", 1): "named at 8 runs with each wheel's phase free (+159 +- 22, 7.2 SE) "
    "but at the signature's 27.79 mm, 6.9 % off the rig's 26.0 (the base model's "
    "own 25.17 mm line cuts into the excess: 1.27 cycles/m from the hidden 26.0 mm, the 0.8 m "
    "stroke's resolution; refined on all runs 26.62 mm, 2.4 % off); with one amplitude for "
    "both wheels (independent=False): verdict none, +92 +- 25, 3.8 SE",
    ("sensor_cross_axis", 1): "verdict none at 8 runs (no leak feature, only the rail "
    "refitted: -0.4 to +0.4 SE)",
}
#: seeds the detector is checked on (order tracking, the leak fraction from the transfer
#: function), beyond the two it was developed on; all under
#: ``slow``, measured (8 runs, the shared base fit) with the outcome below where it fails
VALIDATION_SEEDS = {
    "frame_mode": (2, 3),
    "wheel_eccentricity": (2,),
    "rail_waviness": (2, 3),
    "sensor_cross_axis": (2, 3),
}
_MEASURED_FAILING.update(
    {
        ("wheel_eccentricity", 2): "wheel tones 5-16 dB under the vibration: no wheel feature",
    }
)


# cases that pass but cost minutes: a frame mode that carries the rail is refitted with a
# solve of every training run per candidate (1.5-4 min per case on a 2-core machine; frame
# seeds 0-3 named with the coupled mode, +6.5 to +9.4 SE). Mains seed 1 takes the same path
# as seed 0 (82 and 86 s, one process): it runs under slow to keep the default suite within
# its 10 minutes. Rail seed 0 (each wheel's phase free and the locator at the measured peak:
# +202 +- 39, 5.2 SE at 34.64 mm for the rig's 34.68), 2 min. They run in the long tier (CI)


def _case(name: str, seed: int, *, slow: bool):
    heavy = slow or (name, seed) in _MEASURED_FAILING
    # a case that is not slow still costs 1-4 minutes (empty JAX cache: 65-170 s
    # with its share of the base fit): it runs in the long tier, which CI runs after the suite
    marks = [pytest.mark.slow] if heavy else [pytest.mark.long]
    if (name, seed) in _MEASURED_FAILING:
        marks.append(pytest.mark.xfail(strict=True, reason=_MEASURED_FAILING[(name, seed)]))
    return pytest.param(name, seed, marks=marks)


#: the cases that pass at this size run in the long tier (CI); the measured failures and the
#: validation seeds run under ``slow`` (they cost 15-50 s each), the failures as strict
#: expected failures so that a fix shows
CASES = [_case(name, seed, slow=False) for name in EFFECTS for seed in (0, 1)] + [
    _case(name, seed, slow=True) for name, seeds in VALIDATION_SEEDS.items() for seed in seeds
]


@pytest.mark.parametrize(("name", "seed"), CASES)
def test_hidden_effect_is_named(name, seed, base_fit):
    recording, rig = record(name, seed)
    diagnosis = diagnose(recording.campaign, base_fit, seed)
    assert diagnosis.verdict == name, diagnosis.to_json()
    cause = diagnosis.cause(name)
    assert cause.confirmed and rule_passes(np.asarray(cause.gain.per_run))
    assert cause.gain.j_after < cause.gain.j_before
    check_parameters(name, cause, recording, rig)
    # each refitted parameter keeps the value of each of the two held-out folds
    by_fold = [
        v["folds"] for v in cause.parameters.values() if isinstance(v, dict) and "folds" in v
    ]
    assert by_fold and all(len(folds) == 2 for folds in by_fold)
    # ... and the search box they were fitted in, which holds them
    for value in cause.parameters.values():
        if isinstance(value, dict) and "folds" in value:
            lo, hi = value["search_box"]
            assert all(lo <= v <= hi for v in value["folds"]), value
    payload = diagnosis.to_json()
    assert payload["verdict"] == name and payload["causes"][0]["name"] == name
    assert {"name", "evidence", "parameters", "gain"} <= set(payload["causes"][0])


#: seeds 0 and 1 run in the long tier (49 s with an empty JAX cache; seed 0 64 s with the
#: rail-carrying mode's refit)
@pytest.mark.parametrize(
    "seed",
    [
        pytest.param(0, marks=pytest.mark.long),
        pytest.param(1, marks=pytest.mark.long),
        pytest.param(2, marks=pytest.mark.slow),
        pytest.param(3, marks=pytest.mark.slow),
    ],
)
def test_nothing_hidden_gives_none(seed, base_fit):
    recording, _ = record(NONE, seed)
    diagnosis = diagnose(recording.campaign, base_fit, seed)
    assert diagnosis.verdict == NONE, diagnosis.to_json()
    assert not any(c.confirmed for c in diagnosis.causes)


@pytest.mark.long
def test_wrong_extension_shows_no_gain(base_fit):
    """A frame mode forced onto a campaign whose hidden effect is a rail irregularity (tones at
    41-51 Hz; the mode is searched at 72-78 Hz)."""
    recording, _ = record("rail_waviness", 3)
    f = 75.0
    proposal = ExtensionProposal(
        extension=FrameModeExtension(),
        start={"frame_mode.frequency_hz": f, "frame_mode.damping_ratio": 0.02},
        free=(
            "frame_mode.frequency_hz",
            "frame_mode.damping_ratio",
            *(f"frame_mode.participation_{c}" for c in DOOR.channels),
        ),
        bounds={"frame_mode.frequency_hz": (f - 3.0, f + 3.0)},
    )
    gain, refits = extension_gain(
        DOOR, recording.campaign, proposal, fit=base_fit, seed=0, quick=True
    )
    assert not gain.decisive, gain
    assert gain.elpd_difference < 2.0 * gain.elpd_se, gain
    assert len(refits) == 2


@pytest.mark.slow
def test_a_rail_named_at_a_wheel_harmonic_says_it_could_be_the_wheel(base_fit):
    """Three times the rig's wheel seed 1 (its left wheel, six harmonics): one tone at the
    sixth harmonic, named a rail at 31.28 mm (+240 +- 58, 4.1 SE). A rail of
    period 2 pi R / k under one wheel is the same excitation as that wheel's k-th harmonic,
    so the verdict must say that it could be the wheel."""
    wheel = WheelEccentricity.from_seed(1)
    wheel = dataclasses.replace(wheel, amplitudes=tuple(3.0 * a for a in wheel.amplitudes))
    rig = VirtualRig(effects=Effects(wheel_eccentricity=wheel))
    recording = rig.run(["healthy"] * len(SPEEDS), list(SPEEDS), key=jax.random.key(1001))
    diagnosis = diagnose(recording.campaign, base_fit, 1)
    assert diagnosis.verdict == "rail_waviness", diagnosis.to_json()
    (alternative,) = diagnosis.cause("rail_waviness").alternatives
    assert alternative.startswith("wheel_eccentricity:") and "harmonic 6" in alternative
    assert f"the verdict rail_waviness could also be {alternative}" in diagnosis.notes
    assert diagnosis.to_json()["causes"][0]["alternatives"] == [alternative]


def test_decision_rule():
    """The rule on per-run values: decisive only beyond the capped statistic's threshold
    with J lower."""
    before = np.array([-100.0, -110.0, -105.0, -95.0])
    gain = compare_held_out(
        before, before + 10.0 + np.array([0.5, -0.5, 0.2, -0.2]), np.ones(4), np.full(4, 0.9)
    )
    assert gain.decisive and gain.elpd_difference == pytest.approx(40.0)
    noisy = compare_held_out(
        before, before + np.array([30.0, -25.0, 20.0, -15.0]), np.ones(4), np.full(4, 0.9)
    )
    assert not noisy.decisive
    # the per-run differences are kept, and said: a few runs gaining much is not decisive
    assert noisy.per_run == pytest.approx((30.0, -25.0, 20.0, -15.0))
    assert "(2 of 4 gain; per run -25.0 to +30.0, median +2.5)" in noisy.describe()
    assert noisy.to_json()["delta_elpd_per_run"] == pytest.approx([30.0, -25.0, 20.0, -15.0])
    worse_j = compare_held_out(before, before + 10.0, np.ones(4), np.full(4, 1.1))
    assert not worse_j.decisive
    with pytest.raises(ValueError, match="at least 2"):
        compare_held_out(before[:1], before[:1], np.ones(1), np.ones(1))


def test_a_run_that_gains_more_does_not_sink_the_verdict():
    # the rail seed 6 at full size (rounded): 11 of 12 runs gain, one gains +80 (its tone
    # meets a door resonance; the rig's own effect added to the base model gains most in that
    # run too); the plain t is 3.4, under the plain rule's 4
    d = np.array([8.0, 36.0, 35.0, 1.0, 14.0, 17.0, -6.0, 80.0, 15.0, 19.0, 28.0, 14.0])
    base = np.full(12, -100.0)
    gain = compare_held_out(base, base + d, np.ones(12), np.full(12, 0.9))
    on_t, on_capped = rule_thresholds(12)
    assert gain.elpd_difference / gain.elpd_se == pytest.approx(3.41, abs=0.01)
    assert (gain.t_threshold, gain.threshold) == (on_t, on_capped) and gain.decisive
    assert 3.41 < on_t and on_capped < 5.68 == pytest.approx(gain.statistic, abs=0.01)
    assert (
        f"3.4 SE against {on_t:.2f}, with the gains above the median capped 5.68 against "
        f"{on_capped:.2f}: decisive" in gain.describe()
    )
    assert gain.to_json()["statistic"] == gain.statistic
    # ... and more gain in that run lowers t but leaves the verdict
    for more in (120.0, 500.0):
        raised = compare_held_out(
            base, base + np.where(d == 80.0, more, d), np.ones(12), np.full(12, 0.9)
        )
        assert raised.elpd_difference / raised.elpd_se < 3.41
        assert raised.decisive and raised.statistic >= gain.statistic
    # while a run that loses much still counts against it (frame mode seed 2 at full size)
    lost = np.array([29.0, -80.0, -47.0, 44.0, 75.0, 85.0, 53.0, 98.0, 35.0, 65.0, 57.0, 55.0])
    assert not compare_held_out(base, base + lost, np.ones(12), np.full(12, 0.9)).decisive


def test_runs_that_gain_alike_pass_on_the_plain_statistic():
    # frame mode seed 0, 6 runs, quick: five runs gain about +55, one +7; capping
    # cannot help a low run (capped 5.56 against the capped-only 6.62 at 6 runs), the plain t
    # 5.33 passes; a leak beside it gained a steady +4 to +21 (t 3.93) and passes capped
    base = np.full(6, -300.0)
    mode = np.array([57.25, 58.99, 53.82, 7.39, 64.52, 36.71])
    leak = np.array([20.92, 5.87, 7.12, 9.52, 10.50, 3.96])
    on_t, on_capped = rule_thresholds(6)
    by_mode = compare_held_out(base, base + mode, np.ones(6), np.full(6, 0.7))
    assert by_mode.decisive and by_mode.elpd_difference / by_mode.elpd_se > on_t
    assert by_mode.statistic < CAPPED_THRESHOLDS[6]
    by_leak = compare_held_out(base, base + leak, np.ones(6), np.full(6, 0.97))
    assert by_leak.decisive and by_leak.elpd_difference / by_leak.elpd_se < on_t
    assert by_leak.statistic > on_capped
    # both confirmed: the verdict takes the mode, the stronger held-out evidence (5.3 SE
    # against 3.9)
    first = min(
        [("sensor_cross_axis", 0.5, by_leak), ("frame_mode", 1.0, by_mode)],
        key=lambda c: verdict_order(held_out_evidence(c[2]), c[1]),
    )
    assert first[0] == "frame_mode"


def test_the_rule_keeps_the_plain_tests_false_alarm_rate():
    # the union of t > 4 k_n and capped > T_n k_n alarms under normal noise as often as t > 4
    # alone: checked on draws other than the table's
    draws = 100_000
    for runs in (6, 12):
        d = np.random.default_rng(11 + runs).standard_normal((draws, runs))
        on_t, on_capped = rule_thresholds(runs)
        t = d.sum(axis=1) / np.sqrt(runs * d.var(axis=1, ddof=1))
        alarms = np.sum((t > on_t) | (capped_t(d) > on_capped))
        expected = draws * scipy.stats.t.sf(DECISIVE_SE, runs - 1)
        assert abs(alarms - expected) < 4 * np.sqrt(expected), (runs, alarms, expected)
        assert DECISIVE_SE < on_t < on_capped
    assert rule_thresholds(1000) == rule_thresholds(max(UNION_SCALE))


def test_the_verdict_takes_the_strongest_held_out_evidence():
    # an independent implementation of the door with a cross-axis leak hidden: the leak was
    # confirmed at 18.9 SE, a frame mode at 14.8 SE, both signatures matched fully; the leak
    # is named, the mode listed after it
    confirmed = [("frame_mode", 1.0, 14.8), ("sensor_cross_axis", 1.0, 18.9)]
    first = min(confirmed, key=lambda c: verdict_order(c[2], c[1]))
    assert first[0] == "sensor_cross_axis"
    # the signature score only breaks ties of evidence
    tied = [("rail_waviness", 0.75, 6.0), ("frame_mode", 1.0, 6.0), ("mains_hum", 0.5, 9.0)]
    assert [c[0] for c in sorted(tied, key=lambda c: verdict_order(c[2], c[1]))] == [
        "mains_hum",
        "frame_mode",
        "rail_waviness",
    ]


def test_a_verdict_that_explains_its_feature_in_part_says_how_much():
    from bayesdoor.diagnose import Cause, Gain
    from bayesdoor.diagnose._candidates import Refits, judge

    gain = Gain(0.4, 0.3, -120.0, -80.0, 40.0, 5.0, 6, True)
    mode = Cause("frame_mode", "", 1.0, "", {}, gain, True, feature_share=0.3)
    hum = Cause("mains_hum", "", 1.0, "", {}, dataclasses.replace(gain, elpd_difference=20.0))
    ranking = types.SimpleNamespace(causes=())
    judged = judge(ranking, Refits({"frame_mode": mode, "mains_hum": hum}))
    assert judged.verdict == "frame_mode"
    partly = [n for n in judged.notes if "in part" in n]
    assert len(partly) == 1 and "took away 30 % of the feature's excess" in partly[0]
    # all of it taken away, or a recipe that measures no share: no such note
    for share in (1.0, None):
        whole = dataclasses.replace(mode, feature_share=share)
        notes = judge(ranking, Refits({"frame_mode": whole})).notes
        assert not [n for n in notes if "in part" in n]
    assert Cause("x", "", 1.0, "", {}, feature_share=0.25).to_json()["feature_share"] == 0.25


def test_the_verdict_is_the_cause_whose_model_wins_its_contests():
    # a leak confirmed at 18.9 SE over the base model and a frame mode at 14.8 SE: ranked by
    # their gains over the base model the leak is named; judged against each other on the
    # held-out runs the mode's model predicts them better, so the mode is named
    from bayesdoor.diagnose import Cause, Contest
    from bayesdoor.diagnose._candidates import Refits, judge

    base = np.full(12, -300.0)

    def gain(per_run, j_after):
        return compare_held_out(base, base + per_run, np.ones(12), np.full(12, j_after))

    leak = Cause("sensor_cross_axis", "", 1.0, "", {}, gain(np.linspace(2.0, 60.0, 12), 0.5), True)
    mode = Cause("frame_mode", "", 1.0, "", {}, gain(np.linspace(1.0, 50.0, 12), 0.5), True)
    assert held_out_evidence(leak.gain) > held_out_evidence(mode.gain)
    mode_wins = gain(np.linspace(4.0, 9.0, 12), 0.9)  # every run better: decisive
    leak_loses = gain(-np.linspace(4.0, 9.0, 12), 1.1)
    assert mode_wins.decisive and not leak_loses.decisive
    contests = (
        Contest("frame_mode", "sensor_cross_axis", mode_wins),
        Contest("sensor_cross_axis", "frame_mode", leak_loses),
    )
    ranking = types.SimpleNamespace(causes=())
    causes = {"sensor_cross_axis": leak, "frame_mode": mode}
    judged = judge(ranking, Refits(causes, contests=contests))
    assert judged.verdict == "frame_mode"
    assert [c.name for c in judged.causes] == ["frame_mode", "sensor_cross_axis"]
    assert any("frame_mode's model predicts them better" in n for n in judged.notes)
    # without the contests the stronger gain over the base model decides
    assert judge(ranking, Refits(causes)).verdict == "sensor_cross_axis"
    # a contest that neither side wins leaves the order by evidence, and says so
    mixed = gain(np.array([5.0, -4.0] * 6), 1.0)
    assert not mixed.decisive
    even = (
        Contest("frame_mode", "sensor_cross_axis", mixed),
        Contest("sensor_cross_axis", "frame_mode", mixed),
    )
    judged = judge(ranking, Refits(causes, contests=even))
    assert judged.verdict == "sensor_cross_axis"
    assert any("cannot tell sensor_cross_axis from frame_mode" in n for n in judged.notes)


def test_held_out_evidence_is_the_gain_in_standard_errors():
    base = np.full(6, -300.0)
    gain = compare_held_out(base, base + np.arange(1.0, 7.0), np.ones(6), np.full(6, 0.9))
    assert held_out_evidence(gain) == pytest.approx(gain.elpd_difference / gain.elpd_se)
    flat = compare_held_out(base, base + 2.0, np.ones(6), np.full(6, 0.9))
    assert held_out_evidence(flat) == np.inf


def test_a_base_fit_at_its_bounds_is_noted_and_the_law_is_not():
    names = ("K", "n", "mu_d", "I")
    lower, upper = np.array([1300.0, 1.5, 0.6, 1.0]), np.array([2500.0, 2.2, 0.8, 9.0])
    fit = types.SimpleNamespace(
        names=names,
        bounds=(lower, upper),
        point={"K": 2500.0, "n": 1.5 + 1e-5, "mu_d": 0.7, "I": 9.0, "C": 0.01},
    )
    notes = base_fit_notes(DOOR, fit)
    assert len(notes) == 2, notes
    assert notes[0].startswith("the base fit's K = 2500 sits at the upper end of its bounds")
    assert notes[1].startswith("the base fit's n = 1.5 sits at the lower end")
    inside = types.SimpleNamespace(
        names=names, bounds=(lower, upper), point={"K": 2000.0, "n": 1.8, "mu_d": 0.7, "I": 1.0}
    )
    assert base_fit_notes(DOOR, inside) == []


def _map_with_regions(speeds):
    """A residual map of two channels (1 Hz bins, 0-99 Hz) whose regions are replaced below:
    one strong line on channel ``a`` at 20 Hz gives a real ``Region`` to copy."""
    rng = np.random.default_rng(3)
    freqs = np.arange(100.0)
    truth = np.full((len(speeds), 2, 100), -3.0)
    draws = truth + rng.normal(0.0, 0.05, (20, *truth.shape))
    measured = truth + rng.normal(0.0, 0.05, truth.shape)
    measured[:, 0, 20] += 2.0
    res = residual_map(
        freqs, measured, draws, np.full(len(speeds), 0.01), channels=("a", "b"), speeds=speeds
    )
    line = next(r for r in res.regions if r.channel == "a" and r.domain == "frequency")
    assert line.low <= 20.0 <= line.high
    return res, line


def test_feature_bins_mark_the_fixed_frequency_regions_with_their_margin():
    speeds = np.array([0.3, 0.4])
    res, line = _map_with_regions(speeds)
    fixed = dataclasses.replace(line, low=20.0, high=21.0)
    deficit = dataclasses.replace(line, channel="b", low=60.0, high=60.0, z=-abs(line.z))
    # a tone tracking the speed (100 /m: 30 Hz at 0.3 m/s, 40 Hz at 0.4) is not marked
    tracking = dataclasses.replace(line, channel="b", domain="wavenumber", low=100.0, high=100.0)
    res = dataclasses.replace(res, regions=(fixed, deficit, tracking))
    freqs = np.arange(100.0)
    mask = feature_bins(res, freqs, margin=LOCAL_BINS)
    assert LOCAL_BINS == 2
    assert set(np.flatnonzero(mask[0])) == set(range(18, 24))
    assert set(np.flatnonzero(mask[1])) == set(range(58, 63))
    bare = feature_bins(res, freqs, margin=0)
    assert set(np.flatnonzero(bare[0])) == {20, 21} and set(np.flatnonzero(bare[1])) == {60}
    with pytest.raises(ValueError, match="margin"):
        feature_bins(res, freqs, margin=-1)
    with pytest.raises(ValueError, match="two bins"):
        feature_bins(res, freqs[:1])


def _line_case(n_runs=6, n_f=90, line_bin=45, seed=4):
    """Spectra of one channel: each run's broadband misfit has its own size (0.05-0.3
    decades), and a line of 2 decades the base model lacks; the extension adds it."""
    rng = np.random.default_rng(seed)
    scale = np.linspace(0.05, 0.3, n_runs)[:, None, None]
    measured = -3.0 + scale * rng.standard_normal((n_runs, 1, n_f))
    measured[:, :, line_bin] += 2.0
    base = np.full_like(measured, -3.0)
    extended = base.copy()
    extended[:, :, line_bin] += 2.0
    return measured, base, extended, np.full(n_runs, 1e-3)


def test_local_variance_is_the_running_mean_in_feature_bins_and_pooled_elsewhere():
    measured, base, _, lv = _line_case()
    local = np.zeros((1, 90), dtype=bool)
    local[0, 43:48] = True
    disc = estimate_discrepancy(base, measured, lv, 15, local=local)
    # reference by hand: the remaining residual's square, averaged over runs
    resid = measured - base
    square = np.mean((resid - smooth_discrepancy(resid.mean(axis=0), 15)) ** 2, axis=0)[0]
    pooled = np.mean(np.delete(square, range(43, 48))) - lv.mean()
    for k in range(90):
        if 43 <= k < 48:
            expected = np.mean(square[k - 2 : k + 3]) - lv.mean()
        else:
            expected = pooled
        assert disc.variance[0, k] == pytest.approx(expected, rel=1e-12)
    # without feature bins: one value per channel over every bin (the variance before)
    every = estimate_discrepancy(base, measured, lv, 15)
    np.testing.assert_allclose(every.variance, np.mean(square) - lv.mean(), rtol=1e-12)
    with pytest.raises(ValueError, match="local has shape"):
        estimate_discrepancy(base, measured, lv, 15, local=local[:, :10])


def test_a_runs_misfit_elsewhere_barely_moves_its_gain_with_the_line_bins_local():
    """Two models that differ only at a line; the held-out runs' misfit away from the line is
    tripled. With one variance per channel (the line inflates the base model's value over the
    whole band) each held-out run's gain moves by tens to hundreds; with the line's bins local
    the models' terms outside them differ only through the smooth part's shift (the line moves
    the 31-bin running median by about one rank), so the gain moves by a few at most."""
    local = np.zeros((1, 90), dtype=bool)
    local[0, 43:48] = True
    train, test = np.arange(0, 6, 2), np.arange(1, 6, 2)
    outside = np.r_[0:40, 51:90]
    for seed in range(4, 9):
        measured, base, extended, lv = _line_case(seed=seed)
        worse = measured.copy()
        worse[np.ix_(test, [0], outside)] = -3.0 + 3.0 * (
            measured[np.ix_(test, [0], outside)] + 3.0
        )
        moved = {}
        for name, mask in (("local", local), ("pooled", None)):
            gains = []
            for y in (measured, worse):
                lpd = [
                    log_predictive(
                        m[test],
                        y[test],
                        lv[test],
                        estimate_discrepancy(m[train], y[train], lv[train], 15, local=mask),
                    )
                    for m in (base, extended)
                ]
                gains.append(lpd[1] - lpd[0])
            moved[name] = np.max(np.abs(gains[1] - gains[0]))
        assert moved["pooled"] > 100.0, moved
        assert moved["local"] < 0.1 * moved["pooled"], moved


#: full-size cases measured to fail; every case's figures, command and machine are in
#: results/diagnosis_full_size.md (the saved cases: results/full_size). A full-size verdict
#: near the rule depends on the platform's base fit: rail_waviness-3 passes on a 2-core x86
#: machine (+690 +- 124, 5.6 SE, at 9.81 mm), while on a 16-core machine with JAX 0.11.2 its
#: own base fit gave +464 +- 124, 3.7 SE. rail_waviness-6 passes on the capped statistic
#: (+261 +- 77, capped 5.71 against 5.23, at 28.15 mm for 27.62)
_FULL_SIZE_FAILING: dict[tuple[str, int], str] = {
    ("frame_mode", 2): "verdict none at 12 runs (signature verdict rail_waviness; "
    "named at 8 runs, quick): the mode located at 42.5 Hz and refitted (bare "
    "38.6 Hz), its held-out gain +468 +- 181 nats, 2.6 SE: 10 of 12 runs gain +29 to +98, two "
    "lose 80 and 47 (0.295 and 0.341 m/s, both held out by the same fold); "
    "the rig's own mode added to the base model loses in the same two runs (-31, "
    "-131; ceiling 2.0 SE), and the base fit sits at four bounds (K 2500, n 1.5, c_r 0.6, "
    "mu_s 0.85)",
    ("frame_mode", 3): "verdict right (+1276 +- 159 nats), but the bare frequency 28.2 Hz "
    "against the rig's 26.42: at the top of its search box (the signature's 24.21 Hz + 4), "
    "the damping at its 0.1 bound (installed 24.85 against 23.86; the rig's door mode at "
    "21.6 Hz beside it); both end at their boxes' upper ends",
    ("rail_waviness", 5): "verdict none: the rail located at 50.46 mm (truth 51.06), 11 of "
    "12 runs gain but one gains +164 nats, which widens the SE: +380 +- 154, 2.5 SE "
    "(the rig's own effect added to the base model gains 2.8 SE, its run 3 too gaining most)",
    ("wheel_eccentricity", 2): "verdict none: no wheel feature; the rig's own wheel added to "
    "the base model gains +7 +- 25 nats (0.3 SE)",
    ("wheel_eccentricity", 3): "verdict none: no wheel feature; the rig's own wheel added to "
    "the base model gains +2 +- 15 nats (0.1 SE)",
    ("wheel_eccentricity", 4): "verdict none: the signature names the wheel (harmonic comb at "
    "k = 4 and 6, z 5.1 and 3.8; the rig's right wheel, first harmonic 12.5 um), but the refit "
    "(on the left wheel, harmonics 4 and 6) gains +82 +- 33 nats, 11 of 12 runs: 2.5 SE, capped "
    "3.54 against 5.23; the rig's own wheel added to the base model 1.4 SE",
    ("wheel_eccentricity", 5): "verdict none: no wheel feature; the rig's own wheel added to "
    "the base model gains +19 +- 25 nats (0.8 SE)",
    ("wheel_eccentricity", 6): "verdict none: the signature names the wheel (harmonic comb at "
    "k = 4 and 6, z 4.1 and 4.6; the rig's left wheel, first harmonic 7.0 um), the refit (left "
    "wheel, harmonics 4 and 6) gains +58 +- 24 nats, 11 of 12 runs: 2.4 SE, capped 2.43 "
    "against 5.23; the rig's own wheel added to the base model 2.0 SE",
    ("frame_mode", 5): "verdict right (+673 +- 113 nats), but the bare frequency 79.32 Hz "
    "against the rig's 80.38 (1.06 Hz off; installed 80.47), the rail lift at its 0.3 bound",
    ("rail_waviness", 4): "verdict none: a 70 mm rail, tones at 3.6-7.1 Hz at the band's "
    "low edge; no rail feature at all; the rig's "
    "own rail added to the base model gains 2.2 SE",
    ("sensor_cross_axis", 6): "verdict none: the rig's A1 reads 8.2 % of X in Z; the pair's "
    "coherence shows it (max Z 6.8, 12 % of the bins) but its transfer is not flat (relative "
    "spread 1.36, the check's 0.5: score 0.5) and the leak's refit gains +7 +- 9 nats (7 of 12 "
    "runs): a leak of X into Z shows in the coherence, which the held-out spectra do not "
    "contain (as cross-axis seed 1 at 8 runs)",
    ("frame_mode", 6): "verdict right (+8.9 SE; the ceiling 7.3 SE), but the bare frequency "
    "58.60 Hz against the rig's 60.36 (installed 60.89 against the rig's 60.74; the rig's lift "
    "0.105, the fit's 0.25, one fold at the 0.3 bound); refitting the contact's K and n with "
    "the mode moves the bare frequency further off (57.69 Hz, the lift at 0.3, K and n staying "
    "at their upper bounds); with the peak check the folds' modes install at 61.46 and "
    "59.87 Hz for the feature's 61.21",
}


def _full_size_case(name: str, seed: int) -> pytest.ParameterSet:
    if (name, seed) in _FULL_SIZE_FAILING:
        reason = _FULL_SIZE_FAILING[(name, seed)]
        return pytest.param(name, seed, marks=pytest.mark.xfail(strict=True, reason=reason))
    return pytest.param(name, seed)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "seed"), [_full_size_case(n, s) for n in [*EFFECTS, NONE] for s in range(2, 7)]
)
def test_full_size(name, seed):
    """Twelve runs over the whole speed range, the base model fitted on each campaign (the
    command's default sizes). 30 cases of 6-10 minutes each on a 2-core machine, run one at
    a time with ``scripts/full_size_case.py``; 18 pass (mains 5, cross-axis 4, nothing
    hidden 5, rail 3, frame mode 1, wheel 0). The failures are strict expected failures with
    their figures (``_FULL_SIZE_FAILING``). The saved cases: results/diagnosis_full_size.md."""
    recording, rig = record(name, seed, SPEEDS_SLOW)
    diagnosis = diagnose_campaign(
        DOOR, recording.campaign, seed=seed, progress=False, catalogue=DOOR_CATALOGUE
    )
    assert diagnosis.verdict == name, diagnosis.to_json()
    if name != NONE:
        check_parameters(name, diagnosis.cause(name), recording, rig)


def test_the_door_carries_its_catalogue():
    # diagnose_campaign(door, campaign) needs no catalogue= for the door
    assert DOOR.catalogue is DOOR_CATALOGUE
    assert DOOR.with_extensions("mains_hum").catalogue is DOOR_CATALOGUE
