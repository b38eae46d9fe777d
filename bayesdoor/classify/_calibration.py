"""Temperature scaling of an ensemble: one scalar T fitted by the NLL on held-out data."""

from __future__ import annotations

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from jaxtyping import ArrayLike, Float, Int

from .._types import Array, ScalarLike

#: the range searched for the temperature
TEMPERATURE_BOUNDS = (1e-2, 1e2)


@jax.jit
def tempered_log_probabilities(
    member_logits: Float[ArrayLike, "member *batch class"], temperature: ScalarLike
) -> Float[Array, "*batch class"]:
    """Log of the calibrated ensemble probabilities ``softmax(log(mean_m p_m) / T)``.

    ``p_m = softmax(z_m)`` are the members' probabilities; their mean (the ensemble's mixture)
    is raised to the power ``1 / T`` and renormalised ("pool, then calibrate"). ``T = 1`` is the
    plain ensemble, and since ``x -> x / T`` is increasing the most probable class never
    changes. Computed in log space (``logsumexp`` over members) so a confident wrong member does
    not underflow to ``log 0``.
    """
    z = jnp.asarray(member_logits)
    log_mean = jax.scipy.special.logsumexp(jax.nn.log_softmax(z, axis=-1), axis=0) - math.log(
        z.shape[0]
    )
    return jax.nn.log_softmax(log_mean / temperature, axis=-1)


def ensemble_nll(
    member_logits: Float[ArrayLike, "member sample class"],
    labels: Int[ArrayLike, " sample"],
    temperature: float,
) -> float:
    """Mean NLL (nats) at the true classes of the calibrated ensemble probabilities.

    See :func:`tempered_log_probabilities`; float64.
    """
    z = np.asarray(member_logits, dtype=np.float64)
    y = np.asarray(labels)
    log_q = np.asarray(tempered_log_probabilities(z, temperature), dtype=np.float64)
    return float(-np.mean(log_q[np.arange(len(y)), y]))


def fit_temperature(
    member_logits: Float[ArrayLike, "member sample class"], labels: Int[ArrayLike, " sample"]
) -> float:
    """The temperature that minimises the ensemble's NLL on held-out data.

    The calibrated probabilities are ``softmax(log(mean_m p_m) / T)`` (see
    :func:`tempered_log_probabilities`): ``T = 1`` is the uncalibrated ensemble, ``T > 1``
    softens overconfident predictions, ``T < 1`` sharpens underconfident ones, and the predicted
    class never changes, so neither does the accuracy. The NLL is minimised over ``log T``
    (bounded Brent search on ``TEMPERATURE_BOUNDS``).

    Parameters
    ----------
    member_logits
        Logits of every member on the held-out (validation) inputs.
    labels
        True class indices of those inputs.

    Returns
    -------
    temperature

    Raises
    ------
    ValueError
        For inconsistent shapes.

    Warns
    -----
    UserWarning
        When the optimum lies on a bound of ``TEMPERATURE_BOUNDS``; the bound is returned. Likely
        causes: (a) a validation set the ensemble classifies perfectly with margin, so the NLL
        keeps falling as ``T -> 0`` (use more or harder validation data); (b) an ensemble no
        better than chance, so the NLL keeps falling as ``T -> infinity`` (check the training).

    References
    ----------
    Guo, C., Pleiss, G., Sun, Y. and Weinberger, K. Q. (2017). On calibration of modern neural
    networks. ICML. Rahaman, R. and Thiery, A. H. (2021). Uncertainty quantification and deep
    ensembles. NeurIPS (calibrating the pooled ensemble rather than its members).
    """
    z = np.asarray(member_logits, dtype=np.float64)
    y = np.asarray(labels)
    if z.ndim != 3 or y.shape != (z.shape[1],):
        raise ValueError(
            f"member_logits must have shape (member, sample, class) and labels (sample,), got "
            f"{z.shape} and {y.shape}"
        )
    lo, hi = np.log(TEMPERATURE_BOUNDS)

    def objective(log_t: float) -> float:
        return ensemble_nll(z, y, float(np.exp(log_t)))

    # a bounded search (optimistix's minimisers take no bounds): the NLL may keep falling
    # towards a bound, where it is flat to round-off and a gradient search would wander
    result = scipy.optimize.minimize_scalar(
        objective, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6}
    )
    # Brent's bounded search never evaluates the bounds themselves and stops anywhere on an NLL
    # that is flat to round-off (one that underflows to 0 as T -> 0), so compare with the bounds
    # explicitly; 1e-12 nats is far below any difference that matters and above the round-off
    bound = min((lo, hi), key=objective)
    if objective(bound) <= result.fun + 1e-12:
        warnings.warn(
            f"the NLL-optimal temperature lies at the bound {np.exp(bound):.3g} of "
            f"{TEMPERATURE_BOUNDS}: (a) the validation set may be classified perfectly with "
            f"margin (use more or harder validation data) or (b) the ensemble may be no better "
            f"than chance (check the training)",
            stacklevel=2,
        )
        return float(np.exp(bound))
    return float(np.exp(result.x))
