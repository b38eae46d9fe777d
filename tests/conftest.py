"""Test configuration: float64, strict dtype promotion, a seeded key, a project-local JAX cache."""

import gc
import os
from pathlib import Path

#: XLA's backend optimisations off (JAX's flag for smoke tests): most of a cold run is
#: compiling, and the tests' programs mostly run once. On an empty cache tests/test_door.py,
#: test_coupled_frame_mode.py and test_cli_fit.py take 145 s instead of 189 s;
#: every test passes either way. Set in the environment, before JAX is imported, so that the
#: processes the tests start (dask workers, notebook kernels) compile alike: their results
#: are compared bit for bit. ``BAYESDOOR_TEST_XLA_OPT=1`` (as ``make test-long`` sets) tests
#: the optimised programs that users run.
_OPTIMISED = os.environ.get("BAYESDOOR_TEST_XLA_OPT", "0") == "1"
if not _OPTIMISED:
    os.environ["JAX_DISABLE_MOST_OPTIMIZATIONS"] = "1"

import jax  # noqa: E402
import pytest  # noqa: E402

_CACHE = Path(__file__).resolve().parent.parent / ".jax_cache"
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_compilation_cache_dir", os.environ.get("BAYESDOOR_JAX_CACHE", str(_CACHE)))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
jax.config.update("jax_disable_most_optimizations", not _OPTIMISED)


#: ``BAYESDOOR_COMPILE_REPORT=PREFIX``: every JAX duration event (tracing, lowering, XLA
#: compiling, cache reads) summed per test and written to ``PREFIX.<worker>.json`` at the end,
#: to see where a run on an empty cache spends its time (off by default)
_REPORT = os.environ.get("BAYESDOOR_COMPILE_REPORT")
_durations: dict[str, dict[str, float]] = {}
#: by function, over the whole run: [compiles (or cache reads), seconds]
_functions: dict[str, list[float]] = {}
_current = ["(collection)"]
if _REPORT:

    def _listen(event: str, duration: float, fun_name: str = "", **_: object) -> None:
        per = _durations.setdefault(_current[0], {})
        per[event] = per.get(event, 0.0) + float(duration)
        if event.endswith("backend_compile_duration"):
            tally = _functions.setdefault(fun_name, [0, 0.0])
            tally[0] += 1
            tally[1] += float(duration)

    jax.monitoring.register_event_duration_secs_listener(_listen)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item, nextitem):
    _current[0] = item.nodeid
    try:
        return (yield)
    finally:
        _current[0] = "(between tests)"


def pytest_sessionfinish(session, exitstatus):
    if _REPORT:
        import json

        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        report = {**_durations, "(by function)": _functions}
        Path(f"{_REPORT}.{worker}.json").write_text(json.dumps(report, indent=1))


def _release_compiled_programs() -> None:
    """Drop JAX's in-memory compiled programs and traces (later calls read them back from the
    persistent cache).

    Each compiled CPU program holds about 18 memory mappings (measured: 200 small programs
    took a process from 424 to 3,995 mappings, ``jax.clear_caches()`` brought it back to 515).
    A worker of ``pytest -n 2`` runs test after test in one process; in the long tier one
    module alone took it past 20,000 mappings. At Linux's default limit of 65,530
    (``vm.max_map_count``) XLA cannot compile any more ("LLVM compilation error: Cannot
    allocate memory", then the process dies: measured by filling a process's mappings to
    the limit before a ``jax.jit`` call), which is how long-tier workers died in
    ``backend_compile_and_load`` without this release.
    """
    jax.clear_caches()
    gc.collect()


@pytest.fixture(autouse=True, scope="module")
def _release_after_module():
    """After each test module (fixtures of module scope hold compiled programs)."""
    yield
    _release_compiled_programs()


@pytest.fixture(autouse=True)
def _release_after_long_test(request):
    """After each test of the long and slow tiers, which compile the most programs (their
    run time makes the read-back from the persistent cache negligible)."""
    yield
    if request.node.get_closest_marker("long") or request.node.get_closest_marker("slow"):
        _release_compiled_programs()


@pytest.fixture
def key():
    """A fresh, seeded PRNG key for each test."""
    return jax.random.key(20231)


#: tests that take a minute or more on a 2-core machine (on a fresh machine: the notebooks
#: 02-04 219 s, the diagnosis cases 40-120 s each): started first, so
#: that ``pytest -n 2`` does not end with one worker on a long test while the other idles
#: (longest first is the classic rule for sharing jobs between machines)
_LONG = (
    "tests/test_examples.py::test_02_03_04",
    "tests/test_diagnose_job.py::test_hidden_effect_is_named",
    "tests/test_diagnose_job.py::test_nothing_hidden_gives_none",
    "tests/test_diagnose_job.py::test_wrong_extension_shows_no_gain",
    "tests/test_door.py::test_gradient_of_log_psd_loss_matches_central_differences",
    "tests/test_discrepancy_correlation.py::test_nuts_samples",
)


#: files whose tests share compiled programs, run in one process with the file named: the rig's
#: solve at the demo campaign's record length (tests/test_rig.py), the tone system's job
#: (tests/test_pipeline.py), the door-like tone system's job and made-up fit
#: (tests/test_robustness.py)
_TOGETHER = {
    "tests/test_datasets.py": "tests/test_rig.py",
    "tests/test_cli_run.py": "tests/test_pipeline.py",
    "tests/test_json_contract.py": "tests/test_robustness.py",
}


#: the default suite's costliest files (with the files ``_TOGETHER`` sends along with them),
#: costliest first: under ``pytest -n 2`` they start first, so that the run does not end with
#: one process on one of them (the seconds their tests that stay in the default suite took in
#: ``pytest -n 2 --durations=0``, 2026-11-27, the 2-core machine under load 12-16: 280, 260, 245,
#: 215, 200, 190, 160, 155, 150, 140, 120)
_COSTLY = (
    "tests/test_rig.py",
    "tests/test_likelihood.py",
    "tests/test_samplers.py",
    "tests/test_cli_diagnose.py",
    "tests/test_coupled_frame_mode.py",
    "tests/test_robustness.py",
    "tests/test_pipeline.py",
    "tests/test_diagnose.py",
    "tests/test_door.py",
    "tests/test_classify.py",
    "tests/test_extensions.py",
)


def pytest_collection_modifyitems(config, items):
    """The long tests first, in their listed order, then the costly files, in theirs; the rest
    as collected (a stable sort, the same on every worker). None of the long tests shares a
    module-scoped fixture with a test left behind, except the diagnosis cases' base fit, which
    only those use."""

    def rank(item):
        for i, prefix in enumerate(_LONG):
            if item.nodeid.startswith(prefix):
                return (0, i)
        path = item.nodeid.split("::", 1)[0]
        path = _TOGETHER.get(path, path)
        if path in _COSTLY:
            return (1, _COSTLY.index(path))
        return (2, 0)

    items.sort(key=rank)


#: the selection of ``addopts`` (pyproject.toml): the default suite
_DEFAULT_SELECTION = "not slow and not long"


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """Under ``pytest -n 2``, the default suite is shared out file by file: a file's tests run
    in one process, which computes its module-scoped fixtures and compiles its programs once
    (shared out test by test, both processes did much of that work again), and the files of
    ``_TOGETHER`` go with their partner. The files go out in the order of the sort above. The
    long and slow tiers keep xdist's test-by-test scheduling: their tests take minutes each."""
    if config.getvalue("dist") != "load" or config.option.markexpr != _DEFAULT_SELECTION:
        return None
    from xdist.scheduler import LoadScopeScheduling

    class ByFile(LoadScopeScheduling):
        def _split_scope(self, nodeid):
            path = nodeid.split("::", 1)[0]
            return _TOGETHER.get(path, path)

    config.option.loadscopereorder = False  # the order of the sort, not by number of tests
    return ByFile(config, log)
