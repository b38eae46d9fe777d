"""Out-of-distribution score: Mahalanobis distance to the nearest training class mean."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._types import Array, Float, Int


class MahalanobisOOD(eqx.Module):
    """Distance of a (standardised, flattened) input to the nearest training class mean.

    The features are whitened with a shared (tied) within-class covariance, so the score is
    ``min_k sqrt((f - mu_k)^T Sigma^-1 (f - mu_k))``: the Mahalanobis distance to the closest
    class, in units of the training data's own scatter. An input is flagged when its score
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

    References
    ----------
    Lee, K., Lee, K., Lee, H. and Shin, J. (2018). A simple unified framework for detecting
    out-of-distribution samples and adversarial attacks. NeurIPS 31.
    """

    means: Float[Array, "class feature"]
    whitening: Float[Array, "feature feature"]
    threshold: Float[Array, ""]
    quantile: float = eqx.field(static=True)

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


def fit_mahalanobis(
    z_train: Float[Array, "sample channel freq"],
    labels: Int[Array, " sample"],
    z_heldout: Float[Array, "heldout channel freq"],
    n_classes: int,
    *,
    quantile: float = 0.99,
) -> MahalanobisOOD:
    """Fit class means and a tied shrunk covariance on training data; threshold on held-out data.

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

    Returns
    -------
    MahalanobisOOD

    Raises
    ------
    ValueError
        For a quantile outside (0, 1), an empty class, or no held-out inputs.
    """
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"quantile must lie in (0, 1), got {quantile!r}")
    z = np.asarray(z_train, dtype=np.float64).reshape(len(z_train), -1)
    y = np.asarray(labels)
    counts = np.bincount(y, minlength=n_classes)
    if np.any(counts == 0):
        raise ValueError(
            f"every class needs training inputs for the OOD score; counts per class: "
            f"{counts.tolist()}"
        )
    if len(z_heldout) == 0:
        raise ValueError("z_heldout is empty: the threshold needs held-out in-distribution inputs")
    means = np.stack([z[y == k].mean(axis=0) for k in range(n_classes)])
    cov, _ = ledoit_wolf(z - means[y])
    eigval, eigvec = np.linalg.eigh(cov)
    whitening = (eigvec / np.sqrt(eigval)).T
    dtype = jnp.asarray(z_train).dtype
    detector = MahalanobisOOD(
        means=jnp.asarray(means @ whitening.T, dtype=dtype),
        whitening=jnp.asarray(whitening, dtype=dtype),
        threshold=jnp.asarray(np.inf, dtype=dtype),
        quantile=float(quantile),
    )
    scores = np.asarray(detector.score(jnp.asarray(z_heldout, dtype=dtype)))
    threshold = np.quantile(scores, quantile)
    return eqx.tree_at(lambda d: d.threshold, detector, jnp.asarray(threshold, dtype=dtype))
