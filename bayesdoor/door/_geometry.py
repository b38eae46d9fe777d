"""Fixed geometry and constants of the reference door (``docs/model.md``), SI units."""

from __future__ import annotations

import numpy as np

GRAVITY = 9.81
PANEL_MASS = 60.0  # kg, multiplied by the mass factor MF
PANEL_WIDTH = 0.9  # m, along Z
PANEL_HEIGHT = 2.1  # m, along Y
WHEEL_RADIUS = 0.03
WHEEL_Z = (-0.35, 0.35)  # left, right ("top right wheel") from the panel centre
RAIL_HEIGHT = 1.10  # wheel centres (the rail line) above the panel centre
SHOE_DEPTH = 1.05  # guide shoe below the panel centre
SHOE_CLEARANCE = 0.5e-3  # lateral clearance each side of the groove
SHOE_K = 500.0  # N/mm^1.5
SHOE_N = 1.5
GIB_PRELOAD = 20.0  # N
STRIBECK_VELOCITY = 0.01  # m/s
ROLLING_RESISTANCE = 0.01
BELT_STIFFNESS = 2e4
BELT_DAMPING = 200.0
BELT_HEIGHT = 1.05  # belt clamp above the panel centre
FRAME_MODAL_MASS = 20.0
FRAME_FREQUENCIES = (32.0, 58.0, 95.0)  # header X, racking Z, rail vertical Y (bare frame)
RAIL_SPAN = (-0.6, 1.4)
HEADER_TORSION_LIFT = 0.05  # rail lift per unit header X displacement
RACKING_TILT = 0.05  # rail tilt per unit racking displacement, about z = RACKING_PIVOT
RACKING_PIVOT = 0.4
RAIL_MODE_LATERAL = 0.1  # lateral rail-line motion per unit vertical rail mode
A1_Z, A1_Y = 0.40, 0.90  # panel sensor, from the panel centre
A2_Z = 0.45  # header sensor position along the rail
CHANNELS = ("A1X", "A1Z", "A2X", "A2Z")
SAMPLING_RATE_HZ = 2048.0
REST_S = 0.25

# Rail waviness r(z) = sum_k A_k sin(2 pi z / lambda_k + p_k), k = 0..7; the phases are fixed
# (drawn once from a seeded generator so every run of the reference door shares one rail).
WAVINESS_WAVELENGTH = 4e-3 * 25.0 ** (np.arange(8) / 7.0)
WAVINESS_AMPLITUDE = 2e-6 * 10.0 ** (np.arange(8) / 7.0)
WAVINESS_PHASE = np.random.default_rng(20230607).uniform(0.0, 2.0 * np.pi, 8)

# S-curve of the drive (docs/model.md, "Drive profile")
JERK = 8.0
ACCELERATION = 0.8
STROKE = 0.8

# D1 debris bumps and D2 wheel flat
D1_POSITIONS = (0.25, 0.55)
D1_BASE_WIDTH = 8e-3
D2_SPAN_RAD = float(np.deg2rad(20.0))


def rail_mode_shape(z, xp=np):
    """Half-sine shape of the rail's vertical bending mode over the rail span, and its slope."""
    z0, z1 = RAIL_SPAN
    k = np.pi / (z1 - z0)
    return xp.sin(k * (z - z0)), k * xp.cos(k * (z - z0))
