"""Bearing geometry and the kinematic fault frequencies that follow from it.

The frequencies are those of rolling without slip (Randall and Antoni, "Rolling element bearing
diagnostics - A tutorial", MSSP 25, 2011, 485-520), for a stationary outer race:

* ball pass frequency, outer race: BPFO = n/2 f_r (1 - d/D cos a)
* ball pass frequency, inner race: BPFI = n/2 f_r (1 + d/D cos a)
* fundamental train (cage) frequency: FTF = f_r/2 (1 - d/D cos a)
* ball spin frequency: BSF = D/(2d) f_r (1 - (d/D cos a)^2)

with n balls of diameter d on the pitch diameter D, contact angle a and shaft frequency f_r.
"""

from __future__ import annotations

import dataclasses
import math

#: metres per inch
INCH = 0.0254


@dataclasses.dataclass(frozen=True)
class BearingGeometry:
    """A rolling-element bearing's kinematic geometry.

    Parameters
    ----------
    n_balls
        Number of rolling elements.
    ball_diameter_in
        Ball diameter d, inch.
    pitch_diameter_in
        Pitch diameter D, inch.
    contact_angle_deg
        Contact angle a, degrees.
    designation
        A name for the bearing (provenance only).
    """

    n_balls: int = 9
    ball_diameter_in: float = 0.3126
    pitch_diameter_in: float = 1.537
    contact_angle_deg: float = 0.0
    designation: str = "SKF 6205-2RS JEM"

    def __post_init__(self) -> None:
        if self.n_balls < 1:
            raise ValueError(f"n_balls must be at least 1, got {self.n_balls}")
        if not 0 < self.ball_diameter_in < self.pitch_diameter_in:
            raise ValueError(
                f"the ball diameter ({self.ball_diameter_in} in) must be positive and smaller "
                f"than the pitch diameter ({self.pitch_diameter_in} in)"
            )
        if not 0 <= self.contact_angle_deg < 90:
            raise ValueError(f"contact_angle_deg must be in [0, 90), got {self.contact_angle_deg}")

    @property
    def ratio(self) -> float:
        """d/D cos a."""
        a = math.radians(self.contact_angle_deg)
        return self.ball_diameter_in / self.pitch_diameter_in * math.cos(a)

    def orders(self) -> dict[str, float]:
        """The fault frequencies as multiples of the shaft frequency.

        Returns
        -------
        orders
            ``bpfo``, ``bpfi``, ``ftf`` and ``bsf`` (ball spin; a ball defect strikes the races
            at twice this rate).

        Examples
        --------
        >>> o = BearingGeometry().orders()  # the CWRU drive-end bearing
        >>> round(o["bpfi"], 4), round(o["bpfo"], 4), round(o["ftf"], 5), round(o["bsf"], 3)
        (5.4152, 3.5848, 0.39828, 2.357)
        """
        r, n = self.ratio, self.n_balls
        return {
            "bpfo": n / 2 * (1 - r),
            "bpfi": n / 2 * (1 + r),
            "ftf": 0.5 * (1 - r),
            "bsf": self.pitch_diameter_in / (2 * self.ball_diameter_in) * (1 - r**2),
        }

    def fault_frequencies(self, shaft_hz: float) -> dict[str, float]:
        """The fault frequencies (Hz) at a shaft frequency ``shaft_hz`` (see :meth:`orders`)."""
        return {k: v * shaft_hz for k, v in self.orders().items()}

    def surface_speed_per_hz(self) -> float:
        """Rolling surface speed (m/s) per Hz of shaft frequency.

        The speed at which a contact moves over a race (or a ball's surface) in rolling
        without slip: the cage's angular speed times the outer-race contact radius,
        pi f_r (D^2 - d^2) / (2 D) for a = 0 (the same speed on the inner race and the ball).
        A defect of width w is crossed in w / (this times f_r) seconds.
        """
        r = self.ratio
        d_pitch = self.pitch_diameter_in * INCH
        cage = math.pi * (1 - r)  # rad/s per Hz of shaft frequency
        return cage * d_pitch / 2 * (1 + r)

    def impulse_order(self, state: str) -> float:
        """Impulses per shaft revolution of a fault ``state``.

        ``outer_race``: BPFO; ``inner_race``: BPFI; ``ball``: 2 BSF (one strike on each race
        per spin).
        """
        o = self.orders()
        table = {"outer_race": o["bpfo"], "inner_race": o["bpfi"], "ball": 2 * o["bsf"]}
        if state not in table:
            raise ValueError(f"no impulses for state {state!r}: one of {', '.join(table)}")
        return table[state]


#: the drive-end bearing of the CWRU stand
CWRU_DRIVE_END = BearingGeometry()
#: the fan-end bearing of the CWRU stand; its orders agree within 3e-4 with the Data Center's
#: table (BPFI 4.9469, BPFO 3.0530, FTF 0.3817 and 2 BSF 3.9874 times the shaft speed)
CWRU_FAN_END = BearingGeometry(8, 0.2656, 1.122, 0.0, "SKF 6203-2RS JEM")
