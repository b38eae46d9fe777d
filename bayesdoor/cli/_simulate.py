"""``bayesdoor simulate`` and the interim ``bayesdoor demo``: runs of the reduced door model."""

from __future__ import annotations

import numpy as np

from ._common import fail


def _parse_overrides(items: list[str]) -> dict[str, float]:
    out = {}
    for item in items:
        if "=" not in item:
            raise fail(f"--param takes NAME=VALUE (e.g. K=1863), got {item!r}")
        name, value = item.split("=", 1)
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise fail(f"--param {name}: {value!r} is not a number") from None
    return out


def simulate_campaign(states, v_max, *, seed: int, params: dict[str, float], dtype: str, progress):
    """Simulate one run per (state, speed) entry with the reduced door model.

    Severities of D1/D2 are drawn from their documented uniform priors with ``seed``.
    Returns the campaign dataset (``bayesdoor.io.make_campaign``).
    """
    import jax.numpy as jnp

    from ..door import (
        STATES,
        DoorDamage,
        DoorParameters,
        ElevatorDoor,
        SolverConfig,
        motion_duration,
    )
    from ..io import make_campaign

    door = ElevatorDoor(SolverConfig(dtype=dtype))
    optimum = {k: float(v) for k, v in DoorParameters.paper_optimum().to_dict().items()}
    try:
        theta = DoorParameters.from_dict({**optimum, **params})
    except ValueError as err:
        raise fail(str(err)) from None
    rng = np.random.default_rng(seed)
    severities: dict[str, list[float]] = {"d1_height": [], "d2_depth": [], "d2_angle": []}
    for state in states:
        spec = STATES[state]
        for name in severities:
            lo, hi = spec.severity.get(name, (0.0, 0.0))
            severities[name].append(rng.uniform(lo, hi) if hi > lo else 0.0)
    damage = DoorDamage(**{k: jnp.asarray(v) for k, v in severities.items()})
    duration = door.record_duration(v_max)
    with progress(f"simulating {len(states)} runs"):
        res = door.simulate_batch(theta, damage, jnp.asarray(v_max), duration=duration)
    status = np.asarray(res.status)
    if np.any(status != 0):
        bad = np.flatnonzero(status)
        raise fail(f"the solve failed for runs {bad.tolist()} (status {status[bad].tolist()})")
    t_start = np.full(len(states), 0.25)
    extra: dict = {k: np.asarray(v) for k, v in severities.items()}
    return make_campaign(
        np.asarray(res.signals, dtype=float),
        channels=list(door.channels),
        fs=door.sampling_rate_hz,
        state=list(states),
        v_max=np.asarray(v_max, dtype=float),
        t_start=t_start,
        t_stop=t_start + np.asarray(motion_duration(np.asarray(v_max, dtype=float))),
        system=door.name,
        **extra,
    )
