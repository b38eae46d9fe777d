"""``bayesdoor classify``, ``run`` and ``demo``: JSON, reuse, refusals, one-line errors.

``classify`` is exercised with a model trained by the job of ``test_pipeline`` on its tone
system (seconds); ``run`` on the door is checked for the errors it must give before any work,
and end to end (``demo --quick``) under ``slow``.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from test_pipeline import job, runs_to_classify, tone_campaign
from typer.testing import CliRunner

from bayesdoor.cli import app
from bayesdoor.io import make_campaign, save_campaign
from bayesdoor.pipeline import STAGES

runner = CliRunner()
#: the names of the door's catalogue of discrepancy causes (docs/model.md)
DESIGN_CAUSES = (
    "frame_mode",
    "wheel_eccentricity",
    "rail_waviness",
    "sensor_cross_axis",
    "mains_hum",
)


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    out = tmp_path_factory.mktemp("model")
    job(out)
    return out


@pytest.fixture(scope="module")
def tone_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("data") / "tones.nc"
    save_campaign(runs_to_classify(tone_campaign(seed=5)), path)
    return path


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def test_classify_json_and_report(model, tone_file, tmp_path):
    out = tmp_path / "report"
    result = invoke("classify", tone_file, "--model", model, "--out", out, "--json")
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert {"runs", "metrics", "classes", "report", "model"} <= set(payload)
    assert len(payload["runs"]) == 12
    for run in payload["runs"]:
        assert {"predicted", "probabilities", "entropy", "mutual_information", "ood"} <= set(run)
    assert {"accuracy", "ece", "nll", "brier", "confusion"} <= set(payload["metrics"])
    html = (out / "report" / "index.html").read_text()
    assert len(re.findall(r"data:image/png;base64,", html)) >= 5
    # only under --out
    assert sorted(p.name for p in out.iterdir()) == ["classify", "report"]


@pytest.mark.long
def test_classify_reuses_and_refuses_to_overwrite(model, tone_file, tmp_path):
    out = tmp_path / "report"
    assert invoke("classify", tone_file, "--model", model, "--out", out).exit_code == 0
    before = (out / "classify" / "classification.json").read_bytes()
    again = invoke("classify", tone_file, "--model", model, "--out", out)
    assert again.exit_code == 0 and "reused" in again.output
    other = tone_file.parent / "other.nc"
    save_campaign(runs_to_classify(tone_campaign(seed=6)), other)
    refused = invoke("classify", other, "--model", model, "--out", out)
    assert refused.exit_code == 2
    assert "pass --force" in refused.output
    assert (out / "classify" / "classification.json").read_bytes() == before
    forced = invoke("classify", other, "--model", model, "--out", out, "--force")
    assert forced.exit_code == 0
    assert (out / "classify" / "classification.json").read_bytes() != before


def test_classify_selective_risk_option(model, tone_file, tmp_path):
    """0 calls every run; a risk outside [0, 1) is refused with nothing written."""
    every = invoke(
        "classify",
        tone_file,
        "--model",
        model,
        "--out",
        tmp_path / "all",
        "--json",
        "--selective-risk",
        "0",
    )
    assert every.exit_code == 0, every.output
    payload = json.loads(every.stdout)
    assert payload["selective"] is None
    assert all(r["predicted"] == r["most_probable"] for r in payload["runs"])
    strict = invoke(
        "classify",
        tone_file,
        "--model",
        model,
        "--out",
        tmp_path / "strict",
        "--json",
        "--selective-risk",
        "0.001",
    )
    assert strict.exit_code == 0, strict.output
    calls = json.loads(strict.stdout)
    assert calls["selective"]["target_risk"] == 0.001
    assert calls["n_abstained"] == sum(r["predicted"] is None for r in calls["runs"])
    refused = invoke(
        "classify", tone_file, "--model", model, "--out", tmp_path / "bad", "--selective-risk", "1"
    )
    assert refused.exit_code == 2 and "--selective-risk must lie in [0, 1)" in refused.output
    assert not (tmp_path / "bad").exists()


def test_classify_without_a_model(tone_file, tmp_path):
    result = invoke("classify", tone_file, "--model", tmp_path, "--out", tmp_path / "o")
    assert result.exit_code == 2
    assert "no ensemble.eqx" in result.output
    assert not (tmp_path / "o").exists()


def door_file(path, states, split=None):
    rng = np.random.default_rng(0)
    extra = {} if split is None else {"split": split}
    ds = make_campaign(
        0.01 * rng.standard_normal((len(states), 4, 4096)),
        channels=["A1X", "A1Z", "A2X", "A2Z"],
        fs=2048.0,
        state=states,
        v_max=np.full(len(states), 0.4),
        system="elevator_door",
        **extra,
    )
    save_campaign(ds, path)
    return path


def test_run_without_calibration_runs_fails_in_one_line(tmp_path):
    path = door_file(tmp_path / "faulty.nc", ["D1", "D2", "D1"])
    result = invoke("run", path, "--out", tmp_path / "job")
    assert result.exit_code == 2
    assert "no healthy run to update the model on" in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert not (tmp_path / "job").exists()


def test_run_refuses_a_folder_that_is_not_a_job(tmp_path):
    path = door_file(tmp_path / "c.nc", ["healthy", "D1"])
    out = tmp_path / "busy"
    out.mkdir()
    (out / "thesis.tex").write_text("precious")
    result = invoke("run", path, "--out", out)
    assert result.exit_code == 2 and "not a bayesdoor job folder" in result.output
    assert sorted(p.name for p in out.iterdir()) == ["thesis.tex"]


def test_run_bad_options_and_files(tmp_path):
    path = door_file(tmp_path / "c.nc", ["healthy", "D1"])
    bad = invoke("run", path, "--out", tmp_path / "j", "--source", "uniform")
    assert bad.exit_code == 2 and "--source" in bad.output
    # a point fit has no posterior to draw from: asking for one is refused (without a
    # --source, cmaes takes the Gaussian scatter)
    point = invoke(
        "run", path, "--out", tmp_path / "j", "--method", "cmaes", "--source", "posterior"
    )
    assert point.exit_code == 2 and "--source gaussian" in point.output
    missing = invoke("run", tmp_path / "nope.nc", "--out", tmp_path / "j")
    assert missing.exit_code == 2 and "no such file" in missing.output
    text = tmp_path / "text.nc"
    text.write_text("not netcdf")
    garbled = invoke("run", text, "--out", tmp_path / "j")
    assert garbled.exit_code == 2 and "not a readable NetCDF campaign file" in garbled.output
    assert not (tmp_path / "j").exists()


@pytest.mark.slow
def test_demo_quick_end_to_end_and_reuse(tmp_path):
    out = tmp_path / "demo"
    first = invoke("demo", "--quick", "--out", out, "--json")
    assert first.exit_code == 0, first.output
    payload = json.loads(first.stdout)
    assert len(payload["runs"]) == 300
    assert {"accuracy", "ece", "nll", "brier", "confusion"} <= set(payload["metrics"])
    assert [s["name"] for s in payload["stages"]] == list(STAGES)
    assert [s["reused"] for s in payload["stages"]] == [False] * len(STAGES)
    assert payload["diagnosis"]["verdict"] in ("none", None, *DESIGN_CAUSES)
    assert (out / "report" / "index.html").is_file()
    assert (out / "diagnose" / "diagnosis.html").is_file()
    assert len(list((out / "report" / "runs").glob("run-*.html"))) == 300
    second = invoke("demo", "--quick", "--out", out, "--json")
    assert second.exit_code == 0
    again = json.loads(second.stdout)
    assert [s["reused"] for s in again["stages"]] == [True] * len(STAGES)
    assert again["metrics"] == payload["metrics"]
    refused = invoke("demo", "--out", out)
    assert refused.exit_code == 2 and "--force" in refused.output


def _payload(diagnostics):
    row = {"point": 2499.0, "mean": 2353.0, "sd": 68.0, "q5": 2256.0, "q95": 2476.0}
    return {
        "fit": {
            "method": "nuts",
            "j": 0.7987,
            "parameters": {"K": row},
            "diagnostics": diagnostics,
        },
        "runs": [{}] * 3,
        "metrics": None,
        "n_ood": 0,
        "n_failed": 0,
        "diagnosis": None,
        "report": "out/report/index.html",
    }


def test_the_summary_says_whether_the_posterior_passed_its_gates():
    from rich.console import Console

    from bayesdoor.cli._run import gates_line, print_summary

    failed = {
        "passed": False,
        "messages": [
            "R-hat 1.044 > 1.01 for z[6]: the chains disagree; run longer chains",
            "bulk ESS 51 < 400 for z[1] (2 chains x 150 draws): draw more samples",
        ],
    }
    console = Console(record=True, width=200)
    print_summary(_payload(failed), console, quick=True)
    text = console.export_text()
    assert (
        "sampling gates FAILED (R-hat 1.044 > 1.01 for z[6]; bulk ESS 51 < 400 for z[1] "
        "(2 chains x 150 draws))" in text
    )
    assert "run without it" in text
    assert "run without it" not in gates_line(failed, quick=False)
    passed = {"passed": True, "rhat_max": 1.004, "ess_bulk_min": 612.3, "divergences": 0}
    assert gates_line(passed) == "sampling gates passed (R-hat 1.004, bulk ESS 612, 0 divergences)"
    assert gates_line(None) is None  # a CMA-ES point has no gates
    console = Console(record=True, width=200)
    print_summary(_payload(None), console)
    assert "sampling gates" not in console.export_text()


def test_demo_passes_the_jobs_options_on(tmp_path, monkeypatch):
    """``demo`` takes ``run``'s job options, with its defaults (docs/cli.md)."""
    import bayesdoor.cli._run as run_module
    import bayesdoor.systems as systems

    seen = []
    campaign = object()
    shipped = type(
        "Shipped", (), {"cached_path": lambda self: tmp_path, "load": lambda self, **k: campaign}
    )()
    monkeypatch.setattr(systems, "get_demo", lambda name: shipped)
    monkeypatch.setattr(
        run_module, "run", lambda c, out, request, **kwargs: seen.append((c, request))
    )
    args = ["demo", "--out", str(tmp_path / "d"), "--json"]
    assert runner.invoke(app, args).exit_code == 0
    more = ["--method", "cmaes", "--source", "gaussian", "--extend"]
    assert runner.invoke(app, args + more).exit_code == 0
    (first, default), (_, chosen) = seen
    assert first is campaign
    assert (default.method, default.source, default.extend) == ("nuts", None, False)
    assert (chosen.method, chosen.source, chosen.extend) == ("cmaes", "gaussian", True)


def test_run_drops_jaxs_caches_between_the_stages(tmp_path, monkeypatch):
    """``bayesdoor run`` owns its process: its job drops JAX's caches between the stages
    (bayesdoor._memory.release_between_stages), and only while it runs."""
    import bayesdoor._memory as memory
    import bayesdoor.pipeline as pipeline

    seen = []

    def stand_in(*args, **kwargs):
        seen.append(memory._BETWEEN_STAGES["on"])
        raise ValueError("stopped here")

    monkeypatch.setattr(pipeline, "run_job", stand_in)
    path = door_file(tmp_path / "c.nc", ["healthy", "healthy", "D1"])
    result = invoke("run", path, "--out", tmp_path / "job", "--quick")
    assert "stopped here" in result.output
    assert seen == [True]
    assert memory._BETWEEN_STAGES["on"] is False
