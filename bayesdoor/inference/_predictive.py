"""Replicated features of runs under a fit, through the exact simulator."""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr

from .._types import Bool, Float, Int
from ..systems import AbstractSystem
from ._calibration import campaign_data
from ._likelihood import (
    CalibrationData,
    CorrelatedDiscrepancyNormal,
    DiscrepancyNormal,
    band_correlation,
)
from ._population import _full, _Population, _simulate
from ._result import FitResult


def posterior_predictive(
    result: FitResult,
    system: AbstractSystem,
    campaign: xr.Dataset,
    runs: Sequence[int] | Int[np.ndarray, " run"] | None = None,
    *,
    key: jax.Array,
    n_draws: int = 100,
) -> tuple[Float[np.ndarray, "draw run channel band"], CalibrationData, Bool[np.ndarray, " draw"]]:
    """Replicated features of some runs under a fit, through the exact simulator.

    Each replicate takes one posterior draw (``cmaes``: the point), simulates the runs'
    operating points and adds the model's discrepancy and the run's own scatter: the
    distribution the fit predicts for a new measurement of the run. With a shared discrepancy
    (``ModelError(shared=True)``), at an operating point the fit's calibration runs measured
    the discrepancy is drawn from its posterior given those runs (their features are taken
    from ``campaign`` at ``result.runs``), elsewhere from its prior ``Normal(0, sigma_c^2)``;
    the run's scatter has variance ``rho_c^2`` times its Welch variance. With the independent
    model error, the scatter is ``Normal(0, s_r^2 + sigma_c^2)``. With a discrepancy correlated
    over the bands (``ModelError(correlation=...)``) its posterior given the calibration runs
    is the correlated one; each replicate feature has the right marginal, drawn independently
    over the bands.

    Parameters
    ----------
    result
        A fit.
    system
        The system fitted.
    campaign
        The campaign that was fitted, holding the runs (for example its held-out healthy
        runs).
    runs
        Which runs; ``None``: the runs fitted.
    key
        Seeds the choice of draws and the scatter.
    n_draws
        Replicates (draws are taken evenly from the posterior).

    Returns
    -------
    replicates
        Replicated features; rows whose simulation failed are NaN.
    data
        The measured features of the runs (same windows as the fit).
    ok
        Whether each replicate's simulation succeeded.
    """
    runs = result.runs if runs is None else np.asarray(runs, dtype=int)
    data, duration = _campaign_data(result, system, campaign, runs)
    draws = result.posterior_draws()
    total = len(next(iter(draws.values())))
    pick = np.resize(np.linspace(0, total - 1, min(n_draws, total)).round().astype(int), n_draws)
    sigma = _picked(np.asarray(result.model_error_draws()), pick)
    mean, ok = _draw_features(result, system, data, duration, draws, pick)
    welch = np.asarray(data.welch_variance)[None, :, None, None]
    if result.model_error.shared:
        shift, spread, rho, cal_ok = _shared_discrepancy(
            result, system, campaign, data, draws, pick
        )
        ok = ok & cal_ok
        mean = mean + shift
        variance = spread + rho[:, None, :, None] ** 2 * welch
    else:
        variance = welch + sigma[:, None, :, None] ** 2
    noise = np.asarray(jax.random.normal(key, mean.shape, dtype=jnp.float64))
    replicates = np.where(ok[:, None, None, None], mean + np.sqrt(variance) * noise, np.nan)
    return replicates, data, ok


def _campaign_data(
    result: FitResult, system: AbstractSystem, campaign: xr.Dataset, runs: np.ndarray
) -> tuple[CalibrationData, float]:
    """:func:`campaign_data` of ``runs`` with the fit's features and motion length."""
    return campaign_data(
        system,
        campaign,
        runs,
        spec=result.feature_spec,
        max_motion_s=result.settings.max_motion_s,
    )


def _picked(values: np.ndarray, pick: np.ndarray) -> np.ndarray:
    """The draws ``pick`` of ``values``, cycling through them when there are fewer."""
    return values[pick % len(values)]


def _shared_discrepancy(
    result: FitResult,
    system: AbstractSystem,
    campaign: xr.Dataset,
    data: CalibrationData,
    draws: dict[str, np.ndarray],
    pick: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per picked draw, the shared discrepancy's mean and variance at each run of ``data`` (its
    posterior given the fit's calibration runs at a measured operating point, else the common
    part plus a fresh draw of the operating point's own), the run scatter, and whether the
    calibration runs' simulation succeeded."""
    sigma_op = _picked(result.discrepancy_draws(), pick)
    rho = _picked(np.asarray(result.run_scatter_draws()), pick)
    calibration, cal_duration = _campaign_data(result, system, campaign, result.runs)
    cal_mean, cal_ok = _draw_features(result, system, calibration, cal_duration, draws, pick)
    length = _picked(_length_draws(result), pick)
    tau = result.common_draws()
    tau = None if tau is None else _picked(tau, pick)
    delta_mean, delta_var, common_mean, common_var = _discrepancy_posterior(
        calibration, cal_mean, sigma_op, rho, length, tau
    )
    ops = np.asarray(data.operating)[np.asarray(data.run_operating)]
    measured = np.asarray(calibration.operating)
    own = sigma_op if sigma_op.ndim == 2 else np.sqrt(np.mean(sigma_op**2, axis=1))
    shape = (len(pick), *data.y.shape)
    shift = np.broadcast_to(common_mean[:, None], shape).copy()
    spread = np.broadcast_to(own[:, None, :, None] ** 2 + common_var[:, None], shape).copy()
    for i, op in enumerate(ops):
        same = np.isclose(measured, op)
        match = np.flatnonzero(same if measured.ndim == 1 else np.all(same, axis=-1))
        if match.size:
            shift[:, i] = delta_mean[:, match[0]]
            spread[:, i] = delta_var[:, match[0]]
    return shift, spread, rho, cal_ok


def _draw_features(
    result: FitResult,
    system: AbstractSystem,
    data: CalibrationData,
    duration: float,
    draws: dict[str, np.ndarray],
    pick: np.ndarray,
) -> tuple[Float[np.ndarray, "draw run channel band"], Bool[np.ndarray, " draw"]]:
    """The simulated features of the runs of ``data`` at the posterior draws ``pick``."""
    unique, inverse = np.unique(pick, return_inverse=True)
    thetas = np.stack([draws[n][unique] for n in result.names], axis=-1)
    fixed = {k: v for k, v in result.point.items() if k not in result.names}
    population = _Population.build(system, data, duration, result.feature_spec)
    features, ok = _simulate(population, _full(system, thetas, result.names, fixed))
    features, ok = features[inverse.reshape(-1)], ok[inverse.reshape(-1)]
    return features[:, np.asarray(data.run_operating)], ok


def _length_draws(result: FitResult) -> Float[np.ndarray, " draw"]:
    """The discrepancy's correlation length over the bands per draw (NaN: independent bands)."""
    post = None if result.idata is None else result.idata["posterior"]
    if post is not None and "discrepancy_length" in post:
        return np.asarray(post["discrepancy_length"].values).reshape(-1)
    return np.array([result.model_error.correlation_length() or np.nan])


def _discrepancy_posterior(
    data: CalibrationData,
    simulated: Float[np.ndarray, "draw run channel band"],
    sigma: Float[np.ndarray, "draw *op channel"],
    rho: Float[np.ndarray, "draw channel"],
    length: Float[np.ndarray, " draw"],
    tau: Float[np.ndarray, "draw channel"] | None = None,
) -> tuple[
    Float[np.ndarray, "draw op channel band"],
    Float[np.ndarray, "draw op channel band"],
    Float[np.ndarray, "draw channel band"],
    Float[np.ndarray, "draw channel band"],
]:
    """Per draw, mean and marginal variance of the discrepancy at each operating point of
    ``data`` (correlated over the bands where ``length`` is not NaN), and of its part common
    to every operating point (``tau``, its scale; zero without it): the discrepancy at an
    operating point ``data`` did not measure is that part plus a fresh one of its own."""
    shape = (data.operating.shape[0], *data.y.shape[1:])
    correlated = bool(np.all(np.isfinite(length)))
    common = tau is not None
    tau = np.zeros(rho.shape) if tau is None else tau

    def one(loc, s, r, ell, t):
        run_variance = data.welch_variance[:, None, None] * r[None, :, None] ** 2
        variance = jnp.broadcast_to(s[..., None] ** 2, shape)
        if correlated:
            scale = jnp.sqrt(variance)
            covariance = (
                scale[..., :, None] * band_correlation(shape[-1], ell) * scale[..., None, :]
            )
            features: DiscrepancyNormal = CorrelatedDiscrepancyNormal(
                jnp.asarray(loc), run_variance, covariance, data.run_operating
            )
        else:
            features = DiscrepancyNormal(
                jnp.asarray(loc),
                run_variance,
                variance,
                data.run_operating,
                common_variance=jnp.broadcast_to(t[:, None] ** 2, shape[1:]) if common else None,
            )
        return (*features.discrepancy_posterior(data.y), *features.common_posterior(data.y))

    simulated = np.where(np.isfinite(simulated), simulated, np.asarray(data.y)[None])
    out = jax.vmap(one)(
        jnp.asarray(simulated),
        jnp.asarray(sigma),
        jnp.asarray(rho),
        jnp.asarray(length),
        jnp.asarray(tau),
    )
    return tuple(np.asarray(o) for o in out)  # type: ignore[return-value]
