"""The sampling scatter of a Welch PSD estimate: equivalent degrees of freedom, log10 variance.

One implementation serves fitting (JAX, traced segment counts) and diagnosis (numpy): a JAX
array in gives a JAX array out, anything else a numpy array (and its values are checked).
"""

from __future__ import annotations

from types import ModuleType
from typing import overload

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.special as jsp
import numpy as np
import optimistix as optx
import scipy.signal
import scipy.special
import scipy.stats

from .._types import Array, Float
from ._spectra import LOG_FLOOR
from ._welch import segment_weights, welch_psd


def _correlation_table(nperseg: int, noverlap: int, window: str | tuple, bins: int) -> np.ndarray:
    """Squared correlations of periodogram values, by segment lag and bin lag.

    For Gaussian noise with a locally flat spectrum, the periodograms of two segments ``d``
    steps apart at bins ``m`` apart have correlation ``|sum_n w(n) w(n + d D)
    exp(-2 pi i m n / N)|^2 / (sum_n w(n)^2)^2`` (Welch 1967, eq. 12, extended to bin lags).
    """
    win = scipy.signal.get_window(window, nperseg)
    step = nperseg - noverlap
    lags = int(np.ceil(nperseg / step))
    n = np.arange(nperseg)
    table = np.zeros((lags, bins))
    for d in range(lags):
        shift = d * step
        product = win[: nperseg - shift] * win[shift:]
        for m in range(bins):
            phase = np.exp(-2j * np.pi * m * n[: nperseg - shift] / nperseg)
            table[d, m] = abs(np.sum(product * phase)) ** 2
    return table / np.sum(win * win) ** 2


@overload
def welch_dof(
    n_segments: int,
    nperseg: int,
    noverlap: int | None = None,
    window: str | tuple = "hann",
    *,
    bins: int = 1,
) -> float: ...
@overload
def welch_dof(
    n_segments: Float[np.ndarray, "*batch"],
    nperseg: int,
    noverlap: int | None = None,
    window: str | tuple = "hann",
    *,
    bins: int = 1,
) -> Float[np.ndarray, "*batch"]: ...
@overload
def welch_dof(
    n_segments: Float[Array, "*batch"],
    nperseg: int,
    noverlap: int | None = None,
    window: str | tuple = "hann",
    *,
    bins: int = 1,
) -> Float[Array, "*batch"]: ...
def welch_dof(n_segments, nperseg, noverlap=None, window="hann", *, bins=1):
    """Equivalent chi-square degrees of freedom of a Welch PSD, one bin or a band mean of bins.

    A mean of ``B`` adjacent bins, each averaged over ``K`` overlapping windowed segments
    that start every ``S = nperseg - noverlap`` samples, is distributed approximately as
    ``P chi2_nu / nu`` with ``nu = 2 / r`` and ``r`` its relative variance ``(1 / (K B)^2)
    sum_{segments, bins} rho^2``, the sum over all pairs of the squared correlations of
    periodogram values (:func:`_correlation_table`). For one bin this is
    ``nu = 2 K / (1 + 2 sum_{m=1}^{K-1} (1 - m / K) rho_m)``; for a Hann window with 50 %
    overlap ``rho_1 = 1/36`` and the others vanish, so ``nu = 36 K^2 / (19 K - 1)``; with no
    overlap and a boxcar window ``nu = 2 K B``.

    Parameters
    ----------
    n_segments
        Number of averaged segments ``K``. A JAX array may be traced and batched (no check of
        its values); otherwise each value must be a positive integer.
    nperseg, noverlap, window
        The segmentation, as in :func:`bayesdoor.features.welch_psd` (``noverlap=None`` is
        ``nperseg // 2``).
    bins
        Adjacent bins averaged in one band (keyword-only).

    Returns
    -------
    nu
        The equivalent degrees of freedom (2 for one segment and one bin): a JAX array for a
        JAX input, a float for a scalar, else a numpy array.

    Raises
    ------
    ValueError
        For fewer than one segment (numpy input), an overlap outside ``[0, nperseg)`` or
        fewer than one bin.

    References
    ----------
    P. D. Welch (1967), IEEE Trans. Audio Electroacoustics 15(2), eqs. (11)-(12); D. B.
    Percival and A. T. Walden (1993), *Spectral Analysis for Physical Applications*,
    section 6.17, eq. (292b).
    """
    noverlap = nperseg // 2 if noverlap is None else noverlap
    if not 0 <= noverlap < nperseg:
        raise ValueError(f"noverlap must lie in [0, nperseg) = [0, {nperseg}), got {noverlap!r}")
    if isinstance(bins, bool) or not isinstance(bins, int) or bins < 1:
        raise ValueError(f"bins must be a positive integer, got {bins!r}")
    xp: ModuleType
    if isinstance(n_segments, jax.Array):
        xp = jnp
        k = n_segments
        if not jnp.issubdtype(k.dtype, jnp.floating):
            k = k.astype(jnp.result_type(float))
    else:
        xp = np
        k = np.asarray(n_segments, dtype=float)
        if isinstance(n_segments, bool) or not np.all((k >= 1) & (k == np.round(k))):
            raise ValueError(
                f"n_segments must be positive integers, got {n_segments!r}: a Welch estimate "
                "needs at least one segment inside the analysed window"
            )
    table = _correlation_table(nperseg, noverlap, window, bins)
    lag_weight = np.where(np.arange(table.shape[0]) == 0, 1.0, 2.0)
    bin_weight = np.where(np.arange(bins) == 0, 1.0, 2.0) * (bins - np.arange(bins))
    per_lag = xp.asarray(lag_weight * (table @ bin_weight), dtype=k.dtype)
    lags = xp.arange(table.shape[0], dtype=k.dtype)
    pairs = xp.maximum(k[..., None] - lags, 0.0)
    nu = 2.0 / (xp.sum(pairs * per_lag, axis=-1) / (k * bins) ** 2)
    return float(nu) if xp is np and nu.ndim == 0 else nu


@overload
def log10_psd_variance(dof: float | Float[np.ndarray, "*batch"]) -> Float[np.ndarray, "*batch"]: ...
@overload
def log10_psd_variance(dof: Float[Array, "*batch"]) -> Float[Array, "*batch"]: ...
def log10_psd_variance(dof):
    """Variance of ``log10`` of a PSD estimate with ``dof`` equivalent degrees of freedom.

    For ``X = P chi^2_nu / nu``, ``var(ln X) = psi'(nu / 2)`` (the trigamma function),
    whatever ``P``; divided by ``ln(10)^2`` for ``log10``. The mean of ``ln X`` is biased by
    ``psi(nu / 2) - ln(nu / 2)`` (about -0.01 decades at 20-odd segments); that bias cancels
    when measured and predicted spectra are estimated with the same segmentation.

    Parameters
    ----------
    dof
        Equivalent degrees of freedom (positive), for example from :func:`welch_dof`. A JAX
        array may be traced (no check of its values).

    Returns
    -------
    variance
        ``polygamma(1, dof / 2) / ln(10)^2``, decades^2; JAX for a JAX input, else numpy.

    Raises
    ------
    ValueError
        For a non-positive or non-finite ``dof`` (numpy input).
    """
    if isinstance(dof, jax.Array):
        return jsp.polygamma(1, 0.5 * dof) / np.log(10.0) ** 2
    nu = np.asarray(dof, dtype=float)
    if not np.all(np.isfinite(nu) & (nu > 0)):
        raise ValueError(f"dof must be positive and finite, got {dof!r}")
    return scipy.special.polygamma(1, nu / 2.0) / np.log(10.0) ** 2


def _trigamma_residual(log_nu, target):
    return jsp.polygamma(1, 0.5 * jnp.exp(log_nu)) / target - 1.0


@eqx.filter_jit
def _solve_dof(scaled: Float[Array, " n"]) -> Float[Array, " n"]:
    """Degrees of freedom with ``trigamma(nu / 2) = scaled``, elementwise."""

    def one(v):
        # trigamma(x) > 1 / x, so nu = 2 / v lies below the root; the residual is convex and
        # decreasing in ln(nu), so from there Newton's iterates rise monotonically to it
        solution = optx.root_find(
            _trigamma_residual,
            optx.Newton(rtol=1e-12, atol=1e-12),
            jnp.log(2.0 / v),
            args=v,
            max_steps=100,
        )
        return jnp.exp(solution.value)

    return jax.vmap(one)(scaled)


def dof_from_log10_variance(
    variance: float | Float[np.ndarray, "*batch"],
) -> Float[np.ndarray, "*batch"]:
    """The degrees of freedom whose ``log10`` chi-square variance is ``variance``.

    The inverse of :func:`log10_psd_variance` (trigamma decreases monotonically): an
    ``optimistix.Newton`` root find on ``ln(nu)`` from the bound ``psi'(nu / 2) > 2 / nu``,
    once per distinct value.

    Raises
    ------
    ValueError
        For a non-positive or non-finite variance.
    """
    v = np.asarray(variance, dtype=float) * np.log(10.0) ** 2
    if not np.all(np.isfinite(v) & (v > 0)):
        raise ValueError(f"variance must be positive and finite, got {variance!r}")
    distinct, index = np.unique(v, return_inverse=True)
    # padded to a power of two so that a few compiled solves serve every batch size
    padded = np.ones(1 << max(3, (distinct.size - 1).bit_length()))
    padded[: distinct.size] = distinct
    nu = np.asarray(_solve_dof(jnp.asarray(padded)))
    return nu[index.reshape(v.shape)]


def windowed_log_psd(
    signals: Float[np.ndarray, "*draw run channel time"],
    fs: float,
    t_start: Float[np.ndarray, " run"],
    t_stop: Float[np.ndarray, " run"],
    *,
    nperseg: int,
    noverlap: int | None = None,
) -> tuple[
    Float[np.ndarray, " freq"],
    Float[np.ndarray, "*draw run channel freq"],
    Float[np.ndarray, " run"],
]:
    """log10 Welch PSD of each run over its own window, with the Welch log variance.

    Only the Hann segments lying entirely inside ``[t_start, t_stop]`` of each run are
    averaged (:func:`bayesdoor.features.segment_weights`), so every run gets its own number of
    segments and its own degrees of freedom.

    Parameters
    ----------
    signals
        Sensor signals sampled at ``fs`` from time 0; leading axes before (run, channel,
        time) (draws of a population, say) share the runs' windows, and each record's PSD is
        the one it gets alone.
    fs
        Sampling rate, Hz.
    t_start, t_stop
        Each run's window, s (for the motion: when the system starts and stops moving).
    nperseg, noverlap
        Welch segmentation; the bin spacing is ``fs / nperseg``.

    Returns
    -------
    freqs
        Bin frequencies, Hz.
    log_psd
        ``log10`` PSD per run and channel (and draw).
    log_variance
        Variance of each run's ``log10`` PSD estimate (:func:`log10_psd_variance` of
        :func:`welch_dof`).

    Raises
    ------
    ValueError
        When a run's window holds no complete segment (name the run; shorten ``nperseg``).
    """
    x = np.asarray(signals, dtype=float)
    if x.ndim < 3:
        raise ValueError(f"signals must have dims (..., run, channel, time), got shape {x.shape}")
    t0 = np.broadcast_to(np.asarray(t_start, dtype=float), x.shape[-3:-2])
    t1 = np.broadcast_to(np.asarray(t_stop, dtype=float), x.shape[-3:-2])
    weights = np.asarray(
        segment_weights(x.shape[-1], fs, jnp.asarray(t0), jnp.asarray(t1), nperseg, noverlap)
    )
    counts = weights.sum(axis=-1)
    if np.any(counts < 1):
        bad = int(np.argmin(counts))
        raise ValueError(
            f"run {bad}: its window [{t0[bad]:.3f}, {t1[bad]:.3f}] s holds no complete Welch "
            f"segment of nperseg={nperseg} samples at fs={fs} Hz: pass a smaller nperseg"
        )
    # the Welch average in numpy (numpy in, numpy out): no eager JAX dispatch of the large
    # arrays in each of the thousands of calls a diagnosis makes; one draw at a time, whose
    # segments stay in the cache (a population at once runs slower)
    spectra = [
        welch_psd(record, fs, nperseg=nperseg, noverlap=noverlap, segment_weights=weights[:, None])
        for record in x.reshape(-1, *x.shape[-3:])
    ]
    psd = np.stack([p for _, p in spectra]).reshape(*x.shape[:-1], -1)
    dof = welch_dof(counts, nperseg, noverlap)
    log_psd = np.log10(np.maximum(psd, LOG_FLOOR))
    return np.asarray(spectra[0][0]), log_psd, log10_psd_variance(dof)


#: Gauss-Hermite nodes for the expectation over the predictive draws' normal spread
_HERMITE_X, _HERMITE_W = np.polynomial.hermite_e.hermegauss(40)
_HERMITE_W = _HERMITE_W / _HERMITE_W.sum()


def log_chi2_normal_scores(
    difference: Float[np.ndarray, "*batch"],
    draw_variance: Float[np.ndarray, "*batch"],
    dof: Float[np.ndarray, "*batch"],
) -> Float[np.ndarray, "*batch"]:
    """Normal scores of measured-minus-predicted ``log10`` PSDs under the Welch scatter.

    The difference is modelled as ``W + N``: ``W`` the centred ``log10`` of a chi-square
    with ``dof`` degrees of freedom over ``dof`` (the measured estimate's scatter, skewed: a
    long lower tail), ``N`` normal with the draws' variance. Its distribution function is
    the expectation over ``N`` (Gauss-Hermite, 40 nodes) of the regularised incomplete gamma
    function; the score is ``Phi^-1`` of it (taken from the nearer tail for precision). Where
    a tail probability underflows, the normal approximation ``difference / sd`` is used
    instead: such bins are extreme either way.

    Parameters
    ----------
    difference
        Measured minus mean predicted ``log10`` PSD.
    draw_variance
        Variance of the predictive draws (0 allowed).
    dof
        Equivalent degrees of freedom of the measured estimate.

    Returns
    -------
    z
        Standard normal scores.
    """
    d, s2, nu = np.broadcast_arrays(
        np.asarray(difference, dtype=float),
        np.asarray(draw_variance, dtype=float),
        np.asarray(dof, dtype=float),
    )
    half = nu / 2.0
    mean_log = (scipy.special.digamma(half) - np.log(half)) / np.log(10.0)
    w = d[..., None] - np.sqrt(s2)[..., None] * _HERMITE_X + mean_log[..., None]
    x = half[..., None] * 10.0 ** np.clip(w, -300.0, 300.0)
    lower = np.sum(_HERMITE_W * scipy.special.gammainc(half[..., None], x), axis=-1)
    upper = np.sum(_HERMITE_W * scipy.special.gammaincc(half[..., None], x), axis=-1)
    z = np.where(lower < upper, scipy.stats.norm.ppf(lower), scipy.stats.norm.isf(upper))
    approx = d / np.sqrt(s2 + scipy.special.polygamma(1, half) / np.log(10.0) ** 2)
    usable = (np.minimum(lower, upper) > 1e-280) & np.isfinite(z)
    return np.where(usable, z, approx)
