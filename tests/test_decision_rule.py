"""The held-out rule's t statistic and its monotone closure of ``scripts/decision_rule.py``."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
from decision_rule import (
    Threshold,
    main,
    monotone_statistic,
    monotone_statistic_on_grid,
    t_statistic,
    union_scale,
)


def _samples(seed: int, rows: int, runs: int) -> np.ndarray:
    """Normal samples with a random offset per row: some mostly gain, some mostly lose."""
    rng = np.random.default_rng(seed)
    return rng.standard_normal((rows, runs)) + rng.normal(0.0, 1.5, (rows, 1))


#: per-run gains of 12 runs in whole nats, one run far above the rest (a sample for the
#: statistics' arithmetic and the script's tables)
RAIL = np.array([-17, 35, 49, 28, 18, 18, 5, 164, 17, 23, 20, 21], dtype=float)


def test_t_statistic_is_the_rule_of_compare_held_out():
    from bayesdoor.diagnose._gain import compare_held_out

    gain = compare_held_out(np.zeros(12), RAIL, np.ones(12), np.zeros(12))
    assert t_statistic(RAIL) == pytest.approx(gain.elpd_difference / gain.elpd_se, rel=1e-12)


@pytest.mark.parametrize("runs", [3, 6, 7, 12])
def test_monotone_statistic_is_at_least_t(runs):
    d = _samples(1, 5000, runs)
    t, closure = t_statistic(d), monotone_statistic(d)
    # no cap (c >= max d) is one of the caps, so T >= t up to rounding of the two sums
    assert np.all(closure >= t - 1e-12 * np.abs(t))
    # and the caps matter: on most positive samples some cap beats no cap
    assert np.mean(closure[t > 1] > t[t > 1] + 1e-6) > 0.5


@pytest.mark.parametrize("runs", [4, 7, 12])
def test_monotone_statistic_is_the_maximum_over_a_fine_grid_of_caps(runs):
    d = _samples(2, 60, runs)
    exact, grid = monotone_statistic(d), monotone_statistic_on_grid(d, caps=1001)
    # the grid evaluates real caps, so it can only fall below the maximum ...
    assert np.all(grid <= exact + 1e-12 * np.abs(exact))
    # ... by at most the curvature times the squared spacing: with 1001 caps per interval
    # about 1e-8 of T on these samples, so 1e-5 fails only for a wrong maximum
    assert np.all(exact - grid <= 1e-5 * np.abs(exact))


def test_monotone_statistic_equals_t_when_no_value_is_above_the_median():
    d = np.array([[-3.0, -1.0, 2.0, 2.0, 2.0], [0.5, 1.0, 4.0, 4.0, 4.0]])
    np.testing.assert_allclose(monotone_statistic(d), t_statistic(d), rtol=1e-12)


@pytest.mark.parametrize("runs", [3, 6, 7, 12])
def test_raising_the_largest_value_never_lowers_the_statistic(runs):
    # any cap below the old largest value leaves the same sample, and the old largest value
    # as a cap gives back the old sample: nothing the old statistic saw is lost
    rng = np.random.default_rng(3)
    d = _samples(3, 5000, runs)
    raised = d.copy()
    raised[np.arange(len(d)), np.argmax(d, axis=-1)] += rng.exponential(2.0, len(d))
    before = monotone_statistic(d)
    assert np.all(monotone_statistic(raised) >= before - 1e-12 * np.abs(before))


@pytest.mark.parametrize("runs", [5, 6, 7, 12])
def test_raising_a_gain_above_the_median_never_lowers_a_positive_statistic(runs):
    # the case that the median stays and the raised value is not negative: at the optimal cap
    # c* > median the slope of t in c is >= 0 from the left, and then t grows with any
    # uncapped value in [0, c*]; a cap below the raised value leaves the sample as it was
    rng = np.random.default_rng(4)
    rows = np.arange(5000)
    d = _samples(4, len(rows), runs)
    # ranks whose raise leaves the median: above the middle one, or above the upper middle one
    rank = rng.integers(runs // 2 + 1, runs, len(rows))
    index = np.argsort(d, axis=-1)[rows, rank]
    raised = d.copy()
    raised[rows, index] += rng.exponential(1.0, len(rows)) * rng.choice(
        [0.01, 1.0, 10.0], len(rows)
    )
    np.testing.assert_array_equal(np.median(raised, axis=-1), np.median(d, axis=-1))
    before, after = monotone_statistic(d), monotone_statistic(raised)
    kept = (before > 0) & (d[rows, index] >= 0)
    assert kept.sum() > 1000
    assert np.all(after[kept] >= before[kept] - 1e-12 * before[kept])


def test_raising_the_upper_middle_value_of_an_even_sample_can_lower_the_statistic():
    # the median is the lowest cap; raising the upper middle value raises it, and the cap
    # that made T large is no longer allowed
    d = np.array([1.0, 8.0, 9.0, 14.0, 24.0, 25.0])
    raised = np.array([1.0, 8.0, 9.0, 20.0, 24.0, 25.0])
    assert monotone_statistic(d) == pytest.approx(5.2487, abs=1e-4)
    assert monotone_statistic(raised) == pytest.approx(4.6404, abs=1e-4)


def test_one_run_that_gains_far_more_silences_t_but_not_the_closure():
    # campaigns of 12 runs that each gain 25 +- 12 nats (the scale of the rig's rail
    # refits), of which one run gains eight times the median (a run that the cause
    # dominates): the outlier widens t's standard error, the closure caps it
    rng = np.random.default_rng(11)
    gains = rng.normal(25.0, 12.0, (2000, 12))
    outlier = gains.copy()
    outlier[:, 7] = 8.0 * np.median(gains, axis=1)
    assert np.mean(t_statistic(gains) > 4.0) > 0.98
    assert np.mean(t_statistic(outlier) > 4.0) < 0.02
    assert np.mean(monotone_statistic(outlier) > 4.0) > 0.98
    # the script's grid of caps is a lower bound that meets the exact closure within 1e-4
    grid = np.array([monotone_statistic_on_grid(d) for d in outlier[:200]])
    exact = monotone_statistic(outlier[:200])
    assert np.all(grid <= exact + 1e-9) and np.all(exact - grid < 1e-4)


def test_t_false_alarms_under_normal_noise_match_the_t_distribution():
    draws, runs = 20_000, 12
    d = np.random.default_rng(5).standard_normal((draws, runs))
    expected = draws * stats.t.sf(4.0, runs - 1)
    # 4 binomial standard deviations: with about 21 alarms expected, about 4.6 each
    sd = np.sqrt(expected * (1 - expected / draws))
    assert abs(np.sum(t_statistic(d) > 4.0) - expected) < 4 * sd


def test_the_librarys_union_scale_is_found_again_on_other_draws():
    from bayesdoor.diagnose._gain import UNION_SCALE, capped_threshold

    # 10 x 20,000 draws of another seed than the table's 10 x 100,000
    k, se = union_scale(8, 20_000, 3, capped_threshold(8))
    assert se < 0.02
    assert abs(k - UNION_SCALE[8]) < 4 * se + 0.005, (k, se, UNION_SCALE[8])


def test_tail_probability_counts_the_kept_draws_above():
    # 1000 draws of which the largest 3 were kept
    threshold = Threshold(12, 0.001, 2.0, 0.0, 1000, np.array([1.0, 2.0, 3.0]))
    assert threshold.tail_probability(2.5) == 1 / 1000
    assert threshold.tail_probability(3.0) == 0.0
    assert threshold.tail_probability(1.0) == 2 / 1000
    assert threshold.tail_probability(0.5) is None


def test_too_few_runs_is_refused():
    with pytest.raises(ValueError, match="at least 2 runs"):
        monotone_statistic(np.ones((3, 1)))


def _case(name, seed, causes):
    return {"name": name, "seed": seed, "diagnosis": {"causes": causes}}


def _cause(name, per_run=None, gain=True, decisive=False):
    if not gain:
        return {"name": name, "gain": None}
    body = {"decisive": decisive}
    if per_run is not None:
        body["delta_elpd_per_run"] = list(per_run)
    return {"name": name, "gain": body}


def test_main_tables_the_saved_cases_and_counts_the_skipped(tmp_path):
    cases = tmp_path / "cases"
    cases.mkdir()
    spiky = [*RAIL[:7], 400.0, *RAIL[8:]]
    (cases / "rail_waviness-5.json").write_text(
        json.dumps(
            _case(
                "rail_waviness",
                5,
                [
                    _cause("rail_waviness", spiky),
                    _cause("frame_mode", [1.0, -1.0, 2.0, 0.5, -0.5, 0.0]),
                    _cause("mains_hum", []),
                    _cause("none", gain=False),
                ],
            )
        )
    )
    (cases / "none-1.json").write_text(
        json.dumps(
            _case("none", 1, [_cause("frame_mode"), _cause("sensor_cross_axis", gain=False)])
        )
    )
    out = tmp_path / "rule.md"
    main(["--draws", "200", "--cases", str(cases), "--results", str(out)])
    text = out.read_text()
    assert "Made by `python scripts/decision_rule.py --draws 200" in text
    t, closure = t_statistic(np.array(spiky)), monotone_statistic(np.array(spiky))
    assert t < 4 < closure
    assert f"| rail_waviness-5 | rail_waviness | yes | 12 | {t:.2f} | {closure:.2f} |" in text
    assert "| rail_waviness-5 | frame_mode | no | 6 |" in text
    assert "mains_hum" not in text
    assert (
        "Of the 2 saved cases, 2 candidates have per-run gains; 2 refitted candidates were "
        "skipped for want of per-run gains and 2 candidates were not refitted." in text
    )
    assert "`T > 4` changes 1 of the 2 verdicts of `t > 4`: rail_waviness-5 rail_waviness" in text
