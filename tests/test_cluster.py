"""Where the simulation-heavy steps run: this process or a Dask cluster, with the same numbers."""

from __future__ import annotations

import dataclasses
import threading
import time

import jax
import numpy as np
import pytest
from test_bearing_catalogue import _campaign, _point_fit
from test_datagen import TOY, assert_same_data, toy_config, toy_source
from typer.testing import CliRunner

from bayesdoor import Cluster
from bayesdoor._cluster import in_process
from bayesdoor.bearing import BearingSystem
from bayesdoor.cli import app
from bayesdoor.datagen import Execution, generate
from bayesdoor.diagnose import DiagnosisSettings, diagnose_campaign


def test_a_cluster_is_an_address_or_a_number_of_workers():
    assert not Cluster().distributed
    assert Cluster(workers=3).distributed
    assert Cluster(address="tcp://10.0.0.5:8786").distributed
    assert "3 worker processes" in Cluster(workers=3).describe()
    with pytest.raises(ValueError, match="workers"):
        Cluster(workers=-1)
    with pytest.raises(ValueError, match="threads"):
        Cluster(threads=0)
    with pytest.raises(ValueError, match="scheduler's address"):
        Cluster(address="10.0.0.5")
    with pytest.raises(ValueError, match="not both"):
        Cluster(address="tcp://10.0.0.5:8786", workers=2)


def _slow_square(x: int, seconds: float) -> tuple[int, str]:
    time.sleep(seconds)
    return x * x, threading.current_thread().name


def test_the_pool_of_this_process_keeps_the_order_of_the_tasks():
    # the first task finishes last: the answers still come in the tasks' order
    tasks = [(x, 0.2 if x == 0 else 0.0) for x in range(5)]
    got = in_process(2).map(_slow_square, tasks)
    assert [value for value, _ in got] == [0, 1, 4, 9, 16]
    assert len({name for _, name in got}) == 2  # two threads shared the tasks
    alone = in_process(1).map(_slow_square, tasks)
    assert {name for _, name in alone} == {threading.current_thread().name}


def _cache_folder(_: int) -> str:
    return str(jax.config.jax_compilation_cache_dir)


# about 15 s (two worker processes start and import JAX): the cluster path in the default suite
def test_a_local_cluster_gives_the_numbers_of_this_process(tmp_path, key):
    local = generate(TOY, toy_source(), toy_config(), tmp_path / "l", key=key, progress=False)
    with Cluster(workers=2).open() as pool:
        assert pool.address is not None and pool.address.startswith("tcp://")
        # a task runs under this process's JAX settings: it reads the same compilation cache
        folders = pool.map(_cache_folder, [(i,) for i in range(4)])
        remote = generate(
            TOY,
            toy_source(),
            toy_config(),
            tmp_path / "d",
            key=key,
            progress=False,
            execution=Execution(scheduler=pool.address),
        )
    assert folders == [_cache_folder(0)] * 4
    assert_same_data(remote, local)


def test_the_command_line_takes_workers_or_a_scheduler_not_both(tmp_path):
    result = CliRunner().invoke(
        app,
        [
            "run",
            str(tmp_path / "missing.nc"),
            "--out",
            str(tmp_path / "job"),
            "--workers",
            "2",
            "--scheduler",
            "tcp://10.0.0.5:8786",
        ],
    )
    assert result.exit_code != 0
    assert "not both" in result.output
    assert not (tmp_path / "job").exists()


# about 30 s on 2 cores: a diagnosis with refits, on a 2-worker cluster and in this process
@pytest.mark.long
def test_a_diagnosis_on_a_local_cluster_is_the_diagnosis_of_this_process():
    """The bearing with a hidden supply line: the refits of every candidate and the detection
    limits run on the cluster's workers, and the verdict, the refitted values and the limits
    are those of the run in this process, to the last digit."""
    system = BearingSystem()
    campaign = _campaign("line_frequency", seed=7)
    settings = DiagnosisSettings(predictive_draws=4, max_candidates=3, refit_evals=96)

    def diagnose(pool=None):
        return diagnose_campaign(
            system,
            campaign,
            fit=_point_fit(system),
            progress=False,
            settings=settings,
            pool=pool,
        )

    here = diagnose()
    with Cluster(workers=2).open() as pool:
        there = diagnose(pool)
    assert here.verdict == there.verdict == "line_frequency"
    for mine, theirs in zip(here.causes, there.causes, strict=True):
        assert mine.name == theirs.name and mine.confirmed == theirs.confirmed
        assert mine.parameters == theirs.parameters
        assert (mine.gain is None) == (theirs.gain is None)
        if mine.gain is not None:
            assert dataclasses.asdict(mine.gain) == dataclasses.asdict(theirs.gain)
    assert here.limits and here.limits.keys() == there.limits.keys()
    for name, limit in here.limits.items():
        _assert_same(limit, there.limits[name])


def _assert_same(a, b) -> None:
    """``a`` and ``b`` equal to the last digit, through dataclasses, containers and arrays."""
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b)
        for field in dataclasses.fields(a):
            _assert_same(getattr(a, field.name), getattr(b, field.name))
    elif isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            _assert_same(a[k], b[k])
    elif isinstance(a, list | tuple):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _assert_same(x, y)
    elif isinstance(a, np.ndarray | float | np.floating):
        np.testing.assert_array_equal(a, b)
    else:
        assert a == b
