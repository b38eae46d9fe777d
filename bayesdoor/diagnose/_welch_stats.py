"""The sampling scatter of a Welch PSD estimate: equivalent degrees of freedom, log variance."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import scipy.signal
import scipy.special
import scipy.stats

from .._types import Float
from ..features import log_psd, segment_weights, welch_psd


def welch_dof(
    n_segments: int, nperseg: int, noverlap: int | None = None, window: str | tuple = "hann"
) -> float:
    """Equivalent degrees of freedom of a Welch PSD estimate of Gaussian noise.

    A Welch estimate at a frequency away from 0 and Nyquist is approximately a scaled
    chi-square variable with ``nu`` degrees of freedom,

    ``nu = 2 K / (1 + 2 sum_{m=1}^{K-1} (1 - m / K) rho_m)``,
    ``rho_m = (sum_t h_t h_{t + m S})^2 / (sum_t h_t^2)^2``,

    for ``K`` segments of window ``h`` that start every ``S = nperseg - noverlap`` samples.
    For a Hann window with 50 % overlap ``rho_1 = 1/36`` and the others vanish, so
    ``nu = 36 K^2 / (19 K - 1)``.

    Parameters
    ----------
    n_segments
        Number of averaged segments ``K`` (at least 1).
    nperseg, noverlap, window
        The segmentation, as in :func:`bayesdoor.features.welch_psd`.

    Returns
    -------
    nu
        The equivalent degrees of freedom (2 for one segment).

    Raises
    ------
    ValueError
        For fewer than one segment or an overlap outside ``[0, nperseg)``.

    References
    ----------
    P. D. Welch (1967), IEEE Trans. Audio Electroacoustics 15(2), eq. for the variance of the
    averaged periodogram; D. B. Percival and A. T. Walden (1993), *Spectral Analysis for
    Physical Applications*, section 6.17, eq. (292b).
    """
    if isinstance(n_segments, bool) or int(n_segments) != n_segments or n_segments < 1:
        raise ValueError(
            f"n_segments must be a positive integer, got {n_segments!r}: a Welch estimate "
            "needs at least one segment inside the analysed window"
        )
    noverlap = nperseg // 2 if noverlap is None else noverlap
    if not 0 <= noverlap < nperseg:
        raise ValueError(f"noverlap must lie in [0, nperseg) = [0, {nperseg}), got {noverlap!r}")
    k = int(n_segments)
    h = scipy.signal.get_window(window, nperseg)
    step = nperseg - noverlap
    energy = float(np.sum(h * h))
    total = 1.0
    for m in range(1, k):
        shift = m * step
        if shift >= nperseg:
            break
        rho = (float(np.sum(h[: nperseg - shift] * h[shift:])) / energy) ** 2
        total += 2.0 * (1.0 - m / k) * rho
    return 2.0 * k / total


def log10_psd_variance(dof: float | Float[np.ndarray, "*batch"]) -> Float[np.ndarray, "*batch"]:
    """Variance of ``log10`` of a PSD estimate with ``dof`` equivalent degrees of freedom.

    For ``X = P chi^2_nu / nu``, ``var(ln X) = psi'(nu / 2)`` (the trigamma function),
    whatever ``P``; divided by ``ln(10)^2`` for ``log10``. The mean of ``ln X`` is biased by
    ``psi(nu / 2) - ln(nu / 2)``; that bias cancels when measured and predicted spectra are
    estimated with the same segmentation, which :func:`residual_map` assumes.

    Parameters
    ----------
    dof
        Equivalent degrees of freedom (positive), for example from :func:`welch_dof`.

    Returns
    -------
    variance
        ``polygamma(1, dof / 2) / ln(10)^2``.

    Raises
    ------
    ValueError
        For a non-positive or non-finite ``dof``.
    """
    nu = np.asarray(dof, dtype=float)
    if not np.all(np.isfinite(nu) & (nu > 0)):
        raise ValueError(f"dof must be positive and finite, got {dof!r}")
    return scipy.special.polygamma(1, nu / 2.0) / np.log(10.0) ** 2


def windowed_log_psd(
    signals: Float[np.ndarray, "run channel time"],
    fs: float,
    t_start: Float[np.ndarray, " run"],
    t_stop: Float[np.ndarray, " run"],
    *,
    nperseg: int,
    noverlap: int | None = None,
) -> tuple[
    Float[np.ndarray, " freq"], Float[np.ndarray, "run channel freq"], Float[np.ndarray, " run"]
]:
    """log10 Welch PSD of each run over its own window, with the Welch log variance.

    Only the Hann segments lying entirely inside ``[t_start, t_stop]`` of each run are
    averaged (:func:`bayesdoor.features.segment_weights`), so every run gets its own number of
    segments and its own degrees of freedom.

    Parameters
    ----------
    signals
        Sensor signals sampled at ``fs`` from time 0.
    fs
        Sampling rate, Hz.
    t_start, t_stop
        Each run's window, s (for the motion: when the door starts and stops moving).
    nperseg, noverlap
        Welch segmentation; the bin spacing is ``fs / nperseg``.

    Returns
    -------
    freqs
        Bin frequencies, Hz.
    log_psd
        ``log10`` PSD per run and channel.
    log_variance
        Variance of each run's ``log10`` PSD estimate (:func:`log10_psd_variance` of
        :func:`welch_dof`).

    Raises
    ------
    ValueError
        When a run's window holds no complete segment (name the run; shorten ``nperseg``).
    """
    x = np.asarray(signals, dtype=float)
    if x.ndim != 3:
        raise ValueError(f"signals must have dims (run, channel, time), got shape {x.shape}")
    t0 = np.broadcast_to(np.asarray(t_start, dtype=float), x.shape[:1])
    t1 = np.broadcast_to(np.asarray(t_stop, dtype=float), x.shape[:1])
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
    freqs, psd = welch_psd(
        jnp.asarray(x),
        fs,
        nperseg=nperseg,
        noverlap=noverlap,
        segment_weights=jnp.asarray(weights[:, None]),
    )
    dof = np.array([welch_dof(int(c), nperseg, noverlap) for c in counts])
    return np.asarray(freqs), np.asarray(log_psd(psd)), log10_psd_variance(dof)


def dof_from_log10_variance(
    variance: float | Float[np.ndarray, "*batch"],
) -> Float[np.ndarray, "*batch"]:
    """The degrees of freedom whose ``log10`` chi-square variance is ``variance``.

    The inverse of :func:`log10_psd_variance` (trigamma decreases monotonically), by Newton
    iterations on ``ln(nu)`` from the large-``nu`` approximation ``psi'(nu / 2) ~ 2 / nu``.

    Raises
    ------
    ValueError
        For a non-positive or non-finite variance.
    """
    v = np.asarray(variance, dtype=float) * np.log(10.0) ** 2
    if not np.all(np.isfinite(v) & (v > 0)):
        raise ValueError(f"variance must be positive and finite, got {variance!r}")
    log_nu = np.log(2.0 / v + 1.0)
    for _ in range(60):
        nu = np.exp(log_nu)
        f = scipy.special.polygamma(1, nu / 2.0) - v
        slope = scipy.special.polygamma(2, nu / 2.0) * nu / 2.0
        log_nu = log_nu - np.clip(f / slope, -2.0, 2.0)
    return np.exp(log_nu)


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
