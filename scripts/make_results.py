"""Regenerate everything in ``results/`` with one command.

Each step is one script or benchmark of this repository, run as its own process, in the order
below; the table files are written by the scripts themselves (each names the command that made
it at its top), the benchmarks' JSON goes to ``results/benchmarks/``. Nothing is edited by hand
afterwards: ``results/performance.md`` discusses the figures and points at those JSON files.

Usage::

    .venv/bin/python scripts/make_results.py            # everything (hours on a 2-core CPU)
    .venv/bin/python scripts/make_results.py --quick    # the small versions (minutes)
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
BENCH_OUT = ROOT / "results" / "benchmarks"


@dataclass(frozen=True)
class Step:
    """One producer of results: its name, script, arguments, and what ``--quick`` adds."""

    name: str
    script: str
    args: tuple[str, ...] = ()
    quick_args: tuple[str, ...] = ("--quick",)
    json_to: str | None = None  # benchmarks: stdout (JSON) saved under results/benchmarks/

    def command(self, quick: bool) -> list[str]:
        args = [*self.args, *(self.quick_args if quick else ())]
        return [sys.executable, self.script, *args]


STEPS: tuple[Step, ...] = (
    Step("contact_laws", "scripts/contact_laws.py", quick_args=()),
    Step("contact_law_ablation", "scripts/contact_law_ablation.py"),
    Step(
        "sbc",
        "scripts/sbc.py",
        args=("--forward", "surrogate", "--n-datasets", "20"),
        quick_args=(),
    ),
    Step(
        "classification",
        "scripts/classification.py",
        args=("--seeds", "0", "1", "2", "3", "4"),
        quick_args=("--fit-evals", "300", "--fit-motion", "1.5", "--runs-per-state", "200"),
    ),
    Step("diagnosis", "scripts/diagnosis.py"),
    Step("diagnosis_gain", "scripts/diagnosis_gain.py"),
    Step("diagnosis_strength", "scripts/diagnosis_strength.py"),
    # the table of the saved full-size cases (each case: scripts/full_size_case.py, 10-20 min,
    # not rerun here)
    Step("diagnosis_full_size", "scripts/full_size_table.py", quick_args=()),
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


def run_step(step: Step, quick: bool) -> tuple[bool, float]:
    """Run one step; return whether it succeeded and its wall time."""
    cmd = step.command(quick)
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
            BENCH_OUT.mkdir(parents=True, exist_ok=True)
            target = BENCH_OUT / f"{step.json_to}{'-quick' if quick else ''}.json"
            target.write_text(done.stdout)
            print(f"    wrote {target.relative_to(ROOT)}")
    return ok, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the small version of every step")
    parser.add_argument("--only", nargs="+", metavar="STEP", help="run only these steps")
    parser.add_argument("--list", action="store_true", help="print the steps and stop")
    args = parser.parse_args(argv)
    names = [s.name for s in STEPS]
    unknown = sorted(set(args.only or ()) - set(names))
    if unknown:
        parser.error(f"unknown step(s) {unknown}; the steps are: {', '.join(names)}")
    steps = [s for s in STEPS if args.only is None or s.name in args.only]
    if args.list:
        for s in steps:
            print(f"{s.name:22s} {shlex.join(['python', *s.command(args.quick)[1:]])}")
        return 0
    failed = []
    for step in steps:
        ok, wall = run_step(step, args.quick)
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
