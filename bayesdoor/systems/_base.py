"""The generic system interface: what inference, data generation and diagnosis may rely on.

A system is a simulator (parameters -> sensor signals) with a parameter space, damage modes and a
sensor layout. Nothing in this module knows about doors, wheels or rails.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Mapping, Sequence

import equinox as eqx
import numpy as np

from .._types import Array, Float, Int

#: the label of the undamaged state of a system that names no other
#: (:attr:`AbstractSystem.healthy`), and of files written without one
HEALTHY = "healthy"

#: the Welch segments of a record by default (:meth:`AbstractSystem.record_duration`)
DEFAULT_RECORD_SEGMENTS = 8


@dataclasses.dataclass(frozen=True)
class ParameterSpec:
    """One updatable parameter: name, unit, nominal value and bounds (inclusive)."""

    name: str
    unit: str
    nominal: float
    lower: float
    upper: float
    description: str = ""
    integer: bool = False
    reference_value: float | None = None

    def check(self, value: float) -> None:
        """Raise ``ValueError`` naming the value and the allowed range when out of bounds."""
        v = float(value)
        if not np.isfinite(v) or not self.lower <= v <= self.upper:
            unit = f" {self.unit}" if self.unit and self.unit != "-" else ""
            raise ValueError(
                f"parameter {self.name}={v!r}{unit} is outside its allowed range "
                f"[{self.lower}, {self.upper}]{unit} ({self.description})"
            )
        if self.integer and v != round(v):
            raise ValueError(f"parameter {self.name}={v!r} must be an integer")


@dataclasses.dataclass(frozen=True)
class ConditionSpec:
    """One operating condition of a run (a door's peak speed, a shaft's speed or load).

    Campaigns store it per run under ``name``; ``lower`` and ``upper`` bound what the model
    can simulate (inclusive). ``positive``: the format requires a value above zero.
    """

    name: str
    unit: str
    lower: float
    upper: float
    description: str = ""
    positive: bool = True

    def check(self, values) -> None:
        """Raise ``ValueError`` naming the first value outside ``[lower, upper]``."""
        unit = f" {self.unit}" if self.unit and self.unit != "-" else ""
        for v in np.atleast_1d(np.asarray(values, dtype=float)).ravel():
            if not np.isfinite(v) or not self.lower <= v <= self.upper:
                raise ValueError(
                    f"{self.name}={float(v)!r}{unit} is outside the range the model simulates, "
                    f"[{self.lower:g}, {self.upper:g}]{unit} ({self.description})"
                )


@dataclasses.dataclass(frozen=True)
class SpectralFeatures:
    """What fitting and classification compare, as a system declares it: log Welch PSDs.

    The fit compares band means of the log10 Welch PSD (``nperseg`` samples per segment)
    from ``f_low`` to ``f_high`` in bands of ``band_width`` Hz
    (:class:`bayesdoor.inference.FeatureSpec`); the classifier sees each channel's log10
    Welch PSD from 0 Hz to ``classifier_fmax`` with ``classifier_nperseg`` samples per segment
    (:class:`bayesdoor.features.CNNInputSpec`), or, with ``classifier_envelope_band``
    (``(low, high)`` Hz), the log10 Welch PSD of each channel's envelope in that band (the
    input of rolling-element bearing diagnostics). The defaults are the elevator door
    paper's: 4-96 Hz in 4 Hz bands at 2048 Hz sampling.
    """

    f_low: float = 4.0
    f_high: float = 96.0
    band_width: float = 4.0
    nperseg: int = 512
    classifier_fmax: float = 96.0
    classifier_nperseg: int = 512
    classifier_envelope_band: tuple[float, float] | None = None


@dataclasses.dataclass(frozen=True)
class DamageSpec:
    """A damage mode (or the healthy state) with its severity parameters and their priors.

    ``severity`` maps each severity parameter to its (lower, upper) uniform prior range.
    """

    name: str
    description: str
    severity: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)


class SimulationResult(eqx.Module):
    """Sensor signals of one or more runs and the solver status of each.

    ``status`` is 0 for a successful solve; any other value is a diffrax result code (for
    example max_steps reached), in which case ``signals`` of that run are not meaningful.
    """

    signals: Float[Array, "*batch channel time"]
    status: Int[Array, "*batch"]
    time: Float[Array, " time"]

    @property
    def ok(self):
        return self.status == 0


class AbstractSystem(eqx.Module):
    """Interface every simulated system implements.

    A system whose :attr:`healthy` is not one of its :attr:`states` is refused when it is
    built (``ValueError``).
    """

    def __check_init__(self):
        if self.healthy not in self.states:
            raise ValueError(
                f"system {self.name}: its healthy state {self.healthy!r} is not one of its "
                f"states ({', '.join(self.states)}); name the undamaged state in `states`, or "
                "set `healthy` to the one that is"
            )

    @property
    @abc.abstractmethod
    def name(self) -> str: ...

    @property
    @abc.abstractmethod
    def parameters(self) -> Sequence[ParameterSpec]: ...

    @property
    @abc.abstractmethod
    def states(self) -> Mapping[str, DamageSpec]: ...

    @property
    def healthy(self) -> str:
        """The label of the undamaged state, one of :attr:`states` (default :data:`HEALTHY`).

        The state the calibration runs are measured in and the model is updated on; the
        generic layers know the undamaged state only by this name.
        """
        return HEALTHY

    @property
    @abc.abstractmethod
    def channels(self) -> tuple[str, ...]: ...

    @property
    @abc.abstractmethod
    def conditions(self) -> tuple[ConditionSpec, ...]:
        """The operating conditions of a run, in the order of ``operating``'s columns.

        Every method that takes ``operating`` takes one value per run for a single condition
        (shape ``(run,)``), and ``(run, len(conditions))`` for several.
        """

    @property
    @abc.abstractmethod
    def sampling_rate_hz(self) -> float: ...

    def simulate(
        self, theta, damage, operating, *, duration: float | None = None
    ) -> SimulationResult:
        """Runs for parameter values ``theta`` (by name), a damage and operating conditions.

        ``damage`` is a state's name (the severity :meth:`simulate_values` defaults to) or a
        pair ``(state, {severity: value})``. Default: :meth:`simulate_values`; a system whose users
        think in other terms (a parameter record, a damage object) overrides it.
        """
        state, severity = (damage, None) if isinstance(damage, str) else damage
        return self.simulate_values(
            theta, operating, state=state, severity=severity, duration=duration
        )

    def record_duration(self, operating) -> float:
        """Record length (s) that holds whole runs at every one of these operating conditions.

        Default: :data:`DEFAULT_RECORD_SEGMENTS` Welch segments of the fit's features (their
        ``nperseg`` samples at :attr:`sampling_rate_hz`), whatever the conditions: a
        stationary system's record, long enough for a Welch estimate averaged over twice as
        many half-overlapping segments less one. A system whose runs have a length of their
        own (a door's stroke at its speed) overrides it.
        """
        return DEFAULT_RECORD_SEGMENTS * self.features.nperseg / self.sampling_rate_hz

    def motion_window(
        self, operating, *, duration: float | None = None
    ) -> tuple[Float[np.ndarray, " run"], Float[np.ndarray, " run"]]:
        """Start and stop (s) of the motion in simulated runs at these operating conditions.

        The window in which the system is excited (for example the stroke of a drive), in the
        time of the simulated record; with ``duration`` given, the stop is clipped to it.
        Default: the whole record, from its first sample to its last (a system excited
        throughout: a turning shaft, a vehicle on a road).
        """
        values = np.asarray(operating, dtype=float)
        runs = (
            np.atleast_1d(values).shape
            if len(self.conditions) == 1
            else np.atleast_2d(values).shape[:-1]
        )
        seconds = self.record_duration(operating) if duration is None else float(duration)
        n_time = round(seconds * self.sampling_rate_hz)
        return np.zeros(runs), np.full(runs, (n_time - 1) / self.sampling_rate_hz)

    @abc.abstractmethod
    def simulate_values(
        self,
        values: Mapping[str, Float[Array, "*batch"] | float],
        operating: Float[Array, " batch"] | float,
        *,
        state: str,
        severity: Mapping[str, Float[Array, "*batch"] | float] | None = None,
        duration: float | None = None,
        check: bool = True,
    ) -> SimulationResult:
        """A batch of runs from plain arrays, as one vmapped solve.

        This is the entry point of the generic layers (inference, data generation): they know
        the parameters only by the names of :attr:`parameters` and the damage by the names of
        :attr:`states` and their severities.

        Parameters
        ----------
        values
            Every parameter of :attr:`parameters` by name; scalars or arrays that broadcast to
            the batch.
        operating
            The operating condition of each run (for example a speed).
        state
            The damage state, a key of :attr:`states` (:attr:`healthy` for the undamaged
            system: a system may default to it, the generic layers always name it).
        severity
            Its severity parameters by name (missing ones: the middle of their prior range).
        duration
            Record length (s); default :meth:`record_duration` of ``operating``.
        check
            Check names and bounds on the host (``False`` inside jitted likelihoods).

        Returns
        -------
        result
            Signals (batch, channel, time) and a status per run; a failed solve does not raise:
            its status is non-zero and its signals are zero.
        """

    def simulate_gains(
        self,
        values: Mapping[str, Float[Array, "*batch"] | float],
        operating: Float[Array, " batch"] | float,
        gains: Sequence[str],
        *,
        duration: float | None = None,
        check: bool = True,
    ) -> tuple[SimulationResult, Float[Array, "batch channel time"]]:
        """Runs with the ``gains`` at zero, and the signal each gain scales.

        A gain is a parameter that scales one signal added to one channel only (a mode's
        participation on a channel): the signals are linear in it and the dynamics do not
        depend on it. Returns the healthy runs of :meth:`simulate_values` with every gain at
        zero and d(signals)/d(gain) summed over the gains, which holds each gain's signal on
        its own channel. This default simulates twice (gains at 0 and at 1); a system may
        get both from one simulation.
        """
        off = {**values, **dict.fromkeys(gains, 0.0)}
        on = {**values, **dict.fromkeys(gains, 1.0)}
        healthy = self.healthy
        zero = self.simulate_values(off, operating, state=healthy, duration=duration, check=check)
        one = self.simulate_values(on, operating, state=healthy, duration=duration, check=check)
        return zero, one.signals - zero.signals

    @property
    def features(self) -> SpectralFeatures:
        """What fitting and classification compare (default: :class:`SpectralFeatures`'s)."""
        return SpectralFeatures()

    def training_points(self, points: np.ndarray) -> np.ndarray:
        """The operating points the job's training data are simulated at.

        ``points``: the campaign's distinct operating points (``(point,)`` for one condition,
        ``(point, condition)`` for several). Default: those points. A system whose users run
        it at other conditions than the measured ones returns more (keep the campaign's: the
        OOD detector compares the calibration runs with simulations at their own points).
        """
        return points

    def signature_reference(
        self, signals: Float[np.ndarray, "run channel time"], operating
    ) -> dict | None:
        """The reference of the system's physical damage signatures, from healthy runs.

        A system whose damage states leave a signature that a check without learning reads
        in the signal (a bearing's envelope lines at its kinematic fault frequencies) returns
        what :meth:`signatures` needs, as a JSON-able dict, from the healthy calibration
        runs' ``signals`` (in :attr:`channels` order) at their ``operating`` points. Default:
        ``None``, no such check. A reference that holds ``false_alarm_rate`` (the share of
        right calls the check contradicts) lets the job's trust stage warn when many more
        calls are contradicted than that.
        """
        return None

    def signatures(
        self, reference: dict, signals: Float[np.ndarray, "run channel time"], operating
    ) -> list[dict[str, bool | None]]:
        """Per run, per damage state, whether the run's signal agrees with that state.

        ``True``: the state's signature shows (for the healthy state: no damage signature
        shows); ``False``: it does not, at the check's stated false-alarm rate; ``None``: the
        check says nothing of that state. A classification whose call the signal does not
        agree with is flagged (docs/classification.md, "Signature check"). Only called with a
        ``reference`` from :meth:`signature_reference`.

        Raises
        ------
        NotImplementedError
            For a system without a signature check.
        """
        raise NotImplementedError(f"{self.name} has no signature check")

    @property
    def catalogue(self):
        """The system's catalogue of discrepancy causes, for diagnosis (a
        :class:`bayesdoor.diagnose.Catalogue`); ``None`` for a system without one."""
        return None

    @property
    def extension_names(self) -> tuple[str, ...]:
        """Catalogue names of the model extensions switched on (none by default)."""
        return ()

    def with_extensions(self, *extensions) -> AbstractSystem:
        """The same system with model extensions (catalogue names or modules) switched on.

        Raises
        ------
        ValueError
            Always, for a system without a catalogue of model extensions.
        """
        raise ValueError(
            f"{self.name} has no model extensions, so {extensions!r} cannot be switched on"
        )

    def without_output_extensions(self) -> AbstractSystem:
        """The system with only the extensions that act inside the simulation (see below)."""
        return self

    def apply_output_extensions(
        self,
        signals: Float[Array, "*batch channel time"],
        time: Float[Array, " time"],
        values: Mapping[str, Float[Array, "*batch"] | float],
    ) -> Float[Array, "*batch channel time"]:
        """Signals of :meth:`without_output_extensions` with the output extensions applied.

        Extensions that act on the sensor signals only (not inside the solve) can be refitted
        on signals simulated once; ``values`` names at least their parameters. Without such
        extensions the signals are returned unchanged.
        """
        return signals

    def settings(self) -> dict:
        """The settings that make this system one of several of its name (a bearing's
        geometry and sampling rate), JSON-able: what :meth:`with_settings` reads back. A
        campaign of a system that differs from the registered one records them in
        ``attrs['system_settings']`` (JSON), and :func:`bayesdoor.io.system_of` applies them.
        Default: none."""
        return {}

    def with_settings(self, settings: Mapping) -> AbstractSystem:
        """This system with ``settings`` (as :meth:`settings` writes them) applied.

        Raises
        ------
        ValueError
            For settings the system does not take (by default: any).
        """
        if settings:
            raise ValueError(f"{self.name} takes no settings, got {sorted(settings)}")
        return self

    def describe(self) -> dict:
        """A JSON-able description (name, extensions) for provenance and configuration hashes."""
        return {"name": self.name, "extensions": []}

    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    def nominal(self) -> dict[str, float]:
        return {p.name: p.nominal for p in self.parameters}

    def check_parameters(self, values: Mapping[str, float]) -> None:
        """Raise ``ValueError`` for unknown names or out-of-bounds values."""
        specs = {p.name: p for p in self.parameters}
        for k, v in values.items():
            if k not in specs:
                raise ValueError(
                    f"unknown parameter {k!r} for system {self.name}: allowed {', '.join(specs)}"
                )
            specs[k].check(v)

    def condition_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.conditions)

    def check_operating(self, operating) -> None:
        """Raise ``ValueError`` for operating conditions the model cannot simulate."""
        values = np.asarray(operating, dtype=float)
        if len(self.conditions) == 1:
            self.conditions[0].check(values)
            return
        values = np.atleast_2d(values)
        if values.shape[-1] != len(self.conditions):
            raise ValueError(
                f"operating has {values.shape[-1]} columns; {self.name} has the conditions "
                f"{', '.join(self.condition_names())}"
            )
        for i, spec in enumerate(self.conditions):
            spec.check(values[..., i])

    def check_state(self, state: str) -> DamageSpec:
        if state not in self.states:
            raise ValueError(
                f"unknown state {state!r} for system {self.name}: allowed {', '.join(self.states)}"
            )
        return self.states[state]
