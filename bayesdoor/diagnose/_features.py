"""All residual features of a campaign in one object: the input of the signatures."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from .._types import Float
from ..features import windowed_log_psd
from ._coherence import CoherenceMap, coherence_map
from ._order import OrderSpectra, order_log_psd
from ._residual import Region, ResidualMap, residual_map
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


def find_features(
    measured: Float[np.ndarray, "run channel time"],
    predictive: Float[np.ndarray, "draw run channel time"],
    fs: float,
    *,
    channels: Sequence[str],
    t_start: Float[np.ndarray, " run"],
    t_stop: Float[np.ndarray, " run"],
    speeds: Float[np.ndarray, " run"] | None = None,
    speed_profiles: Float[np.ndarray, "run time"] | None = None,
    within_run: bool = True,
    order_segment_m: float | None = None,
    pairs: Sequence[tuple[str, str]] = (),
    nperseg: int | None = None,
    coherence_nperseg: int | None = None,
    rest_nperseg: int | None = None,
    band: tuple[float, float] | None = None,
    q: float = 0.01,
    smooth_discrepancy_bins: int | None = None,
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
    t_start, t_stop
        Each run's motion window, s.
    speeds
        Each run's speed, for the wavenumber map and the speed fits.
    speed_profiles
        Each run's speed at every sample, for the within-run speed test of every region
        (:func:`within_run_speed`) and the order spectra.
    within_run
        With speed profiles, run the within-run speed test.
    order_segment_m
        With speed profiles, compute order spectra (:func:`order_log_psd`) with segments of
        this many metres; ``None``: none.
    pairs
        Channel pairs whose coherence is examined (none: no coherence map).
    nperseg
        Segment of the residual map; default ``fs`` samples (1 Hz bins).
    coherence_nperseg
        Segment of the coherence; default ``fs / 4`` samples.
    rest_nperseg
        Segment of the rest spectra; default the largest power of two that fits the shortest
        rest before the motion, at most ``fs / 4``.
    band
        Analysed frequency range, Hz (all three analyses).
    q
        False discovery rate of each analysis.
    smooth_discrepancy_bins
        Half-width (bins) of the smooth discrepancy taken out of the residual map
        (:func:`residual_map`); ``None``: none.

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
    t0 = np.broadcast_to(np.asarray(t_start, dtype=float), (n_runs,))
    t1 = np.broadcast_to(np.asarray(t_stop, dtype=float), (n_runs,))
    nperseg = int(fs) if nperseg is None else nperseg
    freqs, y, log_var = windowed_log_psd(x, fs, t0, t1, nperseg=nperseg)
    draws = np.stack([windowed_log_psd(s, fs, t0, t1, nperseg=nperseg)[1] for s in sims])
    residuals = residual_map(
        freqs,
        y,
        draws,
        log_var,
        channels=channels,
        speeds=speeds,
        band=band,
        q=q,
        smooth_discrepancy_bins=smooth_discrepancy_bins,
    )
    coherence = None
    if pairs:
        windows = [
            (int(np.ceil(a * fs)), int(np.floor(b * fs)) + 1) for a, b in zip(t0, t1, strict=True)
        ]
        coherence = coherence_map(
            [x[r, :, a:b] for r, (a, b) in enumerate(windows)],
            [sims[0, r, :, a:b] for r, (a, b) in enumerate(windows)],
            fs,
            channels=channels,
            pairs=pairs,
            nperseg=int(fs) // 4 if coherence_nperseg is None else coherence_nperseg,
            band=band,
            q=q,
        )
    before, after = rest_segments(x, fs, t0, t1)
    split_draws = [rest_segments(s, fs, t0, t1) for s in sims]
    sim_before, sim_after = [s[0] for s in split_draws], [s[1] for s in split_draws]
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
                channels=channels,
                nperseg=rest_nperseg,
                simulated=sim_rest,
                band=band,
                q=q,
            )
        )
    within = None
    if speed_profiles is not None and within_run:
        within = within_run_speed(x, sims, fs, speed_profiles, residuals.regions, channels)
    orders, orders_predictive = None, None
    if speed_profiles is not None and order_segment_m is not None:
        orders, *rest = (
            order_log_psd(s, fs, speed_profiles, t_start=t0, t_stop=t1, segment_m=order_segment_m)
            for s in (x, *sims)
        )
        orders_predictive = tuple(rest)
    return Features(
        residuals=residuals,
        coherence=coherence,
        rest_before=rests[0],
        rest_after=rests[1],
        within_run=within,
        orders=orders,
        orders_predictive=orders_predictive,
    )
