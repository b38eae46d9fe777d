"""The rig's measurement chain: sensor errors, anti-alias filter, decimation, noise, ADC.

Numpy and scipy at the edge of the rig: the physics (JAX) hands over accelerations at the fine
integration rate, and this chain turns them into what a 16-bit data acquisition system records.
"""

from __future__ import annotations

import numpy as np
import scipy.signal

from ._effects import CHANNELS, MainsHum, SensorCrossAxis


def apply_cross_axis(x: np.ndarray, effect: SensorCrossAxis | None) -> np.ndarray:
    """Add ``fraction`` of the source axis to the receiving channel (run, channel, time)."""
    if effect is None:
        return x
    into, source = (CHANNELS.index(c) for c in effect.channels)
    out = x.copy()
    out[:, into] += effect.fraction * x[:, source]
    return out


def mains_signal(effect: MainsHum, t: np.ndarray, phases: np.ndarray) -> np.ndarray:
    """Hum on each channel (run, channel, time) for per-run phases (run, harmonic)."""
    orders = np.arange(1, len(effect.harmonic_ratios) + 2)
    ratios = np.concatenate([[1.0], np.asarray(effect.harmonic_ratios, dtype=float)])
    arg = 2.0 * np.pi * effect.frequency_hz * orders[None, :, None] * t + phases[:, :, None]
    hum = effect.amplitude * np.sum(ratios[None, :, None] * np.cos(arg), axis=1)
    return np.asarray(effect.gains, dtype=float)[None, :, None] * hum[:, None, :]


def anti_alias_decimate(x: np.ndarray, factor: int, fs_out: float, cutoff: float, order: int):
    """Causal Butterworth low-pass at ``cutoff`` x ``fs_out``, then keep every ``factor``-th sample.

    Causal (``sosfilt``) as an analogue anti-alias filter is: the record keeps its group delay
    (about 1 ms at low frequency for the default 8th order at 819 Hz).
    """
    sos = scipy.signal.butter(order, cutoff * fs_out, fs=fs_out * factor, output="sos")
    return scipy.signal.sosfilt(sos, x, axis=-1)[..., ::factor]


def quantise(x: np.ndarray, full_scale: float, bits: int) -> np.ndarray:
    """Mid-tread ADC: round to the LSB = 2 full_scale / 2^bits, saturate at the codes' ends."""
    lsb = 2.0 * full_scale / 2**bits
    codes = np.clip(np.round(x / lsb), -(2 ** (bits - 1)), 2 ** (bits - 1) - 1)
    return codes * lsb
