"""Reliability diagram: accuracy against confidence in equal-width and equal-mass bins."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from jaxtyping import ArrayLike, Float, Int

from ..classify import Binning, expected_calibration_error, reliability_bins
from ..io import atomic_write


def _reliability_panel(ax, ax_n, binning: Binning, sets: dict, labels, n_bins: int) -> None:
    """One binning's column: accuracy against confidence above, confidences' histogram below."""
    ax.plot([0, 1], [0, 1], color="0.3", lw=1, ls=":", label="perfect calibration")
    for name, p in sets.items():
        bins = reliability_bins(p, labels, n_bins, binning)
        ece = expected_calibration_error(p, labels, n_bins, binning)
        used = bins.counts > 0
        label = f"{name}: ECE = {ece:.3f}"
        if name == "uncalibrated":
            ax.plot(
                bins.confidence[used],
                bins.accuracy[used],
                "o--",
                color="0.45",
                ms=4,
                label=label,
            )
            continue
        if binning == "width":
            _accuracy_bars(ax, bins, used, label)
        else:
            ax.plot(bins.confidence, bins.accuracy, "o-", color="tab:blue", ms=5, label=label)
            for edge in bins.upper[:-1]:
                ax_n.axvline(edge, color="0.5", lw=0.6)
        ax_n.hist(
            np.max(np.asarray(p), axis=1),
            bins=np.linspace(0, 1, 51),
            color="tab:blue",
            alpha=0.85,
        )
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("accuracy")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize=9, frameon=False)
    kind = "equal-width" if binning == "width" else "equal-mass"
    ax.set_title(f"{n_bins} {kind} bins", fontsize=11)
    ax_n.set_xlabel("confidence (top-label probability)")
    ax_n.set_ylabel("samples per 0.02")
    ax_n.grid(True, alpha=0.3)


def _accuracy_bars(ax, bins, used: np.ndarray, label: str) -> None:
    """Equal-width bins: a bar of the accuracy per bin and the hatched gap to its confidence."""
    centres = (bins.lower + bins.upper) / 2
    width = bins.upper - bins.lower
    ax.bar(
        centres[used],
        bins.accuracy[used],
        width[used],
        color="tab:blue",
        edgecolor="white",
        alpha=0.85,
        label=f"{label} (accuracy per bin)",
    )
    ax.bar(
        centres[used],
        bins.confidence[used] - bins.accuracy[used],
        width[used],
        bottom=bins.accuracy[used],
        facecolor="none",
        edgecolor="tab:red",
        hatch="///",
        lw=0.8,
        label="gap to the bin's mean confidence",
    )


def plot_reliability(
    probabilities: Float[ArrayLike, "sample class"],
    labels: Int[ArrayLike, " sample"],
    path: str | os.PathLike,
    *,
    n_bins: int = 15,
    uncalibrated: Float[ArrayLike, "sample class"] | None = None,
    title: str | None = None,
) -> Path:
    """Write a reliability diagram (PNG) of top-label confidence against accuracy.

    Two panels: equal-width bins (bars of the accuracy per bin, the gap to the diagonal
    shaded) and equal-mass bins (points at the mean confidence and accuracy of each bin), each
    with its ECE; below, the distribution of the confidence (with the equal-mass bin edges).
    A perfectly calibrated predictor lies on the diagonal.

    Parameters
    ----------
    probabilities
        Predictive probabilities (e.g. the calibrated ensemble's).
    labels
        True class indices.
    path
        The PNG to write (replaced atomically if it exists: the caller decides whether it may
        be).
    n_bins
        Bins of each kind.
    uncalibrated
        Optional probabilities before calibration, drawn as a dashed line for comparison.
    title
        The figure's title.

    Returns
    -------
    path
        The file written.

    Raises
    ------
    ValueError
        From :func:`bayesdoor.classify.reliability_bins` for inconsistent inputs, or fewer
        samples than ``n_bins`` (the equal-mass panel needs one per bin).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = {"calibrated" if uncalibrated is not None else "model": probabilities}
    if uncalibrated is not None:
        sets["uncalibrated"] = uncalibrated
    fig, axes = plt.subplots(
        2, 2, figsize=(11, 6.4), sharex=True, gridspec_kw={"height_ratios": [3, 1]}
    )
    binnings: tuple[Binning, Binning] = ("width", "mass")
    for col, binning in enumerate(binnings):
        _reliability_panel(axes[0, col], axes[1, col], binning, sets, labels, n_bins)
    n = len(np.asarray(labels))
    fig.suptitle(f"{title} ({n} samples)" if title else f"Reliability diagram ({n} samples)")
    fig.tight_layout()
    try:
        atomic_write(
            Path(path), lambda tmp: fig.savefig(tmp, format="png", dpi=120), overwrite=True
        )
    finally:
        plt.close(fig)
    return Path(path)
