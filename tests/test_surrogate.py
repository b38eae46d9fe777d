"""The surrogate: exactness on a quadratic, held-out error on the door, NUTS on it, whitening,
and (slow) agreement with NUTS straight through the diffrax simulator."""

import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from numpyro.infer import MCMC, NUTS
from numpyro.infer.util import log_density

from bayesdoor.door import ElevatorDoor, SolverConfig
from bayesdoor.inference import (
    AbstractForward,
    CalibrationData,
    Discrepancy,
    ForwardOutput,
    ModelError,
    SamplingTransform,
    SimulatorForward,
    box_around,
    fit_surrogate,
    log_likelihood,
    make_model,
    simulate_design,
)

#: the door case's two runs are the reduced model itself plus 1e-3 m/s^2 noise: replicas whose
#: features differ by far less than a Welch sd, so the shared model error would fit a run
#: scatter near zero and leave the surrogate's error (independent per feature) as the only
#: spread, which is overconfident (C's 99 % interval missed the truth). These tests are about
#: the surrogate and the whitening, so they use the independent form, whose Welch variance
#: stands in for a real door's run-to-run scatter
INDEPENDENT = ModelError(shared=False)

#: a short record at the fastest speed keeps the default tests quick: 0.25 s rest, 0.75 s motion
DURATION = 1.0
SPEED = 0.5
FREE = ("K", "n", "C", "MF")


class QuadraticForward(AbstractForward):
    """An exactly quadratic forward model with known coefficients (independent reference)."""

    names: tuple[str, ...]
    operating: jax.Array
    coef: jax.Array  # (term, op * 2 * 3)

    def __call__(self, theta):
        x = theta
        phi = jnp.concatenate([jnp.ones(1), x, x**2, x[:1] * x[1:]])
        out = (phi @ self.coef).reshape(2, 2, 3)
        return ForwardOutput(out, jnp.zeros_like(out), jnp.asarray(True))


def test_surrogate_is_exact_on_a_quadratic(key):
    k1, k2 = jax.random.split(key)
    # basis of the reference: 1, x0, x1, x2, x0^2, x1^2, x2^2, x0 x1, x0 x2 (no x1 x2 term)
    coef = jax.random.normal(k1, (9, 12))
    forward = QuadraticForward(("a", "b", "c"), jnp.array([0.3, 0.4]), coef)
    box = ([-1.0, 0.0, 2.0], [1.0, 3.0, 2.5])
    sur = fit_surrogate(forward, box, key=k2, n_train=24, n_test=16)
    # a quadratic reproduced by a quadratic: the held-out error is round-off
    assert float(jnp.max(sur.heldout_rms)) < 1e-6
    theta = jnp.array([0.3, 2.9, 2.1])
    np.testing.assert_allclose(sur(theta).features, forward(theta).features, atol=1e-6)
    with pytest.raises(ValueError, match="n_train >= 20"):
        fit_surrogate(forward, box, key=k2, n_train=12)


def test_simulate_design_on_threads_equals_one_thread(key):
    """Chunks on two threads give exactly the one-thread features (same chunk size, so the
    same vmapped computation); a bad thread count is refused."""
    coef = jax.random.normal(key, (9, 12))
    forward = QuadraticForward(("a", "b", "c"), jnp.array([0.3, 0.4]), coef)
    thetas = np.random.default_rng(0).uniform(-1.0, 1.0, size=(23, 3))
    one_f, one_ok = simulate_design(forward, thetas, chunk=4)
    two_f, two_ok = simulate_design(forward, thetas, chunk=4, workers=2)
    np.testing.assert_array_equal(two_f, one_f)
    np.testing.assert_array_equal(two_ok, one_ok)
    assert one_f.shape == (23, 2, 2, 3)
    # and the independent reference: the quadratic evaluated point by point
    np.testing.assert_allclose(one_f[7], forward(jnp.asarray(thetas[7])).features, atol=1e-12)
    with pytest.raises(ValueError, match="workers=0"):
        simulate_design(forward, thetas, workers=0)


def test_box_around_clips_to_the_bounds():
    lo, hi = box_around([1.0, 0.5], [1.0, 0.0], [2.0, 1.0], 0.25)
    np.testing.assert_allclose(lo, [1.0, 0.25])
    np.testing.assert_allclose(hi, [1.25, 0.75])
    with pytest.raises(ValueError, match="outside the bounds"):
        box_around([3.0, 0.5], [1.0, 0.0], [2.0, 1.0], 0.25)


# ---------------------------------------------------------------------------------------------
# the reduced door: four free parameters, one speed, short records


@pytest.fixture(scope="module")
def door_case():
    door = ElevatorDoor()
    truth = {p.name: float(p.reference_value) for p in door.parameters}
    truth["MF"] = 1.2  # inside the box, so every free parameter has room on both sides
    ops = np.full(2, SPEED)
    result = door.simulate_values(truth, ops, duration=DURATION)
    noise = 1e-3 * np.random.default_rng(7).standard_normal(result.signals.shape)
    t_start, t_stop = door.motion_window(ops, duration=DURATION)
    data = CalibrationData.from_signals(
        np.asarray(result.signals) + noise, door.sampling_rate_hz, ops, t_start, t_stop
    )
    fixed = {k: v for k, v in truth.items() if k not in FREE}
    forward = SimulatorForward.build(door, FREE, fixed, data.operating, duration=DURATION)
    specs = {p.name: p for p in door.parameters}
    centre = np.array([truth[n] for n in FREE])
    lo, hi = box_around(
        centre, [specs[n].lower for n in FREE], [specs[n].upper for n in FREE], 0.25
    )
    surrogate = fit_surrogate(
        forward, (lo, hi), key=jax.random.key(3), n_train=48, n_test=16, chunk=16
    )
    return {
        "data": data,
        "forward": forward,
        "surrogate": surrogate,
        "truth": centre,
        "box": SamplingTransform.box(FREE, lo, hi),
    }


# 105 s (101 s of it the setup of `door_case`, a design of door solves) in the default suite
# (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): with the other tests of
# `door_case`; in the long tier, which CI runs after the default suite
@pytest.mark.long
def test_door_surrogate_heldout_error_is_reported_and_bounded(door_case):
    """The quadratic's held-out RMS error, and an independent check of it on fresh runs.

    Bound: the error must stay below the Welch scatter it is added to (sd 0.21 decades for
    these five-segment records), overall RMS below a quarter of it. Measured on this case:
    overall 0.030, worst feature 0.14 decades (the mass factor moves a low resonance through
    the 4 Hz band, which no quadratic follows exactly); the error variance enters the
    likelihood, so such features simply weigh less.
    """
    sur, forward = door_case["surrogate"], door_case["forward"]
    welch_sd = float(jnp.sqrt(door_case["data"].welch_variance[0]))
    rms = np.asarray(sur.heldout_rms)
    overall = float(np.sqrt(np.mean(rms**2)))
    print(f"held-out RMS: overall {overall:.4f}, worst feature {rms.max():.4f} decades")
    assert rms.shape == (1, 4, 24)
    assert rms.max() < welch_sd
    assert overall < 0.25 * welch_sd
    lo, hi = np.asarray(sur.lower), np.asarray(sur.upper)
    fresh = lo + (hi - lo) * np.random.default_rng(11).uniform(size=(16, len(FREE)))
    exact, ok = simulate_design(forward, fresh, chunk=16)
    assert ok.all()
    predicted = np.asarray(jax.vmap(lambda t: sur(t).features)(jnp.asarray(fresh)))
    fresh_rms = float(np.sqrt(np.mean((predicted - exact) ** 2)))
    # two 16-point estimates of the same RMS error: a factor 2 covers their sampling scatter
    assert 0.5 * overall < fresh_rms < 2.0 * overall


# 82 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16):
# gradients through the door surrogate of `door_case`; in the long tier, which CI runs after the
# default suite
@pytest.mark.long
def test_surrogate_log_density_has_finite_gradients(door_case, key):
    model = make_model(door_case["data"], door_case["surrogate"], door_case["box"])
    zs = 3.0 * jax.random.normal(key, (20, len(FREE)))  # out to the box's edges

    def logp(z):
        params = {"z": z, "sigma_operating": jnp.full((1, 4), 0.05), "run_scatter": jnp.ones(4)}
        return log_density(model, (), {}, params)[0]

    values, grads = jax.vmap(jax.value_and_grad(logp))(zs)
    assert bool(jnp.all(jnp.isfinite(values))) and bool(jnp.all(jnp.isfinite(grads)))


def _nuts(model, key, warmup=300, samples=400):
    mcmc = MCMC(NUTS(model), num_warmup=warmup, num_samples=samples, progress_bar=False)
    # numpyro's tree building mixes integer and float scalars, which strict promotion refuses
    with jax.numpy_dtype_promotion("standard"):
        mcmc.run(key, extra_fields=("diverging",))
    return mcmc.get_samples(), int(mcmc.get_extra_fields()["diverging"].sum())


@pytest.fixture(scope="module")
def box_posterior(door_case):
    start = time.perf_counter()
    model = make_model(door_case["data"], door_case["surrogate"], door_case["box"], INDEPENDENT)
    samples, divergences = _nuts(model, jax.random.key(5))
    return samples, divergences, time.perf_counter() - start


# the two NUTS runs on the surrogate (the plain box's, shared through ``box_posterior``, and the
# whitened one's): 19-40 s and 18-56 s with an empty JAX cache on a 2-core machine (the higher
# figures with other work beside it), in the long tier, which CI runs after the default suite
# (the surrogate's error and its density's gradients stay in it)
@pytest.mark.long
def test_nuts_on_the_surrogate_is_fast_and_covers_the_truth(door_case, box_posterior):
    samples, divergences, seconds = box_posterior
    print(f"NUTS on the surrogate: 700 iterations in {seconds:.1f} s (compilation included)")
    assert divergences <= 4  # under 1 % of the draws
    for i, name in enumerate(FREE):
        lo, hi = np.quantile(np.asarray(samples[name]), [0.005, 0.995])
        assert lo < door_case["truth"][i] < hi, (name, lo, hi, door_case["truth"][i])


@pytest.mark.long
def test_laplace_whitening_conditions_the_sampling_coordinates(door_case, box_posterior):
    """The posterior covariance in the sampling coordinates: plain logit box vs whitened.

    The whitening comes from a Laplace approximation at the mode found from the truth (as
    from a CMA-ES optimum), with the model-error scales held at 0.05; it does not see the
    samples. Measured: condition number 259 in the logit box (the parameters' posterior
    scales differ by more than an order), 3.3 whitened.
    """
    data, sur, box = door_case["data"], door_case["surrogate"], door_case["box"]
    white = box.whitened_at(
        lambda theta: log_likelihood(
            theta, Discrepancy(jnp.full(4, 0.05), shared=False), data, sur
        ),
        jnp.asarray(door_case["truth"]),
    )
    plain = np.asarray(box_posterior[0]["z"])
    whitened, _ = _nuts(make_model(data, sur, white, INDEPENDENT), jax.random.key(6))
    cond_plain = np.linalg.cond(np.cov(plain.T))
    cond_white = np.linalg.cond(np.cov(np.asarray(whitened["z"]).T))
    print(f"condition number of the posterior covariance: {cond_plain:.1f} -> {cond_white:.1f}")
    assert cond_plain > 20.0
    assert cond_white < 5.0
    for name in FREE:  # the same posterior, whichever coordinates
        a, b = np.asarray(box_posterior[0][name]), np.asarray(whitened[name])
        assert abs(a.mean() - b.mean()) < 0.3 * a.std()


# ---------------------------------------------------------------------------------------------
# slow: NUTS straight through the diffrax simulator


@pytest.mark.slow
def test_exact_simulator_posterior_agrees_with_the_surrogate_posterior(door_case):
    """Two free parameters (K, C), the rest at the truth: NUTS through diffrax vs surrogate.

    Posterior means agree within 0.3 posterior sd and sds within 30 %: the exact chain is
    short (150 draws, each gradient a diffrax solve and its adjoint), so the Monte Carlo error
    of its mean is about 0.1 sd and of its sd about 7 %; the surrogate's error (0.003 decades
    on this two-parameter box) shifts the likelihood far less.
    """
    data = door_case["data"]
    door = door_case["forward"].system
    names = ("K", "C")
    truth = dict(zip(FREE, door_case["truth"], strict=True))
    fixed = {p.name: float(p.reference_value) for p in door.parameters if p.name not in names}
    fixed["MF"] = truth["MF"]
    exact = SimulatorForward.build(door, names, fixed, data.operating, duration=DURATION)
    centre = np.array([truth[n] for n in names])
    specs = {p.name: p for p in door.parameters}
    lo, hi = box_around(
        centre, [specs[n].lower for n in names], [specs[n].upper for n in names], 0.25
    )
    sur = fit_surrogate(exact, (lo, hi), key=jax.random.key(8), n_train=24, n_test=16, chunk=16)
    box = SamplingTransform.box(names, lo, hi)
    start = time.perf_counter()
    s_sur, _ = _nuts(make_model(data, sur, box), jax.random.key(9), 300, 600)
    t_sur = time.perf_counter() - start
    start = time.perf_counter()
    s_exact, div = _nuts(make_model(data, exact, box), jax.random.key(9), 100, 150)
    t_exact = time.perf_counter() - start
    print(f"NUTS: surrogate {t_sur:.0f} s, exact simulator {t_exact:.0f} s, {div} divergences")
    for name in (*names, "sigma_model"):
        a, b = np.asarray(s_exact[name]), np.asarray(s_sur[name])
        print(name, a.mean(axis=0), a.std(axis=0), b.mean(axis=0), b.std(axis=0))
        assert np.all(np.abs(a.mean(axis=0) - b.mean(axis=0)) < 0.3 * a.std(axis=0))
        assert np.all(np.abs(b.std(axis=0) / a.std(axis=0) - 1.0) < 0.3)


@pytest.mark.slow
def test_failed_simulation_is_minus_inf_with_finite_gradients(door_case):
    data = door_case["data"]
    door = ElevatorDoor(config=SolverConfig(max_steps=16))
    names = ("K", "C")
    fixed = {p.name: float(p.reference_value) for p in door.parameters if p.name not in names}
    broken = SimulatorForward.build(door, names, fixed, data.operating, duration=DURATION)
    theta = jnp.array([1863.0, 0.018])
    value, grad = jax.value_and_grad(log_likelihood)(theta, jnp.full(4, 0.1), data, broken)
    assert float(value) == -np.inf
    assert bool(jnp.all(jnp.isfinite(grad)))
