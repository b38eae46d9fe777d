"""Tracing without host callbacks, so that XLA programs can enter JAX's persistent cache.

JAX does not write a program that holds a host callback to its persistent compilation cache
(its log: "Not writing persistent cache entry ... because it uses host callbacks"). Equinox's
run-time checks (``eqx.error_if``, used by diffrax for ``SaveAt(ts=...)``: increasing, inside
``[t0, t1]``) raise through such a callback under the default ``EQX_ON_ERROR=raise``, so every
process would compile the door's solves again (33 compiles of the batched solve, 175 s, in one
run of the test suite, none of them cached). Traced under :func:`errors_as_nan`, the
checks return NaN where they would have raised; a solve checks its own output for finite
values and reports a failed status, so nothing is lost. Only the traces inside the context
change: bayesdoor's own ``eqx.error_if`` checks of user input raise as before, and so does
user code elsewhere in the process.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator
from typing import Any

import equinox as eqx

_LOCK = threading.RLock()


@contextlib.contextmanager
def errors_as_nan() -> Iterator[None]:
    """Equinox's ``error_if`` traced inside this context returns NaN instead of a callback.

    The setting is read while tracing (``equinox._errors.EQX_ON_ERROR``), so the context only
    has to hold while a function is traced, once per compiled program. A lock keeps two
    threads that trace at once from restoring it under each other. Equinox traces each check
    once per argument shapes and reuses that trace: a check of the same shapes traced
    earlier outside the context (a user's own diffrax solve with save times of the same
    length) keeps its callback inside. Where equinox keeps the setting elsewhere (another
    version), nothing changes: the programs are then only not cached. Tested by
    ``tests/test_door.py``: the door's batched solve lowers without a callback.
    """
    try:
        from equinox import _errors
    except ImportError:  # pragma: no cover - equinox reorganised
        yield
        return
    if not hasattr(_errors, "EQX_ON_ERROR"):  # pragma: no cover - equinox reorganised
        yield
        return
    with _LOCK:
        before = _errors.EQX_ON_ERROR
        _errors.EQX_ON_ERROR = "nan"
        try:
            yield
        finally:
            _errors.EQX_ON_ERROR = before


def error_if(x: Any, pred: Any, msg: str) -> Any:
    """``eqx.error_if`` that follows :func:`errors_as_nan`: NaN inside the context, raise
    outside.

    Equinox keys the trace of its check by the arguments' shapes and the ``on_error`` it is
    given, not by the setting in force: a check traced outside the context (say on a measured
    record, eagerly) would be reused, callback and all, by a program traced inside it. Naming
    ``on_error="nan"`` inside the context gives those programs a check of their own.
    """
    try:
        from equinox import _errors

        inside = getattr(_errors, "EQX_ON_ERROR", None) == "nan"
    except ImportError:  # pragma: no cover - equinox reorganised
        inside = False
    return eqx.error_if(x, pred, msg, on_error="nan" if inside else "default")  # type: ignore[call-arg]
