"""The reference elevator door: parameters, damage modes, equations and simulation."""

from typing import TYPE_CHECKING

from ._extensions import EXTENSIONS as EXTENSIONS
from ._extensions import AbstractDoorExtension as AbstractDoorExtension
from ._extensions import CoupledFrameMode as CoupledFrameMode
from ._extensions import FrameMode as FrameMode
from ._extensions import MainsHum as MainsHum
from ._extensions import RailWaviness as RailWaviness
from ._extensions import SensorCrossAxis as SensorCrossAxis
from ._extensions import WheelEccentricity as WheelEccentricity
from ._extensions import extension as extension
from ._geometry import CHANNELS as CHANNELS
from ._model import STATE_SIZE as STATE_SIZE
from ._model import DoorArgs as DoorArgs
from ._model import DoorConstants as DoorConstants
from ._model import contact_kinematics as contact_kinematics
from ._model import make_args as make_args
from ._model import rhs as rhs
from ._model import state_size as state_size
from ._params import PARAMETERS as PARAMETERS
from ._params import STATES as STATES
from ._params import DoorDamage as DoorDamage
from ._params import DoorParameters as DoorParameters
from ._profile import commanded_motion as commanded_motion
from ._profile import motion_duration as motion_duration
from ._profile import record_duration as record_duration
from ._simulate import STATUS_MESSAGES as STATUS_MESSAGES
from ._simulate import SolverConfig as SolverConfig
from ._simulate import central_jacobian as central_jacobian
from ._simulate import initial_state as initial_state
from ._simulate import oscillatory_modes as oscillatory_modes
from ._simulate import sample_times as sample_times
from ._simulate import solve as solve
from ._simulate import static_equilibrium as static_equilibrium
from ._system import V_MAX_RANGE as V_MAX_RANGE
from ._system import ElevatorDoor as ElevatorDoor
from ._system import check_speed as check_speed

if TYPE_CHECKING:
    from ._catalogue import DOOR_CATALOGUE as DOOR_CATALOGUE
    from ._catalogue import WHEEL_CIRCUMFERENCE as WHEEL_CIRCUMFERENCE

#: names read from the discrepancy catalogue on first use: it imports the diagnosis and
#: inference layers (arviz, cma, ...), which simulating the door does not need
_CATALOGUE_NAMES = ("DOOR_CATALOGUE", "WHEEL_CIRCUMFERENCE")


def __getattr__(name: str):
    if name in _CATALOGUE_NAMES:
        from . import _catalogue

        return getattr(_catalogue, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
