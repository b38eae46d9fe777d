"""A job's progress is not interrupted by third-party announcements: importing bayesdoor and
then ArviZ prints nothing, where ArviZ alone announces its refactor (once a day per machine)."""

import importlib.util
import os
import subprocess
import sys

import pytest


def stderr_of(code: str, cache) -> str:
    env = {**os.environ, "XDG_CACHE_HOME": str(cache)}  # ArviZ's once-a-day stamp lives there
    result = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr
    return result.stderr


def test_importing_arviz_through_bayesdoor_prints_nothing(tmp_path):
    assert stderr_of("import bayesdoor.inference, arviz", tmp_path / "a") == ""


def test_arviz_alone_still_announces_so_the_filter_is_needed(tmp_path):
    import arviz

    if tuple(int(v) for v in arviz.__version__.split(".")[:2]) < (0, 22):
        pytest.skip(f"ArviZ {arviz.__version__} makes no announcement: nothing to filter")
    parts = ("arviz_base", "arviz_stats", "arviz_plots")
    if all(importlib.util.find_spec(p) is not None for p in parts):
        pytest.skip("ArviZ's new subpackages are installed: it makes no announcement")
    assert "ArviZ is undergoing a major refactor" in stderr_of("import arviz", tmp_path / "b")
