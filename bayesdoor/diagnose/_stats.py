"""Multiple testing and small numerical helpers shared by the diagnosis modules."""

from __future__ import annotations

import numpy as np

from .._types import Bool, Float


def benjamini_hochberg(
    p_values: Float[np.ndarray, "*shape"], q: float
) -> tuple[Bool[np.ndarray, "*shape"], float]:
    """The Benjamini-Hochberg step-up procedure at false discovery rate ``q``.

    Sort the ``m`` p-values, find the largest ``k`` with ``p_(k) <= k q / m`` and reject the
    ``k`` smallest. Under the complete null (nothing to find) the false discovery rate equals
    the probability of any rejection, so ``q`` then bounds the false-alarm probability exactly
    as Bonferroni would; when there is something to find, the threshold rises with the number
    of discoveries, which is what wide residual features (a resonance over several bins, a
    tone at a different bin in every run) need.

    Parameters
    ----------
    p_values
        The p-values of all the tests of one family (any shape; NaN counts as not tested).
    q
        The false discovery rate, in (0, 1).

    Returns
    -------
    rejected
        Which hypotheses are rejected, in the shape of ``p_values``.
    threshold
        The p-value at or below which a hypothesis is rejected (0 when none is).

    Raises
    ------
    ValueError
        For ``q`` outside (0, 1).

    References
    ----------
    Y. Benjamini and Y. Hochberg (1995), "Controlling the false discovery rate", J. R. Stat.
    Soc. B 57(1); Y. Benjamini and D. Yekutieli (2001), Ann. Stat. 29(4) (validity under
    positive dependence).
    """
    if not 0.0 < q < 1.0:
        raise ValueError(f"q must lie in (0, 1), got {q!r}; a typical false discovery rate is 0.01")
    p = np.asarray(p_values, dtype=float)
    tested = np.isfinite(p)
    m = int(tested.sum())
    if m == 0:
        return np.zeros(p.shape, dtype=bool), 0.0
    ordered = np.sort(p[tested])
    below = ordered <= q * np.arange(1, m + 1) / m
    if not below.any():
        return np.zeros(p.shape, dtype=bool), 0.0
    threshold = float(ordered[np.nonzero(below)[0][-1]])
    return tested & (p <= threshold), threshold


def contiguous_runs(mask: Bool[np.ndarray, " n"]) -> list[tuple[int, int]]:
    """The (first, last) indices of each run of consecutive ``True`` values."""
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(int)))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def parabolic_offset(left: float, centre: float, right: float) -> float:
    """Offset in bins, within [-0.5, 0.5], of the vertex of the parabola through three points."""
    denominator = left - 2.0 * centre + right
    if not np.isfinite(denominator) or denominator >= 0.0:
        return 0.0
    return float(np.clip(0.5 * (left - right) / denominator, -0.5, 0.5))
