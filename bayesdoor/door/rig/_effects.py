"""Catalogue effects the rig can inject into its data (names are API).

The names are those of the door's catalogue of discrepancy causes (``docs/model.md``, "Model
extensions"); each effect's physics and ``from_seed`` ranges are in ``docs/rig.md``, "Catalogue
effects".

Each effect is a frozen module with physical parameters and a ``from_seed`` class method that
draws them over a documented range, so a test can hide an effect "drawn from a seed, not chosen
to suit the detector". :class:`Effects` holds at most one of each.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import numpy as np

from ._door import WHEEL_RADIUS

CHANNELS = ("A1X", "A1Z", "A2X", "A2Z")
SENSORS = ("A1", "A2")
WHEELS = ("left", "right")
#: most radius harmonics of :class:`WheelEccentricity` (fewer are padded with zeros, so every
#: rig shares one compiled solve)
MAX_HARMONICS = 8


def _check_range(owner: str, name: str, value: float, lo: float, hi: float) -> None:
    if not (np.isfinite(value) and lo <= value <= hi):
        raise ValueError(f"{owner}.{name}={value!r} is outside its allowed range [{lo}, {hi}]")


class FrameMode(eqx.Module):
    """An extra structural mode of the frame, absent from the model (``frame_mode``).

    A modal oscillator (modal mass 20 kg) that lifts the rail under both wheels by
    ``rail_lift`` per unit modal displacement, so the wheel forces excite it while the door
    moves; each channel reads ``participation[c]`` times its acceleration. Signature: a peak at
    ``frequency_hz`` whatever the door speed, with the bandwidth of ``damping_ratio``,
    decaying once the door is at rest.

    ``from_seed`` ranges: frequency 20-95 Hz, damping ratio 0.005-0.03, rail lift 0.05-0.2,
    participation 0.2-1.0 on each channel (uniform).
    """

    frequency_hz: float
    damping_ratio: float
    rail_lift: float
    participation: tuple[float, ...]

    def __check_init__(self):
        _check_range("FrameMode", "frequency_hz", self.frequency_hz, 5.0, 400.0)
        _check_range("FrameMode", "damping_ratio", self.damping_ratio, 1e-4, 0.5)
        _check_range("FrameMode", "rail_lift", self.rail_lift, 0.0, 1.0)
        if len(self.participation) != len(CHANNELS):
            raise ValueError(
                f"FrameMode.participation needs one value per channel {CHANNELS}, "
                f"got {self.participation!r}"
            )

    @classmethod
    def from_seed(cls, seed: int) -> FrameMode:
        rng = np.random.default_rng(seed)
        return cls(
            frequency_hz=float(rng.uniform(20.0, 95.0)),
            damping_ratio=float(rng.uniform(0.005, 0.03)),
            rail_lift=float(rng.uniform(0.05, 0.2)),
            participation=tuple(float(x) for x in rng.uniform(0.2, 1.0, len(CHANNELS))),
        )


class WheelEccentricity(eqx.Module):
    """An out-of-round wheel (``wheel_eccentricity``).

    The wheel's radius varies with its rotation angle alpha as
    sum_k amplitudes[k-1] cos(k alpha + phases[k-1]), k = 1..H. Rolling without slip, it
    excites tones at k v / (2 pi R): the rotation frequency and its harmonics, tracking the
    door speed.

    ``from_seed`` ranges: the wheel (left or right), H = 6 harmonics with amplitudes
    a_k = a_1 u_k / k, a_1 uniform in 5-20 um, u_k uniform in 0.5-1; phases uniform.
    """

    wheel: str
    amplitudes: tuple[float, ...]
    phases: tuple[float, ...]

    def __check_init__(self):
        if self.wheel not in WHEELS:
            raise ValueError(f"WheelEccentricity.wheel={self.wheel!r}: allowed {WHEELS}")
        if (
            len(self.amplitudes) != len(self.phases)
            or not 1 <= len(self.amplitudes) <= MAX_HARMONICS
        ):
            raise ValueError(
                f"WheelEccentricity needs 1 to {MAX_HARMONICS} harmonic amplitudes and one "
                f"phase per amplitude, got {len(self.amplitudes)} amplitudes and "
                f"{len(self.phases)} phases"
            )
        for k, amp in enumerate(self.amplitudes, 1):
            _check_range("WheelEccentricity", f"amplitudes[{k - 1}] (m)", amp, 0.0, 0.2e-3)

    @property
    def revolution_m(self) -> float:
        """Travel per wheel revolution, 2 pi R (m)."""
        return 2.0 * np.pi * WHEEL_RADIUS

    @classmethod
    def from_seed(cls, seed: int) -> WheelEccentricity:
        rng = np.random.default_rng(seed)
        wheel = WHEELS[int(rng.integers(2))]
        k = np.arange(1, 7)
        amplitudes = rng.uniform(5e-6, 20e-6) * rng.uniform(0.5, 1.0, k.size) / k
        phases = rng.uniform(0.0, 2.0 * np.pi, k.size)
        return cls(wheel, tuple(map(float, amplitudes)), tuple(map(float, phases)))


class RailWaviness(eqx.Module):
    """An extra periodic rail irregularity (``rail_waviness``): amplitude sin(2 pi z / lambda).

    Both wheels roll over it; signature: a tone at v / lambda, tracking the door speed.

    ``from_seed`` ranges: wavelength 8-80 mm (log-uniform), amplitude 3-15 um, phase uniform.
    """

    wavelength_m: float
    amplitude_m: float
    phase: float = 0.0

    def __check_init__(self):
        _check_range("RailWaviness", "wavelength_m", self.wavelength_m, 2e-3, 1.0)
        _check_range("RailWaviness", "amplitude_m", self.amplitude_m, 0.0, 0.2e-3)

    @classmethod
    def from_seed(cls, seed: int) -> RailWaviness:
        rng = np.random.default_rng(seed)
        return cls(
            wavelength_m=float(np.exp(rng.uniform(np.log(8e-3), np.log(80e-3)))),
            amplitude_m=float(rng.uniform(3e-6, 15e-6)),
            phase=float(rng.uniform(0.0, 2.0 * np.pi)),
        )


class SensorCrossAxis(eqx.Module):
    """Cross-axis sensitivity or misalignment of one accelerometer (``sensor_cross_axis``).

    The ``into`` channel of ``sensor`` (``"X"`` or ``"Z"``) measures its own axis plus
    ``fraction`` times the other axis. Signature: coherence between the sensor's X and Z.

    ``from_seed`` ranges: sensor A1 or A2, ``into`` X or Z, fraction 0.02-0.2 (uniform).
    """

    sensor: str
    into: str
    fraction: float

    def __check_init__(self):
        if self.sensor not in SENSORS:
            raise ValueError(f"SensorCrossAxis.sensor={self.sensor!r}: allowed {SENSORS}")
        if self.into not in ("X", "Z"):
            raise ValueError(f"SensorCrossAxis.into={self.into!r}: allowed 'X' or 'Z'")
        _check_range("SensorCrossAxis", "fraction", self.fraction, 0.0, 1.0)

    @property
    def channels(self) -> tuple[str, str]:
        """(receiving channel, source channel), e.g. ("A1X", "A1Z")."""
        other = "Z" if self.into == "X" else "X"
        return f"{self.sensor}{self.into}", f"{self.sensor}{other}"

    @classmethod
    def from_seed(cls, seed: int) -> SensorCrossAxis:
        rng = np.random.default_rng(seed)
        return cls(
            sensor=SENSORS[int(rng.integers(2))],
            into=("X", "Z")[int(rng.integers(2))],
            fraction=float(rng.uniform(0.02, 0.2)),
        )


class MainsHum(eqx.Module):
    """Electrical interference in the measurement chain (``mains_hum``).

    On every channel c: gain[c] amplitude (cos(2 pi f t + phi) + sum_h ratios[h-2]
    cos(2 pi h f t + phi_h)) for h = 2, 3, ..., with constant amplitude, present at rest as
    while moving; the phases are random per run (the mains is not synchronised with the
    record). Added before the anti-alias filter, as in the analogue chain.

    ``from_seed`` ranges: 50 or 60 Hz, amplitude 5-30 mm/s^2, harmonic ratios 0.1-0.5 for
    the 2nd and 3rd harmonics, per-channel gains 0.5-1 (uniform).
    """

    frequency_hz: float
    amplitude: float
    harmonic_ratios: tuple[float, ...] = ()
    gains: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0)

    def __check_init__(self):
        if self.frequency_hz not in (50.0, 60.0):
            raise ValueError(
                f"MainsHum.frequency_hz={self.frequency_hz!r}: mains is 50.0 or 60.0 Hz"
            )
        _check_range("MainsHum", "amplitude", self.amplitude, 0.0, 10.0)
        if len(self.gains) != len(CHANNELS):
            raise ValueError(f"MainsHum.gains needs one gain per channel {CHANNELS}")

    @classmethod
    def from_seed(cls, seed: int) -> MainsHum:
        rng = np.random.default_rng(seed)
        return cls(
            frequency_hz=(50.0, 60.0)[int(rng.integers(2))],
            amplitude=float(rng.uniform(5e-3, 30e-3)),
            harmonic_ratios=tuple(float(x) for x in rng.uniform(0.1, 0.5, 2)),
            gains=tuple(float(x) for x in rng.uniform(0.5, 1.0, len(CHANNELS))),
        )


class Effects(eqx.Module):
    """The catalogue effects injected by a :class:`~bayesdoor.door.rig.VirtualRig` (None: absent).

    Examples
    --------
    >>> Effects(mains_hum=MainsHum.from_seed(3)).names()
    ('mains_hum',)
    """

    frame_mode: FrameMode | None = None
    wheel_eccentricity: WheelEccentricity | None = None
    rail_waviness: RailWaviness | None = None
    sensor_cross_axis: SensorCrossAxis | None = None
    mains_hum: MainsHum | None = None

    def __check_init__(self):
        expected = {
            "frame_mode": FrameMode,
            "wheel_eccentricity": WheelEccentricity,
            "rail_waviness": RailWaviness,
            "sensor_cross_axis": SensorCrossAxis,
            "mains_hum": MainsHum,
        }
        for name, kind in expected.items():
            value = getattr(self, name)
            if value is not None and not isinstance(value, kind):
                raise ValueError(
                    f"Effects.{name} must be a {kind.__name__} or None, got "
                    f"{type(value).__name__}; build one with {kind.__name__}.from_seed(seed)"
                )

    def names(self) -> tuple[str, ...]:
        """Names of the effects present, in the catalogue's order."""
        return tuple(f.name for f in dataclasses.fields(self) if getattr(self, f.name) is not None)

    def to_dict(self) -> dict[str, dict | None]:
        """Every effect's parameters as plain values (JSON-ready); None where absent."""
        out: dict[str, dict | None] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            out[f.name] = (
                None
                if value is None
                else {g.name: getattr(value, g.name) for g in dataclasses.fields(value)}
            )
        return out
