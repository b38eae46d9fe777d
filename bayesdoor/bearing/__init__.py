"""The drive-end rolling-element bearing of the CWRU test stand, and its real records.

:class:`BearingSystem` models the drive-end accelerometer (12 kHz, channel ``DE``) of a
"""

from ._envelope import envelope_spectrum as envelope_spectrum
from ._geometry import CWRU_DRIVE_END as CWRU_DRIVE_END
from ._geometry import BearingGeometry as BearingGeometry
from ._system import BearingSystem as BearingSystem
