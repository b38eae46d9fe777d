"""Give the memory a finished step no longer uses back to the operating system.

A job's stages each allocate and free hundreds of megabytes of host memory from many
threads (simulated records, XLA's work buffers) and leave compiled programs in JAX's
in-memory caches. The C library keeps what was freed for later allocations and JAX keeps
every program it compiled, so a process's resident memory grows from stage to stage: the
job's peak is the sum of what the stages left, not the largest stage's own.

:func:`release_memory` drops JAX's caches, collects the garbage and hands the freed pages
back (glibc's ``malloc_trim``). Dropping the caches is the process's business, not a
library's (a notebook's own programs go with them), so a job drops them where a stage ends,
and only inside :func:`release_between_stages`, which the command line opens for
``bayesdoor run`` and ``demo`` (:func:`stage_ended`). Not inside a stage: the diagnosis's refits and
limits call again the programs its residual map traced, and dropping them between those
steps made the quick demo's diagnosis a third to a half slower in two runs of three, its
peak no lower. Nothing computed depends on it: a program a later stage calls again is traced
again and read back from the persistent compilation cache (results/performance.md gives the
job's peak memory and time).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import gc
from collections.abc import Iterator
from typing import Any

import jax


@functools.cache
def _libc() -> Any | None:
    """The C library, when it has ``malloc_trim`` (glibc); ``None`` elsewhere."""
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        libc = ctypes.CDLL(name)
    except OSError:
        return None
    return libc if hasattr(libc, "malloc_trim") else None


def release_memory() -> bool:
    """Drop JAX's in-memory caches of traced and compiled programs (:func:`jax.clear_caches`;
    a later call traces again and reads its program back from the persistent compilation
    cache), collect Python's garbage and return the C heaps' free pages to the system.

    Returns
    -------
    bool
        Whether the heaps were trimmed (``False`` where the C library has no
        ``malloc_trim``: macOS, Windows, musl; the garbage is collected everywhere).
    """
    jax.clear_caches()
    gc.collect()
    libc = _libc()
    if libc is None:
        return False
    libc.malloc_trim(0)
    return True


_BETWEEN_STAGES = {"on": False}


@contextlib.contextmanager
def release_between_stages() -> Iterator[None]:
    """While open, a job's stage that ends drops JAX's in-memory caches of compiled programs
    and hands the memory it freed back to the system (as ``bayesdoor run`` does).

    Use it around :func:`bayesdoor.pipeline.run_job` in a process that does little else
    (a script): the job's peak memory falls to about its largest stage's; the programs a
    later stage calls again are traced again and read back from the persistent compilation
    cache (:func:`bayesdoor.configure_jax`).
    """
    before = _BETWEEN_STAGES["on"]
    _BETWEEN_STAGES["on"] = True
    try:
        yield
    finally:
        _BETWEEN_STAGES["on"] = before


def stage_ended() -> None:
    """Where a job's stage has ended: :func:`release_memory` inside
    :func:`release_between_stages`; nothing outside it."""
    if _BETWEEN_STAGES["on"]:
        release_memory()
