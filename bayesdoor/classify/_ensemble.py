"""The trained ensemble (members, input standardisation, temperature, OOD) and its prediction."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._exported import persistent_jit
from .._types import Array, Bool, Float, Int
from ._calibration import tempered_log_probabilities
from ._config import TrainConfig
from ._network import ConvNet, NetworkConfig
from ._ood import MahalanobisOOD
from ._uncertainty import entropy, expected_entropy, mutual_information


class Ensemble(eqx.Module):
    """A deep ensemble of :class:`ConvNet` members with everything needed to predict.

    Build one with :func:`train_ensemble` (or :func:`fit_classifier`), not by hand.

    Parameters
    ----------
    members
        The member networks stacked along a leading member axis (``eqx.filter_vmap`` of the
        constructor), so a prediction through all members is one vectorised call.
    mean, scale
        Per (channel, bin) mean and standard deviation of the training inputs: the networks see
        ``(x - mean) / scale``.
    temperature
        Calibrates the pooled probabilities, ``softmax(log(mean_m p_m) / T)`` (1: uncalibrated).
    class_names
        Name of each class index.
    ood
        The out-of-distribution detector, or ``None`` before :func:`fit_ood`.
    train_config
        How the members were trained (kept for the record and the saved file).
    """

    members: ConvNet
    mean: Float[Array, "channel freq"]
    scale: Float[Array, "channel freq"]
    temperature: Float[Array, ""]
    class_names: tuple[str, ...] = eqx.field(static=True)
    ood: MahalanobisOOD | None = None
    train_config: TrainConfig | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if len(self.class_names) != self.network.n_classes:
            raise ValueError(
                f"class_names has {len(self.class_names)} names for a network with "
                f"{self.network.n_classes} classes: give one name per class"
            )
        if self.mean.shape != self.network.input_shape:
            raise ValueError(
                f"mean has shape {self.mean.shape}, the network takes inputs of shape "
                f"{self.network.input_shape}"
            )

    @property
    def network(self) -> NetworkConfig:
        """The members' architecture."""
        return self.members.config

    @property
    def n_members(self) -> int:
        """Number of members."""
        return int(self.members.conv.weight.shape[0])

    @property
    def dtype(self) -> np.dtype:
        """Floating type of the weights; inputs are cast to it."""
        return np.dtype(self.members.conv.weight.dtype)

    def standardise(
        self, x: Float[Array, "batch channel freq"]
    ) -> Float[Array, "batch channel freq"]:
        """``(x - mean) / scale`` in the ensemble's dtype.

        Raises
        ------
        ValueError
            When the inputs are not ``(batch, channel, freq)`` with the training shape.
        """
        if x.ndim != 3 or tuple(x.shape[1:]) != self.network.input_shape:
            raise ValueError(
                f"inputs must have shape (batch, {', '.join(map(str, self.network.input_shape))})"
                f" like the training data, got {tuple(x.shape)}: add a leading axis for a single "
                f"input, and use the same channels and frequency bins as in training"
            )
        return (jnp.asarray(x).astype(self.dtype) - self.mean) / self.scale

    def member_logits(
        self, x: Float[Array, "batch channel freq"]
    ) -> Float[Array, "member batch class"]:
        """Logits of every member (before the temperature)."""
        z = self.standardise(x)
        return eqx.filter_vmap(lambda m: jax.vmap(m)(z))(self.members)


class Prediction(eqx.Module):
    """What the ensemble says about each input.

    Attributes
    ----------
    probabilities
        Calibrated predictive probabilities ``softmax(log(mean_m p_m) / T)``; their most
        probable class is that of the plain ensemble mean.
    member_probabilities
        Each member's softmax ``p_m`` (before the temperature).
    entropy
        Entropy (nats) of ``probabilities``: the calibrated total uncertainty.
    expected_entropy
        Mean entropy of the members (nats): what each member is unsure of on its own.
    mutual_information
        ``H(mean_m p_m) - expected_entropy`` (nats): the members' disagreement, >= 0. At
        ``T = 1`` it equals ``entropy - expected_entropy``; the temperature rescales the
        ensemble's overall confidence, not the disagreement between its members.
    ood_score
        The out-of-distribution score, ``None`` without a detector.
    ood
        True where ``ood_score`` exceeds the detector's threshold or is NaN (an input with
        non-finite values), ``None`` without a detector.
    """

    probabilities: Float[Array, "batch class"]
    member_probabilities: Float[Array, "member batch class"]
    entropy: Float[Array, " batch"]
    expected_entropy: Float[Array, " batch"]
    mutual_information: Float[Array, " batch"]
    ood_score: Float[Array, " batch"] | None
    ood: Bool[Array, " batch"] | None

    @property
    def predicted(self) -> Int[Array, " batch"]:
        """Index of the most probable class of each input."""
        return jnp.argmax(self.probabilities, axis=-1)


@persistent_jit
def predict(ensemble: Ensemble, x: Float[Array, "batch channel freq"]) -> Prediction:
    """Calibrated probabilities, uncertainty decomposition and OOD flag for a batch of inputs.

    Parameters
    ----------
    ensemble
        A trained ensemble.
    x
        Inputs in the training data's layout (not standardised).

    Returns
    -------
    Prediction
    """
    logits = ensemble.member_logits(x)
    member_p = jax.nn.softmax(logits, axis=-1)
    probabilities = jnp.exp(tempered_log_probabilities(logits, ensemble.temperature))
    if ensemble.ood is None:
        score, flag = None, None
    else:
        z = ensemble.standardise(x)
        score, flag = ensemble.ood.score(z), ensemble.ood.flag(z)
    return Prediction(
        probabilities=probabilities,
        member_probabilities=member_p,
        entropy=entropy(probabilities),
        expected_entropy=expected_entropy(member_p),
        mutual_information=mutual_information(member_p),
        ood_score=score,
        ood=flag,
    )
