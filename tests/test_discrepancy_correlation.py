"""A model discrepancy correlated over the bands (ModelError(correlation=...)): the closed form
against dense multivariate normals, correlation 0 as today's likelihood, the numpyro model, and
the fit and predictive path."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import numpyro.distributions as dist
import pytest
import scipy.stats
from _helpers import TableForward
from numpyro.infer import Predictive
from numpyro.infer.util import log_density
from numpyro.infer.util import log_likelihood as numpyro_log_likelihood

from bayesdoor.inference import (
    CalibrationData,
    CorrelatedDiscrepancyNormal,
    DiscrepancyNormal,
    ModelError,
    NUTSSettings,
    SamplingTransform,
    band_correlation,
    make_model,
    sample_nuts,
)

FS = 2048.0


def _dense(y, loc, run_variance, covariance, run_operating):
    """Joint log density, leave-one-out conditionals and the discrepancy's posterior from the
    full covariance of each operating point and channel, written out element by element.

    Per operating point o and channel c the runs' bands are stacked into one vector with
    covariance diag(v) + 1 1^T kron Sigma_oc; scipy gives the joint, its inverse Q the
    conditionals (log p(y_i | y_-i) = log N(r_i; r_i - (Q r)_i / Q_ii, 1 / Q_ii)), and Gaussian
    conditioning the discrepancy given the runs: mean Sigma U^T C^-1 r, covariance
    Sigma - Sigma U^T C^-1 U Sigma with U stacking identities."""
    n_op, n_channel, n_band = covariance.shape[:3]
    joint, conditional = 0.0, np.zeros(y.shape)
    post_mean = np.zeros((n_op, n_channel, n_band))
    post_cov = np.array(covariance, copy=True)
    for o, c in itertools.product(range(n_op), range(n_channel)):
        idx = np.flatnonzero(run_operating == o)
        if idx.size == 0:
            continue
        sigma = covariance[o, c]
        u = np.tile(np.eye(n_band), (idx.size, 1))
        cov = np.diag(run_variance[idx, c].reshape(-1)) + u @ sigma @ u.T
        r = (y[idx, c] - loc[idx, c]).reshape(-1)
        joint += scipy.stats.multivariate_normal(np.zeros(r.size), cov).logpdf(r)
        q = np.linalg.inv(cov)
        qr = q @ r
        cond = scipy.stats.norm.logpdf(r, r - qr / np.diag(q), np.sqrt(1.0 / np.diag(q)))
        conditional[idx, c] = cond.reshape(idx.size, n_band)
        post_mean[o, c] = sigma @ u.T @ qr
        post_cov[o, c] = sigma - sigma @ u.T @ q @ u @ sigma
    return joint, conditional, post_mean, post_cov


def _case(rng, length=2.5):
    """Six runs at four operating points (3, 2, 1 and 0 runs), two channels, seven bands;
    run variances differ per run, channel and band; one discrepancy is zero."""
    run_operating = np.array([0, 1, 0, 2, 0, 1])
    shape = (6, 2, 7)
    loc = rng.normal(size=shape)
    run_variance = rng.uniform(0.005, 0.05, shape)
    scale = rng.uniform(0.05, 0.4, (4, 2, 7))
    correlation = np.asarray(band_correlation(7, length))
    covariance = scale[..., :, None] * correlation * scale[..., None, :]
    covariance += np.vectorize(np.diag, signature="(n)->(n,n)")(rng.uniform(0, 0.01, (4, 2, 7)))
    covariance[1, 0] = 0.0  # no discrepancy: the runs are independent there
    y = loc + rng.normal(scale=0.3, size=shape)
    return y, loc, run_variance, covariance, run_operating


def test_band_correlation_is_the_squared_exponential():
    r = np.asarray(band_correlation(4, 2.0))
    np.testing.assert_allclose(r[0], np.exp(-0.5 * (np.arange(4) / 2.0) ** 2), rtol=1e-15)
    np.testing.assert_array_equal(r, r.T)


def test_correlated_discrepancy_matches_the_dense_covariance():
    """Float64 linear algebra on matrices of at most 21 x 21 with condition numbers below
    1e4, so agreement to 1e-9 relative; the smooth discrepancy (length 2.5 bands) makes the
    squared-exponential Sigma itself nearly singular, which the closed form never inverts."""
    y, loc, run_variance, covariance, run_operating = _case(np.random.default_rng(4))
    d = CorrelatedDiscrepancyNormal(
        jnp.asarray(loc),
        jnp.asarray(run_variance),
        jnp.asarray(covariance),
        jnp.asarray(run_operating),
    )
    joint, conditional, mean, cov = _dense(y, loc, run_variance, covariance, run_operating)
    assert float(d.joint_log_prob(jnp.asarray(y))) == pytest.approx(joint, rel=1e-10)
    np.testing.assert_allclose(np.asarray(d.log_prob(jnp.asarray(y))), conditional, rtol=1e-9)
    got_mean, got_cov = d.discrepancy_posterior_covariance(jnp.asarray(y))
    np.testing.assert_allclose(np.asarray(got_mean), mean, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.asarray(got_cov), cov, rtol=1e-8, atol=1e-12)
    # the marginal of each element: its run's scatter plus the discrepancy's prior variance
    expected = run_variance + np.diagonal(covariance, axis1=-2, axis2=-1)[run_operating]
    np.testing.assert_allclose(np.asarray(d.variance), expected, rtol=1e-15)


def test_diagonal_covariance_is_the_independent_bands_closed_form():
    """With Sigma diagonal the correlated form is DiscrepancyNormal (Sherman-Morrison per
    element); two different algorithms, so agreement to round-off (1e-12)."""
    y, loc, run_variance, covariance, run_operating = _case(np.random.default_rng(5))
    diagonal = np.diagonal(covariance, axis1=-2, axis2=-1)
    args = (jnp.asarray(loc), jnp.asarray(run_variance))
    flat = DiscrepancyNormal(*args, jnp.asarray(diagonal), jnp.asarray(run_operating))
    full = CorrelatedDiscrepancyNormal(
        *args,
        jnp.asarray(np.vectorize(np.diag, signature="(n)->(n,n)")(diagonal)),
        jnp.asarray(run_operating),
    )
    value = jnp.asarray(y)
    assert float(full.joint_log_prob(value)) == pytest.approx(
        float(flat.joint_log_prob(value)), rel=1e-12
    )
    np.testing.assert_allclose(full.log_prob(value), flat.log_prob(value), rtol=1e-12)
    for a, b in zip(
        full.discrepancy_posterior(value), flat.discrepancy_posterior(value), strict=True
    ):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)


def test_samples_have_the_correlated_shared_covariance(key):
    """Covariances of 40000 draws within 5 Monte Carlo standard errors (for a Gaussian,
    sd(cov estimate) = sqrt((var_i var_j + cov_ij^2) / n)): two runs at one operating point,
    three bands, so the 6 x 6 covariance is diag(v) + [[S, S], [S, S]]."""
    sigma = 0.3**2 * np.asarray(band_correlation(3, 1.5))
    run_variance = np.array([0.01, 0.04])[:, None, None] * np.ones((2, 1, 3))
    d = CorrelatedDiscrepancyNormal(
        jnp.zeros((2, 1, 3)),
        jnp.asarray(run_variance),
        jnp.asarray(sigma[None, None]),
        jnp.asarray([0, 0]),
    )
    x = np.asarray(d.sample(key, (40000,))).reshape(40000, 6)
    expected = np.diag(run_variance.reshape(-1)) + np.tile(sigma, (2, 2))
    se = np.sqrt((np.outer(np.diag(expected), np.diag(expected)) + expected**2) / len(x))
    assert np.all(np.abs(np.cov(x.T) - expected) < 5 * se)


# ---------------------------------------------------------------------------------------------
# the numpyro model


def _data(key):
    x = jax.random.normal(key, (3, 2, 4096))
    return CalibrationData.from_signals(
        x, FS, np.array([0.3, 0.5, 0.3]), np.full(3, 0.1), np.full(3, 1.9)
    )


def _forward(data, key):
    m = jax.random.normal(key, (2, *data.y.shape[1:])) - 3.0
    return TableForward(("a", "b"), data.operating, m, 0.01 * jnp.ones_like(m))


def _params(transform, extra=()):
    theta = np.array([0.25, 1.5])
    params = {
        "z": transform.to_sampling(jnp.asarray(theta)),
        "sigma_operating": jnp.asarray([[0.2, 0.05], [0.1, 0.3]]),
        "run_scatter": jnp.asarray([0.5, 1.3]),
    }
    params.update(extra)
    return theta, params


@pytest.mark.long
def test_correlation_zero_is_todays_likelihood_exactly(key):
    """ModelError(correlation=0) is the default: the same numpyro density and pointwise terms
    bit for bit (the independent-bands code path)."""
    k1, k2 = jax.random.split(key)
    data, transform = _data(k1), SamplingTransform.box(("a", "b"), [0.0, 0.0], [1.0, 2.0])
    forward = _forward(data, k2)
    _, params = _params(transform)
    today = make_model(data, forward, transform, ModelError())
    zero = make_model(data, forward, transform, ModelError(correlation=0.0))
    assert ModelError(correlation=0.0) == ModelError()
    assert float(log_density(zero, (), {}, params)[0]) == float(
        log_density(today, (), {}, params)[0]
    )
    batch = {k: v[None] for k, v in params.items()}
    np.testing.assert_array_equal(
        numpyro_log_likelihood(zero, batch)["y"], numpyro_log_likelihood(today, batch)["y"]
    )


@pytest.mark.parametrize("infer", [False, True])
def test_correlated_model_density_is_the_dense_marginal(key, infer):
    """The numpyro model's log density less its priors is the dense joint Gaussian of the
    reference above, with Sigma_oc = S R S + diag(e^2) (the forward model's error, 0.01,
    independent over bands); its pointwise terms are the dense leave-one-out conditionals.
    Inferred, the length is a site with a LogNormal(ln 3, 0.5) prior, here at 1.7 bands."""
    k1, k2 = jax.random.split(key)
    data, transform = _data(k1), SamplingTransform.box(("a", "b"), [0.0, 0.0], [1.0, 2.0])
    forward = _forward(data, k2)
    if infer:
        error = ModelError(correlation=3.0, infer_correlation=True, correlation_scale=0.5)
        length = 1.7
        theta, params = _params(transform, {"discrepancy_length": jnp.asarray(length)})
    else:
        error = ModelError(correlation=3.0)
        length = 3.0
        theta, params = _params(transform)
    model = make_model(data, forward, transform, error)
    sigma, rho = np.asarray(params["sigma_operating"]), np.asarray(params["run_scatter"])
    r = np.exp(-0.5 * ((np.arange(24)[:, None] - np.arange(24)[None, :]) / length) ** 2)
    covariance = sigma[..., None, None] ** 2 * r + 0.01 * np.eye(24)
    run_variance = np.asarray(data.welch_variance)[:, None, None] * rho[None, :, None] ** 2
    loc = np.asarray(forward.features)[[0, 1, 0]] + theta.sum()
    y = np.asarray(data.y)
    joint, conditional, _, _ = _dense(
        y, loc, np.broadcast_to(run_variance, y.shape), covariance, np.array([0, 1, 0])
    )
    priors = float(transform.prior().log_prob(params["z"]))
    priors += float(dist.HalfNormal(error.scale).log_prob(params["sigma_operating"]).sum())
    priors += float(dist.LogNormal(0.0, error.scatter_scale).log_prob(params["run_scatter"]).sum())
    if infer:
        priors += float(dist.LogNormal(np.log(3.0), 0.5).log_prob(length))
    density = float(log_density(model, (), {}, params)[0])
    assert density - priors == pytest.approx(joint, rel=1e-10)
    pointwise = numpyro_log_likelihood(model, {k: v[None] for k, v in params.items()})["y"][0]
    np.testing.assert_allclose(np.asarray(pointwise), conditional, rtol=1e-9)


def test_model_error_refuses_inconsistent_correlation_settings():
    with pytest.raises(ValueError, match=r"correlation=-1\.0 must be >= 0"):
        ModelError(correlation=-1.0)
    with pytest.raises(ValueError, match="infer_correlation=True needs correlation > 0"):
        ModelError(infer_correlation=True)
    with pytest.raises(ValueError, match="needs shared=True"):
        ModelError(correlation=2.0, shared=False)


#: 32-35 s on an empty JAX cache, nearly all of it compiling NUTS through the correlated
#: likelihood: in the long tier, which CI runs after the default suite
@pytest.mark.long
def test_nuts_samples_the_length_and_replicates_are_finite(key):
    """The sampled site, a start value for it, and posterior-predictive replicates through
    the correlated distribution's ``sample`` (a short chain: this checks the plumbing, the
    closed form is checked above)."""
    k1, k2, k3, k4 = jax.random.split(key, 4)
    data, transform = _data(k1), SamplingTransform.box(("a", "b"), [0.0, 0.0], [1.0, 2.0])
    error = ModelError(correlation=2.0, infer_correlation=True)
    model = make_model(data, _forward(data, k2), transform, error)
    _, init = _params(transform, {"discrepancy_length": jnp.asarray(2.0)})
    idata = sample_nuts(
        model,
        key=k3,
        init_values=init,
        settings=NUTSSettings(num_warmup=50, num_samples=50, num_chains=1),
        progress=False,
    )
    length = np.asarray(idata["posterior"]["discrepancy_length"].values)
    assert length.shape == (1, 50) and np.all(length > 0)
    samples = {
        n: jnp.asarray(idata["posterior"][n].values[0])
        for n in ("z", "sigma_operating", "run_scatter", "discrepancy_length")
    }
    y = Predictive(model, posterior_samples=samples, return_sites=["y"])(k4, y=None)["y"]
    assert y.shape == (50, *data.y.shape) and np.all(np.isfinite(np.asarray(y)))
