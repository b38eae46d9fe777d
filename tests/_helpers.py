"""Stand-ins shared by the test modules of the inference layer."""

import jax
import jax.numpy as jnp

from bayesdoor.inference import AbstractForward, ForwardOutput


class TableForward(AbstractForward):
    """Fixed features shifted by the sum of the parameters (an independent stand-in for a
    simulator); ``ok=False`` reports a failed solve."""

    names: tuple[str, ...]
    operating: jax.Array
    features: jax.Array
    variance: jax.Array
    ok: bool = True

    def __call__(self, theta):
        shift = jnp.sum(theta) * jnp.ones_like(self.features)
        return ForwardOutput(self.features + shift, self.variance, jnp.asarray(self.ok))
