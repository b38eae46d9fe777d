"""``bayesdoor plan``: the campaign that would name a cause of a given size (the planning
itself is tested in test_diagnose_limits.py; here the command's contract, with a stand-in)."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest
from test_cli_diagnose import door_file, fake_fit_folder, invoke, one_line_failure

from bayesdoor.diagnose import CampaignPlan
from bayesdoor.door import ElevatorDoor

PLAN = CampaignPlan(
    cause="wheel_eccentricity",
    size=15e-6,
    unit="m",
    configuration="typical: left wheel",
    power=0.8,
    conditions=(0.3, 0.35),
    runs_per_condition=10,
    probability=0.83,
    record_s=4.0,
    current=0.2,
)


@pytest.fixture
def calls(monkeypatch):
    seen = []

    def plan_campaign(system, campaign, cause, size, *, fit, configuration, settings):
        seen.append(
            SimpleNamespace(
                cause=cause,
                size=size,
                fit=fit,
                configuration=configuration,
                seed=settings.seed,
                machines=settings.machines,
            )
        )
        if cause == "nothing":
            raise ValueError("no cause 'nothing';\nthe catalogue holds [...]")
        return PLAN

    monkeypatch.setattr("bayesdoor.diagnose.plan_campaign", plan_campaign)
    return seen


@pytest.fixture
def posterior(tmp_path, monkeypatch):
    folder, fit = fake_fit_folder(tmp_path, monkeypatch, ElevatorDoor().nominal())
    return folder, fit


def test_the_plan_as_json(calls, posterior, tmp_path):
    campaign = door_file(tmp_path / "door.nc", ["healthy"] * 4)
    folder, fit = posterior
    result = invoke(
        "plan", campaign, "--cause", "wheel_eccentricity", "--size", "15e-6",
        "--model", folder, "--json",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert payload["runs"] == 20 and payload["runs_per_condition"] == 10
    assert payload["conditions"] == [0.3, 0.35] and payload["unit"] == "m"
    assert payload["file"] == str(campaign) and payload["ratio"] is None
    assert calls[0].size == pytest.approx(15e-6) and calls[0].fit is fit
    assert calls[0].machines == "family"


def test_the_machines_a_plan_holds_for(calls, posterior, tmp_path):
    campaign = door_file(tmp_path / "door.nc", ["healthy"] * 4)
    args = ["plan", campaign, "--cause", "wheel_eccentricity", "--size", "15e-6"]
    result = invoke(*args, "--model", posterior[0], "--machines", "model")
    assert result.exit_code == 0, result.output
    assert calls[-1].machines == "model"
    assert "if the machine transmits it as the model does" in result.stdout
    one_line_failure(invoke(*args, "--model", posterior[0], "--machines", "rig"), "machines='rig'")


def test_the_plan_in_words(calls, posterior, tmp_path):
    campaign = door_file(tmp_path / "door.nc", ["healthy"] * 4)
    result = invoke(
        "plan", campaign, "--cause", "wheel_eccentricity", "--size", "15e-6",
        "--model", posterior[0],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "10 runs at each of 2 conditions" in result.stdout and "20 runs" in result.stdout


def test_an_unknown_cause_is_refused_in_one_line(calls, posterior, tmp_path):
    campaign = door_file(tmp_path / "door.nc", ["healthy"] * 4)
    result = invoke("plan", campaign, "--cause", "nothing", "--size", "1", "--model", posterior[0])
    one_line_failure(result, "no cause 'nothing'")


def test_a_run_jobs_folder_gives_its_fit_and_posterior_is_the_same_option(
    calls, posterior, tmp_path
):
    """``--model`` takes the output folder of ``bayesdoor run`` (its fit under fit/result);
    ``--posterior`` is the option's former name."""
    campaign = door_file(tmp_path / "door.nc", ["healthy"] * 4)
    folder, fit = posterior
    job = tmp_path / "job"
    (job / "fit").mkdir(parents=True)
    folder.rename(job / "fit" / "result")
    for option, path in (("--model", job), ("--posterior", job / "fit" / "result")):
        result = invoke(
            "plan", campaign, "--cause", "wheel_eccentricity", "--size", "15e-6",
            option, path, "--json",
        )  # fmt: skip
        assert result.exit_code == 0, result.output
    assert [c.fit for c in calls] == [fit, fit]


@pytest.mark.parametrize("quick", [True, False])
def test_without_a_model_the_plan_fits_here_at_the_sizes_asked(calls, tmp_path, monkeypatch, quick):
    fits = []

    def fit_campaign(system, campaign, **kwargs):
        fits.append(kwargs)
        return SimpleNamespace(point=system.nominal())

    monkeypatch.setattr("bayesdoor.inference.fit_campaign", fit_campaign)
    campaign = door_file(tmp_path / "door.nc", ["healthy"] * 4)
    flags = ["--quick"] if quick else []
    result = invoke(
        "plan", campaign, "--cause", "wheel_eccentricity", "--size", "15e-6", "--json", *flags
    )
    assert result.exit_code == 0, result.output
    assert fits[0]["quick"] is quick and fits[0]["method"] == "cmaes"
