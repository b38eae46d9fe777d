"""``bayesdoor fit``: JSON keys, files, refusal to overwrite, a clear error without healthy runs."""

import json

import jax
import numpy as np
import pytest
from typer.testing import CliRunner

from bayesdoor.cli import app
from bayesdoor.door.rig import VirtualRig
from bayesdoor.io import make_campaign, save_campaign

runner = CliRunner()


@pytest.fixture(scope="module")
def rig_file(tmp_path_factory):
    campaign = VirtualRig().record(["healthy"] * 2, [0.5] * 2, key=jax.random.key(3))
    path = tmp_path_factory.mktemp("rig") / "rig.nc"
    save_campaign(campaign, path)
    return path


# 40 s with its rig file: in the long tier, to keep the default
# suite within its 10 minutes (the refusals below stay in it)
@pytest.mark.long
def test_fit_prints_json_writes_files_and_refuses_to_overwrite(rig_file, tmp_path):
    out = tmp_path / "fit"
    args = ["fit", str(rig_file), "--method", "cmaes", "--quick", "--out", str(out), "--json"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert payload["method"] == "cmaes"
    assert {"j", "parameters", "diagnostics", "held", "model_error", "files"} <= set(payload)
    assert set(payload["held"]) == {"I"}  # the contact-law index, searched, then held
    assert set(payload["parameters"]) == {"K", "n", "c_r", "I", "mu_s", "mu_d", "C", "MF"}
    for entry in payload["parameters"].values():
        assert {"point", "sd", "q5", "q95"} <= set(entry)
    assert payload["diagnostics"] is None  # CMA-ES has no sampler to diagnose
    assert np.isfinite(payload["j"]) and payload["j"] > 0
    assert 0.0 <= payload["predictive_coverage_90"] <= 1.0
    for name in ("fit.json", "cmaes_history.png", "predictive_psd.png", "fit_summary.json"):
        assert (out / name).is_file(), name
    stamp = (out / "fit.json").stat().st_mtime_ns
    again = runner.invoke(app, args)
    assert again.exit_code != 0
    assert "already exists" in again.stderr and "--force" in again.stderr
    assert (out / "fit.json").stat().st_mtime_ns == stamp


def test_fit_refuses_a_campaign_of_faulty_runs_with_one_line(tmp_path):
    signals = np.random.default_rng(0).standard_normal((2, 4, 4096))
    campaign = make_campaign(
        signals,
        channels=("A1X", "A1Z", "A2X", "A2Z"),
        fs=2048.0,
        state=["D1", "D2"],
        system="elevator_door",
        v_max=[0.4, 0.4],
    )
    path = tmp_path / "faulty.nc"
    save_campaign(campaign, path)
    result = runner.invoke(app, ["fit", str(path), "--out", str(tmp_path / "out"), "--json"])
    assert result.exit_code == 2
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "no healthy run" in lines[0]
    assert not (tmp_path / "out").exists()


def test_fit_rejects_a_bad_method_and_law(tmp_path):
    out = str(tmp_path / "out")
    bad_method = runner.invoke(app, ["fit", "x.nc", "--method", "bfgs", "--out", out])
    assert bad_method.exit_code == 2 and "--method 'bfgs'" in bad_method.stderr
    missing = runner.invoke(app, ["fit", str(tmp_path / "none.nc"), "--out", out])
    assert missing.exit_code == 2 and "no campaign file" in missing.stderr


def test_fix_and_each_reach_the_fit_and_give_one_folder_per_value(tmp_path, monkeypatch):
    """``--fix C=0.01 --each I``: one fit per contact-law index, each holding C and its I,
    written to ``--out/I_1`` ... ``I_9`` with an ablation table keyed by I (the fit and the
    figures are stand-ins; their own tests are elsewhere)."""
    import dataclasses

    from test_json_contract import made_up_fit
    from test_robustness import campaign

    import bayesdoor.inference
    from bayesdoor.cli import _fit as cli_fit

    calls = []

    def fit(system, data, **options):
        calls.append(options["problem"].fixed)
        made = made_up_fit(system, data, **options)
        held = dict(options["problem"].fixed or {})
        return dataclasses.replace(made, held=held, point={**made.point, **held})

    monkeypatch.setattr(bayesdoor.inference, "fit_campaign", fit)
    monkeypatch.setattr(
        cli_fit, "write_figures", lambda *a: {"files": {}, "predictive_coverage_90": 0.9}
    )
    path = save_campaign(campaign(), tmp_path / "campaign.nc")
    out = tmp_path / "laws"
    args = ["fit", str(path), "--out", str(out), "--method", "nuts", "--json"]
    result = runner.invoke(app, [*args, "--fix", "C=0.01", "--each", "I"])
    assert result.exit_code == 0, result.output
    assert calls == [{"C": 0.01, "I": float(i)} for i in range(1, 10)]
    payload = json.loads(result.stdout)
    assert payload["fixed"] == {"C": 0.01} and payload["each"] == "I"
    assert [f["folder"] for f in payload["fits"]] == [str(out / f"I_{i}") for i in range(1, 10)]
    assert [f["held"] for f in payload["fits"]] == calls
    assert all((out / f"I_{i}" / "fit.json").is_file() for i in range(1, 10))
    rows = payload["ablation"]
    assert [(r["parameter"], r["value"]) for r in rows] == [("I", i) for i in range(1, 10)]
    table = (out / "ablation.md").read_text()
    assert table.startswith("| I | J |") and "\n| 9 | 0.2500 |" in table
    # one fit: into --out itself, with what it held
    calls.clear()
    single = runner.invoke(app, [*args, "--force", "--fix", "I=3"])
    assert single.exit_code == 0, single.output
    assert calls == [{"I": 3.0}] and json.loads(single.stdout)["held"] == {"I": 3.0}
    assert (out / "fit.json").is_file()
    # nothing held: fit_campaign searches the integer parameters itself
    calls.clear()
    assert runner.invoke(app, [*args, "--force"]).exit_code == 0 and calls == [None]
