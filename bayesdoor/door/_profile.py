"""The drive's commanded 7-segment S-curve (jerk-limited) opening stroke."""

from __future__ import annotations

from types import ModuleType

import numpy as np

from . import _geometry as g


def max_speed_limit(stroke: float = g.STROKE) -> float:
    """Largest v_max for which the S-curve still has a (zero-length) cruise phase."""
    a, j = g.ACCELERATION, g.JERK
    # stroke = v (v / a + a / j): the accelerating and decelerating halves meet
    return float((-(a * a / j) + np.sqrt((a * a / j) ** 2 + 4.0 * stroke * a)) / 2.0 * 1.0)


def switch_times(v_max, t0=g.REST_S, xp: ModuleType = np):
    """The eight jerk switching times of the S-curve for peak speed ``v_max``.

    Assumes v_max >= a^2 / j (0.08 m/s) so the constant-acceleration phase exists; the door's
    speeds (0.1-0.75 m/s) satisfy it.
    """
    a, j, L = g.ACCELERATION, g.JERK, g.STROKE
    tj = a / j
    ta = v_max / a - tj
    tc = (L - v_max * (v_max / a + tj)) / v_max
    d = [tj, ta, tj, tc, tj, ta, tj]
    times = [t0 + 0.0 * v_max]
    for dt in d:
        times.append(times[-1] + dt)
    return xp.stack(times)


def motion_duration(v_max):
    """Duration of the stroke in seconds for a peak speed ``v_max`` (numpy)."""
    ts = switch_times(np.asarray(v_max, dtype=float), t0=0.0)
    return ts[-1]


def record_duration(v_max, rest_s: float = g.REST_S, fs: float = g.SAMPLING_RATE_HZ) -> float:
    """Record length for runs at these speeds: rest, the slowest stroke, rest; whole samples."""
    t = rest_s + float(np.max(motion_duration(np.asarray(v_max, dtype=float)))) + rest_s
    return float(np.ceil(t * fs) / fs)


def commanded_motion(t, v_max, xp: ModuleType = np):
    """Commanded position and velocity of the belt at time ``t``.

    Written as a sum of cubic ramps at the jerk switches, so it is exact, smooth to second order
    and free of branches (jit- and vmap-friendly).
    """
    ts = switch_times(v_max, xp=xp)
    signs = xp.asarray([1.0, -1.0, -1.0, 1.0, -1.0, 1.0, 1.0, -1.0], dtype=ts.dtype)
    te = xp.minimum(t, ts[-1])
    r = xp.maximum(te - ts, 0.0)
    # products, not r**3: in float32, XLA on the CPU computed the cube wrongly (off by 0.1 m
    # after the stroke) once the sensor outputs of a whole record were compiled in one program
    r2 = r * r
    pos = g.JERK * xp.sum(signs * r2 * r) / 6.0
    vel = g.JERK * xp.sum(signs * r2) / 2.0
    return pos, vel
