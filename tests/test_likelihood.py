"""Fitting features, the Welch scatter, the likelihood with model error, the parameterisation."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist
import pytest
import scipy.signal
import scipy.stats
from _helpers import TableForward
from numpyro.infer.util import log_density
from numpyro.infer.util import log_likelihood as numpyro_log_likelihood

from bayesdoor.door import ElevatorDoor
from bayesdoor.inference import (
    CalibrationData,
    Discrepancy,
    DiscrepancyNormal,
    FeatureSpec,
    ModelError,
    SamplingTransform,
    log_likelihood,
    make_model,
    run_features,
    welch_degrees_of_freedom,
    welch_log10_variance,
)

FS = 2048.0


# ---------------------------------------------------------------------------------------------
# features


def test_default_spec_is_the_papers_4_to_96_hz_band_at_4_hz():
    spec = FeatureSpec()
    assert spec.bins_per_band(FS) == 1
    np.testing.assert_allclose(spec.band_centres(FS), np.arange(4.0, 97.0, 4.0))
    np.testing.assert_allclose(spec.band_edges(FS), np.arange(2.0, 99.0, 4.0))
    wide = FeatureSpec(nperseg=1024, f_high=98.0)
    assert wide.bins_per_band(FS) == 2
    assert wide.band_centres(FS).size == 24


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"band_width": 3.0}, "whole multiple of the bin spacing"),
        ({"nperseg": 1024}, "pass f_high=98"),
        ({"f_low": 5.0}, "bin grid"),
        ({"f_high": 2000.0}, "Nyquist"),
    ],
)
def test_inconsistent_specs_are_refused_with_the_fix(kwargs, match):
    with pytest.raises(ValueError, match=match):
        FeatureSpec(**kwargs).band_edges(FS)


def test_run_features_match_scipy_welch_on_the_window(key):
    """Reference: scipy.signal.welch over the window's samples, then numpy band means."""
    spec = FeatureSpec(nperseg=1024, f_high=98.0)
    x = np.asarray(jax.random.normal(key, (2, 3, 8192)))
    first = np.array([3, 1]) * spec.step  # the windows start on segment starts
    n_seg = np.array([9, 5])
    last = first + (n_seg - 1) * spec.step + spec.nperseg - 1
    t_start, t_stop = first / FS, last / FS
    feats, counts = run_features(jnp.asarray(x), FS, t_start, t_stop, spec)
    np.testing.assert_array_equal(np.asarray(counts), n_seg)
    edges = spec.band_edges(FS)
    for r in range(2):
        f, p = scipy.signal.welch(x[r, :, first[r] : last[r] + 1], FS, nperseg=spec.nperseg)
        ref = [p[:, (f >= lo) & (f < hi)].mean(axis=1) for lo, hi in itertools.pairwise(edges)]
        # float64 FFTs of the same samples: agreement to round-off
        np.testing.assert_allclose(np.asarray(feats[r]), np.log10(np.array(ref).T), rtol=1e-10)


# ---------------------------------------------------------------------------------------------
# Welch scatter


def test_degrees_of_freedom_in_closed_form_limits():
    # one segment, one bin: a chi-square with 2 dof, var(ln X) = trigamma(1) = pi^2 / 6
    assert float(welch_degrees_of_freedom(1, FS)) == pytest.approx(2.0, rel=1e-12)
    expected = np.pi**2 / 6 / np.log(10.0) ** 2
    assert float(welch_log10_variance(1, FS)) == pytest.approx(expected, rel=1e-10)
    # boxcar without overlap: independent segments and orthogonal bins, nu = 2 K B
    box = FeatureSpec(nperseg=1024, f_high=98.0, noverlap=0, window="boxcar")
    np.testing.assert_allclose(
        welch_degrees_of_freedom(jnp.arange(1.0, 6.0), FS, box), 4 * np.arange(1, 6)
    )
    # Hann at 50 %, one bin: Welch's (1967) correction with rho^2 = 1/36 between neighbours
    k = np.arange(1.0, 30.0)
    np.testing.assert_allclose(
        welch_degrees_of_freedom(jnp.asarray(k), FS),
        2 * k**2 / (k + (k - 1) / 18),
        rtol=1e-6,  # the table sums the window numerically; 1/36 holds to ~1e-6 at 512 points
    )


@pytest.mark.parametrize("colour", ["white", "coloured"])
@pytest.mark.parametrize(("nperseg", "f_high"), [(512, 96.0), (1024, 98.0)])
@pytest.mark.parametrize("n_segments", [4, 16])
def test_welch_log_variance_matches_monte_carlo(colour, nperseg, f_high, n_segments):
    """Empirical variance of the log10 band PSD over 1500 records within 10 % of the formula.

    The Monte Carlo standard error of the band-averaged variance is about 2 %; the chi-square
    approximation of a sum of correlated chi-squares (two bins per band) costs up to ~6 % at
    few segments, so 10 % separates a right formula from a wrong overlap or bin correction
    (ignoring the overlap correlation alone is 5 %, ignoring the bin correlation 25 %).
    """
    spec = FeatureSpec(nperseg=nperseg, f_high=f_high)
    n = spec.nperseg + (n_segments - 1) * spec.step
    rng = np.random.default_rng(nperseg + n_segments)
    x = rng.standard_normal((1500, 1, n))
    if colour == "coloured":  # a resonance at ~70 Hz: the PSD varies 100-fold over the band
        x = scipy.signal.lfilter([1.0], [1.0, -1.6, 0.8], x, axis=-1)
    feats, counts = run_features(jnp.asarray(x), FS, 0.0, n / FS, spec)
    assert int(counts[0]) == n_segments
    empirical = float(np.mean(np.var(np.asarray(feats), axis=0)))
    predicted = float(welch_log10_variance(counts[0], FS, spec))
    assert empirical == pytest.approx(predicted, rel=0.10)


# ---------------------------------------------------------------------------------------------
# data and likelihood


def _data(key, n_run=3):
    x = jax.random.normal(key, (n_run, 2, 4096))
    ops = np.array([0.3, 0.5, 0.3])[:n_run]
    return CalibrationData.from_signals(x, FS, ops, np.full(n_run, 0.1), np.full(n_run, 1.9))


def test_calibration_data_groups_runs_by_operating_point(key):
    data = _data(key)
    np.testing.assert_allclose(data.operating, [0.3, 0.5])
    np.testing.assert_array_equal(data.run_operating, [0, 1, 0])
    assert data.y.shape == (3, 2, 24)
    with pytest.raises(ValueError, match="no whole Welch segment"):
        CalibrationData.from_signals(jnp.zeros((1, 2, 4096)), FS, [0.3], [0.1], [0.3])
    with pytest.raises(ValueError, match="one operating point and window per run"):
        CalibrationData.from_signals(jnp.zeros((2, 2, 4096)), FS, [0.3], [0.1], [1.0])


def _forward(data, key, ok=True):
    m = jax.random.normal(key, (2, *data.y.shape[1:])) - 3.0
    var = 0.01 * jnp.ones_like(m)
    return TableForward(("a", "b"), data.operating, m, var, ok)


@pytest.mark.parametrize("slope", [False, True])
def test_independent_pointwise_log_likelihood_is_the_stated_gaussian(key, slope):
    """Reference: scipy.stats.norm.logpdf with the variance written out by hand."""
    k1, k2 = jax.random.split(key)
    data = _data(k1)
    forward = _forward(data, k2)
    transform = SamplingTransform.box(("a", "b"), [0.0, 0.0], [1.0, 2.0])
    model = make_model(data, forward, transform, ModelError(slope=slope, shared=False))
    theta = np.array([0.25, 1.5])
    sigma = np.array([0.2, 0.05])
    beta = np.array([0.7, -1.2])
    params = {"z": transform.to_sampling(jnp.asarray(theta)), "sigma_model": jnp.asarray(sigma)}
    if slope:
        params["sigma_slope"] = jnp.asarray(beta)
    pointwise = numpyro_log_likelihood(model, {k: v[None] for k, v in params.items()})["y"][0]
    assert pointwise.shape == data.y.shape
    f = np.arange(4.0, 97.0, 4.0)
    x = (f - 50.0) / 92.0
    s = sigma[:, None] * (np.exp(beta[:, None] * x) if slope else 1.0)
    mean = np.asarray(forward.features)[[0, 1, 0]] + theta.sum()
    var = np.asarray(data.welch_variance)[:, None, None] + s[None] ** 2 + 0.01
    ref = scipy.stats.norm.logpdf(np.asarray(data.y), mean, np.sqrt(var))
    np.testing.assert_allclose(np.asarray(pointwise), ref, rtol=1e-12)


def _dense_reference(y, loc, run_variance, shared_variance, run_operating):
    """Joint log density and leave-one-out conditionals from the full covariance matrices.

    Independent of DiscrepancyNormal's closed form: per operating point and element, the
    covariance diag(v) + s 11^T is built, scipy gives the joint, and the conditionals come from
    its inverse Q: log p(y_i | y_-i) = log N(r_i; r_i - (Q r)_i / Q_ii, 1 / Q_ii).
    """
    joint, conditional = 0.0, np.zeros(y.shape)
    for o in range(shared_variance.shape[0]):
        idx = np.flatnonzero(run_operating == o)
        if idx.size == 0:
            continue
        for c, b in itertools.product(range(y.shape[1]), range(y.shape[2])):
            cov = np.diag(run_variance[idx, c, b]) + shared_variance[o, c, b]
            r = y[idx, c, b] - loc[idx, c, b]
            joint += scipy.stats.multivariate_normal(np.zeros(idx.size), cov).logpdf(r)
            q = np.linalg.inv(cov)
            qr = q @ r
            for k, i in enumerate(idx):
                conditional[i, c, b] = scipy.stats.norm.logpdf(
                    r[k], r[k] - qr[k] / q[k, k], np.sqrt(1.0 / q[k, k])
                )
    return joint, conditional


def test_discrepancy_normal_matches_the_dense_covariance():
    """Groups of 3, 2, 1 and 0 runs; float64 linear algebra on matrices of at most 3 x 3, so
    agreement to round-off (1e-10 relative)."""
    rng = np.random.default_rng(3)
    run_operating = np.array([0, 1, 0, 2, 0, 1])
    shape = (6, 2, 5)
    loc = rng.normal(size=shape)
    run_variance = rng.uniform(0.005, 0.05, shape)
    shared_variance = rng.uniform(0.0, 0.2, (4, 2, 5))
    shared_variance[1, 0, :2] = 0.0  # no discrepancy: the runs are independent there
    y = loc + rng.normal(scale=0.3, size=shape)
    d = DiscrepancyNormal(
        jnp.asarray(loc),
        jnp.asarray(run_variance),
        jnp.asarray(shared_variance),
        jnp.asarray(run_operating),
    )
    joint, conditional = _dense_reference(y, loc, run_variance, shared_variance, run_operating)
    assert float(d.joint_log_prob(jnp.asarray(y))) == pytest.approx(joint, rel=1e-10)
    np.testing.assert_allclose(np.asarray(d.log_prob(jnp.asarray(y))), conditional, rtol=1e-10)
    # the lone run of operating point 2 has no other run to learn its discrepancy from
    lone = scipy.stats.norm.logpdf(y[3], loc[3], np.sqrt(run_variance[3] + shared_variance[2]))
    np.testing.assert_allclose(np.asarray(d.log_prob(jnp.asarray(y)))[3], lone, rtol=1e-10)


def test_discrepancy_normal_samples_share_the_discrepancy(key):
    """Covariances of 40000 draws within 5 Monte Carlo standard errors (for a Gaussian,
    sd(cov estimate) = sqrt((var_i var_j + cov_ij^2) / n))."""
    run_operating = jnp.asarray([0, 0, 1])
    run_variance = jnp.asarray([0.01, 0.04, 0.02])[:, None, None]
    shared_variance = jnp.asarray([0.09, 0.25])[:, None, None]
    d = DiscrepancyNormal(jnp.zeros((3, 1, 1)), run_variance, shared_variance, run_operating)
    x = np.asarray(d.sample(key, (40000,)))[:, :, 0, 0]
    expected = np.array([[0.10, 0.09, 0.0], [0.09, 0.13, 0.0], [0.0, 0.0, 0.27]])
    se = np.sqrt((np.outer(np.diag(expected), np.diag(expected)) + expected**2) / len(x))
    assert np.all(np.abs(np.cov(x.T) - expected) < 5 * se)


@pytest.mark.parametrize(("slope", "per_operating"), [(False, True), (True, True), (True, False)])
def test_shared_model_density_is_the_marginal_over_the_discrepancy(key, slope, per_operating):
    """The numpyro model's log density less its priors is the dense joint Gaussian; its
    pointwise log likelihood the leave-one-out conditionals (the reference as above)."""
    k1, k2 = jax.random.split(key)
    data = _data(k1)
    forward = _forward(data, k2)
    transform = SamplingTransform.box(("a", "b"), [0.0, 0.0], [1.0, 2.0])
    error = ModelError(slope=slope, per_operating=per_operating)
    model = make_model(data, forward, transform, error)
    theta = np.array([0.25, 1.5])
    # per operating point (0.3 and 0.5 m/s) and channel, or per channel
    sigma = np.array([[0.2, 0.05], [0.1, 0.3]]) if per_operating else np.array([0.2, 0.05])
    rho, beta = np.array([0.5, 1.3]), np.array([0.7, -1.2])
    site = "sigma_operating" if per_operating else "sigma_model"
    params = {
        "z": transform.to_sampling(jnp.asarray(theta)),
        site: jnp.asarray(sigma),
        "run_scatter": jnp.asarray(rho),
    }
    if slope:
        params["sigma_slope"] = jnp.asarray(beta)
    x = (np.arange(4.0, 97.0, 4.0) - 50.0) / 92.0
    s = (sigma[..., None] * (np.exp(beta[:, None] * x) if slope else 1.0)) ** 2
    # the forward model's own error variance (0.01) is shared too
    shared = np.broadcast_to(s + 0.01, (2, 2, 24))
    run_variance = np.asarray(data.welch_variance)[:, None, None] * rho[None, :, None] ** 2
    loc = np.asarray(forward.features)[[0, 1, 0]] + theta.sum()
    y = np.asarray(data.y)
    joint, conditional = _dense_reference(
        y, loc, np.broadcast_to(run_variance, y.shape), shared, np.array([0, 1, 0])
    )
    priors = float(transform.prior().log_prob(params["z"]))
    priors += float(dist.HalfNormal(error.scale).log_prob(params[site]).sum())
    priors += float(dist.LogNormal(0.0, error.scatter_scale).log_prob(params["run_scatter"]).sum())
    if slope:
        priors += float(dist.Normal(0.0, error.slope_scale).log_prob(params["sigma_slope"]).sum())
    density = float(log_density(model, (), {}, params)[0])
    assert density - priors == pytest.approx(joint, rel=1e-10)
    pointwise = numpyro_log_likelihood(model, {k: v[None] for k, v in params.items()})["y"][0]
    np.testing.assert_allclose(np.asarray(pointwise), conditional, rtol=1e-10)
    if per_operating:  # the per-channel summary: the root mean square over operating points
        trace = numpyro.handlers.trace(numpyro.handlers.substitute(model, params)).get_trace()
        np.testing.assert_allclose(
            trace["sigma_model"]["value"], np.sqrt(np.mean(sigma**2, axis=0)), rtol=1e-12
        )
    discrepancy = Discrepancy(
        jnp.asarray(sigma), jnp.asarray(beta) if slope else None, run_scatter=jnp.asarray(rho)
    )
    value = log_likelihood(jnp.asarray(theta), discrepancy, data, forward)
    assert float(value) == pytest.approx(joint, rel=1e-10)


def test_replicate_runs_do_not_average_the_discrepancy_away(key):
    """The information about a location parameter from n runs at one operating point: the
    independent form grows like n, the shared one saturates at 1 / sigma^2 per feature."""
    rng = np.random.default_rng(0)
    sigma, welch_sd = 0.2, 0.1

    def information(n, shared):
        data = CalibrationData(
            y=jnp.asarray(rng.normal(scale=0.1, size=(n, 1, 24))),
            welch_variance=jnp.full(n, welch_sd**2),
            operating=jnp.asarray([0.4]),
            run_operating=jnp.zeros(n, dtype=jnp.int32),
            band_centres=jnp.arange(4.0, 97.0, 4.0),
        )
        flat = jnp.zeros((1, 1, 24))
        forward = TableForward(("a",), data.operating, flat, flat, True)

        def loglik(theta):
            discrepancy = Discrepancy(jnp.asarray([sigma]), shared=shared)
            return log_likelihood(theta, discrepancy, data, forward)

        # the log likelihood is quadratic in theta: the second difference is exact
        low, mid, high = np.asarray(jax.vmap(loglik)(jnp.asarray([[-1.0], [0.0], [1.0]])))
        return -(low - 2.0 * mid + high)

    for n in (1, 10, 100):
        # 24 features, each a Gaussian whose mean moves one for one with theta
        independent = 24 * n / (sigma**2 + welch_sd**2)
        shared = 24 / (sigma**2 + welch_sd**2 / n)
        assert information(n, False) == pytest.approx(independent, rel=1e-8)
        assert information(n, True) == pytest.approx(shared, rel=1e-8)
    assert information(100, True) < 24 / sigma**2 < information(10, False)


def test_failed_forward_gives_minus_inf_with_finite_gradients(key):
    k1, k2 = jax.random.split(key)
    data = _data(k1)
    broken = _forward(data, k2, ok=False)
    broken = TableForward(
        broken.names, broken.operating, broken.features * jnp.nan, broken.variance, False
    )
    transform = SamplingTransform.box(("a", "b"), [0.0, 0.0], [1.0, 2.0])
    model = make_model(data, broken, transform)
    params = {
        "z": jnp.array([0.1, -0.3]),
        "sigma_operating": jnp.array([[0.1, 0.2], [0.3, 0.1]]),
        "run_scatter": jnp.array([0.5, 1.0]),
    }

    def logp(p):
        return log_density(model, (), {}, p)[0]

    value, grads = jax.value_and_grad(logp)(params)
    assert float(value) == -np.inf
    assert all(bool(jnp.all(jnp.isfinite(g))) for g in jax.tree_util.tree_leaves(grads))
    working = make_model(data, _forward(data, k2), transform)
    assert np.isfinite(float(log_density(working, (), {}, params)[0]))


def test_make_model_refuses_mismatched_parts(key):
    k1, k2 = jax.random.split(key)
    data = _data(k1)
    forward = _forward(data, k2)
    with pytest.raises(ValueError, match="same names"):
        make_model(data, forward, SamplingTransform.box(("b", "a"), [0.0, 0.0], [1.0, 1.0]))
    shifted = TableForward(
        forward.names, data.operating + 0.1, forward.features, forward.variance, True
    )
    with pytest.raises(ValueError, match="operating points"):
        make_model(data, shifted, SamplingTransform.box(("a", "b"), [0.0, 0.0], [1.0, 1.0]))


# ---------------------------------------------------------------------------------------------
# parameterisation


def _whitened():
    t = SamplingTransform.box(("a", "b"), [1.0, 0.0], [3.0, 0.5])
    return t.with_covariance(jnp.array([2.2, 0.1]), np.array([[0.3, 0.25], [0.25, 0.3]]))


def test_prior_density_includes_the_jacobian_and_samples_are_uniform(key):
    t = _whitened()
    z = jnp.array([0.3, -0.7])
    jac = jax.jacfwd(t.from_sampling)(z)
    expected = -np.log(2.0 * 0.5) + np.log(abs(np.linalg.det(np.asarray(jac))))
    assert float(t.prior().log_prob(z)) == pytest.approx(expected, rel=1e-12)
    np.testing.assert_allclose(t.to_sampling(t.from_sampling(z)), z, atol=1e-12)
    theta = np.asarray(t.from_sampling(t.prior().sample(key, (4000,))))
    for i, (lo, hi) in enumerate([(1.0, 3.0), (0.0, 0.5)]):
        # a wrong Jacobian or order of the transforms gives p-values far below 1e-3
        assert scipy.stats.kstest(theta[:, i], scipy.stats.uniform(lo, hi - lo).cdf).pvalue > 1e-3


def test_transform_refuses_integer_parameters_and_bad_covariances():
    door = ElevatorDoor()
    t = SamplingTransform.from_specs(door.parameters)
    assert "I" not in t.names and len(t.names) == 7
    with pytest.raises(ValueError, match="integer"):
        SamplingTransform.from_specs(door.parameters, ["K", "I"])
    with pytest.raises(ValueError, match="not positive definite"):
        t2 = SamplingTransform.box(("a", "b"), [0.0, 0.0], [1.0, 1.0])
        t2.with_covariance(jnp.array([0.5, 0.5]), np.array([[1.0, 1.0], [1.0, 1.0]]))


def test_laplace_whitening_recovers_a_gaussian_in_logit_coordinates():
    """A density that is exactly Gaussian in the logit coordinates: Laplace is exact."""
    t = SamplingTransform.box(("a", "b"), [1300.0, 1.5], [2500.0, 2.2])
    mean = jnp.array([0.4, -0.2])
    cov = jnp.array([[0.04, 0.035], [0.035, 0.04]])  # correlation 0.875

    def log_density(theta):
        u = t.unconstrained(theta)
        gauss = dist.MultivariateNormal(mean, cov).log_prob(u)
        return gauss - t.log_jacobian(u)

    w = t.whitened_at(log_density, jnp.array([1900.0, 1.8]))
    np.testing.assert_allclose(w.centre, mean, atol=1e-6)
    np.testing.assert_allclose(w.chol @ w.chol.T, cov, rtol=1e-5)
    # the whitened coordinates of that density have unit covariance
    u = np.random.default_rng(0).multivariate_normal(np.asarray(mean), np.asarray(cov), 20000)
    z = np.asarray(w.to_sampling(t.constrained(jnp.asarray(u))))
    assert np.linalg.cond(np.cov(z.T)) < 1.1 < np.linalg.cond(np.cov(u.T))
