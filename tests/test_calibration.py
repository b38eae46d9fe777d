"""Calibration metrics, temperature scaling, uncertainty decomposition and the OOD covariance.

Metrics are checked against values worked out by hand on tiny examples (the arithmetic is in the
comments); tolerances of 1e-12 there are float64 round-off on sums of a handful of terms.
"""

import math

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.special

from bayesdoor.classify import (
    accuracy,
    brier_score,
    classification_metrics,
    confusion_matrix,
    ensemble_nll,
    entropy,
    expected_calibration_error,
    expected_entropy,
    fit_temperature,
    ledoit_wolf,
    mutual_information,
    negative_log_likelihood,
    predictive_entropy,
    reliability_bins,
    tempered_log_probabilities,
)

# five predictions of three classes; confidences 0.95, 0.95, 0.65, 0.45, 0.82
P = np.array(
    [
        [0.95, 0.03, 0.02],  # true 0, predicted 0: correct
        [0.05, 0.95, 0.00],  # true 0, predicted 1: wrong
        [0.65, 0.30, 0.05],  # true 0, predicted 0: correct
        [0.20, 0.35, 0.45],  # true 1, predicted 2: wrong
        [0.10, 0.82, 0.08],  # true 1, predicted 1: correct
    ]
)
Y = np.array([0, 0, 0, 1, 1])


def test_accuracy_and_confusion_by_hand():
    assert accuracy(P, Y) == pytest.approx(3 / 5, abs=1e-15)
    # rows true, columns predicted: true 0 -> (0, 1, 0); true 1 -> (2, 1)
    expected = np.array([[2, 1, 0], [0, 1, 1], [0, 0, 0]])
    np.testing.assert_array_equal(confusion_matrix(Y, P.argmax(axis=1), 3), expected)


def test_nll_and_brier_by_hand():
    # p(true) = 0.95, 0.05, 0.65, 0.35, 0.82
    nll = -(math.log(0.95) + math.log(0.05) + math.log(0.65) + math.log(0.35) + math.log(0.82)) / 5
    assert negative_log_likelihood(P, Y) == pytest.approx(nll, abs=1e-12)
    # per sample sum_k (p_k - onehot_k)^2:
    # 0.05^2 + 0.03^2 + 0.02^2 = 0.0038
    # 0.95^2 + 0.95^2 + 0 = 1.805
    # 0.35^2 + 0.30^2 + 0.05^2 = 0.215
    # 0.20^2 + 0.65^2 + 0.45^2 = 0.665
    # 0.10^2 + 0.18^2 + 0.08^2 = 0.0488
    brier = (0.0038 + 1.805 + 0.215 + 0.665 + 0.0488) / 5
    assert brier_score(P, Y) == pytest.approx(brier, abs=1e-12)


def test_nll_of_a_zero_probability_is_large_and_finite():
    p = np.array([[1.0, 0.0], [0.5, 0.5]])
    value = negative_log_likelihood(p, np.array([1, 0]))
    assert np.isfinite(value) and value > 300


def test_ece_equal_width_15_bins_by_hand():
    # bin floor(15 c): 0.95 -> 14 (twice, one right), 0.65 -> 9, 0.45 -> 6, 0.82 -> 12
    # gaps: |0.5 - 0.95| = 0.45 (2 samples), |1 - 0.65| = 0.35, |0 - 0.45| = 0.45, |1 - 0.82| = 0.18
    ece = (2 * 0.45 + 0.35 + 0.45 + 0.18) / 5
    assert expected_calibration_error(P, Y, 15, "width") == pytest.approx(ece, abs=1e-12)
    bins = reliability_bins(P, Y, 15, "width")
    np.testing.assert_array_equal(np.flatnonzero(bins.counts), [6, 9, 12, 14])
    assert bins.accuracy[14] == 0.5 and bins.confidence[14] == pytest.approx(0.95, abs=1e-15)
    assert np.isnan(bins.accuracy[0])


def test_ece_equal_mass_by_hand():
    # sorted confidences: 0.45 (wrong), 0.65, 0.82 (right) | 0.95 (right), 0.95 (wrong)
    # bin 1: accuracy 2/3, confidence (0.45 + 0.65 + 0.82) / 3 = 0.64; bin 2: 0.5 vs 0.95
    ece = (3 * abs(2 / 3 - 0.64) + 2 * 0.45) / 5
    assert expected_calibration_error(P, Y, 2, "mass") == pytest.approx(ece, abs=1e-12)


def test_ece_equal_mass_15_bins_one_sample_each():
    # with as many samples as bins every bin holds one sample: ECE = mean |correct - confidence|
    rng = np.random.default_rng(3)
    p = rng.dirichlet(np.ones(3), size=15)
    y = rng.integers(0, 3, size=15)
    correct = p.argmax(axis=1) == y
    expected = np.mean(np.abs(correct - p.max(axis=1)))
    assert expected_calibration_error(p, y, 15, "mass") == pytest.approx(expected, abs=1e-12)
    assert reliability_bins(p, y, 15, "mass").counts.tolist() == [1] * 15


def test_ece_is_zero_when_confidence_matches_accuracy():
    # ten predictions at confidence 0.7 of which seven are right: calibrated in both binnings
    p = np.tile([0.7, 0.2, 0.1], (10, 1))
    y = np.array([0] * 7 + [1] * 3)
    assert expected_calibration_error(p, y, 15, "width") == pytest.approx(0, abs=1e-12)
    assert expected_calibration_error(p, y, 5, "mass") == pytest.approx(0, abs=1e-12)


def test_metric_errors_name_the_problem():
    with pytest.raises(ValueError, match="labels must be integer class indices"):
        accuracy(P, np.array([0, 0, 0, 1, 3]))
    with pytest.raises(ValueError, match="shape \\(sample, class\\)"):
        brier_score(P[0], Y[:1])
    with pytest.raises(ValueError, match="binning must be"):
        expected_calibration_error(P, Y, 15, "quantile")
    with pytest.raises(ValueError, match="at least n_bins=15 samples"):
        expected_calibration_error(P, Y, 15, "mass")


def test_classification_metrics_bundle():
    m = classification_metrics(P, Y)
    assert m["accuracy"] == pytest.approx(0.6)
    assert m["confusion"] == [[2, 1, 0], [0, 1, 1], [0, 0, 0]]
    assert np.isnan(m["ece_mass"])  # 5 samples, 15 bins


def _pooled(logits, t=1.0):
    """Calibrated ensemble probabilities written out: (mean_m softmax(z_m))^(1/T), normalised."""
    q = scipy.special.softmax(logits, axis=-1).mean(axis=0) ** (1.0 / t)
    return q / q.sum(axis=-1, keepdims=True)


def _overconfident_logits(factor, rng, n=4000, members=5, noise=0.1):
    """Logits ``factor * log p_true`` (plus small member noise) for labels drawn from p_true."""
    p_true = rng.dirichlet(np.full(3, 0.7), size=n)
    y = np.array([rng.choice(3, p=p) for p in p_true])
    base = factor * np.log(p_true)
    return base[None] + noise * rng.standard_normal((members, n, 3)), y


@pytest.mark.parametrize("factor", [4.0, 0.5])
def test_temperature_recovers_the_over_or_underconfidence(factor):
    # labels drawn from p_true and logits sharpened (factor > 1) or flattened (factor < 1): the
    # NLL-optimal temperature is close to the factor. With 4000 samples the sampling spread of
    # the fitted T is a few per cent; 15 % also covers the bias from the member noise.
    rng = np.random.default_rng(11)
    logits, y = _overconfident_logits(factor, rng)
    t = fit_temperature(logits, y)
    assert t == pytest.approx(factor, rel=0.15)
    assert ensemble_nll(logits, y, t) < ensemble_nll(logits, y, 1.0) - 0.05


def test_temperature_lowers_nll_and_keeps_accuracy_of_an_overconfident_model():
    rng = np.random.default_rng(5)
    logits, y = _overconfident_logits(4.0, rng, n=2000)
    t = fit_temperature(logits, y)
    before, after = _pooled(logits), _pooled(logits, t)
    assert negative_log_likelihood(after, y) < negative_log_likelihood(before, y)
    assert accuracy(after, y) == accuracy(before, y)
    assert expected_calibration_error(after, y) < expected_calibration_error(before, y)


def test_fitted_temperature_is_the_grid_minimum():
    # an independent reference: a dense grid over log T finds the same minimiser
    rng = np.random.default_rng(2)
    logits, y = _overconfident_logits(2.0, rng, n=500)
    grid = np.exp(np.linspace(np.log(0.5), np.log(8.0), 4001))
    best = grid[np.argmin([ensemble_nll(logits, y, t) for t in grid])]
    assert fit_temperature(logits, y) == pytest.approx(best, rel=2e-3)  # the grid spacing


def test_ensemble_nll_matches_the_direct_formula():
    rng = np.random.default_rng(4)
    logits = rng.normal(size=(3, 50, 4))
    y = rng.integers(0, 4, size=50)
    t = 1.7
    direct = -np.mean(np.log(_pooled(logits, t)[np.arange(50), y]))
    assert ensemble_nll(logits, y, t) == pytest.approx(direct, rel=1e-12)
    np.testing.assert_allclose(
        np.exp(tempered_log_probabilities(logits, t)), _pooled(logits, t), rtol=1e-12
    )


def test_temperature_never_changes_the_predicted_class():
    # members that disagree (independent random logits): the calibrated ensemble's top class is
    # the plain ensemble's for any temperature
    rng = np.random.default_rng(6)
    logits = 3 * rng.normal(size=(5, 400, 3))
    top = _pooled(logits).argmax(axis=1)
    for t in (0.05, 0.3, 1.0, 4.0, 50.0):
        np.testing.assert_array_equal(
            np.argmax(tempered_log_probabilities(logits, t), axis=1), top, err_msg=f"T={t}"
        )


def test_temperature_on_a_perfectly_separated_set_warns():
    logits = np.array([[[10.0, 0.0], [0.0, 10.0]]])
    with pytest.warns(UserWarning, match="at the bound"):
        fit_temperature(logits, np.array([0, 1]))


def test_entropy_identities():
    rng = np.random.default_rng(0)
    members = jnp.asarray(rng.dirichlet(np.full(3, 0.5), size=(7, 200)))
    h, e, mi = predictive_entropy(members), expected_entropy(members), mutual_information(members)
    np.testing.assert_allclose(h, e + mi, atol=1e-14)  # the definition, up to round-off
    assert float(jnp.min(mi)) >= -1e-14  # Jensen: the entropy is concave
    assert float(jnp.max(h)) <= math.log(3) + 1e-14
    agree = jnp.broadcast_to(members[0], members.shape)
    np.testing.assert_allclose(mutual_information(agree), 0, atol=1e-14)
    np.testing.assert_allclose(predictive_entropy(agree), entropy(members[0]), atol=1e-14)


def test_entropy_by_hand():
    assert float(entropy(jnp.array([1 / 3, 1 / 3, 1 / 3]))) == pytest.approx(math.log(3))
    assert float(entropy(jnp.array([1.0, 0.0, 0.0]))) == 0.0
    # two confident members on different classes: no aleatoric, all epistemic, log 2 nats
    members = jnp.array([[[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]])
    assert float(expected_entropy(members)[0]) == 0.0
    assert float(mutual_information(members)[0]) == pytest.approx(math.log(2), abs=1e-15)


def test_ledoit_wolf_shortcut_matches_the_definition():
    # the implementation uses sum_k ||x_k x_k^T - S||^2 = sum_k ||x_k||^4 - n ||S||^2; check it
    # against the sum itself (Ledoit and Wolf 2004, lemma 3.3 and theorem 3.1)
    rng = np.random.default_rng(8)
    x = rng.normal(size=(40, 6)) * np.array([1, 2, 0.5, 1, 3, 1])
    x = x - x.mean(axis=0)
    n, p = x.shape
    s = x.T @ x / n
    mu = np.trace(s) / p
    delta2 = np.sum((s - mu * np.eye(p)) ** 2) / p
    beta2 = sum(np.sum((np.outer(r, r) - s) ** 2) / p for r in x) / n**2
    shrink = min(beta2, delta2) / delta2
    cov, got = ledoit_wolf(x)
    assert got == pytest.approx(shrink, rel=1e-10)
    np.testing.assert_allclose(cov, shrink * mu * np.eye(p) + (1 - shrink) * s, rtol=1e-12)
    # many samples of a non-spherical covariance: little shrinkage
    _, small = ledoit_wolf(rng.normal(size=(20000, 6)) * np.array([1, 2, 0.5, 1, 3, 1]))
    assert small < 0.01


def test_reliability_diagram_is_written(tmp_path):
    from bayesdoor.report import plot_reliability

    rng = np.random.default_rng(5)
    logits, y = _overconfident_logits(3.0, rng, n=300)
    before, after = _pooled(logits), _pooled(logits, 3.0)
    path = plot_reliability(after, y, tmp_path / "reliability.png", uncalibrated=before)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(ValueError, match="at least n_bins=15 samples"):
        plot_reliability(after[:10], y[:10], tmp_path / "small.png")
