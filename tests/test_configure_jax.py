"""`bayesdoor.configure_jax`: the cache folder it picks, and float64."""

from pathlib import Path

import jax
import pytest

from bayesdoor import configure_jax


@pytest.fixture
def restore_cache_dir():
    before = jax.config.jax_compilation_cache_dir
    yield
    jax.config.update("jax_compilation_cache_dir", before)


def test_cache_folder_argument_then_environment_then_working_directory(
    tmp_path, monkeypatch, restore_cache_dir
):
    assert configure_jax(tmp_path / "a") == tmp_path / "a"
    assert jax.config.jax_compilation_cache_dir == str(tmp_path / "a")
    assert jax.config.jax_enable_x64
    monkeypatch.setenv("BAYESDOOR_JAX_CACHE", str(tmp_path / "b"))
    assert configure_jax() == tmp_path / "b"
    monkeypatch.delenv("BAYESDOOR_JAX_CACHE")
    monkeypatch.chdir(tmp_path)
    assert configure_jax() == Path(tmp_path) / ".jax_cache"
    assert jax.config.jax_compilation_cache_dir == str(tmp_path / ".jax_cache")


_SMALL_PROGRAM = """
import sys
import jax
import jax.numpy as jnp
from bayesdoor import configure_jax

configure_jax(sys.argv[1])
hits = []
jax.monitoring.register_event_listener(
    lambda event, **_: hits.append(event) if event.endswith("cache_hits") else None
)
jax.jit(lambda x: jnp.sin(x) * 3.0 + 1.0)(jnp.arange(7.0)).block_until_ready()
print(len(hits))
"""


def test_a_program_that_compiles_in_milliseconds_is_kept_for_the_next_process(tmp_path):
    import subprocess
    import sys

    def run() -> int:
        done = subprocess.run(
            [sys.executable, "-c", _SMALL_PROGRAM, str(tmp_path / "cache")],
            capture_output=True,
            text=True,
            check=True,
        )
        return int(done.stdout.split()[-1])

    assert run() == 0
    assert any((tmp_path / "cache").iterdir())
    assert run() >= 1
