"""CMA-ES (pycma) over box bounds with a batch objective, integer variables and IPOP restarts."""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import cma
import numpy as np
from jaxtyping import Float, Int

#: a batch objective: the whole population in, one value per candidate out
BatchObjective = Callable[[Float[np.ndarray, "pop dim"]], Float[np.ndarray, " pop"]]


@dataclasses.dataclass(frozen=True)
class CMAESHistory:
    """Convergence history of a CMA-ES run, one entry per iteration (all restarts in order).

    Attributes
    ----------
    evaluations
        Objective evaluations done so far (over all restarts) at the end of the iteration.
    best_f
        Best finite objective value found so far (``inf`` while none was finite).
    median_f
        Median of the iteration's finite values (``nan`` if none was finite).
    sigma
        pycma's overall step size after the iteration, relative to the box widths (the
        per-coordinate step is ``sigma * (upper - lower)``).
    restart
        Index of the run (0 for the first, 1 for the first restart, ...).
    popsize
        Population size of the iteration.
    failed
        Number of candidates of the iteration whose objective value was not finite.
    """

    evaluations: Int[np.ndarray, " iteration"]
    best_f: Float[np.ndarray, " iteration"]
    median_f: Float[np.ndarray, " iteration"]
    sigma: Float[np.ndarray, " iteration"]
    restart: Int[np.ndarray, " iteration"]
    popsize: Int[np.ndarray, " iteration"]
    failed: Int[np.ndarray, " iteration"]


@dataclasses.dataclass(frozen=True)
class CMAESResult:
    """Outcome of :func:`minimize_cmaes`.

    Attributes
    ----------
    x_best
        Best candidate evaluated (integer variables hold integral values); ``nan`` if no
        evaluation was finite.
    f_best
        Its objective value (``inf`` if no evaluation was finite).
    evaluations
        Objective evaluations over all runs.
    restarts
        Restarts done after the first run.
    failed
        Evaluations whose value was not finite (treated as the worst of their population).
    stop
        pycma's termination reasons of each run, e.g. ``"tolfun=1e-11"``.
    history
        Per-iteration convergence record.
    seed
        The seed of the first run (restart ``r`` used ``seed + r``, as ``cma.fmin2`` does).
    """

    x_best: Float[np.ndarray, " dim"]
    f_best: float
    evaluations: int
    restarts: int
    failed: int
    stop: tuple[str, ...]
    history: CMAESHistory
    seed: int

    @property
    def success(self) -> bool:
        """Whether any evaluation returned a finite value."""
        return bool(np.isfinite(self.f_best))


@dataclasses.dataclass(frozen=True)
class CMAESOptions:
    """The settings of a :func:`minimize_cmaes` run: step, budget, restarts, population.

    Attributes
    ----------
    sigma0
        Initial step size as a fraction of each coordinate's box width.
    max_evals
        Budget of objective evaluations over all runs; the last population may overshoot it
        by less than one population.
    restarts
        Maximum number of restarts after the first run.
    popsize
        Population size of the first run (``None``: pycma's default ``4 + 3 ln(dim)``).
    incpopsize
        Population factor per restart.
    affordable_restarts
        Start a restart only while the budget left is at least the evaluations the previous
        run used: IPOP's larger population needs at least as many to converge, so a restart
        with less would be cut off by ``max_evals`` and only cost time. The skip is noted
        in the last run's ``stop`` text. ``False``: ``cma.fmin2``'s rule.
    pycma
        Further pycma options, e.g. ``{"tolfun": 1e-12, "ftarget": 1e-8}``.
    """

    sigma0: float = 0.25
    max_evals: int = 10_000
    restarts: int = 0
    popsize: int | None = None
    incpopsize: float = 2.0
    affordable_restarts: bool = False
    pycma: Mapping[str, Any] | None = None


def _check_inputs(
    x0: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    integer_variables: Sequence[int],
    seed: int,
    options: CMAESOptions,
) -> None:
    if x0.ndim != 1 or lower.shape != x0.shape or upper.shape != x0.shape:
        raise ValueError(
            f"x0, lower and upper must be 1-d of the same length; got shapes {x0.shape}, "
            f"{lower.shape}, {upper.shape}: pass one value per variable in each"
        )
    if not np.all(np.isfinite(lower) & np.isfinite(upper) & (lower < upper)):
        raise ValueError(
            f"bounds must be finite with lower < upper in every coordinate; got lower={lower}, "
            f"upper={upper}: fix the offending coordinates"
        )
    if not np.all((lower <= x0) & (x0 <= upper)):
        raise ValueError(
            f"x0={x0} lies outside the bounds [{lower}, {upper}]: start inside the box"
        )
    _check_integers(x0, lower, upper, integer_variables)
    if not options.sigma0 > 0:
        raise ValueError(
            f"sigma0={options.sigma0} must be positive (a fraction of the box width, e.g. 0.25)"
        )
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 1:
        raise ValueError(
            f"seed={seed!r} must be a positive integer (pycma draws a time-based seed for 0); "
            "pass e.g. seed=1"
        )
    if options.max_evals < 1:
        raise ValueError(f"max_evals={options.max_evals} must be at least 1")
    if options.restarts < 0:
        raise ValueError(f"restarts={options.restarts} must be >= 0 (0: a single run)")


def _check_integers(
    x0: np.ndarray, lower: np.ndarray, upper: np.ndarray, integer_variables: Sequence[int]
) -> None:
    for i in integer_variables:
        if not 0 <= i < x0.size:
            raise ValueError(
                f"integer_variables holds index {i}, outside 0..{x0.size - 1}: "
                "give 0-based coordinate indices"
            )
        if lower[i] != round(lower[i]) or upper[i] != round(upper[i]):
            raise ValueError(
                f"integer variable {i} has non-integral bounds [{lower[i]}, {upper[i]}]: "
                "use integral bounds for integer variables"
            )


def cmaes_options(
    lower: Float[np.ndarray, " dim"],
    upper: Float[np.ndarray, " dim"],
    *,
    seed: int,
    max_evals: int,
    integer_variables: Sequence[int] = (),
    popsize: int | None = None,
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The pycma options :func:`minimize_cmaes` passes to its first run.

    Exposed so that a plain pycma run with exactly the same settings can be set up (the tests
    compare the wrapper with ``cma.fmin2`` this way).

    Parameters
    ----------
    lower, upper
        Box bounds; the initial step size is scaled per coordinate by ``upper - lower``
        (pycma's ``CMA_stds``) so that ``sigma0`` is a fraction of the box width.
    seed
        pycma's seed (positive).
    max_evals
        Total budget of objective evaluations over all runs (pycma's ``maxfevals``).
    integer_variables
        Indices of variables pycma keeps integral (``integer_variables``).
    popsize
        Population size of the first run; ``None`` for pycma's default ``4 + 3 ln(dim)``.
    extra
        Further pycma options (e.g. ``{"tolfun": 1e-12}``); they override these.

    Returns
    -------
    options
        A dict for ``cma.CMAEvolutionStrategy`` with display and file logging switched off.
    """
    lower = np.asarray(lower, dtype=np.float64)
    upper = np.asarray(upper, dtype=np.float64)
    options: dict[str, Any] = {
        "bounds": [lower.tolist(), upper.tolist()],
        "CMA_stds": (upper - lower).tolist(),
        "seed": int(seed),
        "maxfevals": int(max_evals),
        "verbose": -9,
        "verb_log": 0,
        "verb_disp": 0,
    }
    if integer_variables:
        options["integer_variables"] = [int(i) for i in integer_variables]
    if popsize is not None:
        options["popsize"] = int(popsize)
    if extra:
        options.update(extra)
    return options


def _penalised(values: np.ndarray) -> np.ndarray:
    """Replace non-finite values by one worse than every finite value of the population.

    Ranks are all CMA-ES uses, so failures only need to rank last; when the whole
    population failed every candidate ties, which pycma treats as flat fitness.
    """
    ok = np.isfinite(values)
    if ok.all():
        return values
    if not ok.any():
        return np.zeros_like(values)
    worst = float(np.max(values[ok]))
    return np.where(ok, values, worst + max(1.0, abs(worst)))


def minimize_cmaes(
    objective: BatchObjective,
    x0: Sequence[float] | Float[np.ndarray, " dim"],
    *,
    lower: Sequence[float] | Float[np.ndarray, " dim"],
    upper: Sequence[float] | Float[np.ndarray, " dim"],
    seed: int,
    integer_variables: Sequence[int] = (),
    options: CMAESOptions = CMAESOptions(),
    progress: bool = True,
) -> CMAESResult:
    """Minimise a batch objective over a box with CMA-ES (pycma), with IPOP restarts.

    Each iteration asks pycma for a population, evaluates it with one call of
    ``objective`` (so a caller can run the population as one vectorised simulation) and tells
    pycma the values. Restarts follow ``cma.fmin2``'s IPOP scheme: each restart starts again
    from ``x0`` with the population multiplied by ``options.incpopsize`` and the seed
    increased by one, until ``options.restarts`` restarts are done, the budget
    ``options.max_evals`` is spent or an ``ftarget`` option is reached. With the same options
    the sequence of candidates is exactly that of ``cma.fmin2(None, x0, sigma0, options,
    parallel_objective=..., restarts=..., incpopsize=..., eval_final_mean=False)``.

    Parameters
    ----------
    objective
        ``f(X) -> values`` for a population ``X``; values that are not finite (a failed
        simulation) are treated as the worst of their population, never as an error.
    x0
        Start point, inside the bounds.
    lower, upper
        Box bounds (pycma's ``BoundTransform`` keeps every candidate inside).
    seed
        Positive integer seed; same seed and settings, same result. Each run draws from
        a generator of its own seeded with it (pycma's numbers for that seed), so runs in
        several threads at once give each one's result; with ``integer_variables`` pycma
        seeds NumPy's global generator, which threads would share.
    integer_variables
        Indices of integer variables: pycma rounds them in every candidate and keeps a
        minimal step size so they keep moving (LB+IC-CMA-ES, Marty et al. 2024).
    options
        Step size, budget, restarts, population and further pycma options.
    progress
        Show a rich progress bar over the evaluation budget.

    Returns
    -------
    result
        Best point and value, counts, termination reasons and the convergence history.

    Raises
    ------
    ValueError
        If shapes, bounds, ``x0``, integer indices, ``sigma0``, ``seed``, ``max_evals`` or
        ``restarts`` are invalid, or ``objective`` returns the wrong number of values.

    References
    ----------
    N. Hansen, "The CMA Evolution Strategy: A Tutorial", arXiv:1604.00772 (2016).
    A. Auger and N. Hansen, "A restart CMA evolution strategy with increasing population
    size", IEEE CEC 2005.
    """
    x0 = np.asarray(x0, dtype=np.float64)
    opts = _first_options(x0, lower, upper, integer_variables, seed, options)
    record = _Record(x0.shape)
    with _progress_bar(progress, options.max_evals) as advance:
        _runs(objective, x0, opts, integer_variables, seed, options, record, advance)
    return CMAESResult(
        x_best=record.x_best,
        f_best=record.f_best,
        evaluations=record.evaluations,
        restarts=len(record.stops) - 1,
        failed=record.failed,
        stop=tuple(record.stops),
        history=record.history(),
        seed=int(seed),
    )


def _first_options(
    x0: np.ndarray,
    lower: Sequence[float] | np.ndarray,
    upper: Sequence[float] | np.ndarray,
    integer_variables: Sequence[int],
    seed: int,
    options: CMAESOptions,
) -> dict[str, Any]:
    """The inputs checked, and the pycma options of the first run (:func:`cmaes_options`)."""
    lower = np.asarray(lower, dtype=np.float64)
    upper = np.asarray(upper, dtype=np.float64)
    _check_inputs(x0, lower, upper, integer_variables, seed, options)
    return cmaes_options(
        lower,
        upper,
        seed=seed,
        max_evals=options.max_evals,
        integer_variables=integer_variables,
        popsize=options.popsize,
        extra=options.pycma,
    )


class _Record:
    """What the runs of :func:`minimize_cmaes` found so far: the best point and value, the
    failed evaluations, the evaluations done, each run's stop and one history row per
    iteration."""

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.rows: list[tuple[int, float, float, float, int, int, int]] = []
        self.x_best = np.full(shape, np.nan)
        self.f_best = np.inf
        self.failed = 0
        self.stops: list[str] = []
        self.evaluations = 0

    def tell(self, es: cma.CMAEvolutionStrategy, population: list, values: np.ndarray, run: int):
        """Keep the population's best and failures, tell pycma the (penalised) values, and
        add the iteration's history row (pycma's counts and step size after the tell)."""
        finite = np.isfinite(values)
        self.failed += int(np.sum(~finite))
        if finite.any():
            i = int(np.argmin(np.where(finite, values, np.inf)))
            if values[i] < self.f_best:
                self.f_best, self.x_best = float(values[i]), np.array(population[i])
        es.tell(population, _penalised(values))
        median = float(np.median(values[finite])) if finite.any() else np.nan
        self.rows.append(
            (
                es.countevals,
                self.f_best,
                median,
                float(es.sigma),
                run,
                len(population),
                int(np.sum(~finite)),
            )
        )

    def history(self) -> CMAESHistory:
        """The rows as a :class:`CMAESHistory`."""
        columns = list(zip(*self.rows, strict=True)) if self.rows else [()] * 7
        return CMAESHistory(
            evaluations=np.asarray(columns[0], dtype=np.int64),
            best_f=np.asarray(columns[1], dtype=np.float64),
            median_f=np.asarray(columns[2], dtype=np.float64),
            sigma=np.asarray(columns[3], dtype=np.float64),
            restart=np.asarray(columns[4], dtype=np.int64),
            popsize=np.asarray(columns[5], dtype=np.int64),
            failed=np.asarray(columns[6], dtype=np.int64),
        )


def _runs(
    objective: BatchObjective,
    x0: np.ndarray,
    opts: dict[str, Any],
    integer_variables: Sequence[int],
    seed: int,
    options: CMAESOptions,
    record: _Record,
    advance: Callable[[int, float, int], None],
) -> None:
    """The first run and the IPOP restarts, into ``record`` and the progress bar: each
    restart from ``x0`` with the population times ``incpopsize`` and the next seed."""
    for run in range(options.restarts + 1):
        run_start = record.evaluations
        es = _strategy(x0, options.sigma0, opts, integer_variables)
        _run(objective, es, run, record, advance)
        if not _restarts_after(es, run, run_start, record, options):
            break
        opts = dict(es.opts)
        opts["verb_append"] = es.countevals
        opts["popsize"] = options.incpopsize * es.sp.popsize
        opts["seed"] = seed + run + 1


def _strategy(
    x0: np.ndarray, sigma0: float, opts: dict[str, Any], integer_variables: Sequence[int]
) -> cma.CMAEvolutionStrategy:
    """pycma's strategy of one run; without integer variables it draws from a generator of
    its own rather than NumPy's global one that pycma seeds: the same numbers
    (``np.random.seed(s)`` then ``np.random.randn``), but runs in several threads at once no
    longer draw from one shared stream (pycma's integer handling draws from the global one,
    so it keeps pycma's seeding)."""
    run_opts = dict(opts)
    if not integer_variables:
        run_opts["randn"] = np.random.RandomState(int(run_opts.pop("seed"))).randn
    return cma.CMAEvolutionStrategy(x0, sigma0, run_opts)


def _run(
    objective: BatchObjective,
    es: cma.CMAEvolutionStrategy,
    run: int,
    record: _Record,
    advance: Callable[[int, float, int], None],
) -> None:
    """One run to pycma's stop: ask a population, evaluate it in one call, tell, record."""
    while not es.stop():
        population = es.ask()
        values = np.asarray(objective(np.asarray(population)), dtype=np.float64)
        if values.shape != (len(population),):
            raise ValueError(
                f"objective returned shape {values.shape} for a population of "
                f"{len(population)}: return one value per row of X"
            )
        record.tell(es, population, values, run)
        advance(es.countevals - record.evaluations, record.f_best, run)
        record.evaluations = es.countevals


def _restarts_after(
    es: cma.CMAEvolutionStrategy, run: int, run_start: int, record: _Record, options: CMAESOptions
) -> bool:
    """Record the run's stop, and whether another run follows: not after an ``ftarget`` or
    the budget, nor (``affordable_restarts``) when the budget left is less than the run
    used (noted in its stop)."""
    reasons = es.stop(check=False)
    record.stops.append(", ".join(f"{k}={v}" for k, v in reasons.items()))
    evaluations = record.evaluations
    if "ftarget" in reasons or "maxfevals" in reasons or evaluations >= options.max_evals:
        return False
    used, left = evaluations - run_start, options.max_evals - evaluations
    if options.affordable_restarts and run < options.restarts and left < used:
        record.stops[-1] += (
            f"; no restart: {left} evaluations left, fewer than the {used} run {run} used"
        )
        return False
    return True


@contextlib.contextmanager
def _progress_bar(enabled: bool, total: int) -> Iterator[Callable[[int, float, int], None]]:
    """A rich progress bar over the evaluation budget, or a no-op when switched off."""
    if not enabled:
        yield lambda n, f, run: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn

    columns = ("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn())
    with Progress(*columns, TimeElapsedColumn()) as bar:
        task = bar.add_task("CMA-ES", total=total)

        def advance(n: int, f: float, run: int) -> None:
            bar.update(task, advance=n, description=f"CMA-ES run {run} best f {f:.4g}")

        yield advance


def plot_cmaes_history(result: CMAESResult, path: str | Path, *, title: str = "CMA-ES") -> Path:
    """Plot best-so-far and population-median f against evaluations (log scale) to a PNG.

    Restarts are marked by vertical lines; the step size is drawn on a second axis. When
    the best value is not positive, the excess over it is plotted instead.

    Parameters
    ----------
    result
        A :func:`minimize_cmaes` result.
    path
        The PNG file to write (its folder is created).
    title
        Figure title.

    Returns
    -------
    path
        The file written.

    Raises
    ------
    ValueError
        If the history is empty (the run did no iteration).
    """
    from matplotlib.figure import Figure  # no pyplot: the caller's backend stays as it is

    h = result.history
    if h.evaluations.size == 0:
        raise ValueError("the CMA-ES history is empty: nothing to plot (the run did no iteration)")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # log scale needs positive values: plot the excess over the best value when f can be <= 0
    shift = 0.0 if np.nanmin(h.best_f) > 0 else float(np.nanmin(h.best_f)) - 1e-12
    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    ax.plot(h.evaluations, h.best_f - shift, label="best so far")
    ax.plot(h.evaluations, h.median_f - shift, alpha=0.6, label="population median")
    for start in h.evaluations[:-1][np.diff(h.restart) > 0]:
        ax.axvline(start, color="grey", linestyle=":", linewidth=1)
    ax.set_yscale("log")
    ax.set_xlabel("objective evaluations")
    ax.set_ylabel("f" if shift == 0.0 else f"f - ({shift:.6g})")
    twin = ax.twinx()
    twin.plot(h.evaluations, h.sigma, color="tab:green", alpha=0.5, label="sigma")
    twin.set_yscale("log")
    twin.set_ylabel("sigma (fraction of box width)")
    handles = ax.get_legend_handles_labels()[0] + twin.get_legend_handles_labels()[0]
    ax.legend(handles=handles, loc="upper right")
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    return path
