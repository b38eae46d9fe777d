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

import time
from collections.abc import Mapping

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
from ._search import _optimise, _SearchSpace
from ._settings import METHODS, FitSettings, Method
from ._surrogate_posterior import _SAMPLERS, _sample_posterior, _summarise


def fit_campaign(
    system: AbstractSystem,
    campaign: xr.Dataset,
    *,
    method: Method = "cmaes",
    fixed: Mapping[str, float] | None = None,
    seed: int = 0,
    quick: bool = False,
    progress: bool = True,
    settings: FitSettings | None = None,
    spec: FeatureSpec | None = None,
    error: ModelError | None = None,
    x0: dict[str, float] | None = None,
) -> FitResult:
    """Update a system's parameters on the healthy calibration runs of a campaign.

    The steps: the campaign's calibration features; CMA-ES on J (:func:`_optimise`); for
    ``nuts`` and ``emcee``, a surrogate in a box around the optimum and the posterior sampled
    on it (:func:`_sample_posterior`, the box moved when it cuts the posterior); the gates
    and the predictive draws (:func:`_summarise`).

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
    fixed
        Parameters held at these values by name (for example ``{"I": 3}``, the door's
        contact-law index): they are neither searched nor sampled. Every integer parameter
        not in it is searched by CMA-ES as an integer variable and then held at the
        optimum's value, so the posterior is conditional on it; a continuous one in it leaves
        the search and the posterior. ``None``: nothing given.
    seed
        Seeds CMA-ES (``seed + 1``, pycma needs a positive seed), the surrogate design and
        the sampler.
    quick
        Use :meth:`FitSettings.quick` (small sizes for tests and demos).
    progress
        Show progress bars.
    settings
        The stage sizes (overrides ``quick``).
    spec
        The feature definition; ``None`` means the system's (``FeatureSpec.of(system)``).
    error
        The model-error prior; ``None`` means ``ModelError()``.
    x0
        CMA-ES start point by parameter name (a warm start, e.g. another fit's ``point``,
        with a smaller ``settings.cmaes_sigma0``); a searched parameter it lacks starts in
        the middle of its range, and one in ``fixed`` is ignored. ``None``: the middle of
        every range.

    Returns
    -------
    result
        The fit: point, J, posterior, diagnostics, CMA-ES history.

    Raises
    ------
    ValueError
        For an unknown method or ``seed``; a ``fixed`` with an unknown name, a value outside
        its bounds or a non-integral value of an integer parameter, or one that leaves nothing
        to search (or, for ``nuts``/``emcee``, nothing continuous to sample); an ``x0`` with
        an unknown name or a value outside its bounds; or a campaign without a usable healthy
        run (see :func:`calibration_runs`).
    RuntimeError
        When every CMA-ES candidate failed to simulate.

    References
    ----------
    The objective (eq. 2) and parameter bounds (Table 2) of "Real-time condition monitoring
    of mechanical systems using CNNs trained by multibody simulations", X ECCOMAS Thematic
    Conference on Smart Structures and Materials (SMART 2023), 2023; ``docs/inference.md``.
    """
    if method not in METHODS:
        raise ValueError(f"method={method!r}: use one of {', '.join(METHODS)}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed={seed!r} must be an integer >= 0")
    settings = (FitSettings.quick() if quick else FitSettings()) if settings is None else settings
    spec = FeatureSpec.of(system) if spec is None else spec
    error = ModelError() if error is None else error
    search = _SearchSpace.of(system, fixed, method)
    t0 = time.perf_counter()
    runs = calibration_runs(campaign, system.healthy)
    data, duration = campaign_data(
        system, campaign, runs, spec=spec, max_motion_s=settings.max_motion_s
    )
    timings = {"features": time.perf_counter() - t0}
    population = _Population.build(system, data, duration, spec)

    optimum = _optimise(search, population, data, settings, x0=x0, seed=seed, progress=progress)
    timings["cmaes"] = optimum.seconds
    notes = list(optimum.notes)
    described = system.describe()
    sigma_point, scatter_point = _point_error(optimum.residual, data, error)
    common = dict(
        held=optimum.held,
        cmaes=optimum.cmaes,
        feature_spec=spec,
        settings=settings,
        names=search.free,
        sigma_point=sigma_point,
        scatter_point=scatter_point,
        model_error=error,
        bounds=search.bounds(),
        runs=runs,
        duration=duration,
        seed=seed,
        system=described,
    )
    if method == "cmaes":
        return FitResult(
            method=method,
            point=optimum.point,
            j=float(optimum.cmaes.f_best),
            idata=None,
            diagnostics=None,
            surrogate_box=None,
            surrogate_rms=None,
            notes=tuple(notes),
            timings=timings,
            **common,  # type: ignore[arg-type]
        )

    key_sur, key_sample, key_pred = jax.random.split(jax.random.key(seed), 3)
    start = _ErrorStart.at_point(sigma_point, scatter_point, optimum.residual, data, error)
    posterior = _sample_posterior(
        search,
        population,
        data,
        optimum,
        start,
        _SAMPLERS[method](settings),
        error,
        settings,
        keys=(key_sur, key_sample),
        progress=progress,
    )
    timings.update(posterior.timings)
    notes.extend(posterior.notes)
    summary = _summarise(posterior, search, population, data, optimum, settings, key_pred)
    notes.extend(summary.notes)
    record_system(posterior.idata, described)
    return FitResult(
        method=method,
        point=summary.point,
        j=summary.j,
        idata=posterior.idata,
        diagnostics=summary.diagnostics,
        surrogate_box=posterior.box,
        surrogate_rms=posterior.surrogate_rms,
        notes=tuple(notes),
        timings=timings,
        **common,  # type: ignore[arg-type]
    )
