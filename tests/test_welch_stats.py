"""The Welch scatter statistics of bayesdoor.features, from numpy and from JAX callers."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize
import scipy.special

from bayesdoor.features import (
    dof_from_log10_variance,
    log10_psd_variance,
    welch_dof,
)


@pytest.mark.parametrize(
    ("nperseg", "noverlap", "window"), [(512, None, "hann"), (256, 0, "boxcar")]
)
def test_welch_dof_numpy_and_jax_callers_get_the_closed_form(nperseg, noverlap, window):
    k = np.arange(1, 41)
    # Percival and Walden (1993) eq. 292b: Hann at 50 %, rho_1 = 1/36 up to O(1/nperseg^2)
    # of the discrete window; boxcar without overlap: independent segments, nu = 2 K
    expected = 36 * k**2 / (19 * k - 1) if window == "hann" else 2.0 * k
    rtol = 1e-5 if window == "hann" else 1e-12
    from_numpy = welch_dof(k, nperseg, noverlap, window)
    from_jax = welch_dof(jnp.asarray(k, dtype=float), nperseg, noverlap, window)
    assert isinstance(from_numpy, np.ndarray) and isinstance(from_jax, jax.Array)
    np.testing.assert_allclose(from_numpy, expected, rtol=rtol)
    # the same arithmetic in both namespaces: equal to round-off
    np.testing.assert_allclose(np.asarray(from_jax), from_numpy, rtol=1e-14)


def test_welch_dof_band_of_orthogonal_bins_adds_their_degrees_of_freedom():
    # boxcar, no overlap: the bins of one segment are uncorrelated, so a band of B bins over
    # K segments has nu = 2 K B exactly; a Hann band has fewer (neighbouring bins correlate)
    k = jnp.arange(1.0, 11.0)
    np.testing.assert_allclose(welch_dof(k, 256, 0, "boxcar", bins=3), 6.0 * np.arange(1, 11))
    assert np.all(welch_dof(np.arange(1, 11), 256, bins=3) < 6.0 * np.arange(1, 11))


def test_welch_dof_traces_under_jit():
    nu = jax.jit(lambda k: welch_dof(k, 512))(jnp.asarray([1.0, 4.0]))
    np.testing.assert_allclose(nu, welch_dof(np.array([1, 4]), 512), rtol=1e-14)


@pytest.mark.parametrize("bad", [0, 2.5, -1, True])
def test_welch_dof_refuses_a_count_that_is_not_a_positive_integer(bad):
    with pytest.raises(ValueError, match="positive integer"):
        welch_dof(bad, 512)


@pytest.mark.parametrize("nu", [2.0, 7.3, 40.0])
def test_log10_variance_matches_a_chi_square_sample(nu):
    # var(log10(chi2_nu / nu)) from 400000 draws has a relative sampling error of about
    # sqrt(2 / n) ~ 0.2 % (times a kurtosis factor below 3 for these nu): 2 % is 10 sigma
    sample = np.log10(np.random.default_rng(int(nu)).chisquare(nu, 400_000) / nu)
    for value in (log10_psd_variance(nu), log10_psd_variance(jnp.asarray(nu))):
        assert float(value) == pytest.approx(np.var(sample), rel=0.02)


def test_dof_from_log10_variance_matches_a_bracketing_solve():
    nu = np.array([0.3, 1.0, 2.0, 3.3, 6.4, 12.0, 37.5, 100.0, 1e4, 1e6])
    variance = scipy.special.polygamma(1, nu / 2.0) / np.log(10.0) ** 2
    # an independent inverse: Brent's method on scipy's trigamma, bracketed in ln(nu)
    reference = np.array(
        [
            np.exp(
                scipy.optimize.brentq(
                    lambda u, v=v: (
                        scipy.special.polygamma(1, np.exp(u) / 2.0) - v * np.log(10.0) ** 2
                    ),
                    -10.0,
                    20.0,
                    xtol=1e-14,
                    rtol=1e-14,
                )
            )
            for v in variance
        ]
    )
    # trigamma's round-off (~1e-15) divided by its log-slope (between 1 and 2): 1e-12
    np.testing.assert_allclose(dof_from_log10_variance(variance), reference, rtol=1e-12)
    np.testing.assert_allclose(reference, nu, rtol=1e-12)
    # broadcast shape and repeated values are kept
    grid = np.broadcast_to(variance[:3, None], (3, 4))
    assert dof_from_log10_variance(grid).shape == (3, 4)
    with pytest.raises(ValueError, match="positive and finite"):
        dof_from_log10_variance(np.array([0.1, 0.0]))
