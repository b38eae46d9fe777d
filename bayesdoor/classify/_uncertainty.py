"""Ensemble uncertainty: predictive entropy, expected entropy and mutual information (nats)."""

from __future__ import annotations

import jax.numpy as jnp

from .._types import Array, Float


def entropy(probabilities: Float[Array, "*batch class"]) -> Float[Array, "*batch"]:
    """Shannon entropy in nats, with ``0 log 0 = 0``."""
    p = jnp.asarray(probabilities)
    safe = jnp.where(p > 0, p, 1)
    return -jnp.sum(jnp.where(p > 0, p * jnp.log(safe), 0), axis=-1)


def predictive_entropy(
    member_probabilities: Float[Array, "member *batch class"],
) -> Float[Array, "*batch"]:
    """Entropy of the ensemble's mean (mixture) distribution: total uncertainty."""
    return entropy(jnp.mean(member_probabilities, axis=0))


def expected_entropy(
    member_probabilities: Float[Array, "member *batch class"],
) -> Float[Array, "*batch"]:
    """Mean of the members' entropies: the uncertainty each member has on its own (aleatoric)."""
    return jnp.mean(entropy(member_probabilities), axis=0)


def mutual_information(
    member_probabilities: Float[Array, "member *batch class"],
) -> Float[Array, "*batch"]:
    """Predictive minus expected entropy: the members' disagreement (epistemic uncertainty).

    Non-negative by the concavity of the entropy (Jensen), zero when all members give the same
    distribution (up to round-off, which can leave a tiny negative number).

    References
    ----------
    Depeweg, S. et al. (2018). Decomposition of uncertainty in Bayesian deep learning for
    efficient and risk-sensitive learning. ICML.
    """
    return predictive_entropy(member_probabilities) - expected_entropy(member_probabilities)
