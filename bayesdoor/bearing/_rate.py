"""A record's sampling rate read from its own spectrum: the rate that puts the shaft's lines
where its speed says they are (for records whose rate is not stated, or is disputed)."""

from __future__ import annotations

import numpy as np

#: the sampling rates a CWRU record may have been taken at, Hz
CANDIDATE_RATES_HZ = (12000.0, 48000.0)


def shaft_lines(x: np.ndarray, fs: float, shaft_hz: float, harmonics: int = 3) -> np.ndarray:
    """Frequency (Hz) and amplitude of the strongest line within 3 % of each shaft harmonic.

    The amplitude spectrum of the whole record (Hann window, amplitude-corrected), read as
    sampled at ``fs``. Returns shape (harmonics, 2).
    """
    x = np.asarray(x, dtype=float) - np.mean(x)
    w = np.hanning(x.size)
    amplitude = 2 * np.abs(np.fft.rfft(x * w)) / w.sum()
    f = np.fft.rfftfreq(x.size, 1 / fs)
    rows = []
    for h in range(1, harmonics + 1):
        near = np.abs(f - h * shaft_hz) <= 0.03 * h * shaft_hz
        i = np.flatnonzero(near)[np.argmax(amplitude[near])]
        rows.append((f[i], amplitude[i]))
    return np.asarray(rows)


def settle_sampling_rate(
    x: np.ndarray,
    shaft_rpm: float,
    *,
    candidates: tuple[float, ...] = CANDIDATE_RATES_HZ,
    min_ratio: float = 2.0,
) -> tuple[float, dict]:
    """The candidate sampling rate that puts the strongest lines at the shaft's 1x, 2x, 3x.

    For each candidate the record is read as sampled at that rate and the strongest line
    within 3 % of each harmonic of ``shaft_rpm / 60`` is found (:func:`shaft_lines`); the rate
    whose three lines are strongest in sum wins, if by at least ``min_ratio``.

    Returns
    -------
    rate, evidence
        The rate (Hz) and, per candidate, the lines found (Hz, amplitude in the units of
        ``x``) and the winner's margin.

    Raises
    ------
    ValueError
        When no candidate wins by ``min_ratio``.
    """
    shaft_hz = shaft_rpm / 60.0
    lines = {fs: shaft_lines(x, fs, shaft_hz) for fs in candidates}
    score = {fs: float(v[:, 1].sum()) for fs, v in lines.items()}
    ranked = sorted(score, key=score.__getitem__, reverse=True)
    best = ranked[0]
    margin = score[best] / score[ranked[1]] if len(ranked) > 1 else float("inf")
    evidence = {
        "shaft_hz": shaft_hz,
        "candidates": {
            f"{fs:g}": {
                "line_hz": [round(float(v), 3) for v in lines[fs][:, 0]],
                "line_amplitude": [float(v) for v in lines[fs][:, 1]],
            }
            for fs in candidates
        },
        "margin": margin,
    }
    if margin < min_ratio:
        raise ValueError(
            f"cannot settle the sampling rate: the shaft lines read at {best:g} Hz are only "
            f"{margin:.2f} times those at {ranked[1]:g} Hz (at least {min_ratio} needed)"
        )
    return best, evidence
