"""From a diagnosis to the extended system, provenance of extended fits, and the gain script.

The diagnoses here are stand-ins: real signature rankings of synthetic cases
(``test_diagnose.make_case``) with a refit's outcome made up (its configuration and values),
so the tests check the hand-over from a verdict to a system, not the diagnosis itself.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_diagnose import diagnose_case, make_case

from bayesdoor.diagnose import (
    RULE,
    Cause,
    Diagnosis,
    Gain,
    HeldExtension,
    extend_system,
    verdict_extension,
)
from bayesdoor.door import DOOR_CATALOGUE, DoorParameters, ElevatorDoor, FrameMode, SensorCrossAxis

ROOT = Path(__file__).resolve().parent.parent
GAIN = Gain(0.4, 0.3, -120.0, -80.0, 40.0, 5.0, 6, True)


def stand_in(
    effect: str, seed: int, *, label: str | None, values: dict, index: int = 0
) -> Diagnosis:
    """The signature ranking of a synthetic case with ``effect``, its verdict confirmed by a
    made-up refit of configuration ``label`` (``None``: the recipe's proposal ``index``)."""
    ranking = diagnose_case(make_case(effect, seed))
    verdict = ranking.verdict
    causes = []
    for c in ranking.causes:
        if c.name == verdict and verdict != "none":
            recipe = {k.name: k.refit for k in DOOR_CATALOGUE.candidates}[c.name]
            chosen = label or recipe.propose(c.parameters, band=(2.0, 400.0))[index].label
            fitted = {n: {"mean": v, "sd": 0.1 * abs(v)} for n, v in values.items()}
            causes.append(
                Cause(
                    c.name,
                    c.description,
                    c.score,
                    c.evidence,
                    {**dict(c.parameters), **fitted},
                    gain=GAIN,
                    confirmed=True,
                    feature=c.feature,
                    label=chosen,
                )
            )
        else:
            causes.append(Cause(c.name, c.description, c.score, c.evidence, dict(c.parameters)))
    return Diagnosis(
        verdict=verdict,
        causes=tuple(causes),
        ranking=ranking,
        catalogue=DOOR_CATALOGUE,
        rule=RULE,
        runs=np.arange(6),
    )


@pytest.fixture(scope="module")
def base_run():
    """One short base-door run at the paper's optimum (values, speed, signals)."""
    door = ElevatorDoor()
    values = DoorParameters.paper_optimum().to_dict()
    result = door.simulate_values(values, np.array([0.4]), duration=1.0)
    assert int(result.status[0]) == 0
    return values, np.asarray(result.signals[0])


def test_none_verdict_leaves_the_system_unchanged():
    diagnosis = stand_in("none", 0, label=None, values={})
    assert diagnosis.verdict == "none"
    door = ElevatorDoor()
    assert extend_system(door, diagnosis) is door
    assert verdict_extension(door, diagnosis) is None


def test_cross_axis_verdict_switches_on_the_refit_direction_at_its_fraction(base_run):
    # the refit chose a direction the signature did not name (every direction is tried):
    # the extended system must take the refit's, not the signature's
    diagnosis = stand_in(
        "sensor_cross_axis", 1, label="A2Z reads A2X", values={"sensor_cross_axis.fraction": 0.12}
    )
    assert diagnosis.verdict == "sensor_cross_axis"
    door = ElevatorDoor()
    found = verdict_extension(door, diagnosis)
    assert found is not None
    assert found.proposal.extension == SensorCrossAxis(sensor="A2", into="Z")
    assert found.values == {"sensor_cross_axis.fraction": 0.12}

    held = extend_system(door, diagnosis)
    assert isinstance(held, HeldExtension)
    assert held.parameter_names() == door.parameter_names()
    assert held.extension_names == ("sensor_cross_axis",)
    assert held.describe()["held"] == {"sensor_cross_axis.fraction": 0.12}
    values, base = base_run
    signals = np.asarray(held.simulate_values(values, np.array([0.4]), duration=1.0).signals[0])
    # independent reference: A2Z reads itself plus 0.12 A2X; the other channels are unchanged
    expected = base.copy()
    expected[3] += 0.12 * base[2]
    np.testing.assert_allclose(signals, expected, rtol=0, atol=1e-12 * np.abs(base).max())

    free = extend_system(door, diagnosis, hold=False)
    assert free.parameter_names() == (*door.parameter_names(), "sensor_cross_axis.fraction")


def test_frame_mode_verdict_holds_every_parameter_of_the_mode(base_run):
    fitted = {
        "frame_mode.frequency_hz": 61.0,
        "frame_mode.damping_ratio": 0.03,
        "frame_mode.participation_A1X": 0.0,
        "frame_mode.participation_A1Z": 0.05,
        "frame_mode.participation_A2X": 0.0,
        "frame_mode.participation_A2Z": -0.04,
    }
    # the recipe's second proposal, the output mode (its first carries the rail)
    diagnosis = stand_in("frame_mode", 0, label=None, values=fitted, index=1)
    assert diagnosis.verdict == "frame_mode"
    door = ElevatorDoor()
    held = extend_system(door, diagnosis)
    assert held.describe()["held"] == fitted
    assert held.parameter_names() == door.parameter_names()
    values, base = base_run
    got = np.asarray(held.simulate_values(values, np.array([0.4]), duration=1.0).signals[0])
    reference = ElevatorDoor(extensions=(FrameMode(),)).simulate_values(
        {**values, **fitted}, np.array([0.4]), duration=1.0
    )
    np.testing.assert_array_equal(got, np.asarray(reference.signals[0]))
    # the mode shows on the channels it participates in, only there
    changed = np.abs(got - base).max(axis=-1) > 1e-3 * np.abs(base).max(axis=-1)
    assert changed.tolist() == [False, True, False, True]
    with pytest.raises(ValueError, match="held parameters"):
        held.simulate_values({**values, "frame_mode.frequency_hz": 50.0}, np.array([0.4]))


def test_a_configuration_the_recipe_does_not_propose_is_refused():
    diagnosis = stand_in("frame_mode", 0, label="a mode near 999.0 Hz", values={})
    with pytest.raises(ValueError, match=r"a mode near 999\.0 Hz"):
        extend_system(ElevatorDoor(), diagnosis)


def test_held_values_out_of_bounds_are_refused():
    door = ElevatorDoor().with_extensions("sensor_cross_axis")
    with pytest.raises(ValueError, match=r"sensor_cross_axis\.fraction"):
        HeldExtension(door, (("sensor_cross_axis.fraction", 0.9),))
    with pytest.raises(ValueError, match="not parameters"):
        HeldExtension(door, (("frame_mode.frequency_hz", 50.0),))


def test_extended_systems_have_another_description_and_job_hash():
    from bayesdoor.datagen import describe_system

    door = ElevatorDoor()
    extended = door.with_extensions("sensor_cross_axis")
    held = HeldExtension(extended, (("sensor_cross_axis.fraction", 0.1),))
    other = dataclasses.replace(held, held=(("sensor_cross_axis.fraction", 0.2),))
    descriptions = [json.dumps(describe_system(s), sort_keys=True) for s in (door, extended, held)]
    descriptions.append(json.dumps(describe_system(other), sort_keys=True))
    assert len(set(descriptions)) == 4


@pytest.mark.slow
def test_gain_script_runs_one_tiny_case(tmp_path):
    out = tmp_path / "gain.md"
    subprocess.run(
        [
            sys.executable,
            str(ROOT / "scripts" / "diagnosis_gain.py"),
            "--quick",
            "--effects",
            "sensor_cross_axis",
            "--seeds",
            "0",
            "--work",
            str(tmp_path / "work"),
            "--out",
            str(out),
        ],
        check=True,
        cwd=ROOT,
        timeout=7200,
    )
    text = out.read_text()
    assert "sensor_cross_axis" in text
    rows = json.loads((tmp_path / "work" / "cases.json").read_text())
    assert len(rows) == 1
    row = rows[0]
    for key in ("verdict", "base", "extended"):
        assert key in row
    assert 0.0 <= row["base"]["accuracy"] <= 1.0


# ---------------------------------------------------------------------------------------------
# provenance: an extended fit is never taken for a base one


@pytest.fixture(scope="module")
def base_fit():
    """A made-up fit of the base door (``test_json_contract``) that records its system."""
    from test_json_contract import made_up_fit

    door = ElevatorDoor()
    fit = made_up_fit(door, None, seed=0)
    return dataclasses.replace(fit, system=door.describe())


def test_a_fit_records_its_system_and_refuses_another(base_fit, tmp_path):
    from bayesdoor.inference import FitResult, load_posterior, posterior_system, record_system

    door = ElevatorDoor()
    record_system(base_fit.idata, door.describe())
    base_fit.save(tmp_path / "fit")
    loaded = FitResult.load(tmp_path / "fit")
    assert loaded.system == json.loads(json.dumps(door.describe()))
    assert posterior_system(load_posterior(tmp_path / "fit" / "posterior.nc")) == loaded.system
    loaded.check_system(door)
    extended = door.with_extensions(SensorCrossAxis(sensor="A2", into="Z"))
    with pytest.raises(ValueError, match=r"without extensions, not with extensions \[sensor_cro"):
        loaded.check_system(extended)
    held = HeldExtension(extended, (("sensor_cross_axis.fraction", 0.1),))
    with pytest.raises(ValueError, match=r"held at \{'sensor_cross_axis.fraction': 0.1\}"):
        loaded.check_system(held)
    # the same held system, rebuilt, is accepted; a fit without a record is judged by names
    dataclasses.replace(loaded, system=held.describe()).check_system(
        HeldExtension(door.with_extensions(SensorCrossAxis(sensor="A2", into="Z")), held.held)
    )
    dataclasses.replace(loaded, system=None).check_system(held)
    with pytest.raises(ValueError, match="with the parameters"):
        dataclasses.replace(loaded, system=None).check_system(extended)


def test_diagnose_refuses_a_posterior_of_an_extended_door(base_fit, tmp_path, monkeypatch):
    from test_cli_diagnose import door_file
    from test_robustness import invoke, refused

    monkeypatch.setattr("bayesdoor.cli._diagnose.compute", lambda *a, **k: pytest.fail("ran"))
    campaign = door_file(tmp_path / "door.nc", ["healthy", "healthy", "D1"])
    extended = ElevatorDoor().with_extensions(SensorCrossAxis(sensor="A2", into="Z"))
    held = HeldExtension(extended, (("sensor_cross_axis.fraction", 0.1),))
    dataclasses.replace(base_fit, system=held.describe()).save(tmp_path / "fit")
    # the held fit has the base door's parameter names: only its description tells it apart
    result = invoke("diagnose", campaign, "--out", tmp_path / "d", "--model", tmp_path / "fit")
    refused(result, "--model", "held at {'sensor_cross_axis.fraction': 0.1}")
    assert not (tmp_path / "d" / "diagnosis.json").exists()


@pytest.mark.long
def test_run_refuses_a_job_folder_of_the_base_system_for_an_extended_one(tmp_path):
    from test_pipeline import SIZES, SYSTEM, stand_in_fit, tone_campaign

    from bayesdoor.pipeline import JobConfig, run_job

    campaign = tone_campaign()
    config = JobConfig(seed=0, sizes=SIZES, html=False)
    options = dict(fit=stand_in_fit, progress=False, report=lambda line: None)
    run_job(SYSTEM, campaign, tmp_path / "job", config, **options)
    held = HeldExtension(SYSTEM, (("m", 1.0),))
    with pytest.raises(FileExistsError, match="other settings"):
        run_job(held, campaign, tmp_path / "job", config, **options)


def test_a_held_extension_keeps_what_the_system_says_of_itself():
    """The bearing extended and held keeps its own features, training points, envelope check
    and catalogue (the base class's defaults would replace them: 4 Hz bands the bearing's
    sampling cannot resolve, no check, the campaign's points only)."""
    from bayesdoor.bearing import BearingSystem

    bearing = BearingSystem()
    extended = bearing.with_extensions("shaft_harmonics")
    held = HeldExtension(extended, tuple((p.name, 0.0) for p in extended.parameters[-3:]))
    assert held.features == bearing.features
    points = np.array([[1797.0, 0.0]])
    np.testing.assert_array_equal(held.training_points(points), bearing.training_points(points))
    assert held.catalogue is not None
    assert held.catalogue == bearing.catalogue
    rng = np.random.default_rng(0)
    signals = 0.1 * rng.standard_normal((4, 1, 12000))
    operating = np.tile([1797.0, 0.0], (4, 1))
    reference = held.signature_reference(signals, operating)
    assert reference == bearing.signature_reference(signals, operating)
    assert held.signatures(reference, signals, operating) == bearing.signatures(
        reference, signals, operating
    )
