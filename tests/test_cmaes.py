"""CMA-ES wrapper: against plain pycma (sphere, Rosenbrock), integers, failures, bounds, seeds."""

import cma
import numpy as np
import pytest

from bayesdoor.inference import CMAESOptions, CMAESResult, minimize_cmaes, plot_cmaes_history
from bayesdoor.inference._cmaes import cmaes_options


def sphere(X):
    X = np.asarray(X)
    return np.sum((X - 0.3) ** 2, axis=1)


def rosenbrock(X):
    X = np.asarray(X)
    return np.sum(100.0 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1.0 - X[:, :-1]) ** 2, axis=1)


def plain_pycma(f, x0, sigma0, lower, upper, *, seed, max_evals, restarts):
    """The same problem through cma.fmin2's own restart loop, with a parallel objective."""
    opts = cmaes_options(
        lower, upper, seed=seed, max_evals=max_evals, extra={"eval_final_mean": False}
    )
    _, es = cma.fmin2(
        None,
        x0,
        sigma0,
        opts,
        parallel_objective=lambda X: list(f(X)),
        restarts=restarts,
        incpopsize=2,
    )
    return es.all_best[0].f, es.all_best[0].x, es.countevals


@pytest.mark.parametrize(
    ("f", "dim", "optimum", "restarts"),
    [(sphere, 5, 0.3, 0), (rosenbrock, 4, 1.0, 2)],
    ids=["sphere", "rosenbrock-ipop"],
)
def test_reproduces_plain_pycma_and_reaches_the_optimum(f, dim, optimum, restarts):
    lower, upper = -5.0 * np.ones(dim), 5.0 * np.ones(dim)
    x0 = np.full(dim, -1.0)
    ours = minimize_cmaes(
        f,
        x0,
        lower=lower,
        upper=upper,
        seed=7,
        options=CMAESOptions(sigma0=0.1, max_evals=20_000, restarts=restarts),
        progress=False,
    )
    f_ref, x_ref, evals_ref = plain_pycma(
        f, x0, 0.1, lower, upper, seed=7, max_evals=20_000, restarts=restarts
    )
    # the wrapper asks and tells exactly what fmin2 does, so the run is bitwise identical
    assert ours.f_best == f_ref
    np.testing.assert_array_equal(ours.x_best, x_ref)
    assert ours.evaluations == evals_ref
    assert ours.restarts == restarts
    # pycma's default tolfun (1e-11) stops close to the optimum: f ~ |x - x*|^2 (sphere) and
    # Rosenbrock's valley makes x converge like sqrt(f); 1e-9 and 1e-3 leave two orders margin
    assert ours.f_best < 1e-9
    np.testing.assert_allclose(ours.x_best, optimum, atol=1e-3)


def test_ftarget_and_budget_stop_the_restarts():
    kw = dict(lower=-np.ones(3), upper=np.ones(3), seed=2, progress=False)
    hit = minimize_cmaes(
        sphere, np.zeros(3), options=CMAESOptions(restarts=3, pycma={"ftarget": 1e-3}), **kw
    )
    assert hit.restarts == 0 and hit.stop[0].startswith("ftarget")
    assert hit.f_best <= 1e-3
    budget = minimize_cmaes(
        sphere, np.zeros(3), options=CMAESOptions(restarts=3, max_evals=200), **kw
    )
    # pycma checks the budget between iterations: at most one population over it
    assert 200 <= budget.evaluations < 200 + budget.history.popsize[-1]
    assert "maxfevals" in budget.stop[-1]


def test_a_restart_the_budget_cannot_finish_is_skipped():
    kw = dict(lower=-5.0 * np.ones(4), upper=5.0 * np.ones(4), seed=7, progress=False)
    x0 = np.full(4, -1.0)

    def options(**changes):
        return CMAESOptions(sigma0=0.1, **changes)

    single = minimize_cmaes(rosenbrock, x0, options=options(max_evals=20_000, restarts=0), **kw)
    used = single.evaluations
    # half the first run's evaluations left after it: the restart (twice the population)
    # could not converge, so it is not started, and the first run is exactly the single run
    short = minimize_cmaes(
        rosenbrock,
        x0,
        options=options(max_evals=used + used // 2, restarts=2, affordable_restarts=True),
        **kw,
    )
    assert short.restarts == 0 and short.evaluations == used
    assert (
        f"no restart: {used // 2} evaluations left, fewer than the {used} run 0 used"
        in (short.stop[0])
    )
    np.testing.assert_array_equal(short.history.best_f, single.history.best_f)
    # without the rule the same budget starts a restart that the budget then cuts off
    cut = minimize_cmaes(
        rosenbrock, x0, options=options(max_evals=used + used // 2, restarts=2), **kw
    )
    assert cut.restarts == 1 and "maxfevals" in cut.stop[-1]
    # with room for every restart the rule changes nothing (fmin2's sequence, as above)
    roomy = minimize_cmaes(
        rosenbrock,
        x0,
        options=options(max_evals=20_000, restarts=2, affordable_restarts=True),
        **kw,
    )
    plain = minimize_cmaes(rosenbrock, x0, options=options(max_evals=20_000, restarts=2), **kw)
    assert roomy.restarts == plain.restarts == 2
    assert roomy.evaluations == plain.evaluations and roomy.f_best == plain.f_best


def test_history_is_consistent():
    r = minimize_cmaes(
        sphere, np.zeros(3), lower=-np.ones(3), upper=np.ones(3), seed=2, progress=False
    )
    h = r.history
    n = h.evaluations.size
    assert n > 10
    for a in (h.best_f, h.median_f, h.sigma, h.restart, h.popsize, h.failed):
        assert a.shape == (n,)
    assert np.all(np.diff(h.evaluations) > 0)
    assert np.all(np.diff(h.best_f) <= 0)
    assert h.evaluations[-1] == r.evaluations
    assert h.best_f[-1] == r.f_best
    assert np.all(h.median_f >= h.best_f)


def test_same_seed_same_result_other_seed_differs():
    kw = dict(
        lower=-np.ones(4), upper=np.ones(4), options=CMAESOptions(max_evals=600), progress=False
    )
    a = minimize_cmaes(rosenbrock, np.zeros(4), seed=11, **kw)
    b = minimize_cmaes(rosenbrock, np.zeros(4), seed=11, **kw)
    c = minimize_cmaes(rosenbrock, np.zeros(4), seed=12, **kw)
    np.testing.assert_array_equal(a.x_best, b.x_best)
    np.testing.assert_array_equal(a.history.best_f, b.history.best_f)
    assert a.f_best != c.f_best


def test_runs_in_threads_at_once_give_their_own_results():
    # the diagnosis refits two folds in two threads: each run must draw from its own
    # generator. The objective sleeps so that the two threads' draws interleave
    import time
    from concurrent.futures import ThreadPoolExecutor

    def slow(X):
        time.sleep(0.002)
        return rosenbrock(X)

    kw = dict(
        lower=-np.ones(4),
        upper=np.ones(4),
        options=CMAESOptions(max_evals=300, restarts=1),
        progress=False,
    )
    alone = [minimize_cmaes(slow, np.zeros(4), seed=s, **kw) for s in (3, 4)]
    with ThreadPoolExecutor(2) as pool:
        together = list(pool.map(lambda s: minimize_cmaes(slow, np.zeros(4), seed=s, **kw), (3, 4)))
    for a, b in zip(alone, together, strict=True):
        np.testing.assert_array_equal(a.x_best, b.x_best)
        np.testing.assert_array_equal(a.history.best_f, b.history.best_f)


def test_bounds_respected_when_the_optimum_lies_outside():
    seen = []

    def f(X):
        seen.append(np.array(X))
        return np.sum((np.asarray(X) - 3.0) ** 2, axis=1)

    lower, upper = np.array([-1.0, 0.0]), np.array([1.0, 2.0])
    r = minimize_cmaes(f, [0.0, 1.0], lower=lower, upper=upper, seed=5, progress=False)
    X = np.concatenate(seen)
    assert np.all(X >= lower) and np.all(X <= upper)
    # the constrained optimum is the corner nearest to (3, 3)
    np.testing.assert_allclose(r.x_best, upper, atol=1e-4)


def test_integer_variables_stay_integral_and_mixed_optimum_is_found():
    # the index selects one of nine "laws"; law 6 is best, and the continuous part is a
    # shifted sphere whose optimum depends on the law, so both must be found together
    table = np.array([5.0, 3.0, 4.0, 2.5, 1.5, 0.0, 0.8, 2.0, 3.5])
    seen = []

    def f(X):
        X = np.asarray(X)
        seen.append(X[:, 0].copy())
        law = X[:, 0].astype(int)
        return table[law - 1] + np.sum((X[:, 1:] - 0.1 * law[:, None]) ** 2, axis=1)

    r = minimize_cmaes(
        f,
        [1.0, 0.0, 0.0],
        lower=[1.0, -2.0, -2.0],
        upper=[9.0, 2.0, 2.0],
        integer_variables=[0],
        seed=3,
        options=CMAESOptions(restarts=2),
        progress=False,
    )
    laws = np.concatenate(seen)
    assert np.all(laws == np.round(laws)) and laws.min() >= 1 and laws.max() <= 9
    assert r.x_best[0] == 6.0
    np.testing.assert_allclose(r.x_best[1:], 0.6, atol=1e-4)
    assert r.f_best < 1e-8


def test_nan_region_is_survived():
    # half the box returns NaN (a failed simulation); the optimum sits next to the region
    def f(X):
        X = np.asarray(X)
        out = np.sum((X - 0.4) ** 2, axis=1)
        return np.where(X[:, 0] > 0.5, np.nan, out)

    r = minimize_cmaes(f, [0.9, 0.9], lower=[-1.0, -1.0], upper=[1.0, 1.0], seed=4, progress=False)
    assert r.failed > 0
    assert r.history.failed.sum() == r.failed
    np.testing.assert_allclose(r.x_best, 0.4, atol=1e-4)
    assert np.isfinite(r.f_best) and r.success


def test_all_failing_objective_returns_an_unsuccessful_result():
    r = minimize_cmaes(
        lambda X: np.full(len(X), np.inf),
        [0.0, 0.0],
        lower=[-1.0, -1.0],
        upper=[1.0, 1.0],
        seed=1,
        options=CMAESOptions(max_evals=100),
        progress=False,
    )
    assert not r.success
    assert r.failed == r.evaluations > 0
    assert np.all(np.isnan(r.x_best))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(x0=[2.0], lower=[-1.0], upper=[1.0]), "outside the bounds"),
        (dict(x0=[0.0], lower=[1.0], upper=[-1.0]), "lower < upper"),
        (dict(x0=[0.0, 0.0], lower=[-1.0], upper=[1.0]), "same length"),
        (dict(x0=[0.0], lower=[-1.0], upper=[1.0], seed=0), "positive integer"),
        (dict(x0=[0.0], lower=[-1.0], upper=[1.0], integer_variables=[3]), "index 3"),
        (dict(x0=[0.0], lower=[-0.5], upper=[1.0], integer_variables=[0]), "integral bounds"),
    ],
)
def test_bad_input_is_named(kwargs, match):
    kwargs = {"seed": 1, "progress": False, **kwargs}
    x0 = kwargs.pop("x0")
    with pytest.raises(ValueError, match=match):
        minimize_cmaes(sphere, x0, **kwargs)


def test_wrong_objective_shape_is_named():
    with pytest.raises(ValueError, match="one value per row"):
        minimize_cmaes(
            lambda X: np.zeros((len(X), 2)),
            [0.0],
            lower=[-1.0],
            upper=[1.0],
            seed=1,
            progress=False,
        )


def test_progress_bar_and_history_plot(tmp_path):
    r = minimize_cmaes(
        sphere,
        [0.5, 0.5],
        lower=[-1.0, -1.0],
        upper=[1.0, 1.0],
        seed=9,
        options=CMAESOptions(restarts=1),
    )
    assert isinstance(r, CMAESResult)
    out = plot_cmaes_history(r, tmp_path / "figs" / "history.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
