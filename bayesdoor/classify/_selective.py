"""Selective classification: abstain where the call is too likely wrong, at a stated risk.

A classifier that may abstain trades coverage (the share of runs it calls) for selective risk
(the share of its calls that are wrong). Ranking runs by the top probability, the
risk-coverage curve (:func:`risk_coverage`) shows that trade where the true states are known;
:func:`select_calls` picks the point whose expected risk, from the calibrated probabilities
themselves, is the stated one, without labels (Chow's rule). A guarantee from held-out labelled
runs (Geifman and El-Yaniv's selection with guaranteed risk) needs about 90 runs without an
error for a 5 % risk at 95 % confidence, more than a quick job holds out; the probabilities'
calibration is instead checked where labels are known, and :func:`risk_upper_bound` states
how far the realised risk may lie from what was seen.

References
----------
Chow, C. K. (1970). On optimum recognition error and reject tradeoff. IEEE Transactions on
Information Theory 16(1), 41-46. Geifman, Y. and El-Yaniv, R. (2017). Selective
classification for deep neural networks. NeurIPS.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from jaxtyping import ArrayLike, Float, Int
from scipy.stats import beta

#: the selective risk the job keeps its calls under by default
SELECTIVE_RISK = 0.05


def _confidence_correct(
    probabilities: ArrayLike, labels: ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(probabilities, dtype=float)
    y = np.asarray(labels)
    if p.ndim != 2 or y.shape != p.shape[:1]:
        raise ValueError(
            f"probabilities must be (run, class) and labels (run,), got {p.shape} and {y.shape}"
        )
    return p.max(axis=1), (p.argmax(axis=1) == y)


def risk_upper_bound(errors: int, calls: int, delta: float) -> float:
    """The one-sided Clopper-Pearson upper bound of a risk, at confidence ``1 - delta``.

    ``errors`` wrong of ``calls``; 1 when there are no calls.
    """
    if calls <= 0:
        return 1.0
    if errors >= calls:
        return 1.0
    return float(beta.ppf(1 - delta, errors + 1, calls - errors))


class RiskCoverage(NamedTuple):
    """The risk-coverage curve of a ranking by top probability.

    Attributes
    ----------
    threshold
        The top probability at each point (decreasing): a run is called when its top
        probability is at least this.
    coverage
        The share of runs called at each threshold.
    risk
        The share of the called runs whose call is wrong.
    aurc
        The area under the curve (the mean selective risk over coverage, lower is better).
    """

    threshold: np.ndarray
    coverage: np.ndarray
    risk: np.ndarray
    aurc: float


def risk_coverage(
    probabilities: Float[ArrayLike, "run class"], labels: Int[ArrayLike, " run"]
) -> RiskCoverage:
    """The risk-coverage curve, one point per distinct top probability (ties called together)."""
    confidence, correct = _confidence_correct(probabilities, labels)
    if confidence.size == 0:
        empty = np.zeros(0)
        return RiskCoverage(empty, empty, empty, float("nan"))
    order = np.argsort(-confidence, kind="stable")
    conf, wrong = confidence[order], ~correct[order]
    cum_wrong = np.cumsum(wrong)
    # the last index of each tie group: every run of equal confidence is called together
    last = np.flatnonzero(np.r_[conf[1:] != conf[:-1], True])
    calls = last + 1
    coverage = calls / conf.size
    risk = cum_wrong[last] / calls
    # the mean over all coverage levels 1/N .. 1 (each run in turn), ties at their group's risk
    per_run = np.repeat(risk, np.diff(np.r_[0, calls]))
    return RiskCoverage(conf[last], coverage, risk, float(per_run.mean()))


class Selection(NamedTuple):
    """Which runs are called at a stated selective risk.

    Attributes
    ----------
    called
        Per run, whether it is called.
    threshold
        The lowest top probability called (``None``: no run called).
    target_risk
        The stated selective risk.
    expected_risk
        The share of the calls expected wrong, from the probabilities themselves (the mean
        of ``1 - top probability`` over the calls).
    """

    called: np.ndarray
    threshold: float | None
    target_risk: float
    expected_risk: float


def select_calls(
    probabilities: Float[ArrayLike, "run class"], target_risk: float = SELECTIVE_RISK
) -> Selection:
    """Call the most probable runs while the expected share of wrong calls stays under a target.

    With calibrated probabilities, a run called its most probable state is wrong with
    probability ``1 - p_top``, so the expected selective risk of calling every run whose top
    probability is at least ``t`` is the mean of ``1 - p_top`` over them. The runs are called
    from the most probable down while that mean stays at most ``target_risk`` (runs of equal
    top probability together): the largest coverage the probabilities promise at that risk
    (Chow's rule for a risk rather than a cost). Needs no labels; the promise is as good as
    the probabilities' calibration, which :func:`risk_coverage` checks where labels are known.

    Raises
    ------
    ValueError
        For a ``target_risk`` outside (0, 1) or probabilities that are not ``(run, class)``.
    """
    if not 0 < target_risk < 1:
        raise ValueError(f"target_risk must lie in (0, 1), got {target_risk!r}")
    p = np.asarray(probabilities, dtype=float)
    if p.ndim != 2:
        raise ValueError(f"probabilities must be (run, class), got shape {p.shape}")
    top = p.max(axis=1) if p.size else np.zeros(len(p))
    called = np.zeros(len(p), dtype=bool)
    if not len(p):
        return Selection(called, None, target_risk, 0.0)
    order = np.argsort(-top, kind="stable")
    risk = np.cumsum(1 - top[order]) / np.arange(1, len(p) + 1)
    # the last index of each tie group, and the largest group end whose mean risk is allowed
    last = np.flatnonzero(np.r_[top[order][1:] != top[order][:-1], True])
    allowed = last[risk[last] <= target_risk]
    if not allowed.size:
        return Selection(called, None, target_risk, 0.0)
    end = int(allowed[-1])
    called[order[: end + 1]] = True
    return Selection(called, float(top[order][end]), target_risk, float(risk[end]))
