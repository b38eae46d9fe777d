"""The posterior of a fit: sampled with NUTS or emcee on a quadratic surrogate in a box around
the CMA-ES optimum, the box moved while it cuts the posterior; its gates and predictive draws."""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Callable
from typing import Any

import arviz as az
import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr
from numpyro.infer import Predictive

from .._types import Array, Float
from ._diagnostics import SamplingDiagnostics, diagnose_sampling
from ._likelihood import CalibrationData, Discrepancy, ModelError, log_likelihood, make_model
from ._model_error import _ErrorStart
from ._parameterisation import SamplingTransform
from ._population import _full, _j, _PartialForward, _Population, _simulate
from ._samplers import EmceeSettings, NUTSSettings, _Sampler
from ._search import _Optimum, _SearchSpace
from ._settings import FitSettings
from ._surrogate import box_around, fit_surrogate

#: a surrogate box face that is not a bound must lie this many posterior sds from the mean;
#: a moved box reaches at least _BOX_NEW_SD sds each side (the quadratic is fitted where the
#: posterior lives, and a Gaussian's mass beyond 4 sd is 6e-5)
_BOX_ROOM_SD = 4.0
_BOX_NEW_SD = 6.0


def _box_room(
    draws: Float[np.ndarray, "sample param"],
    box: tuple[np.ndarray, np.ndarray],
    bounds: tuple[np.ndarray, np.ndarray],
) -> np.ndarray:
    """Per parameter: posterior sds from the mean to the nearer box face that is not a bound."""
    mean, sd = draws.mean(axis=0), np.maximum(draws.std(axis=0), 1e-300)
    lo, hi = np.asarray(box[0]), np.asarray(box[1])
    width = np.asarray(bounds[1]) - np.asarray(bounds[0])
    below = np.where(lo > np.asarray(bounds[0]) + 1e-12 * width, (mean - lo) / sd, np.inf)
    above = np.where(hi < np.asarray(bounds[1]) - 1e-12 * width, (hi - mean) / sd, np.inf)
    return np.minimum(below, above)


@dataclasses.dataclass(frozen=True)
class _Problem:
    """What the posterior of a fit starts from: the parameters searched and held, the
    simulator over the operating points, the calibration features and CMA-ES's optimum."""

    search: _SearchSpace
    population: _Population
    data: CalibrationData
    optimum: _Optimum


def _box_fractions(problem: _Problem, settings: FitSettings) -> Array:
    """The surrogate box's half-width per parameter, as a fraction of its range: the whole
    range for a parameter whose move across its bounds (the others at the optimum) changes no
    feature by ``settings.insensitive`` Welch sds, else ``settings.box_fraction``."""
    search, optimum = problem.search, problem.optimum
    d, (lower, upper) = len(search.free), search.bounds()
    ends = np.repeat(optimum.theta[None], 2 * d, axis=0)
    ends[2 * np.arange(d), np.arange(d)] = lower
    ends[2 * np.arange(d) + 1, np.arange(d)] = upper
    full = _full(search.system, ends, search.free, optimum.held)
    end_features, _ = _simulate(problem.population, full, optimum.chunk, settings.workers)
    reach = np.max(np.abs(end_features[0::2] - end_features[1::2]), axis=(1, 2, 3))
    welch_sd = float(np.sqrt(np.median(np.asarray(problem.data.welch_variance))))
    loose = reach < settings.insensitive * welch_sd
    return jnp.asarray(np.where(loose, 1.0, settings.box_fraction))


def _surrogate_in_box(
    forward: _PartialForward,
    centre: np.ndarray,
    fractions: Array,
    bounds: tuple[np.ndarray, np.ndarray],
    settings: FitSettings,
    key: jax.Array,
):
    """The box around ``centre`` and the quadratic surrogate fitted in it."""
    d = len(centre)
    n_terms = 1 + d + d * (d + 1) // 2
    box = box_around(jnp.asarray(centre), jnp.asarray(bounds[0]), jnp.asarray(bounds[1]), fractions)
    surrogate = fit_surrogate(
        forward,
        (jnp.asarray(box[0]), jnp.asarray(box[1])),
        key=key,
        n_train=settings.train_per_term * n_terms,
        n_test=settings.n_test,
        workers=settings.workers,
    )
    return box, surrogate


def _whitened_model(
    names: tuple[str, ...],
    data: CalibrationData,
    surrogate,
    box,
    centre: np.ndarray,
    start: _ErrorStart,
    error: ModelError,
) -> tuple[Any, dict[str, Any], str | None]:
    """The numpyro model on the surrogate in Laplace-whitened box coordinates, its start
    values (``centre`` moved 2 % of the box inside it), and a note when the whitening fails
    (then the coordinates are the plain logits of the box)."""
    inside = box[0] + np.clip((centre - box[0]) / (box[1] - box[0]), 0.02, 0.98) * (box[1] - box[0])
    transform = SamplingTransform.box(names, box[0].tolist(), box[1].tolist())

    def density(theta):
        discrepancy = Discrepancy(
            start.sigma,
            run_scatter=start.rho,
            correlation_length=start.length,
            common=start.tau,
            shared=error.shared,
        )
        return log_likelihood(theta, discrepancy, data, surrogate)

    note = None
    try:
        transform = transform.whitened_at(density, jnp.asarray(inside))
    except ValueError as err:
        note = f"Laplace whitening failed ({err}); sampling in plain logit coordinates"
    model = make_model(data, surrogate, transform, error)
    init = {"z": transform.to_sampling(jnp.asarray(inside)), **start.values(error)}
    return model, init, note


def _box_cuts(
    names: tuple[str, ...],
    draws: Float[np.ndarray, "sample param"],
    box,
    bounds: tuple[np.ndarray, np.ndarray],
    surrogate,
) -> list[str]:
    """The parameters whose posterior the box may cut: a face that is not a bound within
    ``_BOX_ROOM_SD`` posterior sds of the mean, or more than 5 % of the draws at it."""
    room = _box_room(draws, box, bounds)
    edge = surrogate.edge_fraction(jnp.asarray(draws), bounds)
    return [
        f"{n} ({r:.1f} sd, {100 * e:.0f} % of the draws at the face)"
        for n, r, e in zip(names, room, edge, strict=True)
        if r < _BOX_ROOM_SD or e > 0.05
    ]


@dataclasses.dataclass(frozen=True)
class _Posterior:
    """The samples of the last box, the model they came from, and the box's surrogate."""

    idata: az.InferenceData
    model: Any
    draws: Float[np.ndarray, "sample free"]
    box: tuple[np.ndarray, np.ndarray]
    surrogate_rms: float
    notes: tuple[str, ...]
    timings: dict[str, float]


def _sample_posterior(
    problem: _Problem,
    start: _ErrorStart,
    sampler: _Sampler,
    error: ModelError,
    settings: FitSettings,
    *,
    keys: tuple[jax.Array, jax.Array],
    progress: bool,
) -> _Posterior:
    """The posterior of the continuous parameters on a surrogate around the optimum.

    A surrogate is fitted in a box around the optimum, the posterior sampled on it from the
    optimum; while the box may cut the posterior (:func:`_box_cuts`) and moves are left
    (``settings.box_moves``), the box moves to the posterior mean, widens to ``_BOX_NEW_SD``
    posterior sds each side, and the posterior is sampled again from the posterior means.
    """
    key_sur, key_sample = keys
    search, data, optimum = problem.search, problem.data, problem.optimum
    names, bounds = search.free, search.bounds()
    notes: list[str] = []
    t0 = time.perf_counter()
    fractions = _box_fractions(problem, settings)
    forward = _PartialForward.build(search.system, problem.population, names, optimum.held)
    timings = {"sensitivity": time.perf_counter() - t0, "surrogate": 0.0, "sampling": 0.0}
    centre = optimum.theta
    for stage in range(settings.box_moves + 1):
        t0 = time.perf_counter()
        box, surrogate = _surrogate_in_box(
            forward, centre, fractions, bounds, settings, jax.random.fold_in(key_sur, stage)
        )
        surrogate_rms = float(np.sqrt(np.mean(np.asarray(surrogate.error_variance))))
        timings["surrogate"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        model, init, note = _whitened_model(names, data, surrogate, box, centre, start, error)
        if note is not None:
            notes.append(note)
        idata = sampler.sample(
            model, key=jax.random.fold_in(key_sample, stage), init_values=init, progress=progress
        )
        timings["sampling"] += time.perf_counter() - t0
        post = idata["posterior"]
        draws = np.stack([np.asarray(post[n].values).reshape(-1) for n in names], axis=-1)
        cut = _box_cuts(names, draws, box, bounds, surrogate)
        if not cut:
            break
        message = (
            f"surrogate box {stage + 1}: a face of the box that is not a bound lies within "
            f"{_BOX_ROOM_SD:g} posterior sds of the mean for {', '.join(cut)}: the box, not "
            "the data, may cut the posterior"
        )
        if stage < settings.box_moves:
            message += (
                "; the box was moved to the posterior mean, widened to at least "
                f"{_BOX_NEW_SD:g} sds each side, and the posterior resampled"
            )
            centre = draws.mean(axis=0)
            wider = np.minimum(1.0, _BOX_NEW_SD * draws.std(axis=0) / (bounds[1] - bounds[0]))
            fractions = jnp.maximum(fractions, jnp.asarray(wider))
            start = start.moved(post, error)
        else:
            message += "; raise box_fraction or box_moves"
            # stacklevel 4: the caller of fit_campaign
            warnings.warn(message, UserWarning, stacklevel=4)
        notes.append(message)
    return _Posterior(idata, model, draws, box, surrogate_rms, tuple(notes), timings)


@dataclasses.dataclass(frozen=True)
class _Summary:
    """The posterior's gates, its mean as the point (held parameters included), J there."""

    diagnostics: SamplingDiagnostics
    point: dict[str, float]
    j: float
    notes: tuple[str, ...]


def _summarise(
    posterior: _Posterior, problem: _Problem, settings: FitSettings, key: jax.Array
) -> _Summary:
    """The sampling gates (their warnings passed on when they fail), the posterior predictive
    draws added to ``posterior.idata``, the posterior mean and its J (exact simulator)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        diagnostics = diagnose_sampling(posterior.idata)
    notes: tuple[str, ...] = ()
    if not diagnostics.passed:
        notes = tuple(f"SAMPLING GATES FAILED: {m}" for m in diagnostics.messages)
        for w in caught:
            # stacklevel 4: the caller of fit_campaign
            warnings.warn(w.message, w.category, stacklevel=4)
    _add_predictive(posterior.idata, posterior.model, settings.predictive_draws, key)
    search, optimum = problem.search, problem.optimum
    names = search.free
    point = {n: float(np.mean(posterior.draws[:, i])) for i, n in enumerate(names)}
    point.update(optimum.held)
    x_mean = _full(search.system, np.array([point[n] for n in names]), names, optimum.held)
    j = float(_j(*_simulate(problem.population, x_mean, optimum.chunk), problem.data)[0])
    return _Summary(diagnostics, point, j, notes)


#: the sd of emcee's start ball in the sampled coordinates: a tenth of the posterior sd where
#: the Laplace whitening succeeds (:func:`_whitened_model`), which makes that sd about 1
_EMCEE_INIT_SCALE = 0.1

#: the samplers of the posterior, by the method's name
_SAMPLERS: dict[str, Callable[[FitSettings], _Sampler]] = {
    "nuts": lambda s: NUTSSettings(
        num_warmup=s.num_warmup,
        num_samples=s.num_samples,
        num_chains=s.num_chains,
        target_accept=s.target_accept,
        chain_method=s.chain_method,
    ),
    "emcee": lambda s: EmceeSettings(
        n_walkers=s.emcee_walkers,
        n_steps=s.emcee_steps,
        max_steps=s.emcee_max_steps,
        burn=s.emcee_burn,
        thin=s.emcee_thin,
        init_scale=_EMCEE_INIT_SCALE,
    ),
}


def _add_predictive(idata: az.InferenceData, model, n_draws: int, key: jax.Array) -> None:
    """A ``posterior_predictive`` group from about ``n_draws`` draws, thinned evenly."""
    post = idata["posterior"]
    n_chain, n_draw = post.sizes["chain"], post.sizes["draw"]
    step = max(1, (n_chain * n_draw) // max(n_draws, 1))
    keep = slice(None, None, step)
    samples = {
        name: jnp.asarray(np.asarray(post[name].values)[:, keep]).reshape(-1, *post[name].shape[2:])
        for name in (
            "z",
            "sigma_model",
            "sigma_operating",
            "run_scatter",
            "discrepancy_length",
            "sigma_common",
        )
        if name in post
    }
    kept = len(range(n_draw)[keep])
    replicate = Predictive(model, posterior_samples=samples, return_sites=["y"])(key, y=None)
    y = np.asarray(replicate["y"]).reshape(n_chain, kept, *replicate["y"].shape[1:])
    observed = idata["observed_data"]["y"]
    coords: dict[str, Any] = {"chain": post["chain"].values, "draw": post["draw"].values[keep]}
    coords.update({str(dim): observed[dim].values for dim in observed.dims})
    idata.add_groups(
        posterior_predictive=xr.Dataset(
            {"y": (("chain", "draw", *observed.dims), y)}, coords=coords
        )
    )
