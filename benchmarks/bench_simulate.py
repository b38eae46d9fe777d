"""Simulation speed: vmapped diffrax batches (float64, float32) against scipy's LSODA.

All timings are taken in one process, so the ratios compare like with like on this machine.
The scipy baseline integrates the *same equations* (the numpy branch of the door's right-hand
side) with ``solve_ivp(method="LSODA")``.

``--steps`` reports instead where a batched solve's time goes (steps, rejected steps, the
batch's lock-step waste, the right-hand side's share).

Usage: python benchmarks/bench_simulate.py [--batch 64] [--duration 3.5] [--json] [--steps]
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp

from bayesdoor.door import (
    DoorDamage,
    DoorParameters,
    SolverConfig,
    initial_state,
    make_args,
    rhs,
    sample_times,
    solve,
)
from bayesdoor.door._simulate import solve_batch

# float64 comes with importing bayesdoor; no persistent compilation cache (configure_jax):
# compile_s is a cold compile on every run


def _batch_args(batch: int, v_max: float, dtype):
    rng = np.random.default_rng(0)
    opt = {k: np.asarray(v) for k, v in DoorParameters.paper_optimum().to_dict().items()}
    opt["K"] = rng.uniform(1600.0, 2100.0, batch)
    opt["n"] = rng.uniform(1.7, 2.1, batch)
    opt["C"] = rng.uniform(0.008, 0.02, batch)
    params = DoorParameters(
        **{k: jnp.broadcast_to(jnp.asarray(v), (batch,)) for k, v in opt.items()}
    )
    damage = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (batch,)), DoorDamage.healthy())
    v = jnp.full((batch,), v_max)
    return jax.vmap(lambda p, d, s: make_args(p, d, s, dtype=dtype))(params, damage, v)


def time_batch(batch: int, duration: float, dtype: str, repeats: int = 2) -> dict:
    jdtype = jnp.float32 if dtype == "float32" else jnp.float64
    config = SolverConfig(dtype=dtype)
    args = _batch_args(batch, 0.3, jdtype)
    ts = sample_times(duration, dtype=jdtype)
    t0 = time.perf_counter()
    compiled = solve_batch.lower(args, ts, config).compile()
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        signals, status = compiled(args, ts, config)
        signals.block_until_ready()
        times.append(time.perf_counter() - t0)
    return {
        "dtype": dtype,
        "batch": batch,
        "compile_s": compile_s,
        "ms_per_run": 1e3 * min(times) / batch,
        "failed_runs": int(np.sum(np.asarray(status) != 0)),
    }


#: new right-hand-side evaluations per Tsit5 step (seven stages, the first shared with the
#: last of the step before)
TSIT5_EVALS_PER_STEP = 6


def _counted_solve(ts, config: SolverConfig, coeffs: tuple[float, float] | None = None):
    """The door's solve saving the states at ``ts``, with diffrax's step counts; the
    controller's proportional and integral coefficients ``coeffs`` (``None``: the config's;
    (0, 1): an integral controller)."""
    pcoeff, icoeff = (config.pcoeff, config.icoeff) if coeffs is None else coeffs
    import diffrax

    def one(b):
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(lambda t, y, c: rhs(t, y, c, jnp)),
            diffrax.Tsit5(),
            ts[0],
            ts[-1],
            None,
            initial_state(b),
            b,
            saveat=diffrax.SaveAt(ts=ts),
            stepsize_controller=diffrax.PIDController(
                rtol=config.rtol, atol=config.absolute_tolerance, pcoeff=pcoeff, icoeff=icoeff
            ),
            max_steps=config.max_steps,
            throw=False,
        )
        return sol.ys, sol.stats["num_steps"], sol.stats["num_rejected_steps"]

    return jax.jit(jax.vmap(one))


def _best_ms(f, *args, repeats: int = 2) -> float:
    jax.block_until_ready(f(*args))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(f(*args))
        times.append(time.perf_counter() - t0)
    return 1e3 * min(times)


def where_steps_go(batch: int, duration: float, evaluations: int = 2000) -> dict:
    """Where a batched float64 solve spends its time, per run of the batch.

    - steps (accepted and rejected; the vmapped batch steps as long as its slowest member);
    - one right-hand side's cost, timed alone (``evaluations`` vmapped evaluations of the
      batch in one compiled loop), and its share: slowest member's steps x evaluations per
      step x cost, against the solve's time;
    - the sensors' share: the project's solve against the same solve returning the states
      (the sensors evaluate the accelerations again at every sample);
    - the default step controller (``SolverConfig``'s coefficients: 0 and 1, integral)
      against a proportional-integral one (0.4 and 0.3; or the integral one, when the
      default is another): steps, time, and each one's largest state error against a solve
      at rtol 1e-8, atol 1e-11.
    """
    config = SolverConfig()
    args = _batch_args(batch, 0.3, jnp.float64)
    ts = sample_times(duration)
    default = _counted_solve(ts, config)
    states, total, rejected = (np.asarray(x) for x in default(args))
    y0 = jax.vmap(initial_state)(args)

    @jax.jit
    def loop(y, a):
        def body(i, y):
            d = jax.vmap(lambda yy, b: rhs(i * 1e-4, yy, b, jnp))(y, a)
            return y + 1e-9 * d

        return jax.lax.fori_loop(0, evaluations, body, y)

    rhs_us = 1e3 * _best_ms(loop, y0, args) / (evaluations * batch)
    sensors = jax.jit(jax.vmap(lambda a: solve(a, ts, config)))
    only_states = jax.jit(jax.vmap(lambda a: solve(a, ts, config, output="states")))
    sensors_ms = _best_ms(sensors, args) / batch
    states_ms = _best_ms(only_states, args) / batch
    rhs_ms = float(total.max()) * TSIT5_EVALS_PER_STEP * rhs_us / 1e3
    reference = np.asarray(
        _counted_solve(ts, SolverConfig(rtol=1e-8, atol=1e-11, max_steps=400_000))(args)[0]
    )
    other_coeffs = (0.4, 0.3) if (config.pcoeff, config.icoeff) == (0.0, 1.0) else (0.0, 1.0)
    other = _counted_solve(ts, config, other_coeffs)
    o_states, o_total, o_rejected = (np.asarray(x) for x in other(args))
    return {
        "batch": batch,
        "steps_per_run": {
            "min": int(total.min()),
            "mean": float(total.mean()),
            "max": int(total.max()),
        },
        "rejected_per_run": float(rejected.mean()),
        "rejected_share": float(rejected.sum() / total.sum()),
        "lock_step_waste": float(total.max() / total.mean() - 1.0),
        "rhs_us_per_evaluation": rhs_us,
        "solve_ms_per_run": sensors_ms,
        "rhs_share_of_solve": rhs_ms / sensors_ms,
        "states_only_ms_per_run": states_ms,
        "sensors_share_of_solve": 1.0 - states_ms / sensors_ms,
        "controller": {
            f"pcoeff/icoeff {config.pcoeff:g}/{config.icoeff:g} (default)": {
                "steps_per_run": float(total.mean()),
                "rejected_per_run": float(rejected.mean()),
                "states_ms_per_run": _best_ms(default, args) / batch,
                "max_state_error": float(np.max(np.abs(states - reference))),
            },
            "pcoeff/icoeff {:g}/{:g}".format(*other_coeffs): {
                "steps_per_run": float(o_total.mean()),
                "rejected_per_run": float(o_rejected.mean()),
                "states_ms_per_run": _best_ms(other, args) / batch,
                "max_state_error": float(np.max(np.abs(o_states - reference))),
            },
        },
    }


def time_scipy(duration: float) -> dict:
    args = make_args(DoorParameters.paper_optimum(), DoorDamage.healthy(), 0.3)
    y0 = np.asarray(initial_state(args))
    args_np = jax.tree_util.tree_map(np.asarray, args)
    ts = np.asarray(sample_times(duration))
    t0 = time.perf_counter()
    sol = solve_ivp(
        lambda t, y: rhs(t, y, args_np, np),
        (0.0, ts[-1]),
        y0,
        method="LSODA",
        t_eval=ts,
        rtol=1e-5,
        atol=1e-8,
    )
    elapsed = time.perf_counter() - t0
    return {
        "method": "LSODA",
        "ms_per_run": 1e3 * elapsed,
        "nfev": int(sol.nfev),
        "ok": bool(sol.success),
    }


def time_single(duration: float) -> dict:
    args = make_args(DoorParameters.paper_optimum(), DoorDamage.healthy(), 0.3)
    ts = sample_times(duration)
    solve(args, ts, SolverConfig())[0].block_until_ready()
    t0 = time.perf_counter()
    solve(args, ts, SolverConfig())[0].block_until_ready()
    return {"ms_per_run": 1e3 * (time.perf_counter() - t0)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--duration", type=float, default=3.5)
    parser.add_argument("--json", action="store_true")
    parser.add_argument(
        "--steps", action="store_true", help="only where a batched solve's time goes"
    )
    ns = parser.parse_args()
    if ns.steps:
        print(json.dumps(where_steps_go(ns.batch, ns.duration), indent=2))
        return
    f64 = time_batch(ns.batch, ns.duration, "float64")
    f32 = time_batch(ns.batch, ns.duration, "float32")
    single = time_single(ns.duration)
    ref = time_scipy(ns.duration)
    result = {
        "duration_s": ns.duration,
        "batched_float64": f64,
        "batched_float32": f32,
        "single_float64": single,
        "scipy": ref,
        "speedup_float64_vs_scipy": ref["ms_per_run"] / f64["ms_per_run"],
        "speedup_float32_vs_scipy": ref["ms_per_run"] / f32["ms_per_run"],
        "devices": [str(d) for d in jax.devices()],
    }
    if ns.json:
        print(json.dumps(result, indent=2))
        return
    print(f"per {ns.duration} s run, batch of {ns.batch}:")
    for r in (f64, f32):
        print(
            f"  diffrax Tsit5 {r['dtype']}: {r['ms_per_run']:.1f} ms/run "
            f"(compile {r['compile_s']:.1f} s, failed {r['failed_runs']})"
        )
    print(f"  diffrax single run float64: {single['ms_per_run']:.1f} ms")
    print(f"  scipy LSODA, numpy rhs: {ref['ms_per_run']:.0f} ms/run ({ref['nfev']} rhs calls)")
    print(f"  speed-up float64 batch vs scipy: {result['speedup_float64_vs_scipy']:.0f}x")
    print(f"  speed-up float32 batch vs scipy: {result['speedup_float32_vs_scipy']:.0f}x")


if __name__ == "__main__":
    main()
