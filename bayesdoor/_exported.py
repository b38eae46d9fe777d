"""Compiled programs that a new process calls without tracing them again.

JAX's persistent cache keeps compiled programs, but its key is the *lowered* program, so a
new process first traces and lowers every function again before the cache can serve it. For
the door's batched solve that is 2-3 s a program (a job traces it for every extension, batch
size and record length), more than the cache read it saves. :func:`persistent_jit` keeps
the traced program itself: the first process exports it (``jax.export``, StableHLO) into
the folder beside JAX's cache, and every later process reads it back and lowers a call of
it, about a tenth of a second; the compiled program then comes from JAX's own cache.

The program is keyed by everything that decides what tracing would produce: the function,
the source of the whole ``bayesdoor`` package and the versions of the libraries that trace
it, the structure and static values of the arguments, and the shapes and dtypes of their
arrays. That key covers only code it can see, so a program is kept across processes only
when every class and function among the arguments comes from ``bayesdoor`` or from those
libraries; an argument of a user's own type (a system or extension defined elsewhere, whose
source may change between processes) is traced as ``eqx.filter_jit`` traces it, every
process again. So is a call inside a transformation (its arguments are tracers) and any
call when JAX's cache has no folder or ``BAYESDOOR_EXPORTED=0`` is set.
"""

from __future__ import annotations

import collections
import dataclasses
import enum
import functools
import hashlib
import importlib.metadata
import os
import pickle
import sys
import threading
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import equinox as eqx
import jax
import numpy as np
from jax import export

F = TypeVar("F", bound=Callable[..., Any])

#: the libraries whose code runs while a program is traced, and whose types may appear among
#: the arguments of a kept program
_LIBRARIES = ("jax", "jaxlib", "equinox", "diffrax", "optimistix", "lineax", "numpy")
_TRUSTED_MODULES = ("bayesdoor", "builtins", *(n for n in _LIBRARIES if n != "jaxlib"))
#: JAX's settings that change what tracing gives (the rest change compiling only)
_TRACING_FLAGS = (
    "jax_enable_x64",
    "jax_numpy_dtype_promotion",
    "jax_numpy_rank_promotion",
    "jax_default_matmul_precision",
    "jax_default_prng_impl",
    "jax_threefry_partitionable",
    "jax_enable_checks",
    "jax_debug_nans",
    "jax_debug_infs",
)
#: the folder inside JAX's cache folder
FOLDER = "bayesdoor-exported"

_LOCK = threading.Lock()
_KEY_LOCKS: dict[str, threading.Lock] = {}
#: programs already read or exported in this process: key -> (jitted call, output rebuild)
_LOADED: dict[str, tuple[Callable[..., Any], Callable[[Any], Any]] | None] = {}
#: calls traced as usual in this process, by function and reason (what the key could not
#: describe): what a test or a user asks when a program is not kept
FALLBACKS: collections.Counter[tuple[str, str]] = collections.Counter()


class _Unkeyable(Exception):
    """An argument the key cannot describe safely: the call is traced as usual."""


@functools.cache
def code_version() -> str:
    """A digest of the ``bayesdoor`` package's source and the tracing libraries' versions."""
    digest = hashlib.sha256()
    package = Path(__file__).resolve().parent
    for path in sorted(package.rglob("*.py")):
        digest.update(str(path.relative_to(package)).encode())
        digest.update(path.read_bytes())
    for name in _LIBRARIES:
        try:
            digest.update(f"{name}={importlib.metadata.version(name)}".encode())
        except importlib.metadata.PackageNotFoundError:
            digest.update(f"{name}=?".encode())
    return digest.hexdigest()


def _folder() -> Path | None:
    if os.environ.get("BAYESDOOR_EXPORTED", "1") == "0":
        return None
    cache = getattr(jax.config, "jax_compilation_cache_dir", None)
    return Path(cache) / FOLDER if cache else None


def _trusted(module: str, own: str) -> bool:
    """Whether the key holds the source of ``module``: bayesdoor's, a tracing library's, or
    ``own``, the module of the function being keyed."""
    return module.split(".")[0] in _TRUSTED_MODULES or module == own


def _type_name(kind: type, own: str) -> str:
    module = kind.__module__ or ""
    if not _trusted(module, own) or "<locals>" in kind.__qualname__:
        raise _Unkeyable(f"{module}.{kind.__qualname__}")
    return f"{module}.{kind.__qualname__}"


def _describe(obj: Any, static: bool, out: list[str], own: str) -> None:
    """Append a description of ``obj`` to ``out`` that fixes what tracing it would give:
    types by name, static values in full, traced arrays by shape and dtype (read from the
    array, not copied to the host: this runs on every call). ``own`` is the module of the
    function being keyed (:func:`_trusted`)."""
    if isinstance(obj, jax.core.Tracer):
        raise _Unkeyable("tracer")
    if isinstance(obj, jax.Array | np.ndarray | np.generic):
        dtype, shape = np.dtype(obj.dtype).str, tuple(obj.shape)
        if static:
            digest = hashlib.sha256(np.asarray(obj).tobytes()).hexdigest()
            out.append(f"S{dtype}{shape}{digest}")
        else:
            weak = bool(getattr(obj, "weak_type", False))
            out.append(f"A{dtype}{shape}{weak}")
        return
    if obj is None or isinstance(obj, bool | int | float | complex | str | bytes):
        out.append(f"{type(obj).__name__}:{obj!r}")
        return
    if isinstance(obj, enum.Enum):
        out.append(f"E{_type_name(type(obj), own)}.{obj.name}")
        return
    if isinstance(obj, tuple | list):
        out.append(f"{_type_name(type(obj), own)}[{len(obj)}")
        for item in obj:
            _describe(item, static, out, own)
        out.append("]")
        return
    if isinstance(obj, dict):
        out.append(f"{{{len(obj)}")
        for k, v in obj.items():
            _describe(k, True, out, own)
            _describe(v, static, out, own)
        out.append("}")
        return
    if isinstance(obj, type):
        out.append(f"T{_type_name(obj, own)}")
        return
    if isinstance(obj, functools.partial):
        out.append("P(")
        _describe(obj.func, True, out, own)
        _describe(obj.args, True, out, own)
        _describe(obj.keywords, True, out, own)
        out.append(")")
        return
    if callable(obj) and hasattr(obj, "__qualname__") and not dataclasses.is_dataclass(obj):
        bound = getattr(obj, "__self__", None)
        if bound is not None and not isinstance(bound, types.ModuleType):
            out.append("M(")
            _describe(bound, True, out, own)
            out.append(")")
        if getattr(obj, "__closure__", None) or "<lambda>" in obj.__qualname__:
            raise _Unkeyable(obj.__qualname__)
        module = getattr(obj, "__module__", "") or ""
        if not _trusted(module, own) or "<locals>" in obj.__qualname__:
            raise _Unkeyable(f"{module}.{obj.__qualname__}")
        out.append(f"F{module}.{obj.__qualname__}")
        return
    if dataclasses.is_dataclass(obj):
        out.append(f"D{_type_name(type(obj), own)}(")
        module = isinstance(obj, eqx.Module)
        for field in dataclasses.fields(obj):
            if not hasattr(obj, field.name):
                continue
            out.append(field.name + "=")
            field_static = static or (module and bool(field.metadata.get("static", False)))
            _describe(getattr(obj, field.name), field_static, out, own)
        out.append(")")
        return
    raise _Unkeyable(type(obj).__qualname__)


@functools.cache
def _source(module: str) -> str:
    """A digest of the source file of ``module`` (outside ``bayesdoor``: a user's function)."""
    path = getattr(sys.modules.get(module), "__file__", None)
    if path is None or not Path(path).is_file():
        raise _Unkeyable(f"no source for {module}")
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _key(fun: Callable[..., Any], args: tuple, kwargs: dict) -> str:
    parts = [code_version(), f"{fun.__module__}.{fun.__qualname__}"]
    if fun.__module__.split(".")[0] != "bayesdoor":
        parts.append(_source(fun.__module__))
    parts.append(f"backend={jax.default_backend()}")
    parts.extend(f"{flag}={getattr(jax.config, flag, None)}" for flag in _TRACING_FLAGS)
    _describe((args, kwargs), False, parts, fun.__module__)
    return hashlib.sha256("\x1f".join(parts).encode()).hexdigest()


def _export(fun: Callable[..., Any], treedef: Any, static: Any, leaves: list) -> tuple[bytes, Any]:
    """Trace ``fun`` on the leaves' shapes: the serialized program, which returns the
    outputs' arrays in order, and a template of the outputs (their arrays as shapes).

    The template is kept, not the outputs' tree structure: a pickled structure of an
    ``eqx.Module`` does not unflatten in another process (equinox's sentinels)."""
    kept: dict[str, Any] = {}

    def flat(dynamic):
        args, kwargs = eqx.combine(jax.tree_util.tree_unflatten(treedef, dynamic), static)
        out = fun(*args, **kwargs)
        kept["template"] = jax.tree_util.tree_map(
            lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype) if eqx.is_array(x) else x, out
        )
        return [x for x in jax.tree_util.tree_leaves(out) if eqx.is_array(x)]

    exported = export.export(jax.jit(flat))(leaves)
    return bytes(exported.serialize()), kept["template"]


def _rebuild(template: Any) -> Callable[[Any], Any]:
    """The outputs from the program's arrays, the rest of ``template`` as it is."""
    slots, structure = jax.tree_util.tree_flatten(template)
    arrays = [isinstance(x, jax.ShapeDtypeStruct) for x in slots]

    def rebuild(values: list) -> Any:
        given = iter(values)
        return jax.tree_util.tree_unflatten(
            structure, [next(given) if a else x for a, x in zip(arrays, slots, strict=True)]
        )

    return rebuild


def _entry(blob: bytes, template: Any) -> tuple[Callable[..., Any], Callable[[Any], Any]]:
    """The jitted call of a serialized program and its outputs' rebuild. The exporting
    process calls the deserialized program too, so that every process lowers the same one."""
    return jax.jit(export.deserialize(bytearray(blob)).call), _rebuild(template)


def _program(
    key: str, folder: Path, fun: Callable[..., Any], treedef: Any, static: Any, leaves: list
) -> tuple[Callable[..., Any], Callable[[Any], Any]] | None:
    """The kept program of ``key`` (read back, or exported now and kept); ``None`` for a
    program that cannot be exported (one with a host callback): it is traced as usual, and a
    marker beside the programs tells later processes so."""
    if key in _LOADED:
        return _LOADED[key]
    with _LOCK:
        lock = _KEY_LOCKS.setdefault(key, threading.Lock())
    with lock:
        if key in _LOADED:
            return _LOADED[key]
        path, skip = folder / f"{key}.bin", folder / f"{key}.skip"
        entry = None
        if path.is_file():
            try:
                entry = _entry(*pickle.loads(path.read_bytes()))
            except Exception:  # a damaged or foreign file: exported anew
                entry = None
        if entry is None and not skip.is_file():
            try:
                blob, template = _export(fun, treedef, static, leaves)
            except NotImplementedError as error:  # jax.export refuses the program
                _write(folder, skip, f"{fun.__module__}.{fun.__qualname__}: {error}".encode())
            else:
                entry = _entry(blob, template)
                try:
                    payload = pickle.dumps((blob, template))
                except Exception:  # an output that cannot be pickled: kept in this process only
                    payload = None
                if payload is not None:
                    _write(folder, path, payload)
        _LOADED[key] = entry
        return entry


def _write(folder: Path, path: Path, payload: bytes) -> None:
    """``payload`` into ``path`` at once (written beside it, then renamed)."""
    folder.mkdir(parents=True, exist_ok=True)
    partial = folder / f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp"
    partial.write_bytes(payload)
    partial.replace(path)


def persistent_jit(fun: F) -> F:
    """``eqx.filter_jit(fun)`` whose traced program is kept on disk for later processes.

    Arrays (JAX and numpy) among the arguments are traced, everything else is static, as
    ``eqx.filter_jit`` has it; the result is the same program, so the same numbers. See the
    module's docstring for what is kept and when a call falls back to tracing.
    """
    jitted = eqx.filter_jit(fun)

    @functools.wraps(fun)
    def call(*args: Any, **kwargs: Any) -> Any:
        folder = _folder()
        if folder is None:
            return jitted(*args, **kwargs)
        try:
            key = _key(fun, args, kwargs)
        except _Unkeyable as reason:
            FALLBACKS[(fun.__qualname__, str(reason))] += 1
            return jitted(*args, **kwargs)
        dynamic, static = eqx.partition((args, kwargs), eqx.is_array)
        leaves, treedef = jax.tree_util.tree_flatten(dynamic)
        kept = _program(key, folder, fun, treedef, static, leaves)
        if kept is None:
            FALLBACKS[(fun.__qualname__, "not exportable")] += 1
            return jitted(*args, **kwargs)
        program, rebuild = kept
        return rebuild(program(leaves))

    call.lower = jitted.lower  # type: ignore[attr-defined]
    call.jitted = jitted  # type: ignore[attr-defined]
    return call  # type: ignore[return-value]
