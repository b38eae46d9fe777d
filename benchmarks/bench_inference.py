"""Inference costs: likelihood and gradient, NUTS and emcee ESS per second, CMA-ES on the demo.

All figures in one process, so the ratios compare like with like on this machine:

1. one evaluation of the log density (priors and likelihood, numpyro's potential) and of its
   value and gradient, through the diffrax simulator (the reduced door, the seven continuous
   Table 2 parameters free, contact law 6, 2 runs at 0.5 m/s, 1 s records) and through a
   quadratic surrogate of it (+-25 % box around the paper's optimum); ratios gradient/value
   and exact/surrogate;
2. NUTS and emcee (independent ensembles) on the same surrogate likelihood, started at the
   truth: smallest bulk ESS over the parameters and model-error scales per second of wall
   time (the second call of each, so compilation is mostly cached; the first call's time is
   reported too); ratio NUTS/emcee;
3. CMA-ES on the paper's J over the 10 calibration runs of the demo campaign
   (``fit_campaign(method="cmaes")``, law searched): wall time, evaluations, and the time
   until J came within 1 % of its final best (from the history, at the mean cost of an
   evaluation).

Usage: python benchmarks/bench_inference.py [--quick] [--json]
(``--quick``: fewer repeats, shorter chains, ``FitSettings.quick()`` for CMA-ES: 120
evaluations on 1 s of motion per run). Wall and process CPU times are both reported: on a
shared machine the CPU time is the steadier figure. Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from numpyro.infer.util import initialize_model

from bayesdoor.inference import (
    CalibrationData,
    SamplingTransform,
    SimulatorForward,
    box_around,
    diagnose_sampling,
    fit_campaign,
    fit_surrogate,
    make_model,
    sample_emcee,
    sample_nuts,
)
from bayesdoor.systems import DoorParameters, ElevatorDoor

jax.config.update("jax_enable_x64", True)
jax.config.update(
    "jax_compilation_cache_dir",
    os.environ.get(
        "BAYESDOOR_JAX_CACHE", str(Path(__file__).resolve().parent.parent / ".jax_cache")
    ),
)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)

SPEED, RUNS, DURATION, LAW = 0.5, 2, 1.0, 6


def problem():
    """Data simulated at the paper's optimum (plus 1e-3 m/s^2 sensor noise), both forwards."""
    door = ElevatorDoor()
    truth = {k: float(v) for k, v in DoorParameters.paper_optimum().to_dict().items()}
    free = tuple(p.name for p in door.parameters if not p.integer)
    ops = np.full(RUNS, SPEED)
    signals = np.asarray(door.simulate_values(truth, ops, duration=DURATION).signals)
    signals = signals + 1e-3 * np.random.default_rng(0).standard_normal(signals.shape)
    t_start, t_stop = door.motion_window(ops, duration=DURATION)
    data = CalibrationData.from_signals(signals, door.sampling_rate_hz, ops, t_start, t_stop)
    fixed = {"I": float(LAW)}
    exact = SimulatorForward.build(door, free, fixed, data.operating, duration=DURATION)
    specs = {p.name: p for p in door.parameters}
    centre = np.array([truth[n] for n in free])
    lo, hi = box_around(
        centre, [specs[n].lower for n in free], [specs[n].upper for n in free], 0.25
    )
    t0 = time.perf_counter()
    surrogate = fit_surrogate(exact, lo, hi, key=jax.random.key(1), n_train=72, n_test=16)
    fit_s = time.perf_counter() - t0
    return data, exact, surrogate, SamplingTransform.box(free, lo, hi), centre, fit_s


def _median_time(fn, arg, repeats: int) -> tuple[float, float]:
    """Median wall and process CPU seconds of ``fn(arg)`` after a first (compiling) call."""
    jax.block_until_ready(fn(arg))
    walls, cpus = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        jax.block_until_ready(fn(arg))
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return float(np.median(walls)), float(np.median(cpus))


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def time_density(model, init: dict, repeats: int) -> dict:
    """Seconds per log density, and per value and gradient, at the unconstrained ``init``."""
    info = initialize_model(jax.random.key(0), model, init_strategy=_init_to(init))
    z = info.param_info.z
    value = jax.jit(info.potential_fn)
    both = jax.jit(jax.value_and_grad(info.potential_fn))
    t0 = time.perf_counter()
    jax.block_until_ready(both(z))
    compile_s = time.perf_counter() - t0
    v, g = both(z)
    finite = bool(np.isfinite(v)) and all(
        bool(np.all(np.isfinite(x))) for x in jax.tree_util.tree_leaves(g)
    )
    value_s, value_cpu = _median_time(value, z, repeats)
    both_s, both_cpu = _median_time(both, z, repeats)
    return {
        "value_s": value_s,
        "value_cpu_s": value_cpu,
        "value_and_grad_s": both_s,
        "value_and_grad_cpu_s": both_cpu,
        "first_value_and_grad_s": compile_s,
        "finite": finite,
    }


def _init_to(values: dict):
    from numpyro.infer import init_to_value

    return init_to_value(values={k: jnp.asarray(v) for k, v in values.items()})


def time_samplers(model, init: dict, quick: bool) -> dict:
    """ESS per second of NUTS and emcee on ``model``, each called twice (the second timed)."""
    nuts_kw = (
        dict(num_warmup=200, num_samples=200, num_chains=2)
        if quick
        else dict(num_warmup=500, num_samples=500, num_chains=4)
    )
    emcee_kw = (
        dict(n_walkers=32, n_ensembles=4, n_steps=1500, burn=500)
        if quick
        else dict(n_walkers=32, n_ensembles=4, n_steps=6000, burn=1000)
    )
    out = {}
    for name, sampler, kw in (
        ("nuts", sample_nuts, nuts_kw),
        ("emcee", sample_emcee, {**emcee_kw, "init_scale": 0.1}),
    ):
        walls, cpus = [], []
        for seed in (0, 1):
            t0, c0 = time.perf_counter(), time.process_time()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                idata = sampler(
                    model, key=jax.random.key(seed), init_values=init, progress=False, **kw
                )
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
            _log(f"{name} call {seed + 1}: {walls[-1]:.1f} s wall, {cpus[-1]:.1f} s CPU")
        # the parameters (deterministic sites), model-error scales and run scatters
        names = [v for v in idata.posterior.data_vars if v != "z"]
        diag = diagnose_sampling(idata, var_names=names, warn=False)
        out[name] = {
            "settings": {k: v for k, v in kw.items()},
            "first_call_s": walls[0],
            "wall_s": walls[1],
            "cpu_s": cpus[1],
            "min_ess_bulk": diag.ess_bulk_min,
            "worst": diag.ess_bulk_worst,
            "rhat_max": diag.rhat_max,
            "rhat_method": diag.rhat_method,
            "gates_passed": diag.passed,
            "ess_per_s": diag.ess_bulk_min / walls[1],
            "ess_per_cpu_s": diag.ess_bulk_min / cpus[1],
        }
    return out


def time_cmaes(quick: bool) -> dict:
    """CMA-ES on J over the demo campaign's calibration runs (the law searched too)."""
    from bayesdoor.datasets import load_demo_campaign

    campaign = load_demo_campaign(show_progress=False)
    door = ElevatorDoor()
    t0, c0 = time.perf_counter(), time.process_time()
    result = fit_campaign(door, campaign, method="cmaes", seed=0, quick=quick, progress=False)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    _log(f"CMA-ES: {wall:.0f} s wall, {cpu:.0f} s CPU")
    c = result.cmaes
    h = c.history
    final = float(c.f_best)
    reached = np.flatnonzero(h.best_f <= final + 0.01 * abs(final))
    evals_to_1pct = int(h.evaluations[reached[0]]) if reached.size else int(c.evaluations)
    per_eval = result.timings["cmaes"] / c.evaluations
    return {
        "quick": quick,
        "wall_s": wall,
        "cpu_s": cpu,
        "cmaes_s": result.timings["cmaes"],
        "features_s": result.timings["features"],
        "evaluations": int(c.evaluations),
        "restarts": int(c.restarts),
        "j_best": final,
        "law": result.law,
        "s_per_evaluation": per_eval,
        "evaluations_to_within_1pct": evals_to_1pct,
        "s_to_within_1pct": evals_to_1pct * per_eval,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--skip-cmaes", action="store_true", help="leave out part 3")
    ns = parser.parse_args()
    repeats = 5 if ns.quick else 20
    load = os.getloadavg()
    data, exact, surrogate, transform, truth, surrogate_fit_s = problem()
    _log(f"problem built, surrogate fitted in {surrogate_fit_s:.0f} s")
    # the default ModelError: discrepancy scales per operating point and channel
    sigma0 = jnp.full((data.operating.shape[0], data.y.shape[1]), 0.05)
    init = {"z": transform.to_sampling(jnp.asarray(truth)), "sigma_operating": sigma0}
    densities = {
        name: time_density(make_model(data, forward, transform), init, repeats)
        for name, forward in (("exact", exact), ("surrogate", surrogate))
    }
    _log(f"densities timed: {json.dumps(densities)}")
    samplers = time_samplers(make_model(data, surrogate, transform), init, ns.quick)
    cmaes = None if ns.skip_cmaes else time_cmaes(ns.quick)
    result = {
        "quick": ns.quick,
        "load_average_at_start": load,
        "load_average_at_end": os.getloadavg(),
        "problem": {
            "free": list(exact.names),
            "runs": RUNS,
            "speed": SPEED,
            "duration_s": DURATION,
            "features": int(np.prod(data.y.shape)),
        },
        "surrogate_fit_s": surrogate_fit_s,
        "surrogate_heldout_rms": float(np.sqrt(np.mean(np.asarray(surrogate.error_variance)))),
        "density": densities,
        "ratio_grad_over_value": {
            k: v["value_and_grad_s"] / v["value_s"] for k, v in densities.items()
        },
        "ratio_exact_over_surrogate_value_and_grad": densities["exact"]["value_and_grad_s"]
        / densities["surrogate"]["value_and_grad_s"],
        "samplers": samplers,
        "ratio_nuts_over_emcee_ess_per_s": samplers["nuts"]["ess_per_s"]
        / samplers["emcee"]["ess_per_s"],
        "cmaes": cmaes,
        "devices": [str(d) for d in jax.devices()],
    }
    if ns.json:
        print(json.dumps(result, indent=2))
        return
    print(f"load average {load[0]:.1f} at the start")
    for k, v in densities.items():
        print(
            f"  log density, {k}: {1e3 * v['value_s']:.2f} ms, value and gradient "
            f"{1e3 * v['value_and_grad_s']:.2f} ms (x{result['ratio_grad_over_value'][k]:.1f})"
        )
    for k, v in samplers.items():
        print(
            f"  {k}: min bulk ESS {v['min_ess_bulk']:.0f} in {v['wall_s']:.1f} s = "
            f"{v['ess_per_s']:.1f} ESS/s (first call {v['first_call_s']:.1f} s)"
        )
    if cmaes is not None:
        print(
            f"  CMA-ES: {cmaes['evaluations']} evaluations in {cmaes['cmaes_s']:.0f} s, within "
            f"1 % of J = {cmaes['j_best']:.4f} after {cmaes['s_to_within_1pct']:.0f} s"
        )


if __name__ == "__main__":
    main()
