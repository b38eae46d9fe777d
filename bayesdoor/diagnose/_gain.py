"""Held-out evidence for a model extension: J and log predictive density, base against extended.

Both models are judged on the same spectra (log10 Welch PSD per run, channel and bin) of runs
they were not fitted on. Each model's predictive distribution of a run's spectrum is

    y_rcf ~ Normal(m_rcf + delta_cf, s_r^2 + sigma_cf^2)

with ``m`` the model's simulated spectrum, ``s_r^2`` the Welch variance of the run's estimate,
and the model's discrepancy estimated on the training runs: ``delta_c(f)`` its smooth part (the
running median over frequency of the training runs' mean residual, :func:`smooth_discrepancy`)
and ``sigma_c^2(f)`` the remaining scatter. The base model thus competes with an anonymous
smooth discrepancy (Kennedy and O'Hagan 2001); a named extension wins only where it predicts
what a smooth correction cannot: a resonance, a tone, a line, a leak's spectral shape.

The scatter is one value per channel, except in the bins of the fixed-frequency features
the residual map found (:func:`feature_bins`), where it is local
(:func:`estimate_discrepancy`). Why: the model's error is not one process over the band.
Where the residual map found nothing, the remaining residual is the smooth misfit of the
spectrum's shape plus estimator scatter, alike at every bin, and one value per channel pools
all of it (a leak, which changes its receiver by a fraction of a dB over the whole band, is
judged against it). In the bins of a narrow feature the model lacks (a line, a missing mode)
the error is that feature's, tens of times larger; pooled with the rest it inflated the
channel's value over the whole band, so each run's gain was mostly that run's misfit
elsewhere scaled by the extended model's smaller variance, not the feature. The feature bins
are fixed before any refit, from the residual map of all the diagnosed runs, and are the same
for the base model and every extension, so neither chooses where it is judged leniently.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import scipy.ndimage

from .._types import Bool, Float
from ._residual import FREQUENCY, ResidualMap, smooth_discrepancy

#: the ELPD difference must exceed this many of its standard errors to be decisive
DECISIVE_SE = 4.0
#: smallest discrepancy scale per channel, decades (keeps a perfect fit's density finite)
SIGMA_FLOOR = 0.01
#: bins on either side of a residual feature that get the local variance, and the half-width of
#: the running mean that estimates it: the Hann window's main lobe (1 Hz bins, ``nperseg =
#: fs``) spreads a line over two bins on either side of its own, so a feature's error reaches
#: two bins past the significant ones
LOCAL_BINS = 2
#: the decision rule, in words (reported with every diagnosis)
RULE = (
    f"an extension is confirmed when, on held-out runs, its log predictive density exceeds the "
    f"base model's by more than {DECISIVE_SE:g} standard errors (the standard error of the sum "
    "of the per-run differences) and its J is lower; the verdict is the confirmed extension "
    "with the largest gain, else none"
)


@dataclasses.dataclass(frozen=True)
class Discrepancy:
    """A model's discrepancy estimated on training runs: smooth part and remaining scatter.

    Attributes
    ----------
    smooth
        ``delta_c(f)``, decades, added to the model's spectrum.
    variance
        ``sigma_c^2(f)`` per channel and bin, decades^2: one value per channel except in the
        feature bins it was estimated with.
    """

    smooth: Float[np.ndarray, "channel freq"]
    variance: Float[np.ndarray, "channel freq"]


def feature_bins(
    residuals: ResidualMap,
    freqs: Float[np.ndarray, " freq"],
    *,
    margin: int = LOCAL_BINS,
) -> Bool[np.ndarray, "channel freq"]:
    """The bins of each channel that lie in or next to a fixed-frequency residual feature.

    Every region of the map in the frequency domain (excess or deficit) covers its extent
    widened by ``margin`` bins on both sides. Regions at fixed wavenumber (a tone that tracks
    the speed) are left out: in run ``r`` such a feature lies at ``f = kappa v_r``, a
    different bin in every run, so a variance local in frequency, estimated on training runs
    whose tones lie elsewhere, does not describe a held-out run's error at its own tone; the
    union of the runs' bins would mark bins where most runs have no feature.

    Parameters
    ----------
    residuals
        The residual map.
    freqs
        The bins to mark, Hz, equally spaced.
    margin
        Bins added on either side.

    Returns
    -------
    mask
        Per channel of ``residuals.channels`` and bin, whether it belongs to a feature.

    Raises
    ------
    ValueError
        For a negative ``margin`` or fewer than two bins.
    """
    if isinstance(margin, bool) or int(margin) != margin or margin < 0:
        raise ValueError(f"margin must be an integer >= 0 (bins), got {margin!r}")
    f = np.asarray(freqs, dtype=float)
    if f.ndim != 1 or f.size < 2:
        raise ValueError(f"freqs must hold at least two bins, got shape {f.shape}")
    pad = int(margin) * float(f[1] - f[0])
    mask = np.zeros((len(residuals.channels), f.size), dtype=bool)
    for region in residuals.regions:
        if region.domain == FREQUENCY:
            c = residuals.channels.index(region.channel)
            mask[c] |= (f >= region.low - pad) & (f <= region.high + pad)
    return mask


def estimate_discrepancy(
    model: Float[np.ndarray, "run channel freq"],
    measured: Float[np.ndarray, "run channel freq"],
    log_variance: Float[np.ndarray, " run"],
    half_width: int,
    *,
    local: Bool[np.ndarray, "channel freq"] | None = None,
) -> Discrepancy:
    """The smooth discrepancy and the remaining scatter of a model on its training runs.

    Parameters
    ----------
    model, measured
        log10 spectra of the simulated and the measured runs.
    log_variance
        Welch variance of each measured run's log10 estimate.
    half_width
        Half-width (bins) of the running median.
    local
        The bins whose scatter is local (:func:`feature_bins`); ``None``: none.

    Returns
    -------
    Discrepancy
        ``smooth`` the running median of the run-mean residual. ``variance``: the runs' mean
        squared remaining residual, averaged over the channel's bins outside ``local`` (over
        all its bins when every one is local), and in the ``local`` bins its running mean
        over ``2 LOCAL_BINS + 1`` bins; less the mean Welch variance, floored at
        ``SIGMA_FLOOR^2``.

    Raises
    ------
    ValueError
        For a ``local`` mask whose shape is not (channel, freq) of the spectra.
    """
    resid = np.asarray(measured, dtype=float) - np.asarray(model, dtype=float)
    smooth = smooth_discrepancy(resid.mean(axis=0), half_width)
    square = np.mean((resid - smooth) ** 2, axis=0)
    near = np.zeros(square.shape, dtype=bool) if local is None else np.asarray(local, dtype=bool)
    if near.shape != square.shape:
        raise ValueError(
            f"local has shape {near.shape}; it must be (channel, freq) = {square.shape}, one "
            "flag per channel and bin of the spectra"
        )
    others = np.where(near.all(axis=-1, keepdims=True), True, ~near)
    pooled = np.sum(square * others, axis=-1, keepdims=True) / np.sum(
        others, axis=-1, keepdims=True
    )
    running = scipy.ndimage.uniform_filter1d(square, 2 * LOCAL_BINS + 1, axis=-1, mode="nearest")
    excess = np.where(near, running, pooled) - np.mean(log_variance)
    return Discrepancy(smooth=smooth, variance=np.maximum(excess, SIGMA_FLOOR**2))


def log_predictive(
    model: Float[np.ndarray, "*pop run channel freq"],
    measured: Float[np.ndarray, "run channel freq"],
    log_variance: Float[np.ndarray, " run"],
    discrepancy: Discrepancy,
) -> Float[np.ndarray, "*pop run"]:
    """Log predictive density of each run's spectrum (summed over channels and bins)."""
    var = np.asarray(log_variance)[:, None, None] + discrepancy.variance
    r = np.asarray(measured) - np.asarray(model) - discrepancy.smooth
    return -0.5 * np.sum(np.log(2.0 * np.pi * var) + r**2 / var, axis=(-2, -1))


def objective_per_run(
    model: Float[np.ndarray, "*pop run channel freq"],
    measured: Float[np.ndarray, "run channel freq"],
) -> Float[np.ndarray, "*pop run"]:
    """The paper's J of each run: the sum over channels of the RMS log-spectral misfit."""
    return np.sum(np.sqrt(np.mean((np.asarray(model) - measured) ** 2, axis=-1)), axis=-1)


@dataclasses.dataclass(frozen=True)
class Gain:
    """Held-out J and log predictive density of the base and the extended model.

    Attributes
    ----------
    j_before, j_after
        Mean J over the held-out runs: the paper's objective on the diagnosis spectra, of
        each model's prediction with its smooth discrepancy (estimated on the training runs;
        without it, J of a model whose spectrum lies broadly above the measured one rises when
        a correct resonance adds power there).
    elpd_before, elpd_after
        Sum over the held-out runs of the log predictive density.
    elpd_difference, elpd_se
        ``elpd_after - elpd_before`` and its standard error, ``sqrt(n var(d_r))`` over the
        per-run differences ``d_r`` (runs are the independent units).
    n_runs
        Held-out runs.
    decisive
        Whether the rule (:data:`RULE`) is met.
    """

    j_before: float
    j_after: float
    elpd_before: float
    elpd_after: float
    elpd_difference: float
    elpd_se: float
    n_runs: int
    decisive: bool

    def to_json(self) -> dict[str, Any]:
        return {
            "j_before": self.j_before,
            "j_after": self.j_after,
            "delta_j": self.j_after - self.j_before,
            "elpd_before": self.elpd_before,
            "elpd_after": self.elpd_after,
            "delta_elpd": self.elpd_difference,
            "elpd_se": self.elpd_se,
            "held_out_runs": self.n_runs,
            "decisive": self.decisive,
        }

    def describe(self) -> str:
        return (
            f"held-out ELPD {self.elpd_before:.1f} -> {self.elpd_after:.1f} "
            f"({self.elpd_difference:+.1f} +- {self.elpd_se:.1f}), J {self.j_before:.4f} -> "
            f"{self.j_after:.4f} over {self.n_runs} runs: "
            + ("decisive" if self.decisive else "not decisive")
        )


def compare_held_out(
    lpd_before: Float[np.ndarray, " run"],
    lpd_after: Float[np.ndarray, " run"],
    j_before: Float[np.ndarray, " run"],
    j_after: Float[np.ndarray, " run"],
) -> Gain:
    """Apply the decision rule to per-run held-out densities and J of two models.

    Raises
    ------
    ValueError
        For fewer than two held-out runs or arrays of different lengths.
    """
    a, b = np.asarray(lpd_before, dtype=float), np.asarray(lpd_after, dtype=float)
    ja, jb = np.asarray(j_before, dtype=float), np.asarray(j_after, dtype=float)
    if not a.shape == b.shape == ja.shape == jb.shape or a.ndim != 1 or a.size < 2:
        raise ValueError(
            f"need one value per held-out run (at least 2) in every array; got shapes "
            f"{a.shape}, {b.shape}, {ja.shape}, {jb.shape}"
        )
    d = b - a
    diff = float(d.sum())
    se = float(np.sqrt(d.size * d.var(ddof=1)))
    j0, j1 = float(ja.mean()), float(jb.mean())
    decisive = bool(np.isfinite(diff) and diff > DECISIVE_SE * se and j1 < j0)
    return Gain(
        j_before=j0,
        j_after=j1,
        elpd_before=float(a.sum()),
        elpd_after=float(b.sum()),
        elpd_difference=diff,
        elpd_se=se,
        n_runs=int(d.size),
        decisive=decisive,
    )
