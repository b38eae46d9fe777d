"""Inference costs on the demo campaign: the log density and its gradient, NUTS and emcee ESS/s.

The problem is the one ``fit_campaign(door, load_demo_campaign(), method="nuts"|"emcee")``
samples: the features of the demo campaign's 10 healthy calibration runs (3 speeds, so one
evaluation of the exact simulator solves 3 records), the seven continuous Table 2 parameters
free, the default ``ModelError()`` (a discrepancy shared by the runs of a speed, one scale per
speed and channel, a run scatter per channel; 23 sampled dimensions) and ``FitSettings()``
(``--quick``: ``FitSettings.quick()``, 1 s of motion per run and short chains). Two
departures, so that the figures come in minutes and not after a CMA-ES run:

* the fit's CMA-ES optimum is replaced by the rig's true parameters and contact law
  (``load_demo_truth()["parameters"]``, inside the Table 2 bounds): the surrogate box, the
  sampler start and the Laplace whitening are built there exactly as ``fit_campaign`` builds
  them at its optimum (first box only: the box-moving loop is left out);
* the quadratic surrogate, the expensive part (``train_per_term`` x 36 + ``n_test`` exact
  simulations), is cached in ``bayesdoor.door.datasets.cache_dir() / "bench"`` under a hash of
  the settings, the surrogate's source and the simulated features at the 14 points of the
  fit's sensitivity test (so a change to the simulator refits it); the fit time of a cached
  surrogate is the one measured when it was fitted (``--refit-surrogate`` refits).

Then, in one process:

1. one evaluation of the log density (priors and likelihood: numpyro's potential, what both
   samplers evaluate) and of its value and gradient, jitted, warm, median of repeats with
   ``block_until_ready``, through (a) the exact diffrax simulator and (b) the surrogate;
   ratios gradient/value and exact/surrogate;
2. NUTS (numpyro) and emcee (4 independent ensembles, as the fit runs it) on the same
   surrogate model from the same start, each timed on its second call (the first compiles:
   NUTS with the same sizes, emcee with 20 steps; the timed call still re-traces its jitted
   functions, and includes building the ArviZ data): wall time, min bulk and tail ESS over
   every posterior variable (ArviZ, through ``diagnose_sampling``, whose gates the fit
   applies), ESS per second, ESS per 1000 evaluations in the kept draws (NUTS: leapfrog
   steps, each a value and gradient; emcee: walker proposals, each a value), R-hat (emcee:
   nested over ensembles), divergences, and whether the gates passed; ratio NUTS/emcee of
   ESS per second. emcee runs with the fit's settings: the fewest walkers the stretch
   move needs (``2 * ndim + 2`` per ensemble), its adaptive length (until the kept steps
   reach 50 autocorrelation times, at most ``emcee_max_steps``) and thinning 5; the steps it
   took and why it stopped are reported.

``--emcee-only`` skips the density timings and NUTS (the figures of emcee alone).

Usage: python benchmarks/bench_inference.py [--quick] [--json] [--refit-surrogate] [--emcee-only]
The exact simulator's program holds host callbacks (equinox's run-time checks), which JAX's
persistent cache never stores: its first value and gradient call compiles in every process.
Wall and process CPU times are both reported (on a shared machine CPU time is the steadier
figure), with the load average at each stage. Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import resource
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from numpyro.infer import init_to_value
from numpyro.infer.util import initialize_model

from bayesdoor import configure_jax
from bayesdoor.door import ElevatorDoor
from bayesdoor.door.datasets import cache_dir, demo_paths, load_demo_campaign, load_demo_truth
from bayesdoor.inference import (
    CalibrationData,
    Discrepancy,
    EmceeSettings,
    FitSettings,
    ModelError,
    NUTSSettings,
    QuadraticSurrogate,
    SamplingTransform,
    SimulatorForward,
    box_around,
    calibration_runs,
    campaign_data,
    diagnose_sampling,
    fit_surrogate,
    log_likelihood,
    make_model,
    sample_emcee,
    sample_nuts,
    simulate_design,
)
from bayesdoor.io import atomic_write

ROOT = Path(__file__).resolve().parent.parent
configure_jax(os.environ.get("BAYESDOOR_JAX_CACHE", ROOT / ".jax_cache"))

#: the surrogate's fitting code: a change to it refits a cached surrogate
SURROGATE_SOURCE = ROOT / "bayesdoor" / "inference" / "_surrogate.py"
#: the settings a surrogate depends on (a change to the sampler settings does not refit it)
SURROGATE_SETTINGS = ("max_motion_s", "box_fraction", "insensitive", "train_per_term", "n_test")
#: the seed fit_campaign uses by default; its surrogate design key derives from it the same way
SEED = 0


def _peak_rss_gb() -> float:
    """The process's peak resident memory so far, GB (Linux reports kB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def _log(message: str) -> None:
    stamp = f"{time.strftime('%H:%M:%S')} load {os.getloadavg()[0]:.1f} rss {_peak_rss_gb():.1f} GB"
    print(f"[{stamp}] {message}", file=sys.stderr)


@dataclasses.dataclass(frozen=True)
class Problem:
    """The demo fit's likelihood at the rig's truth, with both forward models."""

    data: CalibrationData
    exact: SimulatorForward
    surrogate: QuadraticSurrogate
    transform: SamplingTransform
    init: dict[str, jax.Array]
    law: int
    box_fractions: list[float]
    surrogate_info: dict[str, Any]


def _surrogate_path(
    settings: FitSettings, exact: SimulatorForward, truth: np.ndarray, probe: np.ndarray
) -> Path:
    """The cache file of a surrogate: a hash of what it was fitted to and how.

    The simulator enters through ``probe``, its features at the sensitivity test's points
    (each parameter at a bound, the others at the truth): a change to the simulator, the
    features or the contact laws that moves them refits the surrogate, an edit elsewhere in
    those packages does not.
    """
    digest = hashlib.sha256(SURROGATE_SOURCE.read_bytes())
    fitted = {name: getattr(settings, name) for name in SURROGATE_SETTINGS}
    setup = [fitted, exact.names, exact.fixed, exact.duration, SEED]
    digest.update(json.dumps(setup, sort_keys=True).encode())
    for values in (truth, np.asarray(exact.operating), np.round(probe, 12)):
        digest.update(np.ascontiguousarray(values, dtype=np.float64).tobytes())
    return cache_dir() / "bench" / f"bench-inference-surrogate-{digest.hexdigest()[:16]}.npz"


def _fit_or_load_surrogate(
    exact: SimulatorForward,
    box: tuple[np.ndarray, np.ndarray],
    settings: FitSettings,
    path: Path,
    refit: bool,
) -> tuple[QuadraticSurrogate, dict[str, Any]]:
    """The surrogate ``fit_campaign`` fits on its first box, from the cache when it is there."""
    if path.is_file() and not refit:
        stored = np.load(path)
        surrogate = QuadraticSurrogate(
            names=exact.names,
            operating=exact.operating,
            lower=jnp.asarray(stored["lower"]),
            upper=jnp.asarray(stored["upper"]),
            coef=jnp.asarray(stored["coef"]),
            error_variance=jnp.asarray(stored["error_variance"]),
            ridge=jnp.asarray(stored["ridge"]),
            n_train=int(stored["n_train"]),
        )
        return surrogate, {"cached": True, "path": str(path), **json.loads(str(stored["info"]))}
    d = len(exact.names)
    n_terms = 1 + d + d * (d + 1) // 2
    key_surrogate = jax.random.split(jax.random.key(SEED), 3)[0]
    t0, c0, load = time.perf_counter(), time.process_time(), os.getloadavg()[0]
    surrogate = fit_surrogate(
        exact,
        (jnp.asarray(box[0]), jnp.asarray(box[1])),
        key=jax.random.fold_in(key_surrogate, 0),
        n_train=settings.train_per_term * n_terms,
        n_test=settings.n_test,
    )
    info = {
        "fit_s": time.perf_counter() - t0,
        "fit_cpu_s": time.process_time() - c0,
        "fit_load_average": load,
        "simulations": settings.train_per_term * n_terms + settings.n_test,
        "fitted_at": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
    }

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            np.savez(
                f,
                lower=np.asarray(surrogate.lower),
                upper=np.asarray(surrogate.upper),
                coef=np.asarray(surrogate.coef),
                error_variance=np.asarray(surrogate.error_variance),
                ridge=np.asarray(surrogate.ridge),
                n_train=surrogate.n_train,
                info=json.dumps(info),
            )

    atomic_write(path, write, overwrite=True)
    return surrogate, {"cached": False, "path": str(path), **info}


def build_problem(settings: FitSettings, refit: bool) -> Problem:
    """Data, exact forward, surrogate, whitened transform and start, as ``fit_campaign``.

    The steps after CMA-ES in ``fit_campaign`` with the rig's truth for the optimum: a
    parameter whose move across its whole range changes no feature by ``settings.insensitive``
    Welch sds spans its whole range in the box, the others ``settings.box_fraction``; the
    transform is whitened at the box point nearest the truth (2 % inside each face). The
    discrepancy scales start at the RMS over bands of each speed's mean residual (floored at
    0.01 decades), the run scatter at 1 (its prior median), a simpler moment estimate than
    the fit's, shared by both samplers.
    """
    door = ElevatorDoor()
    campaign = load_demo_campaign(show_progress=False)
    truth_all = load_demo_truth(show_progress=False)["parameters"]
    data, duration = campaign_data(
        door, campaign, calibration_runs(campaign), max_motion_s=settings.max_motion_s
    )
    specs = {p.name: p for p in door.parameters}
    free = tuple(p.name for p in door.parameters if not p.integer)
    integer = next(p.name for p in door.parameters if p.integer)
    law = int(truth_all[integer])
    truth = np.array([float(truth_all[n]) for n in free])
    lower = np.array([specs[n].lower for n in free])
    upper = np.array([specs[n].upper for n in free])
    exact = SimulatorForward.build(
        door, free, {integer: float(law)}, data.operating, duration=duration
    )
    # the fit's sensitivity test: each parameter moved to its two bounds, the others at truth
    ends = np.repeat(truth[None], 2 * len(free), axis=0)
    ends[2 * np.arange(len(free)), np.arange(len(free))] = lower
    ends[2 * np.arange(len(free)) + 1, np.arange(len(free))] = upper
    end_features, _ = simulate_design(exact, jnp.asarray(ends), chunk=2 * len(free))
    reach = np.max(np.abs(end_features[0::2] - end_features[1::2]), axis=(1, 2, 3))
    welch_sd = float(np.sqrt(np.median(np.asarray(data.welch_variance))))
    fractions = np.where(reach < settings.insensitive * welch_sd, 1.0, settings.box_fraction)
    box = box_around(
        jnp.asarray(truth), jnp.asarray(lower), jnp.asarray(upper), jnp.asarray(fractions)
    )
    surrogate, info = _fit_or_load_surrogate(
        exact, box, settings, _surrogate_path(settings, exact, truth, end_features), refit
    )
    _log(f"surrogate {'loaded' if info['cached'] else 'fitted'} ({info['fit_s']:.0f} s to fit)")

    sim = np.asarray(exact(jnp.asarray(truth)).features)[np.asarray(data.run_operating)]
    residual = np.asarray(data.y) - sim
    index = np.asarray(data.run_operating)
    means = np.stack([residual[index == o].mean(axis=0) for o in range(data.operating.shape[0])])
    sigma = jnp.asarray(np.maximum(np.sqrt(np.mean(means**2, axis=-1)), 0.01))
    rho = jnp.ones(data.y.shape[1])
    inside = box[0] + np.clip((truth - box[0]) / (box[1] - box[0]), 0.02, 0.98) * (box[1] - box[0])

    def density(theta):
        return log_likelihood(theta, Discrepancy(sigma, run_scatter=rho), data, surrogate)

    transform = SamplingTransform.box(free, box[0].tolist(), box[1].tolist()).whitened_at(
        density, jnp.asarray(inside)
    )
    init = {
        "z": transform.to_sampling(jnp.asarray(inside)),
        "sigma_operating": sigma,
        "run_scatter": rho,
    }
    info["heldout_rms"] = float(np.sqrt(np.mean(np.asarray(surrogate.error_variance))))
    return Problem(data, exact, surrogate, transform, init, law, fractions.tolist(), info)


def _median_time(fn: Callable, arg: Any, repeats: int) -> tuple[float, float]:
    """Median wall and process CPU seconds of ``fn(arg)``, each call waited for."""
    walls, cpus = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        jax.block_until_ready(fn(arg))
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return float(np.median(walls)), float(np.median(cpus))


def time_density(model: Callable, init: dict, repeats: int) -> dict[str, Any]:
    """Seconds per log density, and per value and gradient, at the start point."""
    info = initialize_model(
        jax.random.key(0),
        model,
        init_strategy=init_to_value(values={k: jnp.asarray(v) for k, v in init.items()}),
    )
    z = info.param_info.z
    value = jax.jit(info.potential_fn)
    both = jax.jit(jax.value_and_grad(info.potential_fn))
    out: dict[str, Any] = {"repeats": repeats}
    for name, fn in (("value", value), ("value_and_grad", both)):
        t0 = time.perf_counter()
        first = jax.block_until_ready(fn(z))
        out[f"first_{name}_s"] = time.perf_counter() - t0
        out[f"{name}_s"], out[f"{name}_cpu_s"] = _median_time(fn, z, repeats)
        out["finite"] = out.get("finite", True) and all(
            bool(np.all(np.isfinite(x))) for x in jax.tree_util.tree_leaves(first)
        )
    out["log_density"] = -float(value(z))
    return out


def _sampler_settings(settings: FitSettings) -> dict[str, dict[str, Any]]:
    """The fit's sampler sizes, as ``fit_campaign`` passes them."""
    return {
        "nuts": {
            "num_warmup": settings.num_warmup,
            "num_samples": settings.num_samples,
            "num_chains": settings.num_chains,
            "target_accept": settings.target_accept,
        },
        "emcee": {
            "n_walkers": settings.emcee_walkers,
            "n_steps": settings.emcee_steps,
            "max_steps": settings.emcee_max_steps,
            "burn": settings.emcee_burn,
            "thin": settings.emcee_thin,
            "init_scale": 0.1,
        },
    }


def time_samplers(
    model: Callable, init: dict, settings: FitSettings, names: tuple[str, ...]
) -> dict[str, Any]:
    """ESS per second and per evaluation of NUTS and emcee, each after a compiling call.

    NUTS's compiled loop depends on its sizes, so its first call has the timed call's sizes;
    emcee's compiled density depends on the walkers only, so its first call takes 20 steps.
    """
    ndim = sum(int(np.size(v)) for v in init.values())
    out: dict[str, Any] = {}
    for name, kw in _sampler_settings(settings).items():
        if name not in names:
            continue
        sampler = sample_nuts if name == "nuts" else sample_emcee
        record = NUTSSettings if name == "nuts" else EmceeSettings
        first = kw if name == "nuts" else {**kw, "n_steps": 20, "burn": 0, "thin": 1}
        walls, cpus = [], []
        for seed, sizes in enumerate((first, kw)):
            t0, c0 = time.perf_counter(), time.process_time()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                idata = sampler(
                    model,
                    key=jax.random.key(seed),
                    init_values=init,
                    settings=record(**sizes),
                    progress=False,
                )
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
            _log(f"{name} call {seed + 1}: {walls[-1]:.1f} s wall, {cpus[-1]:.1f} s CPU")
        diag = diagnose_sampling(idata, warn=False)
        stats = idata["sample_stats"]
        if name == "nuts":
            evaluations = int(np.sum(stats["n_steps"].values))
            per_draw = evaluations / stats["n_steps"].size
        else:
            evaluations = int(stats["lp"].shape[0]) * int(stats.attrs["kept_steps"])
            per_draw = evaluations / stats["lp"].size
        out[name] = {
            "settings": {k: v for k, v in kw.items() if k != "init_values"},
            "dimensions": ndim,
            "first_call_s": walls[0],
            "first_call": "same sizes" if name == "nuts" else "20 steps",
            "wall_s": walls[1],
            "cpu_s": cpus[1],
            "draws": diag.draws,
            "min_ess_bulk": diag.ess_bulk_min,
            "worst_bulk": diag.ess_bulk_worst,
            "min_ess_tail": diag.ess_tail_min,
            "worst_tail": diag.ess_tail_worst,
            "ess_bulk_per_s": diag.ess_bulk_min / walls[1],
            "ess_tail_per_s": diag.ess_tail_min / walls[1],
            "ess_bulk_per_cpu_s": diag.ess_bulk_min / cpus[1],
            "kept_evaluations": evaluations,
            "evaluations_per_draw": per_draw,
            "ess_bulk_per_1000_evaluations": 1e3 * diag.ess_bulk_min / evaluations,
            "rhat_max": diag.rhat_max,
            "rhat_worst": diag.rhat_worst,
            "rhat_method": diag.rhat_method,
            "divergences": diag.divergences,
            "autocorr_lengths": diag.autocorr_lengths,
            "walkers": int(stats["lp"].shape[0]),
            "total_steps": int(stats.attrs["total_steps"]) if name == "emcee" else None,
            "stopped": stats.attrs["stopped"] if name == "emcee" else None,
            "gates_passed": diag.passed,
            "gate_messages": list(diag.messages),
            "load_average": os.getloadavg()[0],
            "peak_rss_gb": _peak_rss_gb(),
        }
    return out


def run(quick: bool, refit: bool, emcee_only: bool = False) -> dict[str, Any]:
    """Every figure of the benchmark, as one JSON-ready dict."""
    settings = FitSettings.quick() if quick else FitSettings()
    load = os.getloadavg()
    t_start = time.perf_counter()
    problem = build_problem(settings, refit)
    _log("problem built")
    error = ModelError()
    models = {
        name: make_model(problem.data, forward, problem.transform, error)
        for name, forward in (("exact", problem.exact), ("surrogate", problem.surrogate))
    }
    repeats = {"exact": 3 if quick else 5, "surrogate": 50 if quick else 200}
    densities = {}
    for name, model in models.items() if not emcee_only else ():
        densities[name] = time_density(model, problem.init, repeats[name])
        densities[name]["load_average"] = os.getloadavg()[0]
        densities[name]["peak_rss_gb"] = _peak_rss_gb()
        _log(f"{name} density timed: {json.dumps(densities[name])}")
    names = ("emcee",) if emcee_only else ("nuts", "emcee")
    samplers = time_samplers(models["surrogate"], problem.init, settings, names)
    n_op = int(problem.data.operating.shape[0])
    result: dict[str, Any] = {
        "quick": quick,
        "emcee_only": emcee_only,
        "load_average_at_start": load,
        "load_average_at_end": os.getloadavg(),
        "total_s": time.perf_counter() - t_start,
        "problem": {
            "campaign": demo_paths()[0].name,
            "runs": int(problem.data.y.shape[0]),
            "operating_points": np.asarray(problem.data.operating).tolist(),
            "features": int(np.prod(problem.data.y.shape)),
            "free": list(problem.exact.names),
            "law": problem.law,
            "duration_s": problem.exact.duration,
            "box_fractions": problem.box_fractions,
            "centre": "rig truth (load_demo_truth), in place of the CMA-ES optimum",
        },
        "surrogate": problem.surrogate_info,
        "density": densities,
        "samplers": samplers,
        "devices": [str(d) for d in jax.devices()],
    }
    if densities:
        result["exact_per_simulated_operating_point"] = {
            k: densities["exact"][k] / n_op for k in ("value_s", "value_and_grad_s")
        }
        result["ratio_grad_over_value"] = {
            k: v["value_and_grad_s"] / v["value_s"] for k, v in densities.items()
        }
        result["ratio_exact_over_surrogate"] = {
            k: densities["exact"][k] / densities["surrogate"][k]
            for k in ("value_s", "value_and_grad_s")
        }
    if "nuts" in samplers:
        result["ratio_nuts_over_emcee"] = {
            k: samplers["nuts"][k] / samplers["emcee"][k]
            for k in ("ess_bulk_per_s", "ess_tail_per_s", "ess_bulk_per_1000_evaluations")
        }
    return result


def _print(result: dict[str, Any]) -> None:
    p, s = result["problem"], result["surrogate"]
    print(
        f"{p['runs']} calibration runs at {p['operating_points']} m/s ({p['features']} "
        f"features, {p['duration_s']:.2f} s records), law {p['law']}, centre: {p['centre']}"
    )
    print(
        f"load average {result['load_average_at_start'][0]:.1f} at the start, "
        f"{result['load_average_at_end'][0]:.1f} at the end; {result['total_s']:.0f} s in all"
    )
    print(
        f"surrogate: {'cached' if s['cached'] else 'fitted now'}, {s['simulations']} simulations "
        f"fitted in {s['fit_s']:.0f} s (load {s['fit_load_average']:.1f}), held-out RMS "
        f"{s['heldout_rms']:.3f} decades"
    )
    for name, d in result["density"].items():
        print(
            f"  log density, {name}: {1e3 * d['value_s']:.3g} ms, value and gradient "
            f"{1e3 * d['value_and_grad_s']:.3g} ms (x{result['ratio_grad_over_value'][name]:.1f}); "
            f"first calls {d['first_value_s']:.1f} s and {d['first_value_and_grad_s']:.1f} s"
        )
    if result["density"]:
        per_op = result["exact_per_simulated_operating_point"]
        print(
            f"  exact, per simulated speed: {1e3 * per_op['value_s']:.0f} ms, value and gradient "
            f"{1e3 * per_op['value_and_grad_s']:.0f} ms; exact/surrogate value and gradient "
            f"x{result['ratio_exact_over_surrogate']['value_and_grad_s']:.0f}"
        )
    for name, v in result["samplers"].items():
        verdict = "gates PASSED" if v["gates_passed"] else "GATES FAILED (not converged)"
        div = "" if v["divergences"] is None else f", {v['divergences']} divergences"
        print(
            f"  {name}: {v['wall_s']:.1f} s (first call {v['first_call_s']:.1f} s); min ESS bulk "
            f"{v['min_ess_bulk']:.0f} ({v['worst_bulk']}), tail {v['min_ess_tail']:.0f} = "
            f"{v['ess_bulk_per_s']:.1f} bulk ESS/s, {v['ess_bulk_per_1000_evaluations']:.2f} per "
            f"1000 evaluations; R-hat {v['rhat_max']:.3f} ({v['rhat_method']}){div}; {verdict}"
        )
        if v["stopped"] is not None:
            print(
                f"      {v['walkers']} walkers, {v['total_steps']} steps (stopped: "
                f"{v['stopped']}), {v['autocorr_lengths']:.1f} autocorrelation times kept"
            )
        for message in v["gate_messages"]:
            print(f"      ! {message}")
    if "ratio_nuts_over_emcee" in result:
        r = result["ratio_nuts_over_emcee"]
        print(
            f"  NUTS/emcee: bulk ESS/s x{r['ess_bulk_per_s']:.2f}, tail ESS/s "
            f"x{r['ess_tail_per_s']:.2f}, bulk ESS per evaluation x"
            f"{r['ess_bulk_per_1000_evaluations']:.1f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="FitSettings.quick() sizes")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument(
        "--refit-surrogate", action="store_true", help="fit the surrogate even when cached"
    )
    parser.add_argument(
        "--emcee-only", action="store_true", help="time emcee alone (no densities, no NUTS)"
    )
    ns = parser.parse_args()
    result = run(ns.quick, ns.refit_surrogate, ns.emcee_only)
    if ns.json:
        print(json.dumps(result, indent=2))
    else:
        _print(result)


if __name__ == "__main__":
    main()
