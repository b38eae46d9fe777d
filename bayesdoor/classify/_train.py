"""Training all ensemble members at once: vmapped over members, one jitted scan per epoch."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Literal, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._types import Array, Float, Int
from ._config import TrainConfig
from ._ensemble import Ensemble
from ._network import NetworkConfig, stacked_members

Progress = Literal["rich", "tqdm", "none"]


class Training(NamedTuple):
    """The result of :func:`train_ensemble`.

    Attributes
    ----------
    ensemble
        The trained ensemble (temperature 1, no OOD detector yet).
    loss
        Mean training cross-entropy of each member in each epoch, shape ``(epoch, member)``.
    """

    ensemble: Ensemble
    loss: np.ndarray


def _check_data(x: Any, labels: Any, class_names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x)
    y = np.asarray(labels)
    if x.ndim != 3:
        raise ValueError(
            f"x must have shape (sample, channel, freq), got {x.shape}: one 2-D input per sample"
        )
    if y.shape != (x.shape[0],):
        raise ValueError(
            f"labels must have shape ({x.shape[0]},) like x's first axis, got {y.shape}"
        )
    if not np.issubdtype(y.dtype, np.integer) or np.any((y < 0) | (y >= len(class_names))):
        raise ValueError(
            f"labels must be integer indices into class_names (0..{len(class_names) - 1}), got "
            f"values {np.unique(y)[:10].tolist()}"
        )
    if not np.all(np.isfinite(x)):
        raise ValueError(
            f"x holds {np.count_nonzero(~np.isfinite(x))} non-finite values: remove or repair the "
            f"runs they come from"
        )
    return x, y


def _standardisation(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mean = x.mean(axis=0)
    scale = x.std(axis=0)
    # a bin that is constant over the training set carries no information; keep it at zero
    return mean, np.where(scale > 0, scale, 1.0)


@contextlib.contextmanager
def _progress_bar(kind: Progress, epochs: int) -> Iterator[Callable[[float], None]]:
    if kind == "none":
        yield lambda loss: None
    elif kind == "tqdm":
        from tqdm.auto import tqdm

        with tqdm(total=epochs, desc="training ensemble", unit="epoch") as bar:

            def advance(loss: float) -> None:
                bar.set_postfix(loss=f"{loss:.4f}")
                bar.update(1)

            yield advance
    else:
        from rich.progress import Progress as RichProgress

        with RichProgress(transient=True) as bar:
            task = bar.add_task("training ensemble", total=epochs)

            def advance(loss: float) -> None:
                bar.update(task, advance=1, description=f"training ensemble (loss {loss:.4f})")

            yield advance


def _loss(params, static, x, y, weight):
    model = eqx.combine(params, static)
    log_p = jax.nn.log_softmax(jax.vmap(model)(x), axis=-1)
    cross_entropy = -jnp.take_along_axis(log_p, y[:, None], axis=-1)[:, 0]
    return jnp.sum(weight * cross_entropy) / jnp.sum(weight)


def _member_epoch(params, opt_state, key, x, y, static, learning_rate, batch_size):
    """One epoch of one member: shuffle, pad to whole batches (weight 0), scan Adam steps."""
    optimiser = optax.adam(learning_rate)
    n = x.shape[0]
    n_batches = -(-n // batch_size)
    pad = n_batches * batch_size - n
    order = jnp.concatenate([jax.random.permutation(key, n), jnp.zeros(pad, dtype=int)])
    weight = (jnp.arange(n_batches * batch_size) < n).astype(x.dtype)

    def step(carry, batch):
        params, opt_state = carry
        xb, yb, w = batch
        loss, grads = eqx.filter_value_and_grad(_loss)(params, static, xb, yb, w)
        updates, opt_state = optimiser.update(grads, opt_state, params)
        return (eqx.apply_updates(params, updates), opt_state), loss * jnp.sum(w)

    # one gather per epoch rather than one per step
    batches = (
        x[order].reshape(n_batches, batch_size, *x.shape[1:]),
        y[order].reshape(n_batches, batch_size),
        weight.reshape(n_batches, batch_size),
    )
    (params, opt_state), losses = jax.lax.scan(step, (params, opt_state), batches)
    return params, opt_state, jnp.sum(losses) / n


@eqx.filter_jit
def _epoch(params, opt_state, member_keys, epoch, data, static, learning_rate, batch_size):
    """One epoch of every member: ``eqx.filter_vmap`` over the members of :func:`_member_epoch`.

    ``data`` is the pair of standardised inputs and labels. Each member shuffles with its own
    key folded with the epoch number.

    Module level and jitted once per (shapes, architecture, rate, batch size), so a second
    training with the same settings does not compile again.
    """
    x, y = data
    # optax's Adam bias correction raises a float to its int32 step count, which JAX's strict
    # dtype promotion refuses; standard promotion is confined to this trace
    with jax.numpy_dtype_promotion("standard"):
        return eqx.filter_vmap(
            lambda p, s, k: _member_epoch(
                p, s, jax.random.fold_in(k, epoch), x, y, static, learning_rate, batch_size
            )
        )(params, opt_state, member_keys)


def _network(network: NetworkConfig | None, x: np.ndarray, class_names: tuple) -> NetworkConfig:
    """``network``, or the paper's network sized to ``x`` and the classes when ``None``; a
    ``ValueError`` when it does not fit them."""
    if network is None:
        network = NetworkConfig(
            in_channels=x.shape[1], n_bins=x.shape[2], n_classes=len(class_names)
        )
    if network.input_shape != x.shape[1:] or network.n_classes != len(class_names):
        raise ValueError(
            f"the network takes inputs {network.input_shape} into {network.n_classes} classes, "
            f"the data are {x.shape[1:]} with {len(class_names)} class names: make them agree"
        )
    return network


def _train_members(members, data, config: TrainConfig, key: Array, progress: Progress):
    """The stacked members after ``config.epochs`` epochs on ``data`` (standardised inputs and
    labels), and each epoch's mean loss per member."""
    params, static = eqx.partition(members, eqx.is_inexact_array)
    opt_state = eqx.filter_vmap(optax.adam(config.learning_rate).init)(params)
    member_keys = jax.random.split(key, config.members)
    history = []
    with _progress_bar(progress, config.epochs) as advance:
        for e in range(config.epochs):
            params, opt_state, loss = _epoch(
                params,
                opt_state,
                member_keys,
                jnp.asarray(e, dtype=jnp.int32),
                data,
                static,
                config.learning_rate,
                config.batch_size,
            )
            history.append(np.asarray(loss))
            advance(float(history[-1].mean()))
    return eqx.combine(params, static), np.stack(history)


def train_ensemble(
    x: Float[Array, "sample channel freq"],
    labels: Int[Array, " sample"],
    class_names: Sequence[str],
    *,
    key: Array,
    network: NetworkConfig | None = None,
    config: TrainConfig | None = None,
    progress: Progress = "rich",
) -> Training:
    """Train the members of a deep ensemble together (vmapped), with Adam and cross-entropy.

    The inputs are standardised per (channel, bin) with the training set's mean and standard
    deviation, which are stored in the ensemble. Each member gets its own initialisation key and
    its own shuffling key; one jitted call runs one epoch of all members (``lax.scan`` over the
    batches inside ``eqx.filter_vmap`` over the members).

    Parameters
    ----------
    x
        Training inputs, e.g. the 4 x 25 log-PSD images of :func:`bayesdoor.features.cnn_input`.
    labels
        Class index of each input.
    class_names
        Name of each class index.
    key
        PRNG key; the same key gives the same weights.
    network
        Architecture; ``None`` means the paper's Table 3 network sized to ``x`` and the classes.
    config
        Training settings; ``None`` means ``TrainConfig()`` (10 members, 80 epochs, batch 100).
    progress
        Progress bar per epoch: ``"rich"``, ``"tqdm"`` or ``"none"``.

    Returns
    -------
    Training
        The ensemble and the loss history.

    Raises
    ------
    ValueError
        For inputs, labels or a network that do not fit together, or non-finite inputs.

    References
    ----------
    Lakshminarayanan, B., Pritzel, A. and Blundell, C. (2017). Simple and scalable predictive
    uncertainty estimation using deep ensembles. NeurIPS.
    """
    if progress not in ("rich", "tqdm", "none"):
        raise ValueError(f"progress must be 'rich', 'tqdm' or 'none', got {progress!r}")
    class_names = tuple(class_names)
    x_np, y_np = _check_data(x, labels, class_names)
    config = TrainConfig() if config is None else config
    network = _network(network, x_np, class_names)
    dtype = jnp.dtype(config.dtype)
    mean, scale = _standardisation(x_np.astype(np.float64))
    z = jnp.asarray((x_np - mean) / scale, dtype=dtype)
    y = jnp.asarray(y_np, dtype=jnp.int32)

    init_key, shuffle_key = jax.random.split(key)
    members = stacked_members(network, config.members, dtype, init_key)
    members, loss = _train_members(members, (z, y), config, shuffle_key, progress)
    ensemble = Ensemble(
        members=members,
        mean=jnp.asarray(mean, dtype=dtype),
        scale=jnp.asarray(scale, dtype=dtype),
        temperature=jnp.asarray(1.0, dtype=dtype),
        class_names=class_names,
        train_config=config,
    )
    return Training(ensemble, loss)
