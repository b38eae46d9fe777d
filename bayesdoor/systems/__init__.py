"""The generic system interface and the registry that finds systems by name.

Concrete systems (the elevator door in :mod:`bayesdoor.door`, a user's own) live in their own
packages on top of the generic layers and are found through the ``bayesdoor.systems`` entry
points.
"""

from ._base import HEALTHY as HEALTHY
from ._base import AbstractSystem as AbstractSystem
from ._base import ConditionSpec as ConditionSpec
from ._base import DamageSpec as DamageSpec
from ._base import ParameterSpec as ParameterSpec
from ._base import SimulationResult as SimulationResult
from ._base import SpectralFeatures as SpectralFeatures
from ._extensions import AbstractExtension as AbstractExtension
from ._extensions import UnsynchronisedLines as UnsynchronisedLines
from ._extensions import apply_output_extensions as apply_output_extensions
from ._extensions import build_extension as build_extension
from ._extensions import unsynchronised_line as unsynchronised_line
from ._host import ExtensionHost as ExtensionHost
from ._registry import ENTRY_POINT_GROUP as ENTRY_POINT_GROUP
from ._registry import DemoCampaign as DemoCampaign
from ._registry import available_demos as available_demos
from ._registry import available_importers as available_importers
from ._registry import available_systems as available_systems
from ._registry import get_demo as get_demo
from ._registry import get_importer as get_importer
from ._registry import get_manifest_importer as get_manifest_importer
from ._registry import get_system as get_system
from ._registry import register_system as register_system
