"""A rolling-element bearing (by default the CWRU stand's drive end), and its real records.

:class:`BearingSystem` models the drive-end accelerometer (channel ``DE``; by default the
CWRU bearing at 12 kHz, another geometry and rate as fields) of a healthy bearing and of
inner-race, outer-race and ball faults; :func:`read_records` and :func:`import_records` turn a
folder of records described by a manifest (:func:`read_manifest`) into a campaign, and
:func:`read_cwru` and :func:`import_cwru` the CWRU ``.mat`` records (the built-in manifest
``cwru``). See docs/bearing.md.
"""

from ._catalogue import BEARING_CATALOGUE as BEARING_CATALOGUE
from ._cwru import import_cwru as import_cwru
from ._cwru import read_cwru as read_cwru
from ._cwru import read_record as read_record
from ._envelope import EnvelopeRule as EnvelopeRule
from ._envelope import envelope_spectrum as envelope_spectrum
from ._envelope import fault_indicators as fault_indicators
from ._extensions import LineFrequency as LineFrequency
from ._extensions import ShaftHarmonics as ShaftHarmonics
from ._extensions import StructuralMode as StructuralMode
from ._geometry import CWRU_DRIVE_END as CWRU_DRIVE_END
from ._geometry import CWRU_FAN_END as CWRU_FAN_END
from ._geometry import BearingGeometry as BearingGeometry
from ._manifest import KNOWN_GEOMETRIES as KNOWN_GEOMETRIES
from ._manifest import Manifest as Manifest
from ._manifest import ManifestError as ManifestError
from ._manifest import builtin_manifest as builtin_manifest
from ._manifest import parse_manifest as parse_manifest
from ._manifest import read_manifest as read_manifest
from ._rate import settle_sampling_rate as settle_sampling_rate
from ._records import fault_line_check as fault_line_check
from ._records import import_records as import_records
from ._records import read_records as read_records
from ._system import BearingSystem as BearingSystem
