"""The bookkeeping of ``scripts/solver_tolerance.py`` (no solve: the script itself is run by
hand, and writes results/solver_tolerance.md)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
from solver_tolerance import DEFAULT, candidates, loosest_under, ratio_stats


def _row(rtol, atol, rule, p99, failures=0):
    error = {"all": {"p99": p99}, "healthy": {"p99": p99 / 10}}
    return {"rtol": rtol, "atol": atol, "atol_rule": rule, "failures": failures, "error": error}


def test_candidates_hold_the_default_once_and_both_atol_rules():
    rows = candidates()
    assert rows.count(DEFAULT) == 1
    assert len(set(rows)) == len(rows)
    assert (1e-4, 1e-8) in rows and (1e-4, pytest.approx(1e-7)) in rows
    for rtol, atol in rows:
        assert atol == DEFAULT[1] or atol == pytest.approx(rtol * 1e-3)


def test_ratio_stats_ignore_failed_runs():
    x = np.array([[0.0, 1.0, np.nan], [2.0, np.nan, 3.0]])
    stats = ratio_stats(x)
    assert stats["median"] == pytest.approx(1.5)
    assert stats["max"] == 3.0
    assert np.isnan(ratio_stats(np.full(3, np.nan))["max"])


def test_loosest_under_stops_at_the_first_tolerance_over_the_threshold():
    rows = [
        _row(1e-6, 1e-9, "scaled", 0.01),
        _row(1e-5, 1e-8, "scaled", 0.05),
        _row(1e-4, 1e-7, "scaled", 0.5),
        # under the threshold again, but a tighter one is not: not counted
        _row(1e-3, 1e-6, "scaled", 0.02),
        _row(1e-4, 1e-8, "fixed", 0.08),
        _row(1e-3, 1e-8, "fixed", 0.01, failures=1),
    ]
    assert loosest_under(rows, 0.1, "scaled")["rtol"] == 1e-5
    # the fixed-atol rule continues the scaled rows at and below the default
    assert loosest_under(rows, 0.1, "fixed")["rtol"] == 1e-4
    assert loosest_under(rows, 0.1, "scaled", "healthy")["rtol"] == 1e-3
    assert loosest_under(rows, 0.001, "scaled") is None
