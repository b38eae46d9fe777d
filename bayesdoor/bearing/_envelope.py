"""Envelope analysis of a bearing signal (scipy): the classical check of a localised fault.

Band-pass the signal around the resonances the impulses excite, take the Hilbert envelope and
look for a line at the fault frequency in the envelope's spectrum (Randall and Antoni,
"Rolling element bearing diagnostics - A tutorial", MSSP 25, 2011, 485-520).
"""

from __future__ import annotations

from pathlib import Path

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


#: the envelope lines of each state's family, as multiples of the shaft frequency's name
FAMILIES = {"outer_race": ("bpfo",), "inner_race": ("bpfi",), "ball": ("2bsf", "bsf")}


def fault_line_check(
    folder,
    *,
    band: tuple[float, float] = BAND_HZ,
    tolerance: float = 0.02,
    threshold_db: float = 10.0,
) -> list[dict]:
    """Which CWRU records show their fault frequency in the envelope spectrum.

    Each record under ``folder`` (read as :func:`~bayesdoor.bearing.read_cwru` reads it, at
    its settled sampling rate, whole) is band-passed to ``band``, enveloped and its envelope
    spectrum taken with 1 Hz resolution (:func:`envelope_spectrum`); at BPFO, BPFI, 2 BSF and
    BSF (from the geometry and the record's rpm) the strongest line within ``tolerance`` is
    compared with the median of the spectrum within 20 % (:func:`line_strength`). A fault
    record shows its fault when its own family's line (BPFO; BPFI; the stronger of 2 BSF and
    BSF for a ball) stands ``threshold_db`` or more above that background and above every
    other family's line.

    Returns
    -------
    rows
        Per record: ``record``, ``state``, ``shaft_speed_rpm``, per line its frequency found
        (``<line>_hz``) and prominence (``<line>_db``), and ``shows`` (``None`` for a healthy
        record).
    """
    from ._cwru import _at_campaign_rate, _record_rate, _records
    from ._geometry import CWRU_DRIVE_END
    from ._system import FS

    rows = []
    for record in _records(Path(folder)):
        rate, _ = _record_rate(record)
        x = _at_campaign_rate(record.drive_end_g, rate)
        f, amplitude = envelope_spectrum(x, FS, band)
        hz = CWRU_DRIVE_END.fault_frequencies(record.shaft_speed / 60.0)
        targets = {"bpfo": hz["bpfo"], "bpfi": hz["bpfi"], "2bsf": 2 * hz["bsf"], "bsf": hz["bsf"]}
        row: dict = {
            "record": record.name,
            "state": record.state,
            "shaft_speed_rpm": record.shaft_speed,
        }
        for name, target in targets.items():
            peak, ratio = line_strength(f, amplitude, target, tolerance=tolerance)
            row[f"{name}_hz"] = peak
            row[f"{name}_db"] = round(20 * float(np.log10(ratio)), 1)
        if record.state == "healthy":
            row["shows"] = None
        else:
            family = {k: max(row[f"{n}_db"] for n in v) for k, v in FAMILIES.items()}
            own = family.pop(record.state)
            row["shows"] = bool(own >= threshold_db and own > max(family.values()))
        rows.append(row)
    return rows
