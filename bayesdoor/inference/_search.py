"""The CMA-ES search of a fit: the parameters searched and held, and the optimum of J."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .._types import Float
from ..systems import AbstractSystem
from ._calibration import j_standard_error, welch_j_standard_error
from ._cmaes import CMAESOptions, CMAESResult, minimize_cmaes
from ._likelihood import CalibrationData
from ._population import _full, _j, _Population, _simulate
from ._settings import FitSettings


def _held_parameters(system: AbstractSystem, fixed: Mapping[str, float] | None) -> dict[str, float]:
    """The values ``fixed`` holds, checked against the system's parameters (in their order).

    Raises
    ------
    ValueError
        Naming the unknown names, or the parameter whose value is not a number, lies outside
        its bounds or is not integral for an integer parameter.
    """
    if fixed is None:
        return {}
    specs = {p.name: p for p in system.parameters}
    unknown = [str(n) for n in fixed if n not in specs]
    if unknown:
        raise ValueError(
            f"fixed names {unknown}, which are not parameters of {system.name}: use some of "
            f"{list(specs)}"
        )
    held = {}
    for name, spec in specs.items():
        if name not in fixed:
            continue
        value = fixed[name]
        try:
            if isinstance(value, bool | str):
                raise TypeError
            number = float(value)
        except (TypeError, ValueError):
            raise ValueError(
                f"fixed[{name!r}]={value!r} must be a number in [{spec.lower:g}, "
                f"{spec.upper:g}] ({spec.description})"
            ) from None
        spec.check(number)
        held[name] = number
    return held


def _start_point(
    x0: dict[str, float] | None,
    search: Sequence[str],
    specs: dict[str, Any],
    lower: np.ndarray,
    upper: np.ndarray,
) -> np.ndarray:
    """CMA-ES's start: ``x0``'s values of the searched parameters, else mid-range."""
    start = 0.5 * (lower + upper)
    if x0 is None:
        return start
    unknown = sorted(set(x0) - set(specs))
    if unknown:
        raise ValueError(
            f"x0 names {unknown}, which are not parameters of the system: use some of {list(specs)}"
        )
    outside = {
        n: v for n, v in x0.items() if n in search and not specs[n].lower <= v <= specs[n].upper
    }
    if outside:
        raise ValueError(
            f"x0 holds {outside}, outside the bounds "
            f"{ {n: (specs[n].lower, specs[n].upper) for n in outside} }: clip it to them"
        )
    for i, n in enumerate(search):
        if n in x0:
            start[i] = float(x0[n])
    return start


@dataclasses.dataclass(frozen=True)
class _SearchSpace:
    """The parameters of a fit: those held by the caller, the continuous ones (searched, then
    sampled) and the integer ones (searched, then held at the optimum)."""

    system: AbstractSystem
    given: dict[str, float]
    free: tuple[str, ...]
    integer: tuple[str, ...]

    @classmethod
    def of(
        cls, system: AbstractSystem, fixed: Mapping[str, float] | None, method: str
    ) -> _SearchSpace:
        """The search of ``system`` with ``fixed`` held, for a fit by ``method``.

        Raises
        ------
        ValueError
            When ``fixed`` is invalid (:func:`_held_parameters`), holds every parameter, or
            holds every continuous one when a posterior is to be sampled.
        """
        given = _held_parameters(system, fixed)
        specs = {p.name: p for p in system.parameters}
        free = tuple(p.name for p in system.parameters if not p.integer and p.name not in given)
        integer = tuple(p.name for p in system.parameters if p.integer and p.name not in given)
        if not free + integer:
            raise ValueError(
                f"fixed holds every parameter of {system.name} ({', '.join(given)}): nothing "
                "is left to fit; leave at least one out"
            )
        if method != "cmaes" and not free:
            raise ValueError(
                f"method={method!r} samples the continuous parameters, but fixed holds all "
                f"of them ({', '.join(n for n in given if not specs[n].integer)}): leave one "
                "out, or use method='cmaes'"
            )
        return cls(system, given, free, integer)

    @property
    def names(self) -> tuple[str, ...]:
        """The search vector: the continuous parameters, then the integer ones."""
        return (*self.free, *self.integer)

    def bounds(self, names: Sequence[str] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of ``names`` (``None``: the continuous parameters)."""
        specs = {p.name: p for p in self.system.parameters}
        names = self.free if names is None else names
        return np.array([specs[n].lower for n in names]), np.array([specs[n].upper for n in names])


@dataclasses.dataclass(frozen=True)
class _Optimum:
    """CMA-ES's optimum of J: the run, the parameters held from now on (given and integer),
    the continuous optimum, every parameter's value, and the residuals there."""

    cmaes: CMAESResult
    held: dict[str, float]
    theta: Float[np.ndarray, " free"]
    point: dict[str, float]
    residual: Float[np.ndarray, "run channel band"]
    chunk: int
    notes: tuple[str, ...]
    seconds: float


def _cmaes_tolerance(data: CalibrationData, settings: FitSettings) -> tuple[float | None, str]:
    """CMA-ES's tolerance on J (``settings.cmaes_tolerance`` times J's standard error) and a
    note when the standard error comes from the Welch scatter alone."""
    if settings.cmaes_tolerance is None:
        return None, ""
    se = j_standard_error(data)
    note = ""
    if se is None:
        se = welch_j_standard_error(data)
        note = (
            f"no replicate runs: CMA-ES stops at {settings.cmaes_tolerance:g} x J's standard "
            f"error from the Welch scatter alone ({se:.2g}, a lower bound)"
        )
    return settings.cmaes_tolerance * se, note


def _optimise(
    search: _SearchSpace,
    population: _Population,
    data: CalibrationData,
    settings: FitSettings,
    *,
    x0: dict[str, float] | None,
    seed: int,
    progress: bool,
) -> _Optimum:
    """CMA-ES on J over the search, each population one vmapped batch per worker.

    Raises
    ------
    ValueError
        For an ``x0`` with an unknown name or a value outside its bounds.
    RuntimeError
        When every candidate failed to simulate.
    """
    system, names = search.system, search.names
    lower, upper = search.bounds(names)
    compiled: set[int] = set()

    def batch(x: np.ndarray) -> np.ndarray:
        """J of a population, split into one chunk per worker (the first call of a size
        compiles on one thread)."""
        chunk = -(-len(x) // settings.workers)
        workers = settings.workers if chunk in compiled else 1
        compiled.add(chunk)
        full = _full(system, x, names, search.given)
        return _j(*_simulate(population, full, chunk, workers), data)

    integers = list(range(len(search.free), len(names)))
    specs = {p.name: p for p in system.parameters}
    start = _start_point(x0, names, specs, lower, upper)
    start[integers] = np.round(start[integers])
    tolerance, note = _cmaes_tolerance(data, settings)
    t0 = time.perf_counter()
    cmaes = minimize_cmaes(
        batch,
        start,
        lower=lower,
        upper=upper,
        seed=seed + 1,
        integer_variables=integers,
        options=CMAESOptions(
            sigma0=settings.cmaes_sigma0,
            max_evals=settings.cmaes_max_evals,
            restarts=settings.cmaes_restarts,
            popsize=settings.cmaes_popsize,
            affordable_restarts=True,
            pycma=None if tolerance is None else {"tolfun": tolerance, "tolfunhist": tolerance},
        ),
        progress=progress,
    )
    seconds = time.perf_counter() - t0
    chunk = -(-int(cmaes.history.popsize[0]) // settings.workers)
    if not cmaes.success:
        raise RuntimeError(
            f"every one of {cmaes.evaluations} CMA-ES candidates failed to simulate: (a) the "
            "bounds reach where the solver breaks down, (b) the record is too long for the "
            "solver's max_steps"
        )
    optimum = dict(zip(names, (float(v) for v in cmaes.x_best), strict=True))
    found = {n: float(round(optimum.pop(n))) for n in search.integer}
    values = {**search.given, **found}
    held = {p.name: values[p.name] for p in system.parameters if p.name not in search.free}
    theta = np.array([optimum[n] for n in search.free])
    sim, _ = _simulate(population, _full(system, theta, search.free, held), chunk)
    residual = np.asarray(data.y) - sim[0][np.asarray(data.run_operating)]
    return _Optimum(
        cmaes=cmaes,
        held=held,
        theta=theta,
        point={**optimum, **held},
        residual=residual,
        chunk=chunk,
        notes=(note,) if note else (),
        seconds=seconds,
    )
