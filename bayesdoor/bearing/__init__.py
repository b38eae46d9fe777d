"""The drive-end rolling-element bearing of the CWRU test stand, and its real records.

:class:`BearingSystem` models the drive-end accelerometer (12 kHz, channel ``DE``) of a
healthy bearing and of inner-race, outer-race and ball faults; :func:`read_cwru` and
:func:`import_cwru` turn the CWRU ``.mat`` records into a campaign. See docs/bearing.md.
"""

from ._catalogue import BEARING_CATALOGUE as BEARING_CATALOGUE
from ._cwru import import_cwru as import_cwru
from ._cwru import read_cwru as read_cwru
from ._cwru import read_record as read_record
from ._cwru import settle_sampling_rate as settle_sampling_rate
from ._envelope import EnvelopeRule as EnvelopeRule
from ._envelope import envelope_spectrum as envelope_spectrum
from ._envelope import fault_indicators as fault_indicators
from ._envelope import fault_line_check as fault_line_check
from ._extensions import LineFrequency as LineFrequency
from ._extensions import ShaftHarmonics as ShaftHarmonics
from ._extensions import StructuralMode as StructuralMode
from ._geometry import CWRU_DRIVE_END as CWRU_DRIVE_END
from ._geometry import CWRU_FAN_END as CWRU_FAN_END
from ._geometry import BearingGeometry as BearingGeometry
from ._system import BearingSystem as BearingSystem
