"""Simulated systems behind one generic interface; the elevator door is the flagship."""

from ._base import AbstractSystem as AbstractSystem
from ._base import DamageSpec as DamageSpec
from ._base import ParameterSpec as ParameterSpec
from ._base import SimulationResult as SimulationResult
from .door import DoorDamage as DoorDamage
from .door import DoorParameters as DoorParameters
from .door import ElevatorDoor as ElevatorDoor
from .door import SolverConfig as SolverConfig
