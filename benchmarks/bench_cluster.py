"""The job's simulation-heavy steps in this process and on a local Dask cluster.

Two steps that :class:`bayesdoor.Cluster` sends to workers, each timed in one process under
four placements: this process one task at a time (the baseline), this process two threads
at a time (the default), and a ``distributed.LocalCluster`` of 1 and of N worker processes
(``--workers``, default 2):

1. **generation**: ``bayesdoor.datagen.generate`` of the door's quick training data
   (100 runs per state, healthy / D1 / D2, chunks of 25 runs, Gaussian scatter around the
   paper's optimum), one Dask task per chunk;
2. **diagnosis refits**: ``diagnose_campaign`` of a simulated bearing campaign with a hidden
   supply line (8 runs, the base model at its simulating point, refits of up to three
   candidates on two folds, the detection limits), one Dask task per fold refit and per
   limit.

Each placement runs its step twice and the second is timed (the first compiles, in each
worker too; the workers read the parent's JAX compilation cache). The cluster's start-up is
timed apart. The results of every placement are checked equal to the baseline's. Speed-up:
baseline seconds / placement seconds; on a machine with fewer cores than workers it cannot
exceed the cores.

Usage: python benchmarks/bench_cluster.py [--workers 2] [--json] [--results results/cluster.md]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from bayesdoor import Cluster, configure_jax
from bayesdoor._cluster import Pool, in_process
from bayesdoor.datagen import Execution, GaussianScatter, GenerationConfig, generate
from bayesdoor.door import DoorParameters, ElevatorDoor

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


def _generation(pool: Pool, folder: Path) -> Any:
    door = ElevatorDoor()
    optimum = {k: float(v) for k, v in DoorParameters.paper_optimum().to_dict().items()}
    config = GenerationConfig((0.3, 0.4, 0.5), runs_per_state=100, chunk_size=25)
    data = generate(
        door,
        GaussianScatter.around(door, optimum, 0.05),
        config,
        folder,
        key=jax.random.key(0),
        progress=False,
        execution=Execution(scheduler=pool.address, threads=pool.threads),
    )
    return data.features


def _diagnosis(pool: Pool, folder: Path) -> Any:
    from test_bearing_catalogue import _campaign, _point_fit

    from bayesdoor.bearing import BearingSystem
    from bayesdoor.diagnose import DiagnosisSettings, diagnose_campaign

    system = BearingSystem()
    diagnosis = diagnose_campaign(
        system,
        _campaign("line_frequency", seed=7),
        fit=_point_fit(system),
        progress=False,
        settings=DiagnosisSettings(predictive_draws=4, max_candidates=3, refit_evals=96),
        pool=pool,
    )
    payload = diagnosis.to_json()
    payload.pop("timings", None)
    return json.dumps(payload, sort_keys=True, default=str)


STEPS: dict[str, Callable[[Pool, Path], Any]] = {
    "generation": _generation,
    "diagnosis refits": _diagnosis,
}


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, str):
        return a == b
    return bool(np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True))


def _timed(step: Callable[[Pool, Path], Any], pool: Pool, folder: Path) -> tuple[float, Any]:
    step(pool, folder / "warm")  # compiles (in the workers too)
    t0 = time.perf_counter()
    result = step(pool, folder / "timed")
    return time.perf_counter() - t0, result


def measure(workers: int) -> dict[str, Any]:
    placements: list[tuple[str, Cluster | Pool]] = [
        ("this process, 1 at a time", in_process(1)),
        ("this process, 2 threads", in_process(2)),
        ("local cluster, 1 worker", Cluster(workers=1)),
        (f"local cluster, {workers} workers", Cluster(workers=workers)),
    ]
    rows: list[dict[str, Any]] = []
    baseline: dict[str, tuple[float, Any]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for p, (label, where) in enumerate(placements):
            t0 = time.perf_counter()
            if isinstance(where, Pool):
                pool, stop = where, None
            else:
                opened = where.open()
                pool, stop = opened.__enter__(), opened
            start_s = time.perf_counter() - t0
            try:
                for name, step in STEPS.items():
                    seconds, result = _timed(step, pool, Path(tmp) / f"{p}-{name}")
                    if name not in baseline:
                        baseline[name] = (seconds, result)
                    rows.append(
                        {
                            "step": name,
                            "placement": label,
                            "workers": where.workers if isinstance(where, Cluster) else 0,
                            "start_s": start_s,
                            "seconds": seconds,
                            "speed_up": baseline[name][0] / seconds,
                            "same_result": _same(result, baseline[name][1]),
                        }
                    )
            finally:
                if stop is not None:
                    stop.__exit__(None, None, None)
    return {"rows": rows}


def _commit() -> str:
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def markdown(result: dict[str, Any]) -> str:
    lines = [
        "# The job's simulation-heavy steps on a local Dask cluster",
        "",
        f"- command: `{result['command']}`",
        f"- date: {result['date']}",
        f"- commit: {result['commit']}",
        f"- machine: {result['machine']}; load (1 min) {result['load_start']:.2f} at the start, "
        f"{result['load_end']:.2f} at the end",
        "",
        "Seconds of the second call of each step (the first compiles); speed-up against this "
        "process one task at a time; the cluster's start-up apart. Same result: equal to the "
        "baseline's to the last digit.",
        "",
        "| step | placement | seconds | speed-up | cluster start-up (s) | same result |",
        "|---|---|---|---|---|---|",
    ]
    for row in result["rows"]:
        start = f"{row['start_s']:.1f}" if row["workers"] else "-"
        lines.append(
            f"| {row['step']} | {row['placement']} | {row['seconds']:.1f} | "
            f"{row['speed_up']:.2f} | {start} | {'yes' if row['same_result'] else 'NO'} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2, help="workers of the larger cluster")
    parser.add_argument("--json", action="store_true", help="print the result as JSON only")
    parser.add_argument("--results", type=Path, help="write the table (and .json beside it)")
    args = parser.parse_args()
    configure_jax()
    load_start = os.getloadavg()[0]
    result = {
        "command": "python benchmarks/bench_cluster.py"
        + (f" --workers {args.workers}" if args.workers != 2 else "")
        + (f" --results {args.results}" if args.results else ""),
        "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
        "commit": _commit(),
        "machine": f"{os.cpu_count()} cores",
        "load_start": load_start,
        **measure(args.workers),
        "load_end": os.getloadavg()[0],
    }
    if args.results:
        args.results.write_text(markdown(result))
        args.results.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1) if args.json else markdown(result))


if __name__ == "__main__":
    main()
