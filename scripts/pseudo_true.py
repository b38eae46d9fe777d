"""The reduced model's best parameters on many rig runs against the rig's own values.

CMA-ES (the exact simulator, the paper's J) on every healthy run of the demo campaign: its 10
calibration runs and its 100 held-out test runs, all recorded by the virtual rig at one set of
true parameters. With 11 times the calibration data, an optimum that stays where the 10-run
fit put it is the reduced model's pseudo-true value (the best the model can do against the
rig), not noise; J is also evaluated at the rig's values for comparison.

Usage: ``python scripts/pseudo_true.py [--out FILE.json]`` (about 4 min on 2 idle cores).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

import bayesdoor
from bayesdoor.door import ElevatorDoor
from bayesdoor.door.datasets import load_demo_campaign, load_demo_truth
from bayesdoor.features import objective_j
from bayesdoor.inference import (
    FitProblem,
    FitSettings,
    campaign_data,
    fit_campaign,
    run_features,
)

ROOT = Path(__file__).resolve().parent.parent


def j_at(door: ElevatorDoor, campaign, point: dict[str, float]) -> float:
    """Mean J over every run of ``campaign`` at ``point`` (the system's batch simulation)."""
    runs = np.arange(campaign.sizes["run"])
    data, duration = campaign_data(door, campaign, runs, max_motion_s=FitSettings().max_motion_s)
    ops = np.asarray(data.operating)
    values = {p.name: np.full(ops.size, point[p.name]) for p in door.parameters}
    result = door.simulate_values(values, ops, duration=duration)
    t_start, t_stop = door.motion_window(ops, duration=duration)
    features, _ = run_features(result.signals, door.sampling_rate_hz, t_start, t_stop)
    sim = np.asarray(features)[np.asarray(data.run_operating)]
    return float(np.mean(objective_j(sim, data.y)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    args = parser.parse_args()
    bayesdoor.configure_jax(ROOT / ".jax_cache")
    campaign = load_demo_campaign()
    truth = load_demo_truth()["parameters"]
    healthy = campaign.isel(run=np.flatnonzero(campaign["state"].values == "healthy"))
    healthy["split"] = ("run", np.full(healthy.sizes["run"], "calibration"))
    door = ElevatorDoor()
    t0 = time.perf_counter()
    fit = fit_campaign(
        door,
        healthy,
        method="cmaes",
        problem=FitProblem(fixed={"I": truth["I"]}),
        progress=True,
        seed=0,
    )
    wall = time.perf_counter() - t0
    rig = {p.name: float(truth[p.name]) for p in door.parameters}
    j_truth = j_at(door, healthy, rig)
    print(
        f"CMA-ES on {len(fit.runs)} healthy runs in {wall:.0f} s: J {fit.j:.4f} (J at the "
        f"rig's values {j_truth:.4f})"
    )
    print("| parameter | rig | best on 110 runs | relative |")
    print("|---|---|---|---|")
    for name in fit.names:
        print(
            f"| {name} | {rig[name]:.5g} | {fit.point[name]:.5g} | "
            f"{100 * (fit.point[name] / rig[name] - 1):+.1f} % |"
        )
    if args.out is not None:
        record = dict(
            point=fit.point,
            j=fit.j,
            j_truth=j_truth,
            runs=len(fit.runs),
            truth=rig,
            wall_s=wall,
            timings=fit.timings,
            jax=jax.__version__,
        )
        args.out.write_text(json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
