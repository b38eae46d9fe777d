"""Calibrating a trained ensemble and fitting its OOD detector; the whole fit in one call."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._types import Array, Float, Int
from ._calibration import fit_temperature
from ._config import TrainConfig
from ._ensemble import Ensemble
from ._network import NetworkConfig
from ._ood import check_model_error, fit_mahalanobis
from ._train import Progress, Training, train_ensemble


def calibrate(
    ensemble: Ensemble, x_val: Float[Array, "sample channel freq"], labels: Int[Array, " sample"]
) -> Ensemble:
    """The ensemble with its temperature fitted by the NLL on held-out inputs.

    See :func:`fit_temperature`; the members' logits on ``x_val`` are computed once.
    """
    logits = np.asarray(ensemble.member_logits(jnp.asarray(x_val)), dtype=np.float64)
    temperature = fit_temperature(logits, np.asarray(labels))
    return eqx.tree_at(
        lambda e: e.temperature, ensemble, jnp.asarray(temperature, dtype=ensemble.dtype)
    )


def fit_ood(
    ensemble: Ensemble,
    x_train: Float[Array, "sample channel freq"],
    labels: Int[Array, " sample"],
    x_heldout: Float[Array, "heldout channel freq"],
    *,
    quantile: float = 0.99,
    model_error: Float[Array, "draw channel freq"]
    | Float[np.ndarray, "draw channel freq"]
    | None = None,
    key: Array | None = None,
) -> Ensemble:
    """The ensemble with a Mahalanobis OOD detector (see :func:`fit_mahalanobis`).

    Class means and the shared covariance come from the training inputs, the threshold from
    the ``quantile`` of the score on held-out simulated inputs, all standardised like the
    ensemble's inputs. ``model_error`` (draws of an additive error in the inputs' units, for
    example :func:`bayesdoor.datagen.model_error_draws`) widens the reference distribution
    from "a simulation" to "a measurement of a simulated state"; ``key`` then picks the draw
    added to each held-out input.
    """
    scale = np.asarray(ensemble.scale, dtype=np.float64)
    standardised = None
    if model_error is not None:
        standardised = check_model_error(model_error, scale.shape) / scale
    detector = fit_mahalanobis(
        ensemble.standardise(jnp.asarray(x_train)),
        jnp.asarray(labels),
        ensemble.standardise(jnp.asarray(x_heldout)),
        ensemble.network.n_classes,
        quantile=quantile,
        model_error=standardised,
        key=key,
    )
    return eqx.tree_at(lambda e: e.ood, ensemble, detector, is_leaf=lambda v: v is None)


@dataclasses.dataclass(frozen=True)
class FitOptions:
    """The rarely set knobs of :func:`fit_classifier`.

    Parameters
    ----------
    network
        Architecture; ``None`` means the paper's Table 3 network sized to the inputs and the
        classes (see :func:`train_ensemble`).
    ood_quantile
        Quantile of the validation OOD scores that becomes the threshold.
    ood_model_error
        Draws of the model error for the OOD detector (see :func:`fit_ood`); ``None``
        compares inputs with the simulations alone.
    progress
        Progress bar per epoch: ``"rich"``, ``"tqdm"`` or ``"none"``.
    """

    network: NetworkConfig | None = None
    ood_quantile: float = 0.99
    ood_model_error: (
        Float[Array, "draw channel freq"] | Float[np.ndarray, "draw channel freq"] | None
    ) = None
    progress: Progress = "rich"


def fit_classifier(
    x_train: Float[Array, "sample channel freq"],
    y_train: Int[Array, " sample"],
    x_val: Float[Array, "val channel freq"],
    y_val: Int[Array, " val"],
    class_names: Sequence[str],
    *,
    key: Array,
    config: TrainConfig | None = None,
    options: FitOptions = FitOptions(),
) -> Training:
    """Train the ensemble, fit its temperature and its OOD threshold on the validation split.

    Parameters
    ----------
    x_train, y_train
        Training inputs and class indices (e.g. 70 % of the simulated runs).
    x_val, y_val
        Validation inputs and class indices (the other 30 %), used for the temperature and the
        OOD threshold, never for the weights.
    class_names, key, config
        As in :func:`train_ensemble`.
    options
        The network, the OOD detector's quantile and model error, and the progress bar.

    Returns
    -------
    Training
        The calibrated ensemble with its detector, and the training loss history.
    """
    training = train_ensemble(
        x_train,
        y_train,
        class_names,
        key=key,
        network=options.network,
        config=config,
        progress=options.progress,
    )
    ensemble = calibrate(training.ensemble, x_val, y_val)
    ensemble = fit_ood(
        ensemble,
        x_train,
        y_train,
        x_val,
        quantile=options.ood_quantile,
        model_error=options.ood_model_error,
        key=jax.random.fold_in(key, 1),
    )
    return Training(ensemble, training.loss)
