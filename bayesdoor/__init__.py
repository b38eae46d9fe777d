"""bayesdoor: probabilistic model updating and uncertainty-aware damage classification.

Importing bayesdoor enables JAX's float64 mode: the simulators are float64 by default and run in
float32 only on request (``dtype="float32"``).
"""

import jax as _jax

from ._jax_config import configure_jax as configure_jax

_jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"
