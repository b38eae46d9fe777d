"""Shared jaxtyping aliases used across bayesdoor's public signatures."""

from jaxtyping import Array, Bool, Float, Int

Scalar = Float[Array, ""]
ScalarLike = float | Float[Array, ""]

__all__ = ["Array", "Bool", "Float", "Int", "Scalar", "ScalarLike"]
