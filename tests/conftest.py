"""Test configuration: float64, strict dtype promotion, a seeded key, a project-local JAX cache."""

import os
from pathlib import Path

import jax
import pytest

_CACHE = Path(__file__).resolve().parent.parent / ".jax_cache"
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_compilation_cache_dir", os.environ.get("BAYESDOOR_JAX_CACHE", str(_CACHE)))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


@pytest.fixture
def key():
    """A fresh, seeded PRNG key for each test."""
    return jax.random.key(20231)
