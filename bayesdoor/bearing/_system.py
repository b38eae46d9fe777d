"""A rolling-element bearing as a :class:`~bayesdoor.systems.AbstractSystem`.

By default the drive-end bearing of the CWRU stand at 12 kHz; the geometry and the sampling
rate are fields, so a campaign of another bearing names its own (:meth:`BearingSystem.settings`).
A phenomenological model of the drive-end accelerometer (one channel ``DE``, m/s^2): shaft
harmonics, resonances excited by a broadband background and, for a localised fault, by
impulses at the kinematic fault frequency with slip jitter and load-zone modulation, plus
measurement noise (see :mod:`bayesdoor.bearing._model` and docs/bearing.md). References:
McFadden and Smith, "Model for the vibration produced by a single point defect in a rolling
element bearing", JSV 96(1), 1984, 69-82; Randall and Antoni, "Rolling element bearing
diagnostics - A tutorial", MSSP 25, 2011, 485-520; Antoni and Randall, "A stochastic model for
simulation and diagnostics of rolling element bearings with localized faults", J. Vib. Acoust.
125, 2003, 282-289.

Randomness (slip jitter, phases, defect angle, background and noise) comes from a key derived
from the system's ``seed`` folded with the run's index in the batch and the bits of its shaft
speed and load: the same inputs give the same signal (common random numbers, so a likelihood
is a smooth function of the parameters and ``jax.grad`` holds the draws fixed).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._exported import persistent_jit
from ..systems import (
    ConditionSpec,
    DamageSpec,
    ExtensionHost,
    ParameterSpec,
    SimulationResult,
    SpectralFeatures,
)
from ._catalogue import BEARING_CATALOGUE
from ._extensions import EXTENSIONS, AbstractBearingExtension, ShaftHarmonics
from ._geometry import CWRU_DRIVE_END, BearingGeometry
from ._model import impulse_capacity, run_signal
from ._stand import BAND_HZ, FS

#: what a healthy calibration can update: the structure, the background and the sensor
PARAMETERS = (
    ParameterSpec(
        "resonance_1_hz", "Hz", 3200.0, 2000.0, 4500.0, "natural frequency of the housing mode"
    ),
    ParameterSpec("damping_1", "-", 0.05, 0.005, 0.3, "damping ratio of the housing mode"),
    ParameterSpec(
        "resonance_2_hz", "Hz", 5000.0, 4000.0, 5800.0, "natural frequency of the higher mode"
    ),
    ParameterSpec("damping_2", "-", 0.05, 0.005, 0.3, "damping ratio of the higher mode"),
    ParameterSpec(
        "resonance_2_gain",
        "-",
        0.3,
        0.0,
        3.0,
        "ring-down amplitude of the higher mode per unit of the housing mode's",
    ),
    ParameterSpec("shaft_amplitude", "m/s^2", 0.05, 0.0, 2.0, "amplitude of the 1x shaft line"),
    ParameterSpec(
        "roughness_rms", "m/s^2", 0.1, 0.0, 5.0, "rms of the broadband resonance response"
    ),
    ParameterSpec("noise_rms", "m/s^2", 0.05, 0.0, 2.0, "rms of the white measurement noise"),
)

#: a localised fault's own parameters and their prior ranges (the severity of a fault state):
#: its size, inch; the ring-down amplitude of the housing mode per impulse of a 0.014 in
#: defect, m/s^2; the rms jitter of the impulse spacing (slip); the rotating (unbalance) load
#: per static radial load, which modulates the strikes at 1x. They act on fault runs only, so
#: a healthy calibration cannot update them: the training data draw them from these ranges
FAULT_SIZE_RANGE = (0.005, 0.025)
FAULT_PARAMETERS = {
    "fault_size_in": FAULT_SIZE_RANGE,
    "impulse_amplitude": (0.0, 300.0),
    "slip": (0.0, 0.05),
    "unbalance_ratio": (0.0, 0.8),
}
#: the values of a fault's parameters that a simulation is not given (the size: the middle of
#: its range)
FAULT_DEFAULTS = {
    "fault_size_in": 0.5 * sum(FAULT_SIZE_RANGE),
    "impulse_amplitude": 20.0,
    "slip": 0.01,
    "unbalance_ratio": 0.0,
}

STATES = {
    "healthy": DamageSpec("healthy", "no localised defect"),
    "inner_race": DamageSpec("inner_race", "a defect on the inner race", dict(FAULT_PARAMETERS)),
    "outer_race": DamageSpec(
        "outer_race",
        "a defect on the outer race at 6 o'clock (in the load zone)",
        dict(FAULT_PARAMETERS),
    ),
    "ball": DamageSpec("ball", "a defect on one ball", dict(FAULT_PARAMETERS)),
}

CONDITIONS = (
    ConditionSpec("shaft_speed", "rpm", 1600.0, 1900.0, "shaft speed"),
    ConditionSpec(
        "load_hp",
        "hp",
        0.0,
        3.0,
        "motor load (recorded; the model depends on it only through the shaft speed)",
        positive=False,
    ),
)

#: the highest frequency the model describes, Hz: the upper bound of the higher mode
#: (``resonance_2_hz``); a sampling rate must put the Nyquist frequency above it
MODEL_TOP_HZ = max(p.upper for p in PARAMETERS if p.unit == "Hz")

#: the shaft speeds (rpm) and motor loads (hp) the training data span besides the campaign's
#: own operating points: a user's machine does not run at the calibration speed. The ends and
#: the middle of 1700-1800 rpm, at the ends of 0-3 hp (the model depends on the load only
#: through the speed); few points, so that each, the calibration speed among them, keeps
#: enough simulated runs for the fit-adequacy check
TRAINING_SPEEDS_RPM = (1700.0, 1750.0, 1800.0)
TRAINING_LOADS_HP = (0.0, 3.0)

#: the stated false-alarm rate of the signature check (the envelope rule that checks each
#: call, :meth:`BearingSystem.signatures`): a segment without a family's envelope lines is
#: taken to show them with at most this probability, a healthy segment to show a fault's
#: with at most this probability over the three families
SIGNATURE_FALSE_ALARM_RATE = 0.01
#: the fewest healthy runs the signature check's reference is made from
SIGNATURE_MIN_RUNS = 3

#: what the fit and the classifier compare at 12 kHz (docs/bearing.md, "Features"; at another
#: rate the Welch segments scale with it, :attr:`BearingSystem.features`): the fit, log10 Welch
#: PSDs (480 samples, 25 Hz bins) in 39 bands of 100 Hz from 1.5 to 5.4 kHz, the resonance
#: region the model describes (below it the real healthy record holds lines the model lacks,
#: above it the recorder's anti-alias filter cuts the spectrum); the classifier, the log10
#: Welch PSD of the envelope of the resonance band 2-4.5 kHz (the envelope rule's band) with
#: 4096-sample segments from 0 to 600 Hz (205 bins of 2.9 Hz: the fault lines' fundamentals,
#: BPFO, 2 BSF and BPFI, 107, 141 and 162 Hz at 1797 rpm, lie 7 or more bins apart, and their
#: second and third harmonics lie below 600 Hz at every training speed)
FEATURES = SpectralFeatures(
    f_low=1500.0,
    f_high=5375.0,
    band_width=100.0,
    nperseg=480,
    classifier_fmax=600.0,
    classifier_nperseg=4096,
    classifier_envelope_band=BAND_HZ,
)


class BearingSystem(ExtensionHost):
    """A rolling-element bearing seen by one accelerometer ``DE``; by default the CWRU
    drive-end bearing (SKF 6205-2RS) at 12 kHz.

    Operating conditions: ``shaft_speed`` (rpm) and ``load_hp``, the columns of
    ``operating`` (shape ``(run, 2)``; one run may be given as ``(2,)``).

    Parameters
    ----------
    geometry
        The bearing's geometry (the fault frequencies follow from it: the simulated impulses
        and the envelope rule's lines).
    sampling_rate_hz
        The accelerometer's sampling rate, Hz; above twice :data:`MODEL_TOP_HZ`.
    segment_s
        The length of a record, s (:meth:`record_duration`).
    seed
        The seed of every run's random key (see the module docstring).
    harmonic_ratios
        The shaft harmonics' amplitudes (1x, 2x, 3x) per ``shaft_amplitude``.
    load_zone_epsilon
        Load distribution factor of the Stribeck load zone (0.5: half the circumference).
    ball_inner_ratio
        Weight of a ball defect's strikes on the inner race (those on the outer race: 1).
    entry_ratio
        Area of a defect passage's gradual entry (unloading) per unit of its exit impact.
    extensions
        Model extensions of the catalogue of discrepancy causes (``ShaftHarmonics()``,
        ``StructuralMode()``, ``LineFrequency()``), at most one of each; default none, the
        base model. Their parameters follow the base ones in :attr:`parameters`.

    Examples
    --------
    >>> system = BearingSystem()
    >>> result = system.simulate_values(
    ...     system.nominal(), [1797.0, 0.0], state="outer_race", severity={"fault_size_in": 0.007}
    ... )
    >>> result.signals.shape
    (1, 1, 12000)
    """

    geometry: BearingGeometry = eqx.field(static=True, default=CWRU_DRIVE_END)
    sampling_rate_hz: float = eqx.field(static=True, default=FS, converter=float)
    segment_s: float = eqx.field(static=True, default=1.0)
    seed: int = eqx.field(static=True, default=0)
    harmonic_ratios: tuple[float, ...] = eqx.field(static=True, default=(1.0, 0.6, 0.8))
    load_zone_epsilon: float = eqx.field(static=True, default=0.5)
    ball_inner_ratio: float = eqx.field(static=True, default=0.5)
    entry_ratio: float = eqx.field(static=True, default=0.3)
    extensions: tuple[AbstractBearingExtension, ...] = eqx.field(
        static=True, default=(), converter=tuple
    )

    extension_base: ClassVar[type] = AbstractBearingExtension
    extension_classes: ClassVar[Mapping[str, type[AbstractBearingExtension]]] = EXTENSIONS
    extension_owner: ClassVar[str] = "the bearing"

    def __check_init__(self) -> None:
        if not self.segment_s > 0:
            raise ValueError(f"segment_s must be positive, got {self.segment_s!r}")
        if not (np.isfinite(self.sampling_rate_hz) and self.sampling_rate_hz > 2 * MODEL_TOP_HZ):
            raise ValueError(
                f"sampling_rate_hz={self.sampling_rate_hz!r}: the model describes the spectrum "
                f"up to {MODEL_TOP_HZ:g} Hz (the higher mode's upper bound), so the rate must "
                f"exceed {2 * MODEL_TOP_HZ:g} Hz; resample the records to a higher rate, or "
                "record at one"
            )
        if not 0 < self.load_zone_epsilon:
            raise ValueError(f"load_zone_epsilon must be positive, got {self.load_zone_epsilon}")

    @property
    def name(self) -> str:
        return "bearing"

    @property
    def base_parameters(self) -> tuple[ParameterSpec, ...]:
        """The model's own parameters (the extensions' follow them in :attr:`parameters`)."""
        return PARAMETERS

    @property
    def catalogue(self):
        """The bearing's catalogue of discrepancy causes (docs/bearing.md, "Diagnosis")."""
        return BEARING_CATALOGUE

    @property
    def states(self) -> dict[str, DamageSpec]:
        return dict(STATES)

    @property
    def channels(self) -> tuple[str, ...]:
        return ("DE",)

    @property
    def conditions(self) -> tuple[ConditionSpec, ...]:
        return CONDITIONS

    @property
    def features(self) -> SpectralFeatures:
        """Log-PSD bands over the resonance region (:data:`FEATURES`, docs/bearing.md), with
        Welch segments of the same duration at any sampling rate (the same bin widths)."""
        scale = self.sampling_rate_hz / FS
        return dataclasses.replace(
            FEATURES,
            nperseg=round(FEATURES.nperseg * scale),
            classifier_nperseg=round(FEATURES.classifier_nperseg * scale),
        )

    def settings(self) -> dict:
        """The bearing's geometry and sampling rate (JSON-able), which
        :meth:`with_settings` reads back: what a campaign of this bearing records."""
        return {
            "geometry": dataclasses.asdict(self.geometry),
            "sampling_rate_hz": self.sampling_rate_hz,
        }

    def with_settings(self, settings) -> BearingSystem:
        """This bearing with the geometry and sampling rate of :meth:`settings` (either may
        be left out).

        Raises
        ------
        ValueError
            For another key, a geometry with unknown or missing fields, or values the
            geometry or the system refuse.
        """
        unknown = sorted(set(settings) - {"geometry", "sampling_rate_hz"})
        if unknown:
            raise ValueError(
                f"unknown settings {unknown} of {self.name}: it takes geometry and sampling_rate_hz"
            )
        geometry = self.geometry
        if "geometry" in settings:
            try:
                geometry = BearingGeometry(**settings["geometry"])
            except TypeError as err:
                fields = ", ".join(f.name for f in dataclasses.fields(BearingGeometry))
                raise ValueError(f"geometry {settings['geometry']!r}: {err} ({fields})") from None
        rate = settings.get("sampling_rate_hz", self.sampling_rate_hz)
        if isinstance(rate, bool) or not isinstance(rate, int | float):
            raise ValueError(f"sampling_rate_hz must be a number (Hz), got {rate!r}")
        return dataclasses.replace(self, geometry=geometry, sampling_rate_hz=float(rate))

    def describe(self) -> dict:
        """Name, geometry and the model's fixed settings (JSON-able)."""
        return {
            "name": self.name,
            "extensions": self.extension_records(),
            "geometry": {
                "n_balls": self.geometry.n_balls,
                "ball_diameter_in": self.geometry.ball_diameter_in,
                "pitch_diameter_in": self.geometry.pitch_diameter_in,
                "contact_angle_deg": self.geometry.contact_angle_deg,
            },
            "sampling_rate_hz": self.sampling_rate_hz,
            "segment_s": self.segment_s,
            "seed": self.seed,
            "harmonic_ratios": list(self.harmonic_ratios),
            "load_zone_epsilon": self.load_zone_epsilon,
            "ball_inner_ratio": self.ball_inner_ratio,
            "entry_ratio": self.entry_ratio,
        }

    def training_points(self, points: np.ndarray) -> np.ndarray:
        """The campaign's points and the grid of :data:`TRAINING_SPEEDS_RPM` x
        :data:`TRAINING_LOADS_HP` (1700-1800 rpm, 0 and 3 hp), without repeats."""
        grid = np.array([(v, load) for v in TRAINING_SPEEDS_RPM for load in TRAINING_LOADS_HP])
        points = np.asarray(points, dtype=float).reshape(-1, len(CONDITIONS))
        return np.unique(np.concatenate([points, grid]), axis=0)

    def fault_frequencies(self, shaft_speed_rpm: float) -> dict[str, float]:
        """BPFO, BPFI, FTF and BSF (Hz) at a shaft speed in rpm, from the geometry."""
        return self.geometry.fault_frequencies(shaft_speed_rpm / 60.0)

    def signature_reference(self, signals, operating) -> dict | None:
        """The envelope rule (:class:`~bayesdoor.bearing.EnvelopeRule`) from healthy runs'
        ``DE`` signals, at :data:`SIGNATURE_FALSE_ALARM_RATE`, as a dict (``None``, no check,
        from fewer than :data:`SIGNATURE_MIN_RUNS` runs: too few for a prediction bound)."""
        from ._envelope import EnvelopeRule

        segments, rpm = _drive_end(signals, operating)
        if len(segments) < SIGNATURE_MIN_RUNS:
            return None
        rule = EnvelopeRule.from_healthy(
            segments,
            self.sampling_rate_hz,
            rpm,
            false_alarm_rate=SIGNATURE_FALSE_ALARM_RATE,
            geometry=self.geometry,
        )
        return rule.to_json()

    def signatures(self, reference, signals, operating) -> list[dict[str, bool | None]]:
        """Per run, whether its envelope lines agree with each state
        (:meth:`EnvelopeRule.agrees <bayesdoor.bearing.EnvelopeRule.agrees>`)."""
        from ._envelope import EnvelopeRule

        rule = EnvelopeRule.from_json(reference)
        segments, rpm = _drive_end(signals, operating)
        fs = self.sampling_rate_hz
        return [dict(rule.agrees(x, fs, float(s))) for x, s in zip(segments, rpm, strict=True)]

    def record_duration(self, operating) -> float:
        """The segment length, s, whatever the operating conditions."""
        return float(self.segment_s)

    def simulate_values(
        self,
        values,
        operating,
        *,
        state: str = "healthy",
        severity=None,
        duration: float | None = None,
        check: bool = True,
    ) -> SimulationResult:
        """A batch of runs as one vmapped, jitted computation.

        Parameters
        ----------
        values
            Every parameter by name (:attr:`parameters`), scalars or arrays of one value per
            run.
        operating
            ``(run, 2)``: shaft speed (rpm) and load (hp) of each run; ``(2,)`` for one run.
        state
            ``healthy``, ``inner_race``, ``outer_race`` or ``ball``.
        severity
            A fault's own parameters (:data:`FAULT_PARAMETERS`), scalars or one value per run:
            ``{"fault_size_in": ..., "impulse_amplitude": ..., "slip": ...,
            "unbalance_ratio": ...}``; those not given take :data:`FAULT_DEFAULTS`.
        duration
            Record length, s (default :attr:`segment_s`).
        check
            Check names, bounds and operating conditions on the host.

        Returns
        -------
        result
            Signals (run, 1, time) in m/s^2; the status of a run is 1 where its signal is not
            finite (its signal is then zero), else 0.
        """
        spec = self.check_state(state)
        severity = dict(severity or {})
        unknown = sorted(set(severity) - set(spec.severity))
        if unknown:
            raise ValueError(
                f"unknown severity {unknown} for state {state!r} of {self.name}: allowed "
                f"{', '.join(spec.severity) or 'none'}"
            )
        names = self.parameter_names()
        missing = [k for k in names if k not in values]
        extra = [k for k in values if k not in names]
        if missing or extra:
            raise ValueError(
                f"values must name every parameter of {self.name} ({', '.join(names)}); "
                f"missing {missing or 'none'}, unknown {extra or 'none'}"
            )
        op = jnp.atleast_2d(jnp.asarray(operating))
        if op.ndim != 2 or op.shape[-1] != len(CONDITIONS):
            raise ValueError(
                f"operating must have shape (run, {len(CONDITIONS)}) (columns "
                f"{', '.join(self.condition_names())}), got {np.shape(operating)}"
            )
        dtype = jnp.result_type(float)
        op = op.astype(dtype)
        runs = op.shape[0]
        fault = {**FAULT_DEFAULTS, **severity}
        if check:
            self._check_host(values, op, state, fault)
        p = {k: jnp.broadcast_to(jnp.asarray(values[k], dtype=dtype), (runs,)) for k in names}
        for k in FAULT_PARAMETERS:
            if k != "fault_size_in":
                p[k] = jnp.broadcast_to(jnp.asarray(fault[k], dtype=dtype), (runs,))
        size_arr = jnp.broadcast_to(jnp.asarray(fault["fault_size_in"], dtype=dtype), (runs,))
        fs = self.sampling_rate_hz
        n_time = round((self.segment_s if duration is None else float(duration)) * fs)
        signals, status = _simulate(self, p, op, size_arr, state, n_time)
        time = jnp.arange(n_time, dtype=dtype) / fs
        if self.output_extensions:
            signals = self.apply_output_extensions(signals, time, p)
            ok = jnp.all(jnp.isfinite(signals), axis=(-2, -1))
            status = jnp.where(ok, status, 1).astype(jnp.int32)
            signals = jnp.where(ok[:, None, None], signals, 0.0)
        return SimulationResult(signals=signals, status=status, time=time)

    def _check_host(self, values, op, state: str, fault) -> None:
        for spec in self.parameters:
            v = np.asarray(values[spec.name], dtype=float)
            spec.check(float(np.nan if not np.isfinite(v).all() else v.min()))
            spec.check(float(v.max()))
        self.check_operating(np.asarray(op))
        if state != "healthy":
            for name, (lo, hi) in FAULT_PARAMETERS.items():
                s = np.asarray(fault[name], dtype=float)
                if not (np.isfinite(s).all() and s.min() >= lo and s.max() <= hi):
                    raise ValueError(
                        f"{name}={s.ravel().tolist()} is outside its range [{lo}, {hi}] "
                        f"(a fault's own parameter of {self.name})"
                    )


def _drive_end(signals, operating) -> tuple[np.ndarray, np.ndarray]:
    """The runs' ``DE`` signals ``(run, time)`` and shaft speeds (rpm)."""
    rpm = np.atleast_2d(np.asarray(operating, dtype=float))[:, 0]
    return np.asarray(signals, dtype=float)[:, 0], rpm


def _float_bits(x: jax.Array) -> jax.Array:
    return jax.lax.bitcast_convert_type(x.astype(jnp.float32), jnp.uint32)


@persistent_jit
def _simulate(system: BearingSystem, p, op, size, state: str, n_time: int):
    geometry = system.geometry
    fs = system.sampling_rate_hz
    orders = geometry.orders()
    order = geometry.impulse_order(state) if state != "healthy" else 1.0
    slip_max = FAULT_PARAMETERS["slip"][1]
    rpm_max = CONDITIONS[0].upper
    capacity = impulse_capacity(n_time / fs, order, 1.5 * rpm_max / 60.0, slip_max)
    base = jax.random.PRNGKey(system.seed)
    runs = op.shape[0]

    shaft = next((e for e in system.extensions if isinstance(e, ShaftHarmonics)), None)

    def one(p_run, op_run, size_run, index):
        key = jax.random.fold_in(base, index)
        key = jax.random.fold_in(key, _float_bits(op_run[0]))
        key = jax.random.fold_in(key, _float_bits(op_run[1]))
        return run_signal(
            p_run,
            op_run[0] / 60.0,
            size_run,
            key,
            state=state,
            n_time=n_time,
            fs=fs,
            order=order,
            ftf_order=orders["ftf"],
            surface_speed_per_hz=geometry.surface_speed_per_hz(),
            n_impulses=capacity,
            harmonics=system.harmonic_ratios,
            epsilon=system.load_zone_epsilon,
            ball_inner_ratio=system.ball_inner_ratio,
            entry_ratio=system.entry_ratio,
            extra_harmonics=None if shaft is None else shaft.amplitudes(p_run),
        )

    x = jax.vmap(one)(p, op, size, jnp.arange(runs, dtype=jnp.uint32))
    ok = jnp.all(jnp.isfinite(x), axis=-1)
    status = jnp.where(ok, 0, 1).astype(jnp.int32)
    x = jnp.where(ok[:, None], x, 0.0)
    return x[:, None, :], status
