"""Every command against the bad inputs users produce.

Each bad input must give a one-line reason on stderr that names the problem and the fix, a
non-zero exit, no traceback, and leave every file as it was: the input untouched, no output
folder created, no half-written result. A run killed half way (Ctrl-C, SIGKILL) must leave
no half-written result files, and its rerun must complete.

Nothing here fits or trains the door: ``run`` and ``demo`` go through the CLI to
:func:`bayesdoor.pipeline.run_job`, which the ``fast_jobs`` fixture points at the small tone
system of ``test_pipeline`` (given the door's channels and name) with a stand-in fit and tiny
sizes; the commands' own checks, which are the point here, all run before that.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr
from _toy_system import DURATION, REST, ToySystem
from test_pipeline import SIZES, stand_in_diagnose, stand_in_fit
from test_pipeline import SYSTEM as TONES
from typer.testing import CliRunner

import bayesdoor.door.datasets
import bayesdoor.pipeline
from bayesdoor.cli import app
from bayesdoor.io import make_campaign, save_campaign, to_csv
from bayesdoor.pipeline import STAGES

runner = CliRunner()
CHANNELS = ("A1X", "A1Z", "A2X", "A2Z")
FS = 2048.0
ROOT = Path(__file__).resolve().parent.parent


class DoorTones(ToySystem):
    """The tone system of ``test_pipeline`` with the door's four channels (name it so)."""

    @property
    def channels(self):
        return CHANNELS

    def simulate_values(self, values, operating, **options):
        res = super().simulate_values(values, operating, **options)
        x, z = res.signals[:, 0], res.signals[:, 1]
        return eqx.tree_at(lambda r: r.signals, res, jnp.stack([x, z, 0.7 * x, 1.3 * z], 1))


SYSTEM = DoorTones(
    label="elevator_door",
    d2_amplitude=TONES.d2_amplitude,
    d2_phase=TONES.d2_phase,
    background=TONES.background,
)


def campaign(states=None, *, split=True, channels=CHANNELS, seed=0) -> xr.Dataset:
    """A door-like campaign of the tone system: 3 calibration runs, then 3 per state."""
    states = states or ["healthy"] * 3 + ["healthy", "D1", "D2"] * 3
    rng = np.random.default_rng(seed)
    speeds = np.resize([0.3, 0.5], len(states))
    signals = []
    for state, v in zip(states, speeds, strict=True):
        values = {"k": 0.5 + 0.02 * rng.standard_normal(), "m": 1.0, "law": 2.0}
        sev = {n: rng.uniform(lo, hi) for n, (lo, hi) in SYSTEM.states[state].severity.items()}
        res = SYSTEM.simulate_values(values, v, state=state, severity=sev)
        signals.append(np.asarray(res.signals[0]))
    acc = np.stack(signals)[:, [CHANNELS.index(c) for c in channels]]
    calibration = min(3, len(states))
    extra = {"split": ["calibration"] * calibration + ["test"] * (len(states) - calibration)}
    return make_campaign(
        acc,
        channels=list(channels),
        fs=FS,
        state=states,
        system="elevator_door",
        v_max=speeds,
        t_start=np.full(len(states), REST),
        # the last sample lies at DURATION - 1/FS: the window must end inside the record
        t_stop=np.full(len(states), DURATION - 0.01),
        **(extra if split else {}),
    )


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (hidden ones included) with its bytes."""
    if not folder.exists():
        return {}
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def refused(result, *phrases, code=2):
    """A one-line reason that holds ``phrases``, exit ``code``, no traceback, no output."""
    assert isinstance(result.exception, SystemExit), repr(result.exception)  # not a crash
    assert result.exit_code == code, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    for phrase in phrases:
        assert phrase in lines[0], (phrase, lines[0])
    assert "Traceback" not in result.output
    assert result.stdout == ""  # nothing a pipe could take for a result
    return lines[0]


def stopped(result, *phrases):
    """Ctrl-C's answer: exit 130 (128 + SIGINT, what a shell reports for it) and, as the last
    line on stderr, one ``interrupted: ...`` line that holds ``phrases``; no traceback, nothing
    on stdout."""
    assert result.exit_code == 130, result.output
    lines = result.stderr.strip().splitlines()
    assert [line for line in lines if line.startswith("interrupted: ")] == lines[-1:], lines
    for phrase in phrases:
        assert phrase in lines[-1], (phrase, lines[-1])
    assert "Traceback" not in result.output
    assert result.stdout.strip() == ""  # the demo's progress bar may leave a blank line
    return lines[-1]


def door_fit(*args, **options):
    """The stand-in fit of ``test_pipeline`` with a model-error scale per door channel."""
    fit = stand_in_fit(*args, **options)
    fit.model_error_draws = lambda: np.full((200, len(CHANNELS)), 0.05)
    return fit


def fast(monkeypatch, fit=door_fit, diagnose=stand_in_diagnose, interrupt: str | None = None):
    """Point the CLI's ``run_job`` at the tone system, stand-ins of the fit and the diagnosis,
    and tiny sizes.

    ``interrupt``: a stage at whose start Ctrl-C is pressed (``KeyboardInterrupt``).
    """
    real = bayesdoor.pipeline.run_job

    def run_job(system, data, out, config, **options):
        assert system.name == "elevator_door"  # the CLI picked the campaign's system
        report = options["report"]

        def line(text):
            report(text)
            if text.startswith(f"{interrupt}: computing"):
                raise KeyboardInterrupt

        options.update(fit=fit, diagnose=diagnose, progress=False, report=line)
        return real(SYSTEM, data, out, dataclasses.replace(config, sizes=SIZES), **options)

    monkeypatch.setattr(bayesdoor.pipeline, "run_job", run_job)


@pytest.fixture
def fast_jobs(monkeypatch):
    fast(monkeypatch)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """The good campaign and the bad files users produce, by name."""
    folder = tmp_path_factory.mktemp("inputs")
    good = campaign()
    paths = {"good": save_campaign(good, folder / "good.nc")}
    paths["png"] = folder / "photo.nc"
    paths["png"].write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    paths["csv"] = folder / "run_0000.nc"
    to_csv(good.isel(run=[0]), folder / "csv")
    paths["csv"].write_bytes((folder / "csv" / "run_0000.csv").read_bytes())
    whole = paths["good"].read_bytes()
    paths["truncated"] = folder / "truncated.nc"
    paths["truncated"].write_bytes(whole[: len(whole) // 2])
    paths["zero_bytes"] = folder / "zero.nc"
    paths["zero_bytes"].write_bytes(b"")
    paths["other_netcdf"] = folder / "temperatures.nc"
    xr.Dataset({"temperature": ("x", [20.5, 21.0])}).to_netcdf(paths["other_netcdf"])
    paths["folder"] = folder / "a_folder.nc"
    paths["folder"].mkdir()
    paths["missing_channel"] = save_campaign(
        campaign(channels=CHANNELS[:3]), folder / "three_channels.nc"
    )
    nan = good.copy(deep=True)
    nan["acceleration"][1, 2, 100:110] = np.nan  # a calibration run
    paths["nan_calibration"] = save_campaign(nan, folder / "nan_calibration.nc")
    nan_test = good.copy(deep=True)
    nan_test["acceleration"][4, 0, 50] = np.inf  # a test run (D1)
    paths["nan_test"] = save_campaign(nan_test, folder / "nan_test.nc")
    paths["empty"] = save_campaign(good.isel(run=[]), folder / "empty.nc")
    faulty = campaign(["D1", "D2", "D1", "D2"], split=False)
    paths["faulty"] = save_campaign(faulty, folder / "faulty.nc")
    slow = good.assign_coords(time=good["time"] * FS / 1000.0)
    paths["other_rate"] = save_campaign(
        slow.assign_attrs(sampling_rate_hz=1000.0), folder / "other_rate.nc"
    )
    in_g = good.copy(deep=True)
    in_g["acceleration"].attrs["units"] = "g"
    paths["in_g"] = save_campaign(in_g.assign_attrs(units="g"), folder / "in_g.nc")
    paths["other_system"] = save_campaign(
        good.assign_attrs(system="robot_arm"), folder / "other_system.nc"
    )
    return paths


#: how each command is called on a campaign file, an output folder and a model folder
COMMANDS = {
    "inspect": lambda path, out, model: ["inspect", path, "--out", out],
    "fit": lambda path, out, model: ["fit", path, "--out", out, "--method", "cmaes", "--quick"],
    "run": lambda path, out, model: ["run", path, "--out", out, "--quick"],
    "classify": lambda path, out, model: ["classify", path, "--model", model, "--out", out],
    "diagnose": lambda path, out, model: ["diagnose", path, "--out", out, "--quick"],
}
#: the files that are not a campaign, and what the message must say about each
NOT_A_CAMPAIGN = {
    "png": "is not a readable NetCDF campaign file: it is a PNG image; pass the campaign's .nc",
    "csv": "is not a readable NetCDF campaign file: it is a text file (it starts "
    "'time,A1X,A1Z,A2X,A2Z'); a campaign in CSV files is a folder of them",
    "truncated": "it is NetCDF but cannot be read",
    "zero_bytes": "is not a readable NetCDF campaign file: it is empty (0 bytes)",
    "folder": "is a folder, not a campaign file",
}


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("case", NOT_A_CAMPAIGN)
def test_a_file_that_is_not_a_campaign(files, tmp_path, command, case):
    path = files[case]
    before = snapshot(path.parent)
    out = tmp_path / "out"
    result = invoke(*COMMANDS[command](path, out, tmp_path))
    if command == "inspect" and case == "folder":
        refused(result, "no *.csv files in", str(path))  # a folder is read as CSV files
    else:
        line = refused(result, str(path), NOT_A_CAMPAIGN[case])
        if case == "truncated":
            size = path.stat().st_size
            assert f"(a) truncated by an interrupted copy or download (it has {size} bytes)" in line
    assert not out.exists()
    assert snapshot(path.parent) == before


@pytest.mark.parametrize("command", COMMANDS)
def test_a_netcdf_file_of_something_else(files, tmp_path, command):
    path = files["other_netcdf"]
    before = path.read_bytes()
    out = tmp_path / "out"
    result = invoke(*COMMANDS[command](path, out, tmp_path))
    if command == "inspect":  # the problems listed, exit 1
        assert result.exit_code == 1 and isinstance(result.exception, SystemExit)
        assert "problem: a campaign needs a variable 'acceleration'" in result.stderr
    else:
        refused(result, str(path), "acceleration")
    assert not out.exists() or command == "inspect"
    assert path.read_bytes() == before


#: what fit, run and diagnose say about campaigns they cannot use
UNUSABLE = {
    "missing_channel": {
        command: "channels ['A2Z'] are missing" for command in ("fit", "run", "diagnose")
    },
    "nan_calibration": {
        command: "a run the model is fitted on is unusable: run 1, channel A2X: 10 NaN"
        for command in ("fit", "run", "diagnose")
    },
    "empty": {
        "fit": "the campaign holds no runs",
        "run": "holds no runs",
        "diagnose": "holds no runs",
    },
    "other_rate": {
        command: "sampling_rate_hz is 1000 Hz but 2048 Hz is expected"
        for command in ("fit", "run", "diagnose")
    },
    "in_g": {
        command: "convert the samples to m/s^2 by multiplying by 9.80665"
        for command in ("fit", "run", "diagnose")
    },
    "other_system": {
        command: "no system called 'robot_arm': available bearing, elevator_door"
        for command in ("fit", "run", "diagnose")
    },
    "faulty": {
        "fit": "no healthy run to update the model on (its runs: 2 D1, 2 D2)",
        "run": "no healthy run to update the model on (its runs: 2 D1, 2 D2)",
        "diagnose": "has no healthy run",
    },
}


@pytest.mark.parametrize("command", ["fit", "run", "diagnose"])
@pytest.mark.parametrize("case", UNUSABLE)
def test_a_campaign_the_model_cannot_be_fitted_on(files, tmp_path, command, case):
    path = files[case]
    before = snapshot(path.parent)
    out = tmp_path / "out"
    refused(invoke(*COMMANDS[command](path, out, tmp_path)), UNUSABLE[case][command])
    assert not out.exists()
    assert snapshot(path.parent) == before


@pytest.mark.parametrize(
    ("case", "problem"),
    [
        ("missing_channel", "problem: channels ['A2Z'] are missing"),
        ("nan_calibration", "problem: run 1, channel A2X: 10 NaN and 0 Inf samples"),
        ("empty", "problem: the campaign holds no runs"),
    ],
)
def test_inspect_lists_the_problems_and_exits_1(files, case, problem):
    path = files[case]
    before = path.read_bytes()
    result = invoke("inspect", path, "--json")
    assert result.exit_code == 1 and isinstance(result.exception, SystemExit)
    assert json.loads(result.stdout)["valid"] is False
    lines = result.stderr.strip().splitlines()
    assert any(line.startswith(problem) for line in lines), result.stderr
    assert lines[-1].startswith(f"error: {path} is not a valid campaign")
    assert path.read_bytes() == before


def test_fit_accepts_bad_records_outside_the_calibration_runs(files, tmp_path, monkeypatch):
    """An Inf in a test run does not stop the fit (it reaches fit_campaign)."""
    import bayesdoor.inference

    def reached(system, data, **options):
        raise ValueError("fit_campaign reached")

    monkeypatch.setattr(bayesdoor.inference, "fit_campaign", reached)
    out = tmp_path / "out"
    result = invoke(*COMMANDS["fit"](files["nan_test"], out, None), "--json")
    refused(result, "fit_campaign reached")
    assert not out.exists()


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--fix", "I"], "--fix takes NAME=VALUE (e.g. --fix "),
        (["--fix", "I=abc"], "--fix I: 'abc' is not a number"),
        (["--fix", "I=99"], "--fix I=99: parameter I=99.0 is outside its allowed range [1, 9]"),
        (["--fix", "I=1.5"], "--fix I=1.5: parameter I=1.5 must be an integer"),
        (["--fix", "law=3"], "--fix law: unknown name; the known names are "),
        (["--fix", "I=3", "--fix", "I=4"], "--fix I is given twice"),
        (["--each", "law"], "--each law: not a parameter of elevator_door; give one of its"),
        (["--each", "K"], "--each K: not an integer parameter of elevator_door"),
        (["--each", "I", "--fix", "I=3"], "--each I and --fix I=... both given"),
    ],
)
def test_fit_refuses_a_bad_fix_or_each_before_any_work(files, tmp_path, options, message):
    out = tmp_path / "out"
    refused(invoke(*COMMANDS["fit"](files["good"], out, None), *options), message)
    assert not out.exists()


#: a ``bayesdoor run`` (argv: campaign, job folder, tests folder) SIGKILLed as its fit stage
#: writes its files
KILLED_IN_THE_FIT = textwrap.dedent(
    """
    import os, signal, sys
    from pathlib import Path

    sys.path.insert(0, sys.argv[3])
    import pytest
    import test_robustness
    def killed(*args, **options):
        fit = test_robustness.door_fit(*args, **options)

        def save(folder):
            Path(folder).mkdir(parents=True)
            (Path(folder) / "point.json").write_text('{"k": 0.5, ')
            os.kill(os.getpid(), signal.SIGKILL)

        fit.save = save
        return fit

    with pytest.MonkeyPatch.context() as mp:
        test_robustness.fast(mp, fit=killed)
        test_robustness.invoke("run", sys.argv[1], "--out", sys.argv[2], "--quick")
    """
)


def visible(files: dict[str, bytes]) -> list[str]:
    """The files of a snapshot that are not inside a hidden (temporary) file or folder."""
    return sorted(f for f in files if not any(part.startswith(".") for part in Path(f).parts))


@pytest.fixture(scope="module")
def story(files, tmp_path_factory):
    """One job folder through three runs: SIGKILLed while the fit writes its files, then
    interrupted by Ctrl-C as the classification starts, then run to the end."""
    out = tmp_path_factory.mktemp("story") / "job"
    seen = {}
    killed = subprocess.run(
        [
            sys.executable,
            "-c",
            KILLED_IN_THE_FIT,
            str(files["good"]),
            str(out),
            str(ROOT / "tests"),
        ],
        cwd=ROOT,
        capture_output=True,
        timeout=600,
    )
    seen["killed"] = (killed.returncode, snapshot(out), killed.stderr.decode())
    with pytest.MonkeyPatch.context() as mp:
        fast(mp, interrupt="classify")
        seen["interrupted"] = (invoke("run", files["good"], "--out", out, "--quick"), snapshot(out))
    with pytest.MonkeyPatch.context() as mp:
        fast(mp)
        seen["finished"] = (
            invoke("run", files["good"], "--out", out, "--quick", "--json"),
            snapshot(out),
        )
    return out, seen


@pytest.fixture(scope="module")
def job(files, tmp_path_factory):
    """A finished quick job on the good campaign: the model folder of the tests that classify.
    ``story`` makes one too, through a killed and an interrupted run, in the long tier."""
    out = tmp_path_factory.mktemp("job") / "job"
    with pytest.MonkeyPatch.context() as mp:
        fast(mp)
        result = invoke("run", files["good"], "--out", out, "--quick")
    assert result.exit_code == 0, result.output
    return out


# 162 s (the setup of `story`) in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine
# under load 12-16): a job killed in a fresh Python process, interrupted, then run to the end; in
# the long tier, which CI runs after the default suite
@pytest.mark.long
def test_a_killed_run_leaves_no_half_written_result_and_the_rerun_completes(story):
    out, seen = story
    code, after_kill, stderr = seen["killed"]
    assert code == -signal.SIGKILL, stderr
    # the half-written file lies in the fit stage's hidden temporary folder, nowhere else
    assert any(f.startswith(".fit.") and f.endswith("point.json") for f in after_kill)
    assert visible(after_kill) == []

    interrupted, after_interrupt = seen["interrupted"]
    stopped(
        interrupted,
        f"the job in {out} was stopped in its classify stage",
        "its finished stages (fit, generate, adequacy, train) are kept",
        "run the same command again to resume",
    )
    # the finished stages are kept whole (each with its record), nothing else; the temporary
    # folder of the killed run is gone
    names = visible(after_interrupt)
    assert {Path(f).parts[0] for f in names} == {"fit", "generate", "adequacy", "train"}
    assert {
        "fit/stage.json",
        "generate/stage.json",
        "adequacy/stage.json",
        "train/stage.json",
    } <= set(names)
    assert names == sorted(after_interrupt)

    finished, after = seen["finished"]
    assert finished.exit_code == 0, finished.output
    stages = {s["name"]: s["reused"] for s in json.loads(finished.stdout)["stages"]}
    assert stages == {name: name in ("fit", "generate", "adequacy", "train") for name in STAGES}
    assert visible(after) == sorted(after) and "job.json" in after


@pytest.fixture
def demo_is(files, monkeypatch):
    """``bayesdoor demo`` on the good tone campaign (no recording by the virtual rig)."""
    from bayesdoor.io import load_campaign

    monkeypatch.setattr(
        bayesdoor.door.datasets._demo,
        "load_demo_campaign",
        lambda **kw: load_campaign(files["good"]),
    )
    # cached already: the demo says nothing about recording it
    monkeypatch.setattr(
        bayesdoor.door.datasets._demo._DoorDemo, "cached_path", lambda _: files["good"]
    )


#: the system and operating condition that `bayesdoor simulate` needs
SIMULATE_DOOR = ("--system", "elevator_door", "--condition", "v_max=0.3")

#: per command: its arguments (campaign, output, model) and the files of a previous result
PREVIOUS = {
    "simulate": (
        lambda path, out, model: ["simulate", "--out", out / "runs.nc", *SIMULATE_DOOR],
        ["runs.nc"],
    ),
    "inspect": (COMMANDS["inspect"], ["inspect.json", "psd_0-100Hz.png", "psd_0-1024Hz.png"]),
    "fit": (COMMANDS["fit"], ["fit.json", "posterior.nc", "fit_summary.json"]),
    "run": (COMMANDS["run"], ["job.json", "fit/stage.json"]),
    "demo": (lambda path, out, model: ["demo", "--out", out, "--quick"], ["job.json"]),
    "classify": (COMMANDS["classify"], ["classify/stage.json", "classify/classification.json"]),
    "diagnose": (COMMANDS["diagnose"], ["diagnosis.json", "diagnosis.html"]),
}


@pytest.mark.parametrize("command", PREVIOUS)
def test_a_previous_result_is_refused_without_force_and_left_as_it_was(
    files, job, tmp_path, command, demo_is
):
    arguments, previous = PREVIOUS[command]
    out = tmp_path / "out"
    for name in previous:
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        # another job's record, another classification's: the same names, other settings
        text = json.dumps({"job_hash": "another", "config_hash": "another", "seed": 7})
        (out / name).write_text(text if name.endswith(".json") else "a previous result")
    before = snapshot(out)
    line = refused(invoke(*arguments(files["good"], out, job)))
    assert "--force" in line
    assert snapshot(out) == before


@pytest.mark.parametrize("command", PREVIOUS)
def test_an_output_path_below_a_file_is_refused_before_any_work(
    files, job, tmp_path, command, demo_is
):
    arguments, _ = PREVIOUS[command]
    blocker = tmp_path / "notes.txt"
    blocker.write_text("mine")
    line = refused(invoke(*arguments(files["good"], blocker / "out", job)))
    assert f"{blocker} is a file" in line
    assert blocker.read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


@pytest.mark.parametrize("command", PREVIOUS)
def test_a_read_only_output_folder_is_refused_before_any_work(
    files, job, tmp_path, command, demo_is, monkeypatch
):
    """A folder without write permission (for root, which writes anyway, the permission
    check is told so for that folder alone)."""
    arguments, _ = PREVIOUS[command]
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    if os.geteuid() == 0:
        access = os.access
        monkeypatch.setattr(
            os, "access", lambda path, mode: Path(path) != locked and access(path, mode)
        )
    try:
        line = refused(invoke(*arguments(files["good"], locked / "out", job)))
        assert f"no permission to write in {locked}" in line
        assert list(locked.iterdir()) == []
    finally:
        locked.chmod(0o755)


def test_a_full_disk_while_writing_is_one_line_and_leaves_nothing(files, tmp_path, monkeypatch):
    """The figures of ``inspect --out`` fail half way: nothing is left, not even the folder."""
    import errno

    import matplotlib.figure

    def full(self, path, **options):
        Path(path).write_bytes(b"\x89PNG half")
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", full)
    out = tmp_path / "report"
    line = refused(invoke("inspect", files["good"], "--out", out))
    assert "No space left on device; pass a writable --out with free space" in line
    assert not out.exists()


def test_classify_refuses_a_model_of_another_version(files, job, tmp_path):
    model = tmp_path / "old_model"
    shutil.copytree(job / "train", model)
    ensemble = model / "ensemble.eqx"
    header, weights = ensemble.read_bytes().split(b"\n", 1)
    old = {**json.loads(header), "format_version": 0, "library_version": "0.0.1"}
    ensemble.write_bytes(json.dumps(old).encode() + b"\n" + weights)
    out = tmp_path / "report"
    line = refused(invoke("classify", files["good"], "--model", model, "--out", out))
    assert "ensemble format version 0 (written by bayesdoor 0.0.1)" in line
    assert "retrain and save the ensemble with this version" in line
    assert not out.exists()


def test_classify_refuses_a_truncated_model_before_any_work(files, job, tmp_path):
    model = tmp_path / "cut_model"
    shutil.copytree(job / "train", model)
    ensemble = model / "ensemble.eqx"
    ensemble.write_bytes(ensemble.read_bytes()[:-100])
    out = tmp_path / "report"
    line = refused(invoke("classify", files["good"], "--model", model, "--out", out))
    assert "the file is truncated or corrupted" in line
    assert not out.exists()


def test_classify_refuses_a_campaign_without_the_models_channels(files, job, tmp_path):
    out = tmp_path / "report"
    args = ["classify", files["missing_channel"], "--model", job, "--out", out]
    line = refused(invoke(*args))
    assert "takes 4 channels, the campaign has 3 (A1X, A1Z, A2X)" in line
    assert not out.exists()


def test_classify_refuses_an_empty_campaign(files, job, tmp_path):
    out = tmp_path / "report"
    refused(invoke("classify", files["empty"], "--model", job, "--out", out), "no runs")
    assert not out.exists()


def test_classify_reports_a_bad_record_run_by_run(files, job, tmp_path):
    """Corrupted runs are reported per run, not crashed on."""
    out = tmp_path / "report"
    result = invoke("classify", files["nan_test"], "--model", job, "--out", out, "--json")
    assert result.exit_code == 0, result.output
    runs = json.loads(result.stdout)["runs"]
    assert runs[4]["problem"] == "the record holds non-finite samples"
    assert runs[4]["predicted"] is None
    assert all(r["problem"] is None and r["most_probable"] for i, r in enumerate(runs) if i != 4)


# 54 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): a
# whole door simulation before the write it interrupts; in the long tier, which CI runs after the
# default suite
@pytest.mark.long
def test_simulate_interrupted_while_writing_leaves_no_file(tmp_path, monkeypatch):
    """Ctrl-C half way through the NetCDF write: no file, no temporary file."""

    def interrupted(self, path, **options):
        Path(path).write_bytes(b"\x89HDF\r\n\x1a\n half")
        raise KeyboardInterrupt

    monkeypatch.setattr(xr.Dataset, "to_netcdf", interrupted)
    result = invoke("simulate", "--out", tmp_path / "runs.nc", *SIMULATE_DOOR)
    stopped(result, "nothing was written", "run the same command again")
    assert list(tmp_path.iterdir()) == []


# 67 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): a fit
# command run twice, its plots and posterior written; in the long tier, which CI runs after the
# default suite
@pytest.mark.long
def test_fit_killed_half_way_keeps_the_previous_fit_and_the_rerun_completes(
    files, tmp_path, monkeypatch
):
    """``fit --force`` over a finished fit, interrupted after the new fit wrote part of its
    files: the old fit stays whole; the rerun replaces it and leaves no hidden leftovers."""
    from test_json_contract import made_up_fit, made_up_predictive

    import bayesdoor.inference

    out = tmp_path / "fit"
    out.mkdir()
    for name in ("fit.json", "posterior.nc", "fit_summary.json", "trace.png"):
        (out / name).write_text(f"the previous {name}")
    before = snapshot(out)

    def interrupted(*args, **options):
        raise KeyboardInterrupt

    monkeypatch.setattr(bayesdoor.inference, "fit_campaign", made_up_fit)
    monkeypatch.setattr(bayesdoor.inference, "posterior_predictive", interrupted)
    args = ["fit", files["good"], "--out", out, "--method", "nuts", "--force"]
    stopped(invoke(*args), "the fit was stopped", "--out is as it was", "run the same command")
    assert snapshot(out) == before

    monkeypatch.setattr(bayesdoor.inference, "posterior_predictive", made_up_predictive)
    result = invoke(*args, "--json")
    assert result.exit_code == 0, result.output
    after = snapshot(out)
    assert visible(after) == sorted(after)  # no hidden leftovers
    assert set(after) == {
        "fit.json",
        "posterior.nc",
        "fit_summary.json",
        "cmaes_history.png",
        "pairs.png",
        "trace.png",
        "predictive_psd.png",
    }
    assert all(after[name] != before[name] for name in before)
    assert json.loads(after["fit_summary.json"])["method"] == "nuts"


# 43 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): two
# fit commands; in the long tier, which CI runs after the default suite
@pytest.mark.long
def test_a_forced_point_fit_removes_the_posterior_it_replaces(files, tmp_path, monkeypatch):
    """After ``--force`` the folder describes the new fit alone: a CMA-ES fit over a NUTS fit
    leaves no ``posterior.nc``, pair or trace plot of the old one."""
    import dataclasses

    from test_json_contract import made_up_fit, made_up_predictive

    import bayesdoor.inference

    def point_fit(*args, **options):
        fit = made_up_fit(*args, **options)
        return dataclasses.replace(fit, method="cmaes", idata=None, diagnostics=None)

    monkeypatch.setattr(bayesdoor.inference, "posterior_predictive", made_up_predictive)
    out = tmp_path / "fit"
    monkeypatch.setattr(bayesdoor.inference, "fit_campaign", made_up_fit)
    assert invoke("fit", files["good"], "--out", out, "--method", "nuts").exit_code == 0
    assert {"posterior.nc", "pairs.png", "trace.png"} <= set(snapshot(out))
    monkeypatch.setattr(bayesdoor.inference, "fit_campaign", point_fit)
    args = ["fit", files["good"], "--out", out, "--method", "cmaes", "--force", "--json"]
    result = invoke(*args)
    assert result.exit_code == 0, result.output
    assert set(snapshot(out)) == {
        "fit.json",
        "fit_summary.json",
        "cmaes_history.png",
        "predictive_psd.png",
    }
    assert json.loads(result.stdout)["method"] == "cmaes"


def test_demo_with_a_damaged_cache_says_how_to_record_it_again(tmp_path, monkeypatch):
    """A demo campaign cut short in the cache (a full disk, a copy gone wrong)."""
    from bayesdoor.door.datasets import demo_paths

    monkeypatch.setenv("BAYESDOOR_DATA", str(tmp_path / "cache"))
    nc, truth = demo_paths()
    nc.parent.mkdir()
    good = save_campaign(campaign(), tmp_path / "good.nc").read_bytes()
    nc.write_bytes(good[: len(good) // 3])
    truth.write_text("{}")
    out = tmp_path / "demo"
    line = refused(invoke("demo", "--out", out, "--quick"))
    assert "is not a readable NetCDF campaign file" in line
    assert f"delete {nc} and run the demo again to record it anew" in line
    assert not out.exists()


#: 27 s each in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load
#: 12-16), a quick job stopped and run again: the generate case in the long tier, which CI runs
#: after the default suite; the fit case stays
@pytest.mark.parametrize("stage", ["fit", pytest.param("generate", marks=pytest.mark.long)])
def test_run_interrupted_in_a_stage_says_what_is_kept_and_resumes(files, tmp_path, stage):
    """Ctrl-C as a stage starts: the stages before it are kept (and reused by the rerun), the
    stopped one leaves no visible file."""
    out = tmp_path / "job"
    with pytest.MonkeyPatch.context() as mp:
        fast(mp, interrupt=stage)
        line = stopped(invoke("run", files["good"], "--out", out, "--quick"))
    assert f"the job in {out} was stopped in its {stage} stage" in line
    if stage == "fit":
        assert "no stage had finished" in line
    else:
        assert "its finished stages (fit) are kept with the training data chunks" in line
    assert {Path(f).parts[0] for f in visible(snapshot(out))} <= {"fit"}
    with pytest.MonkeyPatch.context() as mp:
        fast(mp)
        rerun = invoke("run", files["good"], "--out", out, "--quick", "--json")
    assert rerun.exit_code == 0, rerun.output
    reused = {s["name"]: s["reused"] for s in json.loads(rerun.stdout)["stages"]}
    assert reused["fit"] == (stage == "generate") and not reused["generate"]


def test_classify_interrupted_while_writing_leaves_nothing(files, job, tmp_path, monkeypatch):
    real = bayesdoor.pipeline.classify_stage

    def interrupted(model, campaign, folder, **options):
        (Path(folder) / "classification.json").write_text('{"runs": [')
        raise KeyboardInterrupt

    out = tmp_path / "report"
    monkeypatch.setattr(bayesdoor.pipeline, "classify_stage", interrupted)
    line = stopped(invoke("classify", files["good"], "--model", job, "--out", out))
    assert f"the classification in {out} was stopped in its classify stage" in line
    assert "no stage had finished" in line
    assert not out.exists()
    monkeypatch.setattr(bayesdoor.pipeline, "classify_stage", real)
    rerun = invoke("classify", files["good"], "--model", job, "--out", out, "--json")
    assert rerun.exit_code == 0, rerun.output


def test_diagnose_interrupted_keeps_the_previous_diagnosis(files, tmp_path, monkeypatch):
    import bayesdoor.diagnose

    def interrupted(*args, **options):
        raise KeyboardInterrupt

    out = tmp_path / "diagnosis"
    out.mkdir()
    for name in ("diagnosis.json", "diagnosis.html"):
        (out / name).write_text(f"the previous {name}")
    before = snapshot(out)
    monkeypatch.setattr(bayesdoor.diagnose, "diagnose_campaign", interrupted)
    result = invoke("diagnose", files["good"], "--out", out, "--quick", "--force")
    stopped(result, "the diagnosis was stopped", "no half-written file", "run the same command")
    assert snapshot(out) == before


def test_inspect_interrupted_while_plotting_leaves_nothing(files, tmp_path, monkeypatch):
    import matplotlib.figure

    def interrupted(self, path, **options):
        Path(path).write_bytes(b"\x89PNG half")
        raise KeyboardInterrupt

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", interrupted)
    out = tmp_path / "inspect"
    result = invoke("inspect", files["good"], "--out", out)
    stopped(result, "inspect was stopped", "no half-written file", "run the same command")
    assert not out.exists()


def test_demo_interrupted_while_recording_keeps_nothing_in_the_cache(tmp_path, monkeypatch):
    import bayesdoor.door.rig
    from bayesdoor.door.datasets import demo_paths

    def interrupted(self, *args, **options):
        raise KeyboardInterrupt

    monkeypatch.setenv("BAYESDOOR_DATA", str(tmp_path / "cache"))
    monkeypatch.setattr(bayesdoor.door.rig.VirtualRig, "run", interrupted)
    out = tmp_path / "demo"
    line = stopped(invoke("demo", "--out", out, "--quick"))
    assert "the recording of the demo campaign was stopped" in line
    assert f"nothing of it is kept in {demo_paths()[0].parent}" in line
    assert "run the same command again to record it" in line
    assert snapshot(tmp_path / "cache") == {}
    assert not out.exists()


def test_demo_says_once_that_it_recorded_the_campaign_and_where(tmp_path, monkeypatch):
    """The recording's bar is transient: after it, one line says how long the first use spent
    recording and where the campaign is cached; a later run, reading the cache, says nothing."""
    import bayesdoor.cli._run
    from bayesdoor.door.datasets import demo_paths

    monkeypatch.setenv("BAYESDOOR_DATA", str(tmp_path / "cache"))
    made = campaign()

    def record(**options):
        demo_paths()[0].parent.mkdir(parents=True, exist_ok=True)
        demo_paths()[0].write_bytes(b"recorded")
        return made

    jobs = []
    monkeypatch.setattr(bayesdoor.door.datasets._demo, "load_demo_campaign", record)
    monkeypatch.setattr(bayesdoor.cli._run, "run", lambda data, *a, **o: jobs.append(data))
    first = invoke("demo", "--out", tmp_path / "demo", "--quick")
    assert first.exit_code == 0, first.output
    said = " ".join(first.output.split())
    assert f"recorded the demo campaign ({made.sizes['run']} runs) in" in said
    assert f"cached in {demo_paths()[0]}" in said
    again = invoke("demo", "--out", tmp_path / "demo", "--quick")
    assert again.exit_code == 0 and "recorded the demo campaign" not in again.output
    assert jobs == [made, made]


# 39 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): a
# whole quick job; in the long tier, which CI runs after the default suite
@pytest.mark.long
def test_a_warning_in_the_job_is_one_line_without_a_source_path(files, tmp_path):
    """A failed sampling gate, say: ``warning: <message>`` once, its lines joined, not Python's
    ``/path/to/_job.py:197: SamplingGateWarning: ...`` with the offending source line."""
    import warnings

    message = "posterior FAILED the sampling gates:\nR-hat 1.07 > 1.01 for k\nbulk ESS 167 < 400"

    def warning_fit(*args, **options):
        warnings.warn(message, UserWarning, stacklevel=1)
        warnings.warn(message, UserWarning, stacklevel=1)  # another place, the same message
        return door_fit(*args, **options)

    with pytest.MonkeyPatch.context() as mp:
        fast(mp, fit=warning_fit)
        result = invoke("run", files["good"], "--out", tmp_path / "job", "--quick")
    assert result.exit_code == 0, result.output
    shown = [line for line in result.stderr.splitlines() if "FAILED" in line]
    assert len(shown) == 1, result.stderr
    assert shown[0].endswith(
        "] warning: posterior FAILED the sampling gates: R-hat 1.07 > 1.01 for k; "
        "bulk ESS 167 < 400"
    )
    assert "UserWarning" not in result.stderr and ".py:" not in result.stderr
