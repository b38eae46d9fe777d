"""``bayesdoor inspect``: validation, summary, JSON, PSD figures, refusals; the report helpers."""

import doctest
import json
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.signal
from typer.testing import CliRunner

from bayesdoor.cli import app
from bayesdoor.io import make_campaign, save_campaign, to_csv
from bayesdoor.report import campaign_psds, motion_windows, plot_state_psds

runner = CliRunner()
FS = 2048.0
CHANNELS = ["A1X", "A1Z", "A2X", "A2Z"]
#: a tone per state during the motion, on a 4 Hz bin of the 512-sample Welch grid
TONES_HZ = {"healthy": 24.0, "D1": 40.0, "D2": 60.0}
T_START, T_STOP = 0.25, 2.0
STATES = ["healthy", "healthy", "healthy", "D1", "D1", "D2", "D2"]
SPEEDS = [0.3, 0.4, 0.4, 0.3, 0.5, 0.4, 0.4]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def synthetic(states=STATES, v_max=SPEEDS, *, channels=CHANNELS, fs=FS, window=True, seed=0):
    """A small campaign: noise at rest, a state-specific tone while the door moves."""
    rng = np.random.default_rng(seed)
    n = int(2.5 * fs)
    t = np.arange(n) / fs
    moving = (t >= T_START) & (t <= T_STOP)
    acc = 1e-3 * rng.standard_normal((len(states), len(channels), n))
    for r, state in enumerate(states):
        for c in range(len(channels)):
            acc[r, c, moving] += (1.0 + 0.5 * c) * np.sin(2 * np.pi * TONES_HZ[state] * t[moving])
    runs = len(states)
    windows = {"t_start": np.full(runs, T_START), "t_stop": np.full(runs, T_STOP)}
    return make_campaign(
        acc,
        channels=channels,
        fs=fs,
        state=states,
        system="elevator_door",
        v_max=v_max,
        split=["calibration"] + ["test"] * (runs - 1),
        **(windows if window else {}),
    )


def write(ds, path):
    save_campaign(ds, path)
    return path, path.read_bytes()


@pytest.fixture(scope="module")
def valid(tmp_path_factory):
    return write(synthetic(), tmp_path_factory.mktemp("valid") / "campaign.nc")[0]


def invoke(*args):
    return runner.invoke(app, ["inspect", *map(str, args)])


def test_valid_campaign_json_summary(valid):
    result = invoke(valid, "--json")
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert payload["valid"] is True and payload["problems"] == []
    assert payload["runs"] == 7
    assert payload["channels"] == CHANNELS
    assert payload["sampling_rate_hz"] == FS
    assert payload["states"] == {"healthy": 3, "D1": 2, "D2": 2}
    assert payload["splits"] == {"calibration": 1, "test": 6}
    assert payload["runs_by_state_and_split"]["healthy"] == {"calibration": 1, "test": 2}
    assert payload["conditions"] == {
        "v_max": {"unit": "m/s", "runs": {"0.3": 2, "0.4": 4, "0.5": 1}}
    }
    assert payload["record_samples"] == 5120 and payload["record_duration_s"] == 2.5
    assert payload["system"] == "elevator_door"
    assert payload["motion_window"] == "t_start/t_stop"
    assert payload["plots"] == [] and payload["summary_file"] is None


def test_valid_campaign_human_summary(valid):
    result = invoke(valid)
    assert result.exit_code == 0, result.output
    assert "runs      7" in result.stdout
    assert "sampling  2048 Hz" in result.stdout
    assert "0.4 m/s x 4" in result.stdout
    assert not result.stderr


def test_plots_written_under_out_and_not_overwritten(valid, tmp_path):
    source = valid.read_bytes()
    out = tmp_path / "report"
    result = invoke(valid, "--out", out, "--json")
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    expected = [out / "psd_0-100Hz.png", out / "psd_0-1024Hz.png"]
    assert payload["plots"] == [str(p) for p in expected]
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["inspect.json", "psd_0-100Hz.png", "psd_0-1024Hz.png"]
    )
    for path in expected:
        assert path.read_bytes()[:8] == PNG_MAGIC
    assert json.loads((out / "inspect.json").read_text())["states"] == payload["states"]
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    again = invoke(valid, "--out", out)
    assert again.exit_code != 0
    assert "already exists" in again.stderr and "--force" in again.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before

    forced = invoke(valid, "--out", out, "--force", "--json")
    assert forced.exit_code == 0, forced.output
    assert sorted(p.name for p in out.iterdir()) == sorted(before)
    assert valid.read_bytes() == source


def test_motion_window_detected_without_t_start_and_t_stop(tmp_path):
    path, _ = write(synthetic(window=False), tmp_path / "nowindow.nc")
    result = invoke(path, "--json", "--out", tmp_path / "out")
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert payload["motion_window"] == "detected" and payload["warnings"] == []
    assert len(payload["plots"]) == 2


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("nan", "problem: run 1, channel A1Z: 5 NaN and 0 Inf samples of 5120"),
        ("missing_channel", "problem: channels ['A2Z'] are missing"),
        ("sampling_rate", "problem: sampling_rate_hz is 1000 Hz but 2048 Hz is expected"),
    ],
)
def test_bad_file_fails_with_one_line_per_problem_and_stays_untouched(tmp_path, case, message):
    if case == "nan":
        ds = synthetic()
        ds["acceleration"][1, 1, 100:105] = np.nan
    elif case == "missing_channel":
        ds = synthetic(channels=CHANNELS[:3])
    else:
        ds = synthetic(fs=1000.0)
    path, before = write(ds, tmp_path / f"{case}.nc")
    result = invoke(path, "--json")
    assert result.exit_code == 1
    payload = json.loads(result.stdout)
    assert payload["valid"] is False and len(payload["problems"]) == 1
    lines = result.stderr.splitlines()
    assert sum(line.startswith(message) for line in lines) == 1, result.stderr
    assert lines[-1] == f"error: {path} is not a valid campaign: 1 problem(s) found"
    assert path.read_bytes() == before


def test_runs_with_their_own_problems_are_left_out_of_the_plots(tmp_path):
    ds = synthetic()
    ds["acceleration"][4, 0, 10] = np.inf
    path, before = write(ds, tmp_path / "inf.nc")
    out = tmp_path / "out"
    result = invoke(path, "--out", out, "--json")
    assert result.exit_code == 1
    payload = json.loads(result.stdout)
    assert len(payload["plots"]) == 2 and all(p.exists() for p in map(type(out), payload["plots"]))
    assert any("runs [4] are left out of the PSD plots" in w for w in payload["warnings"])
    assert path.read_bytes() == before


def test_a_window_that_holds_no_whole_welch_segment_is_left_out(tmp_path):
    ds = synthetic()
    # 601 samples (the format's check passes) but no segment boundary (every 256) fits
    ds["t_start"][3] = 3 / FS
    ds["t_stop"][3] = 603 / FS
    path, _ = write(ds, tmp_path / "short.nc")
    result = invoke(path, "--out", tmp_path / "out", "--json")
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert len(payload["plots"]) == 2
    assert len(payload["warnings"]) == 1
    assert payload["warnings"][0].startswith("run 3: its motion window")
    assert "left out of the PSD plots" in payload["warnings"][0]


def test_no_plots_without_a_usable_time_axis(tmp_path):
    ds = synthetic()
    ds.attrs.pop("sampling_rate_hz")
    path, _ = write(ds, tmp_path / "nofs.nc")
    out = tmp_path / "out"
    result = invoke(path, "--out", out, "--json")
    assert result.exit_code == 1
    payload = json.loads(result.stdout)
    assert payload["plots"] == []
    assert any("no PSD plots" in w and "missing_sampling_rate" in w for w in payload["warnings"])


def test_speed_outside_the_model_range_is_a_warning_not_a_failure(tmp_path):
    path, _ = write(synthetic(v_max=[0.05, *SPEEDS[1:]]), tmp_path / "slow.nc")
    result = invoke(path, "--json")
    assert result.exit_code == 0, result.output
    warnings = json.loads(result.stdout)["warnings"]
    assert len(warnings) == 1 and "elevator_door model cannot simulate runs at" in warnings[0]
    # the value as the condition's check prints it: a plain number, as simulate shows it
    assert (
        "v_max=0.05 m/s is outside the range the model simulates, [0.1, 0.761] m/s" in (warnings[0])
    )


def test_csv_folder(tmp_path):
    folder = tmp_path / "csv"
    to_csv(synthetic(), folder)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    result = invoke(folder, "--json")
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert payload["runs"] == 7 and payload["states"] == {"healthy": 3, "D1": 2, "D2": 2}
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


def _states(states):
    return [a for s in states for a in ("--state", s)]


def test_csv_folder_without_sidecar_takes_system_conditions_and_state(tmp_path):
    """Plain CSV files carry no system, speeds or labels: --system, --condition and --state
    give them."""
    folder = tmp_path / "csv"
    to_csv(synthetic(), folder)
    (folder / "campaign.json").unlink()
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    bare = invoke(folder, "--json")
    assert bare.exit_code == 1
    assert json.loads(bare.stdout)["problem_codes"] == ["missing_system"]
    door = ["--system", "elevator_door"]
    unlabelled = invoke(folder, "--json", *door)
    assert unlabelled.exit_code == 1
    assert json.loads(unlabelled.stdout)["problem_codes"] == ["missing_v_max"]

    one = invoke(folder, "--json", *door, "--condition", "v_max=0.4")
    assert one.exit_code == 0, one.output
    payload = json.loads(one.stdout)
    assert payload["conditions"]["v_max"]["runs"] == {"0.4": 7}
    assert payload["states"] == {"unknown": 7}

    per_run = ["--condition", "v_max=" + ",".join(map(str, SPEEDS))]
    each = invoke(folder, "--json", *door, *per_run, *_states(STATES))
    assert each.exit_code == 0, each.output
    payload = json.loads(each.stdout)
    assert payload["conditions"]["v_max"]["runs"] == {"0.3": 2, "0.4": 4, "0.5": 1}
    assert payload["states"] == {"healthy": 3, "D1": 2, "D2": 2}
    # the runs are the files in name order: run_0000.csv is the first healthy run
    assert payload["runs_by_state_and_split"]["healthy"] == {"(none)": 3}
    assert payload["motion_window"] == "detected"
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--condition", "v_max=0.4,0.5"], "--condition v_max takes one value for all 7 runs"),
        (_states(["healthy", "D1"]), "--state takes one value for all 7 runs of "),
        (
            ["--system", "elevator_door", "--condition", "v_max=0.4", "--state", "D3"],
            "unknown state labels ['D3']",
        ),
    ],
)
def test_csv_labels_that_do_not_fit_the_runs(tmp_path, extra, message):
    folder = tmp_path / "csv"
    to_csv(synthetic(), folder)
    (folder / "campaign.json").unlink()
    result = invoke(folder, *extra)
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], result.stderr


def test_v_max_and_state_are_refused_where_the_metadata_is_stored(valid, tmp_path):
    folder = tmp_path / "csv"
    to_csv(synthetic(), folder)
    for path, where in ((valid, "the file"), (folder, "its campaign.json")):
        result = invoke(path, "--condition", "v_max=0.4")
        assert result.exit_code == 2
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1, result.stderr
        assert "--condition v_max label the runs of a folder of CSV files without" in lines[0]
        assert f"holds its own metadata in {where}" in lines[0]


def test_csv_files_that_do_not_form_a_campaign(tmp_path):
    folder = tmp_path / "csv"
    to_csv(synthetic(), folder)
    (folder / "campaign.json").unlink()
    run = folder / "run_0001.csv"
    run.write_text(run.read_text().replace("A2Z", "B2Z", 1))
    result = invoke(folder, "--json", "--out", tmp_path / "out")
    assert result.exit_code == 1
    payload = json.loads(result.stdout)
    assert payload["runs"] == 0 and payload["channels"] == [] and payload["plots"] == []
    assert payload["problem_codes"] == ["missing_channels"]
    assert "run_0001.csv: channels" in payload["problems"][0]
    assert not (tmp_path / "out").exists()


def test_out_must_be_a_folder(valid, tmp_path):
    out = tmp_path / "taken"
    out.write_text("a file")
    result = invoke(valid, "--out", out)
    assert result.exit_code == 2
    assert "--out" in result.stderr and "is a file" in result.stderr
    assert out.read_text() == "a file"


def test_unreadable_or_missing_file_fails_with_one_line(tmp_path):
    bogus = tmp_path / "bogus.nc"
    bogus.write_text("not netcdf")
    result = invoke(bogus)
    assert result.exit_code != 0
    assert len(result.stderr.strip().splitlines()) == 1
    assert "bogus.nc is not a readable NetCDF campaign file: it is a text file" in result.stderr
    assert bogus.read_text() == "not netcdf"
    missing = invoke(tmp_path / "nothing.nc")
    assert missing.exit_code != 0 and "no campaign at" in missing.stderr


def test_campaign_psds_equal_scipy_welch_on_the_motion_window():
    ds = synthetic()
    psds = campaign_psds(ds)
    # the segments of 512 samples, every 256, that lie wholly inside [T_START, T_STOP]
    first = int(np.ceil(T_START * FS))
    last = int(np.floor(T_STOP * FS))
    starts = [s for s in range(0, ds.sizes["time"] - 511, 256) if s >= first and s + 511 <= last]
    segment = ds["acceleration"].values[..., starts[0] : starts[-1] + 512]
    freqs, reference = scipy.signal.welch(segment, fs=FS, nperseg=512)
    np.testing.assert_array_equal(psds.freqs, freqs)
    # float64 round-off of the same sums in another order: a few ulp of log10 values near 1-10
    np.testing.assert_allclose(psds.log_psd, np.log10(reference), rtol=1e-12, atol=1e-12)
    assert psds.states == tuple(STATES) and psds.channels == tuple(CHANNELS)


def test_detected_motion_window_finds_the_tones():
    ds = synthetic(window=False)
    start, stop, notes = motion_windows(ds)
    # detection errs inward by up to about one 20 ms RMS window
    np.testing.assert_allclose(start, T_START, atol=0.025)
    np.testing.assert_allclose(stop, T_STOP, atol=0.025)
    assert notes == []
    psds = campaign_psds(ds, runs=[0, 3, 5])
    peaks = psds.freqs[np.argmax(psds.log_psd, axis=-1)]
    for row, state in zip(peaks, ["healthy", "D1", "D2"], strict=True):
        np.testing.assert_array_equal(row, TONES_HZ[state])


def test_undetectable_motion_falls_back_to_the_whole_record():
    ds = synthetic(window=False)
    ds["acceleration"][2] = 0.0
    ds["acceleration"][2, :, 0] = 1.0
    start, stop, notes = motion_windows(ds)
    assert (start[2], stop[2]) == (0.0, float(ds.time[-1]))
    assert len(notes) == 1 and notes[0].startswith("run 2:")


def test_plot_state_psds_refuses_bad_arguments(tmp_path):
    psds = campaign_psds(synthetic(), runs=[0])
    with pytest.raises(ValueError, match="band must be two increasing percentiles"):
        plot_state_psds(psds, tmp_path / "x.png", band=(95.0, 5.0))
    with pytest.raises(ValueError, match="fewer than two bins"):
        plot_state_psds(psds, tmp_path / "x.png", fmax=2.0)
    assert not (tmp_path / "x.png").exists()


DOCS = Path(__file__).resolve().parent.parent / "docs"


#: docs/features.md's examples take 7-31 s with an empty JAX cache on a 2-core machine (the
#: higher figures with other work beside it), most of it compiling the feature functions they
#: call (tests/test_features.py checks those in the default suite): in the long tier, as
#: tests/test_doc_blocks.py puts pages whose examples take more than a few seconds
@pytest.mark.parametrize("page", [pytest.param("features.md", marks=pytest.mark.long), "data.md"])
def test_documentation_examples_run_and_print_what_they_show(page, tmp_path, monkeypatch):
    """Every ```python block of the page, in order, in one namespace, as doctests."""
    text = (DOCS / page).read_text(encoding="utf-8")
    blocks = re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)
    assert blocks, f"{page} has no python examples"
    monkeypatch.chdir(tmp_path)  # examples that write files write them here
    parser = doctest.DocTestParser()
    test = parser.get_doctest("\n".join(blocks), {}, page, str(DOCS / page), 0)
    flags = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
    runner = doctest.DocTestRunner(optionflags=flags)
    output: list[str] = []
    runner.run(test, out=output.append)
    assert runner.failures == 0, "".join(output)
    assert runner.tries >= len(blocks)
