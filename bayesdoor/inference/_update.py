"""Model updating of a system on a measurement campaign: CMA-ES on J, then a posterior.

The pipeline of :func:`fit_campaign`:

1. the calibration runs of the campaign (``split == "calibration"`` when present, else every
   ``healthy`` run) become feature vectors (:class:`CalibrationData`), with each run's motion
   window clipped to the length of the simulated one, so both sides average the same stretch;
2. CMA-ES minimises the paper's objective J over the bounds of the parameters not held fixed,
   every integer parameter (a contact-law index) as an integer variable, each population
   simulated as one vmapped batch over all operating points; the integer parameters are then
   held at the optimum's values;
3. for ``nuts`` and ``emcee``, over the continuous parameters not held: a quadratic surrogate
   of the features is fitted in a box around the optimum (parameters the data cannot move
   span their whole range), its held-out error enters the likelihood, the sampling
   coordinates are whitened by a Laplace approximation, and the sampler starts at the
   optimum; the convergence gates are checked and a failure is reported loudly.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from typing import Any

import jax
import numpy as np
import xarray as xr

from ..systems import AbstractSystem
from ._calibration import calibration_runs, campaign_data
from ._features import FeatureSpec
from ._likelihood import ModelError
from ._model_error import _ErrorStart, _point_error
from ._population import _Population
from ._posterior import record_system
from ._result import FitResult
from ._samplers import _Sampler
from ._search import _optimise, _SearchSpace
from ._settings import METHODS, FitSettings, Method
from ._surrogate_posterior import _SAMPLERS, _Problem, _sample_posterior, _summarise


@dataclasses.dataclass(frozen=True)
class FitProblem:
    """What :func:`fit_campaign` fits beyond the system and the campaign: the parameters held,
    the search's start, the features and the model-error prior.

    Attributes
    ----------
    fixed
        Parameters held at these values by name (for example ``{"I": 3}``, the door's
        contact-law index): they are neither searched nor sampled. Every integer parameter
        not in it is searched by CMA-ES as an integer variable and then held at the
        optimum's value, so the posterior is conditional on it; a continuous one in it leaves
        the search and the posterior. ``None``: nothing given.
    x0
        CMA-ES start point by parameter name (a warm start, e.g. another fit's ``point``,
        with a smaller ``settings.cmaes_sigma0``); a searched parameter it lacks starts in
        the middle of its range, and one in ``fixed`` is ignored. ``None``: the middle of
        every range.
    spec
        The feature definition; ``None`` means the system's (``FeatureSpec.of(system)``).
    error
        The model-error prior; ``None`` means ``ModelError()``.
    """

    fixed: Mapping[str, float] | None = None
    x0: Mapping[str, float] | None = None
    spec: FeatureSpec | None = None
    error: ModelError | None = None


def fit_campaign(
    system: AbstractSystem,
    campaign: xr.Dataset,
    *,
    method: Method = "cmaes",
    problem: FitProblem | None = None,
    seed: int = 0,
    quick: bool = False,
    progress: bool = True,
    settings: FitSettings | None = None,
) -> FitResult:
    """Update a system's parameters on the healthy calibration runs of a campaign.

    The steps: the campaign's calibration features and CMA-ES on J (:func:`_search`); for
    ``nuts`` and ``emcee``, a surrogate in a box around the optimum and the posterior sampled
    on it, the gates and the predictive draws (:func:`_sampled`).

    Parameters
    ----------
    system
        The simulated system.
    campaign
        The measurements (docs/data.md): runs with ``split == "calibration"`` when
        present, else every run of the system's healthy state, are fitted.
    method
        ``cmaes`` (the optimum of J only), ``nuts`` or ``emcee`` (a posterior on a surrogate
        of the simulator, started at the CMA-ES optimum).
    problem
        The parameters held, the CMA-ES start, the features and the model-error prior
        (:class:`FitProblem`); ``None``: ``FitProblem()``.
    seed
        Seeds CMA-ES (``seed + 1``, pycma needs a positive seed), the surrogate design and
        the sampler.
    quick
        Use :meth:`FitSettings.quick` (small sizes for tests and demos).
    progress
        Show progress bars.
    settings
        The stage sizes (overrides ``quick``).

    Returns
    -------
    result
        The fit: point, J, posterior, diagnostics, CMA-ES history.

    Raises
    ------
    ValueError
        For an unknown method or ``seed``; a ``problem.fixed`` with an unknown name, a value
        outside its bounds or a non-integral value of an integer parameter, or one that
        leaves nothing to search (or, for ``nuts``/``emcee``, nothing continuous to sample);
        an ``x0`` with an unknown name or a value outside its bounds; or a campaign without a
        usable healthy run (see :func:`calibration_runs`).
    RuntimeError
        When every CMA-ES candidate failed to simulate.

    References
    ----------
    The objective (eq. 2) and parameter bounds (Table 2) of "Real-time condition monitoring
    of mechanical systems using CNNs trained by multibody simulations", X ECCOMAS Thematic
    Conference on Smart Structures and Materials (SMART 2023), 2023; ``docs/inference.md``.
    """
    _check_method_and_seed(method, seed)
    settings = (FitSettings.quick() if quick else FitSettings()) if settings is None else settings
    resolved = _Resolved.of(system, FitProblem() if problem is None else problem)
    search = _SearchSpace.of(system, resolved.fixed, method)
    found = _search(system, campaign, resolved, search, settings, seed, progress)
    if method == "cmaes":
        return _optimum_result(found)
    return _sampled(found, resolved.error, _SAMPLERS[method](settings), method, seed, progress)


def _check_method_and_seed(method: str, seed: int) -> None:
    """Raise for a method that is not one of :data:`METHODS` or a seed that is not an integer
    of at least 0."""
    if method not in METHODS:
        raise ValueError(f"method={method!r}: use one of {', '.join(METHODS)}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed={seed!r} must be an integer >= 0")


@dataclasses.dataclass(frozen=True)
class _Resolved:
    """A :class:`FitProblem` with the system's features and the default model error filled
    in."""

    fixed: Mapping[str, float] | None
    x0: dict[str, float] | None
    spec: FeatureSpec
    error: ModelError

    @classmethod
    def of(cls, system: AbstractSystem, problem: FitProblem) -> _Resolved:
        """``problem`` with ``FeatureSpec.of(system)`` and ``ModelError()`` for ``None``."""
        return cls(
            fixed=problem.fixed,
            x0=None if problem.x0 is None else dict(problem.x0),
            spec=FeatureSpec.of(system) if problem.spec is None else problem.spec,
            error=ModelError() if problem.error is None else problem.error,
        )


@dataclasses.dataclass(frozen=True)
class _Found:
    """The search's outcome: the problem at the optimum, the fields every :class:`FitResult`
    of it shares, and the seconds of the features and of CMA-ES."""

    at: _Problem
    common: dict[str, Any]
    timings: dict[str, float]


def _search(
    system: AbstractSystem,
    campaign: xr.Dataset,
    problem: _Resolved,
    search: _SearchSpace,
    settings: FitSettings,
    seed: int,
    progress: bool,
) -> _Found:
    """The calibration runs' features, CMA-ES on J from ``problem.x0`` (:func:`_optimise`),
    and the model error's moment estimates at the optimum."""
    t0 = time.perf_counter()
    runs = calibration_runs(campaign, system.healthy)
    data, duration = campaign_data(
        system, campaign, runs, spec=problem.spec, max_motion_s=settings.max_motion_s
    )
    timings = {"features": time.perf_counter() - t0}
    population = _Population.build(system, data, duration, problem.spec)
    optimum = _optimise(
        search, population, data, settings, x0=problem.x0, seed=seed, progress=progress
    )
    timings["cmaes"] = optimum.seconds
    sigma_point, scatter_point = _point_error(optimum.residual, data, problem.error)
    common = dict(
        held=optimum.held,
        cmaes=optimum.cmaes,
        feature_spec=problem.spec,
        settings=settings,
        names=search.free,
        sigma_point=sigma_point,
        scatter_point=scatter_point,
        model_error=problem.error,
        bounds=search.bounds(),
        runs=runs,
        duration=duration,
        seed=seed,
        system=system.describe(),
    )
    return _Found(_Problem(search, population, data, optimum), common, timings)


def _optimum_result(found: _Found) -> FitResult:
    """The CMA-ES optimum alone as the fit's result."""
    optimum = found.at.optimum
    return FitResult(
        method="cmaes",
        point=optimum.point,
        j=float(optimum.cmaes.f_best),
        idata=None,
        diagnostics=None,
        surrogate_box=None,
        surrogate_rms=None,
        notes=tuple(optimum.notes),
        timings=found.timings,
        **found.common,
    )


def _sampled(
    found: _Found, error: ModelError, sampler: _Sampler, method: str, seed: int, progress: bool
) -> FitResult:
    """The posterior on a surrogate around the optimum (:func:`_sample_posterior`), its
    gates, predictive draws and mean (:func:`_summarise`), as the fit's result."""
    at, common = found.at, found.common
    key_sur, key_sample, key_pred = jax.random.split(jax.random.key(seed), 3)
    start = _ErrorStart.at_point(
        common["sigma_point"], common["scatter_point"], at.optimum.residual, at.data, error
    )
    settings = common["settings"]
    posterior = _sample_posterior(
        at, start, sampler, error, settings, keys=(key_sur, key_sample), progress=progress
    )
    summary = _summarise(posterior, at, settings, key_pred)
    record_system(posterior.idata, common["system"])
    return FitResult(
        method=method,
        point=summary.point,
        j=summary.j,
        idata=posterior.idata,
        diagnostics=summary.diagnostics,
        surrogate_box=posterior.box,
        surrogate_rms=posterior.surrogate_rms,
        notes=(*at.optimum.notes, *posterior.notes, *summary.notes),
        timings={**found.timings, **posterior.timings},
        **common,
    )
