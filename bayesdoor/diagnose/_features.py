"""All residual features of a campaign in one object: the input of the signatures."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from .._types import Float
from ..features import windowed_log_psd
from ._coherence import CoherenceMap, coherence_map
from ._order import OrderSpectra, order_log_psd
from ._residual import Region, ResidualMap, ResidualSettings, residual_map
from ._rest import RestLines, rest_lines, rest_segments
from ._within import WithinRunFit, within_run_speed


@dataclasses.dataclass(frozen=True)
class Features:
    """What the data say the model gets wrong, ready for the catalogue's signatures.

    Attributes
    ----------
    residuals
        The posterior-predictive residual map of the motion spectra.
    coherence
        Measured against simulated coherence of the examined pairs (``None``: not examined).
    rest_before, rest_after
        Lines in the rest before the motion starts and after it stops (``None``: no rest).
    within_run
        Per region of ``residuals``, whether it follows the speed inside the runs (``None``:
        not examined).
    orders, orders_predictive
        Order spectra (against travelled distance) of the measured runs and of each
        predictive draw (``None``: not computed); a spatial period is a line there.
    """

    residuals: ResidualMap
    coherence: CoherenceMap | None = None
    rest_before: RestLines | None = None
    rest_after: RestLines | None = None
    within_run: tuple[WithinRunFit, ...] | None = None
    orders: OrderSpectra | None = None
    orders_predictive: tuple[OrderSpectra, ...] | None = None

    def order_excess(self) -> Float[np.ndarray, "run channel wavenumber"] | None:
        """Measured minus the draws' mean log10 order PSD per run, channel and bin."""
        if self.orders is None or not self.orders_predictive:
            return None
        draws = np.stack([p.log_psd for p in self.orders_predictive])
        return self.orders.log_psd - draws.mean(axis=0)

    def within(self, region: Region) -> WithinRunFit | None:
        """The within-run speed test of one of the residual map's regions."""
        if self.within_run is None:
            return None
        for mine, fit in zip(self.residuals.regions, self.within_run, strict=True):
            if mine is region:
                return fit
        return None

    @property
    def n_runs(self) -> int:
        return int(self.residuals.z.shape[0])

    def summary(self) -> list[str]:
        """One line per significant feature (empty when the model explains the data)."""
        out = [f"residual {r.describe()}" for r in self.residuals.regions]
        if self.coherence is not None:
            out += [
                f"coherence {p.pair[0]}-{p.pair[1]} above simulated in "
                f"{100 * p.fraction_significant:.0f} % of bins"
                for p in self.coherence.pairs
                if p.significant.any()
            ]
        for when, rest in (("before", self.rest_before), ("after", self.rest_after)):
            if rest is not None:
                out += [
                    f"line at rest {when} the motion: {line.channel} {line.frequency_hz:.2f} Hz, "
                    f"{line.level_db:.1f} dB over the floor"
                    for line in rest.unexplained()
                ]
        return out


@dataclasses.dataclass(frozen=True)
class RunMotion:
    """Each run's motion, as :func:`find_features` reads it.

    Attributes
    ----------
    t_start, t_stop
        Each run's motion window, s.
    speeds
        Each run's speed, for the wavenumber map and the speed fits (``None``: none).
    speed_profiles
        Each run's speed at every sample, for the within-run speed test of every region
        (:func:`within_run_speed`) and the order spectra (``None``: none).
    """

    t_start: Float[np.ndarray, " run"]
    t_stop: Float[np.ndarray, " run"]
    speeds: Float[np.ndarray, " run"] | None = None
    speed_profiles: Float[np.ndarray, "run time"] | None = None


@dataclasses.dataclass(frozen=True)
class FeatureSettings:
    """What :func:`find_features` examines, and how finely.

    Attributes
    ----------
    pairs
        Channel pairs whose coherence is examined (none: no coherence map).
    band
        Analysed frequency range, Hz (all three analyses).
    q
        False discovery rate of each analysis.
    smooth_discrepancy_bins
        Half-width (bins) of the smooth discrepancy taken out of the residual map
        (:func:`residual_map`); ``None``: none.
    within_run
        With speed profiles, run the within-run speed test.
    order_segment_m
        With speed profiles, compute order spectra (:func:`order_log_psd`) with segments of
        this many metres; ``None``: none.
    nperseg
        Segment of the residual map; default ``fs`` samples (1 Hz bins).
    coherence_nperseg
        Segment of the coherence; default ``fs / 4`` samples.
    rest_nperseg
        Segment of the rest spectra; default the largest power of two that fits the shortest
        rest before the motion, at most ``fs / 4``.
    """

    pairs: Sequence[tuple[str, str]] = ()
    band: tuple[float, float] | None = None
    q: float = 0.01
    smooth_discrepancy_bins: int | None = None
    within_run: bool = True
    order_segment_m: float | None = None
    nperseg: int | None = None
    coherence_nperseg: int | None = None
    rest_nperseg: int | None = None


def find_features(
    measured: Float[np.ndarray, "run channel time"],
    predictive: Float[np.ndarray, "draw run channel time"],
    fs: float,
    *,
    channels: Sequence[str],
    motion: RunMotion,
    settings: FeatureSettings = FeatureSettings(),
) -> Features:
    """Residual map, coherence and rest lines of measured runs against predictive simulations.

    The motion window ``[t_start, t_stop]`` of each run gives the spectra of the residual map
    (:func:`windowed_log_psd`, the same segmentation for measured and predictive runs) and the
    coherence (measured against the first predictive draw of the same run); the samples
    before ``t_start`` and after ``t_stop`` give the rest lines; with speed profiles, the
    short-time spectra give each region's within-run speed test.

    Parameters
    ----------
    measured
        The measured runs, sampled at ``fs`` from time 0.
    predictive
        Posterior-predictive simulations of every run (same lengths and windows).
    fs
        Sampling rate, Hz.
    channels
        Channel names.
    motion
        Each run's motion window, speed and speed profile (:class:`RunMotion`).
    settings
        The pairs, band, false discovery rate, segments and optional analyses
        (:class:`FeatureSettings`).

    Returns
    -------
    Features

    Raises
    ------
    ValueError
        For inconsistent shapes, or windows too short for the segment lengths.
    """
    x = np.asarray(measured, dtype=float)
    sims = np.asarray(predictive, dtype=float)
    if x.ndim != 3 or sims.ndim != 4 or sims.shape[1:] != x.shape:
        raise ValueError(
            f"measured must be (run, channel, time) and predictive (draw, run, channel, time) "
            f"with the same runs; got {x.shape} and {sims.shape}"
        )
    n_runs = x.shape[0]
    t0 = np.broadcast_to(np.asarray(motion.t_start, dtype=float), (n_runs,))
    t1 = np.broadcast_to(np.asarray(motion.t_stop, dtype=float), (n_runs,))
    runs = _Runs(x, sims, fs, tuple(channels), t0, t1)
    residuals = _residuals(runs, motion.speeds, settings)
    coherence = _coherence(runs, settings) if settings.pairs else None
    rest_before, rest_after = _rests(runs, settings)
    profiles = motion.speed_profiles
    within = None
    if profiles is not None and settings.within_run:
        within = within_run_speed(x, sims, fs, profiles, residuals.regions, channels)
    orders, orders_predictive = None, None
    if profiles is not None and settings.order_segment_m is not None:
        orders, *rest = (
            order_log_psd(
                s, fs, profiles, t_start=t0, t_stop=t1, segment_m=settings.order_segment_m
            )
            for s in (x, *sims)
        )
        orders_predictive = tuple(rest)
    return Features(
        residuals=residuals,
        coherence=coherence,
        rest_before=rest_before,
        rest_after=rest_after,
        within_run=within,
        orders=orders,
        orders_predictive=orders_predictive,
    )


@dataclasses.dataclass(frozen=True)
class _Runs:
    """The measured runs and their predictive draws, with the motion windows of the runs."""

    x: np.ndarray
    sims: np.ndarray
    fs: float
    channels: tuple[str, ...]
    t0: np.ndarray
    t1: np.ndarray


def _residuals(runs: _Runs, speeds: np.ndarray | None, settings: FeatureSettings) -> ResidualMap:
    """The residual map of the motion spectra (:func:`residual_map`)."""
    fs, t0, t1 = runs.fs, runs.t0, runs.t1
    nperseg = int(fs) if settings.nperseg is None else settings.nperseg
    freqs, y, log_var = windowed_log_psd(runs.x, fs, t0, t1, nperseg=nperseg)
    draws = windowed_log_psd(runs.sims, fs, t0, t1, nperseg=nperseg)[1]
    return residual_map(
        freqs,
        y,
        draws,
        log_var,
        channels=runs.channels,
        speeds=speeds,
        settings=ResidualSettings(
            band=settings.band,
            q=settings.q,
            smooth_discrepancy_bins=settings.smooth_discrepancy_bins,
        ),
    )


def _coherence(runs: _Runs, settings: FeatureSettings) -> CoherenceMap:
    """The coherence of the pairs over the motion windows, measured against the first
    predictive draw (:func:`coherence_map`)."""
    fs = runs.fs
    windows = [
        (int(np.ceil(a * fs)), int(np.floor(b * fs)) + 1)
        for a, b in zip(runs.t0, runs.t1, strict=True)
    ]
    nperseg = settings.coherence_nperseg
    return coherence_map(
        [runs.x[r, :, a:b] for r, (a, b) in enumerate(windows)],
        [runs.sims[0, r, :, a:b] for r, (a, b) in enumerate(windows)],
        fs,
        channels=runs.channels,
        pairs=settings.pairs,
        nperseg=int(fs) // 4 if nperseg is None else nperseg,
        band=settings.band,
        q=settings.q,
    )


def _rests(runs: _Runs, settings: FeatureSettings) -> tuple[RestLines | None, RestLines | None]:
    """The lines at rest before and after the motion (:func:`rest_lines`; ``None`` where no
    run's rest holds one segment)."""
    fs, t0, t1 = runs.fs, runs.t0, runs.t1
    before, after = rest_segments(runs.x, fs, t0, t1)
    split_draws = [rest_segments(s, fs, t0, t1) for s in runs.sims]
    sim_before, sim_after = [s[0] for s in split_draws], [s[1] for s in split_draws]
    rest_nperseg = settings.rest_nperseg
    if rest_nperseg is None:
        shortest = min(b.shape[-1] for b in before)
        rest_nperseg = min(int(fs) // 4, 2 ** int(np.floor(np.log2(max(shortest, 2)))))
    rests: list[RestLines | None] = []
    for meas_rest, sim_rest in ((before, sim_before), (after, sim_after)):
        if max(s.shape[-1] for s in meas_rest) < rest_nperseg:
            rests.append(None)
            continue
        rests.append(
            rest_lines(
                meas_rest,
                fs,
                channels=runs.channels,
                nperseg=rest_nperseg,
                simulated=sim_rest,
                band=settings.band,
                q=settings.q,
            )
        )
    return rests[0], rests[1]
