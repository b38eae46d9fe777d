"""Every command's ``--json`` against docs/cli.md: the keys users read.

``SCHEMA`` writes the design's "JSON (at least)" column as the keys each payload must hold.
The payloads come from the commands themselves through typer's runner, with the heavy work
replaced where it is not the point: ``fit`` returns a real ``FitResult`` holding a made-up
posterior (its JSON, files and figures are the real ones), ``run`` and ``demo`` train on the
tone system of ``test_robustness`` with a stand-in fit, and the diagnosis is a real
``Diagnosis`` built from the signature ranking of a synthetic frame mode (``test_diagnose``).
``simulate`` and ``inspect`` run as they are.
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import arviz as az
import numpy as np
import pytest
from test_diagnose import diagnose_case, make_case
from test_robustness import CHANNELS, campaign, door_fit, fast, invoke

import bayesdoor.diagnose
import bayesdoor.door.datasets
import bayesdoor.inference
from bayesdoor.diagnose import RULE, Cause, Diagnosis, Gain
from bayesdoor.door import DOOR_CATALOGUE, DoorParameters, ElevatorDoor
from bayesdoor.inference import (
    CMAESHistory,
    CMAESResult,
    FeatureSpec,
    FitResult,
    FitSettings,
    ModelError,
    diagnose_sampling,
)
from bayesdoor.io import load_campaign, save_campaign

#: the system and operating condition that `bayesdoor simulate` needs
DOOR = ("--system", "elevator_door", "--condition", "v_max=0.4")

ANY = None


def keys(*names: str) -> dict:
    """Keys whose values may be anything."""
    return dict.fromkeys(names, ANY)


class Each(dict):
    """Keys every value of an object (or every item of a list) must hold; not empty."""


class OneOf(tuple):
    """At least one of these keys (the design's "point value or mean")."""


FIT = {
    "parameters": Each({OneOf(("point", "mean")): ANY, **keys("sd", "q5", "q95")}),
    "diagnostics": keys("rhat_max", "ess_bulk_min", "divergences"),
    "j": ANY,
}
CLASSIFY = {
    "classes": ANY,
    "healthy_state": ANY,
    "runs": Each(
        {
            "probabilities": keys("healthy", "D1", "D2"),
            **keys("predicted", "entropy", "mutual_information", "ood"),
        }
    ),
    "metrics": keys("accuracy", "ece", "nll", "brier", "confusion"),
}
DIAGNOSE = {"verdict": ANY, "causes": Each(keys("name", "evidence", "parameters", "gain"))}
#: the keys docs/cli.md documents for each command; ``run`` holds the union of the fit, the
#: classification and the diagnosis: the classification's keys at the top, the fit's under
#: ``fit`` and the diagnosis's under ``diagnosis``
SCHEMA = {
    "simulate": keys("file", "runs", "channels"),
    "inspect": keys("runs", "channels", "sampling_rate_hz", "states", "problems"),
    "fit": FIT,
    "classify": CLASSIFY,
    "diagnose": DIAGNOSE,
    "run": {**CLASSIFY, "fit": FIT, "diagnosis": DIAGNOSE},
    "demo": {**CLASSIFY, "fit": FIT, "diagnosis": DIAGNOSE},
}


def missing(payload, schema, where="") -> list[str]:
    """Where ``payload`` lacks a key of ``schema`` (a ``null`` counts as missing when the
    schema says what the value must hold)."""
    if isinstance(schema, Each):
        if not isinstance(payload, dict | list) or not payload:
            return [f"{where}: no entries"]
        items = payload.items() if isinstance(payload, dict) else enumerate(payload)
        return [m for k, v in items for m in missing(v, dict(schema), f"{where}[{k}]")]
    if not isinstance(payload, dict):
        return [f"{where}: not an object"]
    found = []
    for key, inner in schema.items():
        if isinstance(key, OneOf):
            if not any(k in payload for k in key):
                found.append(f"{where}.{'|'.join(key)}")
        elif key not in payload:
            found.append(f"{where}.{key}")
        elif inner is not None:
            if payload[key] is None:
                found.append(f"{where}.{key}: null")
            else:
                found += missing(payload[key], inner, f"{where}.{key}")
    return found


def test_the_checker_names_what_is_missing():
    good = {"parameters": {"K": {"mean": 1.0, "sd": 0.1, "q5": 0.9, "q95": 1.1}}, "j": 0.3}
    good["diagnostics"] = {"rhat_max": 1.0, "ess_bulk_min": 800.0, "divergences": 0}
    assert missing(good, FIT) == []
    bad = json.loads(json.dumps(good))
    del bad["parameters"]["K"]["mean"], bad["j"]
    bad["diagnostics"] = None
    assert missing(bad, FIT) == [".parameters[K].point|mean", ".diagnostics: null", ".j"]
    assert missing({**good, "parameters": {}}, FIT) == [".parameters: no entries"]
    assert missing({"verdict": "none", "causes": [{"name": "x"}]}, DIAGNOSE) == [
        ".causes[0].evidence",
        ".causes[0].parameters",
        ".causes[0].gain",
    ]


def posterior(names, rng) -> az.InferenceData:
    """A made-up NUTS posterior with every group a saved posterior needs (2 chains x 200)."""
    shape = (2, 200)
    return az.from_dict(
        posterior={
            **{n: 1.0 + 0.01 * rng.standard_normal(shape) for n in names},
            "sigma_model": 0.1 + 0.01 * rng.random((*shape, len(CHANNELS))),
        },
        sample_stats={
            "diverging": np.zeros(shape, dtype=bool),
            "energy": rng.standard_normal(shape),
            "lp": rng.standard_normal(shape),
        },
        observed_data={"y": np.zeros((2, 4, 5))},
        log_likelihood={"y": rng.standard_normal((*shape, 2))},
    )


DIAGNOSTICS = diagnose_sampling(
    posterior(["K"], np.random.default_rng(1)), var_names=["K"], warn=False
)


def made_up_fit(system, data, **options) -> FitResult:
    """What ``fit_campaign`` returns, holding a made-up posterior."""
    rng = np.random.default_rng(0)
    point = {k: float(v) for k, v in DoorParameters.paper_optimum().to_dict().items()}
    names = tuple(p.name for p in system.parameters if not p.integer)
    idata = posterior(names, rng)
    history = CMAESHistory(*(np.arange(1.0, 4.0) for _ in range(7)))
    return FitResult(
        method="nuts",
        held={"I": point["I"]},
        point=point,
        j=0.25,
        idata=idata,
        diagnostics=diagnose_sampling(idata, var_names=list(names), warn=False),
        cmaes=CMAESResult(
            np.array([point[n] for n in names]), 0.25, 300, 0, 0, ("tolfun",), history, 0
        ),
        feature_spec=FeatureSpec(),
        settings=FitSettings.quick(),
        names=names,
        sigma_point=np.full(len(CHANNELS), 0.1),
        scatter_point=np.ones(len(CHANNELS)),
        model_error=ModelError(),
        bounds=(np.zeros(len(names)), np.full(len(names), 10.0)),
        surrogate_box=None,
        surrogate_rms=None,
        runs=np.arange(3),
        duration=1.5,
        notes=(),
        timings={},
        seed=options["seed"],
    )


def made_up_predictive(result, system, data, runs=None, *, key, n_draws):
    """What ``posterior_predictive`` returns: replicates around the measured features."""
    rng = np.random.default_rng(1)
    y = rng.standard_normal((2, len(CHANNELS), 5))
    replicates = y + 0.1 * rng.standard_normal((n_draws, *y.shape))
    operating = np.array([0.3, 0.5])
    features = SimpleNamespace(
        y=y, run_operating=np.array([0, 1]), operating=operating, band_centres=np.arange(5.0)
    )
    return replicates, features, np.ones(n_draws, dtype=bool)


@pytest.fixture(scope="module")
def diagnosis() -> Diagnosis:
    """A real diagnosis of a synthetic frame mode, confirmed by a made-up refit's gain."""
    ranking = diagnose_case(make_case("frame_mode", 0))
    gain = Gain(0.4, 0.3, -120.0, -80.0, 40.0, 5.0, 6, True)
    causes = tuple(
        Cause(
            c.name,
            c.description,
            c.score,
            c.evidence,
            dict(c.parameters),
            gain=gain if c.name == ranking.verdict else None,
            confirmed=c.name == ranking.verdict,
            feature=c.feature,
        )
        for c in ranking.causes
    )
    return Diagnosis(
        verdict=ranking.verdict or "none",
        causes=causes,
        ranking=ranking,
        catalogue=DOOR_CATALOGUE,
        rule=RULE,
        runs=np.arange(3),
    )


@pytest.fixture(scope="module")
def campaign_file(tmp_path_factory):
    return save_campaign(campaign(), tmp_path_factory.mktemp("contract") / "campaign.nc")


def _patched(mp, campaign_file, diagnosis):
    """The stand-ins of the payloads' commands (the module docstring says which)."""

    def diagnose(*args, **options):
        return diagnosis

    def fit_with_diagnostics(*args, **options):
        fit = door_fit(*args, **options)
        fit.diagnostics = DIAGNOSTICS
        return fit

    mp.setattr(bayesdoor.inference, "fit_campaign", made_up_fit)
    mp.setattr(bayesdoor.inference, "posterior_predictive", made_up_predictive)
    mp.setattr(bayesdoor.diagnose, "diagnose_campaign", diagnose)
    mp.setattr(
        bayesdoor.door.datasets._demo,
        "load_demo_campaign",
        lambda **kw: load_campaign(campaign_file),
    )
    fast(mp, fit=fit_with_diagnostics, diagnose=diagnose)


def _payload(found, name, *args):
    result = invoke(*args, "--json")
    assert result.exit_code == 0, result.output
    found[name] = json.loads(result.stdout)  # the JSON alone on stdout


@pytest.fixture(scope="module")
def quick_payloads(campaign_file, diagnosis, tmp_path_factory):
    """The ``--json`` of the commands that take seconds, by name."""
    folder = tmp_path_factory.mktemp("outputs")
    found = {}
    with pytest.MonkeyPatch.context() as mp:
        _patched(mp, campaign_file, diagnosis)
        _payload(found, "inspect", "inspect", campaign_file)
        _payload(found, "fit", "fit", campaign_file, "--out", folder / "fit", "--method", "nuts")
        _payload(found, "diagnose", "diagnose", campaign_file, "--out", folder / "diag", "--quick")
    return found


@pytest.fixture(scope="module")
def payloads(quick_payloads, campaign_file, diagnosis, tmp_path_factory):
    """The ``--json`` of every command, by name: ``quick_payloads`` and those of the door's
    simulation and the job (its training data and ensemble), which take tens of seconds."""
    folder = tmp_path_factory.mktemp("outputs")
    found = dict(quick_payloads)
    with pytest.MonkeyPatch.context() as mp:
        _patched(mp, campaign_file, diagnosis)
        job = folder / "job"
        _payload(found, "simulate", "simulate", "--out", folder / "sim.nc", "--state", "D1", *DOOR)
        _payload(found, "run", "run", campaign_file, "--out", job, "--quick")
        # the same job on the same campaign: every stage is reused
        _payload(found, "demo", "demo", "--out", job, "--quick")
        _payload(
            found, "classify", "classify", campaign_file, "--model", job, "--out", folder / "cls"
        )
    return found


#: the commands whose payloads take tens of seconds (the door's simulation, the job; all seven
#: payloads took 40-207 s with an empty JAX cache): in the long tier, which CI runs after the
#: default suite, with the test that reads every payload. The default suite checks the JSON of
#: ``simulate`` in tests/test_cli.py and of ``classify`` in tests/test_cli_run.py
_SLOW_PAYLOADS = ("simulate", "run", "demo", "classify")


@pytest.mark.parametrize(
    "command",
    [pytest.param(c, marks=pytest.mark.long) if c in _SLOW_PAYLOADS else c for c in SCHEMA],
)
def test_json_holds_the_design_keys(request, command):
    fixture = "payloads" if command in _SLOW_PAYLOADS else "quick_payloads"
    assert missing(request.getfixturevalue(fixture)[command], SCHEMA[command]) == []


@pytest.mark.long
def test_the_payloads_describe_what_was_done(payloads, campaign_file):
    """Spot checks that the keys hold the values they name."""
    assert payloads["simulate"]["runs"] == 1 and payloads["simulate"]["channels"] == list(CHANNELS)
    assert payloads["inspect"]["runs"] == 12 and payloads["inspect"]["problems"] == []
    fit = payloads["fit"]
    names = {p.name for p in ElevatorDoor().parameters}
    assert set(fit["parameters"]) == names
    # the contact-law index is fixed, not sampled: a point, no interval
    law = float(DoorParameters.paper_optimum().to_dict()["I"])
    assert fit["parameters"]["I"]["point"] == law and fit["parameters"]["I"]["q5"] is None
    assert fit["held"] == {"I": law} and "law" not in fit
    assert fit["parameters"]["K"]["q5"] < fit["parameters"]["K"]["mean"]
    assert fit["diagnostics"]["divergences"] == 0
    run = payloads["run"]
    assert [s["reused"] for s in payloads["demo"]["stages"]] == [True] * len(run["stages"])
    assert run["fit"]["diagnostics"] == DIAGNOSTICS.to_json()
    # the run's fit block is keyed as the fit command keys its own
    assert set(run["fit"]["parameters"]["k"]) >= {"point", "mean", "sd", "q5", "q95"}
    assert run["metrics"] == payloads["demo"]["metrics"]
    assert len(payloads["classify"]["runs"]) == 12  # every run, splits ignored
    assert payloads["diagnose"]["verdict"] == run["diagnosis"]["verdict"] != "none"
