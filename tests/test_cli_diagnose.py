"""``bayesdoor diagnose``: the command-line contract and the HTML report.

The diagnosis itself (``bayesdoor.diagnose.diagnose_campaign``) is tested in
``test_diagnose_job.py``; here the command gets a :class:`Diagnosis` whose causes are ranked
by the real signatures on the synthetic records of ``test_diagnose`` (a hidden frame mode, a
hidden cross-axis leak) and whose gain is made up, so the report draws real residual maps and
evidence in seconds. The door campaign the command reads is a few runs of noise: the stand-in
does not look at it. The real command end to end on rig data is under ``slow``.
"""

from __future__ import annotations

import base64
import json
import re
from types import SimpleNamespace

import numpy as np
import pytest
from test_diagnose import diagnose_case, make_case
from typer.testing import CliRunner

from bayesdoor.cli import app
from bayesdoor.diagnose import Cause, Diagnosis, Gain
from bayesdoor.door import DOOR_CATALOGUE, ElevatorDoor
from bayesdoor.inference import FitResult
from bayesdoor.io import make_campaign, save_campaign
from bayesdoor.report import diagnosis_page, gain_figure

runner = CliRunner()
#: the diagnosis the command calls (replaced by a stand-in)
COMPUTE = "bayesdoor.cli._diagnose.compute"


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def as_diagnosis(ranking):
    """A :class:`Diagnosis` of the signature ranking, the named cause with a made-up gain."""
    gain = Gain(
        j_before=0.5,
        j_after=0.25,
        elpd_before=-100.0,
        elpd_after=-87.5,
        elpd_difference=12.5,
        elpd_se=2.0,
        n_runs=6,
        decisive=True,
    )
    causes = tuple(
        Cause(
            name=c.name,
            description=c.description,
            score=c.score,
            evidence=c.evidence,
            parameters=dict(c.parameters),
            gain=gain if c.name == ranking.verdict else None,
            confirmed=c.name == ranking.verdict,
            feature=c.feature,
        )
        for c in ranking.causes
    )
    return Diagnosis(
        verdict=ranking.verdict,
        causes=causes,
        ranking=ranking,
        catalogue=DOOR_CATALOGUE,
        rule="a stand-in rule",
        runs=np.arange(ranking.features.n_runs),
    )


@pytest.fixture(scope="module")
def frame_mode():
    return as_diagnosis(diagnose_case(make_case("frame_mode", 0)))


@pytest.fixture(scope="module")
def cross_axis():
    return as_diagnosis(diagnose_case(make_case("sensor_cross_axis", 0)))


@pytest.fixture
def calls(monkeypatch, frame_mode):
    seen = []

    def compute(system, campaign, fit, *, seed, quick, progress):
        seen.append(SimpleNamespace(system=system, fit=fit, seed=seed, quick=quick))
        return frame_mode

    monkeypatch.setattr(COMPUTE, compute)
    return seen


def door_file(path, states):
    rng = np.random.default_rng(0)
    ds = make_campaign(
        0.01 * rng.standard_normal((len(states), 4, 2048)),
        channels=["A1X", "A1Z", "A2X", "A2Z"],
        fs=2048.0,
        state=states,
        v_max=np.full(len(states), 0.4),
        system="elevator_door",
    )
    save_campaign(ds, path)
    return path


@pytest.fixture
def campaign(tmp_path):
    return door_file(tmp_path / "door.nc", ["healthy", "healthy", "D1"])


# ----------------------------------------------------------------------------- the contract


def test_json_alone_on_stdout_and_both_files_under_out(calls, campaign, tmp_path):
    out = tmp_path / "diag"
    result = invoke("diagnose", campaign, "--out", out, "--json", "--seed", 3, "--quick")
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert payload["verdict"] == "frame_mode"
    for cause in payload["causes"]:
        assert {"name", "evidence", "parameters", "gain"} <= set(cause)
    assert payload["causes"][0]["name"] == "frame_mode"
    gain = payload["causes"][0]["gain"]
    assert (gain["delta_j"], gain["delta_elpd"], gain["decisive"]) == (-0.25, 12.5, True)
    assert payload["report"] == str(out / "diagnosis.html")
    assert sorted(p.name for p in out.iterdir()) == ["diagnosis.html", "diagnosis.json"]
    on_disk = json.loads((out / "diagnosis.json").read_text())
    assert on_disk["causes"] == payload["causes"] and on_disk["report"] == "diagnosis.html"
    # the options reach the diagnosis; without --model it fits itself
    (call,) = calls
    assert (call.seed, call.quick, call.fit) == (3, True, None)
    assert call.system.name == ElevatorDoor().name


def test_human_summary_names_the_verdict_the_causes_and_the_report(calls, campaign, tmp_path):
    out = tmp_path / "diag"
    result = invoke("diagnose", campaign, "--out", out)
    assert result.exit_code == 0, result.output
    assert "verdict: frame_mode" in result.stdout
    for name in ("frame_mode", "rail_waviness", "sensor_cross_axis", "mains_hum"):
        assert name in result.stdout
    assert "delta_elpd = 12.5" in result.stdout
    assert f"report: {out / 'diagnosis.html'}" in result.stdout.replace("\n", "")


def test_a_previous_diagnosis_is_kept_without_force(calls, campaign, tmp_path):
    out = tmp_path / "diag"
    assert invoke("diagnose", campaign, "--out", out).exit_code == 0
    (out / "diagnosis.json").write_text("mine")
    refused = invoke("diagnose", campaign, "--out", out)
    assert refused.exit_code == 2
    assert "--force" in refused.output and len(refused.output.strip().splitlines()) == 1
    assert (out / "diagnosis.json").read_text() == "mine"
    assert len(calls) == 1  # refused before any work
    forced = invoke("diagnose", campaign, "--out", out, "--force")
    assert forced.exit_code == 0
    assert json.loads((out / "diagnosis.json").read_text())["verdict"] == "frame_mode"


def test_other_files_in_out_are_left_alone(calls, campaign, tmp_path):
    out = tmp_path / "diag"
    out.mkdir()
    (out / "notes.txt").write_text("precious")
    assert invoke("diagnose", campaign, "--out", out).exit_code == 0
    assert (out / "notes.txt").read_text() == "precious"
    assert sorted(p.name for p in out.iterdir()) == [
        "diagnosis.html",
        "diagnosis.json",
        "notes.txt",
    ]


def one_line_failure(result, *words, alone=True):
    """Exit 2 with the reason on one line (the only line unless the work had begun)."""
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    errors = [line for line in lines if line.startswith("error: ")]
    assert len(errors) == 1 and errors[0] == lines[-1], result.output
    assert len(lines) == 1 or not alone, result.output
    for word in words:
        assert word in lines[-1], lines[-1]
    assert "Traceback" not in result.output


def test_bad_campaigns_fail_in_one_line_before_any_work(calls, tmp_path):
    out = tmp_path / "diag"
    one_line_failure(invoke("diagnose", tmp_path / "nope.nc", "--out", out), "no such file")
    text = tmp_path / "text.nc"
    text.write_text("not netcdf")
    one_line_failure(invoke("diagnose", text, "--out", out), "not a readable NetCDF campaign file")
    faulty = door_file(tmp_path / "faulty.nc", ["D1", "D2"])
    one_line_failure(invoke("diagnose", faulty, "--out", out), "no healthy run", "1 D1, 1 D2")
    assert not out.exists() and calls == []


def test_an_out_that_is_a_file_is_refused(calls, campaign, tmp_path):
    target = tmp_path / "diag"
    target.write_text("a file")
    one_line_failure(invoke("diagnose", campaign, "--out", target), "is a file")
    assert target.read_text() == "a file" and calls == []


def test_bad_posterior_folders_fail_in_one_line(calls, campaign, tmp_path):
    out = tmp_path / "diag"
    one_line_failure(
        invoke("diagnose", campaign, "--out", out, "--model", tmp_path / "none"),
        "no such folder",
    )
    empty = tmp_path / "empty"
    empty.mkdir()
    one_line_failure(
        invoke("diagnose", campaign, "--out", out, "--model", empty), "holds no fit.json"
    )
    laws = tmp_path / "laws"  # bayesdoor fit --each I
    for i in (1, 2):
        (laws / f"I_{i}").mkdir(parents=True)
        (laws / f"I_{i}" / "fit.json").write_text("{}")
    one_line_failure(
        invoke("diagnose", campaign, "--out", out, "--model", laws),
        "holds several fits, one per value of a parameter (I_1, I_2)",
        str(laws / "I_1"),
    )
    broken = laws / "I_1"
    one_line_failure(
        invoke("diagnose", campaign, "--out", out, "--model", broken), "cannot be read"
    )
    assert not out.exists() and calls == []


def fake_fit_folder(tmp_path, monkeypatch, point):
    """A fit folder whose ``FitResult.load`` gives a fit with ``point`` (the IO is not tested)."""
    folder = tmp_path / "fit"
    folder.mkdir()
    (folder / "fit.json").write_text("{}")
    fit = SimpleNamespace(
        point=point,
        to_json=lambda: {"method": "cmaes", "j": 0.1, "parameters": point},
    )
    monkeypatch.setattr(FitResult, "load", classmethod(lambda cls, f: fit))
    return folder, fit


def test_a_posterior_of_another_system_is_refused(calls, campaign, tmp_path, monkeypatch):
    folder, _ = fake_fit_folder(tmp_path, monkeypatch, {"k": 0.5, "m": 1.0})
    result = invoke("diagnose", campaign, "--out", tmp_path / "diag", "--model", folder)
    one_line_failure(result, "another system", "'k'", "missing")
    assert calls == []


def test_a_posterior_of_the_system_is_reused(calls, campaign, tmp_path, monkeypatch):
    point = ElevatorDoor().nominal()
    folder, fit = fake_fit_folder(tmp_path, monkeypatch, point)
    out = tmp_path / "diag"
    result = invoke("diagnose", campaign, "--out", out, "--model", folder, "--json")
    assert result.exit_code == 0, result.output
    assert calls[0].fit is fit
    assert json.loads(result.stdout)["posterior"] == str(folder)
    page = (out / "diagnosis.html").read_text()
    assert "Base model" in page and "cmaes" in page


def test_a_diagnosis_error_is_one_line(monkeypatch, campaign, tmp_path):
    def refuse(system, campaign, fit, *, seed, quick, progress):
        raise ValueError("the campaign has 1 healthy run:\nthe held-out check needs 2")

    monkeypatch.setattr(COMPUTE, refuse)
    out = tmp_path / "diag"
    one_line_failure(invoke("diagnose", campaign, "--out", out), "needs 2", alone=False)
    assert not (out / "diagnosis.json").exists()


# ------------------------------------------------------------------------------- the report


def images(page: str) -> list[bytes]:
    data = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    return [base64.b64decode(d) for d in data]


def test_report_is_self_contained_with_the_residual_map_and_evidence(frame_mode):
    page = diagnosis_page(
        frame_mode.to_json(), features=frame_mode.features, catalogue=DOOR_CATALOGUE
    )
    pngs = images(page)
    # the residual map, then the frame mode's speed plot and excess spectrum, and the figures
    # of the other causes with a feature
    assert len(pngs) >= 3
    assert all(p[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs)
    assert 'src="http' not in page and "<script" not in page
    assert "Where the model is wrong" in page and "Gain of the extensions" in page
    assert "a resonance stays at one frequency" in page
    assert "The most likely cause of the discrepancy is frame_mode" in page
    # every check of the evidence is listed
    top = frame_mode.ranking.causes[0]
    for part in top.evidence.split("; "):
        assert part.replace("'", "&#x27;") in page or part in page


def test_report_shows_coherence_for_a_cross_axis_leak(cross_axis):
    assert cross_axis.ranking.verdict == "sensor_cross_axis"
    page = diagnosis_page(
        cross_axis.to_json(), features=cross_axis.features, catalogue=DOOR_CATALOGUE
    )
    assert "coherence, measured and simulated" in page
    # the fitted fraction with its uncertainty, as the diagnosis reports it
    with_sd = cross_axis.to_json()
    with_sd["causes"][0]["parameters"]["fraction"] = {
        "mean": 0.1,
        "sd": 0.01,
        "q5": 0.084,
        "q95": 0.116,
    }
    page = diagnosis_page(with_sd, features=cross_axis.features, catalogue=DOOR_CATALOGUE)
    assert "0.1 ± 0.01 [0.084, 0.116]" in page


def test_report_without_features_and_with_no_verdict():
    payload = {
        "verdict": None,
        "causes": [
            {"name": "frame_mode", "evidence": "a; b", "parameters": {}, "gain": {}},
            {"name": "rail_waviness", "evidence": "c", "parameters": {}, "gain": {}},
        ],
    }
    page = diagnosis_page(payload)
    assert "no cause has decisive evidence" in page
    assert images(page) == []
    assert "Gain of the extensions" not in page


def test_report_says_what_else_could_give_the_named_symptom():
    wheel = "wheel_eccentricity: the wavelength 31.28 mm is 0.4 % from the wheel's harmonic 6"
    payload = {
        "verdict": "rail_waviness",
        "causes": [
            {
                "name": "rail_waviness",
                "evidence": "c",
                "parameters": {},
                "gain": {"delta_elpd": 30.0, "delta_elpd_per_run": [20.0, -2.0, 12.0]},
                "confirmed": True,
                "alternatives": [wheel],
            },
            {"name": "frame_mode", "evidence": "a", "parameters": {}, "gain": {}},
        ],
    }
    page = diagnosis_page(payload)
    assert page.count("The same symptom could come from wheel_eccentricity") == 1
    assert "harmonic 6" in page
    # the gain table counts the runs that gain instead of listing them
    assert "runs_gaining" in page and "2 of 3" in page and "delta_elpd_per_run" not in page


def test_report_plots_each_runs_gain_against_its_speed(frame_mode):
    payload = frame_mode.to_json()
    page = diagnosis_page(payload, features=frame_mode.features, catalogue=DOOR_CATALOGUE)
    n = frame_mode.features.n_runs
    gain = payload["causes"][0]["gain"]
    gain["delta_elpd_per_run"] = [float(d) for d in np.linspace(-2.0, 9.0, n)]
    gain["delta_elpd_runs"] = list(range(n))[::-1]
    with_runs = diagnosis_page(payload, features=frame_mode.features, catalogue=DOOR_CATALOGUE)
    assert len(images(with_runs)) == len(images(page)) + 1
    assert "held-out gain of each run against its speed" in with_runs
    speeds = frame_mode.features.residuals.speeds
    assert gain_figure(payload["causes"], speeds)[:8] == b"\x89PNG\r\n\x1a\n"
    # nothing to plot: no per-run gains, or positions that do not match them
    assert gain_figure(frame_mode.to_json()["causes"], speeds) is None
    gain["delta_elpd_runs"] = [0]
    assert gain_figure(payload["causes"], speeds) is None


def test_report_shows_the_speed_dependence_of_a_tracking_tone():
    ranking = diagnose_case(make_case("rail_waviness", 1))
    assert ranking.verdict == "rail_waviness"
    page = diagnosis_page(
        as_diagnosis(ranking).to_json(), features=ranking.features, catalogue=DOOR_CATALOGUE
    )
    assert "a tone from a spatial period tracks the speed" in page


# ------------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def rig_file(tmp_path_factory):
    """Six healthy rig runs at spread speeds with a hidden mains hum (seed 0)."""
    import jax

    from bayesdoor.door.rig import Effects, MainsHum, VirtualRig

    rig = VirtualRig(effects=Effects(mains_hum=MainsHum.from_seed(0)))
    campaign = rig.record(["healthy"] * 6, np.linspace(0.25, 0.5, 6), key=jax.random.key(0))
    path = tmp_path_factory.mktemp("rig") / "rig.nc"
    save_campaign(campaign, path)
    return path


@pytest.mark.slow
def test_diagnose_quick_end_to_end_on_rig_runs(rig_file, tmp_path):
    out = tmp_path / "diag"
    result = invoke("diagnose", rig_file, "--out", out, "--quick", "--json")
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    names = {c.name for c in DOOR_CATALOGUE.candidates}
    assert payload["verdict"] in names
    assert [c["name"] for c in payload["causes"]] and set(
        c["name"] for c in payload["causes"]
    ) <= names
    assert "fit" in payload["timings"]  # no --model: fitted here
    page = (out / "diagnosis.html").read_text()
    assert len(images(page)) >= 1 and "Where the model is wrong" in page


@pytest.mark.slow
def test_diagnose_reuses_the_fit_of_bayesdoor_fit(rig_file, tmp_path):
    fitted = invoke(
        "fit", rig_file, "--method", "cmaes", "--quick", "--out", tmp_path / "fit", "--json"
    )
    assert fitted.exit_code == 0, fitted.output
    out = tmp_path / "diag"
    result = invoke(
        "diagnose", rig_file, "--model", tmp_path / "fit", "--out", out, "--quick", "--json"
    )
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert "fit" not in payload["timings"]  # the fit was reused, not redone
    assert payload["posterior"] == str(tmp_path / "fit")
    page = (out / "diagnosis.html").read_text()
    assert "Base model" in page and "cmaes" in page


def test_parameter_text_reads_every_summary_the_reports_meet():
    from bayesdoor.report import parameter_text

    # a refitted parameter, a CMA-ES point keyed as fit --json keys it, a job's table row
    assert parameter_text({"mean": 0.1, "sd": 0.01, "q5": 0.084, "q95": 0.116}) == (
        "0.1 ± 0.01 [0.084, 0.116]"
    )
    assert (
        parameter_text({"point": 1.5, "mean": None, "sd": None, "q5": None, "q95": None}) == "1.5"
    )
    row = {
        "parameter": "K",
        "point": 1800.0,
        "mean": 1850.0,
        "sd": 20.0,
        "q05": 1820.0,
        "q95": 1880.0,
    }
    assert parameter_text(row) == "1850 ± 20 [1820, 1880]"
    # a diagnosis refit's parameter with each held-out fold's own value
    refit = {"mean": 42.5, "sd": None, "folds": [42.1, 42.9]}
    assert parameter_text(refit) == "42.5 (held-out folds: 42.1, 42.9)"
    # ... and one whose fit stopped at an end of its search box says so
    pushed = {"mean": 0.3, "sd": None, "search_box": [0.01, 0.3], "at_bound": "upper"}
    assert parameter_text(pushed) == (
        "0.3, at the upper end of its search box [0.01, 0.3]: not an estimate"
    )
    assert parameter_text({**pushed, "at_bound": None}) == "0.3"
    assert parameter_text(row) == "1850 ± 20 [1820, 1880]"
    assert parameter_text(3) == "3" and parameter_text("A1X") == "A1X"
    assert parameter_text(float("nan")) == "-" and parameter_text([1.0, 2.5]) == "1, 2.5"
