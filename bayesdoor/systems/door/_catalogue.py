"""The door's catalogue of discrepancy causes (DESIGN.md section 6), its numbers as data."""

from __future__ import annotations

import numpy as np

from ...diagnose import (
    Candidate,
    Catalogue,
    CrossAxisCoherence,
    FixedFrequency,
    NoResidual,
    RestLine,
    SpeedTracking,
)
from . import _geometry as g

#: travel per wheel revolution, m (2 pi R = 0.1885 m)
WHEEL_CIRCUMFERENCE = 2.0 * np.pi * g.WHEEL_RADIUS
#: wheel harmonics whose tones the catalogue attributes to an out-of-round wheel
WHEEL_HARMONICS = tuple(range(1, 9))
#: the two sensors, each an X and a Z channel of one accelerometer
SENSOR_PAIRS = (("A1X", "A1Z"), ("A2X", "A2Z"))
#: mains frequencies, Hz
MAINS_HZ = (50.0, 60.0)
#: band of a plausible missing structural resonance, Hz (the frame's are 25-95 Hz installed)
FRAME_MODE_BAND = (10.0, 300.0)

_WHEEL_WAVELENGTHS = tuple(WHEEL_CIRCUMFERENCE / k for k in WHEEL_HARMONICS)

DOOR_CATALOGUE = Catalogue(
    candidates=(
        Candidate(
            name="frame_mode",
            description="a structural resonance the model lacks",
            signature=FixedFrequency(band=FRAME_MODE_BAND),
        ),
        Candidate(
            name="wheel_eccentricity",
            description="an out-of-round wheel: tones at the wheel rotation frequency "
            "v / (2 pi R) and its harmonics",
            signature=SpeedTracking(wavelengths=_WHEEL_WAVELENGTHS, labels=WHEEL_HARMONICS),
        ),
        Candidate(
            name="rail_waviness",
            description="a periodic rail irregularity: a tone at v / wavelength, the wavelength "
            "not a wheel harmonic",
            signature=SpeedTracking(excluded=_WHEEL_WAVELENGTHS),
        ),
        Candidate(
            name="sensor_cross_axis",
            description="cross-axis sensitivity or misalignment of one accelerometer",
            signature=CrossAxisCoherence(pairs=SENSOR_PAIRS),
        ),
        Candidate(
            name="mains_hum",
            description="electrical interference in the measurement chain",
            signature=RestLine(fundamentals=MAINS_HZ, harmonics=3),
        ),
        Candidate(
            name="none",
            description="the model explains the data within its uncertainty",
            signature=NoResidual(),
        ),
    )
)
