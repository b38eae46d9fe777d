"""A single-degree-of-freedom oscillator: the small reference system to learn from.

:class:`Oscillator` is a mass on a spring and a damper whose base follows a rough road,
seen by one accelerometer; its states are ``healthy``, ``stiffness_loss`` (the natural
frequency falls) and ``loose_mount`` (the damping rises), and its catalogue of discrepancy
causes names one cause, ``second_mode`` (:class:`SecondMode`). docs/systems.md writes a
system by reading it.
"""

from ._extensions import EXTENSIONS as EXTENSIONS
from ._extensions import MODE_BAND_HZ as MODE_BAND_HZ
from ._extensions import SecondMode as SecondMode
from ._model import BASE_BAND_HZ as BASE_BAND_HZ
from ._model import base_velocity_psd as base_velocity_psd
from ._model import mass_acceleration as mass_acceleration
from ._model import transmissibility as transmissibility
from ._system import CONDITIONS as CONDITIONS
from ._system import FEATURES as FEATURES
from ._system import PARAMETERS as PARAMETERS
from ._system import STATES as STATES
from ._system import Oscillator as Oscillator
