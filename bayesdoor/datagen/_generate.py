"""Chunked, resumable, reproducible generation of simulated training data, local or on Dask.

Output folder layout::

    OUT/manifest.json          provenance and the configuration hash (written first)
    OUT/chunks/chunk-00000.npz one file per chunk, written atomically
    OUT/summary.json           counts, dropped runs and timing (written last)
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import hashlib
import json
import os
import time
import warnings
from collections.abc import Callable, Generator, Iterator, Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

import jax
import numpy as np

from .._cluster import Cluster
from .._types import Array
from ..io import atomic_write
from ..systems import HEALTHY, AbstractSystem
from ._chunks import Job, run_chunk
from ._config import GenerationConfig
from ._sources import AbstractParameterSource, ModelErrorDraws, _digest

#: format tag of the manifest and the chunk files
FORMAT = "bayesdoor.datagen/1"
_VERSIONED = ("bayesdoor", "jax", "jaxlib", "diffrax", "equinox", "numpy")


@dataclasses.dataclass(frozen=True)
class TrainingData:
    """Simulated runs with their features, labels, split and the draws that made them.

    Runs are ordered by ``run_ids`` (state by state); runs dropped after failed solves are
    missing and listed in ``dropped_run_ids``. ``features`` already include the model-error
    offsets (kept separately in ``model_error``; zero without model-error draws). Severities
    of a run are NaN for the severity parameters of other states. ``speeds`` holds each run's
    operating point: ``(run,)`` for a system with one operating condition, ``(run,
    condition)`` for one with several.
    """

    features: np.ndarray
    labels: np.ndarray
    states: tuple[str, ...]
    validation: np.ndarray
    speeds: np.ndarray
    t_start: np.ndarray
    t_stop: np.ndarray
    run_ids: np.ndarray
    redraws: np.ndarray
    model_error: np.ndarray
    parameters: Mapping[str, np.ndarray]
    severities: Mapping[str, np.ndarray]
    channels: tuple[str, ...]
    frequencies: np.ndarray
    dropped_run_ids: np.ndarray
    manifest: Mapping[str, Any]

    @property
    def healthy(self) -> str:
        """The simulated system's healthy state (:attr:`AbstractSystem.healthy
        <bayesdoor.systems.AbstractSystem.healthy>`), as the manifest describes the system;
        :data:`~bayesdoor.systems.HEALTHY` where it names none."""
        return str(self.manifest.get("system", {}).get("healthy_state", HEALTHY))

    def subset(self, which: str) -> TrainingData:
        """The ``"train"`` or ``"validation"`` runs."""
        if which not in ("train", "validation"):
            raise ValueError(f"which must be 'train' or 'validation', got {which!r}")
        keep = self.validation if which == "validation" else ~self.validation
        per_run = {f.name for f in dataclasses.fields(self)} - {
            "states",
            "channels",
            "frequencies",
            "dropped_run_ids",
            "manifest",
            "parameters",
            "severities",
        }
        return dataclasses.replace(
            self,
            **{name: getattr(self, name)[keep] for name in per_run},
            parameters={k: v[keep] for k, v in self.parameters.items()},
            severities={k: v[keep] for k, v in self.severities.items()},
        )

    def counts(self) -> dict[str, dict[str, int]]:
        """Runs per state in the train and validation splits."""
        return {
            state: {
                "train": int(np.sum((self.labels == i) & ~self.validation)),
                "validation": int(np.sum((self.labels == i) & self.validation)),
            }
            for i, state in enumerate(self.states)
        }


def describe_system(system: AbstractSystem) -> dict[str, Any]:
    """A JSON-able description of a system for provenance (its settings and array leaves).

    It names the system's healthy state (``healthy_state``) only where that is not
    :data:`~bayesdoor.systems.HEALTHY`, which is what a description without it means
    (:attr:`TrainingData.healthy`): a system with the default is described, and its jobs and
    generations hashed, alike with or without the key.
    """
    leaves = jax.tree_util.tree_leaves(system)
    healthy = {} if system.healthy == HEALTHY else {"healthy_state": system.healthy}
    return {
        "name": system.name,
        **healthy,
        "repr": repr(system),
        "leaves_sha256": _digest({str(i): np.asarray(v) for i, v in enumerate(leaves)}),
        "channels": list(system.channels),
        "sampling_rate_hz": float(system.sampling_rate_hz),
        "parameters": [dataclasses.asdict(p) for p in system.parameters],
        "states": {
            k: {n: list(r) for n, r in s.severity.items()} for k, s in system.states.items()
        },
    }


def _versions() -> dict[str, str]:
    out = {}
    for name in _VERSIONED:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def _manifest(job: Job) -> dict[str, Any]:
    described = {
        "format": FORMAT,
        "config": job.config.to_dict(),
        "states": list(job.states),
        "n_chunks": job.n_chunks,
        "duration": job.duration,
        "system": describe_system(job.system),
        "source": job.source.describe(),
        "model_error": None if job.model_error is None else job.model_error.describe(),
        "key": {
            "impl": str(jax.random.key_impl(job.key)),
            "data": np.asarray(jax.random.key_data(job.key)).tolist(),
        },
        "x64": job.x64,
        "versions": _versions(),
    }
    text = json.dumps(described, sort_keys=True, default=str)
    return {**described, "config_hash": hashlib.sha256(text.encode()).hexdigest()}


def _differences(old: Any, new: Any, path: str = "") -> list[str]:
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for k in sorted(set(old) | set(new)):
            out += _differences(old.get(k), new.get(k), f"{path}.{k}" if path else k)
        return out
    return [] if old == new else [f"{path}: {old!r} -> {new!r}"]


def _chunk_path(out: Path, index: int) -> Path:
    return out / "chunks" / f"chunk-{index:05d}.npz"


def _save_chunk(out: Path, index: int, arrays: Mapping[str, np.ndarray], config_hash: str):
    def write(tmp: Path) -> None:
        payload: dict[str, Any] = {
            "index": np.asarray(index),
            "config_hash": np.asarray(config_hash),
            **arrays,
        }
        with open(tmp, "wb") as f:
            np.savez(f, **payload)

    atomic_write(_chunk_path(out, index), write, overwrite=False)


def _load_chunk(out: Path, index: int, config_hash: str) -> dict[str, np.ndarray]:
    path = _chunk_path(out, index)
    with np.load(path, allow_pickle=False) as f:
        arrays = {k: f[k] for k in f.files}
    if str(arrays.pop("config_hash")) != config_hash or int(arrays.pop("index")) != index:
        raise ValueError(
            f"{path} belongs to another generation (configuration hash or chunk index differs "
            f"from the manifest's {config_hash[:12]}): remove it or use a new output folder"
        )
    return arrays


def _open_folder(out: Path, manifest: dict[str, Any]) -> None:
    """Write the manifest of a new folder, or check that an existing one matches it."""
    path = out / "manifest.json"
    if path.exists():
        old = json.loads(path.read_text())
        if old.get("config_hash") != manifest["config_hash"]:
            changed = _differences(
                {k: v for k, v in old.items() if k not in ("config_hash", "created")},
                {k: v for k, v in manifest.items() if k != "config_hash"},
            )
            raise ValueError(
                f"{out} holds training data of a different configuration (hash "
                f"{str(old.get('config_hash'))[:12]} vs {manifest['config_hash'][:12]}); "
                f"refusing to mix chunks. Differences: {'; '.join(changed[:8]) or 'unknown'}. "
                "Use a new output folder, delete this one, or restore the original settings "
                "to resume"
            )
        return
    if out.exists() and any(out.iterdir()):
        raise ValueError(
            f"{out} is not empty and has no manifest.json: it is not a training-data folder; "
            "pass an empty or new folder"
        )
    created = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    text = json.dumps({**manifest, "created": created}, indent=1)
    atomic_write(path, lambda tmp: tmp.write_text(text), overwrite=False)


@contextlib.contextmanager
def _progress(enabled: bool, total: int, done: int) -> Iterator[Callable[[], None]]:
    if not enabled:
        yield lambda: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn

    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
    ) as bar:
        task = bar.add_task("training-data chunks", total=total, completed=done)
        yield lambda: bar.advance(task)


_Chunks = Generator[tuple[int, dict[str, np.ndarray]], None, None]


def _cores() -> int:
    """CPU cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _map_local(job: Job, pending: list[int], threads: int) -> _Chunks:
    """Chunks computed in this process, ``threads`` at a time, yielded as they finish.

    XLA releases the GIL while it runs a chunk's solve, so two threads keep two cores busy
    (on the 2-core development machine: 1.4-2.2 times less wall time and 30 % less CPU time
    than one chunk after the other). Closing the generator (an exception in the caller, such
    as an interrupt) cancels the chunks not started and waits for the running ones, whose
    results are dropped.
    """
    if threads == 1:
        for index in pending:
            yield run_chunk(job, index)
        return
    with concurrent.futures.ThreadPoolExecutor(threads) as pool:
        futures = [pool.submit(run_chunk, job, index) for index in pending]
        try:
            for future in concurrent.futures.as_completed(futures):
                yield future.result()
        finally:
            for future in futures:
                future.cancel()


def _map_dask(job: Job, pending: list[int], scheduler: str, n_workers: int) -> _Chunks:
    from distributed import as_completed

    cluster = Cluster(workers=n_workers) if scheduler == "local" else Cluster(address=scheduler)
    with cluster.open() as pool:
        client = pool.client
        shared = client.scatter(job, broadcast=True, hash=False)
        futures = [client.submit(run_chunk, shared, i, pure=False) for i in pending]
        for future in as_completed(futures):
            yield future.result()


@dataclasses.dataclass(frozen=True)
class Execution:
    """Where and how :func:`generate` computes its chunks (the data are the same for all).

    Parameters
    ----------
    scheduler
        ``None``: compute chunks in this process; ``"local"``: start a
        ``distributed.LocalCluster`` of ``n_workers`` processes with one thread each;
        ``"tcp://host:port"``: use that Dask scheduler. Every path gives identical data.
    n_workers
        Worker processes of the local cluster.
    threads
        With ``scheduler=None``: chunks computed at once in this process, each in its own
        thread (the data are the same for any number). ``None`` means 2, or 1 on a machine
        with one core; 2 was measured on a 2-core machine, more is untested.
    on_chunk
        Called with the chunk index after each chunk has been saved (in the order the chunks
        finish, which with several threads or workers is not the index order).
    """

    scheduler: str | None = None
    n_workers: int = 2
    threads: int | None = None
    on_chunk: Callable[[int], None] | None = None


def _check_job(
    system: AbstractSystem,
    source: AbstractParameterSource,
    config: GenerationConfig,
    execution: Execution,
) -> int:
    """Refuse a source, states or execution settings that do not fit; the number of threads."""
    names = set(system.parameter_names())
    if set(source.names) != names:
        raise ValueError(
            f"the parameter source gives {sorted(source.names)} but {system.name} needs exactly "
            f"{sorted(names)}: missing {sorted(names - set(source.names))}, unknown "
            f"{sorted(set(source.names) - names)}"
        )
    for state in config.states or ():
        system.check_state(state)
    threads = min(2, _cores()) if execution.threads is None else execution.threads
    if threads < 1:
        raise ValueError(f"threads must be at least 1 (or None for the default), got {threads}")
    if execution.scheduler == "local" and execution.n_workers < 1:
        raise ValueError(
            f"n_workers must be at least 1 for a local cluster, got {execution.n_workers}"
        )
    return threads


def _pending_chunks(job: Job, out: Path) -> tuple[str, list[int]]:
    """Open or check the folder's manifest and the chunks already there; the configuration
    hash and the chunks still to compute."""
    manifest = _manifest(job)
    _open_folder(out, manifest)
    config_hash = manifest["config_hash"]
    for index in range(job.n_chunks):
        if _chunk_path(out, index).exists():
            _load_chunk(out, index, config_hash)
    return config_hash, [i for i in range(job.n_chunks) if not _chunk_path(out, i).exists()]


def _compute_chunks(
    job: Job,
    out: Path,
    config_hash: str,
    pending: list[int],
    execution: Execution,
    threads: int,
    progress: bool,
) -> list[float]:
    """Compute and save the pending chunks; the times (``perf_counter``) of the start and
    of each saved chunk."""
    arrivals = [time.perf_counter()]
    with _progress(progress, job.n_chunks, job.n_chunks - len(pending)) as advance:
        # a finished folder needs no cluster
        chunks = (
            _map_local(job, pending, threads)
            if execution.scheduler is None or not pending
            else _map_dask(job, pending, execution.scheduler, execution.n_workers)
        )
        with contextlib.closing(chunks):
            for index, arrays in chunks:
                _save_chunk(out, index, arrays, config_hash)
                arrivals.append(time.perf_counter())
                advance()
                if execution.on_chunk is not None:
                    execution.on_chunk(index)
    return arrivals


def _write_summary(
    out: Path,
    data: TrainingData,
    new_runs: int,
    arrivals: list[float],
    seconds: float,
    execution: Execution,
    threads: int,
) -> None:
    """``summary.json``: counts, dropped and redrawn runs, and timing."""
    summary = {
        "runs": int(data.labels.size),
        "counts": data.counts(),
        "dropped_run_ids": data.dropped_run_ids.tolist(),
        "redrawn_runs": int(np.sum(data.redraws > 0)),
        "chunks_computed": len(arrivals) - 1,
        # time between saved chunks: the first includes compilation (and cluster start-up)
        "chunk_seconds": np.diff(arrivals).tolist(),
        "seconds": seconds,
        "seconds_per_run": seconds / new_runs if new_runs else None,
        "scheduler": execution.scheduler,
        "threads": threads if execution.scheduler is None else None,
    }
    text = json.dumps(summary, indent=1)
    atomic_write(out / "summary.json", lambda tmp: tmp.write_text(text), overwrite=True)


def generate(
    system: AbstractSystem,
    source: AbstractParameterSource,
    config: GenerationConfig,
    out: str | Path,
    *,
    key: Array,
    model_error: ModelErrorDraws | None = None,
    progress: bool = True,
    execution: Execution = Execution(),
) -> TrainingData:
    """Simulate labelled training runs in chunks, save them under ``out`` and return them all.

    For every state, ``config.runs_per_state`` runs: parameters from ``source``, severities
    uniform over the state's ``DamageSpec.severity`` priors, a speed drawn from
    ``config.speeds``; features from :func:`featurize` over each run's motion window, plus
    model-error offsets when ``model_error`` is given. Chunk ``c`` uses the key
    ``fold_in(k_chunks, c)`` with ``k_chunks, k_split = split(key)``, so the result depends
    on ``key`` and the configuration only: not on the chunk order, the scheduler or on
    interruptions. A folder that already holds chunks of the same configuration is resumed
    (finished chunks are loaded, not recomputed); one of another configuration is refused.

    Parameters
    ----------
    system
        The simulated system (its ``simulate_values``, ``motion_window`` and
        ``record_duration``).
    source
        Where the parameters come from (:class:`PosteriorDraws`, :class:`GaussianScatter`);
        it must give exactly the system's parameter names.
    config
        Sizes, states, speeds, split and features.
    out
        Output folder (created; see the module docstring for its layout).
    key
        The PRNG key of the whole generation.
    model_error
        Optional model-error draws added to the features.
    progress
        Show a progress bar (rich).
    execution
        The scheduler, workers and threads that compute the chunks, and a callback per
        saved chunk (:class:`Execution`).

    Returns
    -------
    data
        All runs of all chunks (see :class:`TrainingData`).

    Raises
    ------
    ValueError
        For a source whose names differ from the system's parameters, unknown states, bad
        speeds (through the system), draws outside the bounds, or an output folder of a
        different configuration.
    """
    threads = _check_job(system, source, config, execution)
    job = Job(system, source, model_error, config, key, bool(jax.config.read("jax_enable_x64")))
    system.motion_window(np.asarray(config.speeds), duration=job.duration)
    out = Path(out)
    config_hash, pending = _pending_chunks(job, out)
    new_runs = sum(job.chunk_runs(i)[1].size for i in pending)
    arrivals = _compute_chunks(job, out, config_hash, pending, execution, threads, progress)
    seconds = time.perf_counter() - arrivals[0]
    data = load_training_data(out)
    _write_summary(out, data, new_runs, arrivals, seconds, execution, threads)
    if data.dropped_run_ids.size:
        warnings.warn(
            f"{data.dropped_run_ids.size} simulated runs were dropped after failed solves "
            f"(run ids {data.dropped_run_ids.tolist()[:10]}); see {out / 'summary.json'}",
            stacklevel=2,
        )
    return data


def load_training_data(out: str | Path) -> TrainingData:
    """Assemble the training data of a finished generation folder.

    Raises
    ------
    ValueError
        When the folder has no manifest or some chunks are missing (resume the generation).
    """
    out = Path(out)
    path = out / "manifest.json"
    if not path.exists():
        raise ValueError(f"{out} has no manifest.json: not a training-data folder")
    manifest = json.loads(path.read_text())
    n_chunks = int(manifest["n_chunks"])
    missing = [i for i in range(n_chunks) if not _chunk_path(out, i).exists()]
    if missing:
        raise ValueError(
            f"{out} misses {len(missing)} of {n_chunks} chunks (first {missing[:5]}): the "
            "generation was interrupted; call generate again with the same settings to resume"
        )
    chunks = [_load_chunk(out, i, manifest["config_hash"]) for i in range(n_chunks)]
    joined = {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}
    system = manifest["system"]
    spec = manifest["config"]["spec"]
    fs = system["sampling_rate_hz"]
    n_bins = joined["features"].shape[-1]
    return TrainingData(
        features=joined["features"],
        labels=joined["label"],
        states=tuple(manifest["states"]),
        validation=joined["validation"],
        speeds=joined["speed"],
        t_start=joined["t_start"],
        t_stop=joined["t_stop"],
        run_ids=joined["run_id"],
        redraws=joined["redraws"],
        model_error=joined["model_error"],
        parameters={k.split("/", 1)[1]: v for k, v in joined.items() if k.startswith("parameter/")},
        severities={k.split("/", 1)[1]: v for k, v in joined.items() if k.startswith("severity/")},
        channels=tuple(system["channels"]),
        frequencies=np.arange(n_bins) * (fs / spec["nperseg"]),
        dropped_run_ids=joined["dropped_run_id"],
        manifest=manifest,
    )
