"""JAX settings shared by the command line, the scripts and the benchmarks."""

from __future__ import annotations

import os
from pathlib import Path

import jax


def configure_jax(cache_dir: str | Path | None = None) -> Path:
    """Float64 and a persistent compilation cache, so a second process skips most compiling.

    Parameters
    ----------
    cache_dir
        The cache folder. ``None``: ``$BAYESDOOR_JAX_CACHE`` when set, else ``.jax_cache`` in
        the working directory.

    Returns
    -------
    Path
        The cache folder in use.
    """
    folder = Path(
        cache_dir
        if cache_dir is not None
        else os.environ.get("BAYESDOOR_JAX_CACHE", Path.cwd() / ".jax_cache")
    )
    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    return folder
