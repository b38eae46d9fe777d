"""JAX settings shared by the command line, the scripts and the benchmarks."""

from __future__ import annotations

import os
from pathlib import Path

import jax


def configure_jax(cache_dir: str | Path | None = None) -> Path:
    """Float64 and a persistent compilation cache, so a second process skips most compiling.

    Every compiled program is kept, however quickly it compiled: a job compiles hundreds of
    small programs (eager array operations on new shapes, short jitted helpers) of tens of
    milliseconds each, which JAX's default threshold would compile again in every process.
    Reading one back takes a few milliseconds (the quick demo fit in a fresh process: 622 of
    626 programs read back, 33 s against 50-60 s when only the programs over 0.5 s were kept;
    ``benchmarks/bench_job.py`` reports the compile seconds per stage).

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
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    return folder
