"""Where the model is wrong: posterior-predictive spectral residuals, significant regions, speed."""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.ndimage
import scipy.stats

from .._types import Bool, Float
from ..features import dof_from_log10_variance, log_chi2_normal_scores
from ._stats import benjamini_hochberg, contiguous_runs, parabolic_offset

#: a run counts as affected by a region when its own standardised residual there exceeds this
#: (two-sided p of about 0.003 for one pre-located bin: a descriptor, not the tested statistic)
RUN_Z = 3.0
#: bins on either side of a run's peak whose median residual is its local background
PROMINENCE_HALF_WIDTH = 15
#: bins searched on either side of a region when locating each run's peak
SEARCH_PAD_BINS = 2
#: the rss of the losing speed model must exceed the winner's by this factor to decide
SPEED_DECISION_RATIO = 10.0
#: a region this many times stronger than the other domain's map over its span decides speed
CONTRAST_DECISION = 2.0
#: a run shows a feature when its residual reaches this at the aligned peak (one-sided p 0.023)
PRESENT_Z = 2.0
#: the smallest spread of speeds (max / min) that can tell a tracking from a fixed feature
MIN_SPEED_SPREAD = 1.15

FIXED = "fixed"
TRACKING = "tracking"
UNDETERMINED = "undetermined"
FREQUENCY = "frequency"
WAVENUMBER = "wavenumber"


@dataclasses.dataclass(frozen=True)
class RunPeaks:
    """Where a residual feature peaks in each run (NaN where the run was not searched).

    Attributes
    ----------
    frequency_hz
        Peak frequency per run, refined between bins by a parabola through the excess (dB).
    z
        The run's standardised residual at its peak bin (signed towards the feature).
    prominence
        ``z`` less the median ``z`` of the bins around the peak (``PROMINENCE_HALF_WIDTH``
        on either side, the main lobe left out): large for a peak, small inside a broadband
        excess.
    excess_db
        Measured minus predicted ``10 log10`` PSD at the peak bin.
    power
        Excess band power ``sum (10^y - 10^mu) df`` over the peak bin and its two neighbours
        on either side (the main lobe of a Hann-windowed tone), in signal units squared.
    affected
        Whether both ``z`` and ``prominence`` reach ``RUN_Z``: the run has a peak there. A run
        whose largest value in the window sits on the window's edge, below its outer
        neighbour, has its peak outside and is not searched (NaN).
    """

    frequency_hz: Float[np.ndarray, " run"]
    z: Float[np.ndarray, " run"]
    prominence: Float[np.ndarray, " run"]
    excess_db: Float[np.ndarray, " run"]
    power: Float[np.ndarray, " run"]
    affected: Bool[np.ndarray, " run"]


@dataclasses.dataclass(frozen=True)
class SpeedFit:
    """``f = c`` (fixed) against ``f = a v`` (tracking) over the affected runs' peaks.

    Both models are fitted by least squares in ``ln f`` (one parameter each, so their residual
    sums compare directly) to the peaks of the affected runs. A run's peak is searched where
    the region's own domain puts it, which would favour that domain's model for a feature
    without a real peak (a broadband excess fills any window); hence a run counts only with a
    prominent local maximum inside the window (see :class:`RunPeaks`), and a window-free check
    counts the runs that are "lit" (standardised residual at least ``RUN_Z`` within one bin)
    at each model's predicted frequencies, among the runs where the two predictions lie more
    than two bins apart (the others cannot tell).

    The preferred model is the one whose residual sum is at least ``SPEED_DECISION_RATIO``
    times smaller, provided the loser's RMS in ``ln f`` exceeds half the relative bin width
    (otherwise the data cannot tell them apart) and the loser lights no more runs than the
    winner. Runs lying more than 1.5 bins off the better line are dropped first, one at a
    time while more than three remain (a neighbouring feature's peak in the window). With
    fewer than three affected runs, speeds spread by less than
    ``MIN_SPEED_SPREAD``, or peaks that do not decide, the domain contrast does: a region whose
    combined statistic is at least ``CONTRAST_DECISION`` times the other domain's largest
    over the same span belongs to its own domain (fixed for frequency, tracking for
    wavenumber); otherwise ``undetermined``. Weak features, significant only when the runs are
    combined, are decided this way.

    Attributes
    ----------
    preferred
        ``"fixed"``, ``"tracking"`` or ``"undetermined"``.
    frequency_hz
        The fixed model's frequency ``c`` (geometric mean of the peaks).
    period
        The tracking model's ``1 / a``: the tone's period in the tracked condition's unit
        per cycle (metres of travel when the condition is a speed in m/s, revolutions when it
        is a shaft speed in rev/s).
    rss_fixed, rss_tracking
        Residual sums of squares in ``ln f`` (NaN when undetermined for lack of runs).
    n_runs
        Affected runs used.
    lit_fixed, lit_tracking
        Runs lit at ``f = c`` and at ``f = v / period``, among those that can tell.
    contrast
        The region's combined statistic over the largest one of the other domain's map where
        the region maps to (NaN without a wavenumber map): about ``R`` for a feature of
        ``R`` equally affected runs in its own domain, about 1 for a broadband excess.
    """

    preferred: str
    frequency_hz: float
    period: float
    rss_fixed: float
    rss_tracking: float
    n_runs: int
    lit_fixed: int
    lit_tracking: int
    contrast: float


@dataclasses.dataclass(frozen=True)
class Region:
    """A contiguous set of significant bins of one channel in one domain.

    Attributes
    ----------
    domain
        ``"frequency"`` (bins of fixed frequency combined over runs) or ``"wavenumber"`` (bins
        of fixed ``f / v``, cycles per metre, combined over runs).
    channel
        The channel name.
    low, high, peak
        The region's extent and the bin of largest ``|Z|``, in Hz or 1/m by domain.
    z
        The combined statistic at the peak (signed: positive for excess).
    excess_db
        Mean over runs of measured minus predicted ``10 log10`` PSD at the aligned peak.
    runs
        Each run's peak near the region.
    speed
        The speed fit over the affected runs.
    runs_present
        Runs whose own residual reaches ``PRESENT_Z`` within one bin of the region's peak
        (mapped to the run's frequency): a feature of most runs, not of one.
    centroid_hz, half_power_width_hz
        Frequency domain only (else NaN): the centroid and width of the half-power band of
        the run-averaged excess power, a resonance's frequency and bandwidth (the width
        includes the Hann main lobe, about 1.5 bins).
    """

    domain: str
    channel: str
    low: float
    high: float
    peak: float
    z: float
    excess_db: float
    runs: RunPeaks
    speed: SpeedFit
    runs_present: int
    centroid_hz: float
    half_power_width_hz: float

    @property
    def sign(self) -> int:
        return 1 if self.z > 0 else -1

    @property
    def runs_affected(self) -> tuple[int, ...]:
        return tuple(int(i) for i in np.flatnonzero(self.runs.affected))

    @property
    def frequency_hz(self) -> float:
        """Mean peak frequency over the affected runs (over all searched runs if none is)."""
        f = self.runs.frequency_hz
        use = self.runs.affected if self.runs.affected.any() else np.isfinite(f)
        return float(np.mean(f[use])) if use.any() else float("nan")

    @property
    def width_hz(self) -> float:
        return float(self.high - self.low)

    def describe(self) -> str:
        unit = "Hz" if self.domain == FREQUENCY else "1/m"
        return (
            f"{self.channel} {self.low:.4g}-{self.high:.4g} {unit} ({self.domain}), peak "
            f"{self.peak:.4g} {unit}, Z = {self.z:.1f}, {self.excess_db:+.1f} dB, "
            f"runs {list(self.runs_affected)}, speed: {self.speed.preferred}"
        )


@dataclasses.dataclass(frozen=True)
class ResidualMap:
    """Posterior-predictive residuals per run, channel and frequency, and what is significant.

    Attributes
    ----------
    freqs
        The analysed bins, Hz.
    channels
        Channel names.
    speeds
        Each run's speed (``None`` when not given).
    z
        Standardised residual per run, channel and bin.
    excess_db
        Measured minus predicted ``10 log10`` PSD per run, channel and bin.
    combined
        The combined statistic over runs at fixed frequency, per channel and bin.
    wavenumbers
        The bins (1/m) of the fixed-wavenumber combination (empty without a speed spread).
    combined_wavenumber
        The combined statistic at fixed wavenumber, per channel and wavenumber bin.
    significant, significant_wavenumber
        Bins rejected by Benjamini-Hochberg over the pooled family of both maps.
    q
        The false discovery rate.
    p_threshold
        The largest p-value rejected (0 when nothing is).
    n_tests
        The size of the tested family.
    regions
        The significant regions, strongest first, duplicates across domains removed.
    """

    freqs: Float[np.ndarray, " freq"]
    channels: tuple[str, ...]
    speeds: Float[np.ndarray, " run"] | None
    z: Float[np.ndarray, "run channel freq"]
    excess_db: Float[np.ndarray, "run channel freq"]
    combined: Float[np.ndarray, "channel freq"]
    wavenumbers: Float[np.ndarray, " wavenumber"]
    combined_wavenumber: Float[np.ndarray, "channel wavenumber"]
    significant: Bool[np.ndarray, "channel freq"]
    significant_wavenumber: Bool[np.ndarray, "channel wavenumber"]
    q: float
    p_threshold: float
    n_tests: int
    regions: tuple[Region, ...]

    @property
    def method(self) -> str:
        return "Benjamini-Hochberg"

    @property
    def resolution_hz(self) -> float:
        return float(self.freqs[1] - self.freqs[0])


def smooth_discrepancy(
    residual: Float[np.ndarray, "*batch freq"], half_width: int
) -> Float[np.ndarray, "*batch freq"]:
    """Running median over ``2 half_width + 1`` bins along the last axis (edges: nearest).

    The part of a residual that is smooth on the window's scale: a feature narrower than
    half the window (a resonance peak, a tone, a line) barely moves it, a broad misfit of the
    spectrum's shape is all of it.

    Raises
    ------
    ValueError
        For a negative ``half_width``.
    """
    if isinstance(half_width, bool) or int(half_width) != half_width or half_width < 0:
        raise ValueError(f"half_width must be an integer >= 0 (bins), got {half_width!r}")
    r = np.asarray(residual, dtype=float)
    size = (1,) * (r.ndim - 1) + (2 * int(half_width) + 1,)
    return scipy.ndimage.median_filter(r, size=size, mode="nearest")


def _combine(
    resid: np.ndarray, dev: np.ndarray, welch_share: np.ndarray
) -> Float[np.ndarray, "channel bin"]:
    """Sum of the runs' standardised residuals over the standard deviation of that sum.

    The predictive draws share their parameters across runs, so the sum's variance is the
    draws' variance of the summed deviations (which keeps those correlations) plus the
    independent Welch scatter of every run.
    """
    total = resid.sum(axis=0)
    var = welch_share.sum(axis=0)
    if dev.shape[0] > 1:
        var = var + dev.sum(axis=1).var(axis=0, ddof=1)
    return total / np.sqrt(var)


def _resample(values: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Linear interpolation along the last axis at fractional bin positions ``index``."""
    i0 = np.clip(np.floor(index).astype(int), 0, values.shape[-1] - 2)
    w = index - i0
    return values[..., i0] * (1.0 - w) + values[..., i0 + 1] * w


def _check_inputs(freqs, measured, predictive, log_variance, channels, speeds):
    f = np.asarray(freqs, dtype=float)
    y = np.asarray(measured, dtype=float)
    draws = np.asarray(predictive, dtype=float)
    if y.ndim != 3:
        raise ValueError(f"measured must have dims (run, channel, freq), got shape {y.shape}")
    if f.shape != y.shape[-1:]:
        raise ValueError(f"freqs has shape {f.shape}; measured has {y.shape[-1]} frequency bins")
    if f.size < 3 or not np.allclose(np.diff(f), f[1] - f[0], rtol=1e-9, atol=0.0):
        raise ValueError("freqs must be at least 3 equally spaced bins (a Welch grid)")
    if draws.ndim != 4 or draws.shape[1:] != y.shape:
        raise ValueError(
            f"predictive must have dims (draw, run, channel, freq) = (draw, {y.shape}), got "
            f"shape {draws.shape}: one set of predictive spectra per measured run"
        )
    var = np.asarray(log_variance, dtype=float)
    if var.ndim == 1 and var.shape[0] == y.shape[0]:
        var = var[:, None, None]
    try:
        var = np.broadcast_to(var, y.shape)
    except ValueError:
        raise ValueError(
            f"log_variance must have shape (run,) or broadcast to (run, channel, freq) = "
            f"{y.shape}, got {np.shape(log_variance)}"
        ) from None
    if not np.all(np.isfinite(var) & (var > 0)):
        raise ValueError("log_variance must be positive and finite (see log10_psd_variance)")
    if len(channels) != y.shape[1]:
        raise ValueError(f"channels names {len(channels)} channels; measured has {y.shape[1]}")
    v = None
    if speeds is not None:
        v = np.asarray(speeds, dtype=float)
        if v.shape != y.shape[:1] or not np.all(np.isfinite(v) & (v > 0)):
            raise ValueError(
                f"speeds must hold one positive speed per run ({y.shape[0]}), got {speeds!r}"
            )
    return f, y, draws, var, v


@dataclasses.dataclass(frozen=True)
class ResidualSettings:
    """What :func:`residual_map` tests, and at what rate.

    Attributes
    ----------
    band
        Only bins with ``band[0] <= f <= band[1]`` are analysed; ``None`` drops only 0 Hz and
        the Nyquist bin.
    q
        False discovery rate of the pooled family.
    smooth_discrepancy_bins
        When given, the half-width ``h`` (bins) of the model's smooth discrepancy: the running
        median over ``2 h + 1`` bins of each run's residual ``y - mean_d y_d`` is added to
        the prediction (and every draw) before anything is tested, so only features narrower
        than the window remain (a missing resonance, a tone, a line), not a smooth misfit of
        the spectrum's shape that the base model cannot follow but no catalogue cause
        explains. ``None``: no correction (the prediction as given).
    """

    band: tuple[float, float] | None = None
    q: float = 0.01
    smooth_discrepancy_bins: int | None = None


def residual_map(
    freqs: Float[np.ndarray, " freq"],
    measured: Float[np.ndarray, "run channel freq"],
    predictive: Float[np.ndarray, "draw run channel freq"],
    log_variance: Float[np.ndarray, " run"] | Float[np.ndarray, "run channel freq"],
    *,
    channels: Sequence[str],
    speeds: Float[np.ndarray, " run"] | None = None,
    settings: ResidualSettings = ResidualSettings(),
) -> ResidualMap:
    """Posterior-predictive residual map of measured log PSDs, with significant regions.

    Per run ``r``, channel and bin the standardised residual ``z`` is the normal score of
    ``y - mean_d y_d``, the measured ``log10`` PSD against the predictive band of the draws
    widened by the Welch scatter of the measured estimate: a normal spread with the draws'
    variance plus the centred ``log10`` of a chi-square with the degrees of freedom whose
    variance is ``log_variance`` (:func:`log_chi2_normal_scores`; its long lower tail would
    make ``(y - mu) / sd`` raise false deficits several times too often). Runs are combined
    (Stouffer) along two families of paths: at fixed frequency, and, when the runs' speeds
    differ, at fixed wavenumber ``f / v`` (each run's residuals interpolated to
    ``f = kappa v_r``), so that a feature that stays put and one that tracks the speed each
    line up in one of them. The variance of each combined sum keeps the
    correlation that shared posterior parameters induce between runs. Both maps are tested
    two-sided in one Benjamini-Hochberg family at rate ``q``; contiguous significant bins
    of one sign form regions (see :class:`Region` for what each records, and
    :class:`SpeedFit` for how its speed dependence is decided); a region in one domain that
    shares most of its runs' peaks with a stronger region of the other is dropped as the same
    feature.

    Parameters
    ----------
    freqs
        Equally spaced bin frequencies, Hz.
    measured
        The measured runs' ``log10`` PSDs.
    predictive
        Posterior-predictive draws of the same spectra, estimated with the same segmentation.
    log_variance
        Variance of each measured ``log10`` estimate (:func:`log10_psd_variance`), per run or
        per run, channel and bin.
    channels
        Channel names.
    speeds
        Each run's speed (for the door its peak speed ``v_max``, m/s); enables the
        wavenumber map and the speed fits.
    settings
        The band, the false discovery rate and the smooth discrepancy
        (:class:`ResidualSettings`).

    Returns
    -------
    ResidualMap

    Raises
    ------
    ValueError
        For inconsistent shapes, a non-uniform frequency grid, non-positive variances or
        speeds, or a band holding fewer than three bins.

    References
    ----------
    A. Gelman, X.-L. Meng and H. Stern (1996), posterior predictive assessment, Stat. Sinica
    6(4); Y. Benjamini and Y. Hochberg (1995), J. R. Stat. Soc. B 57(1).
    """
    f, y, draws, var, v = _check_inputs(freqs, measured, predictive, log_variance, channels, speeds)
    f, y, draws, var = _in_band(f, y, draws, var, settings.band)
    mu, z, dev, share = _standardise(y, draws, var, settings.smooth_discrepancy_bins)
    spread = v is not None and v.max() / v.min() >= MIN_SPEED_SPREAD
    bins = _Bins(f, y, mu, z, 10.0 * (y - mu), v, bool(spread), tuple(channels))
    return _tested_map(bins, dev, share, settings.q)


def _in_band(
    f: np.ndarray,
    y: np.ndarray,
    draws: np.ndarray,
    var: np.ndarray,
    band: tuple[float, float] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The grid, measured spectra, draws and variances at the band's bins (at least three)."""
    lo, hi = (f[1], f[-2]) if band is None else band
    keep = (f >= lo) & (f <= hi)
    if keep.sum() < 3:
        raise ValueError(f"band={band!r} holds {int(keep.sum())} bins of the grid; widen it")
    return f[keep], y[..., keep], draws[..., keep], var[..., keep]


def _standardise(
    y: np.ndarray, draws: np.ndarray, var: np.ndarray, smooth_bins: int | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The prediction, the standardised residuals, the draws' standardised deviations and the
    Welch share of each bin's variance (after the smooth discrepancy, when asked for)."""
    mu = draws.mean(axis=0)
    if smooth_bins is not None:
        smooth = smooth_discrepancy(y - mu, smooth_bins)
        mu, draws = mu + smooth, draws + smooth
    draw_var = draws.var(axis=0, ddof=1) if draws.shape[0] > 1 else np.zeros_like(mu)
    sigma = np.sqrt(draw_var + var)
    z = log_chi2_normal_scores(y - mu, draw_var, dof_from_log10_variance(var))
    return mu, z, (draws - mu) / sigma, var / sigma**2


def _tested_map(bins: _Bins, dev: np.ndarray, share: np.ndarray, q: float) -> ResidualMap:
    """Both domains' combined maps, tested in one family at rate ``q``, and their regions."""
    f, z = bins.f, bins.z
    combined = _combine(z, dev, share)
    kappa, combined_k = _wavenumber_map(f, z, dev, share, bins.v if bins.spread else None)
    p = 2.0 * scipy.stats.norm.sf(np.abs(np.concatenate([combined, combined_k], axis=1)))
    rejected, threshold = benjamini_hochberg(p, q)
    sig_f, sig_k = rejected[:, : f.size], rejected[:, f.size :]
    maps = {FREQUENCY: (f, combined), WAVENUMBER: (kappa, combined_k)}
    return ResidualMap(
        freqs=f,
        channels=bins.channels,
        speeds=bins.v,
        z=z,
        excess_db=bins.excess_db,
        combined=combined,
        wavenumbers=kappa,
        combined_wavenumber=combined_k,
        significant=sig_f,
        significant_wavenumber=sig_k,
        q=float(q),
        p_threshold=threshold,
        n_tests=int(np.isfinite(p).sum()),
        regions=_distinct(_regions(bins, maps, sig_f, sig_k), float(f[1] - f[0])),
    )


def _wavenumber_map(
    f: np.ndarray, z: np.ndarray, dev: np.ndarray, share: np.ndarray, v: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """The wavenumbers and the runs' combined residuals at fixed wavenumber ``f / v`` (each
    run's residuals interpolated to ``f = kappa v_r``); none without ``v`` (speeds that do
    not spread enough)."""
    if v is None:
        return np.zeros(0), np.zeros((z.shape[1], 0))
    df = float(f[1] - f[0])
    kappa = np.arange(f[0] / v.min(), f[-1] / v.max(), df / v.max())
    index = (kappa[None, :] * v[:, None] - f[0]) / df
    z_k = np.stack([_resample(z[r], index[r]) for r in range(len(v))])
    dev_k = np.stack([_resample(dev[:, r], index[r]) for r in range(len(v))], axis=1)
    share_k = np.stack([_resample(share[r], index[r]) for r in range(len(v))])
    return kappa, _combine(z_k, dev_k, share_k)


@dataclasses.dataclass(frozen=True)
class _Bins:
    """The band's bins of a residual map, which every region reads: measured and predicted
    log10 PSDs, the residuals, their excess in dB, each run's speed (``spread``: speeds that
    tell tracking from fixed) and the channel names."""

    f: np.ndarray
    y: np.ndarray
    mu: np.ndarray
    z: np.ndarray
    excess_db: np.ndarray
    v: np.ndarray | None
    spread: bool
    channels: tuple[str, ...]


#: per domain, the grid and the combined statistic (channel, bin) on it
_Maps = dict[str, tuple[np.ndarray, np.ndarray]]


def _regions(bins: _Bins, maps: _Maps, sig_f: np.ndarray, sig_k: np.ndarray) -> list[Region]:
    """Every region: per channel, domain and sign, the contiguous significant bins, split at
    deep dips (:func:`_split`)."""
    regions = []
    for c in range(len(bins.channels)):
        for domain, sig in ((FREQUENCY, sig_f[c]), (WAVENUMBER, sig_k[c])):
            stat = maps[domain][1][c]
            for sign in (1, -1):
                for span in _split(sign * stat, contiguous_runs(sig & (np.sign(stat) == sign))):
                    regions.append(_region(bins, maps, c, domain, sign, span))
    return regions


def _region(
    bins: _Bins, maps: _Maps, c: int, domain: str, sign: int, span: tuple[int, int]
) -> Region:
    """The region of channel ``c``'s bins ``span`` (first and last) of one sign in one
    domain's map."""
    f, y = bins.f, bins.y
    v: Any = bins.v  # None only without a wavenumber map, where no region reads it
    df = float(f[1] - f[0])
    a, b = span
    grid, stat = maps[domain][0], maps[domain][1][c]
    i = a + int(np.argmax(sign * stat[a : b + 1]))
    other = WAVENUMBER if domain == FREQUENCY else FREQUENCY
    scale = (1.0 / v if domain == FREQUENCY else v) if bins.spread else None
    contrast = _contrast(sign * stat[i], grid[a], grid[b], scale, *maps[other], c, sign)
    peaks = _run_peaks(bins, c, domain, grid[a], grid[b], sign)
    at = grid[i] * (v if domain == WAVENUMBER else np.ones(y.shape[0]))
    index = np.clip(np.rint((at - f[0]) / df).astype(int), 0, f.size - 1)
    centroid, width = _resonance(f, y, bins.mu, c, grid[a], grid[b], domain)
    return Region(
        domain=domain,
        channel=bins.channels[c],
        low=float(grid[a]),
        high=float(grid[b]),
        peak=float(grid[i]),
        z=float(stat[i]),
        excess_db=float(np.mean(bins.excess_db[np.arange(y.shape[0]), c, index])),
        runs=peaks,
        speed=_speed_fit(peaks, v, f, sign * bins.z[:, c], domain, contrast),
        runs_present=_present(f, sign * bins.z[:, c], at),
        centroid_hz=centroid,
        half_power_width_hz=width,
    )


def _split(values: np.ndarray, spans: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """Split each span at the deepest dip between two peaks that falls below half the lower.

    Two features whose significant bins touch (two close harmonics, say) stay two regions.
    """
    out = []
    todo = list(spans)
    while todo:
        a, b = todo.pop()
        x = values[a : b + 1]
        peaks = [
            i
            for i in range(len(x))
            if (i == 0 or x[i] >= x[i - 1]) and (i == len(x) - 1 or x[i] >= x[i + 1])
        ]
        best = None
        for p, q in itertools.pairwise(peaks):
            m = p + int(np.argmin(x[p : q + 1]))
            depth = min(x[p], x[q]) - x[m]
            if x[m] < 0.5 * min(x[p], x[q]) and (best is None or depth > best[1]):
                best = (m, depth)
        if best is None:
            out.append((a, b))
        else:
            todo += [(a, a + best[0] - 1), (a + best[0] + 1, b)] if best[0] > 0 else [(a + 1, b)]
    return sorted(out)


def _present(f: np.ndarray, signed_z: np.ndarray, at: np.ndarray) -> int:
    """Runs whose residual reaches ``PRESENT_Z`` within one bin of their aligned peak ``at``."""
    df = f[1] - f[0]
    count = 0
    for r, target in enumerate(at):
        near = np.abs(f - target) <= df
        count += bool(near.any() and np.max(signed_z[r, near]) >= PRESENT_Z)
    return count


def _contrast(strength, low, high, scale, grid, stat, c, sign) -> float:
    """The region's statistic over the other domain's largest one where the region maps to.

    ``scale`` maps this domain's values to the other's per run (``1 / v`` from frequency to
    wavenumber, ``v`` back); NaN without a wavenumber map.
    """
    if scale is None or grid.size == 0:
        return float("nan")
    inside = (grid >= low * scale.min()) & (grid <= high * scale.max())
    largest = float(np.max(sign * stat[c, inside])) if inside.any() else 0.0
    return float(strength / max(largest, 1.0))


def _resonance(f, y, mu, c, low, high, domain) -> tuple[float, float]:
    """Centroid and width of the half-power band of the run-averaged excess power.

    Only for the frequency domain (NaN otherwise): the excess PSD ``10^y - 10^mu`` averaged
    over runs, its largest bin within the region (padded), the contiguous bins around it above
    half that value, inside the padded region. The width includes the Hann window's main lobe
    (about 1.5 bins). Without any positive excess power (a deficit), the bin of the largest
    value and no width.
    """
    nan = float("nan")
    if domain != FREQUENCY:
        return nan, nan
    df = f[1] - f[0]
    excess = np.mean(10.0 ** y[:, c] - 10.0 ** mu[:, c], axis=0)
    inside = np.flatnonzero((f >= low - SEARCH_PAD_BINS * df) & (f <= high + SEARCH_PAD_BINS * df))
    m = int(inside[np.argmax(excess[inside])])
    if excess[m] <= 0:
        return float(f[m]), nan
    lo = m
    while lo > inside[0] and excess[lo - 1] >= excess[m] / 2:
        lo -= 1
    hi = m
    while hi < inside[-1] and excess[hi + 1] >= excess[m] / 2:
        hi += 1
    band = slice(lo, hi + 1)
    centroid = float(np.sum(f[band] * excess[band]) / np.sum(excess[band]))
    return centroid, float((hi - lo + 1) * df)


def _run_peaks(bins: _Bins, c: int, domain: str, low, high, sign: int) -> RunPeaks:
    """Each run's peak of ``sign z`` within the region (mapped to its frequencies), padded."""
    f, y, mu, z, excess_db = bins.f, bins.y, bins.mu, bins.z, bins.excess_db
    v: Any = bins.v  # read in the wavenumber domain only, which has speeds
    n_runs = y.shape[0]
    df = f[1] - f[0]
    keys = ("frequency_hz", "z", "prominence", "excess_db", "power")
    out = {k: np.full(n_runs, np.nan) for k in keys}
    for r in range(n_runs):
        scale = v[r] if domain == WAVENUMBER else 1.0
        inside = np.flatnonzero(
            (f >= low * scale - SEARCH_PAD_BINS * df) & (f <= high * scale + SEARCH_PAD_BINS * df)
        )
        if inside.size == 0:
            continue
        i = int(inside[np.argmax(sign * z[r, c, inside])])
        if (i > 0 and sign * z[r, c, i - 1] > sign * z[r, c, i]) or (
            i < f.size - 1 and sign * z[r, c, i + 1] > sign * z[r, c, i]
        ):
            continue  # the largest value sits on the window's edge: the run's peak lies outside
        shift = 0.0
        if 0 < i < f.size - 1:
            e = sign * excess_db[r, c, i - 1 : i + 2]
            shift = parabolic_offset(e[0], e[1], e[2])
        lobe = slice(max(i - 2, 0), i + 3)
        out["frequency_hz"][r] = f[i] + shift * df
        out["z"][r] = sign * z[r, c, i]
        around = np.r_[
            max(i - PROMINENCE_HALF_WIDTH, 0) : max(i - 2, 0),
            min(i + 3, f.size) : min(i + PROMINENCE_HALF_WIDTH + 1, f.size),
        ]
        out["prominence"][r] = sign * (z[r, c, i] - np.median(z[r, c, around]))
        out["excess_db"][r] = excess_db[r, c, i]
        out["power"][r] = float(np.sum(10.0 ** y[r, c, lobe] - 10.0 ** mu[r, c, lobe]) * df)
    affected = (np.nan_to_num(out["z"], nan=-np.inf) >= RUN_Z) & (
        np.nan_to_num(out["prominence"], nan=-np.inf) >= RUN_Z
    )
    return RunPeaks(affected=affected, **out)


def _lit(f: np.ndarray, signed_z: np.ndarray, at: np.ndarray, runs: np.ndarray) -> int:
    """How many of ``runs`` show ``signed_z >= RUN_Z`` within one bin of frequency ``at``."""
    df = f[1] - f[0]
    hits = 0
    for r in np.flatnonzero(runs):
        near = np.abs(f - at[r]) <= df
        hits += bool(near.any() and np.max(signed_z[r, near]) >= RUN_Z)
    return hits


def _drop_outliers(freq: np.ndarray, v: np.ndarray, use: np.ndarray, df: float) -> np.ndarray:
    """Drop, one at a time, the run lying farthest (over 1.5 bins) off the better line.

    A run's window can hold a neighbouring feature's peak (the next harmonic at a slow run);
    such a run sits off both lines and would hide which one fits. At least 3 runs are kept.
    """
    use = use.copy()
    while use.sum() > 3:
        log_f, log_v = np.log(freq[use]), np.log(v[use])
        fixed = np.full(log_f.shape, np.exp(log_f.mean()))
        tracking = np.exp(log_v + np.mean(log_f - log_v))
        off = [np.abs(freq[use] - fixed), np.abs(freq[use] - tracking)]
        worst = off[int(np.argmin([np.sum(o**2) for o in off]))]
        if worst.max() <= 1.5 * df:
            break
        use[np.flatnonzero(use)[int(np.argmax(worst))]] = False
    return use


def _speed_fit(
    peaks: RunPeaks, v, f: np.ndarray, signed_z: np.ndarray, domain: str, contrast: float
) -> SpeedFit:
    nan = float("nan")
    use = peaks.affected & np.isfinite(peaks.frequency_hz) & (peaks.frequency_hz > 0)
    n = int(use.sum())
    fallback = UNDETERMINED
    if np.isfinite(contrast) and contrast >= CONTRAST_DECISION:
        fallback = FIXED if domain == FREQUENCY else TRACKING
    if n == 0:
        return SpeedFit(fallback, nan, nan, nan, nan, 0, 0, 0, contrast)
    log_f = np.log(peaks.frequency_hz[use])
    c = float(np.exp(log_f.mean()))
    if v is None:
        return SpeedFit(fallback, c, nan, nan, nan, n, 0, 0, contrast)
    log_v = np.log(v[use])
    log_a = float(np.mean(log_f - log_v))
    period = float(np.exp(-log_a))
    if n < 3 or v[use].max() / v[use].min() < MIN_SPEED_SPREAD:
        return SpeedFit(fallback, c, period, nan, nan, n, 0, 0, contrast)
    use = _drop_outliers(peaks.frequency_hz, v, use, f[1] - f[0])
    n = int(use.sum())
    log_f, log_v = np.log(peaks.frequency_hz[use]), np.log(v[use])
    c = float(np.exp(log_f.mean()))
    log_a = float(np.mean(log_f - log_v))
    period = float(np.exp(-log_a))
    rss_fixed = float(np.sum((log_f - log_f.mean()) ** 2))
    rss_tracking = float(np.sum((log_f - log_v - log_a) ** 2))
    at_fixed, at_tracking = np.full(v.shape, c), v / period
    telling = np.abs(at_fixed - at_tracking) > 2.0 * (f[1] - f[0])
    lit_fixed = _lit(f, signed_z, at_fixed, telling)
    lit_tracking = _lit(f, signed_z, at_tracking, telling)
    resolvable = 0.5 * (f[1] - f[0]) / c
    preferred = fallback
    if (
        rss_tracking * SPEED_DECISION_RATIO <= rss_fixed
        and np.sqrt(rss_fixed / n) > resolvable
        and lit_fixed <= lit_tracking
    ):
        preferred = TRACKING
    elif (
        rss_fixed * SPEED_DECISION_RATIO <= rss_tracking
        and np.sqrt(rss_tracking / n) > resolvable
        and lit_tracking <= lit_fixed
    ):
        preferred = FIXED
    return SpeedFit(
        preferred, c, period, rss_fixed, rss_tracking, n, lit_fixed, lit_tracking, contrast
    )


def _distinct(regions: list[Region], df: float) -> tuple[Region, ...]:
    """Strongest first; drop a region whose affected runs mostly peak where a kept one does."""
    kept: list[Region] = []
    for region in sorted(regions, key=lambda r: -abs(r.z)):
        mine = region.runs.affected
        duplicate = False
        for other in kept:
            if other.channel != region.channel or other.sign != region.sign:
                continue
            both = mine & other.runs.affected
            close = np.abs(region.runs.frequency_hz[both] - other.runs.frequency_hz[both])
            shared = int(np.sum(close <= 1.5 * df))
            if mine.any() and shared >= max(1, int(np.ceil(mine.sum() / 2))):
                duplicate = True
                break
        if not duplicate:
            kept.append(region)
    return tuple(kept)
