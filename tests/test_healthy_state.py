"""A system whose undamaged state is not called ``healthy`` goes through the generic layers.

The tone system of ``_toy_system`` with its states renamed ``ok``, ``crack`` and ``loose``
and ``healthy = "ok"``: its ``simulate_values`` keeps the default ``state="healthy"``, which
it refuses, so a generic layer that simulates without naming the system's healthy state
fails here. It is taken through the whole job (a stand-in fit keeps it to seconds; the fit's
simulations are checked on their own), the trust checks, the signature evidence, the
report's palette, the training data's description and the command line.
"""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest
from _toy_system import CENTER, DURATION, FS, REST, ToySystem
from test_pipeline import StandInFit
from typer.testing import CliRunner

from bayesdoor.classify import TrainConfig
from bayesdoor.cli import app
from bayesdoor.datagen import describe_system
from bayesdoor.diagnose import HeldExtension
from bayesdoor.inference import FeatureSpec, SimulatorForward, calibration_runs, campaign_data
from bayesdoor.inference._population import _Population
from bayesdoor.io import load_campaign, make_campaign
from bayesdoor.pipeline import JobConfig, Sizes, run_job
from bayesdoor.pipeline._classify import _with_evidence
from bayesdoor.pipeline._trust import judge_trust
from bayesdoor.report import HEALTHY_COLOR, UNKNOWN_COLOR, state_colors
from bayesdoor.systems import HEALTHY, DamageSpec, register_system


class RenamedToy(ToySystem):
    """The tone system with states ``ok``, ``crack`` (its 48 Hz tone) and ``loose`` (80 Hz)."""

    @property
    def states(self):
        tones = super().states
        return {
            "ok": DamageSpec("ok", "no fault"),
            "crack": DamageSpec("crack", tones["D1"].description, tones["D1"].severity),
            "loose": DamageSpec("loose", tones["D2"].description, tones["D2"].severity),
        }

    @property
    def healthy(self) -> str:
        return "ok"


SYSTEM = RenamedToy(label="ok_tones", d2_phase=False)
# found by name, as the stages and commands that get no system object find it
register_system("ok_tones", lambda: SYSTEM)
STATES = ("ok", "crack", "loose")


def ok_campaign(*, calibration=4, per_state=3, seed=0):
    """Measured-like runs: ``calibration`` ok runs, then ``per_state`` test runs per state."""
    rng = np.random.default_rng(seed)
    states = ["ok"] * calibration + list(STATES) * per_state
    speeds = np.resize([0.3, 0.5], len(states))
    signals = []
    for state, v in zip(states, speeds, strict=True):
        values = {"k": 0.5 + 0.02 * rng.standard_normal(), "m": 1.0, "law": 2.0}
        sev = {n: rng.uniform(lo, hi) for n, (lo, hi) in SYSTEM.states[state].severity.items()}
        res = SYSTEM.simulate_values(values, v, state=state, severity=sev)
        signals.append(np.asarray(res.signals[0]))
    return make_campaign(
        np.stack(signals),
        channels=["X", "Z"],
        fs=FS,
        state=states,
        v_max=speeds,
        t_start=np.full(len(states), REST),
        t_stop=np.full(len(states), DURATION),
        system="ok_tones",
        split=["calibration"] * calibration + ["test"] * (len(states) - calibration),
    )


def test_the_toy_refuses_a_simulation_that_does_not_name_its_state():
    """What makes the tests below bite: the default ``healthy`` is not one of its states."""
    with pytest.raises(ValueError, match="unknown state 'healthy'"):
        SYSTEM.simulate_values(CENTER, 0.3)


def test_a_system_whose_healthy_state_is_not_one_of_its_states_is_refused():
    class Misnamed(ToySystem):
        healthy = "ok"

    with pytest.raises(ValueError, match=r"healthy state 'ok' is not one of its states"):
        Misnamed()
    assert ToySystem().healthy == HEALTHY == "healthy"


def test_the_fit_and_the_extensions_simulate_the_systems_healthy_state():
    forward = SimulatorForward.build(SYSTEM, ("k", "m"), {"law": 2.0}, [0.3, 0.5])
    out = forward(jnp.asarray([0.5, 1.0]))
    assert bool(out.ok) and out.features.shape[0] == 2
    # the CMA-ES population's simulations, on the ok calibration runs
    campaign = ok_campaign()
    data, duration = campaign_data(SYSTEM, campaign, calibration_runs(campaign, "ok"))
    population = _Population.build(SYSTEM, data, duration, FeatureSpec.of(SYSTEM))
    features, ok = population(jnp.asarray([[0.5, 1.0, 2.0], [0.4, 1.2, 1.0]]))
    assert np.asarray(ok).tolist() == [True, True] and np.all(np.isfinite(features))
    zero, slope = SYSTEM.simulate_gains(CENTER, jnp.asarray([0.3, 0.5]), ("m",))
    assert np.all(np.asarray(zero.status) == 0) and np.any(np.asarray(slope) != 0)
    held = HeldExtension(SYSTEM, (("law", 2.0),))
    assert held.healthy == "ok"
    assert np.asarray(held.simulate_values({"k": 0.5, "m": 1.0}, 0.3).status).tolist() == [0]


def test_calibration_runs_are_the_systems_healthy_ones():
    campaign = ok_campaign()
    assert calibration_runs(campaign, "ok").tolist() == [0, 1, 2, 3]
    with pytest.raises(ValueError, match=r"no healthy run .* state='healthy'"):
        calibration_runs(campaign)


def test_the_description_names_the_healthy_state_only_where_it_is_not_the_default():
    assert describe_system(SYSTEM)["healthy_state"] == "ok"
    assert "healthy_state" not in describe_system(ToySystem())


def test_the_palette_gives_the_healthy_state_its_colour_wherever_it_stands():
    colors = state_colors(["crack", "ok", "loose", "unknown"], "ok")
    assert colors["ok"] == HEALTHY_COLOR and colors["unknown"] == UNKNOWN_COLOR
    assert colors == state_colors(["crack", "ok", "loose", "unknown", "crack"], "ok")
    others = [colors["crack"], colors["loose"]]
    assert len(set(others)) == 2 and HEALTHY_COLOR not in others and UNKNOWN_COLOR not in others
    # a system whose healthy state is called as another's damage: the name alone decides
    assert state_colors(["healthy", "ok"], "ok")["healthy"] == colors["crack"]
    assert len(set(state_colors([f"s{i}" for i in range(20)], "s0").values())) == 9


def test_the_signature_evidence_weighs_against_the_systems_healthy_state():
    classes = list(STATES)
    probabilities = np.tile([0.2, 0.6, 0.2], (8, 1))
    # the check finds no damage signature on any run
    agreement = [{"ok": True, "crack": False, "loose": False}] * 8
    ok = np.ones(8, dtype=bool)
    weighed, applies, summary = _with_evidence(probabilities, agreement, 0.05, classes, "ok", ok)
    assert summary is not None and summary["checked_runs"] == 8
    assert np.all(np.isfinite(applies)) and weighed.shape == probabilities.shape
    same, _, none = _with_evidence(probabilities, agreement, 0.05, classes, "healthy", ok)
    assert none is None and np.array_equal(same, probabilities)


def _training():
    labels = [0] * 20 + [1] * 20 + [2] * 20
    probs = [[0.98, 0.01, 0.01]] * 20 + [[0.01, 0.98, 0.01]] * 20 + [[0.01, 0.01, 0.98]] * 20
    return {
        "states": list(STATES),
        "healthy_state": "ok",
        "ood_quantile": 0.99,
        "validation": {"labels": labels, "probabilities": probs},
    }


def _runs(called):
    return {"runs": [{"run": i, "predicted": p, "ood": False} for i, p in enumerate(called)]}


def test_trust_judges_the_known_runs_by_the_healthy_state_of_the_training():
    adequacy = {"verdict": "reproduces", "summary": "fine"}
    test = _runs(["crack"] * 10)
    missed = judge_trust(adequacy, _runs(["crack"] * 9 + ["ok"]), test, _training(), [])
    assert missed["verdict"] == "not trusted"
    assert missed["checks"]["known_runs"]["state"] == "ok"
    assert "1 of 10 measured ok calibration runs were called ok" in missed["reasons"][0]
    known = judge_trust(adequacy, _runs(["ok"] * 10), _runs(["ok"] * 10), _training(), [4])
    assert known["verdict"] == "trusted", known
    assert known["checks"]["unlike_healthy"]["called_healthy"] == 10


def stand_in_fit(system, campaign, *, method, seed, quick, progress):
    assert set(np.asarray(campaign["state"].values)) == {"ok"}
    return StandInFit(seed)


# the quick job's few validation runs are classified perfectly, so the temperature's fit ends at
# its bound, which the job says in a warning that is not this test's business
@pytest.mark.filterwarnings("ignore:the NLL-optimal temperature lies at the bound:UserWarning")
def test_the_job_runs_on_a_system_whose_healthy_state_is_ok(tmp_path):
    sizes = Sizes(
        runs_per_state=12,
        chunk_size=12,
        validation_fraction=0.5,
        train=TrainConfig(members=2, epochs=20, batch_size=12, learning_rate=1e-2),
    )
    result = run_job(
        SYSTEM,
        ok_campaign(),
        tmp_path,
        JobConfig(seed=0, sizes=sizes, diagnosis=False),
        fit=stand_in_fit,
        progress=False,
        report=lambda line: None,
    )
    classification = result.classification
    assert classification["classes"] == list(STATES)
    assert classification["healthy_state"] == "ok"
    assert classification["metrics"]["runs"] == 9
    training = json.loads((tmp_path / "train" / "training.json").read_text())
    assert training["healthy_state"] == "ok"
    manifest = json.loads((tmp_path / "generate" / "data" / "manifest.json").read_text())
    assert manifest["system"]["healthy_state"] == "ok"
    # the ok calibration runs were found: the fit's adequacy and the known runs were checked
    assert result.adequacy["verdict"] is not None, result.adequacy
    assert result.trust["checks"]["known_runs"]["state"] == "ok"
    assert result.trust["checks"]["known_runs"]["runs"] == 4
    page = (tmp_path / "report" / "index.html").read_text()
    assert f'style="background:{HEALTHY_COLOR}">ok</span>' in page


def test_simulate_on_the_command_line_simulates_the_healthy_state(tmp_path):
    out = tmp_path / "one.nc"
    args = ["simulate", "--system", "ok_tones", "--condition", "v_max=0.4", "--out", str(out)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    # the toy's motion window reaches its record's end, which the format's check refuses
    assert load_campaign(out, check=False)["state"].values.tolist() == ["ok"]
