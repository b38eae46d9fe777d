"""Equations of motion of the reduced-order door (constants and derivation in ``docs/model.md``).

Generalised coordinates q = (s, y, theta, phi, q1, q2, q3):
s slide of the panel centre along Z, y its vertical position (0 = wheels touching the undeformed
rail), theta pitch about X, phi sway about the rail line, q1..q3 the frame's modal coordinates
(header X, racking Z, rail vertical). The state is (q, q_dot, latch) with one approach-velocity
latch per contact (left wheel, right wheel, +X groove wall, -X groove wall): 18 entries, then
the coordinates x and velocities of extensions that add their own (``n_dof``; none for the
base door).

Every function here takes an array namespace ``xp`` (``numpy`` or ``jax.numpy``) so the very same
equations run in diffrax and in the scipy reference integrator used by the tests and benchmarks.
"""

from __future__ import annotations

from types import ModuleType

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._types import Array, Float
from . import _geometry as g
from ._extensions import AbstractDoorExtension
from ._params import DoorDamage, DoorParameters
from ._profile import commanded_motion
from .contact import hysteresis_factor, latch_rate, smooth_contact_force, stribeck_friction

N_DOF = 7
N_LATCH = 4
STATE_SIZE = 2 * N_DOF + N_LATCH
S, Y, TH, PHI, Q1, Q2, Q3 = range(N_DOF)


class DoorConstants(eqx.Module):
    """Secondary constants of the reference door that are not updated (``docs/model.md``).

    They are leaves, not Python constants, so a study can vary them (for example switch the
    frame cross-couplings off to obtain a linear limit) without recompiling.
    """

    gib_preload: float = g.GIB_PRELOAD
    rolling_resistance: float = g.ROLLING_RESISTANCE
    waviness_scale: float = 1.0
    torsion_lift: float = g.HEADER_TORSION_LIFT
    racking_tilt: float = g.RACKING_TILT
    rail_lateral: float = g.RAIL_MODE_LATERAL


class DoorArgs(eqx.Module):
    """Everything the right-hand side needs, precomputed from parameters, damage and speed.

    All leaves are arrays (SI units), so one compiled solve serves any parameter values,
    contact law, damage state and speed. ``extensions`` are the model extensions that act
    inside the solve (static: one compiled solve per set of them) and ``extension_values``
    their parameters by full name.
    """

    k_contact: Float[Array, ""]  # N/m^n
    n: Float[Array, ""]
    xi: Float[Array, ""]
    k_shoe: Float[Array, ""]
    mu_s: Float[Array, ""]
    mu_d: Float[Array, ""]
    mass: Float[Array, ""]
    i_pitch: Float[Array, ""]
    i_sway: Float[Array, ""]
    frame_k: Float[Array, " 3"]
    frame_c: Float[Array, " 3"]
    d1_height: Float[Array, ""]
    d2_depth: Float[Array, ""]
    d2_angle: Float[Array, ""]
    v_max: Float[Array, ""]
    constants: DoorConstants
    extensions: tuple[AbstractDoorExtension, ...] = eqx.field(static=True, default=())
    extension_values: dict[str, Float[Array, ""]] = eqx.field(default_factory=dict)


def make_args(
    params: DoorParameters,
    damage: DoorDamage,
    v_max,
    dtype=jnp.float64,
    constants: DoorConstants | None = None,
    extensions: tuple[AbstractDoorExtension, ...] = (),
    extension_values=None,
) -> DoorArgs:
    """Convert Table 2 parameters (K in N/mm^n) to the SI quantities of the equations.

    ``extensions`` that act inside the solve (``needs_resolve``) take their parameters from
    ``extension_values`` (full names); output extensions are applied after the solve.
    """

    def f(x):
        return jnp.asarray(x, dtype=dtype)

    constants = jax.tree_util.tree_map(f, DoorConstants() if constants is None else constants)
    resolved = tuple(e for e in extensions if e.needs_resolve)
    values = {} if extension_values is None else extension_values

    n = f(params.n)
    # F = K [N/mm^n] (1000 d [m])^n = K 1000^n d^n
    k_si = f(params.K) * jnp.exp(n * float(np.log(1000.0)))
    mass = g.PANEL_MASS * f(params.MF)
    omega = 2.0 * np.pi * jnp.asarray(g.FRAME_FREQUENCIES, dtype=dtype)
    frame_k = g.FRAME_MODAL_MASS * omega**2
    frame_c = 2.0 * f(params.C) * g.FRAME_MODAL_MASS * omega
    return DoorArgs(
        k_contact=k_si,
        n=n,
        xi=f(hysteresis_factor(params.I, f(params.c_r))),
        k_shoe=f(g.SHOE_K * 1000.0**g.SHOE_N),
        mu_s=f(params.mu_s),
        mu_d=f(params.mu_d),
        mass=mass,
        i_pitch=mass * (g.PANEL_WIDTH**2 + g.PANEL_HEIGHT**2) / 12.0,
        i_sway=mass * g.PANEL_HEIGHT**2 / 12.0,
        frame_k=frame_k,
        frame_c=frame_c,
        d1_height=f(damage.d1_height),
        d2_depth=f(damage.d2_depth),
        d2_angle=f(damage.d2_angle),
        v_max=f(v_max),
        constants=constants,
        extensions=resolved,
        extension_values={k: f(v) for e in resolved for k, v in e.full(values).items()},
    )


def _raised_cosine(u, width, xp):
    """Raised-cosine bump of unit height and base ``width`` centred at 0, and its slope."""
    inside = xp.abs(u) < 0.5 * width
    arg = 2.0 * np.pi * u / width
    val = xp.where(inside, 0.5 * (1.0 + xp.cos(arg)), 0.0)
    slope = xp.where(inside, -0.5 * xp.sin(arg) * 2.0 * np.pi / width, 0.0)
    return val, slope


def _waviness(z, scale, xp, dtype):
    """Rail waviness r(z) and its slope dr/dz under both wheels (z: the left wheel's
    coordinate; the right wheel's lies ``WHEEL_Z[1] - WHEEL_Z[0]`` further along).

    The components are summed one by one (elementwise operations that XLA fuses into one
    loop under ``vmap``, where a sum over the small component axis does not fuse), and the
    right wheel's sines and cosines follow from the left's by the angle-addition formulas:
    16 sines and cosines per evaluation instead of 32, the largest single cost of the
    right-hand side (``docs/model.md``, "Initial state and solver"). In numpy (the scipy
    reference solves, where every operation is a Python call) each wheel's components are
    one array each.
    """
    shift = g.WHEEL_Z[1] - g.WHEEL_Z[0]
    if xp is np:
        k = 2.0 * np.pi / g.WAVINESS_WAVELENGTH
        a = scale * g.WAVINESS_AMPLITUDE
        args = [k * (z + d)[..., None] + g.WAVINESS_PHASE for d in (0.0, shift)]
        return (
            [np.sum(a * np.sin(arg), axis=-1) for arg in args],
            [np.sum(a * k * np.cos(arg), axis=-1) for arg in args],
        )
    zero = 0.0 * z
    r, dr = [zero, zero], [zero, zero]
    for wavelength, amplitude, phase in zip(
        g.WAVINESS_WAVELENGTH, g.WAVINESS_AMPLITUDE, g.WAVINESS_PHASE, strict=True
    ):
        k = 2.0 * np.pi / float(wavelength)
        a = scale * xp.asarray(float(amplitude), dtype=dtype)
        sin_l, cos_l = xp.sin(k * z + float(phase)), xp.cos(k * z + float(phase))
        c, s = float(np.cos(k * shift)), float(np.sin(k * shift))
        for side, (sine, cosine) in enumerate(
            ((sin_l, cos_l), (sin_l * c + cos_l * s, cos_l * c - sin_l * s))
        ):
            r[side] = r[side] + a * sine
            dr[side] = dr[side] + a * k * cosine
    return r, dr


def _flat(zeta, args, xp):
    """Radius reduction of the right wheel's flat at rail coordinate ``zeta``, and d/dzeta."""
    alpha = zeta / g.WHEEL_RADIUS - args.d2_angle
    delta = xp.mod(alpha + np.pi, 2.0 * np.pi) - np.pi
    val, slope = _raised_cosine(delta, g.D2_SPAN_RAD, xp)
    return args.d2_depth * val, args.d2_depth * slope / g.WHEEL_RADIUS


def _debris(z_shoe, args, xp):
    """Protrusion of the +X groove wall (D1 bumps) at the shoe position, and its slope."""
    val = 0.0 * z_shoe
    slope = 0.0 * z_shoe
    for zk in g.D1_POSITIONS:
        v, s = _raised_cosine(z_shoe - zk, g.D1_BASE_WIDTH, xp)
        val = val + v
        slope = slope + s
    return args.d1_height * val, args.d1_height * slope


def _unit(i, xp, dtype):
    e = np.zeros(N_DOF)
    e[i] = 1.0
    return xp.asarray(e, dtype=dtype)


def contact_kinematics(q, args: DoorArgs, xp: ModuleType = jnp, lift=0.0):
    """Gaps of the four contacts and their Jacobians d(gap)/dq (rows: L, R, +X wall, -X wall).

    Also returns the Jacobians of the wheel rolling coordinates (for rolling resistance) and of
    the shoe's (Z, X) position (for friction). ``lift`` raises the rail under both wheels
    (extensions' coordinates, which are not among q).
    """
    dtype = q.dtype
    c = args.constants
    s, y, th, _, q1, q2, q3 = (q[i] for i in range(N_DOF))
    e = [_unit(i, xp, dtype) for i in range(N_DOF)]

    gaps, jacs, roll_jacs = [], [], []
    along = s - g.RAIL_HEIGHT * th - q2
    rail, rail_slope = _waviness(along + g.WHEEL_Z[0], c.waviness_scale, xp, dtype)
    for side, zl in enumerate(g.WHEEL_Z):
        zeta = along + zl  # wheel centre along the (racking) rail
        r, dr = rail[side], rail_slope[side]
        for extension in args.extensions:
            extra = extension.surface(zeta, side, args.extension_values, xp)
            if extra is not None:
                r, dr = r + extra[0], dr + extra[1]
        psi, dpsi = g.rail_mode_shape(zeta, xp)
        if side == 1:
            fl, dfl = _flat(zeta, args, xp)
        else:
            fl, dfl = 0.0 * zeta, 0.0 * zeta
        frame_lift = c.torsion_lift * q1 + c.racking_tilt * (zeta - g.RACKING_PIVOT) * q2
        gap = r + frame_lift + lift + psi * q3 - y - th * zl - fl
        slope = dr + c.racking_tilt * q2 + dpsi * q3 - dfl  # d(gap)/d(zeta)
        dzeta = e[S] - g.RAIL_HEIGHT * e[TH] - e[Q2]
        jac = (
            slope * dzeta
            - e[Y]
            - zl * e[TH]
            + c.torsion_lift * e[Q1]
            + c.racking_tilt * (zeta - g.RACKING_PIVOT) * e[Q2]
            + psi * e[Q3]
        )
        gaps.append(gap)
        jacs.append(jac)
        roll_jacs.append(dzeta)

    a = c.rail_lateral * g.rail_mode_shape(s, xp)[0]
    lever = g.RAIL_HEIGHT + g.SHOE_DEPTH
    x_shoe = q1 + a * q3 + lever * q[PHI]
    z_shoe = s + g.SHOE_DEPTH * th
    jx = e[Q1] + a * e[Q3] + lever * e[PHI]
    jz = e[S] + g.SHOE_DEPTH * e[TH]
    bump, dbump = _debris(z_shoe, args, xp)
    gaps.append(x_shoe - g.SHOE_CLEARANCE + bump)
    jacs.append(jx + dbump * jz)
    gaps.append(-g.SHOE_CLEARANCE - x_shoe)
    jacs.append(-jx)
    return xp.stack(gaps), xp.stack(jacs), xp.stack(roll_jacs), jz, jx


def _solve_mass(force, q, args: DoorArgs, xp):
    """Accelerations from generalised forces: M(s) a = Q.

    M is diagonal except for the lateral block (phi, q1, q3), which is D + m w w^T with
    w = (H, 1, a(s)); it is inverted exactly by the Sherman-Morrison formula.
    """
    dtype = q.dtype
    m, mf = args.mass, g.FRAME_MODAL_MASS
    a = args.constants.rail_lateral * g.rail_mode_shape(q[S], xp)[0]
    w = xp.stack([g.RAIL_HEIGHT + 0.0 * a, 1.0 + 0.0 * a, a])
    d_lat = xp.stack([args.i_sway, mf + 0.0 * a, mf + 0.0 * a])
    f_lat = xp.stack([force[PHI], force[Q1], force[Q3]])
    dinv_f = f_lat / d_lat
    dinv_w = w / d_lat
    acc_lat = dinv_f - m * dinv_w * xp.sum(w * dinv_f) / (1.0 + m * xp.sum(w * dinv_w))
    diag = xp.stack([m, m, args.i_pitch, 1.0 + 0.0 * m, 1.0 + 0.0 * m, mf + 0.0 * m, 1.0 + 0.0 * m])
    acc = force / diag
    lat = np.array([PHI, Q1, Q3])
    mask = np.zeros(N_DOF)
    mask[lat] = 1.0
    mask = xp.asarray(mask, dtype=dtype)
    scatter = xp.asarray(np.eye(N_DOF)[:, lat], dtype=dtype)
    return acc * (1.0 - mask) + scatter @ acc_lat


def extension_dofs(args: DoorArgs) -> int:
    """Coordinates the solved extensions add to the state (each with its velocity)."""
    return sum(e.n_dof for e in args.extensions)


def state_size(args: DoorArgs) -> int:
    """Length of the state vector: (q, q_dot, latch, x, x_dot), x the extensions' coordinates."""
    return STATE_SIZE + 2 * extension_dofs(args)


def _extension_slices(args: DoorArgs):
    """(extension, slice of its coordinates within x) for every extension with coordinates."""
    out, start = [], 0
    for e in args.extensions:
        if e.n_dof:
            out.append((e, slice(start, start + e.n_dof)))
            start += e.n_dof
    return out


def accelerations(t, state, args: DoorArgs, xp: ModuleType = jnp):
    """Generalised accelerations, latch rates and the extensions' coordinate accelerations."""
    q, v = state[:N_DOF], state[N_DOF : 2 * N_DOF]
    latch = state[2 * N_DOF : STATE_SIZE]
    n_ext = extension_dofs(args)
    x, xv = state[STATE_SIZE : STATE_SIZE + n_ext], state[STATE_SIZE + n_ext :]
    owned = _extension_slices(args)
    values = args.extension_values
    lift = 0.0 * q[S]
    for e, part in owned:
        lift = lift + e.wheel_lift(x[part], values, xp)
    gaps, jacs, roll_jacs, jz, jx = contact_kinematics(q, args, xp, lift)
    rates = jacs @ v
    k = xp.stack([args.k_contact, args.k_contact, args.k_shoe, args.k_shoe])
    n = xp.stack([args.n, args.n, g.SHOE_N + 0.0 * args.n, g.SHOE_N + 0.0 * args.n])
    normal = smooth_contact_force(gaps, rates, latch, k, n, args.xi, xp=xp)
    force = -(normal @ jacs)

    # rolling resistance, opposing the wheels' rolling along the rail
    roll_speed = roll_jacs @ v
    c = args.constants
    rr = -c.rolling_resistance * normal[:2] * roll_speed / xp.sqrt(roll_speed**2 + 1e-6)
    force = force + rr @ roll_jacs

    # shoe friction against its (Z, X) sliding velocity; normal = gib preload + wall contact
    vz, vx = jz @ v, jx @ v
    factor = stribeck_friction(
        vz**2 + vx**2,
        c.gib_preload + normal[2] + normal[3],
        args.mu_s,
        args.mu_d,
        v_s=g.STRIBECK_VELOCITY,
        xp=xp,
    )
    force = force + factor * (vz * jz + vx * jx)

    # belt drive: spring-damper between the clamp and the racking-mounted anchor
    pos_cmd, vel_cmd = commanded_motion(t, args.v_max, xp)
    ext = q[S] - g.BELT_HEIGHT * q[TH] - q[Q2] - pos_cmd
    ext_rate = v[S] - g.BELT_HEIGHT * v[TH] - v[Q2] - vel_cmd
    belt = -g.BELT_STIFFNESS * ext - g.BELT_DAMPING * ext_rate
    dtype = q.dtype
    e_belt = xp.asarray([1.0, 0.0, -g.BELT_HEIGHT, 0.0, 0.0, -1.0, 0.0], dtype=dtype)
    force = force + belt * e_belt

    # gravity (vertical, and the pendulum restoring moment of the sway) and the frame
    zeros3 = 0.0 * q[:3]
    gravity = xp.concatenate(
        [
            xp.stack([0.0 * q[S], -args.mass * g.GRAVITY, 0.0 * q[S]]),
            xp.stack([-args.mass * g.GRAVITY * g.RAIL_HEIGHT * q[PHI]]),
            zeros3,
        ]
    )
    frame = xp.concatenate([0.0 * q[:4], -args.frame_k * q[4:] - args.frame_c * v[4:]])
    acc = _solve_mass(force + gravity + frame, q, args, xp)
    latch_dot = latch_rate(gaps, rates, latch, xp=xp)
    # the wheels' load beyond the door's weight (zero at rest: the wheels alone carry it)
    wheel_load = normal[0] + normal[1] - args.mass * g.GRAVITY
    ext_acc = [e.dof_accelerations(x[part], xv[part], wheel_load, values, xp) for e, part in owned]
    ext_acc = xp.concatenate(ext_acc) if ext_acc else 0.0 * x
    return acc, latch_dot, ext_acc


def rhs(t, state, args: DoorArgs, xp: ModuleType = jnp):
    """d(state)/dt for the state (q, q_dot, latch, x, x_dot)."""
    acc, latch_dot, ext_acc = accelerations(t, state, args, xp)
    xv = state[STATE_SIZE + extension_dofs(args) :]
    return xp.concatenate([state[N_DOF : 2 * N_DOF], acc, latch_dot, xv, ext_acc])


def sensor_signals(t, state, args: DoorArgs, xp: ModuleType = jnp):
    """Absolute accelerations at the four channels A1X, A1Z, A2X, A2Z (m/s^2)."""
    acc, _, ext_acc = accelerations(t, state, args, xp)
    lateral = args.constants.rail_lateral
    a_panel = lateral * g.rail_mode_shape(state[S], xp)[0]
    a_header = lateral * float(g.rail_mode_shape(g.A2_Z)[0])
    a1x = acc[Q1] + a_panel * acc[Q3] + (g.RAIL_HEIGHT - g.A1_Y) * acc[PHI]
    a1z = acc[S] - g.A1_Y * acc[TH]
    a2x = acc[Q1] + a_header * acc[Q3]
    a2z = acc[Q2]
    out = xp.stack([a1x, a1z, a2x, a2z])
    for e, part in _extension_slices(args):
        out = out + e.sensor_accelerations(ext_acc[part], args.extension_values, xp)
    return out


def static_residual(q, args: DoorArgs, xp: ModuleType = jnp):
    """Generalised forces at rest with the commanded position 0 (zero at equilibrium)."""
    dtype = q.dtype
    rest = xp.zeros(2 * extension_dofs(args), dtype=dtype)
    state = xp.concatenate([q, 0.0 * q, xp.full((N_LATCH,), 0.05, dtype=dtype), rest])
    acc, _, _ = accelerations(xp.asarray(0.0, dtype=dtype), state, args, xp)
    return acc
