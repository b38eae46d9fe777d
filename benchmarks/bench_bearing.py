"""Bearing simulation speed: one simulated second, a vmapped JAX batch against numpy/scipy.

The bearing model is phenomenological (``bayesdoor.bearing._model``): no differential equation
is integrated, so the baseline is not ``solve_ivp`` but a numpy/scipy implementation of the
*same signal synthesis*, run by run in a Python loop: shaft harmonics, white background through
the two resonances (their impulse-invariant transfer function applied on the DFT grid), the
jittered impulse train placed with the same windowed-sinc taps, the defect passage's spectrum,
and white noise. It takes the same random draws as the JAX model (drawn from the same keys
before the clock starts), so the two signals must agree to rounding: the benchmark checks it
and reports the largest difference. All timings are taken in one process.

Usage: python benchmarks/bench_bearing.py [--batch 64] [--state outer_race] [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np
from _timing import median_s
from scipy import fft as sfft

from bayesdoor.bearing import BearingSystem
from bayesdoor.bearing._model import REFERENCE_SIZE_IN, TAPS, impulse_capacity
from bayesdoor.bearing._system import CONDITIONS, FAULT_DEFAULTS, FAULT_PARAMETERS, FS, _float_bits

INCH = 0.0254


def _draws(system: BearingSystem, op: np.ndarray, n_time: int, n_impulses: int) -> list[dict]:
    """The random draws of each run, from the keys the JAX model derives (not timed)."""
    base = jax.random.PRNGKey(system.seed)
    out = []
    for i, (rpm, load) in enumerate(op):
        key = jax.random.fold_in(base, np.uint32(i))
        key = jax.random.fold_in(key, _float_bits(jnp.asarray(rpm)))
        key = jax.random.fold_in(key, _float_bits(jnp.asarray(load)))
        k_phase, k_rough, k_noise, k_jitter, k_start, k_angle = jax.random.split(key, 6)
        out.append(
            {
                "phases": np.asarray(jax.random.uniform(k_phase, (len(system.harmonic_ratios),))),
                "white": np.asarray(jax.random.normal(k_rough, (n_time,))),
                "noise": np.asarray(jax.random.normal(k_noise, (n_time,))),
                "jitter": np.asarray(jax.random.normal(k_jitter, (n_impulses,))),
                "start": float(jax.random.uniform(k_start, ())),
                "angle": float(jax.random.uniform(k_angle, ())),
            }
        )
    return out


def _resonance(f, freq_hz, zeta):
    wn = 2 * np.pi * freq_hz
    r = np.exp(-zeta * wn / FS)
    th = wn * np.sqrt(1 - zeta**2) / FS
    z = np.exp(-2j * np.pi * f / FS)
    return r * np.sin(th) * z / (1 - 2 * r * np.cos(th) * z + r**2 * z**2)


def numpy_signal(system: BearingSystem, p: dict, rpm: float, size: float, d: dict, state: str):
    """One run's signal in numpy/scipy: the synthesis of ``bayesdoor.bearing._model``."""
    n = round(system.segment_s * FS)
    shaft_hz = rpm / 60.0
    t = np.arange(n) / FS
    f = np.arange(n // 2 + 1) * (FS / n)
    h = np.arange(1, len(system.harmonic_ratios) + 1)
    phases = d["phases"] * 2 * np.pi
    ratios = np.asarray(system.harmonic_ratios)
    shaft = p["shaft_amplitude"] * np.sum(
        ratios[:, None] * np.cos(2 * np.pi * h[:, None] * shaft_hz * t + phases[:, None]), axis=0
    )
    res = _resonance(f, p["resonance_1_hz"], p["damping_1"]) + p["resonance_2_gain"] * _resonance(
        f, p["resonance_2_hz"], p["damping_2"]
    )
    weight = np.ones_like(f)
    weight[1:] = 2.0
    if n % 2 == 0:
        weight[-1] = 1.0
    gain = np.sqrt(np.sum(weight * np.abs(res) ** 2) / n)
    rough = sfft.irfft(sfft.rfft(d["white"]) * res, n=n) / gain
    x = shaft + p["roughness_rms"] * rough + p["noise_rms"] * d["noise"]
    if state == "healthy":
        return x
    geometry = system.geometry
    order = geometry.impulse_order(state)
    period = 1 / (order * shaft_hz)
    spacing = period * np.maximum(1 + p["slip"] * d["jitter"], 0.5)
    tk = d["start"] * period + np.concatenate([[0.0], np.cumsum(spacing[:-1])])
    inside = tk < n / FS
    angle = d["angle"] * 2 * np.pi

    def zone(theta):
        eps = system.load_zone_epsilon
        return np.maximum(0.0, 1 - (1 - np.cos(theta)) / (2 * eps)) ** 1.5

    if state == "inner_race":
        q = zone(2 * np.pi * shaft_hz * tk + angle)
    elif state == "ball":
        alternate = np.where(np.arange(tk.size) % 2 == 0, 1.0, system.ball_inner_ratio)
        q = zone(2 * np.pi * geometry.orders()["ftf"] * shaft_hz * tk + angle) * alternate
    else:
        q = np.ones_like(tk)
    weights = np.where(inside, p["impulse_amplitude"] * size / REFERENCE_SIZE_IN * q, 0.0)
    pos = np.where(inside, tk, 0.0) * FS
    n0 = np.floor(pos)
    j = np.arange(-TAPS // 2 + 1, TAPS // 2 + 1)
    offset = j[None, :] - (pos - n0)[:, None]
    taps = np.sinc(offset) * (0.5 + 0.5 * np.cos(np.pi * offset / (TAPS / 2))) * weights[:, None]
    train = np.zeros(n)
    np.add.at(train, (n0.astype(int)[:, None] + j[None, :]) % n, taps)
    tau = size * INCH / (geometry.surface_speed_per_hz() * shaft_hz)
    u = f * tau
    near = np.abs(1 - u**2) < 1e-6
    safe = np.where(near, 0.5, u)
    hann = np.where(near, 0.5, np.sinc(safe) / (1 - safe**2))
    e = system.entry_ratio
    passage = np.exp(-2j * np.pi * u) - e * hann * np.exp(-1j * np.pi * u)
    return x + sfft.irfft(sfft.rfft(train) * res * passage, n=n)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument(
        "--state", default="outer_race", choices=("healthy", "inner_race", "outer_race", "ball")
    )
    parser.add_argument("--json", action="store_true")
    ns = parser.parse_args()
    system = BearingSystem()
    rng = np.random.default_rng(0)
    op = np.column_stack([rng.uniform(1700, 1800, ns.batch), rng.integers(0, 4, ns.batch)])
    values = {k: float(v) for k, v in system.nominal().items()}
    # the reference has no rotating load: the fault's parameters at their defaults (none)
    p = {**values, **FAULT_DEFAULTS}
    severity = None if ns.state == "healthy" else {"fault_size_in": 0.014}
    size = 0.014

    def batch():
        out = system.simulate_values(values, op, state=ns.state, severity=severity, check=False)
        return jax.block_until_ready(out.signals)

    t0 = time.perf_counter()
    signals = np.asarray(batch())[:, 0]
    first_s = time.perf_counter() - t0
    jax_s = median_s(batch, 5)
    n_time = round(system.segment_s * FS)
    order = system.geometry.impulse_order(ns.state) if ns.state != "healthy" else 1.0
    slip_max = FAULT_PARAMETERS["slip"][1]
    capacity = impulse_capacity(n_time / FS, order, 1.5 * CONDITIONS[0].upper / 60.0, slip_max)
    draws = _draws(system, op, n_time, capacity)

    def loop():
        return [
            numpy_signal(system, p, r, size, d, ns.state)
            for r, d in zip(op[:, 0], draws, strict=True)
        ]

    reference = np.stack(loop())
    numpy_s = median_s(loop, 3)
    result = {
        "state": ns.state,
        "batch": ns.batch,
        "simulated_seconds_per_run": system.segment_s,
        "jax_first_call_s": first_s,
        "jax_ms_per_run": 1e3 * jax_s / ns.batch,
        "numpy_ms_per_run": 1e3 * numpy_s / ns.batch,
        "speedup_jax_vs_numpy": numpy_s / jax_s,
        "max_abs_difference_m_s2": float(np.max(np.abs(signals - reference))),
        "signal_rms_m_s2": float(np.sqrt(np.mean(reference**2))),
        "devices": [str(d) for d in jax.devices()],
    }
    if ns.json:
        print(json.dumps(result, indent=2))
        return
    print(f"one simulated second per run ({ns.state}), batch of {ns.batch}:")
    print(
        f"  JAX vmap + jit: {result['jax_ms_per_run']:.2f} ms/run "
        f"(first call with compile {first_s:.1f} s)"
    )
    print(f"  numpy/scipy loop, same synthesis: {result['numpy_ms_per_run']:.2f} ms/run")
    print(f"  speed-up JAX batch vs numpy loop: {result['speedup_jax_vs_numpy']:.1f}x")
    print(
        f"  largest difference {result['max_abs_difference_m_s2']:.2e} m/s^2 "
        f"(signal rms {result['signal_rms_m_s2']:.3g} m/s^2)"
    )


if __name__ == "__main__":
    main()
