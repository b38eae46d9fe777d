"""The main job: stages reused or recomputed by their configuration, the JSON, the reports.

A small analytic system (tones whose frequency and amplitude follow the parameters, one extra
tone per damage state) and a stand-in fit (posterior draws around a known point) keep the job
to seconds; the door end to end is under ``slow``.
"""

from __future__ import annotations

import base64
import dataclasses
import json
import re
import shutil
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from _toy_system import CENTER, DURATION, FS, REST, ToySystem

from bayesdoor.classify import TrainConfig
from bayesdoor.io import make_campaign
from bayesdoor.pipeline import (
    FitSummary,
    JobConfig,
    Sizes,
    calibration_runs,
    configuration_hash,
    peak_memory_mb,
    run_job,
    run_stage,
    runs_to_classify,
)
from bayesdoor.systems import register_system

#: the tones present in both channels of every record
BACKGROUND = (("sin", 30.0, 0.02), ("cos", 91.0, 0.01))
SYSTEM = ToySystem(
    label="tones",
    d2_amplitude=(0.3, 0.6),
    d2_phase=False,
    background=tuple((c, kind, hz, a) for c in (0, 1) for kind, hz, a in BACKGROUND),
)
# found by name, as the CLI and the stages that get no system object find a campaign's system
register_system("tones", lambda: SYSTEM)


def tone_campaign(*, calibration=3, per_state=4, split=True, seed=0):
    """Measured-like runs: parameters scattered around CENTER, known states."""
    rng = np.random.default_rng(seed)
    states = ["healthy"] * calibration + ["healthy", "D1", "D2"] * per_state
    speeds = np.resize([0.3, 0.5], len(states))
    signals = []
    for state, v in zip(states, speeds, strict=True):
        values = {"k": 0.5 + 0.02 * rng.standard_normal(), "m": 1.0, "law": 2.0}
        sev = {n: rng.uniform(lo, hi) for n, (lo, hi) in SYSTEM.states[state].severity.items()}
        res = SYSTEM.simulate_values(values, v, state=state, severity=sev)
        signals.append(np.asarray(res.signals[0]))
    extra = {}
    if split:
        extra["split"] = ["calibration"] * calibration + ["test"] * (len(states) - calibration)
    return make_campaign(
        np.stack(signals),
        channels=["X", "Z"],
        fs=FS,
        state=states,
        v_max=speeds,
        t_start=np.full(len(states), REST),
        t_stop=np.full(len(states), DURATION),
        system="tones",
        **extra,
    )


class StandInFit:
    """What the pipeline reads of a fit: draws around CENTER; counts its calls."""

    calls = 0

    names = ("k", "m")

    def __init__(self, seed):
        rng = np.random.default_rng(seed)
        self.point = dict(CENTER)
        self.cmaes = SimpleNamespace(x_best=np.array([0.51, 0.99]))
        self.j = 0.1
        self._draws = {
            "k": np.clip(0.5 + 0.02 * rng.standard_normal(200), 0, 1),
            "m": np.clip(1.0 + 0.05 * rng.standard_normal(200), 0.5, 2),
        }

    def posterior_draws(self):
        return self._draws

    def model_error_draws(self):
        return np.full((200, 2), 0.05)

    def save(self, folder):
        Path(folder).mkdir(parents=True)
        (Path(folder) / "point.json").write_text(json.dumps(self.point))


def stand_in_fit(system, campaign, *, method, seed, quick, progress):
    StandInFit.calls += 1
    assert set(np.asarray(campaign["split"].values)) == {"calibration"}
    return StandInFit(seed)


class StandInDiagnosis:
    """What the pipeline reads of a diagnosis: its JSON; counts the calls and the runs seen."""

    calls = 0

    def __init__(self, fit_point):
        self.fit_point = fit_point

    def to_json(self):
        return {
            "verdict": "none",
            "causes": [
                {
                    "name": "none",
                    "evidence": "no significant residual",
                    "parameters": {"k": self.fit_point["k"]},
                    "gain": {},
                }
            ],
        }


def stand_in_diagnose(system, campaign, fit_folder, *, seed, quick, progress):
    StandInDiagnosis.calls += 1
    # the job hands over the fit it saved
    return StandInDiagnosis(json.loads((fit_folder / "point.json").read_text()))


SIZES = Sizes(
    runs_per_state=12,
    chunk_size=6,
    validation_fraction=0.5,
    train=TrainConfig(members=3, epochs=30, batch_size=12, learning_rate=1e-2),
)


def job_arguments(**kw):
    """``run_job``'s :class:`JobConfig` and its other keyword arguments, from one set."""
    fields = {f.name for f in dataclasses.fields(JobConfig)}
    config = JobConfig(**{k: v for k, v in kw.items() if k in fields})
    return config, {k: v for k, v in kw.items() if k not in fields}


def job(out, campaign=None, lines=None, **kw):
    settings = dict(
        seed=0, sizes=SIZES, fit=stand_in_fit, diagnose=stand_in_diagnose, progress=False
    )
    settings.update(kw)
    config, options = job_arguments(**settings)
    return run_job(
        SYSTEM,
        tone_campaign() if campaign is None else campaign,
        out,
        config,
        report=(lines.append if lines is not None else lambda line: None),
        **options,
    )


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """One job run to the end (shared by the tests that only read its output)."""
    out = tmp_path_factory.mktemp("job")
    StandInFit.calls = 0
    StandInDiagnosis.calls = 0
    return job(out), out


# ------------------------------------------------------------------------------------ stages


def test_stage_reused_only_with_the_same_configuration(tmp_path):
    calls = []

    def compute(folder):
        calls.append(folder)
        (folder / "x.txt").write_text(str(len(calls)))

    a = run_stage(tmp_path, "s", {"a": 1}, compute)
    b = run_stage(tmp_path, "s", {"a": 1}, compute)
    assert (a.reused, b.reused, len(calls)) == (False, True, 1)
    c = run_stage(tmp_path, "s", {"a": 2}, compute)
    assert not c.reused and len(calls) == 2
    assert (tmp_path / "s" / "x.txt").read_text() == "2"
    assert a.config_hash == configuration_hash({"a": 1}) != c.config_hash
    # nothing but the stage folder is left behind
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]


def test_stage_records_its_cpu_time_and_the_peak_memory(tmp_path):
    def compute(folder):
        # a CPU-bound second and 200 MB held while it runs
        block = np.ones(25_000_000)
        deadline = time.process_time() + 1.0
        while time.process_time() < deadline:
            block[:1000] += 1.0
        (folder / "x.txt").write_text(str(block[0]))

    before = peak_memory_mb()
    first = run_stage(tmp_path, "s", {"a": 1}, compute)
    assert first.cpu_seconds is not None and 0.9 < first.cpu_seconds < 3.0 + first.seconds
    assert first.peak_memory_mb is not None and first.peak_memory_mb >= before
    assert first.peak_memory_mb >= 190.0
    # a reused stage gives the figures of the run that computed it
    again = run_stage(tmp_path, "s", {"a": 1}, compute)
    assert again.reused
    assert (again.cpu_seconds, again.peak_memory_mb) == (first.cpu_seconds, first.peak_memory_mb)


def test_interrupted_stage_leaves_the_finished_one_untouched(tmp_path):
    run_stage(tmp_path, "s", {"a": 1}, lambda f: (f / "x.txt").write_text("old"))

    def crash(folder):
        (folder / "x.txt").write_text("half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_stage(tmp_path, "s", {"a": 2}, crash)
    assert (tmp_path / "s" / "x.txt").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]


def test_resumable_stage_continues_an_interrupted_run_of_the_same_configuration(tmp_path):
    seen = []

    def first(folder):
        (folder / "chunk-0").write_text("done")
        raise KeyboardInterrupt

    def second(folder):
        seen.append(sorted(p.name for p in folder.iterdir()))

    with pytest.raises(KeyboardInterrupt):
        run_stage(tmp_path, "g", {"a": 1}, first, resumable=True)
    run_stage(tmp_path, "g", {"a": 1}, second, resumable=True)
    assert "chunk-0" in seen[0]
    # another configuration starts from an empty folder
    run_stage(tmp_path, "g", {"a": 2}, second, resumable=True)
    assert "chunk-0" not in seen[1]


# ----------------------------------------------------------------------------------- the job


def test_second_run_recomputes_nothing(finished, tmp_path):
    result, out = finished
    assert all(not s.reused for s in result.stages)
    copy = tmp_path / "job"
    shutil.copytree(out, copy)
    lines = []
    again = job(copy, lines=lines)
    assert [s.name for s in again.stages] == [
        "fit",
        "generate",
        "adequacy",
        "train",
        "classify",
        "trust",
        "diagnose",
        "report",
    ]
    assert [s.reused for s in again.stages] == [True] * 8
    assert StandInFit.calls == 1 and StandInDiagnosis.calls == 1
    # one line per stage, plus the verdicts of the adequacy and trust checks
    verdicts = [line for line in lines if "reused" not in line]
    assert [line.split(":")[0] for line in verdicts] == ["adequacy", "trust"]
    assert len(lines) == 10
    assert again.classification == result.classification
    assert again.diagnosis["causes"] == result.diagnosis["causes"]


def test_an_edit_of_the_package_recomputes_every_stage(finished, tmp_path, monkeypatch):
    """Same settings, other bayesdoor source (as after an upgrade from a working tree): the
    stages' keys hold the source's digest, so nothing made by the old code is reused."""
    import bayesdoor.pipeline._job as job_module

    _, out = finished
    copy = tmp_path / "job"
    shutil.copytree(out, copy)
    monkeypatch.setattr(job_module, "code_version", lambda: "0" * 64)
    # the counters are the module's: counted from zero here, put back after the test
    monkeypatch.setattr(StandInFit, "calls", 0)
    monkeypatch.setattr(StandInDiagnosis, "calls", 0)
    again = job(copy)
    assert [s.reused for s in again.stages] == [False] * 8
    assert StandInFit.calls == 1 and StandInDiagnosis.calls == 1


def test_changed_test_runs_recompute_only_the_stages_they_reach(finished, tmp_path):
    _, out = finished
    copy = tmp_path / "job"
    shutil.copytree(out, copy)
    campaign = tone_campaign()
    fewer = campaign.isel(run=np.arange(campaign.sizes["run"] - 1))
    with pytest.raises(FileExistsError, match="other settings"):
        job(copy, campaign=fewer)
    changed = job(copy, campaign=fewer, overwrite=True)
    reused = {s.name: s.reused for s in changed.stages}
    # the run left out is a damaged one: the diagnosis of the healthy runs stands
    assert str(campaign["state"].values[-1]) != "healthy"
    assert reused == {
        "fit": True,
        "generate": True,
        "adequacy": True,
        "train": True,
        "classify": False,
        "trust": False,
        "diagnose": True,
        "report": False,
    }
    assert len(changed.classification["runs"]) == 11
    assert StandInFit.calls == 1 and StandInDiagnosis.calls == 1


def test_the_diagnosis_follows_the_calibration_runs_only(finished, tmp_path):
    """It compares the healthy calibration runs with the fit: a test run does not reach it."""
    _, out = finished
    campaign = tone_campaign()
    # run 3 is the first test run, a healthy one; run 0 a calibration run
    assert [str(campaign["split"].values[i]) for i in (0, 3)] == ["calibration", "test"]
    assert str(campaign["state"].values[3]) == "healthy"
    test_run = campaign.copy(deep=True)
    test_run["acceleration"].values[3] *= 1.01
    copy = tmp_path / "test-run"
    shutil.copytree(out, copy)
    reused = {s.name: s.reused for s in job(copy, campaign=test_run, overwrite=True).stages}
    assert reused["fit"] and reused["diagnose"] and not reused["classify"]
    assert StandInDiagnosis.calls == 1
    calibration = campaign.copy(deep=True)
    calibration["acceleration"].values[0] *= 1.01
    copy = tmp_path / "calibration-run"
    shutil.copytree(out, copy)
    reused = {s.name: s.reused for s in job(copy, campaign=calibration, overwrite=True).stages}
    assert not reused["fit"] and not reused["diagnose"] and not reused["report"]
    assert StandInDiagnosis.calls == 2


def test_the_diagnosis_is_in_the_job_json_and_linked_from_the_report(finished):
    result, out = finished
    payload = result.to_json()
    assert payload["diagnosis"]["verdict"] == "none"
    assert [c["name"] for c in payload["diagnosis"]["causes"]] == ["none"]
    assert payload["diagnosis"]["report"] == str(out / "diagnose" / "diagnosis.html")
    on_disk = json.loads((out / "diagnose" / "diagnosis.json").read_text())
    assert on_disk["verdict"] == "none" and on_disk["report"] == "diagnosis.html"
    assert json.loads((out / "job.json").read_text())["verdict"] == "none"
    index = (out / "report" / "index.html").read_text()
    links = re.findall(r'href="([^"]*diagnosis\.html)"', index)
    assert links == ["../diagnose/diagnosis.html"]
    assert (out / "report" / links[0]).resolve().is_file()
    assert "Discrepancy diagnosis" in index


def test_a_job_without_html_skips_the_diagnosis(tmp_path):
    calls = StandInDiagnosis.calls
    result = job(tmp_path / "batch", html=False)
    assert [s.name for s in result.stages] == [
        "fit",
        "generate",
        "adequacy",
        "train",
        "classify",
        "trust",
    ]
    assert result.diagnosis is None and result.to_json()["diagnosis"] is None
    assert StandInDiagnosis.calls == calls
    assert not (tmp_path / "batch" / "diagnose").exists()


# 33 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): a job
# run twice; in the long tier, which CI runs after the default suite
@pytest.mark.long
def test_a_failed_diagnosis_leaves_the_job_whole_and_is_retried(finished, tmp_path):
    _, out = finished
    copy = tmp_path / "job"
    shutil.copytree(out, copy)
    shutil.rmtree(copy / "diagnose")

    def refuse(system, campaign, fit_folder, *, seed, quick, progress):
        raise ValueError("3 runs cannot be split\ninto halves of 2")

    lines = []
    result = job(copy, lines=lines, diagnose=refuse)
    assert result.diagnosis == {
        "verdict": None,
        "causes": [],
        "error": "3 runs cannot be split into halves of 2",
        "report": None,
    }
    assert "diagnose" not in [s.name for s in result.stages]
    assert any("diagnose: not made" in line for line in lines)
    assert (
        "could not be made: 3 runs cannot be split" in (copy / "report" / "index.html").read_text()
    )
    assert not (copy / "diagnose").exists()
    again = job(copy)
    reused = {s.name: s.reused for s in again.stages}
    assert not reused["diagnose"] and not reused["report"] and reused["classify"]
    assert again.diagnosis["verdict"] == "none"


def test_every_setting_reaches_the_generation_hash():
    """Seed, source and sizes change the generation's configuration, hence its hash."""
    from bayesdoor.pipeline import generation_settings

    summary = FitSummary(
        "nuts", dict(CENTER), dict(CENTER), 0.1, StandInFit(0).posterior_draws(), None
    )
    campaign = tone_campaign()
    base = generation_settings(SYSTEM, campaign, summary, "fit-hash", "posterior", SIZES, 0)
    variants = [
        generation_settings(SYSTEM, campaign, summary, "fit-hash", "posterior", SIZES, 1),
        generation_settings(SYSTEM, campaign, summary, "fit-hash", "gaussian", SIZES, 0),
        generation_settings(SYSTEM, campaign, summary, "other", "posterior", SIZES, 0),
        generation_settings(
            SYSTEM, campaign, summary, "fit-hash", "posterior", Sizes(runs_per_state=13), 0
        ),
    ]
    hashes = {configuration_hash(v.config) for v in [base, *variants]}
    assert len(hashes) == 5


def test_classification_json_keys_and_metrics(finished):
    result, out = finished
    payload = json.loads((out / "classify" / "classification.json").read_text())
    assert payload["classes"] == ["healthy", "D1", "D2"]
    runs = payload["runs"]
    # the test runs only, in campaign order (run indices after the 3 calibration runs)
    assert [r["run"] for r in runs] == list(range(3, 15))
    for r in runs:
        assert {"predicted", "probabilities", "entropy", "mutual_information", "ood"} <= set(r)
        assert set(r["probabilities"]) == set(payload["classes"])
        assert sum(r["probabilities"].values()) == pytest.approx(1.0, abs=1e-5)
        most = max(r["probabilities"], key=r["probabilities"].get)
        assert r["most_probable"] == most
        # called, or left uncalled with the reason, at the selective risk
        assert r["predicted"] in (most, None)
        assert (r["predicted"] is None) == (r["abstained"] is not None)
        assert r["mutual_information"] >= -1e-6
    m = payload["metrics"]
    assert {"accuracy", "ece", "nll", "brier", "confusion"} <= set(m)
    confusion = np.asarray(m["confusion"])
    assert confusion.sum() == len(runs) and confusion.shape == (3, 3)
    # accuracy recomputed from the per-run entries
    correct = np.mean([r["most_probable"] == r["state"] for r in runs])
    assert m["accuracy"] == pytest.approx(correct)
    # the tones separate the states plainly: a working pipeline gets at most two of the 12
    # wrong (chance: 4), trained on 12 simulated runs per state that carry the discrepancy of
    # 3 calibration runs
    assert m["accuracy"] >= 10 / 12
    assert result.to_json()["metrics"] == m


def test_html_reports_embed_their_figures(finished):
    _, out = finished
    index = (out / "report" / "index.html").read_text()
    images = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', index)
    assert len(images) >= 5  # bars, confusion, reliability, uncertainty, bands at 2 speeds
    for data in images:
        assert base64.b64decode(data)[:8] == b"\x89PNG\r\n\x1a\n"
    assert 'src="http' not in index and "<script" not in index
    pages = sorted((out / "report" / "runs").glob("run-*.html"))
    assert len(pages) == 12
    page = pages[0].read_text()
    assert "data:image/png;base64," in page and "../index.html" in page


def test_fit_summary_round_trip(finished):
    _, out = finished
    summary = FitSummary.load(out / "fit")
    assert summary.point == CENTER
    assert summary.optimum == {"k": 0.51, "m": 0.99, "law": 2.0}
    assert set(summary.draws) == {"k", "m"}
    assert summary.sigma_model.shape == (200, 2)
    rows = {r["parameter"]: r for r in summary.table()}
    assert rows["k"]["q05"] < rows["k"]["mean"] < rows["k"]["q95"]
    assert "mean" not in rows["law"]


# ------------------------------------------------------------------------- runs and errors


def test_a_foreign_folder_is_refused(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="not a bayesdoor job folder"):
        job(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_calibration_and_test_selection():
    campaign = tone_campaign(split=False)
    assert set(campaign["state"].values[calibration_runs(campaign)]) == {"healthy"}
    assert runs_to_classify(campaign).sizes["run"] == campaign.sizes["run"]
    with_split = tone_campaign()
    assert runs_to_classify(with_split).sizes["run"] == 12


class FitCalled(Exception):
    """Raised by :func:`recording_fit` once it has seen the runs: nothing after it matters."""


def recording_fit(system, campaign, **options):
    raise FitCalled([int(r) for r in campaign["run"].values])


@pytest.mark.parametrize(
    ("split", "fitted"),
    [
        # a faulty run marked for calibration is not fitted on: updating needs healthy runs
        (["calibration", "calibration", "calibration"] + ["test"] * 12, [0, 2]),
        # no run marked for calibration: every healthy run
        (["test"] * 15, [0, 2, 3, 6, 9, 12]),
    ],
)
def test_the_job_fits_on_the_runs_the_inference_chooses(tmp_path, split, fitted):
    """One rule for the runs a model is updated on: :func:`bayesdoor.inference
    .calibration_runs`, which the pipeline re-exports and its job follows."""
    import bayesdoor.inference

    assert calibration_runs is bayesdoor.inference.calibration_runs
    campaign = tone_campaign()
    states = campaign["state"].values.astype(object)
    states[1] = "D1"
    campaign = campaign.assign_coords(
        state=("run", states.astype(str)), split=("run", np.array(split))
    )
    assert list(calibration_runs(campaign)) == fitted
    with pytest.raises(FitCalled) as called:
        job(tmp_path / "job", campaign=campaign, fit=recording_fit)
    assert called.value.args[0] == [int(campaign["run"].values[i]) for i in fitted]


def test_campaign_without_calibration_runs_is_refused(tmp_path):
    campaign = tone_campaign()
    faulty = campaign.isel(run=np.flatnonzero(campaign["state"].values != "healthy"))
    faulty = faulty.drop_vars("split")
    with pytest.raises(ValueError, match="no healthy run to update the model on"):
        job(tmp_path / "x", campaign=faulty)
    assert not (tmp_path / "x").exists()


def test_model_error_source_needs_the_fit_to_have_one(finished):
    _, out = finished
    summary = FitSummary.load(out / "fit")
    from bayesdoor.pipeline import parameter_source

    # the default source draws the posterior; its model error is the measured discrepancy
    draws = parameter_source(SYSTEM, summary, "posterior+model_error", 0.05)
    assert draws.describe() == parameter_source(SYSTEM, summary, "posterior", 0.05).describe()
    no_error = dataclasses.replace(summary, sigma_model=None)
    with pytest.raises(ValueError, match="needs the model-error posterior"):
        parameter_source(SYSTEM, no_error, "posterior+model_error", 0.05)
    point_only = FitSummary("cmaes", summary.point, summary.point, 0.1, {}, None)
    with pytest.raises(ValueError, match="posterior draws"):
        parameter_source(SYSTEM, point_only, "posterior", 0.05)
    with pytest.raises(ValueError, match="source must be one of"):
        parameter_source(SYSTEM, summary, "uniform", 0.05)


def test_corrupted_and_unknown_runs_are_reported_per_run(finished, tmp_path):
    from bayesdoor.pipeline import classify_stage

    _, out = finished
    campaign = runs_to_classify(tone_campaign(seed=3))
    acc = campaign["acceleration"].values.copy()
    acc[1, 0, 500] = np.nan
    campaign["acceleration"].values[:] = acc
    states = campaign["state"].values.astype(object)
    states[2] = "unknown"
    campaign = campaign.assign_coords(state=("run", states.astype(str)))
    classify_stage(out / "train", campaign, tmp_path)
    payload = json.loads((tmp_path / "classification.json").read_text())
    runs = payload["runs"]
    assert runs[1]["predicted"] is None and "non-finite" in runs[1]["problem"]
    assert runs[2]["predicted"] is not None and runs[2]["state"] == "unknown"
    assert payload["metrics"]["runs"] == len(runs) - 2
    assert payload["n_failed"] == 1


def test_classification_votes_per_record(finished, tmp_path):
    from bayesdoor.pipeline import classify_stage

    _, out = finished
    campaign = runs_to_classify(tone_campaign(seed=4))
    n = campaign.sizes["run"]
    # two records per state, runs of one record adjacent in campaign order
    states = campaign["state"].values.astype(str)
    names = [f"{s}-{i % 2}" for i, s in enumerate(states)]
    campaign = campaign.assign_coords(record=("run", names))
    classify_stage(out / "train", campaign, tmp_path)
    payload = json.loads((tmp_path / "classification.json").read_text())
    runs, classes = payload["runs"], payload["classes"]
    assert [r["record"] for r in payload["records"]] == list(dict.fromkeys(names))
    for entry in payload["records"]:
        members = [runs[i] for i in range(n) if names[i] == entry["record"]]
        assert entry["runs"] == len(members) and entry["state"] == members[0]["state"]
        # the runs left uncalled at the selective risk do not vote
        called = [m for m in members if m["predicted"] is not None]
        votes = {c: sum(m["predicted"] == c for m in called) for c in classes}
        assert entry["votes"] == votes
        if called:
            assert votes[entry["majority"]] == max(votes.values())
            for c in classes:
                mean = np.mean([m["probabilities"][c] for m in called])
                assert entry["mean_probabilities"][c] == pytest.approx(mean)
        else:
            assert entry["majority"] is None and entry["mean_probabilities"] is None
        for m in members:
            assert m["uncertain"] == (max(m["probabilities"].values()) < 1 - payload["max_error"])
        share = np.mean(
            [bool(m["ood"]) or m["uncertain"] or m["predicted"] is None for m in members]
        )
        assert entry["share_flagged"] == pytest.approx(share)
        assert entry["flagged"] == (share > 0.5)
        assert entry["shows"] is None  # the tones have no signature check
    metrics = payload["record_metrics"]
    voted = [r for r in payload["records"] if r["majority"] is not None]
    right = [r["majority"] == r["state"] for r in voted]
    assert metrics["records"] == len(right)
    assert metrics["uncalled"] == len(payload["records"]) - len(voted)
    assert metrics["accuracy"] == pytest.approx(np.mean(right))
    assert np.sum(metrics["confusion"]) == len(right)
    assert payload["n_uncertain"] == sum(r["uncertain"] for r in runs)


def test_record_votes_ties_unclassified_runs_and_balanced_accuracy():
    from bayesdoor.pipeline._classify import record_metrics, record_votes

    classes = ["a", "b"]

    def run(state, predicted, pa=None, ood=False, uncertain=False):
        probabilities = None if predicted is None else {"a": pa, "b": 1 - pa}
        return {
            "state": state,
            "predicted": predicted,
            "probabilities": probabilities,
            "ood": ood,
            "uncertain": uncertain,
        }

    runs = [
        run("a", "a", 0.6),
        run("a", "b", 0.1),  # a tie of one vote each: the mean probability (0.35 for a) decides
        run("b", "b", 0.2, ood=True),
        run("b", None),
        run("b", "a", 0.9, ood=True),
        run("a", "a", 0.8),
        run("b", "b", 0.45, uncertain=True),  # in distribution, but a guess
        run("b", "b", 0.4, uncertain=True),
        run("b", "b", 0.0),
    ]
    record = np.array(["r1", "r1", "r2", "r2", "r2", "r3", "r4", "r4", "r4"])
    r1, r2, r3, r4 = record_votes(runs, record, classes)
    assert (r4["majority"], r4["share_flagged"], r4["flagged"]) == ("b", 2 / 3, True)
    assert r1["votes"] == {"a": 1, "b": 1} and r1["majority"] == "b"
    assert r1["mean_probabilities"]["a"] == pytest.approx(0.35)
    assert (r2["runs"], r2["classified"], r2["share_flagged"], r2["flagged"]) == (3, 2, 1.0, True)
    assert r2["majority"] == "a"  # one vote each, mean p(a) 0.55
    assert (r3["majority"], r3["flagged"]) == ("a", False)
    metrics = record_metrics([r1, r2, r3], classes)
    assert metrics["confusion"] == [[1, 1], [1, 0]]
    assert metrics["accuracy"] == pytest.approx(1 / 3)
    assert metrics["balanced_accuracy"] == pytest.approx((0.5 + 0.0) / 2)
    assert (metrics["misnamed"], metrics["misnamed_flagged"]) == (2, 1)


class _SignedTones(type(SYSTEM)):
    """The tone system with a signature check that a test sets: it disagrees with every call
    of ``D1`` and agrees with the others; its reference counts the healthy runs it saw."""

    def signature_reference(self, signals, operating):
        return {"healthy_runs": int(np.asarray(signals).shape[0])}

    def signatures(self, reference, signals, operating):
        assert reference["healthy_runs"] == 3
        return [{"healthy": True, "D1": False, "D2": None} for _ in range(len(signals))]


def test_calls_the_signal_disagrees_with_are_flagged(finished, tmp_path):
    from bayesdoor.pipeline import classify_stage
    from bayesdoor.pipeline._classify import SIGNATURES, signature_stage

    _, out = finished
    # a system without a check writes no reference, and its runs carry no verdict
    signature_stage(tmp_path, calibration_runs_of(tone_campaign()), SYSTEM)
    assert not (tmp_path / SIGNATURES).exists()
    plain = json.loads((out / "classify" / "classification.json").read_text())
    assert all(r["corroborated"] is None for r in plain["runs"])
    assert plain["n_not_corroborated"] == 0

    signed = _SignedTones(**{f.name: getattr(SYSTEM, f.name) for f in dataclasses.fields(SYSTEM)})
    model = tmp_path / "train"
    shutil.copytree(out / "train", model)
    signature_stage(model, calibration_runs_of(tone_campaign()), signed)
    stored = json.loads((model / SIGNATURES).read_text())
    assert stored == {"system": "tones", "runs": 3, "reference": {"healthy_runs": 3}}
    campaign = runs_to_classify(tone_campaign(seed=4))
    states = campaign["state"].values.astype(str)
    campaign = campaign.assign_coords(
        record=("run", [f"{s}-{i % 2}" for i, s in enumerate(states)])
    )
    classify_stage(model, campaign, tmp_path / "c", system=signed)
    payload = json.loads((tmp_path / "c" / "classification.json").read_text())
    runs = payload["runs"]
    expected = {"healthy": True, "D1": False, "D2": None}
    assert [r["corroborated"] for r in runs] == [expected[r["most_probable"]] for r in runs]
    assert payload["n_not_corroborated"] == sum(r["most_probable"] == "D1" for r in runs) > 0
    for entry in payload["records"]:
        members = [
            r for r, n in zip(runs, campaign["record"].values, strict=True) if n == entry["record"]
        ]
        share = np.mean(
            [
                r["ood"] or r["uncertain"] or r["most_probable"] == "D1" or r["predicted"] is None
                for r in members
            ]
        )
        assert entry["share_flagged"] == pytest.approx(share)
        # what the record's signal shows, by state, without labels (D2: the check says nothing)
        assert entry["shows"] == {"healthy": 1.0, "D1": 0.0}
    # the report's headline counts them
    from bayesdoor.pipeline import report_stage

    report_stage(tmp_path / "c", model, tmp_path / "r")
    page = (tmp_path / "r" / "index.html").read_text()
    assert "not corroborated" in page
    assert "not corroborated" not in _report_without_check(out, tmp_path)
    # a reference of another system is refused, with nothing written
    stored["system"] = "other"
    (model / SIGNATURES).write_text(json.dumps(stored))
    with pytest.raises(ValueError, match=r"signature reference .* of system 'other'"):
        classify_stage(model, campaign, tmp_path / "d", system=signed)
    assert not (tmp_path / "d" / "classification.json").exists()


def calibration_runs_of(campaign):
    return campaign.isel(run=calibration_runs(campaign))


def _report_without_check(out, tmp_path):
    from bayesdoor.pipeline import report_stage

    report_stage(out / "classify", out / "train", tmp_path / "plain")
    return (tmp_path / "plain" / "index.html").read_text()


def test_runs_left_uncalled_keep_the_selective_risk(finished, tmp_path):
    """The selective risk of the calls made on many held-out measured-like runs is not
    significantly above the target, and every run above the threshold is called."""
    from scipy.stats import beta

    from bayesdoor.pipeline import classify_stage

    _, out = finished
    campaign = runs_to_classify(tone_campaign(per_state=40, seed=11))
    classify_stage(out / "train", campaign, tmp_path / "sel", selective_risk=0.05)
    payload = json.loads((tmp_path / "sel" / "classification.json").read_text())
    runs, selective = payload["runs"], payload["selective"]
    top = np.array([max(r["probabilities"].values()) for r in runs])
    called = np.array([r["predicted"] is not None for r in runs])
    assert selective["called"] == called.sum() == payload["metrics"]["selective"]["called"]
    assert 0 < called.sum() < len(runs)
    # a threshold rule: every run at or above the lowest probability called is called
    assert np.all(called == (top >= selective["threshold"]))
    # the probabilities' promise: the mean of 1 - p over the calls is at most the target
    assert np.mean(1 - top[called]) <= 0.05 + 1e-12
    wrong = sum(r["predicted"] != r["state"] for r in np.asarray(runs)[called])
    # realised: the 95 % lower confidence bound of the calls' risk stays under the target
    low = beta.ppf(0.05, wrong, called.sum() - wrong + 1) if wrong else 0.0
    assert low <= 0.05, (wrong, called.sum())
    for r in np.asarray(runs)[~called]:
        assert r["abstained"].startswith(f"its probability of {r['most_probable']}")
    # no abstention asked for: every run is called its most probable state
    classify_stage(out / "train", campaign, tmp_path / "all", selective_risk=None)
    every = json.loads((tmp_path / "all" / "classification.json").read_text())
    assert every["selective"] is None
    assert all(r["predicted"] == r["most_probable"] is not None for r in every["runs"])


def test_a_job_config_resolves_its_defaults_from_what_it_is_given():
    quick = JobConfig.quick_look(seed=3)
    assert quick.effective_sizes == Sizes.quick() and quick.effective_fit_seed == 3
    # a replaced setting carries what follows from it: the sizes follow quick, the source
    # follows the method
    full = dataclasses.replace(quick, quick=False)
    assert full.effective_sizes == Sizes() == JobConfig.paper_sizes().effective_sizes
    assert quick.effective_source == "posterior+model_error"
    assert dataclasses.replace(quick, method="cmaes").effective_source == "gaussian"
    # the diagnosis follows the HTML report unless told, and always runs with extend
    assert JobConfig(html=False).effective_diagnosis is False
    assert JobConfig(html=False, extend=True).effective_diagnosis is True
    with pytest.raises(ValueError, match="diagnosis=False skips the diagnosis"):
        JobConfig(extend=True, diagnosis=False)
    with pytest.raises(ValueError, match="source must be one of"):
        JobConfig(source="prior")  # type: ignore[arg-type]
    # what a job folder is checked against names every resolved setting
    settings = JobConfig(seed=2).settings({"name": "toy"}, "digest")
    assert settings["fit_seed"] == 2 and settings["source"] == "posterior+model_error"
    assert settings["sizes"] == Sizes().to_json()
