"""Fixed-step classical RK4 of the rig's equations, with the contact latches as discrete state.

The approach-velocity latch of each contact is not a smoothed ODE state (as in the reduced
model) but a discrete one, updated between steps: when a gap turns positive, the latch takes
the indentation rate at the crossing (linearly interpolated inside the step) floored at
``LATCH_FLOOR``; it then stays fixed until the next contact begins.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..._types import Array, Float
from ._door import (
    _GAPS,
    LATCH_FLOOR,
    N_CONTACT,
    RunArgs,
    contact_coordinates,
    dynamics,
    static_equilibrium,
)


def _run(a: RunArgs, n_steps: int, dt: float) -> Float[Array, "4 step"]:
    """One run from rest: the sensors' accelerations at every fine step (channel, step)."""
    q0 = static_equilibrium(a)
    qd0 = jnp.zeros_like(q0)
    g0, r0 = jax.jvp(lambda x: contact_coordinates(x, a)[_GAPS], (q0,), (qd0,))
    latch0 = jnp.full(N_CONTACT, LATCH_FLOOR)

    def step(carry, k):
        q, qd, latch, g_prev, r_prev = carry
        t = k * dt
        # stage 1 gives the gaps at the step's start: a contact that began since the last
        # step latches its rate at the crossing, interpolated between the two steps. Stage 1
        # itself still used the previous latch; the force it changes is K d^n with d below
        # one step's travel (micrometres), so this costs nothing measurable and saves an
        # evaluation of the contact geometry per step.
        a1, sensors, g, r = dynamics(t, q, qd, latch, a)
        onset = (g > 0.0) & (g_prev <= 0.0)
        frac = jnp.where(onset, g_prev / jnp.where(onset, g_prev - g, 1.0), 0.0)
        crossing_rate = r_prev + frac * (r - r_prev)
        latch = jnp.where(onset, jnp.maximum(crossing_rate, LATCH_FLOOR), latch)

        h = 0.5 * dt
        v2 = qd + h * a1
        a2 = dynamics(t + h, q + h * qd, v2, latch, a)[0]
        v3 = qd + h * a2
        a3 = dynamics(t + h, q + h * v2, v3, latch, a)[0]
        v4 = qd + dt * a3
        a4 = dynamics(t + dt, q + dt * v3, v4, latch, a)[0]
        q_new = q + dt / 6.0 * (qd + 2.0 * v2 + 2.0 * v3 + v4)
        qd_new = qd + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        return (q_new, qd_new, latch, g, r), sensors

    steps = jnp.arange(n_steps, dtype=q0.dtype)
    _, sensors = jax.lax.scan(step, (q0, qd0, latch0, g0, r0), steps)
    return sensors.T


@functools.partial(jax.jit, static_argnums=(1, 2))
def integrate(a: RunArgs, n_steps: int, dt: float) -> Float[Array, "run 4 step"]:
    """Sensor accelerations of a batch of runs (leading axis of every leaf of ``a``).

    ``n_steps`` and ``dt`` are static: one compilation per batch size, record length and step.
    """
    return jax.vmap(_run, in_axes=(0, None, None))(a, n_steps, dt)
