"""Draws of the model error in the classifier's features: what a measurement adds to a simulation.

The OOD detector of :mod:`bayesdoor.classify` compares an input with a reference
distribution. Simulated training runs alone make a poor reference for measured runs: a model
with a handful of parameters fills a thin slab of the feature space, and every measurement
lies a little off it. These draws describe "a little": the structured discrepancy seen on
the measured runs of a known state (the calibration runs the fit used), plus the per-feature
scatter the fit's likelihood assigns to every measured feature (the Welch estimation scatter
of a finite record and the fitted model-error scale).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import numpy as np

from .._types import Array, Float
from ..inference import FeatureSpec, welch_log10_variance
from ._generate import TrainingData
from ._points import at_point, point_list, unique_points
from ._points import measured_points as _measured_points
from ._points import show_point as _show


def calibration_residuals(
    data: TrainingData,
    features: Float[np.ndarray, "run channel freq"],
    speeds: Float[np.ndarray, " run"] | Sequence[float],
    *,
    state: str,
) -> Float[np.ndarray, "run channel freq"]:
    """Measured features of runs of a known state minus the simulated mean at their speed.

    For measured run ``i`` at speed ``v_i``: ``features[i]`` minus the mean features of the
    training split's simulated runs of ``state`` at ``v_i``. With a posterior-predictive
    training set this is the measurement's discrepancy from the model (its systematic part
    and one realisation of its random part), not from one parameter draw.

    Parameters
    ----------
    data
        The simulated training data.
    features
        Classifier features of the measured runs (:func:`campaign_features`), for example
        the healthy calibration runs a fit used.
    speeds
        The operating speed of each measured run (its ``v_max``).
    state
        The state of the measured runs, one of ``data.states``.

    Returns
    -------
    residuals

    Raises
    ------
    ValueError
        For an unknown state, features of another shape than the training data's, or a speed
        at which the training split holds no simulated run of ``state``.
    """
    if state not in data.states:
        raise ValueError(f"state={state!r} is not one of the training data's {data.states}")
    x = np.asarray(features, dtype=float)
    v = _measured_points(speeds, data.speeds)
    if x.ndim != 3 or x.shape[1:] != data.features.shape[1:] or len(v) != len(x):
        raise ValueError(
            f"features must be (run, {', '.join(map(str, data.features.shape[1:]))}) like the "
            f"training data with one speed per run; got features {x.shape}, speeds {v.shape}"
        )
    train = data.subset("train")
    own = train.labels == data.states.index(state)
    residuals = np.empty_like(x)
    for i, speed in enumerate(v):
        at = own & at_point(train.speeds, speed)
        if not at.any():
            raise ValueError(
                f"run {i} has speed {_show(speed)} but the training split holds no {state} run "
                f"at that speed (simulated speeds {point_list(train.speeds)}): generate the "
                "training data at the campaign's speeds"
            )
        residuals[i] = x[i] - train.features[at].mean(axis=0)
    return residuals


def measurement_variance(
    data: TrainingData, sigma_model: Float[np.ndarray, "sample ..."] | None = None
) -> Float[np.ndarray, "channel freq"]:
    """Per-feature variance the fit's likelihood gives a measured feature about the model.

    The sum of the Welch estimation variance of a log10 PSD bin of the shortest simulated
    motion window (:func:`bayesdoor.inference.welch_log10_variance`: the fewest segments,
    the largest variance) and, with ``sigma_model``, the posterior mean of ``sigma^2``.

    Parameters
    ----------
    data
        The simulated training data (its windows, sampling rate and feature spec).
    sigma_model
        Posterior draws of the model-error scale in log10 decades, ``(sample,)``,
        ``(sample, channel)`` or ``(sample, channel, freq)``; ``None`` for the Welch scatter
        alone.

    Returns
    -------
    variance
        In decades^2.

    Raises
    ------
    ValueError
        When ``sigma_model`` does not fit the features' shape.
    """
    shape = data.features.shape[1:]
    fs = float(data.manifest["system"]["sampling_rate_hz"])
    nperseg = int(data.manifest["config"]["spec"]["nperseg"])
    step = nperseg - nperseg // 2
    first = np.ceil(np.round(data.t_start * fs, 6) / step)
    last = np.floor(np.round((data.t_stop * fs - nperseg + 1), 6) / step)
    segments = max(float(np.min(last - first + 1)), 1.0)
    bin_hz = fs / nperseg
    spec = FeatureSpec(f_low=bin_hz, f_high=bin_hz, band_width=bin_hz, nperseg=nperseg)
    variance = np.full(shape, float(welch_log10_variance(segments, fs, spec)))
    if sigma_model is None:
        return variance
    s = np.asarray(sigma_model, dtype=float)
    if s.ndim == 0 or s.shape[1:] not in ((), shape[:1], shape):
        raise ValueError(
            f"sigma_model of shape {s.shape} does not fit features of shape {shape}: give "
            "draws of one scale (sample,), one per channel (sample, channel) or one per feature"
        )
    second_moment = np.mean(s**2, axis=0)
    return variance + second_moment.reshape(second_moment.shape + (1,) * (3 - s.ndim))


def model_error_draws(
    n: int,
    *,
    key: Array,
    residuals: Float[np.ndarray, "run channel freq"] | None = None,
    variance: Float[np.ndarray, "channel freq"] | None = None,
) -> Float[np.ndarray, "n channel freq"]:
    """``n`` draws of the model error: a measured residual plus independent Gaussian scatter.

    Draw ``j`` is ``residuals[i_j] + sqrt(variance) * z_j`` with ``i_j`` uniform over the
    residuals and ``z_j`` standard normal per feature; either part may be left out. Pass
    them to :func:`bayesdoor.classify.fit_classifier` as
    ``FitOptions(ood_model_error=...)``.

    Parameters
    ----------
    n
        Number of draws.
    key
        PRNG key.
    residuals
        Discrepancies of measured runs of known state (:func:`calibration_residuals`).
    variance
        Per-feature variance of the independent part (:func:`measurement_variance`).

    Returns
    -------
    draws

    Raises
    ------
    ValueError
        When both parts are missing, ``n < 1``, their shapes differ, or a value is not finite
        (or a variance negative).
    """
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    r = None if residuals is None else np.asarray(residuals, dtype=float)
    v = None if variance is None else np.asarray(variance, dtype=float)
    if r is not None and (r.ndim != 3 or len(r) == 0 or not np.all(np.isfinite(r))):
        raise ValueError(f"residuals must be finite (run, channel, freq) arrays, got {r.shape}")
    if v is not None and (v.ndim != 2 or not np.all(np.isfinite(v)) or np.any(v < 0)):
        raise ValueError(f"variance must be a finite, non-negative (channel, freq) array: {v}")
    if r is not None and v is not None and r.shape[1:] != v.shape:
        raise ValueError(f"residuals {r.shape} and variance {v.shape} describe other features")
    if r is not None:
        shape = r.shape[1:]
    elif v is not None:
        shape = v.shape
    else:
        raise ValueError("give residuals, variance or both: the model error needs a description")
    k_pick, k_z = jax.random.split(key)
    draws = np.zeros((n, *shape))
    if r is not None:
        draws += r[np.asarray(jax.random.randint(k_pick, (n,), 0, len(r)))]
    if v is not None:
        draws += np.sqrt(v) * np.asarray(jax.random.normal(k_z, (n, *shape)))
    return draws


def with_measured_discrepancy(
    data: TrainingData,
    features: Float[np.ndarray, "run channel freq"],
    speeds: Float[np.ndarray, " run"] | Sequence[float],
    *,
    seed: int = 0,
    state: str | None = None,
) -> TrainingData:
    """Training data whose every simulated run carries the measured discrepancy of one known run.

    The discrepancy of measured run ``i`` (of the known ``state``, at speed ``v_i``) is its
    features minus the mean features of all simulated ``state`` runs at ``v_i``: what the
    model leaves out there (a mode it lacks, a sensor's gain, the noise floor), in log10
    PSD. Each simulated run, of every state, gets the discrepancy of one measured run at its
    speed, drawn at random (of any measured run when none is at its speed): the simulations
    then carry the error the model makes on this machine, as measured, not only its scale.
    Where the measurement holds more power than the model (noise, a mode the model lacks,
    a line), the excess is *added* to each simulated run's power spectrum, as such sources
    add to a signal: a fault's signature then stands out of the measured floor as little as
    it would on the machine. Where it holds less (a lower sensor gain, more damping), the
    deficit scales the spectrum (a log10 offset). ``results/transfer.md`` measures what it
    gains on doors the model lacks.

    Parameters
    ----------
    data
        The simulated training data (train and validation runs both get offsets).
    features
        Classifier features of the measured runs of ``state`` (the calibration runs).
    speeds
        Their speeds.
    seed
        Seed of the draws of which run's discrepancy each simulated run gets.
    state
        The measured runs' state; ``None``: the training data's healthy state
        (:attr:`TrainingData.healthy`).

    Returns
    -------
    TrainingData
        With ``features`` and ``model_error`` shifted by the drawn discrepancies.

    Raises
    ------
    ValueError
        For an unknown state, features of another shape, no measured run, or a measured
        speed without simulated runs of ``state``.
    """
    state = data.healthy if state is None else state
    if state not in data.states:
        raise ValueError(f"state={state!r} is not one of the training data's {data.states}")
    x = np.asarray(features, dtype=float)
    v = _measured_points(speeds, data.speeds)
    if x.ndim != 3 or x.shape[1:] != data.features.shape[1:] or len(v) != len(x) or not len(x):
        raise ValueError(
            f"features must be (run, {', '.join(map(str, data.features.shape[1:]))}) with one "
            f"speed per run and at least one run; got {x.shape} and {v.shape}"
        )
    own = data.labels == data.states.index(state)
    residuals = _residuals(data, x, v, own, state)
    rng = np.random.default_rng(seed)
    shifted = np.empty_like(data.features)
    for speed in unique_points(data.speeds):
        runs = np.flatnonzero(at_point(data.speeds, speed))
        pool = np.flatnonzero(at_point(v, speed))
        pool = pool if pool.size else np.arange(len(v))
        at = own & at_point(data.speeds, speed)
        # the simulated healthy mean at this speed (speeds without one take the residual
        # as a plain offset)
        base = data.features[at].mean(axis=0) if at.any() else None
        drawn = residuals[rng.choice(pool, size=runs.size)]
        shifted[runs] = _add_discrepancy(data.features[runs], drawn, base)
    offsets = shifted - data.features
    return dataclasses.replace(data, features=shifted, model_error=data.model_error + offsets)


def _residuals(
    data: TrainingData, x: np.ndarray, v: np.ndarray, own: np.ndarray, state: str
) -> np.ndarray:
    """Each measured run's features minus the mean of the simulated runs of ``state``
    (``own``) at its speed."""
    residuals = np.empty_like(x)
    for i, speed in enumerate(v):
        at = own & at_point(data.speeds, speed)
        if not at.any():
            raise ValueError(
                f"measured run {i} has speed {_show(speed)} but no simulated {state} run is at "
                f"that speed (simulated: {point_list(data.speeds)})"
            )
        residuals[i] = x[i] - data.features[at].mean(axis=0)
    return residuals


#: the discrepancy's form (the generation stage's configuration names it)
DISCREPANCY_FORM = "excess power added, deficit scaled"


def _add_discrepancy(features: np.ndarray, residuals: np.ndarray, base: np.ndarray | None):
    """log10 PSD features plus measured residuals about the simulated mean ``base``: the
    excess power ``10^(base + r) - 10^base`` where ``r > 0``, a factor ``10^r`` where not."""
    if base is None:
        return features + residuals
    excess = np.clip(10.0 ** (base + residuals) - 10.0**base, 0.0, None)
    deficit = np.minimum(residuals, 0.0)
    return np.log10(10.0**features + excess) + deficit
