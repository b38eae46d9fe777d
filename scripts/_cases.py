"""What the hidden-effect results scripts share: the rig's effects, a case's settings hash,
its run in parallel processes, and the table's number format.

``scripts/diagnosis.py`` and ``scripts/diagnosis_gain.py`` import it as ``_cases``: a script
run as ``python scripts/x.py`` (by hand, by ``scripts/make_results.py`` or by a test) has its
own folder first on ``sys.path``, and the processes that ``run_cases`` spawns inherit it.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import hashlib
import json
import multiprocessing
import os
import pickle
import subprocess
import sys
import time
import traceback
from collections.abc import Callable, Hashable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

ROOT = Path(__file__).resolve().parent.parent
#: the rig's catalogue effects, in the order of ``bayesdoor.door.rig.Effects``
RIG_EFFECTS = (
    "frame_mode",
    "wheel_eccentricity",
    "rail_waviness",
    "sensor_cross_axis",
    "mains_hum",
)
NONE = "none"
Case = TypeVar("Case", bound=Hashable)


def digest(settings: Any, length: int) -> str:
    """The first ``length`` hex digits of the SHA-256 of a settings dataclass's fields.

    The hash names a case's saved result, so that a change of settings never reads a case
    made with other settings.
    """
    text = json.dumps(dataclasses.asdict(settings), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:length]


def hidden_effect(effect: str, seed: int):
    """The rig's ``Effects`` with ``effect`` drawn by its ``from_seed(seed)``.

    ``effect`` is one of ``RIG_EFFECTS``, or ``NONE`` for nothing hidden.
    """
    from bayesdoor.door import rig

    kinds: dict[str, Any] = {
        "frame_mode": rig.FrameMode,
        "wheel_eccentricity": rig.WheelEccentricity,
        "rail_waviness": rig.RailWaviness,
        "sensor_cross_axis": rig.SensorCrossAxis,
        "mains_hum": rig.MainsHum,
    }
    if effect == NONE:
        return rig.Effects()
    if effect not in kinds:
        raise ValueError(
            f"effect={effect!r} is not a rig effect; use one of {', '.join(RIG_EFFECTS)} or "
            f"{NONE!r}"
        )
    return rig.Effects(**{effect: kinds[effect].from_seed(seed)})


def setup_jax() -> None:
    """float64 and the project's persistent compilation cache, wherever the script runs from."""
    from bayesdoor import configure_jax

    configure_jax(ROOT / ".jax_cache")


def attempt(run_case: Callable[..., dict[str, Any]], effect: str, seed: int, *args: Any):
    """``run_case(effect, seed, *args)``, or the failure as a row when it raises.

    A failed case is a result too: it is counted in the table, not hidden. Its row has
    ``verdict`` ``None``, ``error`` (the exception's type and message) and ``traceback``.
    """
    try:
        return run_case(effect, seed, *args)
    except Exception as err:
        return {
            "effect": effect,
            "seed": seed,
            "verdict": None,
            "error": f"{type(err).__name__}: {err}",
            "traceback": traceback.format_exc(),
        }


def saved_diagnosis(
    campaign, fit_folder: Path, path: Path, *, quick: bool, seed: int
) -> tuple[Any, tuple[float, float]]:
    """The door's diagnosis of ``campaign`` under the fit saved in ``fit_folder``: made once
    and pickled to ``path`` (through a rename), then read; with its wall and CPU seconds
    (zero when read)."""
    from bayesdoor.diagnose import diagnose_campaign
    from bayesdoor.door import DOOR_CATALOGUE, ElevatorDoor
    from bayesdoor.inference import FitResult

    if path.is_file():
        with open(path, "rb") as f:
            return pickle.load(f), (0.0, 0.0)
    start, cpu = time.perf_counter(), time.process_time()
    diagnosis = diagnose_campaign(
        ElevatorDoor(),
        campaign,
        fit=FitResult.load(fit_folder),
        seed=seed,
        quick=quick,
        progress=False,
        catalogue=DOOR_CATALOGUE,
    )
    seconds = (time.perf_counter() - start, time.process_time() - cpu)
    tmp = path.with_suffix(".tmp")
    with open(tmp, "wb") as f:
        pickle.dump(diagnosis, f)
    os.replace(tmp, path)
    return diagnosis, seconds


def save_json(path: Path, row: Mapping[str, Any]) -> None:
    """Write ``row`` as indented JSON through a rename, so a saved case is never half written."""
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(row, indent=1) + "\n")
    os.replace(tmp, path)


def run_cases(
    worker: Callable[..., dict[str, Any]],
    calls: Mapping[Case, tuple[Any, ...]],
    jobs: int,
    finished: Callable[[Case, dict[str, Any]], None],
) -> None:
    """``worker(*calls[case])`` for every case, ``jobs`` processes at a time.

    With ``jobs > 1`` each case runs in a spawned process with one CPU thread, so that the
    cases do not fight over the cores; ``worker`` must then be a module-level function.
    ``finished(case, row)`` is called with each case's row as it finishes.
    """
    if jobs < 1:
        raise ValueError(f"jobs={jobs} must be at least 1 (the number of processes)")
    if jobs == 1:
        for case, args in calls.items():
            finished(case, worker(*args))
        return
    os.environ.setdefault(
        "XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    )
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context) as pool:
        futures = {pool.submit(worker, *args): case for case, args in calls.items()}
        for future in concurrent.futures.as_completed(futures):
            finished(futures[future], future.result())


def fmt(value: Any, spec: str) -> str:
    """``value`` formatted by ``spec``, or ``-`` when it is missing."""
    return "-" if value is None else format(value, spec)


def command_line(script: str, argv: Sequence[str] | None) -> str:
    """How the script was called, for the table's header (``argv`` ``None``: ``sys.argv``)."""
    words = sys.argv[1:] if argv is None else argv
    return f"python scripts/{script} {' '.join(words)}".strip()


#: the markers around what a script writes in its results file: the text outside them (notes
#: written by hand after a run, earlier runs' sections) is kept when the script runs again
BEGIN = "<!-- generated: begin (the script rewrites what lies between these markers) -->"
END = "<!-- generated: end -->"
#: the heading under which a file's old text is kept when it had no markers
KEPT = "## Kept from this file before the run above (it had no generated-block markers)"


def merge_results(old: str | None, text: str) -> str:
    """The results file's new text: ``text`` between the markers, the rest of ``old`` kept.

    ``old`` is the file's present text (``None``: no file). With the markers in it, only what
    lies between them is replaced; without them nothing of it is dropped: it follows the new
    block under :data:`KEPT`.
    """
    block = f"{BEGIN}\n{text.rstrip()}\n{END}\n"
    if old is None or not old.strip():
        return block
    if old.count(BEGIN) == 1 and old.count(END) == 1 and old.index(BEGIN) < old.index(END):
        before, _, rest = old.partition(BEGIN)
        _, _, after = rest.partition(END)
        return before + block + after.removeprefix("\n")
    return f"{block}\n{KEPT}\n\n{old.rstrip()}\n"


def write_results(path: Path, text: str, *, echo: bool = True) -> None:
    """Write a script's results to ``path`` (making its folder), keeping the file's notes.

    What lies between the file's generated-block markers is replaced by ``text``; everything
    else in the file stays (:func:`merge_results`). The new text is printed unless ``echo`` is
    false. The file is replaced in one step, so a killed run leaves the old one whole.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    old = path.read_text() if path.is_file() else None
    partial = path.with_name(f".{path.name}.partial")
    try:
        partial.write_text(merge_results(old, text))
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)  # a failed write leaves neither it nor a broken file
    if echo:
        print(text)


def code_version() -> str:
    """The commit of the ``bayesdoor`` code that is imported, and whether it was changed.

    Looked up in the git checkout that holds the imported package (which need not be this
    script's), so that a table names the code that made it.
    """
    import bayesdoor

    package = Path(bayesdoor.__file__).resolve().parent

    def git(*words: str) -> str:
        done = subprocess.run(
            ["git", "-C", str(package), *words], capture_output=True, text=True, check=False
        )
        return done.stdout.strip() if done.returncode == 0 else ""

    commit = git("rev-parse", "--short", "HEAD")
    if not commit:
        return f"bayesdoor from {package} (not a git checkout: commit unknown)"
    changed = git("status", "--porcelain", "--", ".")
    return f"bayesdoor at commit {commit}" + (
        " with uncommitted changes" if changed else " (no uncommitted changes)"
    )
