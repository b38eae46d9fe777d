"""Selective classification: the risk-coverage curve, the calls at a stated risk, the bound."""

from __future__ import annotations

import numpy as np
import pytest

from bayesdoor.classify import SELECTIVE_RISK, risk_coverage, risk_upper_bound, select_calls


def _calibrated(n: int, seed: int, *, sharpen: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Three-class probabilities whose top class is right with its stated probability (raised
    to ``sharpen`` towards 1 when ``sharpen < 1``: the stated probability then overstates)."""
    rng = np.random.default_rng(seed)
    top = rng.uniform(1 / 3, 1, n)
    right = rng.random(n) < top
    stated = 1 - (1 - top) * sharpen
    p = np.column_stack([stated, (1 - stated) / 2, (1 - stated) / 2])
    labels = np.where(right, 0, rng.integers(1, 3, n))
    return p, labels


def test_calls_on_calibrated_probabilities_keep_the_stated_risk():
    risks, coverages = [], []
    for seed in range(20):
        p, labels = _calibrated(2000, seed)
        selection = select_calls(p, 0.05)
        called = selection.called
        risks.append(np.mean(p[called].argmax(axis=1) != labels[called]))
        coverages.append(called.mean())
        assert selection.expected_risk <= 0.05
        assert np.all(called == (p.max(axis=1) >= selection.threshold))
    # the calls' top probabilities are uniform on [t, 1] with mean error (1 - t) / 2 = 0.05,
    # so t = 0.9 and the coverage (1 - 0.9) / (2 / 3) = 0.15
    assert np.mean(risks) == pytest.approx(0.05, abs=0.005)
    assert np.mean(coverages) == pytest.approx(0.15, abs=0.01)


def test_overconfident_probabilities_break_the_promise_and_the_curve_shows_it():
    p, labels = _calibrated(20000, 3, sharpen=0.3)
    called = select_calls(p, 0.05).called
    realised = np.mean(p[called].argmax(axis=1) != labels[called])
    assert realised > 0.1
    curve = risk_coverage(p, labels)
    at = np.flatnonzero(curve.coverage >= called.mean())[0]
    assert curve.risk[at] == pytest.approx(realised, abs=0.01)


def test_risk_coverage_by_hand_with_ties():
    p = np.array([[0.9, 0.1], [0.8, 0.2], [0.8, 0.2], [0.6, 0.4]])
    labels = np.array([0, 1, 0, 0])
    curve = risk_coverage(p, labels)
    np.testing.assert_allclose(curve.threshold, [0.9, 0.8, 0.6])
    np.testing.assert_allclose(curve.coverage, [0.25, 0.75, 1.0])
    np.testing.assert_allclose(curve.risk, [0.0, 1 / 3, 0.25])
    # the mean risk over coverages 1/4 .. 4/4, the tied pair at its group's risk
    assert curve.aurc == pytest.approx((0 + 1 / 3 + 1 / 3 + 0.25) / 4)


def test_nothing_called_when_no_run_is_sure_enough():
    p = np.full((5, 2), 0.5)
    selection = select_calls(p, SELECTIVE_RISK)
    assert not selection.called.any() and selection.threshold is None


def test_risk_upper_bound_is_clopper_pearson():
    # no error in n calls: 1 - delta^(1/n)
    assert risk_upper_bound(0, 59, 0.05) == pytest.approx(1 - 0.05 ** (1 / 59))
    assert risk_upper_bound(0, 0, 0.05) == 1.0
    assert risk_upper_bound(3, 100, 0.05) > 0.03


@pytest.mark.parametrize("risk", [0.0, 1.0, -0.1])
def test_a_target_risk_outside_zero_one_is_refused(risk):
    with pytest.raises(ValueError, match="target_risk"):
        select_calls(np.array([[0.9, 0.1]]), risk)
