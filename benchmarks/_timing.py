"""The timing the benchmarks share.

The benchmarks import it as ``_timing``: a benchmark run as ``python benchmarks/x.py`` has its
own folder first on ``sys.path``.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np


def median_s(fn: Callable[[], object], calls: int) -> float:
    """Median wall seconds of ``calls`` calls of ``fn()``; a JAX ``fn`` must wait for its own
    result (``jax.block_until_ready``), or the time is its dispatch and not its work."""
    times = []
    for _ in range(calls):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))
