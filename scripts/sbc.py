"""Simulation-based calibration of the door posterior, on data from the reduced model itself.

Where the model is exact, a correct likelihood, parameterisation and sampler give ranks of the
true parameters among posterior draws that are uniform (Talts et al. 2018). The problem:

- the reduced door (``ElevatorDoor()``), contact law 6; free ``K``, ``C`` and ``mu_d`` with the
  uniform Table 2 prior (``SamplingTransform.from_specs``), every other parameter fixed at the
  paper's optimum;
- ``--runs`` runs (default 2) at one speed (``--speed``, 0.5 m/s), records of ``--duration``
  seconds (1.0: 0.25 s rest and 0.75 s of motion, 5 Welch segments), the default features
  (4 to 96 Hz in 4 Hz bands, 96 per run);
- the library's likelihood and priors as they are (``make_model`` with the default
  ``ModelError()``: a discrepancy per channel shared by the runs, and a run scatter per
  channel), so the ranked scalars are ``K``, ``C``, ``mu_d``, ``sigma_model[c]`` and
  ``run_scatter[c]``;
- each data set one joint draw of the model's prior predictive (``run_sbc``): parameters from
  the prior, then features from the likelihood around the simulated features;
- the posterior by ``sample_nuts`` (``--chains`` x (``--warmup`` + ``--samples``)), ranks
  among 99 draws thinned evenly over the chains, uniformity by chi-square and KS per scalar
  at a family-wise level of 0.01 (Bonferroni).

``--forward exact`` (default) simulates through diffrax in every likelihood and gradient
evaluation: this checks the simulator's gradients too, and costs about 0.1 to 0.3 s per
gradient. ``--forward surrogate`` replaces the simulator, for data and fit alike, by a
quadratic surrogate fitted to the exact simulator on the whole prior box (``fit_surrogate``);
the model is then exact for the surrogate, and the check covers the likelihood, the transform
and the sampler but not the simulator's gradients.

The data sets are independent: ``--workers`` processes (default one per core) each fit one at
a time with XLA on one thread, writing ``dataset_NNN.json`` into ``--work`` as it finishes;
a rerun skips the data sets already there (so a run cut off by a time limit resumes). The
report (``results/sbc.md`` and ``results/sbc_ranks.png`` unless ``--report`` says otherwise)
is written from every data set found in ``--work`` once all ``--n-datasets`` are there.

Usage::

    .venv/bin/python scripts/sbc.py [--forward exact|surrogate] [--n-datasets 20]
        [--workers W] [--work DIR] [--report FILE.md] [--seed N]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from _cases import code_version, write_results

ROOT = Path(__file__).resolve().parent.parent
FREE = ("K", "C", "mu_d")
LAW = 6
N_RANK_DRAWS = 99


def _configure_jax() -> None:
    os.environ.setdefault("JAX_PLATFORMS", "cpu")  # small solves: the CPU, one per process
    from bayesdoor import configure_jax

    configure_jax(ROOT / ".jax_cache")


def build_problem(settings: dict):
    """The calibration structure, the forward model and the transform of the SBC problem.

    The measured features of ``CalibrationData`` are placeholders (the nominal door's): every
    SBC data set replaces them by its own prior-predictive draw; what is used is the
    structure (runs, operating points, the Welch variance of each run's window).
    """
    import jax
    import numpy as np

    from bayesdoor.door import DoorParameters, ElevatorDoor
    from bayesdoor.inference import (
        CalibrationData,
        SamplingTransform,
        SimulatorForward,
        fit_surrogate,
    )

    door = ElevatorDoor()
    values = {k: float(v) for k, v in DoorParameters.paper_optimum().to_dict().items()}
    values["I"] = LAW
    ops = np.full(settings["runs"], settings["speed"])
    nominal = door.simulate_values(values, ops, duration=settings["duration"])
    t_start, t_stop = door.motion_window(ops, duration=settings["duration"])
    data = CalibrationData.from_signals(
        np.asarray(nominal.signals), door.sampling_rate_hz, ops, t_start, t_stop
    )
    fixed = {k: v for k, v in values.items() if k not in FREE}
    forward = SimulatorForward.build(
        door, FREE, fixed, data.operating, duration=settings["duration"]
    )
    transform = SamplingTransform.from_specs(door.parameters, FREE)
    if settings["forward"] == "surrogate":
        forward = fit_surrogate(
            forward,
            (np.asarray(transform.lower), np.asarray(transform.upper)),
            key=jax.random.key(settings["seed"] + 1),
            n_train=80,
            n_test=32,
            chunk=16,
        )
    return data, forward, transform


def fit_datasets(indices: list[int], settings: dict, forward) -> list[dict]:
    """Worker: simulate and fit the data sets ``indices``; each saved as soon as it is done."""
    _configure_jax()
    import jax

    from bayesdoor.inference import (
        NUTSSettings,
        SBCDesign,
        make_model,
        run_sbc,
        sample_nuts,
        save_sbc,
    )

    data, exact, transform = build_problem({**settings, "forward": "exact"})
    model = make_model(data, forward if forward is not None else exact, transform)
    work = Path(settings["work"])

    def fit(kwargs, *, key):
        return sample_nuts(
            model,
            key=key,
            model_kwargs=kwargs,
            settings=NUTSSettings(
                num_warmup=settings["warmup"],
                num_samples=settings["samples"],
                num_chains=settings["chains"],
                jit_model_args=True,
            ),
            progress=False,
        )

    records = []
    for index in indices:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = run_sbc(
                model,
                key=jax.random.key(settings["seed"]),
                design=SBCDesign(settings["n_datasets"], N_RANK_DRAWS, datasets=[index]),
                fit=fit,
                var_names=[*FREE, "sigma_model", "run_scatter"],
            )
        save_sbc(result, work / f"dataset_{index:03d}.json", overwrite=True)
        records.append({"dataset": index, "seconds": float(result.seconds[0])})
    return records


def report(settings: dict, result, elapsed: float, surrogate_rms: float | None) -> str:
    """The Markdown of ``results/sbc.md``."""
    import numpy as np

    test = result.uniformity()
    lines = [
        "# Simulation-based calibration of the door posterior",
        "",
        "Command: `.venv/bin/python scripts/sbc.py " + settings["argv"] + "`  ",
        f"Date: {time.strftime('%Y-%m-%d')}  ",
        f"Code: {code_version()}",
        "",
        f"- forward model: **{settings['forward']}**"
        + (
            f" (quadratic surrogate of the reduced door on the whole prior box, 80 training "
            f"and 32 held-out simulations, held-out RMS {surrogate_rms:.4f} decades; data and "
            "fit both use it, so the model is exact for it)"
            if settings["forward"] == "surrogate"
            else " (every likelihood and gradient evaluation a diffrax solve of the reduced door)"
        ),
        f"- free parameters {', '.join(FREE)} (uniform Table 2 prior), the rest at the paper's "
        f"optimum, contact law {LAW}",
        f"- {settings['runs']} runs at {settings['speed']} m/s, {settings['duration']} s records, "
        "default features (96 per run), default `ModelError()`",
        f"- NUTS: {settings['chains']} chains x ({settings['warmup']} warm-up + "
        f"{settings['samples']} draws); ranks among {result.n_rank_draws} draws thinned evenly",
        f"- {test.n_datasets} data sets (seed {settings['seed']}), {test.bins} rank bins, "
        f"family-wise level {test.alpha} over {2 * len(test.names)} tests (Bonferroni)",
        f"- wall time {elapsed / 60:.1f} min for the data sets fitted in this call; fit time per "
        f"data set median {np.median(result.seconds):.0f} s (range "
        f"{result.seconds.min():.0f} to {result.seconds.max():.0f} s)",
        f"- data sets whose fit passed the sampling gates: {int(result.gates_passed.sum())} of "
        f"{test.n_datasets}; smallest bulk ESS over the ranked scalars: median "
        f"{np.median(result.ess_bulk):.0f}, minimum {result.ess_bulk.min():.0f} (ranks need "
        f"about {result.n_rank_draws} independent draws)",
        "",
        f"**Verdict: {'ranks consistent with uniform' if test.passed else 'RANKS NOT UNIFORM'}**",
        "",
        "| scalar | chi2 p | KS p | mean rank (0.5) | spread (1) | counts per bin |",
        "|---|---|---|---|---|---|",
    ]
    for i, name in enumerate(test.names):
        lines.append(
            f"| {name} | {test.chi2_pvalue[i]:.3f} | {test.ks_pvalue[i]:.3f} | "
            f"{test.mean_rank[i]:.3f} | {test.spread[i]:.2f} | "
            f"{' '.join(str(c) for c in test.counts[i])} |"
        )
    lines += [f"- {m}" for m in test.messages]
    lines += [
        "",
        "![rank histograms](sbc_ranks.png)",
        "",
        "With 20 data sets the test only detects gross miscalibration (a posterior about half "
        "or twice as wide as it should be, or a bias of about half a posterior sd); "
        "`tests/test_sbc.py` shows on a conjugate target with 120 data sets that it rejects a "
        "likelihood whose noise sd is halved.",
        "",
    ]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--forward", choices=("exact", "surrogate"), default="exact")
    parser.add_argument("--n-datasets", type=int, default=20)
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--speed", type=float, default=0.5)
    parser.add_argument("--duration", type=float, default=1.0)
    parser.add_argument("--chains", type=int, default=2)
    parser.add_argument("--warmup", type=int, default=300)
    parser.add_argument("--samples", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=None, help="default: one per CPU core")
    parser.add_argument("--work", type=Path, default=None, help="default: results/sbc_<forward>")
    parser.add_argument("--report", type=Path, default=ROOT / "results" / "sbc.md")
    args = parser.parse_args()
    workers = args.workers or os.cpu_count() or 1
    if args.n_datasets < 10:
        parser.error(f"--n-datasets={args.n_datasets}: the uniformity test needs at least 10")
    work = args.work or ROOT / "results" / f"sbc_{args.forward}"
    settings = {
        "forward": args.forward,
        "n_datasets": args.n_datasets,
        "runs": args.runs,
        "speed": args.speed,
        "duration": args.duration,
        "chains": args.chains,
        "warmup": args.warmup,
        "samples": args.samples,
        "seed": args.seed,
        "work": str(work),
        "argv": " ".join(sys.argv[1:]),
    }
    # read by XLA when a worker starts its backend: one compute thread per worker process
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "")
        + " --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    ).strip()
    _configure_jax()
    import numpy as np

    from bayesdoor.inference import SBCResult, load_sbc, plot_sbc_ranks

    work.mkdir(parents=True, exist_ok=True)
    config = work / "settings.json"
    fixed_settings = {k: v for k, v in settings.items() if k not in ("work", "argv")}
    if config.exists() and json.loads(config.read_text()) != fixed_settings:
        parser.error(
            f"{work} holds data sets of other settings ({config}); pass another --work or remove it"
        )
    config.write_text(json.dumps(fixed_settings, indent=1))
    todo = [i for i in range(args.n_datasets) if not (work / f"dataset_{i:03d}.json").exists()]
    started = time.perf_counter()
    forward, surrogate_rms = None, None
    if args.forward == "surrogate":
        _, forward, _ = build_problem(settings)
        surrogate_rms = float(np.sqrt(np.mean(np.asarray(forward.error_variance))))
        print(f"surrogate fitted, held-out RMS {surrogate_rms:.4f} decades", file=sys.stderr)
    print(f"{len(todo)} of {args.n_datasets} data sets to fit, {workers} workers", file=sys.stderr)
    if todo:
        with ProcessPoolExecutor(
            min(workers, len(todo)), mp_context=multiprocessing.get_context("spawn")
        ) as pool:
            futures = [pool.submit(fit_datasets, [i], settings, forward) for i in todo]
            for future in as_completed(futures):
                for record in future.result():
                    print(
                        f"data set {record['dataset']}: {record['seconds']:.0f} s "
                        f"({time.perf_counter() - started:.0f} s elapsed)",
                        file=sys.stderr,
                    )
    elapsed = time.perf_counter() - started
    result = SBCResult.concatenate(
        [load_sbc(work / f"dataset_{i:03d}.json") for i in range(args.n_datasets)]
    )
    test = result.uniformity()
    print(test, file=sys.stderr)
    figure = args.report.with_name(args.report.stem + "_ranks.png")
    plot_sbc_ranks(result, figure, title=f"SBC, reduced door ({args.forward})")
    write_results(
        args.report,
        report(settings, result, elapsed, surrogate_rms).replace("sbc_ranks.png", figure.name),
        echo=False,
    )
    print(json.dumps({"passed": test.passed, "report": str(args.report)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
