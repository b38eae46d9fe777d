"""Training-data speed: the paper's 1800 simulated door runs, the ensemble, one run to a report.

1. **Generation**: ``bayesdoor.datagen.generate`` of the paper's sizes (600 runs per state,
   healthy / D1 / D2, chunks of 100 vmapped runs, speeds 0.3 / 0.4 / 0.5 m/s, Gaussian scatter
   of 5 % around the paper's optimum), float64, in a fresh folder; the wall time includes
   compiling the solve of each state (reported apart from the chunk times) unless the
   persistent compilation cache already holds them. Baseline in the same process: the same
   solver one run at a time (``--single`` runs, after compiling). With ``--dask N`` the same
   generation again on a local Dask cluster of N worker processes (compiling in each; the
   data are checked equal to the in-process ones). With ``--compare-threads N`` the same
   generation again (compiled by then), one chunk at a time and N at a time in this process.
1b. **The cut record**: the same chunk of draws (``--cut-runs`` runs of one state) solved to
   the record's end (``GenerationConfig.record_duration``, what generation did before) and to
   just after the latest motion stop (``simulated_duration``, what it does now), alternately
   in this process: seconds per run of both and the largest difference of their features.
2. **float32 against float64**: the same draws (same key, same configuration) generated with
   ``SolverConfig(dtype="float32")``: seconds per run of both and the largest difference of
   the log10 features (decades).
3. **Training**: the 10-member ensemble (the paper's network, 80 epochs, batch 100) on the
   generated training split (1260 runs), with and without compiling; ``fit_classifier`` also
   calibrates and fits the OOD detector.
4. **One run to a report**: a 3.7 s four-channel record at 2048 Hz through ``featurize`` (its
   motion window) and ``predict`` (all members, temperature, entropies, OOD score): two jitted
   calls, against one jitted function of both (baseline: the two calls).

Timings are medians of repeated calls, each waited for with ``block_until_ready``.

Usage: python benchmarks/bench_datagen.py [--runs-per-state 600] [--chunk-size 100] [--dask 2]
    [--generation-only] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from _timing import median_s

from bayesdoor.classify import FitOptions, fit_classifier, predict
from bayesdoor.datagen import (
    Execution,
    GaussianScatter,
    GenerationConfig,
    TrainingData,
    featurize,
    generate,
)
from bayesdoor.door import DoorParameters, ElevatorDoor, SolverConfig

# float64 comes with importing bayesdoor; no persistent compilation cache (configure_jax):
# the compile overheads and the training with compiling are cold compiles on every run
SPEEDS = (0.3, 0.4, 0.5)
FS = 2048.0


def _source(door: ElevatorDoor) -> GaussianScatter:
    optimum = {k: float(v) for k, v in DoorParameters.paper_optimum().to_dict().items()}
    return GaussianScatter.around(door, optimum, 0.05)


def time_generation(
    runs_per_state: int,
    chunk_size: int,
    folder: Path,
    *,
    threads: int | None = None,
    dask_workers: int = 0,
) -> tuple[dict, TrainingData]:
    """Generate in ``folder``: in this process (``threads``), or on a local Dask cluster."""
    door = ElevatorDoor()
    config = GenerationConfig(SPEEDS, runs_per_state=runs_per_state, chunk_size=chunk_size)
    c0, t0 = time.process_time(), time.perf_counter()
    data = generate(
        door,
        _source(door),
        config,
        folder,
        key=jax.random.key(0),
        progress=False,
        execution=Execution(
            scheduler="local" if dask_workers else None,
            n_workers=max(dask_workers, 1),
            threads=threads,
        ),
    )
    wall_s = time.perf_counter() - t0
    summary = json.loads((folder / "summary.json").read_text())
    out = {
        "runs": int(data.labels.size),
        "chunk_size": chunk_size,
        "threads": summary["threads"],
        "dask_workers": dask_workers,
        "simulated_s": config.simulated_duration(door),
        "record_s": config.record_duration(door),
        "wall_s": wall_s,
        # the workers' CPU time is not counted (Dask)
        "cpu_s": time.process_time() - c0,
        "dropped_runs": int(data.dropped_run_ids.size),
    }
    chunks = np.asarray(summary["chunk_seconds"])
    if summary["threads"] == 1:
        # in index order: the first chunk of every state compiles its solve
        per_state = config.chunks_per_state
        first = chunks[::per_state]
        rest = np.delete(chunks, np.arange(0, chunks.size, per_state))
        steady = float(np.median(rest)) if rest.size else float(np.median(chunks))
        out.update(
            first_chunk_of_each_state_s=first.tolist(),
            compile_overhead_s=float(np.sum(first) - first.size * steady),
        )
    else:
        # chunks finish in any order, several at a time: the first arrival holds the compile
        steady = float(np.median(chunks[1:])) if chunks.size > 1 else float(chunks[0])
        out["first_arrival_s"] = float(chunks[0])
    out.update(steady_chunk_s=steady, steady_ms_per_run=1e3 * steady / chunk_size)
    return out, data


def compare_threads(runs_per_state: int, chunk_size: int, folder: Path, threads: int) -> dict:
    """The same generation one chunk at a time and ``threads`` at a time, after compiling."""
    out: dict[str, Any] = {}
    data = {}
    for n in (1, threads):
        timing, data[n] = time_generation(
            runs_per_state, chunk_size, folder / f"threads-{n}", threads=n
        )
        out[f"threads_{n}"] = {k: timing[k] for k in ("wall_s", "cpu_s", "steady_ms_per_run")}
    out["wall_speedup"] = out["threads_1"]["wall_s"] / out[f"threads_{threads}"]["wall_s"]
    out["data_equal"] = bool(np.array_equal(data[1].features, data[threads].features))
    return out


def compare_cut(runs: int, repeats: int = 2) -> dict:
    """The same D1 draws solved to the record's end and to just after the motion stop."""
    door = ElevatorDoor()
    config = GenerationConfig(SPEEDS, runs_per_state=runs, chunk_size=runs)
    source = _source(door)
    draws = source.sample(runs, key=jax.random.key(3))
    speeds = np.asarray(SPEEDS)[np.arange(runs) % len(SPEEDS)]
    severity = {"d1_height": np.linspace(*door.states["D1"].severity["d1_height"], runs)}
    t_start, t_stop = door.motion_window(speeds, duration=config.record_duration(door))

    def run(duration: float):
        res = door.simulate_values(draws, speeds, state="D1", severity=severity, duration=duration)
        return np.asarray(featurize(jax.block_until_ready(res.signals), FS, t_start, t_stop))

    lengths = {"record": config.record_duration(door), "cut": config.simulated_duration(door)}
    features = {name: run(duration) for name, duration in lengths.items()}  # compile both
    seconds: dict[str, list[float]] = {name: [] for name in lengths}
    for _ in range(repeats):
        for name, duration in lengths.items():
            c0 = time.process_time()
            run(duration)
            seconds[name].append(time.process_time() - c0)
    record_ms = 1e3 * float(np.median(seconds["record"])) / runs
    cut_ms = 1e3 * float(np.median(seconds["cut"])) / runs
    return {
        "runs": runs,
        "record_s": lengths["record"],
        "cut_s": lengths["cut"],
        "record_cpu_ms_per_run": record_ms,
        "cut_cpu_ms_per_run": cut_ms,
        "speedup": record_ms / cut_ms,
        "feature_max_abs_diff_decades": float(np.abs(features["record"] - features["cut"]).max()),
    }


def time_single(runs: int) -> dict:
    """The same solver one run at a time (the baseline of the vmapped chunks)."""
    door = ElevatorDoor()
    draws = _source(door).sample(runs, key=jax.random.key(1))
    duration = float(door.record_duration(np.asarray(SPEEDS)))

    def one(i: int):
        values = {k: v[i : i + 1] for k, v in draws.items()}
        res = door.simulate_values(values, np.asarray([0.4]), duration=duration)
        return jax.block_until_ready(res.signals)

    one(0)  # compile the batch-of-one solve
    t0 = time.perf_counter()
    for i in range(runs):
        one(i)
    return {"runs": runs, "ms_per_run": 1e3 * (time.perf_counter() - t0) / runs}


def compare_float32(runs_per_state: int, folder: Path) -> dict:
    """The same draws in float64 and float32: seconds per run and the feature difference."""
    out = {}
    features = {}
    for dtype in ("float64", "float32"):
        door = ElevatorDoor(config=SolverConfig(dtype=dtype))
        config = GenerationConfig(SPEEDS, runs_per_state=runs_per_state, chunk_size=runs_per_state)
        # twice: the first compiles the three states' solves
        for attempt in ("compile", "timed"):
            target = folder / f"{dtype}-{attempt}"
            t0 = time.perf_counter()
            data = generate(
                door, _source(door), config, target, key=jax.random.key(2), progress=False
            )
            seconds = time.perf_counter() - t0
        out[f"{dtype}_ms_per_run"] = 1e3 * seconds / data.labels.size
        features[dtype] = (data.run_ids, np.asarray(data.features, dtype=np.float64))
    ids64, f64 = features["float64"]
    ids32, f32 = features["float32"]
    common, i64, i32 = np.intersect1d(ids64, ids32, return_indices=True)
    diff = np.abs(f64[i64] - f32[i32])
    out.update(
        runs_compared=int(common.size),
        feature_max_abs_diff_decades=float(diff.max()),
        feature_mean_abs_diff_decades=float(diff.mean()),
        feature_p99_abs_diff_decades=float(np.quantile(diff, 0.99)),
        feature_sd_decades=float(f64.std(axis=0).mean()),
    )
    return out


def time_training(data) -> tuple[dict, object]:
    train, val = data.subset("train"), data.subset("validation")

    def fit(seed: int):
        return fit_classifier(
            train.features,
            train.labels,
            val.features,
            val.labels,
            data.states,
            key=jax.random.key(seed),
            options=FitOptions(progress="none"),
        ).ensemble

    t0 = time.perf_counter()
    ensemble = fit(0)
    first_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    fit(1)
    second_s = time.perf_counter() - t0
    c0 = time.process_time()
    fit(2)
    cpu_s = time.process_time() - c0
    return {
        "train_runs": int(train.labels.size),
        "first_call_s": first_s,
        "second_call_s": second_s,
        "cpu_s": cpu_s,
    }, ensemble


def time_one_run(ensemble, calls: int) -> dict:
    fs = 2048.0
    signals = jnp.asarray(np.random.default_rng(3).standard_normal((1, 4, round(3.7 * fs))))
    t_start, t_stop = jnp.asarray([0.25]), jnp.asarray([2.6])

    def two_calls():
        return jax.block_until_ready(predict(ensemble, featurize(signals, fs, t_start, t_stop)))

    fused = jax.jit(lambda s, a, b: predict(ensemble, featurize(s, fs, a, b)).probabilities)

    def one_call():
        return jax.block_until_ready(fused(signals, t_start, t_stop))

    two_calls()
    one_call()
    two_us = 1e6 * median_s(two_calls, calls)
    fused_us = 1e6 * median_s(one_call, calls)
    return {
        "two_jitted_calls_us": two_us,
        "one_fused_jit_us": fused_us,
        "fused_speedup": two_us / fused_us,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs-per-state", type=int, default=600)
    parser.add_argument("--chunk-size", type=int, default=100)
    parser.add_argument("--single", type=int, default=8, help="runs of the one-at-a-time baseline")
    parser.add_argument(
        "--compare-runs", type=int, default=16, help="runs per state of the float32 comparison"
    )
    parser.add_argument("--calls", type=int, default=500, help="timed one-run calls")
    parser.add_argument(
        "--cut-runs", type=int, default=100, help="runs of the record-against-cut comparison"
    )
    parser.add_argument(
        "--threads", type=int, default=None, help="threads of the generation (default: generate's)"
    )
    parser.add_argument(
        "--compare-threads",
        type=int,
        default=0,
        help="after the generation, time it again one chunk at a time and N at a time",
    )
    parser.add_argument(
        "--dask", type=int, default=0, help="also generate on a local Dask cluster of N workers"
    )
    parser.add_argument(
        "--generation-only",
        action="store_true",
        help="generation and the cut comparison only (no training, float32, one-run timings)",
    )
    parser.add_argument("--json", action="store_true", help="print the result as JSON only")
    args = parser.parse_args()

    result: dict = {"load_average_at_start": list(os.getloadavg()), "cpu_count": os.cpu_count()}
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        generation, data = time_generation(
            args.runs_per_state, args.chunk_size, tmp_path / "gen", threads=args.threads
        )
        result["generation"] = generation
        if args.compare_threads:
            result["threads_compared"] = compare_threads(
                args.runs_per_state, args.chunk_size, tmp_path / "compare", args.compare_threads
            )
        if args.dask:
            dask, dask_data = time_generation(
                args.runs_per_state, args.chunk_size, tmp_path / "dask", dask_workers=args.dask
            )
            dask["data_equal_to_in_process"] = bool(
                np.array_equal(dask_data.features, data.features)
                and np.array_equal(dask_data.run_ids, data.run_ids)
            )
            result["generation_dask"] = dask
        result["cut_record"] = compare_cut(args.cut_runs)
        if not args.generation_only:
            single = time_single(args.single)
            generation["speedup_vs_one_at_a_time"] = (
                single["ms_per_run"] / generation["steady_ms_per_run"]
            )
            training, ensemble = time_training(data)
            result.update(
                one_at_a_time=single,
                float32_vs_float64=compare_float32(args.compare_runs, tmp_path / "precision"),
                training=training,
                one_run_features_and_members=time_one_run(ensemble, args.calls),
            )
    result["load_average_at_end"] = list(os.getloadavg())
    if args.json:
        print(json.dumps(result, indent=2))
        return
    g, c = generation, result["cut_record"]
    print(
        f"generation of {g['runs']} runs (chunks of {g['chunk_size']}, {g['threads']} "
        f"thread(s)): {g['wall_s']:.1f} s wall, {g['cpu_s']:.1f} s CPU"
    )
    print(f"  steady: {g['steady_ms_per_run']:.1f} ms per run")
    if args.compare_threads:
        t = result["threads_compared"]
        print(
            f"  again, 1 thread against {args.compare_threads}: {t['wall_speedup']:.2f}x less "
            f"wall time (data equal: {t['data_equal']})"
        )
    if args.dask:
        d = result["generation_dask"]
        print(
            f"  on {d['workers']} Dask workers: {d['wall_s']:.1f} s wall "
            f"(data equal: {d['data_equal_to_in_process']})"
        )
    print(
        f"cut record ({c['cut_s']:.2f} of {c['record_s']:.2f} s): {c['cut_cpu_ms_per_run']:.1f} "
        f"against {c['record_cpu_ms_per_run']:.1f} ms CPU per run ({c['speedup']:.2f}x); "
        f"features differ by at most {c['feature_max_abs_diff_decades']:.3g} decades"
    )
    print(f"load average: {result['load_average_at_start']} -> {result['load_average_at_end']}")
    if args.generation_only:
        return
    single = result["one_at_a_time"]
    p, t, o = (
        result["float32_vs_float64"],
        result["training"],
        result["one_run_features_and_members"],
    )
    print(
        f"  one run at a time: {single['ms_per_run']:.1f} ms per run "
        f"({g['speedup_vs_one_at_a_time']:.1f}x slower than the chunks)"
    )
    print(
        f"float32: {p['float32_ms_per_run']:.1f} ms per run against {p['float64_ms_per_run']:.1f}; "
        f"features differ by at most {p['feature_max_abs_diff_decades']:.3g} decades "
        f"(mean {p['feature_mean_abs_diff_decades']:.3g})"
    )
    print(
        f"training on {t['train_runs']} runs: {t['second_call_s']:.1f} s "
        f"(first call {t['first_call_s']:.1f} s, {t['cpu_s']:.1f} s CPU)"
    )
    print(
        f"one run, features + 10 members: {o['two_jitted_calls_us']:.0f} us "
        f"(one fused jit: {o['one_fused_jit_us']:.0f} us)"
    )


if __name__ == "__main__":
    main()
