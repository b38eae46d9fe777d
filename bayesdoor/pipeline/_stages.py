"""Stages of a job: one folder each, finished atomically, reused when their configuration matches.

A stage ``NAME`` of a job in ``OUT`` owns the folder ``OUT/NAME``. It is finished when
``OUT/NAME/stage.json`` exists; that record holds the SHA-256 of the stage's configuration
(which includes the hashes of the stages it reads, so a change upstream propagates). A finished
stage with the same hash is reused as it is; any other content of the folder is replaced.

Most stages are computed in a temporary sibling folder that is renamed into place when it is
complete, so an interrupted stage leaves nothing behind. A *resumable* stage (training-data
generation, which saves chunk by chunk) computes in its own folder; a start marker holding the
hash lets an interrupted run of the same configuration continue where it stopped, while one of
another configuration starts afresh.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import resource
import shutil
import sys
import time
import uuid
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from .._memory import stage_ended
from ..io import atomic_write

RECORD = "stage.json"
_STARTED = ".started"


def configuration_hash(config: Mapping[str, Any]) -> str:
    """SHA-256 of a JSON-able configuration (keys sorted, so their order does not matter)."""
    text = json.dumps(config, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


@dataclasses.dataclass(frozen=True)
class StageRecord:
    """What ``OUT/NAME/stage.json`` says about a finished stage.

    Attributes
    ----------
    name
        The stage's name (its folder).
    path
        The stage's folder.
    config_hash
        SHA-256 of the stage's configuration.
    reused
        True when this call found the stage finished and did not recompute it.
    seconds
        Wall time the stage took when it was computed.
    cpu_seconds
        CPU time of the process (every thread) while the stage was computed; above
        ``seconds`` when it used several cores. ``None`` for a record written without it.
    peak_memory_mb
        The process's peak resident memory (MB) when the stage ended: the largest of this
        stage and everything the process did before it (``None`` as above).
    """

    name: str
    path: Path
    config_hash: str
    reused: bool
    seconds: float
    cpu_seconds: float | None = None
    peak_memory_mb: float | None = None

    @classmethod
    def of(cls, path: Path, record: Mapping[str, Any]) -> StageRecord:
        """The record of the finished stage in ``path`` (``record``: its ``stage.json``), as
        reused."""
        return cls(
            path.name,
            path,
            str(record["config_hash"]),
            True,
            float(record.get("seconds", 0.0)),
            _optional_float(record.get("cpu_seconds")),
            _optional_float(record.get("peak_memory_mb")),
        )


def peak_memory_mb() -> float:
    """The process's peak resident memory so far, MB (``getrusage``: kB on Linux, bytes on
    macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024.0**2 if sys.platform == "darwin" else 1024.0)


def _optional_float(value: Any) -> float | None:
    return None if value is None else float(value)


def finished_record(path: Path) -> dict[str, Any] | None:
    """The record of a finished stage folder, ``None`` when the stage is not finished."""
    record = path / RECORD
    if not record.is_file():
        return None
    try:
        return json.loads(record.read_text())
    except (OSError, json.JSONDecodeError):
        return None


def stage_in(folder: Path) -> StageRecord | None:
    """The record of the finished stage in ``folder`` (``None`` when it is not one)."""
    record = finished_record(folder)
    return None if record is None else StageRecord.of(folder, record)


class Finished:
    """What a stage's product tells of the stage that made it (its ``stage`` record).

    A product is a frozen dataclass with a ``stage`` field (``None`` until a stage saved it),
    ``save(folder)`` and a class method ``load(folder)``.
    """

    stage: StageRecord | None

    @property
    def folder(self) -> Path:
        """The folder of the stage that made it."""
        return self._record().path

    @property
    def key(self) -> str:
        """The configuration hash of the stage that made it (its inputs' hash)."""
        return self._record().config_hash

    def _record(self) -> StageRecord:
        if self.stage is None:
            raise ValueError(
                f"this {type(self).__name__} was not made by a stage of a job: it has no "
                "folder or key; load it from a finished stage's folder"
            )
        return self.stage


def _write_record(path: Path, payload: dict[str, Any]) -> None:
    text = json.dumps(payload, indent=1, default=str) + "\n"
    atomic_write(path / RECORD, lambda tmp: tmp.write_text(text), overwrite=True)


def run_stage(
    out: Path,
    name: str,
    config: Mapping[str, Any],
    compute: Callable[[Path], None],
    *,
    resumable: bool = False,
    report: Callable[[str], None] = lambda line: None,
) -> StageRecord:
    """Run the stage ``name`` of the job in ``out`` unless it is finished with this configuration.

    Parameters
    ----------
    out
        The job's output folder.
    name
        The stage (its folder under ``out``).
    config
        Everything the stage's output depends on, JSON-able (the hashes of the stages it reads
        included).
    compute
        Writes the stage's files into the folder it is given.
    resumable
        Compute in the stage's own folder and let an interrupted run of the same configuration
        continue (``compute`` must then tolerate partial content of its own making).
    report
        Receives one progress line when the stage starts and one when it ends or is reused.

    Returns
    -------
    StageRecord
    """
    path = out / name
    digest = configuration_hash(config)
    old = finished_record(path)
    if old is not None and old.get("config_hash") == digest:
        report(f"{name}: reused (configuration {digest[:10]}, finished {old.get('finished')})")
        return StageRecord.of(path, old)
    report(f"{name}: {'configuration changed' if old is not None else 'computing'} ...")
    start, cpu_start = time.perf_counter(), time.process_time()
    if resumable:
        work = _resume(path, digest, fresh=old is not None)
        compute(work)
    else:
        work = _computed(out, name, compute)
    seconds = time.perf_counter() - start
    cpu_seconds, peak = time.process_time() - cpu_start, peak_memory_mb()
    # what the stage freed goes back to the system before the next stage allocates
    stage_ended()
    finished = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    _write_record(
        work,
        {
            "stage": name,
            "config_hash": digest,
            "config": dict(config),
            "seconds": seconds,
            "cpu_seconds": cpu_seconds,
            "peak_memory_mb": peak,
            "finished": finished,
        },
    )
    if not resumable:
        if path.exists():
            shutil.rmtree(path)
        work.rename(path)
    else:
        (path / _STARTED).unlink(missing_ok=True)
    report(f"{name}: done in {seconds:.1f} s")
    return StageRecord(name, path, digest, False, seconds, cpu_seconds, peak)


def _resume(path: Path, digest: str, *, fresh: bool) -> Path:
    """The folder of a resumable stage: kept when a start marker holds ``digest`` (an
    interrupted run of the same configuration), emptied otherwise or when ``fresh``."""
    marker = path / _STARTED
    if path.exists() and (fresh or not marker.is_file() or marker.read_text() != digest):
        shutil.rmtree(path)
    path.mkdir(parents=True, exist_ok=True)
    marker.write_text(digest)
    return path


def _computed(out: Path, name: str, compute: Callable[[Path], None]) -> Path:
    """``compute`` run in a temporary sibling of the stage's folder (removed if it fails)."""
    # the temporary folder of a run killed half way (SIGKILL, power loss) is garbage
    for stale in out.glob(f".{name}.*.tmp"):
        shutil.rmtree(stale, ignore_errors=True)
    work = out / f".{name}.{uuid.uuid4().hex}.tmp"
    work.mkdir(parents=True)
    try:
        compute(work)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    return work
