"""Regenerate everything in ``results/`` with one command.

Each step is one script or benchmark of this repository, run as its own process, in the order
below; the table files are written by the scripts themselves (each names the command that made
it at its top), the benchmarks' JSON goes to ``results/benchmarks/``. A script rewrites only the
block between its file's generated-block markers: the notes written by hand after a run stay
(``scripts/_cases.py``, ``write_results``). ``results/performance.md`` discusses the figures.
Each step is the command that made its file, the one the README quotes beside its figure.

Usage::

    .venv/bin/python scripts/make_results.py            # everything (hours on a 2-core CPU)
    .venv/bin/python scripts/make_results.py --quick    # the small versions, in out/results-quick
    .venv/bin/python scripts/make_results.py --only sbc diagnosis
    .venv/bin/python scripts/make_results.py --list     # the steps and their commands
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "results"
#: where ``--quick`` writes (its small versions are not the README's figures)
QUICK_RESULTS = ROOT / "out" / "results-quick"


@dataclass(frozen=True)
class Step:
    """One producer of results: its name, script, arguments, and what ``--quick`` adds."""

    name: str
    script: str
    args: tuple[str, ...] = ()
    quick_args: tuple[str, ...] = ("--quick",)
    json_to: str | None = None  # benchmarks: stdout (JSON) saved under <results>/benchmarks/
    #: the script's option naming its results file, and the file's name in the results folder
    out: tuple[str, str] | None = None

    def command(self, quick: bool, results: Path | None = None) -> list[str]:
        """The command line; with ``results`` (a folder other than ``results/``) the step's
        file is written there instead."""
        args = [*self.args, *(self.quick_args if quick else ())]
        if results is not None and self.out is not None:
            args += [self.out[0], str(results / self.out[1])]
        return [sys.executable, self.script, *args]


#: each step is the command that made its results file (the README quotes the same); ``--quick``
#: appends the step's ``quick_args`` (the small version: minutes, and a file that is not the
#: README's figure)
STEPS: tuple[Step, ...] = (
    Step(
        "contact_laws", "scripts/contact_laws.py", quick_args=(), out=("--out", "contact_laws.md")
    ),
    Step(
        "contact_law_ablation",
        "scripts/contact_law_ablation.py",
        args=("--workers", "2"),
        out=("--out", "contact_law_ablation.md"),
    ),
    Step(
        "sbc",
        "scripts/sbc.py",
        args=("--forward", "surrogate", "--n-datasets", "20", "--workers", "2"),
        quick_args=(),
        out=("--report", "sbc.md"),
    ),
    Step(
        "classification",
        "scripts/classification.py",
        args=(
            *("--seeds", "0", "1", "2", "3", "4"),
            *("--fit-evals", "300", "--fit-motion", "1.5", "--jobs", "2"),
        ),
        quick_args=("--seeds", "0", "--runs-per-state", "200"),
        out=("--results", "classification.md"),
    ),
    Step(
        "diagnosis",
        "scripts/diagnosis.py",
        args=(
            *("--seeds", "0", "1", "--none-seeds", "2", "--runs", "6"),
            *("--diagnosis", "quick", "--jobs", "2"),
        ),
        quick_args=("--seeds", "0", "--none-seeds", "1"),
        out=("--results", "diagnosis.md"),
    ),
    Step(
        "diagnosis_gain",
        "scripts/diagnosis_gain.py",
        args=(
            "--quick",
            *("--effects", "sensor_cross_axis", "frame_mode", "mains_hum", "--jobs", "2"),
        ),
        quick_args=("--effects", "mains_hum"),
        out=("--out", "diagnosis_gain.md"),
    ),
    # after "diagnosis": its verdicts are read from that step's work folder (out/diagnosis)
    Step(
        "diagnosis_strength",
        "scripts/diagnosis_strength.py",
        args=("--jobs", "2"),
        out=("--results", "diagnosis_strength.md"),
    ),
    # the table of the saved full-size cases (each case: scripts/full_size_case.py, 10-20 min,
    # not rerun here)
    Step(
        "diagnosis_full_size",
        "scripts/full_size_table.py",
        quick_args=(),
        out=("--results", "diagnosis_full_size.md"),
    ),
    Step(
        "transfer",
        "scripts/transfer.py",
        args=("--doors", "20", "--held-out-from", "12", "--demo-seeds", "0", "1", "2"),
        quick_args=("--doors", "2", "--demo-seeds", "0"),
        out=("--results", "transfer.md"),
    ),
    # after "transfer": the doors' campaigns and fits are read from its work folder
    Step(
        "transfer_extended",
        "scripts/transfer_extend.py",
        args=("--only", "12", "13", "14", "15", "16"),
        quick_args=(),
        out=("--results", "transfer_extended.md"),
    ),
    Step(
        "diagnosis_limits",
        "scripts/diagnosis_limits.py",
        args=("--seeds", "10"),
        quick_args=("--seeds", "2"),
        out=("--results", "diagnosis_limits.md"),
    ),
    # after "diagnosis_limits": its base fit and loops are read from its work folder
    Step(
        "diagnosis_limits_hum",
        "scripts/diagnosis_limits.py",
        args=("--causes", "mains_hum", "--factors", "0.5", "1.5", "--seeds", "10"),
        quick_args=("--seeds", "2"),
        out=("--results", "diagnosis_limits_hum.md"),
    ),
    Step(
        "performance",
        "benchmarks/bench_job.py",
        args=("--warm-up",),
        quick_args=(),
        out=("--results", "performance.md"),
    ),
    Step(
        "solver_tolerance",
        "scripts/solver_tolerance.py",
        quick_args=("--speeds", "2", "--repeats", "1"),
        out=("--out-md", "solver_tolerance.md"),
    ),
    Step(
        "hum_interference",
        "scripts/hum_interference.py",
        quick_args=("--seeds", "2"),
        out=("--results", "hum_interference.md"),
    ),
    Step(
        "cwru",
        "scripts/cwru.py",
        args=(
            *("--data", "../shared/data/cwru", "--quick", "--runs-per-state", "200"),
            *("--more-seeds", "1", "2", "--extend"),
        ),
        quick_args=("--jobs", "cmaes"),
        out=("--results", "cwru.md"),
    ),
    Step(
        "decision_rule",
        "scripts/decision_rule.py",
        quick_args=("--draws", "20000"),
        out=("--results", "decision_rule.md"),
    ),
    Step(
        "order_segment",
        "scripts/order_segment.py",
        quick_args=("--campaigns", "10", "--comb-campaigns", "5"),
        out=("--results", "order_segment.md"),
    ),
    *(
        Step(name, f"benchmarks/{name}.py", ("--json",), ("--quick",) if quick else (), name)
        for name, quick in (
            ("bench_simulate", False),
            ("bench_features", False),
            ("bench_classify", False),
            ("bench_datagen", False),
            ("bench_inference", True),
            ("bench_diagnose", True),
        )
    ),
)


def run_step(step: Step, quick: bool, redirect: Path | None) -> tuple[bool, float]:
    """Run one step, its files going to the folder ``redirect`` (``None``: ``results/``);
    return whether it succeeded and its wall time."""
    cmd = step.command(quick, redirect)
    if not (ROOT / step.script).is_file():
        print(f"\n=== {step.name}: {step.script} does not exist", flush=True)
        return False, 0.0
    shown = shlex.join([Path(cmd[0]).name, *cmd[1:]])
    print(f"\n=== {step.name}: {shown}", flush=True)
    t0 = time.perf_counter()
    if step.json_to is None:
        ok = subprocess.run(cmd, cwd=ROOT).returncode == 0
    else:
        done = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.PIPE, text=True)
        ok = done.returncode == 0
        if ok:
            folder = (redirect or RESULTS) / "benchmarks"
            folder.mkdir(parents=True, exist_ok=True)
            target = folder / f"{step.json_to}{'-quick' if quick else ''}.json"
            target.write_text(done.stdout)
            print(f"    wrote {target}")
    return ok, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the small version of every step")
    parser.add_argument("--only", nargs="+", metavar="STEP", help="run only these steps")
    parser.add_argument("--list", action="store_true", help="print the steps and stop")
    parser.add_argument(
        "--results",
        type=Path,
        default=None,
        help=f"the folder of the files (default {RESULTS.relative_to(ROOT)}/; with --quick "
        f"{QUICK_RESULTS.relative_to(ROOT)}/, so that the small versions do not replace the "
        "README's figures)",
    )
    args = parser.parse_args(argv)
    names = [s.name for s in STEPS]
    unknown = sorted(set(args.only or ()) - set(names))
    if unknown:
        parser.error(f"unknown step(s) {unknown}; the steps are: {', '.join(names)}")
    results = (args.results or (QUICK_RESULTS if args.quick else RESULTS)).resolve()
    redirect = None if results == RESULTS else results  # results/: the steps' own defaults
    steps = [s for s in STEPS if args.only is None or s.name in args.only]
    if args.list:
        for s in steps:
            cmd = s.command(args.quick, redirect)
            print(f"{s.name:22s} {shlex.join(['python', *cmd[1:]])}")
        return 0
    failed = []
    for step in steps:
        ok, wall = run_step(step, args.quick, redirect)
        print(f"    {'ok' if ok else 'FAILED'} in {wall:.0f} s", flush=True)
        if not ok:
            failed.append(step.name)
    if failed:
        print(f"\nfailed steps: {', '.join(failed)}", file=sys.stderr)
        return 1
    print("\nall steps finished")
    return 0


if __name__ == "__main__":
    sys.exit(main())
