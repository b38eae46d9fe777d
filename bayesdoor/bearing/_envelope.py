"""Envelope analysis of a bearing signal (scipy): the classical check of a localised fault.

Band-pass the signal around the resonances the impulses excite, take the Hilbert envelope and
look for a line at the fault frequency in the envelope's spectrum (Randall and Antoni,
"Rolling element bearing diagnostics - A tutorial", MSSP 25, 2011, 485-520).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

#: the default analysis band, Hz: the resonance region of the CWRU drive-end records
BAND_HZ = (2000.0, 4500.0)


def envelope_spectrum(
    x: np.ndarray,
    fs: float,
    band: tuple[float, float] = BAND_HZ,
    *,
    segment_s: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Spectrum of the Hilbert envelope of ``x`` band-passed to ``band``.

    Parameters
    ----------
    x
        One signal (any units).
    fs
        Its sampling rate, Hz.
    band
        The pass band, Hz (a 4th-order Butterworth, applied forward and backward).
    segment_s
        Welch segments of the envelope, s (Hann window, half overlap; the whole signal when
        shorter): the resolution is ``1 / segment_s`` Hz.

    Returns
    -------
    f, amplitude
        Frequencies (Hz) and the rms amplitude of the envelope's lines (the square root of
        Welch's power spectrum, mean removed), in the units of ``x``.
    """
    x = np.asarray(x, dtype=float).ravel()
    lo, hi = band
    if not 0 < lo < hi < fs / 2:
        raise ValueError(f"band {band} Hz must lie inside (0, {fs / 2}) Hz")
    sos = signal.butter(4, [lo, hi], btype="bandpass", fs=fs, output="sos")
    env = np.abs(signal.hilbert(signal.sosfiltfilt(sos, x)))
    nperseg = min(env.size, round(segment_s * fs))
    f, power = signal.welch(env, fs=fs, nperseg=nperseg, detrend="constant", scaling="spectrum")
    return f, np.sqrt(power)


def line_strength(
    f: np.ndarray,
    amplitude: np.ndarray,
    target_hz: float,
    *,
    tolerance: float = 0.03,
    background: float = 0.2,
) -> tuple[float, float]:
    """The strongest line within ``tolerance`` (relative) of ``target_hz`` and its prominence.

    Returns
    -------
    peak_hz, ratio
        The peak's frequency and its amplitude over the median of the spectrum within
        ``background`` (relative) of the target.
    """
    near = np.abs(f - target_hz) <= tolerance * target_hz
    if not near.any():
        raise ValueError(f"no frequency of the spectrum lies near {target_hz} Hz")
    i = np.flatnonzero(near)[np.argmax(amplitude[near])]
    ring = np.abs(f - target_hz) <= background * target_hz
    return float(f[i]), float(amplitude[i] / np.median(amplitude[ring]))
