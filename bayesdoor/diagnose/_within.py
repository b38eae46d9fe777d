"""Speed dependence within a run: short-time spectra against the run's speed profile."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import scipy.signal

from .._types import Float
from ..features import log10_psd_variance
from ._residual import FIXED, FREQUENCY, TRACKING, UNDETERMINED, Region

#: the within-run statistic decides at this many standard deviations
WITHIN_Z = 3.0
#: frames count only while the speed is at least this fraction of the run's peak speed
MOVING_FRACTION = 0.2
#: the two predictions must lie this many frame resolutions apart for a frame to tell
TELLING_BINS = 1.5


@dataclasses.dataclass(frozen=True)
class WithinRunFit:
    """Whether a feature follows the speed inside the runs (accelerating and braking).

    Attributes
    ----------
    preferred
        ``"tracking"``, ``"fixed"`` or ``"undetermined"``.
    z
        The standardised mean of ``e(f_tracking) - e(f_fixed)`` over the telling frames
        (positive: the feature follows the speed).
    n_frames
        Telling frames used (over all runs).
    """

    preferred: str
    z: float
    n_frames: int


def _excess_spectrogram(measured, draws, fs, nperseg, hop, nfft):
    """log10 short-time PSD of the measured run minus the draws' mean, and the frame times."""
    kw = dict(fs=fs, window="hann", nperseg=nperseg, noverlap=nperseg - hop, nfft=nfft)
    freqs, times, meas = scipy.signal.spectrogram(measured, **kw)
    sims = np.stack([scipy.signal.spectrogram(d, **kw)[2] for d in draws])
    floor = 1e-30
    excess = np.log10(np.maximum(meas, floor)) - np.mean(np.log10(np.maximum(sims, floor)), axis=0)
    return freqs, times, excess


@dataclasses.dataclass(frozen=True)
class _Frames:
    """The short-time frames: sampling rate (Hz), frame length and hop (samples)."""

    fs: float
    nperseg: int
    hop: int

    @property
    def resolution(self) -> float:
        """A frame's frequency resolution, Hz."""
        return self.fs / self.nperseg


def _frames(x: np.ndarray, v: np.ndarray, fs: float, frame_s: float, hop_s: float) -> _Frames:
    """The frames of ``frame_s`` every ``hop_s``, once the speed profiles' shape and the frame
    length are checked against the records."""
    if v.shape != (x.shape[0], x.shape[-1]):
        raise ValueError(
            f"speed_profiles must have dims (run, time) = {(x.shape[0], x.shape[-1])}, got "
            f"{v.shape}"
        )
    nperseg = round(frame_s * fs)
    hop = max(1, round(hop_s * fs))
    if not 8 <= nperseg <= x.shape[-1]:
        raise ValueError(f"frame_s={frame_s} s gives {nperseg} samples; use 8 to {x.shape[-1]}")
    return _Frames(fs, nperseg, hop)


def _telling_gaps(
    region: Region,
    f_c: float,
    v_peak: float,
    speed_profile: np.ndarray,
    spectrogram: tuple,
    frames: _Frames,
) -> list[float]:
    """One run's ``e(f_tracking) - e(f_fixed)`` over its telling frames, signed by the region."""
    freqs, times, excess = spectrogram
    starts = np.rint(times * frames.fs).astype(int) - frames.nperseg // 2
    speed = np.array([speed_profile[s : s + frames.nperseg].mean() for s in starts])
    f_track = f_c * speed / v_peak
    telling = (speed >= MOVING_FRACTION * v_peak) & (
        np.abs(f_c - f_track) >= TELLING_BINS * frames.resolution
    )
    gaps = []
    for k in np.flatnonzero(telling):
        e = excess[:, k]
        gap = np.interp(f_track[k], freqs, e) - np.interp(f_c, freqs, e)
        gaps.append(region.sign * gap)
    return gaps


def _within_fit(diffs: list[float], frames: _Frames) -> WithinRunFit:
    """The verdict from the telling frames' gaps, standardised over the independent frames."""
    if not diffs:
        return WithinRunFit(UNDETERMINED, float("nan"), 0)
    n_independent = max(1.0, len(diffs) * frames.hop / frames.nperseg)
    sd = np.sqrt(2.0 * float(log10_psd_variance(2.0)) / n_independent)
    z = float(np.mean(diffs) / sd)
    preferred = TRACKING if z >= WITHIN_Z else FIXED if z <= -WITHIN_Z else UNDETERMINED
    return WithinRunFit(preferred, z, len(diffs))


def within_run_speed(
    measured: Float[np.ndarray, "run channel time"],
    predictive: Float[np.ndarray, "draw run channel time"],
    fs: float,
    speed_profiles: Float[np.ndarray, "run time"],
    regions: Sequence[Region],
    channels: Sequence[str],
    *,
    frame_s: float = 0.25,
    hop_s: float = 0.05,
) -> tuple[WithinRunFit, ...]:
    """Test each region's feature for speed tracking inside the runs.

    Short-time spectra (Hann frames of ``frame_s``, every ``hop_s``, zero-padded 4 times) of
    the measured and the predictive runs give the excess ``e = log10 P - mean_d log10 P_d``
    per frame. A feature at cruise frequency ``f_c`` in a run of peak speed ``v_peak`` lies at
    ``f_c v(t) / v_peak`` if it tracks the speed and at ``f_c`` if it does not; the frames
    where the door moves (speed at least ``MOVING_FRACTION`` of its peak) and the two
    predictions lie at least ``TELLING_BINS`` frame resolutions apart (accelerating and
    braking) tell them apart. The statistic is the mean of ``e(f_tracking) - e(f_fixed)``
    over those frames of all runs (its sign turned for a deficit), standardised by the
    scatter of a single-frame log periodogram (2 degrees of freedom,
    :func:`log10_psd_variance`) over the number of independent frames (frames times hop over
    frame length). Runs of one speed are enough.

    Parameters
    ----------
    measured, predictive
        As for :func:`find_features`.
    fs
        Sampling rate, Hz.
    speed_profiles
        Each run's speed at every sample (for the door, the commanded speed).
    regions
        The residual map's regions (each tested on its own channel).
    channels
        Channel names.
    frame_s, hop_s
        Frame length and hop, s.

    Returns
    -------
    fits
        One :class:`WithinRunFit` per region, in order.

    Raises
    ------
    ValueError
        For a speed profile of the wrong shape or frames longer than the records.
    """
    x = np.asarray(measured, dtype=float)
    sims = np.asarray(predictive, dtype=float)
    v = np.asarray(speed_profiles, dtype=float)
    frames = _frames(x, v, fs, frame_s, hop_s)
    names = list(channels)
    spectra: dict[tuple[int, int], tuple] = {}
    fits = []
    for region in regions:
        c = names.index(region.channel)
        diffs = []
        for r in range(x.shape[0]):
            v_peak = float(v[r].max())
            if v_peak <= 0:
                continue
            f_c = region.peak if region.domain == FREQUENCY else region.peak * v_peak
            if (r, c) not in spectra:
                spectra[r, c] = _excess_spectrogram(
                    x[r, c], sims[:, r, c], fs, frames.nperseg, frames.hop, 4 * frames.nperseg
                )
            diffs += _telling_gaps(region, f_c, v_peak, v[r], spectra[r, c], frames)
        fits.append(_within_fit(diffs, frames))
    return tuple(fits)
