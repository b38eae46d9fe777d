"""The ensemble weighed against a signature check: the stated model's own calibration, and
what it does where the ensemble's calls hold and where they do not."""

from __future__ import annotations

import numpy as np
import pytest

from bayesdoor.classify import combine_evidence, expected_calibration_error

ALPHA = 0.01
#: healthy, then three damage states (the bearing's families)
K = 4


def _rates(d, leak) -> np.ndarray:
    """q[y, k]: the probability that state k's signature shows on a run of state y."""
    q = np.full((K, K), ALPHA)
    for state in range(1, K):
        for k in range(1, K):
            q[state, k] = d[k - 1] if state == k else leak[k - 1]
    return q


def _campaign(n: int, *, pi: float, d, leak, seed: int):
    """Runs drawn from the stated model. With probability ``pi`` the ensemble's probabilities
    hold: they are the exact posterior of the state given the check and a second, independent
    clue (a pointer at the true state, right with probability 0.7), as an ensemble that read
    the whole signal would give. Otherwise it names a damage family at 0.99 while the true
    damage is any family (its healthy share still holds). Each damage state's signature shows
    with ``d`` on its own runs, ``leak`` on other damage and ``ALPHA`` on healthy runs."""
    rng = np.random.default_rng(seed)
    q = _rates(d, leak)
    holds = rng.random(n) < pi
    y = np.where(holds, rng.integers(0, K, n), 1 + rng.integers(0, K - 1, n))
    shown = rng.random((n, K)) < q[y]
    shown[:, 0] = False
    like = np.prod(np.where(shown[:, None, 1:], q[None, :, 1:], 1 - q[None, :, 1:]), axis=2)
    pointer = np.where(rng.random(n) < 0.7, y, rng.integers(0, K, n))
    clue = np.where(np.arange(K)[None] == pointer[:, None], 0.7, 0.3 / (K - 1))
    p = like * clue
    p /= p.sum(axis=1, keepdims=True)
    wrong = np.full((n, K), 0.01 / (K - 1))
    wrong[np.arange(n), 1 + rng.integers(0, K - 1, n)] = 0.99
    p = np.where(holds[:, None], p, wrong)
    shows = shown.astype(float)
    shows[:, 0] = np.nan
    return p, y, shows, holds


def test_void_calls_lose_their_confidence_and_the_campaign_its_calibration_error():
    """30 % of the ensemble's calls void: the ECE falls under the 0.10 the real records are
    held to, from more than twice that."""
    p, y, shows, holds = _campaign(3000, pi=0.7, d=(0.95, 0.9, 0.3), leak=(0.2, 0.5, 0.6), seed=0)
    evidence = combine_evidence(p, shows, 0, ALPHA)
    before = expected_calibration_error(p, y)
    after = expected_calibration_error(evidence.probabilities, y)
    assert before > 0.2
    assert after <= 0.10, (before, after)
    # the void calls' confidence falls; the calls that hold keep theirs
    top = evidence.probabilities.max(axis=1)
    assert np.mean(top[~holds]) < np.mean(p[~holds].max(axis=1)) - 0.2
    assert np.mean(top[holds]) > np.mean(p[holds].max(axis=1)) - 0.1
    # the campaign's rates are learned without labels: the share of calls that hold inside its
    # 90 % interval; the detection rates within 0.1 (their states are drawn from the ensemble
    # and the check together, as if the two were independent: here the ensemble read the
    # check, which biases the rates up a little)
    _, low, high = evidence.pi
    assert low <= 0.7 <= high
    for k, true in zip((1, 2, 3), (0.95, 0.9, 0.3), strict=True):
        assert abs(evidence.detection[k][0] - true) <= 0.1, (k, evidence.detection)
    # the runs whose probabilities do not hold lean to B more (a third of their calls are right
    # by chance, and the leaks show lines of other families: they cannot all be told apart)
    assert np.mean(evidence.applies[~holds]) < np.mean(evidence.applies[holds]) - 0.15


def test_where_the_ensemble_holds_its_probabilities_are_kept():
    p, y, shows, _ = _campaign(1000, pi=1.0, d=(0.95, 0.95, 0.9), leak=(0.1, 0.1, 0.1), seed=1)
    evidence = combine_evidence(p, shows, 0, ALPHA)
    assert evidence.pi[1] > 0.9
    assert np.mean(np.abs(evidence.probabilities - p).sum(axis=1)) < 0.05
    assert np.mean(evidence.probabilities.argmax(axis=1) == y) >= np.mean(p.argmax(axis=1) == y)


def test_runs_without_a_check_keep_the_ensemble_probabilities():
    p, _, shows, _ = _campaign(200, pi=0.5, d=(0.9, 0.9, 0.9), leak=(0.2, 0.2, 0.2), seed=2)
    shows[:50] = np.nan
    evidence = combine_evidence(p, shows, 0, ALPHA)
    np.testing.assert_array_equal(evidence.probabilities[:50], p[:50])
    assert np.all(np.isnan(evidence.applies[:50])) and evidence.checked == 150
    np.testing.assert_allclose(evidence.probabilities.sum(axis=1), 1.0)
    nothing = combine_evidence(p, np.full_like(p, np.nan), 0, ALPHA)
    np.testing.assert_array_equal(nothing.probabilities, p)


def test_the_same_seed_gives_the_same_probabilities():
    p, _, shows, _ = _campaign(100, pi=0.6, d=(0.9, 0.8, 0.4), leak=(0.2, 0.4, 0.5), seed=3)
    a = combine_evidence(p, shows, 0, ALPHA, seed=5)
    b = combine_evidence(p, shows, 0, ALPHA, seed=5)
    np.testing.assert_array_equal(a.probabilities, b.probabilities)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda p, s: (p[:, :3], s), "shape"),
        (lambda p, s: (p * 2, s), "sum to 1"),
        (lambda p, s: (p, np.where(np.isnan(s), s, 0.5)), "1, 0 or NaN"),
    ],
)
def test_bad_input_is_refused(change, match):
    p, _, shows, _ = _campaign(10, pi=0.5, d=(0.9, 0.9, 0.9), leak=(0.2, 0.2, 0.2), seed=4)
    p, shows = change(p, shows)
    with pytest.raises(ValueError, match=match):
        combine_evidence(p, shows, 0, ALPHA)
    with pytest.raises(ValueError, match="false_alarm_rate"):
        combine_evidence(np.full((1, 2), 0.5), np.zeros((1, 2)), 0, 0.0)
