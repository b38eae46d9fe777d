"""What the records contain while the system is at rest: lines above the noise floor."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import scipy.stats

from .._types import Bool, Float
from ..features import welch_dof, welch_psd, welch_segment_count
from ._stats import benjamini_hochberg, contiguous_runs, parabolic_offset

#: bins on either side of a bin whose median is its local noise floor
FLOOR_HALF_WIDTH = 10
#: bins on either side left out of the floor (the main lobe of a Hann-windowed line)
LOBE_HALF_WIDTH = 2
#: asymptotic efficiency of the median relative to the mean (2 / pi), for the floor's dof
MEDIAN_EFFICIENCY = 2.0 / np.pi
#: a measured line counts as simulated when the simulated rest PSD reaches within this (dB)
SIMULATED_WITHIN_DB = 6.0


@dataclasses.dataclass(frozen=True)
class LineAtRest:
    """A spectral line found in the rest segments.

    Attributes
    ----------
    channel
        The channel name.
    frequency_hz
        The line's frequency, refined between bins by a parabola through the log PSD.
    level_db
        PSD over the local floor at the peak bin, dB.
    power
        Line power above the floor over the main lobe (signal units squared).
    z
        The p-value of the peak bin as a standard normal quantile (for ranking).
    in_simulated
        Whether the simulated rest segments hold the line too (within
        ``SIMULATED_WITHIN_DB``); ``False`` when no simulated segments were given.
    """

    channel: str
    frequency_hz: float
    level_db: float
    power: float
    z: float
    in_simulated: bool


@dataclasses.dataclass(frozen=True)
class RestLines:
    """Rest spectra (pooled over runs), their floor and the lines above it.

    Attributes
    ----------
    channels
        Channel names.
    freqs
        Bins, Hz.
    psd, floor
        Measured pooled PSD per channel and its local floor (the running median scaled to a
        mean).
    simulated
        The largest over the draws of the simulated pooled PSD (NaN when none was given).
    dof
        Equivalent degrees of freedom of the pooled estimate.
    significant
        Bins rejected by Benjamini-Hochberg at ``q``.
    lines
        The lines, strongest first.
    q
        The false discovery rate.
    """

    channels: tuple[str, ...]
    freqs: Float[np.ndarray, " freq"]
    psd: Float[np.ndarray, "channel freq"]
    floor: Float[np.ndarray, "channel freq"]
    simulated: Float[np.ndarray, "channel freq"]
    dof: float
    significant: Bool[np.ndarray, "channel freq"]
    lines: tuple[LineAtRest, ...]
    q: float

    @property
    def resolution_hz(self) -> float:
        return float(self.freqs[1] - self.freqs[0])

    def at(self, channel: str, frequency_hz: float) -> tuple[float, float]:
        """The PSD and its floor at the bin nearest ``frequency_hz`` of ``channel``."""
        c = self.channels.index(channel)
        i = int(np.argmin(np.abs(self.freqs - frequency_hz)))
        return float(self.psd[c, i]), float(self.floor[c, i])

    def unexplained(self) -> tuple[LineAtRest, ...]:
        """The lines the simulated rest does not hold."""
        return tuple(line for line in self.lines if not line.in_simulated)

    def near(
        self, frequency_hz: float, tol_hz: float, *, explained: bool = False
    ) -> tuple[LineAtRest, ...]:
        """The unexplained lines (all lines with ``explained``) within ``tol_hz``."""
        lines = self.lines if explained else self.unexplained()
        return tuple(line for line in lines if abs(line.frequency_hz - frequency_hz) <= tol_hz)


def rest_segments(
    signals: Float[np.ndarray, "run channel time"],
    fs: float,
    t_start: Float[np.ndarray, " run"],
    t_stop: Float[np.ndarray, " run"],
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Cut each run into its rest before ``t_start`` and its rest after ``t_stop``.

    Returns
    -------
    before, after
        Per run, the ``(channel, time)`` samples at ``t < t_start`` and at ``t > t_stop``.
    """
    x = np.asarray(signals, dtype=float)
    if x.ndim != 3:
        raise ValueError(f"signals must have dims (run, channel, time), got shape {x.shape}")
    t0 = np.broadcast_to(np.asarray(t_start, dtype=float), x.shape[:1])
    t1 = np.broadcast_to(np.asarray(t_stop, dtype=float), x.shape[:1])
    before = [x[r, :, : int(np.floor(t0[r] * fs))] for r in range(x.shape[0])]
    after = [x[r, :, int(np.ceil(t1[r] * fs)) + 1 :] for r in range(x.shape[0])]
    return before, after


def _pooled_psd(segments, fs: float, nperseg: int, name: str):
    """Welch PSD pooled over runs, weighted by each run's number of segments."""
    total, count, dof, freqs = None, 0, 0.0, None
    for x in segments:
        x = np.asarray(x, dtype=float)
        if x.ndim != 2:
            raise ValueError(f"{name} must hold (channel, time) arrays, got shape {x.shape}")
        k = welch_segment_count(x.shape[-1], nperseg)
        if k < 1:
            continue
        freqs, psd = welch_psd(x, fs, nperseg=nperseg)
        total = k * psd if total is None else total + k * psd
        count += k
        dof += welch_dof(k, nperseg)
    if total is None:
        raise ValueError(
            f"no {name} segment holds nperseg={nperseg} samples: pass a smaller nperseg (the "
            "rest segments are short) or longer rest"
        )
    return freqs, total / count, dof


def _local_floor(psd: np.ndarray) -> np.ndarray:
    """Running median of the neighbours of each bin, leaving out its main lobe."""
    n = psd.shape[-1]
    out = np.empty_like(psd)
    for i in range(n):
        lo, hi = max(i - FLOOR_HALF_WIDTH, 0), min(i + FLOOR_HALF_WIDTH + 1, n)
        idx = np.r_[lo : max(i - LOBE_HALF_WIDTH, lo), min(i + LOBE_HALF_WIDTH + 1, hi) : hi]
        out[..., i] = np.median(psd[..., idx], axis=-1)
    return out


def rest_lines(
    measured: Sequence[Float[np.ndarray, "channel time"]],
    fs: float,
    *,
    channels: Sequence[str],
    nperseg: int,
    simulated: Sequence[Sequence[Float[np.ndarray, "channel time"]]] | None = None,
    band: tuple[float, float] | None = None,
    q: float = 0.01,
) -> RestLines:
    """Lines at fixed frequencies in the rest segments, above the local noise floor.

    The rest segments of all runs are pooled into one Welch PSD (each run weighted by its
    segments; degrees of freedom add over runs). Each bin is compared with the median of its
    neighbours (``FLOOR_HALF_WIDTH`` bins on either side, the main lobe left out) scaled to a
    mean: for noise, the ratio of a chi-square estimate with ``nu`` dof to an independent one
    with about ``(2 / pi) nu n_neighbours`` dof is F-distributed, which gives a one-sided
    p-value per bin. Benjamini-Hochberg at ``q`` over channels and bins; contiguous
    significant bins form one line at their peak.

    Parameters
    ----------
    measured
        Per run, the ``(channel, time)`` samples at rest (see :func:`rest_segments`).
    fs
        Sampling rate, Hz.
    channels
        Channel names.
    nperseg
        Samples per Welch segment (rest segments are short: for 0.25 s at 2048 Hz, 512).
    simulated
        Per predictive draw, the simulated rest segments of every run, to tell lines the
        model already has: a line is simulated when the largest of the draws' pooled PSDs
        reaches within ``SIMULATED_WITHIN_DB`` of the measured one at its peak (a ring-down
        after the motion varies from draw to draw).
    band
        Analysed range, Hz; ``None`` drops only 0 Hz and Nyquist.
    q
        False discovery rate.

    Returns
    -------
    RestLines

    Raises
    ------
    ValueError
        When no rest segment is long enough for ``nperseg``, or for a wrong channel count.
    """
    freqs, psd, dof = _pooled_psd(measured, fs, nperseg, "measured")
    if psd.shape[0] != len(channels):
        raise ValueError(
            f"channels names {len(channels)} channels; the segments have {psd.shape[0]}"
        )
    sim = np.full_like(psd, np.nan)
    if simulated is not None:
        draws = [_pooled_psd(runs, fs, nperseg, "simulated")[1] for runs in simulated]
        sim = np.max(draws, axis=0)
    lo, hi = (freqs[1], freqs[-2]) if band is None else band
    keep = (freqs >= lo) & (freqs <= hi)
    floor_full, ratio, p = _floor_test(psd, dof)
    p[:, ~keep] = np.nan
    rejected, _ = benjamini_hochberg(p, q)
    lines = _lines(channels, freqs, psd, floor_full, sim, ratio, p, rejected)
    return RestLines(
        channels=tuple(channels),
        freqs=freqs[keep],
        psd=psd[:, keep],
        floor=floor_full[:, keep],
        simulated=sim[:, keep],
        dof=float(dof),
        significant=rejected[:, keep],
        lines=tuple(lines),
        q=float(q),
    )


def _floor_test(psd: np.ndarray, dof: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The local floor scaled to a mean, each bin's ratio to it and its one-sided p-value."""
    median_factor = scipy.stats.chi2.median(dof) / dof
    floor_full = _local_floor(psd) / median_factor
    neighbours = 2 * (FLOOR_HALF_WIDTH - LOBE_HALF_WIDTH)
    dof_floor = MEDIAN_EFFICIENCY * dof * neighbours
    ratio = psd / floor_full
    return floor_full, ratio, scipy.stats.f.sf(ratio, dof, dof_floor)


def _lines(
    channels: Sequence[str],
    freqs: np.ndarray,
    psd: np.ndarray,
    floor: np.ndarray,
    sim: np.ndarray,
    ratio: np.ndarray,
    p: np.ndarray,
    rejected: np.ndarray,
) -> list[LineAtRest]:
    """Per channel, one line at the peak of each run of rejected bins; strongest first."""
    df = float(freqs[1] - freqs[0])
    lines = []
    for c, name in enumerate(channels):
        for a, b in contiguous_runs(rejected[c]):
            i = a + int(np.argmax(ratio[c, a : b + 1]))
            shift = 0.0
            if 0 < i < freqs.size - 1:
                lp = np.log(psd[c, i - 1 : i + 2])
                shift = parabolic_offset(lp[0], lp[1], lp[2])
            lobe = slice(max(i - LOBE_HALF_WIDTH, 0), i + LOBE_HALF_WIDTH + 1)
            in_sim = bool(sim[c, i] >= psd[c, i] * 10.0 ** (-SIMULATED_WITHIN_DB / 10.0))
            lines.append(
                LineAtRest(
                    channel=name,
                    frequency_hz=float(freqs[i] + shift * df),
                    level_db=float(10.0 * np.log10(ratio[c, i])),
                    power=float(np.sum(psd[c, lobe] - floor[c, lobe]) * df),
                    z=float(scipy.stats.norm.isf(max(p[c, i], 1e-300))),
                    in_simulated=in_sim,
                )
            )
    lines.sort(key=lambda line: -line.z)
    return lines
