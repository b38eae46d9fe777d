"""A harmonic comb in the order domain: the matched test for a periodic source on a rotating part.

An out-of-round wheel of radius ``R`` repeats once per revolution, every ``2 pi R`` metres of
travel: its tones lie at the wavenumbers ``k / (2 pi R)`` (cycles per metre), ``k = 1, 2, ...``,
whatever the speed. In the order spectra (runs resampled against travelled distance,
:func:`order_log_psd`) they are lines at fixed bins in every part of every run, so the excess
of the measured over the simulated order spectra can be averaged over runs and channels at the
comb's bins, where a time spectrum smears them over the bins the speed sweeps through.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import scipy.stats

from .._types import Float
from ._order import OrderSpectra
from ._residual import smooth_discrepancy

#: the local baseline of the excess is its running median over this many cycles per metre on
#: either side (wide against the Hann main lobe, 2 / segment, so one line barely moves it)
BASELINE_HALF_WIDTH = 8.0
#: a harmonic's line must peak within this fraction of a resolution bin (1 / segment) of the
#: comb's wavenumber (a line 1.4 bins off, as a rail tone next to a wheel harmonic, is not on it)
PEAK_TOLERANCE_BINS = 0.25


@dataclasses.dataclass(frozen=True)
class CombTest:
    """The comb's evidence harmonic by harmonic, and whether the comb is there.

    Attributes
    ----------
    wavenumbers
        The comb's wavenumbers ``k / period``, cycles per metre.
    harmonics
        ``k`` of each.
    excess
        Mean over runs and channels of the measured minus the simulated log10 order PSD at
        each harmonic, less its local baseline (decades).
    sd
        Its standard deviation under the model (the spread of the same statistic off the
        comb; the Welch-chi-square value where that spread is zero or has no bins).
    z
        ``excess / sd``.
    peak
        The nearest local maximum of the mean excess to each harmonic, cycles per metre
        (parabola-refined; NaN when none lies within a resolution bin).
    on_comb
        Whether that peak lies within ``PEAK_TOLERANCE_BINS`` of the harmonic.
    threshold
        One-sided critical ``z`` of each harmonic: level ``alpha`` shared by the harmonics
        tested (Bonferroni).
    present
        ``z > threshold`` and on the comb.
    min_harmonics
        Present harmonics needed for the comb (one line alone may be a rail tone).
    """

    wavenumbers: Float[np.ndarray, " harmonic"]
    harmonics: tuple[int, ...]
    excess: Float[np.ndarray, " harmonic"]
    sd: Float[np.ndarray, " harmonic"]
    z: Float[np.ndarray, " harmonic"]
    peak: Float[np.ndarray, " harmonic"]
    on_comb: np.ndarray
    threshold: float
    present: np.ndarray
    min_harmonics: int

    @property
    def significant(self) -> bool:
        """Whether at least ``min_harmonics`` harmonics are present."""
        return int(self.present.sum()) >= self.min_harmonics

    @property
    def found(self) -> tuple[int, ...]:
        """The present harmonics."""
        return tuple(k for k, p in zip(self.harmonics, self.present, strict=True) if p)

    def describe(self) -> str:
        parts = [
            f"k={k}: {10 * e:+.1f} dB, z={z:.1f}" + ("" if on else " (off the comb)")
            for k, e, z, on in zip(self.harmonics, self.excess, self.z, self.on_comb, strict=True)
        ]
        return (
            f"comb of {len(self.found)} harmonics (need {self.min_harmonics}, z > "
            f"{self.threshold:.2f}): " + "; ".join(parts)
        )


def _local_peak(mean: np.ndarray, kappa: np.ndarray, target: float, reach: float) -> float:
    inside = np.flatnonzero(np.abs(kappa - target) <= reach)
    inside = inside[(inside > 0) & (inside < len(kappa) - 1)]
    tops = [i for i in inside if mean[i] >= mean[i - 1] and mean[i] >= mean[i + 1]]
    if not tops:
        return float("nan")
    i = min(tops, key=lambda j: abs(kappa[j] - target))
    a, b, c = mean[i - 1], mean[i], mean[i + 1]
    denom = a - 2.0 * b + c
    offset = 0.5 * (a - c) / denom if denom < 0 else 0.0
    return float(kappa[i] + offset * (kappa[1] - kappa[0]))


def harmonic_comb(
    measured: OrderSpectra,
    predictive: Sequence[OrderSpectra],
    period_m: float,
    harmonics: Sequence[int],
    *,
    alpha: float = 0.01,
    min_harmonics: int = 2,
) -> CombTest:
    """Test a comb of lines at ``k / period_m`` cycles per metre in the order spectra.

    The excess ``e = y - mean_d y_d`` (measured log10 order PSD against the predictive draws'
    mean) is averaged over runs and channels; a running median over ``BASELINE_HALF_WIDTH``
    cycles per metre either side is taken out (the model's smooth misfit, as in the residual
    map). Its value at each harmonic is tested one-sided against its standard deviation under
    the model: the empirical one below, or the Welch value where the empirical one is zero or
    has no bins to be measured on

    - the Welch value: each run's ``e`` has variance ``v_r (1 + 1 / D)`` (``v_r`` the
      log10 variance of the run's Welch estimate, a scaled chi-square, ``D`` draws); the
      channels see the same vibration, so they are taken as fully correlated (their mean has
      the variance of one), the runs as independent: ``sqrt(sum_r v_r (1 + 1/D)) / R``;
    - the empirical one: 1.4826 times the median absolute deviation of the same statistic at
      the bins farther than one resolution bin from every harmonic (what the model's own
      misfit and the channels' true correlation make of it).

    A harmonic is *present* when its ``z`` exceeds the one-sided ``alpha / len(harmonics)``
    point of the normal (Bonferroni over the harmonics tested) and the mean excess peaks
    within ``PEAK_TOLERANCE_BINS`` resolution bins of it.

    Parameters
    ----------
    measured
        Order spectra of the measured runs.
    predictive
        Order spectra of each predictive draw (the same grid).
    period_m
        Travel per revolution (``2 pi R`` for a wheel), m.
    harmonics
        The ``k`` tested.
    alpha
        Family-wise level over the harmonics.
    min_harmonics
        Present harmonics needed for :attr:`CombTest.significant`.

    Returns
    -------
    CombTest

    Raises
    ------
    ValueError
        For no draws, a non-positive period or harmonic, grids that differ, or ``alpha``
        outside (0, 1).
    """
    harmonics = _checked_harmonics(predictive, period_m, harmonics, alpha)
    kappa = np.asarray(measured.wavenumbers, dtype=float)
    excess = _excess(measured, predictive, kappa)
    resolution = 1.0 / measured.segment_m
    comb = np.array([k / period_m for k in harmonics], dtype=float)
    at = np.interp(comb, kappa, excess)
    sd = _null_sd(excess, kappa, comb, resolution, measured.log_variance, len(predictive))
    z = at / sd
    peak = np.array([_local_peak(excess, kappa, c, resolution) for c in comb])
    on = np.abs(peak - comb) <= PEAK_TOLERANCE_BINS * resolution
    threshold = float(scipy.stats.norm.isf(alpha / len(comb)))
    return CombTest(
        wavenumbers=comb,
        harmonics=tuple(int(k) for k in harmonics),
        excess=at,
        sd=sd,
        z=z,
        peak=peak,
        on_comb=on,
        threshold=threshold,
        present=(z > threshold) & on,
        min_harmonics=int(min_harmonics),
    )


def _checked_harmonics(
    predictive: Sequence[OrderSpectra], period_m: float, harmonics: Sequence[int], alpha: float
) -> tuple[int, ...]:
    """The harmonics as integers, after checking the draws, period, harmonics and alpha."""
    if not predictive:
        raise ValueError("predictive must hold the order spectra of at least one draw")
    harmonics = tuple(int(k) for k in harmonics)
    if not period_m > 0 or not harmonics or min(harmonics) < 1:
        raise ValueError(
            f"period_m={period_m!r} must be positive and harmonics={tuple(harmonics)!r} "
            "non-empty integers >= 1"
        )
    if not 0 < alpha < 1:
        raise ValueError(f"alpha={alpha!r} must lie in (0, 1)")
    return harmonics


def _excess(
    measured: OrderSpectra, predictive: Sequence[OrderSpectra], kappa: np.ndarray
) -> np.ndarray:
    """Measured less the draws' mean log10 order PSD, averaged over runs and channels, less
    its running-median baseline."""
    if any(p.log_psd.shape != measured.log_psd.shape for p in predictive):
        raise ValueError("the predictive order spectra must share the measured runs' grid")
    draws = np.stack([p.log_psd for p in predictive])
    excess = (measured.log_psd - draws.mean(axis=0)).mean(axis=(0, 1))
    step = float(kappa[1] - kappa[0])
    return excess - smooth_discrepancy(excess[None, :], round(BASELINE_HALF_WIDTH / step))[0]


def _null_sd(
    excess: np.ndarray,
    kappa: np.ndarray,
    comb: np.ndarray,
    resolution: float,
    log_variance: np.ndarray,
    n_draws: int,
) -> np.ndarray:
    """The excess's standard deviation under the model at each harmonic: its spread off the
    comb, the Welch value where that spread is zero."""
    v = np.asarray(log_variance, dtype=float)
    n_runs = v.size
    welch_sd = float(np.sqrt(np.sum(v * (1.0 + 1.0 / n_draws))) / n_runs)
    usable = (kappa >= resolution) & (kappa <= 2.0 * comb.max() + resolution)
    off = usable & np.all(np.abs(kappa[:, None] - comb[None, :]) > resolution, axis=1)
    values = excess[off]
    empirical = float(1.4826 * np.median(np.abs(values - np.median(values)))) if values.size else 0
    return np.full(comb.shape, empirical if empirical > 0 else welch_sd)
