"""The reference elevator door: parameters, damage modes, equations and simulation."""

from ._catalogue import DOOR_CATALOGUE as DOOR_CATALOGUE
from ._catalogue import WHEEL_CIRCUMFERENCE as WHEEL_CIRCUMFERENCE
from ._geometry import CHANNELS as CHANNELS
from ._model import STATE_SIZE as STATE_SIZE
from ._model import DoorArgs as DoorArgs
from ._model import DoorConstants as DoorConstants
from ._model import contact_kinematics as contact_kinematics
from ._model import make_args as make_args
from ._model import rhs as rhs
from ._params import PARAMETERS as PARAMETERS
from ._params import STATES as STATES
from ._params import DoorDamage as DoorDamage
from ._params import DoorParameters as DoorParameters
from ._profile import commanded_motion as commanded_motion
from ._profile import motion_duration as motion_duration
from ._profile import record_duration as record_duration
from ._simulate import STATUS_MESSAGES as STATUS_MESSAGES
from ._simulate import SolverConfig as SolverConfig
from ._simulate import initial_state as initial_state
from ._simulate import sample_times as sample_times
from ._simulate import solve as solve
from ._simulate import static_equilibrium as static_equilibrium
from ._system import V_MAX_RANGE as V_MAX_RANGE
from ._system import ElevatorDoor as ElevatorDoor
from ._system import check_speed as check_speed
