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
    assert {"j", "parameters", "diagnostics", "law", "model_error", "files"} <= set(payload)
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
