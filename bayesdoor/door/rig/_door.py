"""The rig's door: its own constants, its true parameters and its equations of motion.

This is deliberately a second implementation of the door of ``docs/model.md``, not the reduced
model's code path: the equations come from a Lagrangian written as positions of points
(exact rotations, every convective term kept) differentiated by JAX; contact is the textbook
law without smoothing; the panel has a bending mode the reduced model lacks. Only the contact
laws' hysteresis factors and the drive's S-curve are shared with the reduced model.

Generalised coordinates q = (s, y, theta, phi, q1, q2, q3, b, p): slide, vertical position and
pitch of the panel centre, sway about the rail line, the three frame modes (header X, racking Z,
rail vertical), the panel bending mode b and the optional extra frame mode p of the
``frame_mode`` catalogue effect (inert when the effect is absent).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ... import door
from ..._types import Array, Float
from ..contact import get_law

# --- the door's geometry and fixed properties (docs/model.md), SI units ----------------------
GRAVITY = 9.81
PANEL_MASS = 60.0
PANEL_WIDTH = 0.9
PANEL_HEIGHT = 2.1
WHEEL_RADIUS = 0.03
WHEEL_Z = (-0.35, 0.35)
RAIL_HEIGHT = 1.10
SHOE_DEPTH = 1.05
SHOE_CLEARANCE = 0.5e-3
SHOE_K_SI = 500.0 * 1000.0**1.5
SHOE_N = 1.5
GIB_PRELOAD = 20.0
STRIBECK_VELOCITY = 0.01
#: regularisation of the friction direction (m/s); half the reduced model's 1 mm/s: the fine
#: fixed step resolves the stiffer sticking damper
FRICTION_EPS = 0.5e-3
ROLLING_RESISTANCE = 0.01
ROLLING_EPS = 1e-3
BELT_STIFFNESS = 2e4
BELT_DAMPING = 200.0
BELT_HEIGHT = 1.05
FRAME_MODAL_MASS = 20.0
FRAME_HZ = (32.0, 58.0, 95.0)
RAIL_SPAN = (-0.6, 1.4)
TORSION_LIFT = 0.05
RACKING_TILT = 0.05
RACKING_PIVOT = 0.4
RAIL_LATERAL = 0.1
A1_Z, A1_Y = 0.40, 0.90
A2_Z = 0.45
LATCH_FLOOR = 0.05
REST_S = 0.25

# The rig's rail: the waviness law of docs/model.md with the rig's own phases (a real
# rail's phases are unknown to the model; the PSD does not depend on them).
WAVINESS_WAVELENGTH = 4e-3 * 25.0 ** (np.arange(8) / 7.0)
WAVINESS_AMPLITUDE = 2e-6 * 10.0 ** (np.arange(8) / 7.0)
WAVINESS_PHASE = np.random.default_rng(7_340_021).uniform(0.0, 2.0 * np.pi, 8)
# ... and fine roughness the reduced model lacks: 10 log-spaced wavelengths of 0.4-1.6 mm with
# a third of the amplitude law's spectral density continued there. At the door's speeds
# (>= 0.25 m/s) it excites the wheels above 150 Hz: broadband rolling excitation of the panel
# bending mode, outside the 0-96 Hz analysis band (only the first and last centimetres of a
# stroke, below 0.15 m/s, sweep it through the band).
ROUGHNESS_WAVELENGTH = np.geomspace(0.4e-3, 1.6e-3, 10)
ROUGHNESS_AMPLITUDE = (
    2e-6
    / 3.0
    * (ROUGHNESS_WAVELENGTH / 4e-3) ** (np.log(10.0) / np.log(25.0))
    * np.sqrt(np.log(1.6 / 0.4) / 9 / (np.log(25.0) / 7))
)
ROUGHNESS_PHASE = np.random.default_rng(7_340_022).uniform(0.0, 2.0 * np.pi, 10)

D1_POSITIONS = (0.25, 0.55)
D1_BASE_WIDTH = 8e-3
D2_SPAN_RAD = float(np.deg2rad(20.0))

# --- the panel bending mode (absent from the reduced model) ------------------------------------
#: modal mass (kg) of the panel's first out-of-plane bending mode
BENDING_MODAL_MASS = 8.0
#: mode shape (per unit modal coordinate) at the guide shoe (X), the wheel contacts (vertical,
#: through the hangers' rocking), the A1 sensor (X and Z)
BENDING_SHAPE_SHOE = 1.0
BENDING_SHAPE_WHEEL = 0.05
BENDING_SHAPE_A1X = -0.8
BENDING_SHAPE_A1Z = 0.05

N_DOF = 9
S, Y, TH, PHI, Q1, Q2, Q3, BEND, EXTRA = range(N_DOF)
N_CONTACT = 4  # left wheel, right wheel, +X groove wall, -X groove wall
# rows of the coordinate vector of :func:`coordinates`
_GAPS = slice(0, 4)  # rows of contact_coordinates
_ZETA = slice(4, 6)
_SHOE_Z, _SHOE_X, _BELT = 6, 7, 8
_CENTRE = slice(0, 3)  # rows of body_coordinates
_SENSORS = slice(3, 7)


class RigTruth(eqx.Module):
    """The rig's "real door": the values every fit of the rig's data should approach.

    The Table 2 parameters (K in N/mm^n, as in the paper) plus the panel bending mode the
    reduced model lacks. The default lies inside the Table 2 bounds but away from both the
    nominal values and the paper's optimum, with Flores et al.'s contact law (I = 3) instead
    of the paper's Lankarani-Nikravesh (I = 6).

    Examples
    --------
    >>> RigTruth().to_dict()["I"]
    3
    """

    K: float = 2120.0
    n: float = 1.74
    c_r: float = 0.84
    I: int = eqx.field(static=True, default=3)
    mu_s: float = 0.74
    mu_d: float = 0.66
    C: float = 0.0135
    MF: float = 1.2
    bending_hz: float = 165.0
    bending_damping: float = 0.005

    def __check_init__(self):
        get_law(self.I)
        for spec in door.PARAMETERS:
            if not spec.integer:
                spec.check(getattr(self, spec.name))
        if not 100.0 <= self.bending_hz <= 700.0:
            raise ValueError(
                f"bending_hz={self.bending_hz!r} must be in [100, 700] Hz: above the 0-96 Hz "
                "analysis band and below the anti-alias filter's 819 Hz corner"
            )
        if not 0.0 < self.bending_damping < 1.0:
            raise ValueError(f"bending_damping={self.bending_damping!r} must be in (0, 1)")

    def to_dict(self) -> dict[str, float | int]:
        """Every field as a plain Python number (JSON-ready)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


class RunArgs(eqx.Module):
    """Everything one run's equations need, as arrays (one leading batch axis when vmapped)."""

    k_contact: Float[Array, ""]  # N/m^n
    n: Float[Array, ""]
    xi: Float[Array, ""]
    mu_s: Float[Array, ""]
    mu_d: Float[Array, ""]
    mass: Float[Array, ""]
    frame_k: Float[Array, " 3"]
    frame_c: Float[Array, " 3"]
    bend_k: Float[Array, ""]
    bend_c: Float[Array, ""]
    v_run: Float[Array, ""]
    d1_height: Float[Array, ""]
    d2_depth: Float[Array, ""]
    d2_angle: Float[Array, ""]
    # frame_mode effect: modal stiffness and damping (mass FRAME_MODAL_MASS), rail lift per
    # unit coordinate, mode shape at the four sensor channels
    extra_k: Float[Array, ""]
    extra_c: Float[Array, ""]
    extra_lift: Float[Array, ""]
    extra_shape: Float[Array, " 4"]
    # wheel_eccentricity effect: radius harmonics k = 1..H per wheel (m) and their phases
    ecc_amplitude: Float[Array, "2 harmonic"]
    ecc_phase: Float[Array, "2 harmonic"]
    # rail_waviness effect: wavenumber (rad/m), amplitude (m), phase
    wav_wavenumber: Float[Array, ""]
    wav_amplitude: Float[Array, ""]
    wav_phase: Float[Array, ""]


def _raised_cosine(u, width):
    inside = jnp.abs(u) < 0.5 * width
    return jnp.where(inside, 0.5 * (1.0 + jnp.cos(2.0 * np.pi * u / width)), 0.0)


def _rail_profile(zeta, a: RunArgs):
    """Height of the rail surface at rail coordinate ``zeta`` (waviness and the extra tone)."""
    wavelength = np.concatenate([WAVINESS_WAVELENGTH, ROUGHNESS_WAVELENGTH])
    amplitude = np.concatenate([WAVINESS_AMPLITUDE, ROUGHNESS_AMPLITUDE])
    phase = np.concatenate([WAVINESS_PHASE, ROUGHNESS_PHASE])
    base = jnp.sum(amplitude * jnp.sin(2.0 * np.pi / wavelength * zeta + phase))
    return base + a.wav_amplitude * jnp.sin(a.wav_wavenumber * zeta + a.wav_phase)


def _rail_mode(z):
    z0, z1 = RAIL_SPAN
    return jnp.sin(np.pi * (z - z0) / (z1 - z0))


def contact_coordinates(q: Float[Array, " 9"], a: RunArgs) -> Float[Array, " 9"]:
    """Positions the contact, friction and drive forces act along, as functions of q.

    Rows: the four contact gaps (indentation > 0; left wheel, right wheel, +X and -X groove
    wall), the two wheels' rolling coordinates along the rail, the shoe's Z and X position and
    the belt clamp's position relative to its anchor. Their Jacobian maps forces along them to
    generalised forces.
    """
    s, y, th, ph, q1, q2, q3, b, p = (q[i] for i in range(N_DOF))
    sin_th, cos_th = jnp.sin(th), jnp.cos(th)
    u = q1 + RAIL_LATERAL * _rail_mode(s) * q3  # lateral motion of the rail line at the panel

    gaps, zetas = [], []
    for side, zl in enumerate(WHEEL_Z):
        zeta = s + zl * cos_th - RAIL_HEIGHT * sin_th - q2  # wheel centre along the rail
        lift = (
            TORSION_LIFT * q1
            + RACKING_TILT * (zeta - RACKING_PIVOT) * q2
            + _rail_mode(zeta) * q3
            + a.extra_lift * p
        )
        axle = y + zl * sin_th + RAIL_HEIGHT * (cos_th - 1.0)  # axle height minus its rest value
        angle = (zeta - zl) / WHEEL_RADIUS  # wheel rotation since the closed position
        harmonics = jnp.arange(1.0, a.ecc_amplitude.shape[-1] + 1.0)
        radius = jnp.sum(a.ecc_amplitude[side] * jnp.cos(harmonics * angle + a.ecc_phase[side]))
        if side == 1:
            wrapped = jnp.mod(angle - a.d2_angle + np.pi, 2.0 * np.pi) - np.pi
            radius = radius - a.d2_depth * _raised_cosine(wrapped, D2_SPAN_RAD)
        gaps.append(_rail_profile(zeta, a) + lift - axle + radius + BENDING_SHAPE_WHEEL * b)
        zetas.append(zeta)

    z_shoe = s + SHOE_DEPTH * sin_th
    x_shoe = u + (RAIL_HEIGHT + SHOE_DEPTH) * jnp.sin(ph) + BENDING_SHAPE_SHOE * b
    bumps = sum(_raised_cosine(z_shoe - zk, D1_BASE_WIDTH) for zk in D1_POSITIONS)
    gaps.append(x_shoe - SHOE_CLEARANCE + a.d1_height * bumps)
    gaps.append(-SHOE_CLEARANCE - x_shoe)
    belt = s - BELT_HEIGHT * sin_th - q2
    return jnp.stack([*gaps, *zetas, z_shoe, x_shoe, belt])


def body_coordinates(q: Float[Array, " 9"], a: RunArgs) -> Float[Array, " 7"]:
    """The panel centre (X, Y, Z) and the sensor positions A1X, A1Z, A2X, A2Z, as functions of q.

    The centre's Jacobian gives the mass matrix; the sensors' second time derivative is what
    the accelerometers measure.
    """
    s, y, th, ph, q1, _, q3, b, p = (q[i] for i in range(N_DOF))
    u = q1 + RAIL_LATERAL * _rail_mode(s) * q3
    e = a.extra_shape * p
    return jnp.stack(
        [
            u + RAIL_HEIGHT * jnp.sin(ph),
            y + RAIL_HEIGHT * (1.0 - jnp.cos(ph)),
            s,
            u + (RAIL_HEIGHT - A1_Y) * jnp.sin(ph) + BENDING_SHAPE_A1X * b + e[0],
            s + A1_Z * jnp.cos(th) - A1_Y * jnp.sin(th) + BENDING_SHAPE_A1Z * b + e[1],
            q[Q1] + RAIL_LATERAL * _rail_mode(A2_Z) * q3 + e[2],
            q[Q2] + e[3],
        ]
    )


def _spd_solve(m, f):
    """Solve m x = f for a small symmetric positive definite m (unrolled Cholesky).

    Unrolled into elementwise operations, which vectorise across a vmapped batch far better
    than a batched LAPACK call per right-hand-side evaluation.
    """
    size = m.shape[-1]
    low = [[None] * size for _ in range(size)]
    for j in range(size):
        diag = m[j, j] - sum(low[j][k] ** 2 for k in range(j))
        low[j][j] = jnp.sqrt(diag)
        for i in range(j + 1, size):
            low[i][j] = (m[i, j] - sum(low[i][k] * low[j][k] for k in range(j))) / low[j][j]
    z = []
    for i in range(size):
        z.append((f[i] - sum(low[i][k] * z[k] for k in range(i))) / low[i][i])
    x = [None] * size
    for i in reversed(range(size)):
        x[i] = (z[i] - sum(low[k][i] * x[k] for k in range(i + 1, size))) / low[i][i]
    return jnp.stack(x)


def contact_force(gap, rate, latch, k, n, xi):
    """Textbook Hunt-Crossley-family force K d^n (1 + xi d_dot / d_dot_minus), no smoothing.

    Zero while separated (d <= 0) and never tensile (the damping term may not pull).
    """
    touching = gap > 0.0
    dn = jnp.where(touching, jnp.exp(n * jnp.log(jnp.where(touching, gap, 1.0))), 0.0)
    return jnp.maximum(k * dn * (1.0 + xi * rate / latch), 0.0)


def _friction(vz, vx, normal, a: RunArgs):
    """Coulomb-Stribeck friction at the shoe, opposite to its (Z, X) sliding velocity."""
    speed2 = vz * vz + vx * vx
    mu = a.mu_d + (a.mu_s - a.mu_d) * jnp.exp(-speed2 / STRIBECK_VELOCITY**2)
    factor = -mu * normal / jnp.sqrt(speed2 + FRICTION_EPS**2)
    return factor * vz, factor * vx


def _inertia(a: RunArgs):
    i_pitch = a.mass * (PANEL_WIDTH**2 + PANEL_HEIGHT**2) / 12.0
    i_sway = a.mass * PANEL_HEIGHT**2 / 12.0
    zero = 0.0 * a.mass
    mf = FRAME_MODAL_MASS + zero
    return jnp.stack(
        [zero, zero, i_pitch, i_sway, mf, mf, mf, BENDING_MODAL_MASS + zero, mf],
    )


def applied_forces(t, q, qd, latch, a: RunArgs):
    """Generalised forces other than inertia, and the contact gaps and their rates.

    J^T f with J the Jacobian of :func:`contact_coordinates` and f the forces along those
    coordinates (contacts, rolling resistance, friction, belt), plus gravity on the panel
    centre and the modal springs and dampers.
    """

    def along(x):
        c = contact_coordinates(x, a)
        return c, c

    jac, c = jax.jacfwd(along, has_aux=True)(q)
    rate = jac @ qd
    gaps, rates = c[_GAPS], rate[_GAPS]
    shoe_k = jnp.full_like(a.k_contact, SHOE_K_SI)
    shoe_n = jnp.full_like(a.n, SHOE_N)
    k = jnp.stack([a.k_contact, a.k_contact, shoe_k, shoe_k])
    n = jnp.stack([a.n, a.n, shoe_n, shoe_n])
    normal = contact_force(gaps, rates, latch, k, n, a.xi)

    roll = rate[_ZETA]
    rolling = -ROLLING_RESISTANCE * normal[:2] * roll / jnp.sqrt(roll**2 + ROLLING_EPS**2)
    fz, fx = _friction(rate[_SHOE_Z], rate[_SHOE_X], GIB_PRELOAD + normal[2] + normal[3], a)
    pos_cmd, vel_cmd = door.commanded_motion(t, a.v_run, jnp)
    belt = -BELT_STIFFNESS * (c[_BELT] - pos_cmd) - BELT_DAMPING * (rate[_BELT] - vel_cmd)
    f = jnp.concatenate([-normal, rolling, jnp.stack([fz, fx, belt])])

    modal_k = jnp.concatenate([a.frame_k, jnp.stack([a.bend_k, a.extra_k])])
    modal_c = jnp.concatenate([a.frame_c, jnp.stack([a.bend_c, a.extra_c])])
    modal = jnp.concatenate([jnp.zeros(4, q.dtype), -modal_k * q[4:] - modal_c * qd[4:]])
    height = jax.grad(lambda x: body_coordinates(x, a)[1])(q)
    return jac.T @ f + modal - a.mass * GRAVITY * height, gaps, rates


def dynamics(t, q, qd, latch, a: RunArgs):
    """Generalised accelerations, sensor accelerations, contact gaps and rates at one instant.

    Lagrange's equations for T = m |v_centre|^2 / 2 + (rotational and modal terms): with J_c
    the Jacobian of the panel centre and h_c = J_c_dot q_dot its convective part,
    (m J_c^T J_c + D) q_ddot = Q - m J_c^T h_c, with Q from :func:`applied_forces`. Sensors
    read J_s q_ddot + h_s.
    """
    force, gaps, rates = applied_forces(t, q, qd, latch, a)

    def body_rate(x):
        return jax.jvp(lambda z: body_coordinates(z, a), (x,), (qd,))[1]

    jac_body = jax.jacfwd(lambda x: body_coordinates(x, a))(q)
    # d/dt (J q_dot) at fixed q_dot: the second directional derivative of the positions
    conv = jax.jvp(body_rate, (q,), (qd,))[1]
    j_centre = jac_body[_CENTRE]
    mass = a.mass * j_centre.T @ j_centre + jnp.diag(_inertia(a))
    qdd = _spd_solve(mass, force - a.mass * j_centre.T @ conv[_CENTRE])
    sensors = jac_body[_SENSORS] @ qdd + conv[_SENSORS]
    return qdd, sensors, gaps, rates


def static_equilibrium(a: RunArgs, iterations: int = 30) -> Float[Array, " 9"]:
    """Rest configuration (drive at the closed position, latches at the floor), by Newton."""
    load = a.mass * GRAVITY / 2.0
    q0 = jnp.zeros(N_DOF).at[Y].set(-jnp.exp(jnp.log(load / a.k_contact) / a.n))
    latch = jnp.full(N_CONTACT, LATCH_FLOOR)
    zero = jnp.zeros(N_DOF)

    def residual(q):
        return applied_forces(0.0, q, zero, latch, a)[0]

    def body(_, q):
        return q - jnp.linalg.solve(jax.jacfwd(residual)(q), residual(q))

    return jax.lax.fori_loop(0, iterations, body, q0)
