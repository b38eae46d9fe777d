"""bayesdoor: probabilistic model updating and uncertainty-aware damage classification.

Importing bayesdoor enables JAX's float64 mode: the simulators are float64 by default and run in
float32 only on request (``dtype="float32"``).
"""

import warnings as _warnings

import jax as _jax

from ._cluster import Cluster as Cluster
from ._cluster import Pool as Pool
from ._jax_config import configure_jax as configure_jax
from ._memory import release_between_stages as release_between_stages

_jax.config.update("jax_enable_x64", True)

# ArviZ 0.22+ announces its coming 1.0 refactor with a FutureWarning when it is imported, in the
# middle of a job's progress; bayesdoor uses the 0.x API, which that release keeps, and ArviZ
# before 0.22 does not import with matplotlib 3.11. Only that announcement is filtered.
_warnings.filterwarnings(
    "ignore", message=r"\s*ArviZ is undergoing a major refactor", category=FutureWarning
)

__version__ = "0.1.0"
