"""The restitution a contact law actually delivers in one impact (the reference check of a law).

A point mass meets a rigid flat at speed ``v_impact`` and leaves at speed ``v_out``; the delivered
coefficient of restitution is ``v_out / v_impact``. A law whose hysteresis factor xi(c_r) is right
is one whose nominal and delivered restitution agree.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from ._laws import AbstractContactLaw, get_law
from ._smooth import LATCH_FLOOR, PENETRATION_SMOOTHING, latch_rate, smooth_contact_force

#: the smoothed impact starts this many smoothing widths before first contact, where the
#: softplus penetration is e^-40 of a width: the force there is nil in float64
_APPROACH_WIDTHS = 40.0


def single_impact(
    law: int | str | AbstractContactLaw | type[AbstractContactLaw],
    c_r: float,
    v_impact: float,
    K: float,
    n: float,
    mass: float,
    *,
    smoothed: bool = False,
    width: float = PENETRATION_SMOOTHING,
    floor: float = LATCH_FLOOR,
    rtol: float = 1e-12,
) -> float:
    """Delivered restitution of one impact of a point mass on a rigid flat.

    The mass approaches at ``v_impact`` and only the contact force acts on it (no gravity, no
    other load): the impact the hysteresis factors were derived for.

    - ``smoothed=False``: the textbook law F = K d^n (1 + xi d_dot / v_impact) for d > 0 and zero
      otherwise, from first contact until d returns to zero.
    - ``smoothed=True``: the door model's force, :func:`smooth_contact_force` with the
      approach-velocity latch of :func:`latch_rate` as a state. The run starts 40 smoothing
      widths before contact with the latch at ``v_impact`` (a long steady approach) and ends when
      the mass is back at its start.

    Integrated with scipy's DOP853 and a terminal event at separation.

    Parameters
    ----------
    law
        Contact law: paper index 1-9, name, class or instance (see :func:`get_law`).
    c_r
        Nominal coefficient of restitution, in (0, 1].
    v_impact
        Approach speed at first contact (m/s), > 0.
    K
        Contact stiffness in SI units, N/m^n (the paper's N/mm^n times 1000^n), > 0.
    n
        Contact exponent, > 0.
    mass
        Mass of the impacting body (kg), > 0.
    smoothed
        Use the door model's smoothed, latched force instead of the textbook law.
    width, floor
        Penetration smoothing width (m) and latch floor (m/s) of the smoothed force.
    rtol
        Relative tolerance of the integration; the absolute tolerances are ``rtol`` times the
        scales of the impact (undamped peak indentation, impact speed).

    Returns
    -------
    float
        Delivered restitution: the speed after separation over the speed before.

    Raises
    ------
    ValueError
        For a parameter out of range; the message names it and the value received.
    RuntimeError
        If the integration fails or the mass has not separated by the end of the time window.

    Notes
    -----
    For the textbook law the result depends on xi alone, not on K, n, the mass or the speed:
    with u = xi d_dot / v_impact, m d_dot d(d_dot) = -K d^n (1 + u) dd separates into
    u du / (1 + u) = -(K xi^2 / (m v_impact^2)) d^n dd, whose right side integrates to zero over
    the closed contact path, so u - ln(1 + u) is the same at entry (u = xi) and exit
    (u = -xi e): e solves -xi e - ln(1 - xi e) = xi - ln(1 + xi). For small xi, 1 - e = 2 xi / 3.
    The smoothed force agrees with this above the latch floor; below it the latch holds ``floor``
    and the law acts as if xi were xi v_impact / floor. ``docs/model.md`` tabulates the laws.

    References
    ----------
    Hunt, K. H., Crossley, F. R. E. (1975). Coefficient of restitution interpreted as damping in
    vibroimpact. J. Appl. Mech. 42(2), 440-445.

    Examples
    --------
    >>> round(single_impact("hunt_crossley", 0.5, 0.1, 4.66e7, 1.5, 30.0), 3)
    0.663
    """
    law = get_law(law)
    for name, value in (("v_impact", v_impact), ("K", K), ("n", n), ("mass", mass)):
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"single_impact: {name} must be finite and > 0, got {value!r}")
    if not (0.0 < c_r <= 1.0):
        raise ValueError(f"single_impact: c_r must be in (0, 1], got {c_r!r}")
    xi = float(law.hysteresis_factor(np.float64(c_r)))  # type: ignore[arg-type]

    # undamped Hertz peak indentation, and the time to cross it at the impact speed
    d_peak = ((n + 1.0) * mass * v_impact**2 / (2.0 * K)) ** (1.0 / (n + 1.0))
    t_scale = d_peak / v_impact

    if smoothed:
        d_start = -_APPROACH_WIDTHS * width

        def rhs(t, y):
            d, d_dot, latch = y
            force = smooth_contact_force(d, d_dot, latch, K, n, xi, width, floor, xp=np)
            return [d_dot, -force / mass, latch_rate(d, d_dot, latch, width=width, xp=np)]

        y0 = [d_start, v_impact, v_impact]
        atol = rtol * np.array([d_peak, v_impact, v_impact])
    else:
        d_start = 0.0

        def rhs(t, y):
            d, d_dot = y
            dn = d**n if d > 0.0 else 0.0
            return [d_dot, -K * dn * (1.0 + xi * d_dot / v_impact) / mass]

        y0 = [d_start, v_impact]
        atol = rtol * np.array([d_peak, v_impact])

    def separated(t, y):
        return y[0] - d_start

    separated.terminal = True  # type: ignore[attr-defined]
    separated.direction = -1.0  # type: ignore[attr-defined]

    # approach, return, and a restitution phase even at 1e-3 of the impact speed fit inside
    t_end = 2.0 * abs(d_start) / v_impact + 1e4 * t_scale
    sol = solve_ivp(
        rhs,
        (0.0, t_end),
        y0,
        method="DOP853",
        events=separated,
        rtol=rtol,
        atol=atol,
        max_step=t_scale,
    )
    if sol.status != 1:
        raise RuntimeError(
            f"single_impact: no separation within {t_end:.3g} s (solver status {sol.status}: "
            f"{sol.message}). Likely causes: (a) rtol={rtol:g} below what DOP853 can reach, "
            f"(b) K, n or mass far from contact-mechanics values, (c) xi={xi:.3g} so large that "
            f"the mass all but stops in contact."
        )
    return float(-sol.y_events[0][0][1] / v_impact)
