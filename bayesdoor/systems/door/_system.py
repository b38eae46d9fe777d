"""The reference elevator door as a :class:`~bayesdoor.systems.AbstractSystem`."""

from __future__ import annotations

from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from ..._types import Array, Float
from .._base import AbstractSystem, DamageSpec, ParameterSpec, SimulationResult
from . import _geometry as g
from ._model import make_args
from ._params import PARAMETERS, STATES, DoorDamage, DoorParameters, check_parameter_values
from ._profile import max_speed_limit, motion_duration, record_duration
from ._simulate import STATUS_MESSAGES, STATUS_OK, SolverConfig, sample_times, solve, solve_batch

V_MAX_RANGE = (0.1, round(max_speed_limit(), 3))


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


class ElevatorDoor(AbstractSystem):
    """The reduced-order elevator landing door of the paper (DESIGN.md section 2).

    Examples
    --------
    >>> door = ElevatorDoor()
    >>> res = door.simulate(DoorParameters.paper_optimum(), DoorDamage.healthy(), 0.4)
    >>> res.signals.shape  # (channel, time)
    (4, 6349)
    """

    config: SolverConfig = SolverConfig()

    @property
    def name(self) -> str:
        return "elevator_door"

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        return PARAMETERS

    @property
    def states(self) -> Mapping[str, DamageSpec]:
        return STATES

    @property
    def channels(self) -> tuple[str, ...]:
        return g.CHANNELS

    @property
    def sampling_rate_hz(self) -> float:
        return g.SAMPLING_RATE_HZ

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
        """
        check_parameter_values(theta.to_dict())
        check_speed(operating)
        duration = record_duration(operating) if duration is None else float(duration)
        ts = sample_times(duration, dtype=self._dtype())
        args = make_args(theta, damage, operating, dtype=self._dtype())
        signals, status = solve(args, ts, self.config)
        code = int(status)
        if code != STATUS_OK:
            raise RuntimeError(f"door simulation failed: {STATUS_MESSAGES[code]}")
        return SimulationResult(signals=signals, status=status, time=ts)

    def simulate_batch(
        self,
        theta: DoorParameters,
        damage: DoorDamage,
        operating: Float[Array, " batch"],
        *,
        duration: float | None = None,
        check: bool = True,
    ) -> SimulationResult:
        """Simulate a batch of runs as one vmapped solve.

        Every leaf of ``theta`` and ``damage`` and ``operating`` is broadcast to a common batch
        size. Failed solves do not raise: their ``status`` is non-zero and their signals zero.
        Set ``check=False`` inside likelihoods (no host round-trip for bounds checks).
        """
        v = jnp.atleast_1d(jnp.asarray(operating, dtype=self._dtype()))
        if check:
            check_parameter_values(theta.to_dict())
            check_speed(np.asarray(v))
        leaves = [*jax.tree_util.tree_leaves((theta, damage)), v]
        size = max(int(np.size(x)) for x in leaves)
        duration = record_duration(np.asarray(v)) if duration is None else float(duration)
        ts = sample_times(duration, dtype=self._dtype())

        def widen(x):
            return jnp.broadcast_to(jnp.asarray(x), (size,))

        theta_b = jax.tree_util.tree_map(widen, theta)
        damage_b = jax.tree_util.tree_map(widen, damage)
        args = jax.vmap(lambda p, d, vm: make_args(p, d, vm, dtype=self._dtype()))(
            theta_b, damage_b, widen(v)
        )
        signals, status = solve_batch(args, ts, self.config)
        return SimulationResult(signals=signals, status=status, time=ts)

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
        """A batch of runs from the Table 2 values by name (see :meth:`simulate_batch`)."""
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
                for p in self.parameters
            }
        )
        return self.simulate_batch(theta, damage, operating, duration=duration, check=check)
