"""Hidden-effect cases on the virtual rig, diagnosed end to end -> results/diagnosis.md.

Every case records healthy runs of the virtual rig (``bayesdoor.door.rig.VirtualRig``) at speeds
spread over the door's range, with one catalogue effect drawn by ``from_seed(seed)`` (its
parameters are the seed's, not chosen to suit the detector) or with nothing hidden, and runs
``bayesdoor.diagnose.diagnose_campaign`` on it as ``bayesdoor diagnose`` does: the base model
is fitted on the case's own runs, then the residual features, the signatures, the refits and
the held-out gain decide. The table gives, per effect, how often the verdict names it, what
else it named, the error of its key parameter against the rig's truth, and the run time; for
the cases with nothing hidden, the false alarms.

Cases run in parallel processes (``--jobs``), one CPU thread each; every finished case is
saved under ``--work`` (one JSON file), so an interrupted run continues where it stopped.

Usage::

    .venv/bin/python scripts/diagnosis.py [--quick] [--seeds 0 1 2 ...] [--none-seeds N]
        [--diagnosis quick|full] [--jobs N] [--runs 8] [--work out/diagnosis]
        [--results results/diagnosis.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from _cases import (
    NONE,
    RIG_EFFECTS,
    ROOT,
    attempt,
    code_version,
    command_line,
    digest,
    fmt,
    hidden_effect,
    run_cases,
    save_json,
    setup_jax,
    write_results,
)

EFFECTS = RIG_EFFECTS
#: the order of the effects in the tables (and a part of each case's rig key)
EFFECTS_INDEX = {name: i for i, name in enumerate((*EFFECTS, NONE), start=1)}
#: the key parameter of each effect, how its error is measured, and the tolerance stated
KEY_PARAMETER = {
    "frame_mode": "frequency (Hz): error within max(1 Hz bin, a quarter of 2 zeta f)",
    "wheel_eccentricity": "revolution length k x wavelength (m): within 3 % of 2 pi R",
    "rail_waviness": "wavelength (m): within 4 %",
    "sensor_cross_axis": "fraction (receiving channel right): within 10 %",
    "mains_hum": "mains frequency (Hz): exact (50 or 60)",
}


@dataclasses.dataclass(frozen=True)
class Settings:
    """What a case depends on (its hash names the saved case)."""

    runs: int
    v_low: float
    v_high: float
    quick: bool

    def digest(self) -> str:
        return digest(self, 12)


# ------------------------------------------------------------------------------ one case


def _number(value: Any) -> float | None:
    """A parameter's value: a number, or the ``mean`` (else ``point``) of a summary."""
    if isinstance(value, Mapping):
        value = value.get("mean", value.get("point", value.get("value")))
    try:
        out = float(value)
    except (TypeError, ValueError):
        return None
    return out if np.isfinite(out) else None


def _parameter(parameters: Mapping[str, Any], quantity: str) -> Any:
    """A cause's parameter by its quantity: the refitted extension's (``frame_mode.frequency_hz``)
    where the cause was refitted, else the signature's estimate (``frequency_hz``)."""
    for name, value in parameters.items():
        if name.endswith("." + quantity):
            return value
    return parameters.get(quantity)


def parameter_error(effect: str, truth: Mapping[str, Any], cause: Mapping[str, Any] | None):
    """The key parameter's estimate, truth, error and whether it is within the tolerance.

    Returns ``None`` entries when the cause is missing or carries no estimate.
    """
    empty = {"estimate": None, "truth": None, "error": None, "within": None}
    params = {} if cause is None else dict(cause.get("parameters") or {})
    if effect == "frame_mode":
        true_f = float(truth["frequency_hz"])
        f = _number(_parameter(params, "frequency_hz"))
        tol = max(1.0, 0.25 * 2.0 * float(truth["damping_ratio"]) * true_f)
        if f is None:
            return {**empty, "truth": true_f}
        return {
            "estimate": f,
            "truth": true_f,
            "error": f - true_f,
            "within": abs(f - true_f) <= tol,
        }
    if effect == "rail_waviness":
        lam = float(truth["wavelength_m"])
        est = _number(_parameter(params, "wavelength_m"))
        est = _number(params.get("period")) if est is None else est
        if est is None:
            return {**empty, "truth": lam}
        rel = est / lam - 1.0
        return {"estimate": est, "truth": lam, "error": rel, "within": abs(rel) <= 0.04}
    if effect == "wheel_eccentricity":
        from bayesdoor.door import WHEEL_CIRCUMFERENCE

        wavelength = _number(_parameter(params, "period"))
        k = _number(_parameter(params, "label")) or _number(_parameter(params, "harmonic"))
        revolution = _number(_parameter(params, "revolution_m"))
        if revolution is None and wavelength is not None:
            revolution = wavelength * (1.0 if k is None else k)
        if revolution is None:
            return {**empty, "truth": WHEEL_CIRCUMFERENCE}
        rel = revolution / WHEEL_CIRCUMFERENCE - 1.0
        return {
            "estimate": revolution,
            "truth": WHEEL_CIRCUMFERENCE,
            "error": rel,
            "within": abs(rel) <= 0.03,
        }
    if effect == "sensor_cross_axis":
        receiver = f"{truth['sensor']}{truth['into']}"
        fraction = float(truth["fraction"])
        est = _number(_parameter(params, "fraction"))
        found = _parameter(params, "receiver")
        if est is None:
            return {**empty, "truth": fraction}
        rel = abs(est) / fraction - 1.0
        right = found in (None, receiver)
        return {
            "estimate": est,
            "truth": fraction,
            "error": rel,
            "within": right and abs(rel) <= 0.1,
        }
    if effect == "mains_hum":
        f0 = float(truth["frequency_hz"])
        est = _number(_parameter(params, "frequency_hz"))
        if est is None:
            return {**empty, "truth": f0}
        return {"estimate": est, "truth": f0, "error": est - f0, "within": abs(est - f0) < 0.5}
    return empty


def run_case(effect: str, seed: int, settings: Settings) -> dict[str, Any]:
    """Record the case on the rig, diagnose it, and compare with the truth."""
    import jax

    setup_jax()

    from bayesdoor.diagnose import diagnose_campaign
    from bayesdoor.door import DOOR_CATALOGUE, ElevatorDoor
    from bayesdoor.door.rig import VirtualRig
    from bayesdoor.pipeline import json_safe

    effects = hidden_effect(effect, seed)
    rng = np.random.default_rng(1000 + seed)
    speeds = np.sort(rng.uniform(settings.v_low, settings.v_high, settings.runs))
    start = time.perf_counter()
    recording = VirtualRig(effects=effects).run(
        ["healthy"] * settings.runs,
        speeds,
        key=jax.random.key(10_000 * EFFECTS_INDEX[effect] + seed),
    )
    recorded = time.perf_counter() - start
    diagnosis = diagnose_campaign(
        ElevatorDoor(),
        recording.campaign,
        seed=seed,
        quick=settings.quick,
        progress=False,
        catalogue=DOOR_CATALOGUE,
    )
    seconds = time.perf_counter() - start - recorded
    payload = json_safe(diagnosis.to_json())
    truth = effects.to_dict()[effect] if effect != NONE else None
    cause = next((c for c in payload["causes"] if c["name"] == effect), None)
    error = parameter_error(effect, truth, cause) if truth is not None else None
    return {
        "effect": effect,
        "seed": seed,
        "speeds": speeds.tolist(),
        "truth": json_safe(truth),
        "verdict": payload["verdict"],
        "named": payload["verdict"] == effect,
        "signature_verdict": payload.get("signature_verdict"),
        "parameter": error,
        "gain": None if cause is None else cause.get("gain"),
        "causes": [c["name"] for c in payload["causes"]],
        "refits": [
            {k: c[k] for k in ("name", "score", "configuration", "gain", "confirmed")}
            for c in payload["causes"]
            if c["gain"] is not None
        ],
        "features": payload["features"],
        "timings": payload["timings"],
        "notes": payload.get("notes", []),
        "code": code_version(),
        "record_seconds": recorded,
        "diagnose_seconds": seconds,
    }


def _case_file(work: Path, effect: str, seed: int, settings: Settings) -> Path:
    return work / f"{effect}-{seed}-{settings.digest()}.json"


def _run_and_save(effect: str, seed: int, settings: Settings, path: str) -> dict[str, Any]:
    result = attempt(run_case, effect, seed, settings)
    if "error" in result:
        result["named"] = False
    save_json(Path(path), result)
    return result


# ---------------------------------------------------------------------------------- table


def _error_text(effect: str, errors: Sequence[float]) -> str:
    if not errors:
        return "-"
    e = np.abs(np.asarray(errors, dtype=float))
    if effect in ("rail_waviness", "wheel_eccentricity", "sensor_cross_axis"):
        return f"{100 * np.median(e):.1f} % / {100 * e.max():.1f} %"
    return f"{np.median(e):.2f} / {e.max():.2f} Hz"


def _refits_text(refits: Sequence[Mapping[str, Any]] | None) -> str:
    """Each refitted cause: its held-out ELPD gain in standard errors and its J change."""
    if not refits:
        return "-"
    words = []
    for r in refits:
        g = r["gain"]
        ratio = g["delta_elpd"] / g["elpd_se"] if g["elpd_se"] > 0 else 0.0
        star = "*" if r["confirmed"] else ""
        words.append(f"{r['name']}{star} {ratio:+.1f}, {g['delta_j']:+.3f}")
    return "; ".join(words)


def table(cases: Sequence[Mapping[str, Any]], command: str, settings: Settings, wall: float) -> str:
    """The markdown of ``results/diagnosis.md``."""
    total = sum(c.get("diagnose_seconds", 0.0) for c in cases)
    codes = sorted({str(c.get("code", "code not recorded")) for c in cases})
    lines = [
        "# Discrepancy diagnosis on hidden rig effects",
        "",
        f"Made by `{command}` ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
        f"{platform.node() or 'this machine'}, {os.cpu_count()} CPUs, load average "
        f"{os.getloadavg()[0]:.1f} at the end; {len(cases)} cases, {total / 60:.0f} min of "
        f"diagnosis in all, {wall / 60:.1f} min wall in the last call, which computed the "
        "cases not already saved; the times are per case, in one process). The cases were "
        f"computed by {' and '.join(codes)}.",
        "",
        f"Each case: {settings.runs} healthy runs of the virtual rig at speeds drawn uniformly "
        f"in {settings.v_low}-{settings.v_high} m/s, one effect drawn by `from_seed(seed)` "
        "(nothing for `none`), diagnosed by `diagnose_campaign(ElevatorDoor(), campaign, "
        f"seed=seed, quick={settings.quick})` with its own base fit. A case is *named* when "
        "the verdict is its effect; the key parameter is that of the effect's cause in the "
        "diagnosis (named or not), compared with the rig's truth.",
        "",
        "The verdict is decided by the refits' held-out gain (`rule` in the diagnosis JSON); "
        "the *signature verdict* is what the residual features alone point to (before any "
        "refit). The key parameter's error is absolute for frequencies and relative for "
        "lengths and fractions; *within tolerance* applies the tolerance stated with it. "
        "Times are the diagnosis's (base fit, predictive simulations, features, refits), "
        "without recording the rig runs.",
        "",
        "| effect | cases | named | detection rate | other verdicts | key parameter "
        "(tolerance) | median / max error | within tolerance | median time (s) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for effect in (*EFFECTS, NONE):
        mine = [c for c in cases if c["effect"] == effect]
        if not mine:
            continue
        named = sum(bool(c["named"]) for c in mine)
        others: dict[str, int] = {}
        for c in mine:
            if not c["named"]:
                key = "failed" if "error" in c else str(c["verdict"])
                others[key] = others.get(key, 0) + 1
        other = ", ".join(f"{k} x{v}" for k, v in sorted(others.items())) or "-"
        times = [c["diagnose_seconds"] for c in mine if "diagnose_seconds" in c]
        if effect == NONE:
            lines.append(
                f"| none (false alarms: {len(mine) - named}) | {len(mine)} | {named} | "
                f"{100 * named / len(mine):.0f} % answer none | {other} | - | - | - | "
                f"{fmt(float(np.median(times)) if times else None, '.0f')} |"
            )
            continue
        params = [c["parameter"] for c in mine if c.get("parameter")]
        errors = [p["error"] for p in params if p["error"] is not None]
        within = [p["within"] for p in params if p["within"] is not None]
        lines.append(
            f"| {effect} | {len(mine)} | {named} | {100 * named / len(mine):.0f} % | {other} | "
            f"{KEY_PARAMETER[effect]} | {_error_text(effect, errors)} | "
            f"{sum(within)} of {len(within)} | "
            f"{fmt(float(np.median(times)) if times else None, '.0f')} |"
        )
    lines += [
        "",
        "## Cases",
        "",
        "| effect | seed | verdict | signature verdict | key parameter: estimate / truth | "
        "gain (delta ELPD +- se, delta J) | refits (delta ELPD / se, delta J; * confirmed) | "
        "time (s) | notes |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c in sorted(cases, key=lambda c: (EFFECTS_INDEX[c["effect"]], c["seed"])):
        if "error" in c:
            lines.append(
                f"| {c['effect']} | {c['seed']} | failed | - | - | - | - | - | {c['error'][:120]} |"
            )
            continue
        p = c.get("parameter") or {}
        estimate = (
            "-"
            if p.get("truth") is None
            else f"{fmt(p.get('estimate'), '.4g')} / {fmt(p.get('truth'), '.4g')}"
        )
        g = c.get("gain") or {}
        gain = (
            "-"
            if not g
            else f"{fmt(g.get('delta_elpd'), '.1f')} +- {fmt(g.get('elpd_se'), '.1f')}, "
            f"{fmt(g.get('delta_j'), '.3g')}"
        )
        notes = "; ".join(c.get("notes") or [])[:120] or "-"
        lines.append(
            f"| {c['effect']} | {c['seed']} | {c['verdict']} | {c.get('signature_verdict')} | "
            f"{estimate} | {gain} | {_refits_text(c.get('refits'))} | "
            f"{c['diagnose_seconds']:.0f} | {notes} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1 seed, 6 runs, quick diagnosis")
    parser.add_argument(
        "--diagnosis",
        choices=("quick", "full"),
        default=None,
        help="sizes of diagnose_campaign (default: quick with --quick, else full)",
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=None, help="default 0-9 (quick: 0)")
    parser.add_argument("--none-seeds", type=int, default=None, help="cases of nothing hidden")
    parser.add_argument("--effects", nargs="+", default=list(EFFECTS), choices=EFFECTS)
    parser.add_argument("--runs", type=int, default=None, help="runs per case (default 8, quick 6)")
    parser.add_argument("--jobs", type=int, default=1, help="cases in parallel (processes)")
    parser.add_argument("--work", type=Path, default=ROOT / "out" / "diagnosis")
    parser.add_argument("--results", type=Path, default=ROOT / "results" / "diagnosis.md")
    args = parser.parse_args(argv)

    seeds = args.seeds if args.seeds is not None else ([0] if args.quick else list(range(10)))
    n_none = args.none_seeds if args.none_seeds is not None else len(seeds)
    settings = Settings(
        runs=args.runs if args.runs is not None else (6 if args.quick else 8),
        v_low=0.25,
        v_high=0.5,
        quick=args.quick if args.diagnosis is None else args.diagnosis == "quick",
    )
    # seed by seed, so that a run cut short has finished cases of every effect
    cases = sorted(
        [(e, s) for e in args.effects for s in seeds] + [(NONE, s) for s in range(n_none)],
        key=lambda c: (c[1], EFFECTS_INDEX[c[0]]),
    )
    args.work.mkdir(parents=True, exist_ok=True)
    todo = [(e, s) for e, s in cases if not _case_file(args.work, e, s, settings).is_file()]
    start = time.perf_counter()
    print(
        f"{len(cases)} cases, {len(cases) - len(todo)} already done, {args.jobs} jobs", flush=True
    )

    def finished(case: tuple[str, int], row: dict[str, Any]) -> None:
        print(
            f"[{time.perf_counter() - start:7.0f} s] {case[0]} seed {case[1]}: {row['verdict']}",
            flush=True,
        )

    calls = {(e, s): (e, s, settings, str(_case_file(args.work, e, s, settings))) for e, s in todo}
    run_cases(_run_and_save, calls, args.jobs, finished)
    results = [json.loads(_case_file(args.work, e, s, settings).read_text()) for e, s in cases]
    command = command_line("diagnosis.py", argv)
    write_results(args.results, table(results, command, settings, time.perf_counter() - start))


if __name__ == "__main__":
    main()
