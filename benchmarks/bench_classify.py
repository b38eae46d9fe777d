"""Classifier speed: training the 10-member ensemble and predicting through all members.

Training: the paper's settings (Table 3 network, 10 members, 80 epochs, batch 100, Adam) on
1260 synthetic 4 x 25 inputs of 3 classes, all members vmapped in one jitted epoch step,
against a baseline measured in the same run: a Python loop training the members one after
the other (``train_ensemble`` with one member, ten times). Prediction: ``predict`` (all members,
temperature, entropies, Mahalanobis OOD score) per input for one input and for a batch, against
a Python loop calling each member's jitted network in turn; and one 3.5 s run end to end (its
4 x 25 log-PSD input, then all members). Compile times are reported apart; timings are medians
of repeated calls, each waited for with ``block_until_ready``; training is also given as process
CPU time, which other jobs on a shared machine disturb less than wall time.

Usage: python benchmarks/bench_classify.py [--repeats 3] [--calls 2000] [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _timing import median_s

from bayesdoor.classify import TrainConfig, fit_ood, predict, train_ensemble
from bayesdoor.features import cnn_input

N_TRAIN = 1260
CLASSES = ("a", "b", "c")


def _data(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    y = rng.integers(0, 3, size=n)
    f = np.linspace(0, 1, 25)
    patterns = np.stack(
        [np.zeros(25), 0.8 * np.exp(-(((f - 0.3) / 0.08) ** 2)), 0.5 * np.sin(6 * np.pi * f)]
    )
    x = -6.0 + 2.0 * f + patterns[y][:, None, :] + 0.4 * rng.standard_normal((n, 4, 25))
    return x, y


def _cpu_s(fn) -> float:
    """Process CPU time of one call: less sensitive than wall time to other jobs on the machine."""
    c0 = time.process_time()
    fn()
    return time.process_time() - c0


def _train(x, y, members: int, seed: int):
    config = TrainConfig(members=members)
    return train_ensemble(
        x, y, CLASSES, key=jax.random.key(seed), config=config, progress="none"
    ).ensemble


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="timed trainings per variant")
    parser.add_argument("--calls", type=int, default=2000, help="timed prediction calls")
    parser.add_argument("--batch", type=int, default=1000, help="inputs in the batched prediction")
    parser.add_argument("--json", action="store_true", help="print the result as JSON only")
    args = parser.parse_args()

    x, y = _data(N_TRAIN, 0)
    t0 = time.perf_counter()
    ensemble = _train(x, y, 10, 0)  # includes compiling the epoch step
    first_s = time.perf_counter() - t0
    vmapped_s = median_s(lambda: _train(x, y, 10, 1), args.repeats)
    vmapped_cpu_s = _cpu_s(lambda: _train(x, y, 10, 2))
    _train(x, y, 1, 0)  # compile the one-member step
    loop_s = median_s(lambda: [_train(x, y, 1, 10 + m) for m in range(10)], args.repeats)
    loop_cpu_s = _cpu_s(lambda: [_train(x, y, 1, 20 + m) for m in range(10)])

    x_val, _ = _data(540, 1)
    ensemble = fit_ood(ensemble, x, y, x_val)
    one = jnp.asarray(_data(1, 2)[0])
    batch = jnp.asarray(_data(args.batch, 3)[0])
    t0 = time.perf_counter()
    jax.block_until_ready(predict(ensemble, one))
    predict_compile_s = time.perf_counter() - t0
    one_us = 1e6 * median_s(lambda: jax.block_until_ready(predict(ensemble, one)), args.calls)
    jax.block_until_ready(predict(ensemble, batch))
    batch_calls = max(20, args.calls // 20)
    batch_us = (
        1e6
        * median_s(lambda: jax.block_until_ready(predict(ensemble, batch)), batch_calls)
        / args.batch
    )

    members = [
        jax.tree_util.tree_map(lambda a, m=m: a[m] if eqx.is_array(a) else a, ensemble.members)
        for m in range(ensemble.n_members)
    ]
    forward = eqx.filter_jit(lambda net, z: jax.nn.softmax(jax.vmap(net)(z), axis=-1))

    def loop_predict(x_in):
        z = ensemble.standardise(x_in)
        return np.mean([np.asarray(forward(net, z)) for net in members], axis=0)

    loop_predict(one)
    loop_one_us = 1e6 * median_s(lambda: loop_predict(one), args.calls // 4)

    # one run end to end: 3.5 s of 4 channels at 2048 Hz -> 4 x 25 log PSD -> all members
    signals = jnp.asarray(np.random.default_rng(4).standard_normal((1, 4, 7168)))
    features = jax.jit(lambda s: cnn_input(s, 2048.0))

    def run_to_report():
        return jax.block_until_ready(predict(ensemble, features(signals)))

    run_to_report()
    run_us = 1e6 * median_s(run_to_report, args.calls)

    result = {
        "train_samples": N_TRAIN,
        "members": 10,
        "epochs": 80,
        "batch_size": 100,
        "train_first_call_s": first_s,
        "train_vmapped_s": vmapped_s,
        "train_member_loop_s": loop_s,
        "train_speedup": loop_s / vmapped_s,
        "train_vmapped_cpu_s": vmapped_cpu_s,
        "train_member_loop_cpu_s": loop_cpu_s,
        "predict_compile_s": predict_compile_s,
        "predict_one_input_us": one_us,
        "predict_per_input_in_batch_us": batch_us,
        "predict_batch": args.batch,
        "member_loop_one_input_us": loop_one_us,
        "predict_speedup_one_input": loop_one_us / one_us,
        "features_and_predict_one_run_us": run_us,
        "dtype": ensemble.dtype.name,
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(f"training, {N_TRAIN} inputs, 10 members, 80 epochs, batch 100 ({result['dtype']})")
    print(f"  first call (with compile)    {first_s:8.2f} s")
    print(f"  vmapped ensemble             {vmapped_s:8.2f} s   ({vmapped_cpu_s:.2f} s CPU)")
    print(
        f"  Python loop over members     {loop_s:8.2f} s   ({loop_cpu_s:.2f} s CPU; "
        f"{loop_s / vmapped_s:.1f}x slower)"
    )
    print("prediction through all 10 members (+ entropies, OOD score)")
    print(f"  one input                    {one_us:8.1f} us")
    print(f"  per input in a batch of {args.batch:<5d}{batch_us:8.2f} us")
    print(f"  Python loop, one input       {loop_one_us:8.1f} us")
    print(f"one 3.5 s run: features + all members {run_us:8.1f} us")


if __name__ == "__main__":
    main()
