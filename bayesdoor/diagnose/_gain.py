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

The held-out judgement of one extension against the base model asks a narrower question:
where the extension predicts something different, does it predict better? Its scatter is
split by :func:`changed_bins`, the bins of each run and channel where the two models'
predictions differ (:func:`estimate_change_discrepancy`). This mask *replaces* the residual
map's for the judgement rather than joining it. Where the two models predict the same
spectrum they have the same residual, so with one scatter estimated on exactly those bins
they score the same there and the run's gain comes from the extension's bins alone, whatever
the run's misfit elsewhere (a second, unrelated feature included: it lies outside and
cancels). Inside, the mask follows the extension's whole effect: a broad refitted mode's
skirts, and a tone that tracks the speed, in its own bin in each run. A residual-map mask
joined to it would put an unrelated feature's error into the extension's bins, for both
models alike, and dilute the comparison there. Inside, the scatter is local in frequency where
training runs were changed near the same bins (a fixed-frequency effect: the residual map's
local variance again) and one value per channel where none were (a tracking tone in a
held-out run at a frequency no training run's tone reached).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import scipy.ndimage

from .._types import Bool, Float
from ._residual import FREQUENCY, ResidualMap, smooth_discrepancy

#: the rule keeps the false-alarm rate of ``t > DECISIVE_SE`` (``t`` the sum of the per-run
#: differences over its standard error) under normal noise: it is the union of ``t`` and the
#: capped statistic (:func:`capped_t`), each over its threshold (:func:`rule_thresholds`)
DECISIVE_SE = 4.0
#: ``T_n`` with ``P(capped_t > T_n) = P(t_{n-1} > 4)`` for ``n`` normal per-run differences,
#: from 2,000,000 seeded draws per ``n`` (Monte Carlo standard errors 0.014-0.036): made by
#: ``python scripts/decision_rule.py --thresholds`` (results/decision_rule.md); each value is
#: the largest estimate at that many runs or more, so that the table never rises with ``n``
#: through the Monte Carlo scatter (a stricter value at 2, 21, 26-28, 30-34 and 37-39 runs).
#: More runs than the table holds use its last value
CAPPED_THRESHOLDS: dict[int, float] = {
    2: 10.355,
    3: 10.355,
    4: 7.693,
    5: 7.487,
    6: 6.618,
    7: 6.273,
    8: 5.926,
    9: 5.568,
    10: 5.388,
    11: 5.154,
    12: 4.961,
    13: 4.888,
    14: 4.695,
    15: 4.594,
    16: 4.508,
    17: 4.434,
    18: 4.383,
    19: 4.349,
    20: 4.283,
    21: 4.261,
    22: 4.261,
    23: 4.220,
    24: 4.201,
    25: 4.159,
    26: 4.157,
    27: 4.157,
    28: 4.157,
    29: 4.157,
    30: 4.129,
    31: 4.129,
    32: 4.129,
    33: 4.129,
    34: 4.129,
    35: 4.129,
    36: 4.082,
    37: 4.080,
    38: 4.080,
    39: 4.080,
    40: 4.080,
}
#: ``k_n`` with ``P(t > 4 k_n or capped_t > T_n k_n) = P(t_{n-1} > 4)`` for ``n`` normal per-run
#: differences (``T_n`` of :data:`CAPPED_THRESHOLDS`): the union of the plain test (most power when
#: the runs gain alike) and the capped one (when a few runs gain much more) at the plain test's
#: false-alarm rate. From 1,000,000 seeded draws per ``n`` (the first half of those of
#: ``CAPPED_THRESHOLDS``): ``python scripts/decision_rule.py --union --draws 100000`` (Monte Carlo
#: standard errors 0.003-0.011); each value is the largest estimate at that many runs or more, and
#: at least 1, so that neither threshold rises with ``n`` through the scatter nor falls under the
#: plain rule's (stricter than the estimate at 2, 4, 12, 14, 18-21, 23 and 25-39 runs). More runs
#: than the table holds use its last value
UNION_SCALE: dict[int, float] = {
    2: 1.3568,
    3: 1.3568,
    4: 1.1797,
    5: 1.1797,
    6: 1.1178,
    7: 1.1062,
    8: 1.0963,
    9: 1.0787,
    10: 1.0761,
    11: 1.0667,
    12: 1.0549,
    13: 1.0549,
    14: 1.0454,
    15: 1.0454,
    16: 1.0398,
    17: 1.0317,
    18: 1.0285,
    19: 1.0285,
    20: 1.0285,
    21: 1.0285,
    22: 1.0285,
    23: 1.0213,
    24: 1.0213,
    25: 1.0202,
    26: 1.0202,
    27: 1.0202,
    28: 1.0202,
    29: 1.0202,
    30: 1.0181,
    31: 1.0181,
    32: 1.0181,
    33: 1.0181,
    34: 1.0181,
    35: 1.0181,
    36: 1.0181,
    37: 1.0181,
    38: 1.0181,
    39: 1.0181,
    40: 1.0181,
}
#: smallest discrepancy scale per channel, decades (keeps a perfect fit's density finite)
SIGMA_FLOOR = 0.01
#: bins on either side of a residual feature that get the local variance, and the half-width of
#: the running mean that estimates it: the Hann window's main lobe (1 Hz bins, ``nperseg =
#: fs``) spreads a line over two bins on either side of its own, so a feature's error reaches
#: two bins past the significant ones
LOCAL_BINS = 2
#: the two models' predictions differ in a bin when their log10 spectra differ there by more
#: than this fraction of the run's Welch standard deviation: a bin where they differ by less
#: carries an expected log-density difference under ``fraction^2 / 2 = 1/32`` nats for the
#: true model, too little for one bin to tell the models apart (a statement about one bin; many
#: such bins still add up, and stay in the per-channel part, where both models score alike)
CHANGE_FRACTION = 0.25
#: the decision rule, in words (reported with every diagnosis)
RULE = (
    "an extension is confirmed when, on held-out runs, its log predictive density exceeds the "
    "base model's by more standard errors (of the sum of the per-run differences) than chance "
    f"gives at the rate of {DECISIVE_SE:g} standard errors under normal noise, judged two ways "
    "at once: as it is, and with the gains of the runs above the median capped at the level "
    "most favourable to it (so that one run gaining much more does not sink it); either passing "
    "its threshold suffices (at 12 runs 4.20 and 5.21 standard errors), and its J is lower; the "
    "verdict is the confirmed extension whose signature matched the residual features best "
    "(then the one with the largest gain), else none"
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
        feature bins it was estimated with; per run too when the bins it is local in differ
        between runs (:meth:`ChangeDiscrepancy.at`).
    """

    smooth: Float[np.ndarray, "channel freq"]
    variance: Float[np.ndarray, "*run channel freq"]


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


def changed_bins(
    base: Float[np.ndarray, "run channel freq"],
    extended: Float[np.ndarray, "run channel freq"],
    log_variance: Float[np.ndarray, " run"],
    *,
    fraction: float = CHANGE_FRACTION,
    margin: int = LOCAL_BINS,
) -> Bool[np.ndarray, "run channel freq"]:
    """The bins of each run and channel where an extension changes the base model's prediction.

    A bin is marked where the two models' log10 spectra differ by more than ``fraction`` of
    the run's Welch standard deviation, then widened by ``margin`` bins on either side (the
    Hann window's main lobe spreads a line over two bins either side of its own, so the
    change a narrow effect makes reaches past its marked bins by that much). Only the two
    predictions enter, never a measured spectrum, and the mask is the same for both models of
    the comparison: neither chooses where it is judged. Per run, so that a tone which tracks
    the speed is marked at its own bin in every run; the whole change, so that a broad mode's
    skirts are marked with its peak.

    Parameters
    ----------
    base, extended
        log10 spectra of the two models for the same runs.
    log_variance
        Welch variance of each run's log10 estimate.
    fraction
        The change that counts, in Welch standard deviations (> 0).
    margin
        Bins added on either side.

    Returns
    -------
    mask
        Per run, channel and bin, whether the extension changes the prediction there.

    Raises
    ------
    ValueError
        For a ``fraction`` that is not positive, a negative ``margin``, or spectra whose shapes
        differ or do not match ``log_variance``.
    """
    if not np.isfinite(fraction) or fraction <= 0:
        raise ValueError(
            f"fraction must be a positive number of Welch standard deviations, got {fraction!r}"
        )
    if isinstance(margin, bool) or int(margin) != margin or margin < 0:
        raise ValueError(f"margin must be an integer >= 0 (bins), got {margin!r}")
    a, b = np.asarray(base, dtype=float), np.asarray(extended, dtype=float)
    lv = np.asarray(log_variance, dtype=float)
    if a.shape != b.shape or a.ndim != 3 or lv.shape != a.shape[:1]:
        raise ValueError(
            f"base {a.shape} and extended {b.shape} must both be (run, channel, freq) and "
            f"log_variance {lv.shape} (run,) of the same runs"
        )
    mask = np.abs(b - a) > fraction * np.sqrt(lv)[:, None, None]
    if margin:
        widen = np.ones((1, 1, 2 * int(margin) + 1), dtype=bool)
        mask = scipy.ndimage.binary_dilation(mask, structure=widen)
    return mask


@dataclasses.dataclass(frozen=True)
class ChangeDiscrepancy:
    """A model's discrepancy on its training runs, its scatter split by an extension's bins.

    Attributes
    ----------
    smooth
        ``delta_c(f)``, decades, added to the model's spectrum.
    changed
        The scatter in the extension's bins, decades^2, per channel and bin: local where
        training runs were changed within ``LOCAL_BINS`` of the bin, the channel's value over
        all its changed training bins elsewhere.
    unchanged
        The scatter in the other bins, decades^2, one value per channel.
    """

    smooth: Float[np.ndarray, "channel freq"]
    changed: Float[np.ndarray, "channel freq"]
    unchanged: Float[np.ndarray, " channel"]

    def at(self, mask: Bool[np.ndarray, "run channel freq"]) -> Discrepancy:
        """The discrepancy of runs whose changed bins are ``mask``."""
        m = np.asarray(mask, dtype=bool)
        if m.shape[1:] != self.changed.shape:
            raise ValueError(
                f"mask has shape {m.shape}; it must be (run, channel, freq) with (channel, "
                f"freq) = {self.changed.shape}"
            )
        return Discrepancy(
            smooth=self.smooth, variance=np.where(m, self.changed, self.unchanged[:, None])
        )


def _change_parts(
    model: np.ndarray, measured: np.ndarray, half_width: int, changed: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Smooth part, squared remaining residual, mask, and the changed and unchanged means."""
    resid = np.asarray(measured, dtype=float) - np.asarray(model, dtype=float)
    m = np.asarray(changed, dtype=bool)
    if m.shape != resid.shape:
        raise ValueError(
            f"changed has shape {m.shape}; it must be (run, channel, freq) = {resid.shape}, "
            "one flag per training run, channel and bin"
        )
    smooth = smooth_discrepancy(resid.mean(axis=0), half_width)
    square = (resid - smooth) ** 2
    n_in, n_out = m.sum(axis=(0, 2)), (~m).sum(axis=(0, 2))
    s_in, s_out = (square * m).sum(axis=(0, 2)), (square * ~m).sum(axis=(0, 2))
    inside = np.where(n_in > 0, s_in / np.maximum(n_in, 1), s_out / np.maximum(n_out, 1))
    outside = np.where(n_out > 0, s_out / np.maximum(n_out, 1), inside)
    return smooth, square, m, inside, outside


def estimate_change_discrepancy(
    model: Float[np.ndarray, "run channel freq"],
    measured: Float[np.ndarray, "run channel freq"],
    log_variance: Float[np.ndarray, " run"],
    half_width: int,
    changed: Bool[np.ndarray, "run channel freq"],
) -> ChangeDiscrepancy:
    """The smooth discrepancy and the scatter of a model on its training runs, split by the
    bins where an extension changes the prediction (:func:`changed_bins`).

    Parameters
    ----------
    model, measured
        log10 spectra of the simulated and the measured training runs.
    log_variance
        Welch variance of each measured run's log10 estimate.
    half_width
        Half-width (bins) of the running median.
    changed
        The extension's bins in each training run.

    Returns
    -------
    ChangeDiscrepancy
        ``smooth`` as :func:`estimate_discrepancy`. With ``e`` the squared remaining residual:
        ``unchanged`` the mean of ``e`` over each channel's unchanged (run, bin) pairs;
        ``changed`` at a bin the mean of ``e`` over the changed pairs within ``LOCAL_BINS`` of
        it, or, where there are none, over all the channel's changed pairs. Where a channel
        has no pair of one kind, the other kind's value. Both less the mean Welch variance,
        floored at ``SIGMA_FLOOR^2``.

    Raises
    ------
    ValueError
        For a ``changed`` mask whose shape is not that of the spectra.
    """
    smooth, square, m, inside, outside = _change_parts(model, measured, half_width, changed)
    width = 2 * LOCAL_BINS + 1
    near_sum = scipy.ndimage.uniform_filter1d((square * m).sum(axis=0), width, mode="constant")
    near_n = scipy.ndimage.uniform_filter1d(m.sum(axis=0).astype(float), width, mode="constant")
    local = np.where(near_n * width > 0.5, near_sum / np.maximum(near_n, 1e-300), inside[:, None])
    welch = np.mean(log_variance)
    return ChangeDiscrepancy(
        smooth=smooth,
        changed=np.maximum(local - welch, SIGMA_FLOOR**2),
        unchanged=np.maximum(outside - welch, SIGMA_FLOOR**2),
    )


@dataclasses.dataclass(frozen=True)
class TrackingChangeDiscrepancy:
    """A model's discrepancy on its training runs, its scatter in the changed bins of an
    extension that tracks the speed local in wavenumber
    (:func:`estimate_tracking_change_discrepancy`).

    Attributes
    ----------
    smooth
        ``delta_c(f)``, decades, added to the model's spectrum.
    unchanged
        The scatter in the unchanged bins, decades^2, one value per channel.
    everywhere
        The scatter over all of a channel's changed training pairs, decades^2: a window's
        value where it holds no changed training pair.
    square
        The training runs' squared remaining residual, decades^2 (the Welch variance not
        taken off).
    changed
        The training runs' changed bins.
    freqs
        The bins, Hz, equally spaced.
    speeds
        The training runs' speeds, m/s.
    welch
        The training runs' mean Welch variance, decades^2 (taken off the local means).
    """

    smooth: Float[np.ndarray, "channel freq"]
    unchanged: Float[np.ndarray, " channel"]
    everywhere: Float[np.ndarray, " channel"]
    square: Float[np.ndarray, "train channel freq"]
    changed: Bool[np.ndarray, "train channel freq"]
    freqs: Float[np.ndarray, " freq"]
    speeds: Float[np.ndarray, " train"]
    welch: float

    def _window(self, target: np.ndarray) -> np.ndarray:
        """Scatter over the changed training pairs within ``LOCAL_BINS`` bins of ``target``.

        ``target`` (run, train, freq) is, for each bin of each run judged, the frequency in
        each training run around which its bins are gathered; the result (run, channel,
        freq) is the mean over all training runs together, less the Welch variance, floored;
        ``everywhere`` where the window holds no changed pair.
        """
        f = self.freqs
        step = float(f[1] - f[0])
        reach = LOCAL_BINS * step + 1e-9 * step
        lo = np.searchsorted(f, target - reach, side="left")
        hi = np.searchsorted(f, target + reach, side="right")
        train = np.arange(self.square.shape[0])[None, :, None]
        zeros = np.zeros((*self.square.shape[:2], 1))

        def gather(values: np.ndarray) -> np.ndarray:
            # running sums over frequency, (channel, train, freq + 1), differenced at the
            # window's edges and summed over the training runs
            cumulative = np.concatenate([zeros, np.cumsum(values, axis=-1)], axis=-1)
            c = cumulative.transpose(1, 0, 2)
            return (c[:, train, hi] - c[:, train, lo]).sum(axis=2).transpose(1, 0, 2)

        total, n = gather(self.square * self.changed), gather(self.changed.astype(float))
        mean = np.maximum(total / np.maximum(n, 1.0) - self.welch, SIGMA_FLOOR**2)
        return np.where(n > 0.5, mean, self.everywhere[None, :, None])

    def at(
        self, mask: Bool[np.ndarray, "run channel freq"], speeds: Float[np.ndarray, " run"]
    ) -> Discrepancy:
        """The discrepancy of runs at ``speeds`` whose changed bins are ``mask``.

        A changed bin ``f`` of a run at speed ``v`` lies at wavenumber ``f / v``; in a
        training run at ``v'`` that wavenumber is the bin ``f v' / v``, and the scatter is the
        mean of the training runs' squared remaining residual over their changed bins within
        ``LOCAL_BINS`` bins of it, all training runs together.
        """
        m = np.asarray(mask, dtype=bool)
        v = np.asarray(speeds, dtype=float)
        if m.ndim != 3 or m.shape[1:] != self.square.shape[1:] or v.shape != m.shape[:1]:
            raise ValueError(
                f"mask has shape {m.shape} and speeds {v.shape}; they must be (run, channel, "
                f"freq) with (channel, freq) = {self.square.shape[1:]} and (run,)"
            )
        if np.any(~np.isfinite(v) | (v <= 0)):
            raise ValueError(f"speeds must be positive m/s, one per run; got {v.tolist()}")
        local = self._window(
            self.freqs[None, None, :] * (self.speeds[None, :, None] / v[:, None, None])
        )
        return Discrepancy(
            smooth=self.smooth, variance=np.where(m, local, self.unchanged[None, :, None])
        )


def _tracking_axes(
    freqs: Float[np.ndarray, " freq"], speeds: Float[np.ndarray, " run"], shape: tuple[int, ...]
) -> tuple[Float[np.ndarray, " freq"], Float[np.ndarray, " run"]]:
    """``freqs`` and ``speeds`` as float arrays, checked against training spectra of ``shape``
    (run, channel, freq): the bins equally spaced, one positive speed per run."""
    f = np.asarray(freqs, dtype=float)
    if f.shape != shape[-1:] or f.size < 2 or not np.allclose(np.diff(f), f[1] - f[0]):
        raise ValueError(
            f"freqs has shape {f.shape}; it must hold the {shape[-1]} equally spaced "
            "bins of the spectra, in Hz"
        )
    v = np.asarray(speeds, dtype=float)
    if v.shape != shape[:1] or np.any(~np.isfinite(v) | (v <= 0)):
        raise ValueError(
            f"speeds={v.tolist()} must be positive m/s, one per training run ({shape[0]})"
        )
    return f, v


def estimate_tracking_change_discrepancy(
    model: Float[np.ndarray, "run channel freq"],
    measured: Float[np.ndarray, "run channel freq"],
    log_variance: Float[np.ndarray, " run"],
    half_width: int,
    changed: Bool[np.ndarray, "run channel freq"],
    freqs: Float[np.ndarray, " freq"],
    speeds: Float[np.ndarray, " run"],
) -> TrackingChangeDiscrepancy:
    """As :func:`estimate_change_discrepancy`, for an extension whose effect tracks the speed:
    the scatter in its changed bins local in the order domain (``f / v``, cycles per metre)
    instead of in frequency.

    Why: a tone excited by a spatial period (a rail's wavelength, a wheel's circumference over
    a harmonic) and its harmonics lie at ``f = kappa v``, a different bin in every run. A
    model's error there, the base model's missing tone or the extension's misfit of its
    level, belongs to the wavenumber ``kappa``, not to the bin: in a training run it lies at
    ``kappa v'``. A variance local in frequency alone takes, at a held-out run's tone, the
    training runs' error at whatever lies in the same bins: at close speeds their own tones a
    bin or two away (the base model's missing tone is then judged against its own size), at
    distant speeds the spectrum between their tones; which one depends on how close the
    nearest training speed lies, so the runs' gains scatter. Gathered at the same
    wavenumber, every held-out run's tone is judged against the training runs' error at that
    tone, whatever the speeds. What it does not serve: the bins such an extension changes
    can also hold errors that stay at their frequency (a door mode the base model misplaces
    slightly, which the tone passes and excites); a window in wavenumber gathers those from
    other frequencies.

    The window is ``LOCAL_BINS`` bins of each training run's own spectrum: the Hann main lobe
    is fixed in frequency, so its width in wavenumber scales with each run's speed. At equal
    speeds it is :func:`estimate_change_discrepancy`'s window exactly. The unchanged bins
    keep one value per channel, as there: both models predict the same spectrum and score
    alike. Nothing here depends on a measured held-out spectrum: the held-out runs enter
    through their changed bins (the two models' predictions) and their speeds
    (:meth:`TrackingChangeDiscrepancy.at`).

    Parameters
    ----------
    model, measured
        log10 spectra of the simulated and the measured training runs.
    log_variance
        Welch variance of each measured run's log10 estimate.
    half_width
        Half-width (bins) of the running median.
    changed
        The extension's bins in each training run.
    freqs
        The bins, Hz, equally spaced.
    speeds
        Each training run's speed (the one the tone's frequency is proportional to), m/s.

    Returns
    -------
    TrackingChangeDiscrepancy

    Raises
    ------
    ValueError
        For a ``changed`` mask whose shape is not that of the spectra, ``freqs`` that do not
        match their bins or are not equally spaced, or speeds that are not positive, one per
        training run.
    """
    smooth, square, m, inside, outside = _change_parts(model, measured, half_width, changed)
    f, v = _tracking_axes(freqs, speeds, square.shape)
    welch = float(np.mean(log_variance))
    return TrackingChangeDiscrepancy(
        smooth=smooth,
        unchanged=np.maximum(outside - welch, SIGMA_FLOOR**2),
        everywhere=np.maximum(inside - welch, SIGMA_FLOOR**2),
        square=square,
        changed=m,
        freqs=f,
        speeds=v,
        welch=welch,
    )


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
    per_run
        The per-run differences ``d_r`` in the held-out runs' order (empty when not
        known): whether every run gains a little or a few gain much is what decides the
        standard error.
    runs
        Where each of ``per_run`` lies among the diagnosed runs (empty when not known).
    statistic, threshold
        The capped statistic (:func:`capped_t` of the per-run differences) and its threshold
        for ``n_runs`` runs (:func:`rule_thresholds`); NaN when not known.
    t_threshold
        The threshold of the plain ``elpd_difference / elpd_se`` (:func:`rule_thresholds`);
        the rule is decisive when either passes (and J is lower).
    """

    j_before: float
    j_after: float
    elpd_before: float
    elpd_after: float
    elpd_difference: float
    elpd_se: float
    n_runs: int
    decisive: bool
    per_run: tuple[float, ...] = ()
    runs: tuple[int, ...] = ()
    statistic: float = float("nan")
    threshold: float = float("nan")
    t_threshold: float = float("nan")

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
            "delta_elpd_per_run": list(self.per_run),
            "delta_elpd_runs": list(self.runs),
            "statistic": self.statistic,
            "threshold": self.threshold,
            "t_threshold": self.t_threshold,
        }

    def describe(self) -> str:
        words = (
            f"held-out ELPD {self.elpd_before:.1f} -> {self.elpd_after:.1f} "
            f"({self.elpd_difference:+.1f} +- {self.elpd_se:.1f}), J {self.j_before:.4f} -> "
            f"{self.j_after:.4f} over {self.n_runs} runs"
        )
        if self.per_run:
            d = np.asarray(self.per_run)
            words += (
                f" ({int(np.sum(d > 0))} of {d.size} gain; per run {d.min():+.1f} to "
                f"{d.max():+.1f}, median {np.median(d):+.1f})"
            )
        if np.isfinite(self.statistic):
            z = self.elpd_difference / self.elpd_se if self.elpd_se > 0 else float("inf")
            words += (
                f"; {z:.1f} SE against {self.t_threshold:.2f}, with the gains above the "
                f"median capped {self.statistic:.2f} against {self.threshold:.2f}"
            )
        return words + ": " + ("decisive" if self.decisive else "not decisive")


def _runs(d: np.ndarray) -> int:
    if d.ndim < 1 or d.shape[-1] < 2:
        raise ValueError(
            f"d has shape {d.shape}; the last axis must hold the per-run differences (at "
            "least 2 runs)"
        )
    return d.shape[-1]


def t_statistic(d: np.ndarray) -> np.ndarray:
    """The one-sample t statistic ``sum(d) / sqrt(n var(d, ddof=1))`` over the last axis.

    Alone it is the plain rule, decisive above :data:`DECISIVE_SE`; :func:`rule_passes`
    judges it together with :func:`capped_t`.

    Parameters
    ----------
    d
        Per-run differences on the last axis; any leading axes are independent samples.

    Returns
    -------
    numpy.ndarray
        One t per sample (``inf`` or ``nan`` for a sample with no spread).
    """
    d = np.asarray(d, dtype=float)
    n = _runs(d)
    with np.errstate(divide="ignore", invalid="ignore"):
        return d.sum(axis=-1) / np.sqrt(n * d.var(axis=-1, ddof=1))


def capped_t(d: np.ndarray) -> np.ndarray:
    """The closure ``T(d) = max over c >= median(d) of t(min(d, c))``, exactly.

    With the sorted values ``x_1 <= ... <= x_n`` and a cap ``c`` between ``x_k`` and
    ``x_{k+1}``, the ``k`` values below stay (sum ``A``, sum of squares ``B``) and ``m = n - k``
    become ``c``. The derivative of ``t(c)`` then has the sign of ``B - A c``, so on each
    interval the maximum lies at an end or at ``c = B / A``. The
    statistic is the largest t over those points of every interval above the median and
    the uncapped t (any cap ``c >= x_n``).

    Parameters
    ----------
    d
        Per-run differences on the last axis; any leading axes are independent samples.

    Returns
    -------
    numpy.ndarray
        One statistic per sample; at least :func:`t_statistic` of the sample.
    """
    d = np.asarray(d, dtype=float)
    n = _runs(d)
    x = np.sort(d, axis=-1)
    median = np.median(x, axis=-1)
    # sums of the uncapped values: A and B in the original scale locate the stationary cap;
    # the spread is summed about the median, so that an offset does not cancel digits
    a = np.cumsum(x, axis=-1)
    b = np.cumsum(x * x, axis=-1)
    z = x - median[..., None]
    az = np.cumsum(z, axis=-1)
    bz = np.cumsum(z * z, axis=-1)
    best = t_statistic(d)
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(1, n):
            m = n - k
            lo = np.maximum(x[..., k - 1], median)
            hi = x[..., k]
            inside = lo <= hi
            stationary = np.clip(
                np.where(a[..., k - 1] != 0, b[..., k - 1] / a[..., k - 1], lo), lo, hi
            )
            for cap in (lo, hi, stationary):
                cz = cap - median
                sz = az[..., k - 1] + m * cz
                spread = np.maximum(bz[..., k - 1] + m * cz * cz - sz * sz / n, 0.0)
                t = (sz + n * median) / np.sqrt(n / (n - 1) * spread)
                best = np.where(inside, np.fmax(best, t), best)
    return best


def capped_threshold(runs: int) -> float:
    """The threshold of :func:`capped_t` for ``runs`` held-out runs (:data:`CAPPED_THRESHOLDS`).

    Raises
    ------
    ValueError
        For fewer runs than the table holds.
    """
    if runs < min(CAPPED_THRESHOLDS):
        raise ValueError(
            f"{runs} held-out runs: the decision rule is calibrated from "
            f"{min(CAPPED_THRESHOLDS)} runs"
        )
    return CAPPED_THRESHOLDS[min(runs, max(CAPPED_THRESHOLDS))]


def rule_thresholds(runs: int) -> tuple[float, float]:
    """The rule's thresholds for ``runs`` held-out runs: ``(on t, on capped_t)``, that is
    ``(4 k_n, T_n k_n)`` (:data:`UNION_SCALE`, :data:`CAPPED_THRESHOLDS`).

    Raises
    ------
    ValueError
        For fewer runs than the tables hold.
    """
    k = UNION_SCALE[min(max(runs, min(UNION_SCALE)), max(UNION_SCALE))]
    return DECISIVE_SE * k, capped_threshold(runs) * k


def rule_passes(d: Float[np.ndarray, " run"]) -> bool:
    """Whether per-run held-out differences pass the rule's statistical part (the plain or
    the capped statistic over its threshold; :func:`compare_held_out` also needs J lower)."""
    d = np.asarray(d, dtype=float)
    if d.ndim != 1 or d.size < 2 or not np.all(np.isfinite(d)):
        return False
    on_t, on_capped = rule_thresholds(d.size)
    return bool(t_statistic(d) > on_t or capped_t(d) > on_capped)


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
    statistic = float(capped_t(d)) if np.all(np.isfinite(d)) else float("nan")
    t_threshold, threshold = rule_thresholds(d.size)
    decisive = bool(np.isfinite(diff) and rule_passes(d) and j1 < j0)
    return Gain(
        j_before=j0,
        j_after=j1,
        elpd_before=float(a.sum()),
        elpd_after=float(b.sum()),
        elpd_difference=diff,
        elpd_se=se,
        n_runs=int(d.size),
        decisive=decisive,
        per_run=tuple(float(v) for v in d),
        statistic=statistic,
        threshold=threshold,
        t_threshold=t_threshold,
    )


def held_out_evidence(gain: Gain) -> float:
    """A held-out gain in standard errors: ``elpd_difference / elpd_se`` (the plain
    statistic of the rule; ``inf`` for a positive gain without spread)."""
    if gain.elpd_se > 0:
        return float(gain.elpd_difference / gain.elpd_se)
    return float(np.sign(gain.elpd_difference) * np.inf) if gain.elpd_difference else 0.0


@dataclasses.dataclass(frozen=True)
class Contest:
    """Two confirmed causes' extended models judged against each other on the held-out runs.

    ``gain`` is the ``challenger``'s over the ``holder``'s: the decision rule applied to the
    per-run difference of their held-out densities in the bins where the two predictions
    differ (``contest``: ``judge_folds`` with the holder as the reference), so it asks which
    of the two predicts the runs neither was fitted on better, not which gains more over the
    base model.
    """

    challenger: str
    holder: str
    gain: Gain

    def to_json(self) -> dict[str, Any]:
        return {
            "challenger": self.challenger,
            "holder": self.holder,
            "evidence_se": held_out_evidence(self.gain),
            "decisive": self.gain.decisive,
            **self.gain.to_json(),
        }
