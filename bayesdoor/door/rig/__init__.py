"""The virtual test rig: a separate, higher-fidelity simulator of the door that records
measured-like campaigns, with its true parameters kept apart, and injectable catalogue effects."""

from ._door import RigTruth as RigTruth
from ._effects import Effects as Effects
from ._effects import FrameMode as FrameMode
from ._effects import MainsHum as MainsHum
from ._effects import RailWaviness as RailWaviness
from ._effects import SensorCrossAxis as SensorCrossAxis
from ._effects import WheelEccentricity as WheelEccentricity
from ._family import OtherDoor as OtherDoor
from ._family import coloured_noise as coloured_noise
from ._family import family_plan as family_plan
from ._rig import Recording as Recording
from ._rig import RestState as RestState
from ._rig import RigConfig as RigConfig
from ._rig import VirtualRig as VirtualRig
