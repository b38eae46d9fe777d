"""Where the motion of a run starts and stops, from the envelope of its signals (numpy)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np


def _moving_rms(x: np.ndarray, m: int, *, leading: bool) -> np.ndarray:
    """RMS over the ``m`` samples ending at (trailing) or starting at (leading) each sample."""
    n = x.shape[-1]
    cs = np.concatenate([np.zeros((*x.shape[:-1], 1)), np.cumsum(x * x, axis=-1)], axis=-1)
    i = np.arange(n)
    lo, hi = (i, np.minimum(i + m, n)) if leading else (np.maximum(i - m + 1, 0), i + 1)
    return np.sqrt(np.maximum(cs[..., hi] - cs[..., lo], 0.0) / (hi - lo))


@dataclasses.dataclass(frozen=True)
class MotionDetection:
    """The thresholds of :func:`motion_window`.

    Parameters
    ----------
    rest_duration
        Length (s) of the still segment at the start of the record.
    rms_window
        Length (s) of the short-time RMS window.
    k
        Threshold as a multiple of the rest RMS.
    relative_floor
        Threshold as a fraction of the channel's peak short-time RMS, whichever is larger.
    """

    rest_duration: float = 0.25
    rms_window: float = 0.02
    k: float = 5.0
    relative_floor: float = 0.05


def motion_window(
    t: np.ndarray,
    signals: np.ndarray,
    *,
    t_start: float | None = None,
    t_stop: float | None = None,
    channels: Sequence[int] | None = None,
    detection: MotionDetection = MotionDetection(),
) -> tuple[float, float]:
    """Start and stop of the motion in one run, detected from the signal envelope.

    The rule: remove from each channel its mean over the rest segment (the samples before
    ``t[0] + rest_duration``, when the system is known to be still); take the short-time RMS
    over ``rms_window`` seconds; a channel is active where that RMS exceeds
    ``max(k x RMS of the rest segment, relative_floor x the channel's largest short-time
    RMS)`` (the second term matters for noise-free simulated records, whose rest RMS is
    nearly zero). The motion starts at the first sample where some selected channel is active
    in the window that *ends* at it, and stops at the last sample where some selected channel
    is active in the window that *starts* at it, so both ends sit within about one window of
    the change and err towards the inside of the motion. After the drive stops, a lightly
    damped structure rings on: ``t_stop`` marks when the vibration decays below the threshold,
    not the end of the commanded stroke.

    Parameters
    ----------
    t
        Sample times (s), increasing.
    signals
        One run's signals, time last.
    t_start, t_stop
        Known values; only a missing one is detected.
    channels
        Indices of the channels whose envelope counts (for the door, its sliding-direction
        channels ``A1Z`` and ``A2Z``); ``None`` means all.
    detection
        ``rest_duration``, ``rms_window``, ``k`` and ``relative_floor`` (:class:`MotionDetection`).

    Returns
    -------
    t_start, t_stop
        Times (s) of the start and stop of the motion.

    Raises
    ------
    ValueError
        For shapes that do not match, a rest segment of fewer than two samples or covering the
        whole record, or a record in which no channel ever exceeds its threshold.
    """
    t = np.asarray(t, dtype=float)
    x = np.atleast_2d(np.asarray(signals, dtype=float))
    if t.ndim != 1 or x.shape[-1] != t.size or x.ndim != 2:
        raise ValueError(
            f"t must be (time,) and signals (channel, time) with the same time length, got "
            f"shapes {t.shape} and {np.shape(signals)}"
        )
    if t_start is not None and t_stop is not None:
        return float(t_start), float(t_stop)
    if channels is not None:
        x = x[list(channels)]
    first, last = _active_span(t, x, detection)
    return (
        first if t_start is None else float(t_start),
        last if t_stop is None else float(t_stop),
    )


def _active_span(t: np.ndarray, x: np.ndarray, detection: MotionDetection) -> tuple[float, float]:
    """The first time some channel of ``x`` is active in the window ending there, and the
    last time some channel is active in the window starting there (see :func:`motion_window`)."""
    rest_duration, k = detection.rest_duration, detection.k
    rest = t < t[0] + rest_duration
    if rest.sum() < 2 or rest.all():
        raise ValueError(
            f"rest_duration={rest_duration} s gives {int(rest.sum())} rest samples of "
            f"{t.size}: it must cover at least two samples and leave some record after it"
        )
    x = x - x[:, rest].mean(axis=1, keepdims=True)
    m = max(1, round(detection.rms_window / np.median(np.diff(t))))
    trailing = _moving_rms(x, m, leading=False)
    leading = _moving_rms(x, m, leading=True)
    rest_rms = np.sqrt(np.mean(x[:, rest] ** 2, axis=1))
    floor = detection.relative_floor * trailing.max(axis=1)
    threshold = np.maximum(k * rest_rms, floor)[:, None]
    starts = np.flatnonzero((trailing > threshold).any(axis=0))
    stops = np.flatnonzero((leading > threshold).any(axis=0))
    if starts.size == 0 or stops.size == 0:
        raise ValueError(
            f"no motion detected: no channel's {detection.rms_window} s RMS exceeds {k} x its "
            f"rest RMS ({rest_rms.tolist()}); (a) the record holds no motion, (b) rest_duration="
            f"{rest_duration} s reaches into the motion, (c) k is too large; or pass t_start "
            "and t_stop"
        )
    return float(t[starts[0]]), float(t[stops[-1]])
