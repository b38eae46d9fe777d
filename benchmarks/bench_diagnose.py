"""``bayesdoor diagnose`` on 12 runs: wall time against the 10-minute target, stage by stage.

The campaign is 12 healthy runs of the virtual rig at speeds spread over 0.25-0.5 m/s with a
hidden frame mode (``FrameMode.from_seed(0)``), so that the diagnosis has a candidate to refit
(the expensive path). The command is timed as a user runs it: the base fit (CMA-ES), the
posterior-predictive simulations and residual features, the refits and the report. The
baseline is the base fit inside the same call (the diagnosis's own ``timings["fit"]``, what
``bayesdoor fit --method cmaes`` computes): the ratio says what the diagnosis costs next to a
fit. Recording the rig campaign is not counted.

Usage: python benchmarks/bench_diagnose.py [--runs 12] [--quick] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from bayesdoor import configure_jax

# as the command line sets JAX up: the cache of $BAYESDOOR_JAX_CACHE or ./.jax_cache
configure_jax()

#: the target for 12 runs on the 2-core development machine
TARGET_S = 600.0


def record(runs: int, seed: int):
    from bayesdoor.door.rig import Effects, FrameMode, VirtualRig

    speeds = np.linspace(0.25, 0.5, runs)
    rig = VirtualRig(effects=Effects(frame_mode=FrameMode.from_seed(seed)))
    return rig.record(["healthy"] * runs, speeds, key=jax.random.key(seed))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=12)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="the command's --quick sizes")
    parser.add_argument("--json", action="store_true", help="print the result as JSON only")
    args = parser.parse_args()

    from typer.testing import CliRunner

    from bayesdoor.cli import app
    from bayesdoor.io import save_campaign

    t0 = time.perf_counter()
    campaign = record(args.runs, args.seed)
    record_s = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "rig.nc"
        save_campaign(campaign, path)
        options = ["--seed", str(args.seed), *(["--quick"] if args.quick else [])]
        t0 = time.perf_counter()
        result = CliRunner().invoke(
            app, ["diagnose", str(path), "--out", str(Path(tmp) / "diag"), "--json", *options]
        )
        diagnose_s = time.perf_counter() - t0
        if result.exception is not None and not isinstance(result.exception, SystemExit):
            raise result.exception
        if result.exit_code != 0:
            raise SystemExit(f"bayesdoor diagnose failed: {result.output}")
        payload = json.loads(result.stdout)
    stages = payload.get("timings", {})
    fit_s = float(stages.get("fit", float("nan")))
    out = {
        "runs": args.runs,
        "quick": args.quick,
        "record_s": record_s,
        "diagnose_s": diagnose_s,
        "stages_s": stages,
        "baseline_fit_s": fit_s,
        "diagnose_over_fit": diagnose_s / fit_s,
        "target_s": TARGET_S,
        "fraction_of_target": diagnose_s / TARGET_S,
        "verdict": payload["verdict"],
        "load_average": os.getloadavg()[0],
        "cpus": os.cpu_count(),
    }
    if args.json:
        print(json.dumps(out, indent=2))
        return
    print(f"recorded {args.runs} rig runs in {record_s:.0f} s (not counted)")
    print(
        f"bayesdoor diagnose{' --quick' if args.quick else ''}: {diagnose_s:.0f} s "
        f"({100 * diagnose_s / TARGET_S:.0f} % of the {TARGET_S:.0f} s target), "
        f"verdict {payload['verdict']}"
    )
    for stage, seconds in out["stages_s"].items():
        print(f"  {stage:10s} {seconds:7.1f} s")
    print(
        f"baseline, the base fit inside it: {fit_s:.0f} s; diagnose / fit = "
        f"{diagnose_s / fit_s:.2f}"
    )
    print(f"load average {out['load_average']:.1f} on {out['cpus']} CPUs")


if __name__ == "__main__":
    main()
