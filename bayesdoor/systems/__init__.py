"""The generic system interface and the registry that finds systems by name.

Concrete systems (the elevator door in :mod:`bayesdoor.door`, a user's own) live in their own
packages on top of the generic layers and are found through the ``bayesdoor.systems`` entry
points.
"""

from ._base import AbstractSystem as AbstractSystem
from ._base import DamageSpec as DamageSpec
from ._base import ParameterSpec as ParameterSpec
from ._base import SimulationResult as SimulationResult
