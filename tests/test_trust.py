"""Fit adequacy, the trust verdict, and the other-door family's measurement chain.

The adequacy check is tested on synthetic features with a known predictive distribution
(its false-alarm rate, and a discrepancy it must find where it is); the job end to end on
the tone system of ``test_pipeline`` with a 10 dB gain error on one channel, which the
simulations cannot reproduce: the job must say it cannot be trusted instead of answering
confidently.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from test_pipeline import SIZES, SYSTEM, job, tone_campaign

from bayesdoor.datagen import AdequacyCheck, TrainingData, fit_adequacy, healthy_outliers
from bayesdoor.door.rig import OtherDoor, coloured_noise
from bayesdoor.pipeline._trust import judge_trust

CHANNELS = ("A", "B")
N_FREQ = 12


def synthetic_data(rng, *, runs_per_speed=40, speeds=(0.3, 0.5)) -> TrainingData:
    """Healthy simulated features: a mean spectrum plus N(0, 0.1^2) per feature."""
    mean = np.linspace(-2.0, -4.0, N_FREQ)[None, :].repeat(len(CHANNELS), 0)
    n = runs_per_speed * len(speeds)
    features = mean + 0.1 * rng.standard_normal((n, len(CHANNELS), N_FREQ))
    zeros = np.zeros(n)
    return TrainingData(
        features=features,
        labels=np.zeros(n, dtype=int),
        states=("healthy", "D1"),
        validation=np.arange(n) % 3 == 0,
        speeds=np.repeat(np.asarray(speeds), runs_per_speed),
        t_start=zeros,
        t_stop=zeros + 1.0,
        run_ids=np.arange(n),
        redraws=zeros,
        model_error=np.zeros_like(features),
        parameters={},
        severities={},
        channels=CHANNELS,
        frequencies=np.arange(N_FREQ) * 4.0,
        dropped_run_ids=np.zeros(0, dtype=int),
        manifest={},
    )


def measured(rng, n, offset=None):
    """Measured runs drawn from the simulated distribution (plus an offset where given)."""
    mean = np.linspace(-2.0, -4.0, N_FREQ)[None, :].repeat(len(CHANNELS), 0)
    x = mean + 0.1 * rng.standard_normal((n, len(CHANNELS), N_FREQ))
    return x if offset is None else x + offset


#: enough simulated runs per speed (20) that a check of 6 runs can fail: with m runs per
#: speed no p-value is below 1 / (2 (m + 1))
MORE = dataclasses.replace(SIZES, runs_per_state=40, chunk_size=20)
VARIANCE = np.full((len(CHANNELS), N_FREQ), 1e-6)


def test_adequacy_false_alarm_rate_is_at_most_its_alpha():
    # measured runs that are draws of the predictive distribution: "reproduces" in all but
    # about alpha of campaigns (alpha 0.05 here, so that 60 campaigns can show it)
    rng = np.random.default_rng(0)
    data = synthetic_data(rng)
    alarms = 0
    for seed in range(60):
        x = measured(np.random.default_rng(100 + seed), 8)
        a = fit_adequacy(
            data, x, np.resize([0.3, 0.5], 8), VARIANCE, seed=seed, check=AdequacyCheck(alpha=0.05)
        )
        alarms += not a.reproduces
    # binomial(60, 0.05): P(X >= 9) < 0.01
    assert alarms <= 8


def test_adequacy_finds_the_discrepancy_where_it_is():
    rng = np.random.default_rng(1)
    data = synthetic_data(rng)
    offset = np.zeros((len(CHANNELS), N_FREQ))
    offset[1, 8:10] = 0.15  # 1.5 dB on channel B, bins 8-9 (32-36 Hz)
    x = measured(rng, 10, offset)
    a = fit_adequacy(data, x, np.resize([0.3, 0.5], 10), VARIANCE, check=AdequacyCheck(bands=6))
    assert a.verdict == "does not reproduce"
    worst = a.failing()[0]
    assert worst["channel"] == "B"
    assert worst["band_hz"][0] <= 32.0 and worst["band_hz"][1] >= 36.0
    assert worst["offset_db"] == pytest.approx(1.5, abs=0.4)
    # no other channel is blamed
    assert {cell["channel"] for cell in a.failing()} == {"B"}
    payload = a.to_json()
    assert payload["verdict"] == "does not reproduce" and payload["worst"] == worst
    assert "channel-bands off, worst B" in payload["summary"]


def test_adequacy_refuses_speeds_it_has_no_simulations_for():
    rng = np.random.default_rng(2)
    data = synthetic_data(rng)
    with pytest.raises(ValueError, match=r"speed 0\.4"):
        fit_adequacy(data, measured(rng, 2), [0.3, 0.4], VARIANCE)
    with pytest.raises(ValueError, match="state='D2'"):
        fit_adequacy(data, measured(rng, 2), [0.3, 0.3], VARIANCE, state="D2")


def test_healthy_outliers_flag_about_alpha_of_like_runs_and_all_unlike_ones():
    rng = np.random.default_rng(3)
    data = synthetic_data(rng, runs_per_speed=60)
    like = measured(rng, 400)
    scores, bounds = healthy_outliers(
        data, like, np.full(400, 0.3), VARIANCE, check=AdequacyCheck(alpha=0.05)
    )
    assert np.mean(scores > bounds) < 0.1
    unlike = measured(rng, 20, offset=0.4)
    scores, bounds = healthy_outliers(data, unlike, np.full(20, 0.5), VARIANCE)
    assert np.all(scores > bounds)


def _training(recall_hits=30, n=30):
    labels = [0] * n + [1] * n
    probs = [[0.99, 0.01]] * recall_hits + [[0.01, 0.99]] * (n - recall_hits) + [[0.01, 0.99]] * n
    return {
        "states": ["healthy", "D1"],
        "ood_quantile": 0.99,
        "validation": {"labels": labels, "probabilities": probs},
    }


def _runs(predicted, ood=()):
    return {
        "runs": [
            {"run": i, "predicted": p, "ood": i in ood, "v_max": 0.3}
            for i, p in enumerate(predicted)
        ]
    }


def test_trust_fails_when_the_measured_healthy_runs_are_not_recognised():
    adequacy = {"verdict": "reproduces", "summary": "fine"}
    known = _runs(["D1"] * 9 + ["healthy"])
    verdict = judge_trust(adequacy, known, _runs(["D1"] * 30), _training(), [])
    assert verdict["verdict"] == "not trusted"
    assert any("1 of 10 measured healthy calibration runs" in r for r in verdict["reasons"])
    # all ten recognised, nothing flagged: trusted
    ok = judge_trust(adequacy, _runs(["healthy"] * 10), _runs(["D1"] * 30), _training(), [])
    assert ok["verdict"] == "trusted" and ok["reasons"] == []


def test_a_low_expected_accuracy_limits_the_verdict():
    adequacy = {"verdict": "reproduces", "summary": "fine"}
    training = {**_training(), "validation": {**_training()["validation"]}}
    training["validation"]["calibrated"] = {"accuracy": 0.82}
    verdict = judge_trust(adequacy, _runs(["healthy"] * 10), _runs(["D1"] * 30), training, [])
    assert verdict["verdict"] == "limited" and verdict["reasons"] == []
    assert "about 82 %" in verdict["warnings"][0]
    training["validation"]["calibrated"] = {"accuracy": 0.95}
    ok = judge_trust(adequacy, _runs(["healthy"] * 10), _runs(["D1"] * 30), training, [])
    assert ok["verdict"] == "trusted" and ok["warnings"] == []


def test_many_more_uncertain_runs_than_the_simulations_have_limit_the_verdict():
    adequacy = {"verdict": "reproduces", "summary": "fine"}
    training = _training()  # validation: every run at probability 0.99, none uncertain

    def classified(n_uncertain, n=30):
        runs = _runs(["D1"] * n)
        for r in runs["runs"]:
            r["uncertain"] = r["run"] < n_uncertain
        return {**runs, "max_error": 0.1}

    # one uncertain run of 30 against a simulated share of 0.5 / 61: not improbable at 1 %
    one = judge_trust(adequacy, _runs(["healthy"] * 10), classified(1), training, [])
    assert one["verdict"] == "trusted", one["warnings"]
    assert one["checks"]["uncertain"]["simulated_share"] == pytest.approx(0.5 / 61)
    ten = judge_trust(adequacy, _runs(["healthy"] * 10), classified(10), training, [])
    assert ten["verdict"] == "limited" and ten["reasons"] == []
    assert "10 of 30 runs are uncertain" in ten["warnings"][0]
    # a classification without the flag (an older job's JSON) is not judged on it
    older = judge_trust(adequacy, _runs(["healthy"] * 10), _runs(["D1"] * 30), training, [])
    assert "uncertain" not in older["checks"]


def test_trust_fails_on_an_inadequate_fit_and_on_many_ood_runs():
    bad = {"verdict": "does not reproduce", "summary": "A 0-16 Hz off by +3.0 dB"}
    verdict = judge_trust(bad, None, _runs(["D1"] * 30), _training(), [])
    assert verdict["verdict"] == "not trusted"
    assert verdict["reasons"][0].startswith("fit inadequate: A 0-16 Hz")
    adequacy = {"verdict": "reproduces", "summary": "fine"}
    # 1 of 30 flagged is what a 99 % threshold admits; 6 of 30 is not
    one = judge_trust(adequacy, None, _runs(["D1"] * 30, ood={0}), _training(), [])
    assert one["verdict"] == "trusted"
    six = judge_trust(adequacy, None, _runs(["D1"] * 30, ood=set(range(6))), _training(), [])
    # an excess of flagged runs is a warning with the runs listed; a majority fails the check
    assert six["verdict"] == "limited" and "6 of 30 runs lie outside" in six["warnings"][0]
    assert six["flagged_runs"] == list(range(6))
    most = judge_trust(adequacy, None, _runs(["D1"] * 30, ood=set(range(16))), _training(), [])
    assert most["verdict"] == "not trusted"
    assert most["reasons"] == ["most runs are flagged (16 of 30)"]


def test_calls_the_signature_check_contradicts_count_toward_the_majority():
    adequacy = {"verdict": "reproduces", "summary": "fine"}
    classification = _runs(["D1"] * 30, ood=set(range(10)))
    # a system without a check: no run carries ``corroborated``; 10 OOD of 30 is no majority
    assert "most runs are flagged" not in " ".join(
        judge_trust(adequacy, None, classification, _training(), [])["reasons"]
    )
    # the check contradicts six more calls (and one OOD run's): 16 of 30 flagged
    for r in classification["runs"]:
        r["corroborated"] = not 9 <= r["run"] < 16
    verdict = judge_trust(adequacy, None, classification, _training(), [])
    assert verdict["verdict"] == "not trusted"
    assert verdict["reasons"] == ["most runs are flagged (16 of 30)"]
    assert verdict["checks"]["ood"]["not_corroborated"] == 7
    assert verdict["flagged_runs"] == list(range(16))
    # a call the check has no word on (None) is not a contradiction
    for r in classification["runs"]:
        r["corroborated"] = None if 9 <= r["run"] < 16 else True
    assert judge_trust(adequacy, None, classification, _training(), [])["reasons"] == []


def test_many_calls_the_signature_check_contradicts_limit_the_verdict():
    adequacy = {"verdict": "reproduces", "summary": "fine"}
    classification = _runs(["D1"] * 60)
    for r in classification["runs"]:
        r["corroborated"] = r["run"] >= 6  # 6 of 60 contradicted
    plain = judge_trust(adequacy, None, classification, _training(), [])
    assert plain["verdict"] == "trusted" and "not_corroborated" not in plain["checks"]
    # 6 of 60 where a check contradicts 1 % of right calls: improbable (p ~ 2e-5)
    strict = judge_trust(adequacy, None, classification, _training(), [], signature_rate=0.01)
    assert strict["verdict"] == "limited" and strict["reasons"] == []
    assert strict["warnings"][0].startswith("6 of 60 calls are not backed")
    assert strict["checks"]["not_corroborated"]["p_value"] < 1e-4
    # a check that contradicts 10 % of right calls makes 6 of 60 unremarkable
    loose = judge_trust(adequacy, None, classification, _training(), [], signature_rate=0.1)
    assert loose["verdict"] == "trusted"


def _gain(campaign, db, runs=None):
    """``campaign`` with channel Z louder by ``db`` (all runs, or the runs ``runs``)."""
    out = campaign.copy(deep=True)
    index = slice(None) if runs is None else runs
    out["acceleration"].loc[{"channel": "Z", "run": out["run"].values[index]}] *= 10 ** (db / 20)
    return out


# 57 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): a
# whole job; in the long tier, which CI runs after the default suite
@pytest.mark.long
def test_a_gross_mismatch_makes_the_job_warn_instead_of_answering_confidently(tmp_path):
    # a 10 dB gain error on channel Z of every run (calibration and test): a sensor whose
    # sensitivity was entered wrong. Simulations from the posterior alone cannot reproduce it.
    campaign = _gain(tone_campaign(calibration=6, per_state=4), 10.0)
    result = job(tmp_path / "gain", campaign=campaign, sizes=MORE, source="posterior")
    assert result.adequacy["verdict"] == "does not reproduce"
    assert {cell["channel"] for cell in result.adequacy["failing"]} == {"Z"}
    assert result.adequacy["worst"]["offset_db"] == pytest.approx(10.0, abs=1.5)
    assert result.trust["verdict"] == "not trusted"
    assert result.trust["reasons"][0].startswith("fit inadequate")
    payload = result.to_json()
    assert payload["fit"]["adequacy"]["verdict"] == "does not reproduce"
    assert payload["trust"]["verdict"] == "not trusted"
    job_json = json.loads((tmp_path / "gain" / "job.json").read_text())
    assert job_json["trust"] == "not trusted"
    page = result.report.read_text()
    assert "cannot be trusted" in page
    assert page.index("Can these results be trusted?") < page.index("Class probabilities")


@pytest.mark.long
def test_the_default_source_carries_a_consistent_gain_error_and_says_so(tmp_path):
    # the same wrong gain on every run: the default source adds the measured discrepancy to
    # the simulations, so the training data reproduce the runs (each run left out of its
    # own discrepancy), while the report says that the model alone does not
    campaign = _gain(tone_campaign(calibration=6, per_state=4), 10.0)
    result = job(tmp_path / "gain", campaign=campaign, sizes=MORE)
    assert result.adequacy["verdict"] == "reproduces", result.adequacy["summary"]
    model = result.adequacy["model"]
    assert model["verdict"] == "does not reproduce"
    assert {cell["channel"] for cell in model["failing"]} == {"Z"}
    assert "The fitted model alone" in result.report.read_text()


def test_runs_unlike_the_calibration_runs_are_flagged(tmp_path):
    # the sensor's gain changed after the calibration: the test runs are 10 dB louder on Z
    base = tone_campaign(calibration=6, per_state=4)
    test_runs = list(range(6, base.sizes["run"]))
    result = job(tmp_path / "later", campaign=_gain(base, 10.0, test_runs), sizes=MORE)
    assert result.adequacy["verdict"] == "reproduces"
    assert result.trust["verdict"] == "not trusted"
    assert len(result.trust["flagged_runs"]) > len(test_runs) / 2
    assert any("most runs are flagged" in r for r in result.trust["reasons"])


def test_the_unchanged_campaign_is_trusted(tmp_path):
    result = job(tmp_path / "fine", campaign=tone_campaign(calibration=6, per_state=4), sizes=MORE)
    assert result.adequacy["verdict"] == "reproduces"
    assert result.trust["verdict"] == "trusted", result.trust["reasons"]
    assert "cannot be trusted" not in result.report.read_text()
    assert SYSTEM.name == "tones"


def test_other_doors_are_reproducible_and_inside_their_ranges():
    a, b = OtherDoor.from_seed(7), OtherDoor.from_seed(7)
    assert a.describe() == b.describe()
    assert OtherDoor.from_seed(8).describe() != a.describe()
    for seed in range(20):
        d = OtherDoor.from_seed(seed)
        mode = d.rig.effects.frame_mode
        assert 8.0 <= mode.frequency_hz <= 40.0
        assert abs(d.speed_bias) <= 0.03
        assert all(abs(20 * np.log10(g)) <= 1.5 for g in d.gains)
        assert d.rig.truth.mu_d <= d.rig.truth.mu_s


def test_the_chain_applies_gain_mounting_and_noise():
    door = OtherDoor.from_seed(4)
    rng = np.random.default_rng(0)
    x = rng.standard_normal((3, 4, 8192))
    quiet = OtherDoor(**{**door.__dict__, "noise_rms": (0.0,) * 4})
    y = quiet.measure(x, 2048.0, seed=0)
    # channel A1X = gain * (cos a * A1X + sin a * A1Z)
    angle = np.radians(door.mounting_deg[0])
    expected = door.gains[0] * (np.cos(angle) * x[:, 0] + np.sin(angle) * x[:, 1])
    np.testing.assert_allclose(y[:, 0], expected, rtol=1e-12)
    noisy = door.measure(np.zeros_like(x), 2048.0, seed=1)
    np.testing.assert_allclose(noisy.std(axis=-1), np.broadcast_to(door.noise_rms, (3, 4)))


def test_coloured_noise_falls_with_frequency():
    x = coloured_noise(np.random.default_rng(0), (8, 16384), 2048.0, 1.0, 1.0)
    spectrum = np.abs(np.fft.rfft(x, axis=-1)) ** 2
    f = np.fft.rfftfreq(16384, 1 / 2048.0)
    low = spectrum[:, (f > 4) & (f < 8)].mean()
    high = spectrum[:, (f > 400) & (f < 800)].mean()
    # 1/f: a hundred times less power a hundred times higher
    assert 30 < low / high < 300


def test_the_measured_discrepancy_adds_excess_power_and_scales_a_deficit():
    from bayesdoor.datagen import with_measured_discrepancy

    rng = np.random.default_rng(5)
    data = synthetic_data(rng, speeds=(0.3,))
    healthy_mean = data.features.mean(axis=0)
    # one measured run: channel A 10x the power of the simulated mean, channel B half of it
    measured = healthy_mean.copy()[None]
    measured[0, 0] += 1.0
    measured[0, 1] -= np.log10(2.0)
    shifted = with_measured_discrepancy(data, measured, [0.3], seed=0)
    # the excess (9x the mean's power) is added to each run's power on A ...
    expected_a = np.log10(10.0 ** data.features[:, 0] + 9.0 * 10.0 ** healthy_mean[0])
    np.testing.assert_allclose(shifted.features[:, 0], expected_a, atol=1e-9)
    # ... and B is scaled by the measured deficit
    np.testing.assert_allclose(shifted.features[:, 1], data.features[:, 1] - np.log10(2.0))
    np.testing.assert_allclose(shifted.model_error, shifted.features - data.features)
    # a run far above the mean on A gains little: the excess is power, not a factor
    loud = data.features.argmax(axis=0)[0, 0]
    assert shifted.features[loud, 0, 0] - data.features[loud, 0, 0] < 1.0
    with pytest.raises(ValueError, match="no simulated healthy run"):
        with_measured_discrepancy(data, measured, [0.5])
