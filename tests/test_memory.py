"""The memory a finished stage leaves is handed back (bayesdoor._memory)."""

from __future__ import annotations

import platform

import jax
import jax.numpy as jnp

import bayesdoor._memory as memory
from bayesdoor._memory import release_between_stages, release_memory
from bayesdoor.pipeline import run_stage


def test_release_drops_the_compiled_programs_and_trims_glibcs_heaps():
    add_one = jax.jit(lambda x: x + 1.0)
    add_one(jnp.ones(3))
    assert add_one._cache_size() == 1
    trimmed = release_memory()
    assert add_one._cache_size() == 0
    assert trimmed == (platform.system() == "Linux" and platform.libc_ver()[0] == "glibc")
    # traced again on the next call, same answer
    assert add_one(jnp.ones(3)).tolist() == [2.0, 2.0, 2.0]


def test_a_stage_drops_the_caches_only_between_stages(tmp_path, monkeypatch):
    """Inside ``release_between_stages`` (as ``bayesdoor run`` opens it) a computed stage drops
    JAX's caches when it ends; a reused one, or any stage outside it, leaves them."""
    calls = []
    monkeypatch.setattr(memory, "release_memory", lambda: calls.append("released"))
    run_stage(tmp_path, "outside", {"a": 1}, lambda f: (f / "x.txt").write_text("1"))
    assert calls == []
    with release_between_stages():
        run_stage(tmp_path, "inside", {"a": 1}, lambda f: (f / "x.txt").write_text("1"))
        assert calls == ["released"]
        assert run_stage(tmp_path, "inside", {"a": 1}, lambda f: None).reused
        assert calls == ["released"]
    run_stage(tmp_path, "after", {"a": 1}, lambda f: (f / "x.txt").write_text("1"))
    assert calls == ["released"]
