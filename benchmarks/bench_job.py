"""The main job stage by stage, against the machine's scipy yardstick in the same process.

One process: first the yardstick (the door's equations with a numpy right-hand side, scipy's
LSODA, one 3.5 s record: ``bench_simulate.time_scipy``) and the simulator (a vmapped float64
batch of the same record, ``bench_simulate.time_batch``), then the main job on a campaign from
an empty folder (every stage computed; the JAX cache as it is). Each stage is reported with its
wall time, the process's CPU time during it, the peak memory so far, and the wall time in
*scipy runs* (``seconds / scipy seconds per run``), the figure that compares machines, and
the wall seconds it spent in JAX's tracing, lowering and compiling (the union of their time
spans from ``jax.monitoring``; a compilation the persistent cache serves still traces and
lowers, so this is the price of a fresh process); inside the fit and the diagnosis their own
steps (the fit's ``timings`` and CMA-ES evaluations, the diagnosis's ``timings``).

``--warm-up`` runs the same job once first, untimed, in a process of its own, so that the timed
run finds the JAX cache as a user's second job does. With ``--results FILE`` the table goes
into the file's generated block (the rest of the file is kept) and the JSON beside it (``FILE``
ending ``.json``).

Usage: python benchmarks/bench_job.py [--campaign demo|PATH] [--full] [--no-diagnosis]
       [--batch 64] [--seed 0] [--keep DIR] [--warm-up] [--keep-caches] [--results FILE]
       [--json]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import jax

from bayesdoor import configure_jax, release_between_stages

# as the command line sets JAX up: the cache of $BAYESDOOR_JAX_CACHE or ./.jax_cache
configure_jax()

#: the targets on the 2-core development machine (seconds; speed-up against scipy; MB)
TARGETS = {"quick": 60.0, "full": 180.0, "simulate_x_scipy": 250.0, "quick_memory_mb": 2000.0}


#: the JAX events whose time spans make up a compilation
COMPILE_EVENTS = (
    "/jax/core/compile/jaxpr_trace_duration",
    "/jax/core/compile/jaxpr_to_mlir_module_duration",
    "/jax/core/compile/backend_compile_duration",
)


class CompileClock:
    """The time spans of JAX's tracing, lowering and compiling, for the union over a window."""

    def __init__(self) -> None:
        self.spans: list[tuple[float, float]] = []
        #: per program (its function's name): [times traced, seconds in the three events]
        self.programs: dict[str, list[float]] = {}
        #: seconds in each of the three events (tracing, lowering, compiling or reading back)
        self.events: dict[str, float] = dict.fromkeys(COMPILE_EVENTS, 0.0)
        self._lock = threading.Lock()
        jax.monitoring.register_event_time_span_listener(self._listen)

    def _listen(self, event: str, start: float, end: float, **kwargs: Any) -> None:
        if event in COMPILE_EVENTS:
            name = str(kwargs.get("fun_name", "?")).removeprefix("jit(").removesuffix(")")
            with self._lock:
                self.spans.append((start, end))
                tally = self.programs.setdefault(name, [0, 0.0])
                tally[0] += event == COMPILE_EVENTS[0]
                tally[1] += end - start
                self.events[event] += end - start

    def heaviest(self, n: int = 6) -> list[dict[str, Any]]:
        """The ``n`` programs that took longest to trace, lower and compile (or read back)."""
        ranked = sorted(self.programs.items(), key=lambda kv: -kv[1][1])[:n]
        return [{"program": k, "traced": int(v[0]), "seconds": v[1]} for k, v in ranked]

    def seconds(self, start: float, end: float) -> float:
        """Wall seconds between ``start`` and ``end`` (``time.time()``) in any span."""
        clipped = sorted(
            (max(a, start), min(b, end)) for a, b in self.spans if b > start and a < end
        )
        total, reach = 0.0, start
        for a, b in clipped:
            if b > reach:
                total += b - max(a, reach)
                reach = b
        return total


def _stage_windows(events: list[tuple[float, str]]) -> dict[str, tuple[float, float]]:
    """Each computed stage's (start, end) from the job's progress lines."""
    starts: dict[str, float] = {}
    windows = {}
    for t, line in events:
        name, _, rest = line.partition(":")
        if "done in" in rest and name in starts:
            windows[name] = (starts[name], t)
        elif rest.strip().startswith(("computing", "configuration changed")):
            starts[name] = t
    return windows


def _commit() -> str:
    """The commit measured; ``+changes`` when the code measured (the package, the
    benchmarks) differs from it."""

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", *args],
            capture_output=True,
            text=True,
            check=True,
            cwd=Path(__file__).resolve().parent,
        ).stdout.strip()

    try:
        commit = git("rev-parse", "--short", "HEAD")
        changed = git("status", "--porcelain", "--untracked-files=no", "--", "../bayesdoor", ".")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return f"{commit}+changes" if changed else commit


def _load() -> list[float]:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return []


def _campaign(spec: str):
    if spec == "demo":
        from bayesdoor.door.datasets import load_demo_campaign

        return load_demo_campaign()
    from bayesdoor.io import load_campaign

    return load_campaign(spec)


def yardstick(batch: int, duration: float = 3.5) -> dict[str, Any]:
    """scipy's LSODA on one record and the vmapped float64 batch, in this process."""
    from bench_simulate import time_batch, time_scipy

    scipy_runs = [time_scipy(duration) for _ in range(2)]
    scipy_ms = min(r["ms_per_run"] for r in scipy_runs)
    f64 = time_batch(batch, duration, "float64")
    return {
        "duration_s": duration,
        "scipy_ms_per_run": scipy_ms,
        "scipy_nfev": scipy_runs[0]["nfev"],
        "batch": batch,
        "batch_float64_ms_per_run": f64["ms_per_run"],
        "batch_compile_s": f64["compile_s"],
        "simulate_x_scipy": scipy_ms / f64["ms_per_run"],
    }


def run(
    campaign_spec: str,
    full: bool,
    diagnosis: bool,
    seed: int,
    keep: str | None,
    clock: CompileClock,
    release: bool = True,
) -> dict:
    from bayesdoor.door import ElevatorDoor
    from bayesdoor.pipeline import JobConfig, peak_memory_mb, run_job

    campaign = _campaign(campaign_spec)
    system = ElevatorDoor()
    if campaign_spec != "demo":
        from bayesdoor.systems import get_system

        system = get_system(str(campaign.attrs.get("system", system.name)))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(keep) if keep else Path(tmp) / "job"
        events: list[tuple[float, str]] = []
        t0, c0, start = time.perf_counter(), time.process_time(), time.time()
        # as `bayesdoor run` runs it: JAX's caches dropped between the stages (unless
        # --keep-caches, to measure what that costs and saves)
        with release_between_stages() if release else contextlib.nullcontext():
            result = run_job(
                system,
                campaign,
                out,
                JobConfig(quick=not full, seed=seed, html=True, diagnosis=diagnosis),
                progress=False,
                report=lambda line: events.append((time.time(), line)),
                overwrite=True,
            )
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        windows = _stage_windows(events)
        compile_s = clock.seconds(start, time.time())
        fit_json = json.loads((out / "fit" / "result" / "fit.json").read_text())
    payload = result.to_json()
    for stage in payload["stages"]:
        window = windows.get(stage["name"])
        stage["compile_seconds"] = None if window is None else clock.seconds(*window)
    metrics = payload.get("metrics") or {}
    diag = payload.get("diagnosis") or {}
    return {
        "campaign": campaign_spec,
        "sizes": "full" if full else "quick",
        "wall_s": wall,
        "cpu_s": cpu,
        "compile_s": compile_s,
        "heaviest_programs": clock.heaviest(),
        "programs_compiled": len(clock.programs),
        "compile_events": {k.rsplit("/", 1)[-1]: v for k, v in clock.events.items()},
        "peak_memory_mb": peak_memory_mb(),
        "stages": payload["stages"],
        "fit_steps": {
            "timings": fit_json.get("timings"),
            "cmaes_evaluations": (fit_json.get("cmaes") or {}).get("evaluations"),
            "gates_passed": (fit_json.get("diagnostics") or {}).get("passed"),
        },
        "diagnosis_steps": {"timings": diag.get("timings"), "verdict": diag.get("verdict")},
        "accuracy": metrics.get("accuracy"),
        "ece": metrics.get("ece"),
    }


def markdown(result: dict[str, Any]) -> str:
    """The generated block of ``--results``: the job against its targets, stage by stage."""
    stick, job = result["yardstick"], result["job"]
    sizes = job["sizes"]
    scipy_s = stick["scipy_ms_per_run"] / 1e3
    target_s = TARGETS[sizes]
    gates = job["fit_steps"]["gates_passed"]
    rows = [
        (
            f"the main job, `{sizes}` sizes, on the {job['campaign']} campaign, with the "
            "diagnosis and the report",
            f"{job['wall_s']:.0f} s ({job['scipy_runs']:.0f} scipy runs); "
            f"{job['compile_s']:.0f} s of it compiling",
            f"<= {target_s:.0f} s ({target_s / scipy_s:.0f} scipy runs on this machine)",
        ),
        (
            "its peak memory",
            f"{job['peak_memory_mb'] / 1024:.1f} GB",
            f"<= {TARGETS['quick_memory_mb'] / 1000:.0f} GB" if sizes == "quick" else "-",
        ),
        (
            "its posterior's sampling gates",
            "pass" if gates else "fail",
            "pass",
        ),
        (
            f"a {stick['duration_s']} s door run, vmapped float64 batch of {stick['batch']}",
            f"{stick['batch_float64_ms_per_run']:.1f} ms a run = "
            f"{stick['simulate_x_scipy']:.0f}x scipy",
            f">= {TARGETS['simulate_x_scipy']:.0f}x scipy",
        ),
    ]
    lines = [
        "# Performance",
        "",
        f"Command: `{result['command']}` ({result['date']}, commit {result['commit']}; "
        f"{result['machine']}, load average {_first(result['load_start'])} at the start and "
        f"{_first(result['load_end'])} at the end). One process: the yardstick first (scipy's "
        "LSODA on the door's equations with a numpy right-hand side, "
        f"{stick['scipy_ms_per_run']:.0f} ms for one {stick['duration_s']} s record), then the "
        "job from an empty folder, "
        + (
            "after one untimed run of the same job (the JAX cache as a user's second job finds it)."
            if result.get("warm_up")
            else "with the JAX cache as the process found it."
        )
        + " A *scipy run* is that record's time: the unit that compares machines.",
        "",
        "| what | now | target |",
        "|---|---|---|",
        *(f"| {a} | {b} | {c} |" for a, b, c in rows),
        "",
        f"The job stage by stage (accuracy {job['accuracy']:.3f}, ECE {job['ece']:.3f}; the "
        "compile column is the wall time inside JAX's tracing, lowering and compiling, the "
        "persistent cache's reads included):",
        "",
        "| stage | wall s | scipy runs | CPU s | compiling s | peak memory GB |",
        "|---|---|---|---|---|---|",
    ]
    for st in job["stages"]:
        lines.append(
            f"| {st['name']} | {st['seconds']:.1f} | {st['scipy_runs']:.1f} | "
            f"{st['cpu_seconds']:.1f} | {st['compile_seconds'] or 0.0:.1f} | "
            f"{st['peak_memory_mb'] / 1024:.1f} |"
        )
    fit_t = job["fit_steps"]["timings"] or {}
    diag_t = job["diagnosis_steps"]["timings"] or {}
    lines += [
        "",
        "Inside the fit: "
        + ", ".join(f"{k} {v:.1f} s" for k, v in fit_t.items())
        + f" (CMA-ES {job['fit_steps']['cmaes_evaluations']} evaluations). Inside the "
        "diagnosis: "
        + ", ".join(f"{k} {v:.1f} s" for k, v in diag_t.items())
        + f" (verdict `{job['diagnosis_steps']['verdict']}`).",
        "",
        f"The process traced {job['programs_compiled']} distinct programs (the yardstick's "
        "included); those that took longest to trace, lower and compile (or read back from the "
        "cache):",
        "",
        "| program | times traced | seconds |",
        "|---|---|---|",
        *(
            f"| `{p['program']}` | {p['traced']} | {p['seconds']:.1f} |"
            for p in job["heaviest_programs"]
        ),
    ]
    return "\n".join(lines) + "\n"


def _first(load: list[float]) -> str:
    return f"{load[0]:.1f}" if load else "unknown"


def write(path: Path, result: dict[str, Any]) -> None:
    """The table into ``path``'s generated block, the JSON beside it."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
    from _cases import write_results

    path.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    write_results(path, markdown(result), echo=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--campaign", default="demo", help="'demo' or a campaign file")
    parser.add_argument("--full", action="store_true", help="the paper's sizes, not --quick")
    parser.add_argument("--no-diagnosis", action="store_true", help="leave the diagnosis out")
    parser.add_argument("--batch", type=int, default=64, help="the simulator's batch")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--keep", help="write the job into this folder (else a temporary one)")
    parser.add_argument(
        "--warm-up", action="store_true", help="run the job once, untimed, before the timed run"
    )
    parser.add_argument(
        "--keep-caches",
        action="store_true",
        help="keep JAX's caches between the stages (bayesdoor run drops them)",
    )
    parser.add_argument("--job-only", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--results", type=Path, help="write the table into this file")
    parser.add_argument("--json", action="store_true", help="print the result as JSON only")
    args = parser.parse_args()

    if args.job_only:
        with tempfile.TemporaryDirectory() as tmp:
            run(args.campaign, args.full, not args.no_diagnosis, args.seed, tmp, CompileClock())
        return
    if args.warm_up:
        # in a process of its own: the timed run is then a fresh process, as `bayesdoor run`
        # is, that finds the persistent JAX cache as the user's second job finds it
        subprocess.run(
            [
                sys.executable,
                __file__,
                "--job-only",
                "--campaign",
                args.campaign,
                "--seed",
                str(args.seed),
                *(["--full"] if args.full else []),
                *(["--no-diagnosis"] if args.no_diagnosis else []),
            ],
            check=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    started = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    load_start = _load()
    clock = CompileClock()
    stick = yardstick(args.batch)
    job = run(
        args.campaign,
        args.full,
        not args.no_diagnosis,
        args.seed,
        args.keep,
        clock,
        release=not args.keep_caches,
    )
    scipy_s = stick["scipy_ms_per_run"] / 1e3
    for stage in job["stages"]:
        stage["scipy_runs"] = stage["seconds"] / scipy_s
    job["scipy_runs"] = job["wall_s"] / scipy_s
    result = {
        "command": "python benchmarks/bench_job.py "
        + " ".join(
            a
            for a in (
                f"--campaign {args.campaign}" if args.campaign != "demo" else "",
                "--full" if args.full else "",
                "--no-diagnosis" if args.no_diagnosis else "",
                "--warm-up" if args.warm_up else "",
                "--keep-caches" if args.keep_caches else "",
            )
            if a
        ),
        "date": started,
        "commit": _commit(),
        "machine": f"{os.cpu_count()} cores, {platform.machine()}",
        "warm_up": args.warm_up,
        "release_between_stages": not args.keep_caches,
        "load_start": load_start,
        "load_end": _load(),
        "yardstick": stick,
        "job": job,
        "targets": TARGETS,
    }
    if args.results is not None:
        write(args.results, result)
    if args.json:
        print(json.dumps(result, indent=1))
        return
    print(
        f"yardstick: scipy LSODA {stick['scipy_ms_per_run']:.0f} ms per {stick['duration_s']} s "
        f"run; vmapped float64 batch of {stick['batch']} "
        f"{stick['batch_float64_ms_per_run']:.1f} ms per run = "
        f"{stick['simulate_x_scipy']:.0f}x scipy (target {TARGETS['simulate_x_scipy']:.0f}x)"
    )
    target = TARGETS[job["sizes"]]
    print(
        f"job ({job['sizes']}, {job['campaign']}): {job['wall_s']:.1f} s wall = "
        f"{job['scipy_runs']:.1f} scipy runs (target {target:.0f} s), {job['cpu_s']:.1f} s CPU, "
        f"{job['compile_s']:.1f} s compiling, "
        f"peak {job['peak_memory_mb']:.0f} MB; accuracy {job['accuracy']}, ECE {job['ece']}"
    )
    for s in job["stages"]:
        print(
            f"  {s['name']:<10} {s['seconds']:7.1f} s  {s['scipy_runs']:6.1f} scipy runs  "
            f"CPU {s['cpu_seconds']:7.1f} s  compiling {s['compile_seconds'] or 0.0:6.1f} s  "
            f"peak {s['peak_memory_mb']:6.0f} MB"
        )
    print(f"  fit steps: {job['fit_steps']}")
    print(f"  diagnosis steps: {job['diagnosis_steps']}")


if __name__ == "__main__":
    main()
