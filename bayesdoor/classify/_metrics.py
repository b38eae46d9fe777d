"""Classification and calibration metrics of probabilistic predictions (numpy, float64)."""

from __future__ import annotations

from typing import Literal, NamedTuple

import numpy as np
from jaxtyping import ArrayLike, Float, Int

Binning = Literal["width", "mass"]


def _check(probabilities: ArrayLike, labels: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(probabilities, dtype=np.float64)
    y = np.asarray(labels)
    if p.ndim != 2:
        raise ValueError(
            f"probabilities must have shape (sample, class), got shape {p.shape}: stack the "
            f"predictions of single inputs along a first axis"
        )
    if y.shape != p.shape[:1]:
        raise ValueError(
            f"labels must hold one class index per sample: shape ({p.shape[0]},) expected, "
            f"got {y.shape}"
        )
    if not np.issubdtype(y.dtype, np.integer) or np.any((y < 0) | (y >= p.shape[1])):
        raise ValueError(
            f"labels must be integer class indices in [0, {p.shape[1]}), got values "
            f"{np.unique(y)[:10].tolist()}"
        )
    return p, y


def accuracy(
    probabilities: Float[ArrayLike, "sample class"], labels: Int[ArrayLike, " sample"]
) -> float:
    """Fraction of samples whose most probable class is the true one."""
    p, y = _check(probabilities, labels)
    return float(np.mean(np.argmax(p, axis=1) == y))


def confusion_matrix(
    labels: Int[ArrayLike, " sample"], predicted: Int[ArrayLike, " sample"], n_classes: int
) -> Int[np.ndarray, "true predicted"]:
    """Counts of samples per (true class, predicted class): rows true, columns predicted."""
    y, yhat = np.asarray(labels), np.asarray(predicted)
    if y.shape != yhat.shape or y.ndim != 1:
        raise ValueError(
            f"labels and predicted must be 1-D of equal length, got shapes {y.shape}, {yhat.shape}"
        )
    for name, v in (("labels", y), ("predicted", yhat)):
        if np.any((v < 0) | (v >= n_classes)):
            raise ValueError(f"{name} must lie in [0, {n_classes}), got {np.unique(v).tolist()}")
    out = np.zeros((n_classes, n_classes), dtype=np.int64)
    np.add.at(out, (y, yhat), 1)
    return out


def negative_log_likelihood(
    probabilities: Float[ArrayLike, "sample class"], labels: Int[ArrayLike, " sample"]
) -> float:
    """Mean ``-log p(true class)`` in nats.

    A probability of exactly 0 for the true class is raised to the smallest positive float64
    (about 2e-308, a loss of about 708), so a single such sample dominates the mean, as it should.
    """
    p, y = _check(probabilities, labels)
    return float(-np.mean(np.log(np.maximum(p[np.arange(len(y)), y], np.finfo(np.float64).tiny))))


def brier_score(
    probabilities: Float[ArrayLike, "sample class"], labels: Int[ArrayLike, " sample"]
) -> float:
    """Multi-class Brier score: mean over samples of ``sum_k (p_k - [k == y])^2``, in [0, 2].

    References
    ----------
    Brier, G. W. (1950). Verification of forecasts expressed in terms of probability. Monthly
    Weather Review 78(1), 1-3.
    """
    p, y = _check(probabilities, labels)
    onehot = np.eye(p.shape[1])[y]
    return float(np.mean(np.sum((p - onehot) ** 2, axis=1)))


class ReliabilityBins(NamedTuple):
    """Top-label calibration per confidence bin (empty bins have ``counts == 0`` and NaN means).

    Attributes
    ----------
    lower, upper
        Confidence range of each bin: the fixed edges for equal-width bins, the smallest and
        largest confidence in the bin for equal-mass bins.
    counts
        Samples in each bin.
    confidence
        Mean top-label confidence in each bin.
    accuracy
        Fraction correct in each bin.
    """

    lower: np.ndarray
    upper: np.ndarray
    counts: np.ndarray
    confidence: np.ndarray
    accuracy: np.ndarray


def reliability_bins(
    probabilities: Float[ArrayLike, "sample class"],
    labels: Int[ArrayLike, " sample"],
    n_bins: int = 15,
    binning: Binning = "width",
) -> ReliabilityBins:
    """Bin the top-label confidence and compare it with the accuracy in each bin.

    Parameters
    ----------
    probabilities, labels
        Predictive probabilities and true class indices.
    n_bins
        Number of bins.
    binning
        ``"width"``: bin ``floor(confidence * n_bins)`` of equal-width bins over [0, 1] (a
        confidence of exactly 1 goes to the last bin). ``"mass"``: bin ``floor(r * n_bins / N)``
        with ``r`` the rank (from 0) of the confidence among the ``N`` samples: consecutive bins
        whose sizes differ by at most one, except that tied confidences share the lowest rank and
        so a bin (the result does not depend on the order of the samples); needs at least
        ``n_bins`` samples.

    Returns
    -------
    ReliabilityBins

    Raises
    ------
    ValueError
        For an unknown ``binning``, ``n_bins < 1``, or fewer samples than equal-mass bins.
    """
    p, y = _check(probabilities, labels)
    if isinstance(n_bins, bool) or not isinstance(n_bins, int) or n_bins < 1:
        raise ValueError(f"n_bins must be a positive integer, got {n_bins!r}")
    confidence = p.max(axis=1)
    correct = (p.argmax(axis=1) == y).astype(np.float64)
    if binning == "width":
        index = np.minimum(np.floor(confidence * n_bins).astype(np.int64), n_bins - 1)
        groups = [np.flatnonzero(index == b) for b in range(n_bins)]
        edges = np.linspace(0.0, 1.0, n_bins + 1)
        lower, upper = edges[:-1], edges[1:]
    elif binning == "mass":
        if len(y) < n_bins:
            raise ValueError(
                f"equal-mass binning needs at least n_bins={n_bins} samples, got {len(y)}: use "
                f"fewer bins or binning='width'"
            )
        # rank from 0, ties sharing the lowest: how many confidences are strictly smaller
        rank = np.searchsorted(np.sort(confidence), confidence, side="left")
        index = rank * n_bins // len(y)
        groups = [np.flatnonzero(index == b) for b in range(n_bins)]
        lower = np.array([confidence[g].min() if len(g) else np.nan for g in groups])
        upper = np.array([confidence[g].max() if len(g) else np.nan for g in groups])
    else:
        raise ValueError(f"binning must be 'width' or 'mass', got {binning!r}")
    counts = np.array([len(g) for g in groups], dtype=np.int64)
    with np.errstate(invalid="ignore"):
        conf = np.array([confidence[g].mean() if len(g) else np.nan for g in groups])
        acc = np.array([correct[g].mean() if len(g) else np.nan for g in groups])
    return ReliabilityBins(lower, upper, counts, conf, acc)


def expected_calibration_error(
    probabilities: Float[ArrayLike, "sample class"],
    labels: Int[ArrayLike, " sample"],
    n_bins: int = 15,
    binning: Binning = "width",
) -> float:
    """Expected calibration error: ``sum_b (n_b / N) |accuracy_b - confidence_b|``.

    The top-label ECE of Guo et al. (2017) with the bins of :func:`reliability_bins`.

    References
    ----------
    Guo, C., Pleiss, G., Sun, Y. and Weinberger, K. Q. (2017). On calibration of modern neural
    networks. ICML. Nixon, J. et al. (2019). Measuring calibration in deep learning. CVPR
    workshops (equal-mass, "adaptive" bins).
    """
    bins = reliability_bins(probabilities, labels, n_bins, binning)
    used = bins.counts > 0
    gaps = np.abs(bins.accuracy[used] - bins.confidence[used])
    return float(np.sum(bins.counts[used] * gaps) / np.sum(bins.counts))


def classification_metrics(
    probabilities: Float[ArrayLike, "sample class"],
    labels: Int[ArrayLike, " sample"],
    n_bins: int = 15,
) -> dict[str, float | list[list[int]]]:
    """Accuracy, NLL, Brier, ECE (equal width and equal mass) and the confusion matrix.

    ``ece_mass`` is NaN when there are fewer samples than bins.
    """
    p, y = _check(probabilities, labels)
    return {
        "accuracy": accuracy(p, y),
        "nll": negative_log_likelihood(p, y),
        "brier": brier_score(p, y),
        "ece": expected_calibration_error(p, y, n_bins, "width"),
        "ece_mass": (
            expected_calibration_error(p, y, n_bins, "mass") if len(y) >= n_bins else float("nan")
        ),
        "confusion": confusion_matrix(y, p.argmax(axis=1), p.shape[1]).tolist(),
    }
