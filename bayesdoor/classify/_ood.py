"""Out-of-distribution score: Mahalanobis distance to the nearest training class mean.

The reference distribution is the simulated training data, optionally widened by draws of the
model error (what a measurement of a known state carries on top of the simulation).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._types import Array, Float, Int


class MahalanobisOOD(eqx.Module):
    """Distance of a (standardised, flattened) input to the nearest training class mean.

    The features are whitened with a shared (tied) within-class covariance, plus the second
    moment of the model error when it was given (:func:`fit_mahalanobis`), so the score is
    ``min_k sqrt((f - mu_k)^T Sigma^-1 (f - mu_k))``: the Mahalanobis distance to the closest
    class, in units of the reference distribution's scatter. An input is flagged when its score
    exceeds ``threshold``, a high quantile of the score on held-out in-distribution data.

    Parameters
    ----------
    means
        Class means in the whitened feature space.
    whitening
        Matrix ``W`` with ``W^T W = Sigma^-1``.
    threshold
        Score above which an input is flagged.
    quantile
        The held-out quantile ``threshold`` was set to (kept for the record).
    model_error_draws
        Number of model-error draws the covariance and the threshold include (0: the score
        compares with the simulations alone; kept for the record).

    References
    ----------
    Lee, K., Lee, K., Lee, H. and Shin, J. (2018). A simple unified framework for detecting
    out-of-distribution samples and adversarial attacks. NeurIPS 31.
    """

    means: Float[Array, "class feature"]
    whitening: Float[Array, "feature feature"]
    threshold: Float[Array, ""]
    quantile: float = eqx.field(static=True)
    model_error_draws: int = eqx.field(static=True, default=0)

    def score(self, z: Float[Array, "batch channel freq"]) -> Float[Array, " batch"]:
        """Mahalanobis distance of each standardised input to its nearest class mean."""
        f = z.reshape(z.shape[0], -1) @ self.whitening.T
        d2 = jnp.sum((f[:, None, :] - self.means[None, :, :]) ** 2, axis=-1)
        return jnp.sqrt(jnp.min(d2, axis=-1))

    def flag(self, z: Float[Array, "batch channel freq"]) -> Array:
        """True where the score exceeds the threshold or is not a number (a corrupted input)."""
        return ~(self.score(z) <= self.threshold)


def ledoit_wolf(residuals: np.ndarray) -> tuple[np.ndarray, float]:
    """Ledoit-Wolf shrinkage estimate of a covariance from centred samples.

    Parameters
    ----------
    residuals
        Centred samples, one per row.

    Returns
    -------
    covariance, shrinkage
        ``(1 - s) S + s (tr S / p) I`` with ``S`` the sample covariance and ``s`` in [0, 1]
        the estimated optimal shrinkage.

    References
    ----------
    Ledoit, O. and Wolf, M. (2004). A well-conditioned estimator for large-dimensional
    covariance matrices. Journal of Multivariate Analysis 88(2), 365-411.
    """
    x = np.asarray(residuals, dtype=np.float64)
    n, p = x.shape
    s = x.T @ x / n
    mu = np.trace(s) / p
    delta2 = np.sum((s - mu * np.eye(p)) ** 2) / p
    # sum_k ||x_k x_k^T - S||_F^2 = sum_k ||x_k||^4 - n ||S||_F^2
    beta2 = (np.sum(np.sum(x**2, axis=1) ** 2) - n * np.sum(s**2)) / (n**2 * p)
    shrinkage = 1.0 if delta2 == 0 else float(min(beta2, delta2) / delta2)
    return (1.0 - shrinkage) * s + shrinkage * mu * np.eye(p), shrinkage


def _tied_scatter(z_train, labels, n_classes: int) -> tuple[np.ndarray, np.ndarray]:
    """The class means of the flattened training inputs and their Ledoit-Wolf shrunk
    within-class covariance; a ``ValueError`` for a class without inputs."""
    z = np.asarray(z_train, dtype=np.float64).reshape(len(z_train), -1)
    y = np.asarray(labels)
    counts = np.bincount(y, minlength=n_classes)
    if np.any(counts == 0):
        raise ValueError(
            f"every class needs training inputs for the OOD score; counts per class: "
            f"{counts.tolist()}"
        )
    means = np.stack([z[y == k].mean(axis=0) for k in range(n_classes)])
    cov, _ = ledoit_wolf(z - means[y])
    return means, cov


def _add_model_error(
    cov: np.ndarray, heldout: np.ndarray, model_error, key: Array | None, shape: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray, int]:
    """The covariance plus the model error's second moment (first half of the draws), the
    held-out inputs each plus one draw of the second half, and the number of draws."""
    if key is None:
        raise ValueError(
            "model_error needs key=: it picks the draw added to each held-out input for "
            "the threshold (e.g. key=jax.random.key(0))"
        )
    e = check_model_error(model_error, shape)
    n_draws = len(e)
    if n_draws < 2:
        raise ValueError(
            f"model_error holds {n_draws} draw: give at least 2 (half for the covariance, "
            "half for the threshold), better thousands"
        )
    # half of the draws for the covariance, the other half for the threshold: a draw
    # scored against a covariance estimated from it looks closer than a fresh one (by a
    # factor n / (n - p - 1) in the squared distance), which would bias the threshold low
    half = n_draws // 2
    flat = e[:half].reshape(half, -1)
    pick = np.asarray(jax.random.randint(key, (len(heldout),), half, n_draws))
    return cov + flat.T @ flat / half, heldout + e[pick], n_draws


def _whitened(
    means: np.ndarray, cov: np.ndarray, quantile: float, n_draws: int, dtype
) -> MahalanobisOOD:
    """The detector of the class means and covariance, its threshold not yet set (infinite)."""
    eigval, eigvec = np.linalg.eigh(cov)
    whitening = (eigvec / np.sqrt(eigval)).T
    return MahalanobisOOD(
        means=jnp.asarray(means @ whitening.T, dtype=dtype),
        whitening=jnp.asarray(whitening, dtype=dtype),
        threshold=jnp.asarray(np.inf, dtype=dtype),
        quantile=float(quantile),
        model_error_draws=n_draws,
    )


def fit_mahalanobis(
    z_train: Float[Array, "sample channel freq"],
    labels: Int[Array, " sample"],
    z_heldout: Float[Array, "heldout channel freq"],
    n_classes: int,
    *,
    quantile: float = 0.99,
    model_error: Float[Array, "draw channel freq"]
    | Float[np.ndarray, "draw channel freq"]
    | None = None,
    key: Array | None = None,
) -> MahalanobisOOD:
    """Fit class means and a tied shrunk covariance on training data; threshold on held-out data.

    Without ``model_error`` the reference distribution is that of the simulated inputs alone:
    its covariance is the Ledoit-Wolf shrunk within-class scatter ``S``. Simulations of a
    model with a few parameters fill a thin slab of the feature space (directions with
    almost no simulated variance), so a measurement that carries the usual model error, small
    in every feature but off the slab, gets a large score. With ``model_error`` the reference
    distribution is that of a measurement, simulation plus model error ``e``: the covariance
    becomes ``S + E[e e^T]`` (the second moment: a systematic offset counts as error of
    either sign), estimated from the first half of the draws, and the threshold is the
    ``quantile`` of the score of held-out inputs with one draw of the second half added to
    each. Both stay fitted on simulated inputs; the draws describe
    the error, not the inputs to be scored.

    Parameters
    ----------
    z_train
        Standardised training inputs.
    labels
        Their class indices.
    z_heldout
        Standardised held-out in-distribution inputs (simulated, not used in training), on which
        the threshold is set to the ``quantile`` of the score.
    n_classes
        Number of classes; each must have at least one training input.
    quantile
        The held-out quantile that becomes the threshold (0.99: about 1 % of in-distribution
        inputs flagged).
    model_error
        Draws of the additive model error in the standardised feature units (for example
        :func:`bayesdoor.datagen.model_error_draws` divided by the ensemble's ``scale``), or
        ``None`` for the simulations alone.
    key
        Picks the draw added to each held-out input; required with ``model_error``.

    Returns
    -------
    MahalanobisOOD

    Raises
    ------
    ValueError
        For a quantile outside (0, 1), an empty class, no held-out inputs, model-error draws
        of another shape than the inputs or with non-finite values, or ``model_error`` without
        ``key``.
    """
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"quantile must lie in (0, 1), got {quantile!r}")
    means, cov = _tied_scatter(z_train, labels, n_classes)
    if len(z_heldout) == 0:
        raise ValueError("z_heldout is empty: the threshold needs held-out in-distribution inputs")
    heldout = np.asarray(z_heldout, dtype=np.float64)
    n_draws = 0
    if model_error is not None:
        cov, heldout, n_draws = _add_model_error(
            cov, heldout, model_error, key, tuple(np.shape(z_train)[1:])
        )
    detector = _whitened(means, cov, quantile, n_draws, jnp.asarray(z_train).dtype)
    scores = np.asarray(detector.score(jnp.asarray(heldout, dtype=detector.means.dtype)))
    threshold = np.quantile(scores, quantile)
    return eqx.tree_at(
        lambda d: d.threshold, detector, jnp.asarray(threshold, dtype=detector.means.dtype)
    )


def check_model_error(model_error, shape: tuple[int, ...]) -> np.ndarray:
    """``model_error`` as float64 draws of ``shape``, or a ``ValueError`` naming the problem."""
    e = np.asarray(model_error, dtype=np.float64)
    if e.ndim != 1 + len(shape) or tuple(e.shape[1:]) != shape or len(e) == 0:
        raise ValueError(
            f"model_error must hold draws of the inputs' shape, (draw, {', '.join(map(str, shape))}"
            f"), got {e.shape}: one additive error per draw, in the same units as the inputs"
        )
    if not np.all(np.isfinite(e)):
        raise ValueError("model_error holds non-finite values: drop those draws")
    return e
