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
