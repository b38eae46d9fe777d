"""The 1-D convolutional network of one ensemble member (the paper's Table 3 by default)."""

from __future__ import annotations

import dataclasses
from typing import Any, cast

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._types import Array, Float


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Architecture of one member: Conv1D + ELU, max-pooling, flatten, dense layers, logits.

    The default is the paper's Table 3 network on its 4 x 25 input: 5 filters of width 3 with
    ELU, max-pooling by 2, flatten, dense to 3 classes (softmax in the loss and the prediction):
    ``4 * 3 * 5 + 5 = 65`` convolution and ``55 * 3 + 3 = 168`` dense parameters, 233 in all.

    Parameters
    ----------
    in_channels
        Input channels (sensor channels); the convolution runs along the frequency axis.
    n_bins
        Input length (frequency bins per channel).
    n_classes
        Output classes.
    filters
        Convolution filters.
    width
        Convolution kernel width (no padding, stride 1).
    pool
        Max-pooling window and stride (``1`` for none).
    hidden
        Widths of hidden dense layers (ELU) between the flatten and the output layer.

    Raises
    ------
    ValueError
        For a non-positive size, or a kernel and pooling that leave no output.
    """

    in_channels: int = 4
    n_bins: int = 25
    n_classes: int = 3
    filters: int = 5
    width: int = 3
    pool: int = 2
    hidden: tuple[int, ...] = ()

    def __post_init__(self):
        for name in ("in_channels", "n_bins", "n_classes", "filters", "width", "pool"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if self.n_classes < 2:
            raise ValueError(f"n_classes must be at least 2, got {self.n_classes}")
        object.__setattr__(self, "hidden", tuple(self.hidden))
        if any(isinstance(h, bool) or not isinstance(h, int) or h < 1 for h in self.hidden):
            raise ValueError(f"hidden must hold positive integer widths, got {self.hidden!r}")
        if self.pooled_length < 1:
            raise ValueError(
                f"a kernel of width {self.width} and pooling by {self.pool} leave no output on "
                f"{self.n_bins} bins: use a smaller width or pool, or more bins"
            )

    @property
    def input_shape(self) -> tuple[int, int]:
        """``(in_channels, n_bins)``."""
        return (self.in_channels, self.n_bins)

    @property
    def pooled_length(self) -> int:
        """Length of each filter's output after convolution and pooling."""
        return (self.n_bins - self.width + 1) // self.pool

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dictionary, inverse of :meth:`from_json`."""
        return {**dataclasses.asdict(self), "hidden": list(self.hidden)}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> NetworkConfig:
        """The configuration written by :meth:`to_json`."""
        return cls(**{**data, "hidden": tuple(data.get("hidden", ()))})


class ConvNet(eqx.Module):
    """One member network: maps a ``(channel, freq)`` input to class logits.

    Parameters
    ----------
    config
        The architecture.
    dtype
        Floating type of the weights.
    key
        PRNG key for the weight initialisation (equinox's defaults).

    References
    ----------
    The CM-CNN of Table 3 of "Real-time condition monitoring of mechanical systems using CNNs
    trained by multibody simulations", X ECCOMAS Thematic Conference on Smart Structures and
    Materials (SMART 2023), 2023; ``docs/classification.md``.
    """

    config: NetworkConfig = eqx.field(static=True)
    conv: eqx.nn.Conv1d
    dense: tuple[eqx.nn.Linear, ...]

    def __init__(self, config: NetworkConfig, *, dtype: Any = jnp.float32, key: Array):
        keys = jax.random.split(key, 2 + len(config.hidden))
        self.config = config
        self.conv = eqx.nn.Conv1d(
            config.in_channels, config.filters, config.width, dtype=dtype, key=keys[0]
        )
        widths = (config.filters * config.pooled_length, *config.hidden, config.n_classes)
        self.dense = tuple(
            eqx.nn.Linear(w_in, w_out, dtype=dtype, key=k)
            for w_in, w_out, k in zip(widths[:-1], widths[1:], keys[1:], strict=True)
        )

    def __call__(self, x: Float[Array, "channel freq"]) -> Float[Array, " class"]:
        # The convolution as a gather of the sliding windows and one contraction, and the
        # pooling as a reshape: the same numbers as `self.conv(x)` and `eqx.nn.MaxPool1d`
        # (tested), but vmapped over members and batches XLA's CPU backend runs them about
        # 1.4 times faster in training than its grouped convolution and reduce-window.
        c = self.config
        length = c.n_bins - c.width + 1
        windows = x[:, np.arange(length)[:, None] + np.arange(c.width)[None, :]]
        bias = cast(Array, self.conv.bias)  # always built with use_bias=True
        h = jnp.einsum("clw,fcw->fl", windows, self.conv.weight) + bias
        h = jax.nn.elu(h[:, : c.pooled_length * c.pool])
        h = jnp.max(h.reshape(c.filters, c.pooled_length, c.pool), axis=-1).reshape(-1)
        for layer in self.dense[:-1]:
            h = jax.nn.elu(layer(h))
        return self.dense[-1](h)


@eqx.filter_jit
def stacked_members(config: NetworkConfig, n_members: int, dtype: Any, key: Array) -> ConvNet:
    """``n_members`` networks stacked along a leading axis, each from its own split of ``key``.

    Jitted: built op by op, the vmapped initialisation spends seconds compiling each random op.
    """
    return eqx.filter_vmap(lambda k: ConvNet(config, dtype=dtype, key=k))(
        jax.random.split(key, n_members)
    )


def parameter_count(model: eqx.Module) -> int:
    """Number of trainable scalars (inexact array leaves) in ``model``."""
    leaves = jax.tree_util.tree_leaves(eqx.filter(model, eqx.is_inexact_array))
    return int(sum(np.prod(leaf.shape) for leaf in leaves))
