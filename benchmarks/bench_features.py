"""Feature speed: Welch PSD + CNN input in JAX (after compile) against scipy.signal.welch.

One 3.5 s run of 4 channels at 2048 Hz (7168 samples, 27 Welch segments of 512), and a batch
of runs. The JAX function returns the full PSD and the 4 x 25 log-PSD CNN input; the scipy
baseline computes the same PSD with ``scipy.signal.welch`` and takes log10 of its first 25
bins. All timings are medians over many calls in one process, each call waited for with
``block_until_ready``, so the ratios compare like with like on this machine.

Usage: python benchmarks/bench_features.py [--calls 2000] [--batch 64] [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.signal
from _timing import median_s

from bayesdoor.features import cnn_input, segment_weights, welch_psd

# float64 comes with importing bayesdoor; no persistent compilation cache (configure_jax):
# compile_s is a cold compile on every run

FS = 2048.0
N_TIME = 7168  # 3.5 s


def _features(x, weights=None):
    _, psd = welch_psd(x, FS, segment_weights=weights)
    return psd, cnn_input(x, FS, segment_weights=weights)


def _scipy_features(x):
    _, psd = scipy.signal.welch(x, FS, nperseg=512)
    return psd, np.log10(psd[..., :25])


def time_jax(x: np.ndarray, calls: int, weights=None) -> dict:
    xj = jnp.asarray(x)
    args = (xj,) if weights is None else (xj, weights)
    t0 = time.perf_counter()
    compiled = jax.jit(_features).lower(*args).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(*args))
    median = median_s(lambda: jax.block_until_ready(compiled(*args)), calls)
    return {"compile_s": compile_s, "median_ms": 1e3 * median}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=2000, help="timed calls per measurement")
    parser.add_argument("--batch", type=int, default=64, help="runs in the batched measurement")
    parser.add_argument("--json", action="store_true", help="print the result as JSON only")
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    one = rng.standard_normal((4, N_TIME))
    batch = rng.standard_normal((args.batch, 4, N_TIME))
    batch_calls = max(10, args.calls // args.batch)

    single = time_jax(one, args.calls)
    scipy_single_ms = 1e3 * median_s(lambda: _scipy_features(one), args.calls)
    window = segment_weights(N_TIME, FS, 0.25, 2.4)
    windowed = time_jax(one, args.calls, window)
    batched = time_jax(batch, batch_calls)
    scipy_batch_ms = 1e3 * median_s(lambda: _scipy_features(batch), batch_calls)

    psd, features = jax.jit(_features)(jnp.asarray(one))
    ref_psd, ref_features = _scipy_features(one)
    result = {
        "device": jax.devices()[0].device_kind,
        "run": {"channels": 4, "samples": N_TIME, "fs_hz": FS, "nperseg": 512},
        "single_run": {
            "jax_ms": single["median_ms"],
            "scipy_ms": scipy_single_ms,
            "speedup": scipy_single_ms / single["median_ms"],
            "compile_s": single["compile_s"],
        },
        "single_run_motion_window": {
            "jax_ms": windowed["median_ms"],
            "compile_s": windowed["compile_s"],
        },
        "batch": {
            "runs": args.batch,
            "jax_ms_per_run": batched["median_ms"] / args.batch,
            "scipy_ms_per_run": scipy_batch_ms / args.batch,
            "speedup": scipy_batch_ms / batched["median_ms"],
            "compile_s": batched["compile_s"],
        },
        "max_rel_diff_psd": float(np.max(np.abs(np.asarray(psd) - ref_psd) / ref_psd)),
        "max_abs_diff_cnn_input": float(np.max(np.abs(np.asarray(features) - ref_features))),
        "calls": args.calls,
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return
    s, b = result["single_run"], result["batch"]
    print(f"one run (4 x {N_TIME}):  JAX {s['jax_ms']:.3f} ms  scipy {s['scipy_ms']:.3f} ms  ")
    print(f"  ratio scipy/JAX = {s['speedup']:.2f}x  (compile {s['compile_s']:.2f} s)")
    print(f"  motion-window (weighted) Welch: JAX {windowed['median_ms']:.3f} ms")
    print(
        f"batch of {b['runs']}:  JAX {b['jax_ms_per_run']:.3f} ms/run  "
        f"scipy {b['scipy_ms_per_run']:.3f} ms/run  ratio {b['speedup']:.2f}x"
    )
    print(
        f"agreement: PSD max rel diff {result['max_rel_diff_psd']:.1e}, "
        f"CNN input max abs diff {result['max_abs_diff_cnn_input']:.1e}"
    )


if __name__ == "__main__":
    main()
