"""Order tracking: spectra against travelled distance, where a spatial period is a sharp line.

A tone excited by a spatial period (a wheel revolution, a rail wavelength) lies at
``f = v(t) / wavelength``: it sweeps while the drive accelerates and brakes, so the spectrum of
a run in time smears it below its cruise frequency. Resampled at uniform steps of travelled
distance, the same tone is a line at the wavenumber ``1 / wavelength`` (cycles per metre) in
every part of every run, whatever the speed profile.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.signal

from .._types import Float
from ..features import (
    WelchOptions,
    log10_psd_variance,
    welch_dof,
    welch_psd,
    welch_segment_count,
)

#: the resampled span is where the speed is at least this fraction of the run's peak speed
MOVING_FRACTION = 0.2
#: zero-padding factor of the order spectra (a finer grid for locating peaks)
PADDING = 4


@dataclasses.dataclass(frozen=True)
class OrderSpectra:
    """Welch spectra of runs resampled at uniform travelled distance.

    Attributes
    ----------
    wavenumbers
        The bins, cycles per metre (the same grid for every run).
    log_psd
        log10 PSD per run, channel and wavenumber bin.
    log_variance
        Welch variance of each run's log10 estimate.
    segment_m
        Segment length, m (the resolution is ``1 / segment_m``).
    travel_m
        Distance resampled per run, m.
    """

    wavenumbers: Float[np.ndarray, " wavenumber"]
    log_psd: Float[np.ndarray, "run channel wavenumber"]
    log_variance: Float[np.ndarray, " run"]
    segment_m: float
    travel_m: Float[np.ndarray, " run"]


def travelled_distance(speed: Float[np.ndarray, "... time"], fs: float) -> np.ndarray:
    """Distance travelled from the first sample, m: the speed (m/s, sampled at ``fs``)
    integrated by trapezoids along its last axis."""
    v = np.asarray(speed, dtype=float)
    steps = np.cumsum(0.5 * (v[..., 1:] + v[..., :-1]) / fs, axis=-1)
    return np.concatenate([np.zeros((*v.shape[:-1], 1)), steps], axis=-1)


@dataclasses.dataclass(frozen=True)
class _Resampling:
    """How a run is resampled and analysed: its sampling rate (Hz), the step of travelled
    distance (m) and the Welch segment (resampled points)."""

    fs: float
    step: float
    nperseg: int


def _run_order_psd(
    low: Float[np.ndarray, "channel time"],
    speed: Float[np.ndarray, " time"],
    moving: np.ndarray,
    resampling: _Resampling,
    segment_m: float,
    run: int,
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """One run's wavenumbers, log10 order PSD and its Welch variance, and the distance it
    travels while ``moving`` (m)."""
    step, nperseg = resampling.step, resampling.nperseg
    distance = travelled_distance(speed, resampling.fs)
    idx = np.flatnonzero(moving)
    z0, z1 = distance[idx[0]], distance[idx[-1]]
    grid = np.arange(z0, z1, step)
    if grid.size < nperseg:
        raise ValueError(
            f"run {run} travels {z1 - z0:.3f} m while moving, shorter than segment_m="
            f"{segment_m}; use a shorter segment"
        )
    span = slice(idx[0], idx[-1] + 1)
    resampled = np.stack([np.interp(grid, distance[span], c[span]) for c in low])
    wavenumbers, psd = welch_psd(
        resampled, 1.0 / step, nperseg=nperseg, options=WelchOptions(nfft=PADDING * nperseg)
    )
    n_segments = welch_segment_count(grid.size, nperseg)
    return (
        wavenumbers,
        np.log10(np.maximum(psd, 1e-300)),
        float(log10_psd_variance(welch_dof(n_segments, nperseg))),
        float(z1 - z0),
    )


def order_log_psd(
    signals: Float[np.ndarray, "run channel time"],
    fs: float,
    speed_profiles: Float[np.ndarray, "run time"],
    *,
    t_start: Float[np.ndarray, " run"],
    t_stop: Float[np.ndarray, " run"],
    segment_m: float,
    step_m: float | None = None,
) -> OrderSpectra:
    """Order spectra: each run resampled against its travelled distance, then Welch.

    The distance is the integral of the speed profile (trapezoids). The span resampled is
    the part of the motion window ``[t_start, t_stop]`` where the speed is at least
    ``MOVING_FRACTION`` of the run's peak. The signals are first low-passed (zero-phase
    Butterworth, order 8) at ``MOVING_FRACTION`` times 0.8 of the Nyquist frequency, so that
    nothing aliases at the slowest speed resampled; then interpolated linearly at steps of
    ``step_m`` (default: the fastest run's peak speed over ``fs``, at most as coarse as the
    samples) and analysed by Welch (Hann, 50 % overlap, ``segment_m`` per segment,
    zero-padded ``PADDING`` times).

    Parameters
    ----------
    signals
        The runs, sampled at ``fs`` from time 0.
    fs
        Sampling rate, Hz.
    speed_profiles
        Each run's speed at every sample (m/s).
    t_start, t_stop
        Each run's motion window, s.
    segment_m
        Welch segment, m.
    step_m
        Resampling step, m.

    Returns
    -------
    OrderSpectra

    Raises
    ------
    ValueError
        For shapes that do not match, or a run whose span is shorter than one segment.
    """
    x = np.asarray(signals, dtype=float)
    v = np.asarray(speed_profiles, dtype=float)
    if x.ndim != 3 or v.shape != (x.shape[0], x.shape[-1]):
        raise ValueError(
            f"signals must be (run, channel, time) and speed_profiles (run, time) with the same "
            f"runs and samples; got {x.shape} and {v.shape}"
        )
    n_runs = x.shape[0]
    t0 = np.broadcast_to(np.asarray(t_start, dtype=float), (n_runs,))
    t1 = np.broadcast_to(np.asarray(t_stop, dtype=float), (n_runs,))
    peak = v.max(axis=-1)
    if np.any(peak <= 0):
        raise ValueError(f"every run needs a positive speed; peak speeds {peak.tolist()}")
    step = float(peak.max() / fs) if step_m is None else float(step_m)
    resampling = _Resampling(fs, step, round(segment_m / step))
    sos = scipy.signal.butter(8, MOVING_FRACTION * 0.8, output="sos")
    low = scipy.signal.sosfiltfilt(sos, x, axis=-1)
    t = np.arange(x.shape[-1]) / fs
    psds, log_var, travel = [], [], []
    wavenumbers = np.zeros(0)
    for r in range(n_runs):
        moving = (t >= t0[r]) & (t <= t1[r]) & (v[r] >= MOVING_FRACTION * peak[r])
        wavenumbers, psd, variance, distance = _run_order_psd(
            low[r], v[r], moving, resampling, segment_m, r
        )
        psds.append(psd)
        log_var.append(variance)
        travel.append(distance)
    return OrderSpectra(
        wavenumbers=wavenumbers,
        log_psd=np.stack(psds),
        log_variance=np.array(log_var),
        segment_m=float(resampling.nperseg * step),
        travel_m=np.array(travel),
    )


def order_peak(
    excess: Float[np.ndarray, "run wavenumber"],
    wavenumbers: Float[np.ndarray, " wavenumber"],
    guess: float,
    rel_window: float,
) -> tuple[float, float]:
    """Where a line lies in the order domain near ``guess``, and its standard error.

    The run-averaged excess (dB-like, log10) is searched within ``guess`` times
    ``1 -+ rel_window`` for its largest local maximum, refined by a parabola through it and
    its neighbours; the standard error is the spread of each run's own refined peak in the
    same window over the square root of the number of runs (NaN with fewer than 3 runs with a
    peak). NaN when the window holds no local maximum.
    """
    k = np.asarray(wavenumbers, dtype=float)
    inside = np.flatnonzero(np.abs(k / guess - 1.0) <= rel_window)
    inside = inside[(inside > 0) & (inside < len(k) - 1)]

    def peak(total: np.ndarray) -> float:
        tops = [i for i in inside if total[i] >= total[i - 1] and total[i] >= total[i + 1]]
        if not tops:
            return float("nan")
        i = max(tops, key=lambda j: total[j])
        a, b, c = total[i - 1], total[i], total[i + 1]
        denom = a - 2.0 * b + c
        offset = 0.5 * (a - c) / denom if denom < 0 else 0.0
        return float(k[i] + offset * (k[1] - k[0]))

    e = np.asarray(excess, dtype=float)
    centre = peak(e.mean(axis=0))
    runs = np.array([peak(row) for row in e])
    runs = runs[np.isfinite(runs)]
    sd = float(np.std(runs, ddof=1) / np.sqrt(runs.size)) if runs.size >= 3 else float("nan")
    return centre, sd
