"""Delivered restitution of a contact law in one impact (the reference check of DESIGN.md s. 3)."""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from ._laws import AbstractContactLaw, get_law
from ._smooth import smooth_contact_force


def single_impact(
    law: int | str | AbstractContactLaw,
    c_r: float,
    *,
    n: float = 1.5,
    K: float = 1e9,
    mass: float = 1.0,
    v_in: float = 0.1,
    smoothed: bool = False,
) -> float:
    """Delivered restitution -v_out / v_in of a point mass hitting a flat through the law.

    The mass meets the surface at ``v_in`` and is integrated (scipy DOP853, rtol 1e-10) until the
    indentation returns to zero. ``smoothed=False`` uses the textbook force
    K d^n (1 + xi d_dot / v_in) clipped at zero; ``smoothed=True`` the door model's smoothed
    force (softplus penetration, latch floor), with the latch frozen at ``v_in``.

    For the textbook force the result depends only on xi and n, not on K, mass or v_in.
    """
    xi = float(get_law(law).hysteresis_factor(np.asarray(c_r)))

    def force(d, d_dot):
        if smoothed:
            return float(smooth_contact_force(d, d_dot, v_in, K, n, xi, xp=np))
        if d <= 0:
            return 0.0
        return max(K * d**n * (1.0 + xi * d_dot / v_in), 0.0)

    def rhs(t, y):
        return [y[1], -force(y[0], y[1]) / mass]

    def separated(t, y):
        return y[0]

    separated.terminal = True
    separated.direction = -1
    # the contact lasts about 3 (m / (K v^(n-1)))^(1/(n+1)) for a Hertz contact
    scale = (mass * v_in ** (1.0 - n) / K) ** (1.0 / (n + 1.0)) * 20.0
    sol = solve_ivp(
        rhs,
        (0.0, scale),
        [1e-12 * v_in, v_in],
        method="DOP853",
        events=separated,
        rtol=1e-10,
        atol=1e-16,
    )
    if sol.status != 1:
        raise RuntimeError(f"the impact did not end within {scale:.3g} s (law {law}, c_r {c_r})")
    return float(-sol.y_events[0][0][1] / v_in)
