"""Write results/solver_tolerance.md: what the door solver's tolerance costs and what it buys.

A batch of door runs like the demo campaign's (speeds spread over 0.25-0.5 m/s; healthy, D1
and D2 at the middle of their severity priors; the paper's optimum parameters), each
simulated for the record length the fit uses (the slowest run's) and turned into the fit's
features (``bayesdoor.inference.run_features``: log10 Welch PSD, 4-96 Hz, every channel,
over the motion window). Every candidate tolerance is compared with a reference solve (rtol
1e-8, atol 1e-11): the feature error of each run, channel and band in units of the Welch
standard deviation of that run's log10 PSD (``welch_log10_variance``, the scatter the fit's
likelihood uses), the solver's steps, the failures, and the wall time per run of the
vmapped float64 batch (compile excluded, best of ``--repeats``) against the scipy LSODA
baseline of ``benchmarks/bench_simulate.py`` timed in the same process.

The batch is solved by a copy of ``bayesdoor.door.solve`` (the same terms, solver,
controller, save function and status) that also returns diffrax's step counts and takes the
tolerances as traced arrays, so one compiled program serves every tolerance. The project's
own ``solve_batch`` at the default ``SolverConfig()`` is run once beside it: the script
stops if the two disagree, and its time is reported next to the copy's.

Usage: python scripts/solver_tolerance.py [--speeds 8] [--json FILE] [--out-md FILE]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
STATES = ("healthy", "D1", "D2")
REFERENCE = (1e-8, 1e-11)
#: a tighter solve than the reference, to bound the reference's own error
CHECK = (1e-9, 1e-12)
DEFAULT = (1e-5, 1e-8)
RTOLS = (1e-6, 3e-6, 1e-5, 3e-5, 1e-4, 3e-4, 1e-3)
#: (solver argument, relative change): how far the features move, at the reference
#: tolerance, when the physics itself changes this little (the contact stiffness K, the
#: dynamic friction, the debris height)
SENSITIVITY = (
    ("k_contact", 1e-6),
    ("mu_d", 1e-6),
    ("d1_height", 1e-6),
    ("k_contact", 1e-4),
    ("mu_d", 1e-4),
    ("d1_height", 1e-4),
)
#: the feature error (Welch standard deviations, 99th percentile) called negligible
THRESHOLD = 0.1


def candidates() -> list[tuple[float, float]]:
    """(rtol, atol): atol = rtol * 1e-3 for every rtol (two tighter than the default, to see
    where the error settles), then atol kept at 1e-8 for the looser ones (rtol 1e-5 with atol
    1e-8 is the default, in the first list already)."""
    scaled = [(r, r * 1e-3) for r in RTOLS]
    fixed = [(r, DEFAULT[1]) for r in RTOLS if r > DEFAULT[0]]
    return scaled + fixed


def ratio_stats(ratio: np.ndarray) -> dict[str, float]:
    """Median, 99th percentile and maximum of the finite entries of ``ratio``."""
    x = np.asarray(ratio, dtype=float).ravel()
    x = x[np.isfinite(x)]
    if x.size == 0:
        return {"median": float("nan"), "p99": float("nan"), "max": float("nan")}
    return {
        "median": float(np.median(x)),
        "p99": float(np.percentile(x, 99.0)),
        "max": float(np.max(x)),
    }


def loosest_under(
    rows: list[dict], threshold: float, atol_rule: str, scope: str = "all"
) -> dict | None:
    """The row of largest rtol, among those of ``atol_rule`` (the fixed-atol rows continue
    the scaled ones tighter than the default) without failures, whose p99 feature error over
    the runs of ``scope`` (``"all"`` or a state) lies below ``threshold`` Welch standard
    deviations, with every tighter rtol of that rule under it too."""
    rule = sorted(
        (
            r
            for r in rows
            if r["atol_rule"] == atol_rule
            or (r["atol_rule"] == "scaled" and r["rtol"] <= DEFAULT[0])
        ),
        key=lambda r: r["rtol"],
    )
    best = None
    for row in rule:
        if row["failures"] == 0 and row["error"][scope]["p99"] < threshold:
            best = row
        else:
            break
    return best


def sh(*words: str) -> str:
    done = subprocess.run(list(words), capture_output=True, text=True, check=False, cwd=ROOT)
    return done.stdout.strip()


def machine_line() -> str:
    model = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (
        f"{os.cpu_count()} CPU cores ({model or platform.processor() or 'unknown CPU'}), "
        f"{platform.system()} {platform.release()}, Python {platform.python_version()}"
    )


def build_batch(n_speeds: int, v_lo: float, v_hi: float):
    """The runs (state x speed), their solver arguments, times, motion windows and spec."""
    import jax
    import jax.numpy as jnp

    from bayesdoor.door import DoorDamage, DoorParameters, ElevatorDoor, make_args, sample_times
    from bayesdoor.inference import FeatureSpec

    door = ElevatorDoor()
    speeds = np.linspace(v_lo, v_hi, n_speeds)
    runs = [(s, float(v)) for s in STATES for v in speeds]
    v = np.array([r[1] for r in runs])
    damages = [DoorDamage.for_state(s) for s, _ in runs]
    damage = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *damages)
    theta = jax.tree_util.tree_map(
        lambda x: jnp.broadcast_to(x, (len(runs),)), DoorParameters.paper_optimum()
    )
    args = jax.vmap(lambda p, d, s: make_args(p, d, s, dtype=jnp.float64))(
        theta, damage, jnp.asarray(v)
    )
    # as the fit's forward model: every run as long as the slowest one's record
    duration = door.record_duration(v)
    ts = sample_times(duration, dtype=jnp.float64)
    t_start, t_stop = door.motion_window(v, duration=duration)
    severity = {
        s: {
            k: float(getattr(DoorDamage.for_state(s), k))
            for k in ("d1_height", "d2_depth", "d2_angle")
        }
        for s in STATES
    }
    return {
        "door": door,
        "runs": runs,
        "v": v,
        "args": args,
        "ts": ts,
        "duration": duration,
        "t_start": t_start,
        "t_stop": t_stop,
        "spec": FeatureSpec.of(door),
        "severity": severity,
    }


def make_solver():
    """The door's solve with traced tolerances, returning diffrax's step counts too."""
    import diffrax
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from bayesdoor._cacheable import errors_as_nan
    from bayesdoor.door import SolverConfig, initial_state
    from bayesdoor.door._model import rhs, sensor_signals
    from bayesdoor.door._simulate import STATUS_FAILED, STATUS_OK, _status

    default = SolverConfig()  # its step controller, for every tolerance

    @eqx.filter_jit
    def solve_with_stats(args, ts, rtol, atol, max_steps: int):
        def one(a):
            term = diffrax.ODETerm(lambda t, y, aa: rhs(t, y, aa, jnp))
            with errors_as_nan():
                sol = diffrax.diffeqsolve(
                    term,
                    diffrax.Tsit5(),
                    t0=ts[0],
                    t1=ts[-1],
                    dt0=None,
                    y0=initial_state(a),
                    args=a,
                    saveat=diffrax.SaveAt(ts=ts, fn=lambda t, y, aa: sensor_signals(t, y, aa, jnp)),
                    stepsize_controller=diffrax.PIDController(
                        rtol=rtol, atol=atol, pcoeff=default.pcoeff, icoeff=default.icoeff
                    ),
                    max_steps=max_steps,
                    throw=False,
                )
            status = _status(sol.result)
            good = (status == STATUS_OK) & jnp.all(jnp.isfinite(sol.ys))
            status = jnp.where((status == STATUS_OK) & ~good, STATUS_FAILED, status)
            stats = sol.stats
            return (
                jnp.where(good, sol.ys, 0.0).T,
                status,
                stats["num_steps"],
                stats["num_accepted_steps"],
                stats["num_rejected_steps"],
            )

        return jax.vmap(one)(args)

    return solve_with_stats


def timed(fn, repeats: int):
    """The result of ``fn()`` (its last call) and the best wall time of ``repeats`` calls."""
    import jax

    best, out = float("inf"), None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - t0)
    return out, best


def features(batch, signals):
    import jax.numpy as jnp

    from bayesdoor.inference import run_features, welch_log10_variance

    fs = batch["door"].sampling_rate_hz
    feats, n_seg = run_features(
        jnp.asarray(signals),
        fs,
        jnp.asarray(batch["t_start"]),
        jnp.asarray(batch["t_stop"]),
        batch["spec"],
    )
    sd = np.sqrt(np.asarray(welch_log10_variance(n_seg, fs, batch["spec"])))
    return np.asarray(feats), sd, np.asarray(n_seg)


def error_summary(batch, feats, ref_feats, sd, ok) -> dict:
    """Feature error / Welch sd: overall and per state, over the runs that succeeded (with
    the largest |mean over the runs of the signed ratio| over channel and band); the
    largest entry's place; each run's largest entry."""
    ratio = (feats - ref_feats) / sd[:, None, None]
    ratio = np.where(ok[:, None, None], ratio, np.nan)
    states = np.array([s for s, _ in batch["runs"]])
    out = {"all": ratio_stats(np.abs(ratio))}
    for s in STATES:
        out[s] = ratio_stats(np.abs(ratio[states == s]))
        with np.errstate(all="ignore"):
            mean = np.nanmean(ratio[states == s], axis=0)
        out[s]["max_abs_mean_signed"] = (
            float(np.nanmax(np.abs(mean))) if np.any(np.isfinite(mean)) else float("nan")
        )
    if np.any(ok):
        flat = np.where(np.isfinite(ratio), np.abs(ratio), -1.0)
        r, c, b = np.unravel_index(np.argmax(flat), flat.shape)
        centres = batch["spec"].band_centres(batch["door"].sampling_rate_hz)
        out["worst"] = {
            "state": batch["runs"][r][0],
            "v_max": batch["runs"][r][1],
            "channel": batch["door"].channels[c],
            "band_hz": float(centres[b]),
            "signed_ratio": float(ratio[r, c, b]),
        }
        out["max_abs_mean_signed"] = float(np.nanmax(np.abs(np.nanmean(ratio, axis=0))))
        out["per_run_max"] = [
            None if not o else float(np.max(np.abs(x))) for x, o in zip(ratio, ok, strict=True)
        ]
    return out


def solve_one(batch, solver, rtol, atol, max_steps, repeats):
    import jax.numpy as jnp

    r, a = jnp.asarray(rtol, jnp.float64), jnp.asarray(atol, jnp.float64)
    out, best = timed(lambda: solver(batch["args"], batch["ts"], r, a, max_steps), repeats)
    signals, status, steps, accepted, rejected = (np.asarray(x) for x in out)
    return {
        "signals": signals,
        "status": status,
        "steps": steps,
        "accepted": accepted,
        "rejected": rejected,
        "batch_s": best,
    }


def step_summary(res, n_runs) -> dict:
    return {
        "steps_mean": float(np.mean(res["steps"])),
        "steps_max": int(np.max(res["steps"])),
        "accepted_mean": float(np.mean(res["accepted"])),
        "rejected_mean": float(np.mean(res["rejected"])),
        "ms_per_run": 1e3 * res["batch_s"] / n_runs,
        "failures": int(np.sum(res["status"] != 0)),
    }


def run(ns) -> dict:
    from _cases import setup_jax

    setup_jax()
    import jax
    import jax.numpy as jnp

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_simulate import time_scipy

    from bayesdoor.door import SolverConfig
    from bayesdoor.door._simulate import solve_batch

    started = time.perf_counter()
    batch = build_batch(ns.speeds, ns.v_min, ns.v_max)
    n = len(batch["runs"])
    solver = make_solver()
    r0, a0 = (jnp.asarray(x, jnp.float64) for x in DEFAULT)
    t0 = time.perf_counter()
    solver.lower(batch["args"], batch["ts"], r0, a0, ns.max_steps).compile()
    compile_s = time.perf_counter() - t0
    print(f"compiled the batched solve in {compile_s:.0f} s", flush=True)

    ref = solve_one(batch, solver, *REFERENCE, ns.max_steps, ns.repeats)
    if np.any(ref["status"] != 0):
        bad = [batch["runs"][i] for i in np.flatnonzero(ref["status"] != 0)]
        raise SystemExit(f"the reference solve failed for {bad}: raise --max-steps")
    ref_feats, sd, n_seg = features(batch, ref["signals"])
    print(f"reference: {step_summary(ref, n)}", flush=True)

    check = None
    if ns.check_reference:
        tight = solve_one(batch, solver, *CHECK, ns.max_steps, 1)
        ok = tight["status"] == 0
        check = {
            "rtol": CHECK[0],
            "atol": CHECK[1],
            **step_summary(tight, n),
            "error": error_summary(batch, features(batch, tight["signals"])[0], ref_feats, sd, ok),
        }
        print(f"reference against rtol {CHECK[0]:g}: {check['error']['all']}", flush=True)

    sensitivity = []
    if ns.check_sensitivity:
        import equinox as eqx

        for name, change in SENSITIVITY:
            args = batch["args"]
            moved = eqx.tree_at(
                lambda a, name=name: getattr(a, name), args, getattr(args, name) * (1 + change)
            )
            res = solve_one({**batch, "args": moved}, solver, *REFERENCE, ns.max_steps, 1)
            ok = res["status"] == 0
            row = {
                "argument": name,
                "relative_change": change,
                "failures": int(np.sum(~ok)),
                "error": error_summary(
                    batch, features(batch, res["signals"])[0], ref_feats, sd, ok
                ),
            }
            sensitivity.append(row)
            print(f"{name} x (1 + {change:g}): {row['error']['all']}", flush=True)

    rows = []
    for rtol, atol in candidates():
        res = solve_one(batch, solver, rtol, atol, ns.max_steps, ns.repeats)
        ok = res["status"] == 0
        feats = features(batch, res["signals"])[0]
        row = {
            "rtol": rtol,
            "atol": atol,
            "atol_rule": "fixed" if atol == DEFAULT[1] and rtol != DEFAULT[0] else "scaled",
            "default": (rtol, atol) == DEFAULT,
            **step_summary(res, n),
            "error": error_summary(batch, feats, ref_feats, sd, ok),
            "steps_by_state": {
                s: float(
                    np.mean(res["steps"][[i for i, r in enumerate(batch["runs"]) if r[0] == s]])
                )
                for s in STATES
            },
        }
        rows.append(row)
        print(
            f"rtol {rtol:g} atol {atol:g}: {row['steps_mean']:.0f} steps, "
            f"{row['ms_per_run']:.1f} ms/run, p99 {row['error']['all']['p99']:.3g}, "
            f"failures {row['failures']}",
            flush=True,
        )

    project = None
    if ns.check_project:
        t0 = time.perf_counter()
        compiled = solve_batch.lower(batch["args"], batch["ts"], SolverConfig()).compile()
        project_compile_s = time.perf_counter() - t0
        (signals, status), best = timed(
            lambda: compiled(batch["args"], batch["ts"], SolverConfig()), ns.repeats
        )
        default = next(r for r in rows if r["default"])
        mine = solve_one(batch, solver, *DEFAULT, ns.max_steps, 1)
        diff = float(np.max(np.abs(np.asarray(signals) - mine["signals"])))
        scale = float(np.max(np.abs(mine["signals"])))
        project = {
            "compile_s": project_compile_s,
            "ms_per_run": 1e3 * best / n,
            "copy_ms_per_run": default["ms_per_run"],
            "failures": int(np.sum(np.asarray(status) != 0)),
            "max_abs_signal_difference": diff,
            "max_abs_signal": scale,
        }
        if not diff <= 1e-9 * scale:
            raise SystemExit(
                f"the copy of the solve disagrees with bayesdoor's solve_batch at the default "
                f"tolerance by {diff:.3g} (signals up to {scale:.3g}): the copy is stale"
            )
        print(f"project solve_batch: {project}", flush=True)

    scipy = time_scipy(batch["duration"])
    for row in [*rows, *([check] if check else [])]:
        row["x_scipy"] = scipy["ms_per_run"] / row["ms_per_run"]
    ref_summary = {"rtol": REFERENCE[0], "atol": REFERENCE[1], **step_summary(ref, n)}
    ref_summary["x_scipy"] = scipy["ms_per_run"] / ref_summary["ms_per_run"]
    return {
        "batch": {
            "runs": n,
            "states": list(STATES),
            "speeds": [float(x) for x in np.linspace(ns.v_min, ns.v_max, ns.speeds)],
            "severity": batch["severity"],
            "parameters": "DoorParameters.paper_optimum()",
            "duration_s": batch["duration"],
            "samples": int(batch["ts"].shape[0]),
            "welch_segments": sorted({int(x) for x in n_seg}),
            "welch_sd_decades": [float(np.min(sd)), float(np.max(sd))],
            "features": "run_features: log10 Welch PSD 4-96 Hz, 24 one-bin bands, 4 channels",
        },
        "compile_s": compile_s,
        "repeats": ns.repeats,
        "max_steps": ns.max_steps,
        "reference": ref_summary,
        "reference_check": check,
        "sensitivity_check": sensitivity,
        "candidates": rows,
        "project_solve_batch": project,
        "scipy": scipy,
        "threshold": THRESHOLD,
        "loosest_under_threshold": {
            rule: {
                scope: (
                    None
                    if (best := loosest_under(rows, THRESHOLD, rule, scope)) is None
                    else {"rtol": best["rtol"], "atol": best["atol"]}
                )
                for scope in ("all", *STATES)
            }
            for rule in ("scaled", "fixed")
        },
        "runs": [{"state": s, "v_max": v} for s, v in batch["runs"]],
        "devices": [str(d) for d in jax.devices()],
        "elapsed_s": time.perf_counter() - started,
    }


def fmt(x: float, digits: int = 2) -> str:
    if not np.isfinite(x):
        return "-"
    return f"{x:.{digits}g}" if abs(x) < 0.01 or abs(x) >= 1000 else f"{x:.{digits}f}"


def markdown(result: dict, meta: dict) -> str:
    b = result["batch"]
    rows = result["candidates"]
    ref = result["reference"]
    default = next(r for r in rows if r["default"])
    lines = [
        "# What the door solver's tolerance costs and buys",
        "",
        f"Command: `{meta['command']}` ({meta['date']}, commit {meta['commit']}, "
        f"{meta['code_version']}; {result['elapsed_s']:.0f} s in all, the batched solve "
        f"compiled once in {result['compile_s']:.0f} s).",
        "",
        f"Machine: {meta['machine']}; JAX devices {', '.join(result['devices'])}. The load "
        "at the start and at the end (`uptime`):",
        "",
        f"- start: `{meta['uptime_start']}`",
        f"- end: `{meta['uptime_end']}`",
        "",
        f"Batch: {b['runs']} runs, states healthy, D1 (d1_height "
        f"{b['severity']['D1']['d1_height'] * 1e3:.2f} mm) and D2 (d2_depth "
        f"{b['severity']['D2']['d2_depth'] * 1e3:.3f} mm at {b['severity']['D2']['d2_angle']:.2f}"
        f" rad), the middle of their priors, each at {len(b['speeds'])} speeds "
        f"{b['speeds'][0]:g}-{b['speeds'][-1]:g} m/s, parameters at the paper's optimum; every "
        f"run {b['duration_s']:.3f} s long ({b['samples']} samples, the slowest run's record, as "
        "the fit's forward model simulates them). Features as the fit takes them "
        "(`bayesdoor.inference.run_features`: log10 Welch PSD over the motion window, 4-96 Hz, "
        f"24 one-bin bands, 4 channels); {', '.join(map(str, b['welch_segments']))} Welch "
        f"segments per run, so the Welch standard deviation of a log10 bin "
        f"(`welch_log10_variance`) is {b['welch_sd_decades'][0]:.3f}-"
        f"{b['welch_sd_decades'][1]:.3f} decades.",
        "",
        f"Reference: rtol {ref['rtol']:g}, atol {ref['atol']:g} (float64, max_steps "
        f"{result['max_steps']}), {ref['steps_mean']:.0f} steps per run, no failure.",
    ]
    check = result["reference_check"]
    if check:
        lines += [
            f"Its own error, against rtol {check['rtol']:g}, atol {check['atol']:g}: "
            f"{fmt(check['error']['all']['p99'], 2)} Welch sd at the 99th percentile, "
            f"{fmt(check['error']['all']['max'], 2)} at most (largest by state: "
            + ", ".join(f"{st} {fmt(check['error'][st]['max'], 2)}" for st in STATES)
            + ").",
        ]
    sens = result.get("sensitivity_check")
    if sens:
        lines += [
            "",
            "The physics' own sensitivity: one solver argument changed by a relative amount, "
            "solved at the reference tolerance, against the reference (error / Welch sd, "
            "p99 / max; `k_contact` is K in SI units, `d1_height` is zero in healthy and D2 "
            "runs):",
            "",
            "| argument | relative change | healthy | D1 | D2 |",
            "|---|---|---|---|---|",
        ]
        for row in sens:
            lines.append(
                f"| `{row['argument']}` | {row['relative_change']:g} | "
                + " | ".join(
                    f"{fmt(row['error'][st]['p99'], 2)} / {fmt(row['error'][st]['max'], 2)}"
                    for st in STATES
                )
                + " |"
            )
    lines += [
        "",
        "Error: |log10 PSD(candidate) - log10 PSD(reference)| of every run, channel and band, "
        "over the Welch standard deviation of that run's bins; median, 99th percentile and "
        "maximum over all of them. Steps: diffrax's accepted plus rejected steps per run (mean "
        f"over the batch; the largest in brackets). Time: the vmapped float64 batch of "
        f"{b['runs']}, compile excluded, best of {result['repeats']} calls, per run; x scipy: "
        f"scipy LSODA ({result['scipy']['ms_per_run']:.0f} ms for one healthy run of the same "
        "length at 0.3 m/s, rtol 1e-5, atol 1e-8, `benchmarks/bench_simulate.py`'s "
        "`time_scipy`, same process) over that.",
        "",
        "| rtol | atol | steps per run | rejected | ms per run | x scipy | error / Welch sd: "
        "median | p99 | max | failures |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    order = sorted(rows, key=lambda r: (r["atol_rule"] != "scaled", r["rtol"]))
    for r in order:
        e = r["error"]["all"]
        name = f"{r['rtol']:g}" + (" (default)" if r["default"] else "")
        lines.append(
            f"| {name} | {r['atol']:g} | {r['steps_mean']:.0f} ({r['steps_max']}) | "
            f"{r['rejected_mean']:.0f} | {r['ms_per_run']:.1f} | {r['x_scipy']:.0f} | "
            f"{fmt(e['median'], 2)} | {fmt(e['p99'], 2)} | {fmt(e['max'], 2)} | {r['failures']} |"
        )
    lines.append(
        f"| {ref['rtol']:g} (reference) | {ref['atol']:g} | {ref['steps_mean']:.0f} "
        f"({ref['steps_max']}) | {ref['rejected_mean']:.0f} | {ref['ms_per_run']:.1f} | "
        f"{ref['x_scipy']:.0f} | - | - | - | {ref['failures']} |"
    )
    lines += [
        "",
        "By state (error / Welch sd, median / p99 / max; mean steps per run):",
        "",
        "| rtol | atol | healthy | D1 | D2 | steps healthy / D1 / D2 | largest error at | "
        "largest mean signed error, healthy / D1 / D2 |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in order:
        e = r["error"]
        cells = [" / ".join(fmt(e[s][k], 2) for k in ("median", "p99", "max")) for s in STATES]
        w = e.get("worst")
        where = (
            f"{w['state']} {w['v_max']:.3f} m/s, {w['channel']} {w['band_hz']:g} Hz "
            f"({w['signed_ratio']:+.2f})"
            if w
            else "-"
        )
        steps = " / ".join(f"{r['steps_by_state'][s]:.0f}" for s in STATES)
        lines.append(
            f"| {r['rtol']:g} | {r['atol']:g} | {' | '.join(cells)} | {steps} | {where} | "
            + " / ".join(fmt(e[st]["max_abs_mean_signed"], 2) for st in STATES)
            + " |"
        )
    p = result["project_solve_batch"]
    if p:
        lines += [
            "",
            f"The copy of the solve that counts the steps agrees with bayesdoor's own "
            f"`solve_batch` at the default `SolverConfig()` to {p['max_abs_signal_difference']:.1g}"
            f" m/s^2 (signals up to {p['max_abs_signal']:.3g}); `solve_batch` takes "
            f"{p['ms_per_run']:.1f} ms per run on the same batch (the copy "
            f"{p['copy_ms_per_run']:.1f} ms; compiled in {p['compile_s']:.0f} s), "
            f"{p['failures']} failures.",
        ]
    lines += [
        "",
        "## Loosest tolerance under the threshold",
        "",
        f"The largest rtol whose feature error stays under {THRESHOLD} Welch standard "
        "deviations at the 99th percentile, with every tighter rtol of the same atol rule "
        "under it too and no failure (the atol-1e-8 rule continues the scaled rows at and "
        "below the default); time relative to the default's on the same batch.",
        "",
        "| atol rule | runs | rtol | atol | p99 | max | steps per run | ms per run | "
        "default's time / this |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for rule, label in (("scaled", "rtol x 1e-3"), ("fixed", "1e-8")):
        for scope in ("all", *STATES):
            best = result["loosest_under_threshold"][rule][scope]
            if best is None:
                lines.append(f"| {label} | {scope} | none | - | - | - | - | - | - |")
                continue
            row = next(r for r in rows if (r["rtol"], r["atol"]) == (best["rtol"], best["atol"]))
            e = row["error"][scope]
            lines.append(
                f"| {label} | {scope} | {row['rtol']:g} | {row['atol']:g} | {fmt(e['p99'], 2)} "
                f"| {fmt(e['max'], 2)} | {row['steps_mean']:.0f} | {row['ms_per_run']:.1f} | "
                f"{default['ms_per_run'] / row['ms_per_run']:.2f} |"
            )
    speeds = sorted({run["v_max"] for run in result["runs"]})
    shown = [r for r in order if r["atol_rule"] == "scaled"]
    lines += [
        "",
        "## Each run's largest error",
        "",
        "The largest error / Welch sd over the channels and bands of each run, by state and "
        "speed (m/s), for the tolerances with atol = rtol x 1e-3:",
        "",
        "| rtol | state | " + " | ".join(f"{v:.3f}" for v in speeds) + " |",
        "|---|---|" + "---|" * len(speeds),
    ]
    for r in shown:
        per_run = r["error"].get("per_run_max") or [None] * len(result["runs"])
        for s in STATES:
            cells = []
            for v in speeds:
                i = next(
                    k
                    for k, run in enumerate(result["runs"])
                    if run["state"] == s and run["v_max"] == v
                )
                cells.append("failed" if per_run[i] is None else fmt(per_run[i], 2))
            lines.append(f"| {r['rtol']:g} | {s} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speeds", type=int, default=8, help="speeds per state (default 8)")
    parser.add_argument("--v-min", type=float, default=0.25, help="slowest speed, m/s")
    parser.add_argument("--v-max", type=float, default=0.5, help="fastest speed, m/s")
    parser.add_argument("--repeats", type=int, default=2, help="timed calls, best taken")
    parser.add_argument(
        "--max-steps", type=int, default=200_000, help="the solver's max_steps (all solves)"
    )
    parser.add_argument(
        "--no-check-reference",
        dest="check_reference",
        action="store_false",
        help=f"skip the solve at rtol {CHECK[0]:g} that bounds the reference's own error",
    )
    parser.add_argument(
        "--no-check-sensitivity",
        dest="check_sensitivity",
        action="store_false",
        help="skip the reference solves with K, mu_d and d1_height moved a little",
    )
    parser.add_argument(
        "--no-check-project",
        dest="check_project",
        action="store_false",
        help="skip bayesdoor's own solve_batch at the default tolerance (one more compile)",
    )
    parser.add_argument(
        "--json",
        type=Path,
        default=None,
        help="the JSON file to write (default: the Markdown file's, ending .json)",
    )
    parser.add_argument(
        "--out-md",
        type=Path,
        default=ROOT / "results" / "solver_tolerance.md",
        help="the Markdown file to write (default results/solver_tolerance.md)",
    )
    ns = parser.parse_args()
    if ns.json is None:
        ns.json = ns.out_md.with_suffix(".json")
    if ns.speeds < 1 or ns.repeats < 1:
        parser.error("--speeds and --repeats must be at least 1")
    from _cases import code_version, write_results

    meta = {
        "command": "python scripts/solver_tolerance.py" + "".join(f" {a}" for a in sys.argv[1:]),
        "date": f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC",
        "commit": sh("git", "rev-parse", "--short", "HEAD"),
        "code_version": code_version(),
        "machine": machine_line(),
        "uptime_start": sh("uptime"),
    }
    result = run(ns)
    meta["uptime_end"] = sh("uptime")
    result["meta"] = meta
    ns.json.parent.mkdir(parents=True, exist_ok=True)
    ns.json.write_text(json.dumps(result, indent=2) + "\n")
    write_results(ns.out_md, markdown(result, meta))


if __name__ == "__main__":
    main()
