"""The demo campaign: generated on first use, cached under a generator hash, truth kept apart."""

import re

import numpy as np
import pytest

from bayesdoor.door import STATES
from bayesdoor.door.datasets import cache_dir, demo_paths, load_demo_campaign, load_demo_truth
from bayesdoor.io import check_campaign

SMALL = {"calibration_runs": 1, "test_runs_per_state": 1, "show_progress": False}


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A 4-run demo campaign in a fresh cache folder (the full one is a slow test)."""
    folder = tmp_path_factory.mktemp("bayesdoor-data")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("BAYESDOOR_DATA", str(folder))
        campaign = load_demo_campaign(**SMALL)
        files = sorted(p.name for p in folder.iterdir())
        mtimes = {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}
        again = load_demo_campaign(**SMALL)
        mtimes_again = {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}
        test_only = load_demo_campaign("test", **SMALL)
        truth = load_demo_truth(**SMALL)
        paths = demo_paths(1, 1)
    return {
        "campaign": campaign,
        "again": again,
        "test": test_only,
        "truth": truth,
        "files": files,
        "unchanged": mtimes == mtimes_again,
        "paths": paths,
        "folder": folder,
    }


# 75 s (the setup of `small`: a demo campaign recorded by the virtual rig) in the default suite
# (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): with the other tests of `small`;
# in the long tier, which CI runs after the default suite
@pytest.mark.long
def test_small_demo_campaign_has_the_planned_runs(small):
    ds = small["campaign"]
    check_campaign(ds, channels=["A1X", "A1Z", "A2X", "A2Z"], sampling_rate_hz=2048.0)
    assert ds.sizes["run"] == 4
    assert list(ds.split.values) == ["calibration", "test", "test", "test"]
    assert ds.state.values[0] == "healthy"
    assert sorted(ds.state.values[1:]) == ["D1", "D2", "healthy"]
    assert set(ds.v_max.values) <= {0.3, 0.4, 0.5}
    assert np.all(ds.t_stop.values > ds.t_start.values)
    test = small["test"]
    assert list(test.split.values) == ["test"] * 3


# 0.1 s after `small` (75 s) in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine
# under load 12-16): with the other tests of `small`; in the long tier, which CI runs after the
# default suite
@pytest.mark.long
def test_demo_is_cached_atomically_under_a_generator_hash(small):
    nc, truth = small["paths"]
    assert small["files"] == sorted([nc.name, truth.name])  # no temporary files left
    assert re.fullmatch(r"demo-campaign-v\d+-[0-9a-f]{12}-c1-t1\.nc", nc.name)
    assert nc.parent == small["folder"]
    # the second call read the cache: nothing rewritten, identical data
    assert small["unchanged"]
    np.testing.assert_array_equal(
        small["again"].acceleration.values, small["campaign"].acceleration.values
    )
    # other sizes are other files; the default lives in the user's cache folder
    assert demo_paths(1, 2)[0].name != nc.name


# 0.1 s after `small` (75 s) in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine
# under load 12-16): with the other tests of `small`; in the long tier, which CI runs after the
# default suite
@pytest.mark.long
def test_truth_is_separate_and_matches_the_runs(small):
    ds, truth = small["campaign"], small["truth"]
    assert truth["parameters"]["I"] == 3
    assert len(truth["runs"]) == ds.sizes["run"]
    names = set(ds.variables) | set(ds.attrs)
    assert not names & {"K", "c_r", "mu_s", "truth", "d1_height", "d2_depth"}
    for state, run in zip(ds.state.values, truth["runs"], strict=True):
        for name, (lo, hi) in STATES[str(state)].severity.items():
            assert lo <= run[name] <= hi
        if state == "healthy":
            assert run["d1_height"] == run["d2_depth"] == 0.0


def test_bad_arguments_are_refused(tmp_path, monkeypatch):
    monkeypatch.setenv("BAYESDOOR_DATA", str(tmp_path))
    assert cache_dir() == tmp_path
    with pytest.raises(ValueError, match="split='train'"):
        load_demo_campaign("train")
    with pytest.raises(ValueError, match="test_runs_per_state >= 1"):
        load_demo_campaign(calibration_runs=1, test_runs_per_state=0)
    assert list(tmp_path.iterdir()) == []  # nothing written


@pytest.mark.slow
def test_full_demo_campaign(tmp_path, monkeypatch):
    """The 310-run campaign (a few minutes on a 2-core CPU)."""
    monkeypatch.setenv("BAYESDOOR_DATA", str(tmp_path))
    ds = load_demo_campaign(show_progress=False)
    assert ds.sizes["run"] == 310
    assert int((ds.split == "calibration").sum()) == 10
    test = ds.isel(run=np.flatnonzero(ds.split.values == "test"))
    for state in ("healthy", "D1", "D2"):
        assert int((test.state == state).sum()) == 100
    for v in (0.3, 0.4, 0.5):
        assert int((ds.v_max == v).sum()) >= 100
    assert len(load_demo_truth(show_progress=False)["runs"]) == 310
