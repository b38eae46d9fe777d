"""A discrepancy part common to every operating point (ModelError(common=True)): the closed
form against dense multivariate normals, no common part as today's likelihood, and the
numpyro model's site."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import numpyro.distributions as dist
import pytest
import scipy.stats
from _helpers import TableForward
from numpyro.infer.util import log_density
from numpyro.infer.util import log_likelihood as numpyro_log_likelihood

from bayesdoor.door import ElevatorDoor
from bayesdoor.door.rig import VirtualRig
from bayesdoor.inference import (
    CalibrationData,
    DiscrepancyNormal,
    FitProblem,
    ModelError,
    SamplingTransform,
    fit_campaign,
    make_model,
    posterior_predictive,
)


def _problem(seed, n_channel=2, n_band=3):
    """Five runs at three operating points (2, 2 and 1 runs), unequal run variances."""
    rng = np.random.default_rng(seed)
    run_operating = np.array([0, 0, 1, 1, 2])
    shape = (len(run_operating), n_channel, n_band)
    loc = rng.normal(size=shape)
    run_variance = rng.uniform(0.01, 0.2, size=shape)
    shared = rng.uniform(0.0, 0.3, size=(3, n_channel, n_band))
    common = rng.uniform(0.05, 0.5, size=(n_channel, n_band))
    y = loc + rng.normal(size=shape)
    return y, loc, run_variance, shared, common, run_operating


def _dense(y, loc, run_variance, shared, common, run_operating):
    """Per channel and band the five runs' covariance diag(v) + s_o [same op] + tau^2, written
    out: scipy's joint, the leave-one-out conditionals from its inverse Q (log N(r_i; r_i -
    (Q r)_i / Q_ii, 1 / Q_ii)), and Gaussian conditioning of each operating point's whole
    discrepancy gamma + delta_o (covariance with run r: tau^2 + s_o [op(r) = o]) and of gamma
    (tau^2 with every run)."""
    n_run, n_channel, n_band = y.shape
    n_op = shared.shape[0]
    same = run_operating[:, None] == run_operating[None, :]
    joint, conditional = 0.0, np.zeros(y.shape)
    post = np.zeros((2, n_op, n_channel, n_band))
    common_post = np.zeros((2, n_channel, n_band))
    for c, b in itertools.product(range(n_channel), range(n_band)):
        s = shared[run_operating, c, b]
        cov = (
            np.diag(run_variance[:, c, b]) + same * np.sqrt(s[:, None] * s[None, :]) + common[c, b]
        )
        r = y[:, c, b] - loc[:, c, b]
        joint += scipy.stats.multivariate_normal(np.zeros(n_run), cov).logpdf(r)
        q = np.linalg.inv(cov)
        qr = q @ r
        conditional[:, c, b] = scipy.stats.norm.logpdf(
            r, r - qr / np.diag(q), np.sqrt(1.0 / np.diag(q))
        )
        for o in range(n_op):
            k = common[c, b] + shared[o, c, b] * (run_operating == o)
            post[0, o, c, b] = k @ qr
            post[1, o, c, b] = common[c, b] + shared[o, c, b] - k @ q @ k
        k = np.full(n_run, common[c, b])
        common_post[:, c, b] = k @ qr, common[c, b] - k @ q @ k
    return joint, conditional, post, common_post


def _distribution(loc, v, s, t, ops):
    return DiscrepancyNormal(
        jnp.asarray(loc),
        jnp.asarray(v),
        jnp.asarray(s),
        jnp.asarray(ops),
        common_variance=jnp.asarray(t),
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_closed_form_matches_dense_normals(seed):
    """Joint, conditionals, each operating point's discrepancy and the common part's posterior
    agree with the dense computation to rounding (1e-10: float64, a few hundred operations)."""
    y, loc, v, s, t, ops = _problem(seed)
    d = _distribution(loc, v, s, t, ops)
    joint, conditional, post, common_post = _dense(y, loc, v, s, t, ops)
    np.testing.assert_allclose(float(d.joint_log_prob(jnp.asarray(y))), joint, rtol=1e-10)
    np.testing.assert_allclose(np.asarray(d.log_prob(jnp.asarray(y))), conditional, rtol=1e-9)
    mean, variance = d.discrepancy_posterior(jnp.asarray(y))
    np.testing.assert_allclose(np.asarray(mean), post[0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.asarray(variance), post[1], rtol=1e-9)
    mean, variance = d.common_posterior(jnp.asarray(y))
    np.testing.assert_allclose(np.asarray(mean), common_post[0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.asarray(variance), common_post[1], rtol=1e-9)
    np.testing.assert_allclose(np.asarray(d.variance), v + s[ops] + t[None], rtol=1e-12)


def test_the_common_part_changes_the_density_and_zero_is_none():
    """A common part is not a no-op (the joint moves by more than rounding), and a zero
    common variance gives today's density and conditionals."""
    y, loc, v, s, t, ops = _problem(2)
    args = (jnp.asarray(loc), jnp.asarray(v), jnp.asarray(s), jnp.asarray(ops))
    base = DiscrepancyNormal(*args)
    zero = DiscrepancyNormal(*args, common_variance=jnp.zeros_like(jnp.asarray(t)))
    with_common = DiscrepancyNormal(*args, common_variance=jnp.asarray(t))
    yy = jnp.asarray(y)
    np.testing.assert_allclose(
        float(zero.joint_log_prob(yy)), float(base.joint_log_prob(yy)), rtol=1e-13
    )
    np.testing.assert_allclose(
        np.asarray(zero.log_prob(yy)), np.asarray(base.log_prob(yy)), rtol=1e-10
    )
    assert abs(float(with_common.joint_log_prob(yy)) - float(base.joint_log_prob(yy))) > 0.1


def test_samples_have_the_common_covariance():
    """Draws from the joint: runs at different operating points covary by tau^2 (the common
    part), runs at one operating point by tau^2 + s_o. 40000 draws: the sample covariance's
    standard error is under 0.01 here, the tolerance 0.02."""
    _, loc, v, s, t, ops = _problem(3, n_channel=1, n_band=1)
    d = _distribution(loc, v, s, t, ops)
    draws = np.asarray(d.sample(jax.random.key(0), (40000,)))[:, :, 0, 0]
    cov = np.cov(draws.T)
    assert abs(cov[0, 2] - t[0, 0]) < 0.02
    assert abs(cov[0, 1] - (t[0, 0] + s[0, 0, 0])) < 0.02
    assert abs(cov[4, 4] - (t[0, 0] + s[2, 0, 0] + v[4, 0, 0])) < 0.02
    np.testing.assert_allclose(draws.mean(axis=0), loc[:, 0, 0], atol=0.02)


def test_model_error_refuses_common_without_sharing_or_with_correlation():
    with pytest.raises(ValueError, match="common=True needs shared=True"):
        ModelError(common=True, shared=False)
    with pytest.raises(ValueError, match="common=True needs shared=True"):
        ModelError(common=True, correlation=2.0)
    assert ModelError(common=True).common


@pytest.mark.long
def test_numpyro_model_density_is_the_dense_marginal(key):
    """make_model with ModelError(common=True): the log density less its priors (now with
    sigma_common ~ HalfNormal(scale)) is the dense joint of the reference above, the pointwise
    terms its leave-one-out conditionals. Three runs at two speeds, tiny Welch features."""
    k1, k2 = jax.random.split(key)
    x = jax.random.normal(k1, (3, 2, 4096))
    data = CalibrationData.from_signals(
        x, 2048.0, np.array([0.3, 0.5, 0.3]), np.full(3, 0.1), np.full(3, 1.9)
    )
    m = jax.random.normal(k2, (2, *data.y.shape[1:])) - 3.0
    forward = TableForward(("a", "b"), data.operating, m, 0.01 * jnp.ones_like(m))
    transform = SamplingTransform.box(("a", "b"), [0.0, 0.0], [1.0, 2.0])
    error = ModelError(common=True)
    model = make_model(data, forward, transform, error)
    theta = np.array([0.25, 1.5])
    sigma, rho, tau = (
        np.array([[0.2, 0.05], [0.1, 0.3]]),
        np.array([0.5, 1.3]),
        np.array([0.4, 0.1]),
    )
    params = {
        "z": transform.to_sampling(jnp.asarray(theta)),
        "sigma_operating": jnp.asarray(sigma),
        "run_scatter": jnp.asarray(rho),
        "sigma_common": jnp.asarray(tau),
    }
    y = np.asarray(data.y)
    ops = np.asarray(data.run_operating)
    n_band = y.shape[-1]
    shared = np.broadcast_to(sigma[..., None] ** 2 + 0.01, (2, 2, n_band))
    common = np.broadcast_to(tau[:, None] ** 2, (2, n_band))
    run_variance = np.broadcast_to(
        np.asarray(data.welch_variance)[:, None, None] * rho[None, :, None] ** 2, y.shape
    )
    loc = np.asarray(m)[ops] + theta.sum()
    joint, conditional, _, _ = _dense(y, loc, run_variance, shared, common, ops)
    priors = float(transform.prior().log_prob(params["z"]))
    priors += float(dist.HalfNormal(error.scale).log_prob(params["sigma_operating"]).sum())
    priors += float(dist.LogNormal(0.0, error.scatter_scale).log_prob(params["run_scatter"]).sum())
    priors += float(dist.HalfNormal(error.scale).log_prob(params["sigma_common"]).sum())
    density = float(log_density(model, (), {}, params)[0])
    assert density - priors == pytest.approx(joint, rel=1e-10)
    pointwise = numpyro_log_likelihood(model, {k: v[None] for k, v in params.items()})["y"][0]
    np.testing.assert_allclose(np.asarray(pointwise), conditional, rtol=1e-9)


@pytest.mark.slow
def test_fit_and_predictive_with_a_common_part():
    """A quick NUTS fit with the common part on rig runs at two speeds, then replicates of
    those runs and of one at a speed no calibration run measured (0.4 m/s): every replicate
    finite, and the unmeasured speed's band is wider than the measured speeds' (there the
    discrepancy is the common part's posterior plus a fresh own part, not a posterior given
    runs at that speed)."""
    recording = VirtualRig().run(
        ["healthy"] * 4,
        [0.3, 0.5, 0.3, 0.4],
        key=jax.random.key(3),
        split=["calibration"] * 3 + ["test"],
    )
    door = ElevatorDoor()
    result = fit_campaign(
        door,
        recording.campaign,
        method="nuts",
        quick=True,
        progress=False,
        problem=FitProblem(error=ModelError(common=True)),
    )
    tau = result.common_draws()
    assert tau is not None and tau.shape[1] == 4 and np.all(tau > 0)
    sigma = result.discrepancy_draws()
    np.testing.assert_allclose(
        result.model_error_draws(), np.sqrt(np.mean(sigma**2, axis=1) + tau**2), rtol=1e-12
    )
    replicates, data, ok = posterior_predictive(
        result, door, recording.campaign, [0, 1, 2, 3], key=jax.random.key(4), n_draws=40
    )
    assert ok.all() and np.all(np.isfinite(replicates))
    assert replicates.shape == (40, *np.asarray(data.y).shape)
    width = np.std(replicates, axis=0).mean(axis=(1, 2))
    assert width[3] > width[:3].max(), width
