"""The generic layers with two operating conditions: an operating point is a row.

A small analytic system with the conditions ``speed`` and ``load`` (``operating`` of shape
``(run, 2)``) runs the fit, the training-data generation, the adequacy and model-error
helpers and the whole job. Its runs at one speed and two loads differ, so a layer that keyed
the runs by their first condition alone (or flattened the rows) would mix them.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bayesdoor.classify import TrainConfig
from bayesdoor.datagen import (
    GaussianScatter,
    GenerationConfig,
    calibration_residuals,
    campaign_features,
    fit_adequacy,
    generate,
    healthy_outliers,
    measurement_variance,
    with_measured_discrepancy,
)
from bayesdoor.inference import fit_campaign, posterior_predictive
from bayesdoor.io import make_campaign
from bayesdoor.io import operating as campaign_operating
from bayesdoor.pipeline import JobConfig, PredictiveBands, Sizes, run_job
from bayesdoor.systems import (
    AbstractSystem,
    ConditionSpec,
    DamageSpec,
    ParameterSpec,
    register_system,
)

FS = 2048.0
REST = 0.1
DURATION = 0.75
CENTER = {"k": 0.5, "m": 1.0}
#: the campaign's operating points: two loads at one speed, so the speed alone does not key a run
POINTS = np.array([[0.3, 0.0], [0.3, 2.0], [0.5, 1.0]])


class LoadToySystem(AbstractSystem):
    """A tone of frequency 20 + 40 k Hz and amplitude m v (1 + load / 2) during the motion
    (after ``REST`` s), plus 48 Hz (D1) or 80 Hz (D2); conditions ``speed`` and ``load``."""

    label: str = eqx.field(static=True, default="tones_load")

    @property
    def name(self):
        return self.label

    @property
    def parameters(self):
        return (
            ParameterSpec("k", "-", 0.5, 0.0, 1.0, "tone frequency"),
            ParameterSpec("m", "-", 1.0, 0.5, 2.0, "amplitude"),
        )

    @property
    def states(self):
        return {
            "healthy": DamageSpec("healthy", "none"),
            "D1": DamageSpec("D1", "a 48 Hz tone", {"a1": (0.5, 1.0)}),
            "D2": DamageSpec("D2", "an 80 Hz tone", {"a2": (0.3, 0.6)}),
        }

    @property
    def channels(self):
        return ("X", "Z")

    @property
    def sampling_rate_hz(self):
        return FS

    @property
    def conditions(self):
        return (
            ConditionSpec("speed", "m/s", 0.05, 2.0, "speed"),
            ConditionSpec("load", "-", 0.0, 3.0, "load", positive=False),
        )

    def record_duration(self, operating):
        return DURATION

    def motion_window(self, operating, *, duration=None):
        runs = np.atleast_2d(np.asarray(operating, dtype=float)).shape[0]
        stop = DURATION if duration is None else min(DURATION, duration)
        return np.full(runs, REST), np.full(runs, stop)

    def simulate(self, theta, damage, operating, *, duration=None):
        return self.simulate_values(theta, operating, state=damage, duration=duration)

    def simulate_values(
        self, values, operating, *, state="healthy", severity=None, duration=None, check=True
    ):
        spec = self.check_state(state)
        op = jnp.atleast_2d(jnp.asarray(operating, dtype=float))
        if op.ndim != 2 or op.shape[-1] != 2:
            raise ValueError(f"operating must be (run, 2), got {np.shape(operating)}")
        if check:
            self.check_operating(np.asarray(op))
        runs = op.shape[0]
        severity = dict(severity or {})
        sev = {k: severity.get(k, 0.5 * (lo + hi)) for k, (lo, hi) in spec.severity.items()}
        k, m = (jnp.broadcast_to(jnp.asarray(values[n], dtype=float), (runs,)) for n in "km")
        sev = {n: jnp.broadcast_to(jnp.asarray(x, dtype=float), (runs,)) for n, x in sev.items()}
        n_time = round((duration or DURATION) * FS)
        return _signals(k, m, op, sev, n_time)


@eqx.filter_jit
def _signals(k, m, op, sev, n_time: int):
    t = jnp.arange(n_time, dtype=float) / FS
    on = (t >= REST).astype(float)
    gain = (m * op[:, 0] * (1.0 + 0.5 * op[:, 1]))[:, None]
    x = gain * jnp.sin(2 * jnp.pi * (20.0 + 40.0 * k[:, None]) * t)
    if "a1" in sev:
        x = x + sev["a1"][:, None] * jnp.sin(2 * jnp.pi * 48 * t)
    if "a2" in sev:
        x = x + sev["a2"][:, None] * jnp.sin(2 * jnp.pi * 80 * t)
    floor = 0.01 * jnp.cos(2 * jnp.pi * 30.0 * t)
    signals = jnp.stack([x * on + floor, 0.5 * x * on + floor], axis=1)
    return _Result(signals, jnp.zeros(op.shape[0], dtype=jnp.int32), t)


class _Result(eqx.Module):
    signals: jax.Array
    status: jax.Array
    time: jax.Array


SYSTEM = LoadToySystem()
register_system("tones_load", lambda: SYSTEM)


def load_campaign(*, calibration=6, per_state=3, seed=0):
    """Runs at the three operating points, parameters scattered around CENTER."""
    rng = np.random.default_rng(seed)
    states = ["healthy"] * calibration + ["healthy", "D1", "D2"] * per_state
    points = POINTS[np.arange(len(states)) % len(POINTS)]
    signals = []
    for state, point in zip(states, points, strict=True):
        values = {"k": 0.5 + 0.02 * rng.standard_normal(), "m": 1.0}
        sev = {n: rng.uniform(lo, hi) for n, (lo, hi) in SYSTEM.states[state].severity.items()}
        res = SYSTEM.simulate_values(values, point, state=state, severity=sev)
        signals.append(np.asarray(res.signals[0]))
    return make_campaign(
        np.stack(signals),
        channels=["X", "Z"],
        fs=FS,
        state=states,
        speed=points[:, 0],
        load=points[:, 1],
        t_start=np.full(len(states), REST),
        t_stop=np.full(len(states), DURATION),
        split=["calibration"] * calibration + ["test"] * (len(states) - calibration),
        system="tones_load",
    )


@pytest.fixture(scope="module")
def campaign():
    return load_campaign()


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    config = GenerationConfig(POINTS, runs_per_state=30, chunk_size=15, validation_fraction=0.3)
    return generate(
        SYSTEM,
        GaussianScatter.around(SYSTEM, CENTER, 0.05),
        config,
        tmp_path_factory.mktemp("data"),
        key=jax.random.key(0),
        progress=False,
    )


def test_generation_keeps_the_rows(data):
    assert data.speeds.shape == (data.labels.size, 2)
    drawn = {tuple(p) for p in data.speeds.tolist()}
    assert drawn == {tuple(p) for p in POINTS.tolist()}
    config = data.manifest["config"]
    assert config["speeds"] == POINTS.tolist()
    # one condition: the configuration stays a list of numbers
    assert GenerationConfig([0.3, 0.5]).to_dict()["speeds"] == [0.3, 0.5]
    assert GenerationConfig([0.3, 0.5]).speeds == (0.3, 0.5)


def test_features_follow_the_load_at_one_speed(data):
    healthy = data.labels == 0
    low = healthy & np.all(data.speeds == POINTS[0], axis=1)
    high = healthy & np.all(data.speeds == POINTS[1], axis=1)
    # (1 + 2 / 2)^2 = 4 times the power at the tone: 0.6 decades
    peak = np.argmax(data.features[low][:, 0].mean(axis=0))
    diff = data.features[high][:, 0, peak].mean() - data.features[low][:, 0, peak].mean()
    assert diff == pytest.approx(np.log10(4.0), abs=0.1)


def test_helpers_match_runs_by_their_whole_point(data, campaign):
    known = campaign.isel(run=np.flatnonzero(np.asarray(campaign["split"]) == "calibration"))
    points = campaign_operating(known, SYSTEM)
    assert points.shape == (6, 2)
    features = campaign_features(known)
    residuals = calibration_residuals(data, features, points, state="healthy")
    # the measured runs are simulations about CENTER: at the tone the residual is small at
    # every point (against the other load at the same speed it would be 0.6 decades)
    peak = np.argmax(features[:, 0], axis=-1)
    assert np.abs(residuals[np.arange(6), 0, peak]).max() < 0.1
    shifted = with_measured_discrepancy(data, features, points, seed=1)
    assert shifted.features.shape == data.features.shape
    variance = measurement_variance(data)
    adequacy = fit_adequacy(data, features, points, variance, discrepancy=True)
    assert adequacy.runs == 6
    scores, bounds = healthy_outliers(data, features, points, variance)
    assert scores.shape == bounds.shape == (6,)
    # a point the data were not simulated at is refused, not matched by its speed alone
    with pytest.raises(ValueError, match="no healthy run"):
        calibration_residuals(data, features[:1], [[0.3, 1.0]], state="healthy")
    bands = PredictiveBands.from_training_data(data)
    assert bands.speeds.shape == (3, 2) and bands.values.shape[:2] == (3, 3)
    assert not np.isnan(bands.values).any()
    assert bands.nearest([0.3, 1.9]) == 1


# 36 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): a CMA-
# ES fit; in the long tier, which CI runs after the default suite
@pytest.mark.long
def test_cmaes_fit_on_two_conditions(campaign):
    fit = fit_campaign(SYSTEM, campaign, method="cmaes", quick=True, progress=False, seed=0)
    assert fit.point["k"] == pytest.approx(0.5, abs=0.05)
    replicates, data, ok = posterior_predictive(
        fit, SYSTEM, campaign, key=jax.random.key(0), n_draws=4
    )
    assert np.asarray(data.operating).shape == (3, 2)
    assert replicates.shape[:2] == (4, 6) and ok.all()


# 41 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): a
# whole job; in the long tier, which CI runs after the default suite
@pytest.mark.long
# the quick job's few validation runs are classified perfectly, so the temperature's fit ends at
# its bound, which the job says in a warning that is not this test's business
@pytest.mark.filterwarnings("ignore:the NLL-optimal temperature lies at the bound:UserWarning")
def test_job_on_two_conditions(tmp_path, campaign):
    sizes = Sizes(
        runs_per_state=30,
        chunk_size=15,
        validation_fraction=0.5,
        train=TrainConfig(members=2, epochs=20, batch_size=12, learning_rate=1e-2),
    )
    result = run_job(
        SYSTEM,
        campaign,
        tmp_path / "job",
        JobConfig.quick_look(method="cmaes", sizes=sizes, html=False),
        progress=False,
        report=lambda line: None,
    )
    runs = result.classification["runs"]
    assert len(runs) == 9
    assert all(r["most_probable"] is not None for r in runs)
    assert [r["operating"] for r in runs[:3]] == POINTS.tolist()
    assert runs[1]["speed"] == 0.3 and runs[1]["load"] == 2.0
    assert result.adequacy["verdict"] is not None, result.adequacy
    assert result.trust["verdict"] in ("trusted", "not trusted")
