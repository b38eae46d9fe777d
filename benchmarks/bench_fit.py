"""Model-updating times on the demo campaign: the CMA-ES stage and the default NUTS posterior.

The targets on a 2-core machine: CMA-ES on the 10 calibration runs within 3 minutes, the
default posterior (R-hat <= 1.01 and bulk ESS >= 400 for every parameter) within 15 minutes.
All figures come from one process, so the ratio in 1 compares like with like under load:

1. the cost of one CMA-ES population (12 candidates, law searched, at the campaign's three
   speeds) evaluated the former way (chunks of 10 candidates, so 12 padded to 20, full
   3.64 s records, one thread) and as now (one chunk per worker, records up to
   ``simulation_horizon``, ``FitSettings.workers`` threads): wall and CPU seconds per
   candidate, each after a compiling call, median of three; ratio old/new. Both through the
   public simulator (``ElevatorDoor.simulate_values``, ``run_features``, ``objective_j``),
   the computation ``fit_campaign`` does per population;
2. ``fit_campaign(method="cmaes")`` with the default ``FitSettings`` (seed 0): the CMA-ES
   stage's wall time (compilation included: the persistent cache is used as the CLI uses
   it), the process CPU time of the fit, evaluations, stop reasons, J and the point;
3. ``fit_campaign(method="nuts")`` with the default ``FitSettings``: every stage's wall
   time, the total, and the sampling gates.

Usage: python benchmarks/bench_fit.py [--quick] [--json] [--skip-nuts]
(``--quick``: ``FitSettings.quick()`` for 2 and 3, minutes, not converged). Progress goes to
stderr; on a shared machine the CPU times and the ratio are the steadier figures.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np

from bayesdoor import configure_jax
from bayesdoor.door import ElevatorDoor
from bayesdoor.door.datasets import demo_paths, load_demo_campaign
from bayesdoor.features import objective_j
from bayesdoor.inference import (
    FeatureSpec,
    FitSettings,
    calibration_runs,
    campaign_data,
    fit_campaign,
    run_features,
)
from bayesdoor.inference._population import simulation_horizon

ROOT = Path(__file__).resolve().parent.parent
configure_jax(os.environ.get("BAYESDOOR_JAX_CACHE", ROOT / ".jax_cache"))

#: pycma's first population with the law searched (8 variables, one integer)
POPULATION = 12
#: the chunk every batch was padded to in the former batching
OLD_CHUNK = 10


def _log(message: str) -> None:
    print(f"{time.strftime('%H:%M:%S')} load {os.getloadavg()[0]:.1f} {message}", file=sys.stderr)


def population_cost(door: ElevatorDoor, campaign, workers: int) -> dict[str, Any]:
    """Seconds per candidate of one population, the old way and the new way (see 1 above)."""
    runs = calibration_runs(campaign)
    spec = FeatureSpec()
    data, duration = campaign_data(door, campaign, runs, spec=spec)
    horizon = simulation_horizon(door, data, duration, spec)
    ops = np.asarray(data.operating)
    t_start, t_stop = door.motion_window(ops, duration=duration)
    names = [p.name for p in door.parameters]
    lower = np.array([p.lower for p in door.parameters])
    upper = np.array([p.upper for p in door.parameters])
    integer = [i for i, p in enumerate(door.parameters) if p.integer]

    def features(x, record):
        values = {n: jnp.repeat(x[:, i], ops.size) for i, n in enumerate(names)}
        speeds = jnp.tile(jnp.asarray(ops), x.shape[0])
        sim = door.simulate_values(values, speeds, duration=record, check=False)
        f, _ = run_features(
            sim.signals,
            door.sampling_rate_hz,
            jnp.tile(jnp.asarray(t_start), x.shape[0]),
            jnp.tile(jnp.asarray(t_stop), x.shape[0]),
            spec,
        )
        return f.reshape(x.shape[0], ops.size, *f.shape[1:])

    compiled = {r: jax.jit(features, static_argnums=1) for r in (duration, horizon)}

    def evaluate(x, chunk, record, threads):
        blocks = [x[s : s + chunk] for s in range(0, len(x), chunk)]
        padded = [np.concatenate([b, np.repeat(b[-1:], chunk - len(b), axis=0)]) for b in blocks]
        out: list[Any] = [None] * len(padded)

        def one(i):
            out[i] = np.asarray(compiled[record](jnp.asarray(padded[i]), record))

        if threads > 1:
            pool = [threading.Thread(target=one, args=(i,)) for i in range(len(padded))]
            for t in pool:
                t.start()
            for t in pool:
                t.join()
        else:
            for i in range(len(padded)):
                one(i)
        sim = np.concatenate(out)[: len(x)][:, np.asarray(data.run_operating)]
        return np.asarray(objective_j(jnp.asarray(sim), data.y[None])).mean(axis=-1)

    rng = np.random.default_rng(0)

    def draw():
        x = lower + rng.uniform(size=(POPULATION, lower.size)) * (upper - lower)
        x[:, integer] = np.round(x[:, integer])
        return x

    chunk_new = -(-POPULATION // workers)
    ways = {
        "old": dict(chunk=OLD_CHUNK, record=duration, threads=1),
        "new": dict(chunk=chunk_new, record=horizon, threads=workers),
    }
    out: dict[str, Any] = {
        "candidates": POPULATION,
        "speeds": ops.tolist(),
        "record_s": duration,
        "horizon_s": horizon,
        "workers": workers,
    }
    first = draw()
    js = {}
    for name, way in ways.items():
        t0 = time.perf_counter()
        evaluate(first, way["chunk"], way["record"], 1)  # compiles, one thread
        out[f"{name}_first_call_s"] = time.perf_counter() - t0
        js[name] = evaluate(first, **way)
    for name, way in ways.items():
        walls, cpus = [], []
        for _ in range(3):
            x = draw()
            t0, c0 = time.perf_counter(), time.process_time()
            evaluate(x, **way)
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
        out[f"{name}_s_per_candidate"] = float(np.median(walls)) / POPULATION
        out[f"{name}_cpu_s_per_candidate"] = float(np.median(cpus)) / POPULATION
        _log(f"population, {name} way: {np.median(walls):.2f} s wall, {np.median(cpus):.2f} s CPU")
    out["ratio_old_over_new"] = out["old_s_per_candidate"] / out["new_s_per_candidate"]
    out["ratio_old_over_new_cpu"] = out["old_cpu_s_per_candidate"] / out["new_cpu_s_per_candidate"]
    # the same J up to the solver's tolerance: the horizon drops only samples no segment uses,
    # but the batch size moves the adaptive solver's round-off
    out["max_abs_j_difference"] = float(np.max(np.abs(js["old"] - js["new"])))
    return out


def time_fit(
    door: ElevatorDoor, campaign, method: Literal["cmaes", "nuts"], settings: FitSettings
) -> dict[str, Any]:
    """One ``fit_campaign`` call: stage times, process CPU, CMA-ES figures, gates."""
    t0, c0, load = time.perf_counter(), time.process_time(), os.getloadavg()[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_campaign(door, campaign, method=method, seed=0, progress=False, settings=settings)
    out: dict[str, Any] = {
        "method": method,
        "wall_s": time.perf_counter() - t0,
        "cpu_s": time.process_time() - c0,
        "load_average_at_start": load,
        "load_average_at_end": os.getloadavg()[0],
        "timings": fit.timings,
        "held": fit.held,
        "j": fit.j,
        "point": fit.point,
        "cmaes": {
            "f_best": fit.cmaes.f_best,
            "evaluations": fit.cmaes.evaluations,
            "restarts": fit.cmaes.restarts,
            "stop": list(fit.cmaes.stop),
            "s_per_evaluation": fit.timings["cmaes"] / fit.cmaes.evaluations,
        },
    }
    if fit.diagnostics is not None:
        d = fit.diagnostics
        out["gates"] = {
            "passed": d.passed,
            "rhat_max": d.rhat_max,
            "ess_bulk_min": d.ess_bulk_min,
            "divergences": d.divergences,
            "messages": list(d.messages),
        }
        out["notes"] = list(fit.notes)
    _log(f"{method} fit: {out['wall_s']:.0f} s wall, {out['cpu_s']:.0f} s CPU, {fit.timings}")
    return out


def run(quick: bool, skip_nuts: bool) -> dict[str, Any]:
    """Every figure of the benchmark, as one JSON-ready dict."""
    settings = FitSettings.quick() if quick else FitSettings()
    door = ElevatorDoor()
    campaign = load_demo_campaign(show_progress=False)
    result: dict[str, Any] = {
        "quick": quick,
        "campaign": demo_paths()[0].name,
        "load_average_at_start": os.getloadavg(),
        "cpu_count": os.cpu_count(),
    }
    result["population"] = population_cost(door, campaign, settings.workers)
    result["cmaes"] = time_fit(door, campaign, "cmaes", settings)
    if not skip_nuts:
        result["nuts"] = time_fit(door, campaign, "nuts", settings)
    result["load_average_at_end"] = os.getloadavg()
    return result


def _print(result: dict[str, Any]) -> None:
    p = result["population"]
    print(
        f"{result['campaign']}; load average {result['load_average_at_start'][0]:.1f} at the "
        f"start, {result['load_average_at_end'][0]:.1f} at the end ({result['cpu_count']} CPUs)"
    )
    print(
        f"one population of {p['candidates']} at {p['speeds']} m/s, per candidate: old "
        f"{p['old_s_per_candidate']:.3f} s ({p['old_cpu_s_per_candidate']:.3f} s CPU; chunks of "
        f"{OLD_CHUNK}, {p['record_s']:.2f} s records, 1 thread), new "
        f"{p['new_s_per_candidate']:.3f} s ({p['new_cpu_s_per_candidate']:.3f} s CPU; "
        f"{p['horizon_s']:.2f} s records, {p['workers']} threads): "
        f"x{p['ratio_old_over_new']:.2f} wall, x{p['ratio_old_over_new_cpu']:.2f} CPU; "
        f"J differs by {p['max_abs_j_difference']:.1e}"
    )
    for method in ("cmaes", "nuts"):
        if method not in result:
            continue
        f = result[method]
        c = f["cmaes"]
        stages = ", ".join(f"{k} {v:.0f} s" for k, v in f["timings"].items())
        print(
            f"{method}: {f['wall_s']:.0f} s wall, {f['cpu_s']:.0f} s CPU (load "
            f"{f['load_average_at_start']:.1f} -> {f['load_average_at_end']:.1f}); {stages}"
        )
        print(
            f"  CMA-ES: {c['evaluations']} evaluations, {c['restarts']} restarts, stop "
            f"{c['stop']}, J {f['j']:.5f}, held {f['held']}, {c['s_per_evaluation']:.3f} s per "
            "evaluation"
        )
        if "gates" in f:
            g = f["gates"]
            print(
                f"  gates {'passed' if g['passed'] else 'FAILED'}: R-hat max {g['rhat_max']:.4f},"
                f" bulk ESS min {g['ess_bulk_min']:.0f}, divergences {g['divergences']}"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="FitSettings.quick() sizes")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument("--skip-nuts", action="store_true", help="time the CMA-ES fit only")
    ns = parser.parse_args()
    result = run(ns.quick, ns.skip_nuts)
    if ns.json:
        print(json.dumps(result, indent=2, default=float))
    else:
        _print(result)


if __name__ == "__main__":
    main()
