"""Envelope analysis of a bearing signal (scipy): the classical check of a localised fault.

Band-pass the signal around the resonances the impulses excite, take the Hilbert envelope and
look for a line at the fault frequency in the envelope's spectrum (Randall and Antoni,
"Rolling element bearing diagnostics - A tutorial", MSSP 25, 2011, 485-520).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import signal

from ._geometry import CWRU_DRIVE_END, BearingGeometry
from ._stand import BAND_HZ


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


#: the lines of the physics rule's indicator of each fault state: harmonics 1..3 of BPFO and
#: BPFI; harmonics 1..4 of BSF for a ball (a ball strikes the races at 2 BSF and, when its
#: defect meets one race only, at BSF)
RULE_LINES = {
    "outer_race": ("bpfo", (1, 2, 3)),
    "inner_race": ("bpfi", (1, 2, 3)),
    "ball": ("bsf", (1, 2, 3, 4)),
}


def fault_indicators(
    x: np.ndarray,
    fs: float,
    shaft_speed_rpm: float,
    *,
    band: tuple[float, float] = BAND_HZ,
    tolerance: float = 0.02,
    geometry=None,
) -> dict[str, float]:
    """Each fault family's envelope-line indicator of one segment, dB.

    The segment is band-passed to ``band``, enveloped and its envelope spectrum taken at the
    resolution of the whole segment (:func:`envelope_spectrum`); at each line of
    :data:`RULE_LINES` (from the geometry and ``shaft_speed_rpm``) the strongest bin within
    ``tolerance`` (relative, for slip) is compared with the median within 20 %
    (:func:`line_strength`). A family's indicator is the mean of its lines' prominences, dB.
    ``geometry``: the bearing's (default the CWRU drive end's).
    """
    geometry = CWRU_DRIVE_END if geometry is None else geometry
    x = np.asarray(x, dtype=float).ravel()
    f, amplitude = envelope_spectrum(x, fs, band, segment_s=x.size / fs)
    hz = geometry.fault_frequencies(shaft_speed_rpm / 60.0)
    out = {}
    for state, (line, harmonics) in RULE_LINES.items():
        ratios = [
            line_strength(f, amplitude, k * hz[line], tolerance=tolerance)[1] for k in harmonics
        ]
        out[state] = float(np.mean(20 * np.log10(ratios)))
    return out


@dataclasses.dataclass(frozen=True)
class EnvelopeRule:
    """A physics rule without learning: envelope lines at the kinematic fault frequencies.

    Each segment's family indicators (:func:`fault_indicators`) are standardised by their
    mean and standard deviation over healthy reference segments. A segment is called healthy
    when no family's standardised indicator exceeds ``z_threshold``; else the family with the
    largest one. ``z_threshold`` follows from the stated false-alarm rate
    ``false_alarm_rate`` of a healthy segment (:meth:`from_healthy`): the one-sided normal
    prediction bound for a new segment from ``n`` reference segments (Student's t with
    ``n - 1`` degrees of freedom, times ``sqrt(1 + 1/n)``), at the rate split over the three
    families (Bonferroni), so a healthy segment whose indicators scatter as the reference's
    (normally) is called faulty with at most that probability.

    The same reference checks a call (:meth:`agrees`): a call of a fault state agrees with
    the segment when that family's standardised indicator exceeds ``family_threshold``, the
    prediction bound at the stated rate for that one family (a segment without the family's
    lines exceeds it with at most that probability); a healthy call, when the rule would call
    the segment healthy (no family above ``z_threshold``).

    Attributes
    ----------
    mean, sd
        Per family, the healthy reference's indicator mean and standard deviation, dB.
    z_threshold
        The standardised indicator above which a family is detected.
    false_alarm_rate
        The stated false-alarm rate per healthy segment it was derived from.
    band
        The envelope's pass band, Hz.
    family_threshold
        The standardised indicator above which one given family counts as shown (``None``:
        ``z_threshold``).
    geometry
        The bearing whose fault frequencies the lines sit at.
    """

    mean: dict[str, float]
    sd: dict[str, float]
    z_threshold: float
    false_alarm_rate: float
    band: tuple[float, float] = BAND_HZ
    family_threshold: float | None = None
    geometry: BearingGeometry = CWRU_DRIVE_END

    @classmethod
    def from_healthy(
        cls,
        segments: np.ndarray,
        fs: float,
        shaft_speed_rpm: np.ndarray,
        *,
        false_alarm_rate: float = 0.01,
        band: tuple[float, float] = BAND_HZ,
        geometry: BearingGeometry = CWRU_DRIVE_END,
    ) -> EnvelopeRule:
        """The rule from healthy reference segments ``(segment, time)`` and their speeds, for
        a bearing of ``geometry``."""
        from scipy.stats import t as student

        if not 0 < false_alarm_rate < 1:
            raise ValueError(f"false_alarm_rate must be in (0, 1), got {false_alarm_rate!r}")
        segments = np.atleast_2d(np.asarray(segments, dtype=float))
        speeds = np.broadcast_to(np.asarray(shaft_speed_rpm, dtype=float), (len(segments),))
        if len(segments) < 3:
            raise ValueError(f"the rule needs at least 3 healthy segments, got {len(segments)}")
        rows = [
            fault_indicators(x, fs, s, band=band, geometry=geometry)
            for x, s in zip(segments, speeds, strict=True)
        ]
        mean = {k: float(np.mean([r[k] for r in rows])) for k in RULE_LINES}
        sd = {k: float(np.std([r[k] for r in rows], ddof=1)) for k in RULE_LINES}
        n = len(rows)
        quantile = student.ppf(1 - false_alarm_rate / len(RULE_LINES), n - 1)
        z = float(quantile * np.sqrt(1 + 1 / n))
        one = float(student.ppf(1 - false_alarm_rate, n - 1) * np.sqrt(1 + 1 / n))
        return cls(mean, sd, z, false_alarm_rate, band, one, geometry)

    def to_json(self) -> dict:
        """The rule as a JSON-able dict (:meth:`from_json` reads it back)."""
        return dataclasses.asdict(self) | {"band": list(self.band)}

    @classmethod
    def from_json(cls, payload: dict) -> EnvelopeRule:
        """The rule written by :meth:`to_json`."""
        fields = {f.name for f in dataclasses.fields(cls)}
        unknown = set(payload) - fields
        if unknown:
            raise ValueError(f"not an envelope rule: unknown keys {sorted(unknown)}")
        geometry = BearingGeometry(**payload.get("geometry", dataclasses.asdict(CWRU_DRIVE_END)))
        return cls(
            **(payload | {"band": tuple(payload.get("band", BAND_HZ)), "geometry": geometry})
        )

    def agrees(self, x: np.ndarray, fs: float, shaft_speed_rpm: float) -> dict[str, bool]:
        """Whether the segment agrees with each state: ``healthy`` when the rule calls it
        healthy; a fault state when its family's indicator exceeds ``family_threshold``."""
        z = self.scores(x, fs, shaft_speed_rpm)
        one = self.z_threshold if self.family_threshold is None else self.family_threshold
        out = {"healthy": bool(max(z.values()) <= self.z_threshold)}
        return out | {k: bool(v > one) for k, v in z.items()}

    def scores(self, x: np.ndarray, fs: float, shaft_speed_rpm: float) -> dict[str, float]:
        """The standardised indicator of each fault family for one segment."""
        raw = fault_indicators(x, fs, shaft_speed_rpm, band=self.band, geometry=self.geometry)
        return {k: (raw[k] - self.mean[k]) / self.sd[k] for k in RULE_LINES}

    def classify(self, x: np.ndarray, fs: float, shaft_speed_rpm: float) -> str:
        """``healthy`` or the state of the most prominent detected family."""
        z = self.scores(x, fs, shaft_speed_rpm)
        best = max(z, key=lambda k: z[k])
        return best if z[best] > self.z_threshold else "healthy"
