"""The reference elevator door as a :class:`~bayesdoor.systems.AbstractSystem`."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._types import Array, Float
from ..systems import (
    ConditionSpec,
    DamageSpec,
    ExtensionHost,
    ParameterSpec,
    SimulationResult,
)
from . import _geometry as g
from ._extensions import EXTENSIONS, AbstractDoorExtension
from ._model import make_args
from ._params import PARAMETERS, STATES, DoorDamage, DoorParameters, check_parameter_values
from ._profile import max_speed_limit, motion_duration, record_duration
from ._simulate import (
    STATUS_MESSAGES,
    STATUS_OK,
    SolverConfig,
    rest_modes,
    sample_times,
    solve,
    solve_batch,
)

V_MAX_RANGE = (0.1, round(max_speed_limit(), 3))


#: the door's one operating condition: the commanded peak speed of the S-curve (above the upper
#: bound the S-curve of the stroke has no cruise phase)
SPEED = ConditionSpec(
    "v_max",
    "m/s",
    *V_MAX_RANGE,
    description="commanded peak speed",
)


def check_speed(v_max) -> None:
    """Raise ``ValueError`` naming the speed and the allowed range."""
    lo, hi = V_MAX_RANGE
    for v in np.atleast_1d(np.asarray(v_max, dtype=float)):
        if not np.isfinite(v) or not lo <= v <= hi:
            raise ValueError(
                f"v_max={float(v)!r} m/s is outside the allowed range [{lo}, {hi}] m/s "
                f"(the S-curve of a {g.STROKE} m stroke with a = {g.ACCELERATION} m/s^2 and "
                f"j = {g.JERK} m/s^3 has no cruise phase above {hi} m/s)"
            )


class ElevatorDoor(ExtensionHost):
    """The reduced-order elevator landing door of the paper (``docs/model.md``).

    Parameters
    ----------
    config
        How the equations are integrated.
    extensions
        Model extensions from the discrepancy catalogue (``FrameMode()``,
        ``WheelEccentricity(wheel="left")``, ...), at most one of each; default none, the
        base model of the paper. Their parameters follow Table 2 in :attr:`parameters`.

    Examples
    --------
    >>> door = ElevatorDoor()
    >>> res = door.simulate(DoorParameters.paper_optimum(), DoorDamage.healthy(), 0.4)
    >>> res.signals.shape  # (channel, time)
    (4, 6349)
    >>> ElevatorDoor().with_extensions("mains_hum").parameter_names()[8]
    'mains_hum.amplitude_A1X'
    """

    config: SolverConfig = SolverConfig()
    extensions: tuple[AbstractDoorExtension, ...] = eqx.field(
        static=True, default=(), converter=tuple
    )

    extension_base: ClassVar[type] = AbstractDoorExtension
    extension_classes: ClassVar[Mapping[str, type[AbstractDoorExtension]]] = EXTENSIONS
    extension_owner: ClassVar[str] = "the door"

    @property
    def catalogue(self):
        """The door's catalogue of discrepancy causes (``docs/model.md``), for diagnosis."""
        # imported here: the catalogue pulls in the diagnosis and inference layers, which
        # simulating the door does not need
        from ._catalogue import DOOR_CATALOGUE

        return DOOR_CATALOGUE

    @property
    def name(self) -> str:
        return "elevator_door"

    @property
    def base_parameters(self) -> tuple[ParameterSpec, ...]:
        """Table 2 (the extensions' parameters follow it in :attr:`parameters`)."""
        return PARAMETERS

    def describe(self) -> dict:
        """Name, solver settings and every extension with its configuration (JSON-able)."""
        return {
            "name": self.name,
            "config": {
                f.name: getattr(self.config, f.name) for f in dataclasses.fields(SolverConfig)
            },
            "extensions": self.extension_records(),
        }

    def _extension_values(self, values) -> dict[str, Array]:
        """Extension parameters by full name; missing ones at their (inert) nominal values."""
        specs = {p.name: p for e in self.extensions for p in e.parameters}
        values = {} if values is None else dict(values)
        unknown = [k for k in values if k not in specs]
        if unknown:
            raise ValueError(
                f"extension_values names {unknown}, which are not parameters of this door's "
                f"extensions ({', '.join(specs) or 'none switched on'})"
            )
        return {k: jnp.asarray(values.get(k, p.nominal), dtype=float) for k, p in specs.items()}

    def _check_extension_values(self, values: Mapping[str, Array]) -> None:
        specs = {p.name: p for e in self.extensions for p in e.parameters}
        for name, value in values.items():
            for v in np.atleast_1d(np.asarray(value, dtype=float)).ravel():
                specs[name].check(v)

    @property
    def states(self) -> Mapping[str, DamageSpec]:
        return STATES

    @property
    def channels(self) -> tuple[str, ...]:
        return g.CHANNELS

    @property
    def sampling_rate_hz(self) -> float:
        return g.SAMPLING_RATE_HZ

    @property
    def conditions(self) -> tuple[ConditionSpec, ...]:
        return (SPEED,)

    def record_duration(self, v_max) -> float:
        """Record length (s) for runs at these speeds: rest, the slowest stroke, rest."""
        check_speed(v_max)
        return record_duration(v_max)

    def _dtype(self):
        return jnp.float32 if self.config.dtype == "float32" else jnp.float64

    def simulate(
        self,
        theta: DoorParameters,
        damage: DoorDamage,
        operating,
        *,
        duration: float | None = None,
        extension_values: Mapping[str, float] | None = None,
    ) -> SimulationResult:
        """Simulate one run; raises ``RuntimeError`` with the cause if the solve fails.

        Parameters
        ----------
        theta
            Table 2 parameters (scalars).
        damage
            Damage severities (``DoorDamage.healthy()``, ``DoorDamage.for_state("D2", ...)``).
        operating
            Peak door speed v_max (m/s).
        duration
            Record length in seconds; default: 0.25 s rest, the stroke, 0.25 s rest.
        extension_values
            Parameters of the :attr:`extensions` by full name; missing ones at their nominal
            values, which switch the extension off.
        """
        ext = self._extension_values(extension_values)
        check_parameter_values(theta.to_dict())
        self._check_extension_values(ext)
        check_speed(operating)
        duration = record_duration(operating) if duration is None else float(duration)
        ts = sample_times(duration, dtype=self._dtype())
        args = make_args(
            theta,
            damage,
            operating,
            dtype=self._dtype(),
            extensions=self.extensions,
            extension_values=ext,
        )
        signals, status = solve(args, ts, self.config)
        code = int(status)
        if code != STATUS_OK:
            raise RuntimeError(f"door simulation failed: {STATUS_MESSAGES[code]}")
        signals = self.apply_output_extensions(signals, ts, ext)
        return SimulationResult(signals=signals, status=status, time=ts)

    def simulate_batch(
        self,
        theta: DoorParameters,
        damage: DoorDamage,
        operating: Float[Array, " batch"],
        *,
        duration: float | None = None,
        check: bool = True,
        extension_values: Mapping[str, Float[Array, "*batch"] | float] | None = None,
    ) -> SimulationResult:
        """Simulate a batch of runs as one vmapped solve.

        Every leaf of ``theta`` and ``damage``, every extension value and ``operating`` is
        broadcast to a common batch size. Failed solves do not raise: their ``status`` is
        non-zero and their signals zero. Set ``check=False`` inside likelihoods (no host
        round-trip for bounds checks). ``extension_values`` as in :meth:`simulate`.
        """
        signals, status, ts, _ = self._batch(
            theta, damage, operating, duration, check, extension_values, ()
        )
        return SimulationResult(signals=signals, status=status, time=ts)

    def _batch(self, theta, damage, operating, duration, check, extension_values, gains):
        """:meth:`simulate_batch`'s solve: signals, status, times and, for ``gains``, the
        signal each gain scales (see :meth:`simulate_gains`; ``None`` without gains)."""
        ext = self._extension_values(extension_values)
        v = jnp.atleast_1d(jnp.asarray(operating, dtype=self._dtype()))
        if check:
            check_parameter_values(theta.to_dict())
            self._check_extension_values(ext)
            check_speed(np.asarray(v))
        leaves = [*jax.tree_util.tree_leaves((theta, damage)), *ext.values(), v]
        size = max(int(np.size(x)) for x in leaves)
        duration = record_duration(np.asarray(v)) if duration is None else float(duration)
        ts = sample_times(duration, dtype=self._dtype())

        def widen(x):
            return jnp.broadcast_to(jnp.asarray(x), (size,))

        theta_b = jax.tree_util.tree_map(widen, theta)
        damage_b = jax.tree_util.tree_map(widen, damage)
        ext_b = {k: widen(x) for k, x in ext.items()}
        args = jax.vmap(
            lambda p, d, vm, e: make_args(
                p, d, vm, dtype=self._dtype(), extensions=self.extensions, extension_values=e
            )
        )(theta_b, damage_b, widen(v), ext_b)
        signals, status = solve_batch(args, ts, self.config, tuple(gains))
        n = len(self.channels)
        signals, slope = signals[:, :n], (signals[:, n:] if gains else None)
        ok = (status == STATUS_OK)[:, None, None]
        if self.output_extensions:
            # they are affine in the signals (a leak, a mode driven by the channels, an
            # additive line): a gain's signal passes as the difference it makes
            extended = self.apply_output_extensions(signals, ts, ext_b)
            if slope is not None:
                on = self.apply_output_extensions(signals + slope, ts, ext_b)
                slope = jnp.where(ok, on - extended, 0.0)
            signals = jnp.where(ok, extended, 0.0)
        return signals, status, ts, slope

    def simulate_gains(self, values, operating, gains, *, duration=None, check=True):
        """Runs with the ``gains`` at zero and the signal each gain scales, from one solve.

        For gains of extensions solved with the door (a rail-carrying mode's
        participations), the solve also returns the sensors' derivative along the gains
        (:func:`~bayesdoor.door.solve`); others take the generic two simulations.
        """
        gains = tuple(gains)
        solved = {p.name for e in self.extensions if e.needs_resolve for p in e.parameters}
        if not gains or not set(gains) <= solved:
            return super().simulate_gains(values, operating, gains, duration=duration, check=check)
        theta, damage, ext = self._from_values({**values, **dict.fromkeys(gains, 0.0)})
        signals, status, ts, slope = self._batch(
            theta, damage, operating, duration, check, ext, gains
        )
        return SimulationResult(signals=signals, status=status, time=ts), slope

    def motion_window(
        self, operating, *, duration: float | None = None
    ) -> tuple[Float[np.ndarray, " run"], Float[np.ndarray, " run"]]:
        """The commanded stroke of each run: from the end of the initial rest to its stop.

        The start is the end of the 0.25 s rest, the stop the end of the S-curve at this peak
        speed (the same window ``bayesdoor simulate`` writes as ``t_start``/``t_stop``),
        clipped to ``duration`` when given.
        """
        v = np.atleast_1d(np.asarray(operating, dtype=float))
        check_speed(v)
        t_start = np.full(v.shape, g.REST_S)
        t_stop = g.REST_S + np.asarray(motion_duration(v), dtype=float)
        if duration is not None:
            t_stop = np.minimum(t_stop, float(duration))
            if np.any(t_stop <= t_start):
                raise ValueError(
                    f"duration={duration} s ends before the motion starts at {g.REST_S} s: "
                    "pass a longer duration"
                )
        return t_start, t_stop

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
        """A batch of runs from every parameter's value by name (see :meth:`simulate_batch`).

        ``values`` names Table 2 and every extension parameter (:meth:`parameter_names`).
        """
        theta, damage, ext = self._from_values(values, state, severity)
        return self.simulate_batch(
            theta, damage, operating, duration=duration, check=check, extension_values=ext
        )

    def rest_modes(self, values: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """Frequencies (Hz, damped) and damping ratios of the healthy door's modes at rest.

        The equations (with the extensions that have coordinates of their own, such as a
        frame mode that carries the rail) linearised at the static equilibrium; ``values``
        names every parameter, as for :meth:`simulate_values`. A mode coupled to the door
        through the wheel contact is found here at its installed frequency, which is the
        peak a measurement shows, not at its bare one.

        Examples
        --------
        >>> from bayesdoor.door import DoorParameters, ElevatorDoor
        >>> from bayesdoor.door import CoupledFrameMode
        >>> door = ElevatorDoor().with_extensions(CoupledFrameMode())
        >>> values = {p.name: p.nominal for p in door.parameters}
        >>> values.update(DoorParameters.paper_optimum().to_dict())
        >>> values.update({"frame_mode.frequency_hz": 40.0, "frame_mode.rail_lift": 0.0})
        >>> f, zeta = door.rest_modes(values)
        >>> bool(abs(f[abs(f - 40.0).argmin()] - 40.0) < 0.01)  # no lift: the bare mode
        True
        """
        theta, damage, ext = self._from_values(values)
        # any speed: at t = 0 the drive rests at the closed position whatever its peak speed
        args = make_args(
            theta,
            damage,
            0.4,
            dtype=self._dtype(),
            extensions=self.extensions,
            extension_values=self._extension_values(ext),
        )
        return rest_modes(args)

    def _from_values(self, values, state: str = "healthy", severity=None):
        """Table 2 parameters, damage and extension values of :meth:`simulate_values`."""
        names = self.parameter_names()
        missing = [k for k in names if k not in values]
        unknown = [k for k in values if k not in names]
        if missing or unknown:
            raise ValueError(
                f"values must name every parameter of {self.name} ({', '.join(names)}); "
                f"missing {missing or 'none'}, unknown {unknown or 'none'}"
            )
        spec = self.check_state(state)
        severity = {} if severity is None else dict(severity)
        extra = [k for k in severity if k not in spec.severity]
        if extra:
            raise ValueError(
                f"state {state} takes severities {list(spec.severity) or 'none'}, got {extra}"
            )
        levels = {k: severity.get(k, 0.5 * (lo + hi)) for k, (lo, hi) in spec.severity.items()}
        damage = DoorDamage(
            **{k: jnp.asarray(levels.get(k, 0.0)) for k in ("d1_height", "d2_depth", "d2_angle")}
        )
        theta = DoorParameters(
            **{
                p.name: jnp.asarray(values[p.name]).astype(jnp.int32 if p.integer else float)
                for p in PARAMETERS
            }
        )
        ext = {p.name: values[p.name] for e in self.extensions for p in e.parameters}
        return theta, damage, ext
