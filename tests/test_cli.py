"""The command line: JSON output, campaign files, refusals with a one-line reason."""

import json
import re
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

from bayesdoor.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "runs.nc"
    args = ["simulate", "--system", "elevator_door", "--state", "healthy", "--state", "D2"]
    args += ["--condition", "v_max=0.5", "--seed", "3"]
    result = runner.invoke(app, [*args, "--out", str(out), "--json"])
    return out, result, args


def test_simulate_writes_a_campaign_and_prints_json(simulated):
    out, result, _ = simulated
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert payload["file"] == str(out)
    assert payload["runs"] == 2
    assert payload["channels"] == ["A1X", "A1Z", "A2X", "A2Z"]
    ds = xr.load_dataset(out)
    assert ds.acceleration.dims == ("run", "channel", "time")
    assert list(ds.state.values) == ["healthy", "D2"]
    assert ds.attrs["sampling_rate_hz"] == 2048.0
    # the seed drew the D2 flat's depth from its prior (0.05-0.3 mm); the healthy run has none
    assert 0.05e-3 <= float(ds.d2_depth.values[1]) <= 0.3e-3
    assert float(ds.d2_depth.values[0]) == 0.0
    assert np.all(np.isfinite(ds.acceleration.values))


def test_same_seed_same_file(simulated, tmp_path):
    out, _, args = simulated
    again = tmp_path / "again.nc"
    assert runner.invoke(app, [*args, "--out", str(again)]).exit_code == 0
    a, b = xr.load_dataset(out), xr.load_dataset(again)
    np.testing.assert_array_equal(a.acceleration.values, b.acceleration.values)
    np.testing.assert_array_equal(a.d2_angle.values, b.d2_angle.values)


def test_existing_output_is_not_overwritten(simulated):
    out, _, args = simulated
    before = out.read_bytes()
    result = runner.invoke(app, [*args, "--out", str(out)])
    assert result.exit_code != 0
    assert "already exists" in result.stderr and "--force" in result.stderr
    assert out.read_bytes() == before


#: the speed check's message names the value as a plain number and the allowed range
def _speed_message(value: str) -> str:
    return (
        rf"--condition v_max={re.escape(value)} m/s is outside the range the model simulates, "
        r"\[0\.1, 0\.761\] m/s"
    )


@pytest.mark.parametrize(
    ("extra", "pattern"),
    [
        (["--state", "D3"], re.escape("unknown state 'D3'")),
        (["--condition", "v_max=0"], _speed_message("0.0")),
        (["--condition", "v_max=-0.2"], _speed_message("-0.2")),
        (["--condition", "v_max=0.9"], _speed_message("0.9")),
        (["--condition", "v_max=nan"], _speed_message("nan")),
        (
            ["--condition", "speed=0.3"],
            re.escape("--condition speed: unknown name; the known names are v_max"),
        ),
        (
            ["--condition", "v_max=0.3", "--condition", "v_max=0.4"],
            re.escape("v_max is given twice"),
        ),
        (["--param", "nope=1"], re.escape("--param nope: unknown name; the known names are ")),
        (["--param", "K=stiff"], re.escape("--param K: 'stiff' is not a number")),
        (["--param", "K=9000"], re.escape("K=9000.0")),
        (["--param", "K"], re.escape("NAME=VALUE")),
        (["--system", "lift"], re.escape("no system called 'lift'")),
    ],
)
def test_bad_input_exits_non_zero_with_a_reason(tmp_path, extra, pattern):
    out = tmp_path / "x.nc"
    base = ["simulate", "--out", str(out), "--system", "elevator_door"]
    if "--condition" not in extra:
        base += ["--condition", "v_max=0.4"]
    result = runner.invoke(app, [*base, *extra])
    assert result.exit_code != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and re.search(pattern, lines[0]), result.stderr
    assert not out.exists()


@pytest.mark.slow
def test_demo_writes_the_campaign_and_both_psd_figures(tmp_path):
    out = tmp_path / "demo"
    result = runner.invoke(app, ["demo", "--out", str(out), "--json"])
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert payload["runs"] == 3
    for key in ("psd_plot", "psd_plot_full_band"):
        assert Path(payload[key]).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert list(xr.load_dataset(payload["campaign"]).state.values) == ["healthy", "D1", "D2"]
    again = runner.invoke(app, ["demo", "--out", str(out)])
    assert again.exit_code != 0 and "--force" in again.stderr


def test_classify_prints_the_records_votes():
    from rich.console import Console

    from bayesdoor.cli._classify import _records_table

    records = [
        {
            "record": "IR007_0",
            "state": "inner_race",
            "runs": 10,
            "majority": "inner_race",
            "mean_probabilities": {"healthy": 0.1, "inner_race": 0.85},
            "share_flagged": 0.7,
            "flagged": True,
        },
        {
            "record": "B007_0",
            "state": "ball",
            "runs": 4,
            "majority": None,
            "mean_probabilities": None,
            "share_flagged": 1.0,
            "flagged": True,
        },
    ]
    console = Console(record=True, width=120)
    console.print(_records_table(records, ["healthy", "inner_race"]))
    text = console.export_text()
    assert re.search(
        r"IR007_0\s.*inner_race\s.*10\s.*inner_race\s.*0\.85\s.*70 % \(flagged\)", text
    )
    assert re.search(r"B007_0\s.*uncalled\s.*-\s.*100 % \(flagged\)", text)
    assert "signal shows" not in text  # no record was checked
    # with a signature check: the states whose signature shows in most of the runs
    records[0]["shows"] = {"inner_race": 0.8, "healthy": 0.0}
    records[1]["shows"] = {"inner_race": 0.25, "healthy": 0.5}
    console = Console(record=True, width=140)
    console.print(_records_table(records, ["healthy", "inner_race"]))
    text = console.export_text()
    assert "signal shows" in text
    assert re.search(r"IR007_0\s.*10\s.*inner_race\s.*inner_race\s.*0\.85", text)
    assert re.search(r"B007_0\s.*4\s.*-\s.*uncalled", text)
