"""Detection limits against simulate-refit-judge loops on the rig -> results/diagnosis_limits.md.

1. The virtual rig records 12 healthy runs over 0.25-0.50 m/s with nothing hidden (key
   ``--base-key``); the base model is fitted on them (CMA-ES, the diagnosis tests' quick
   settings) and every catalogue cause's detection limit is computed on them
   (``bayesdoor.diagnose.detection_limits``, timed): the size the decision rule names with
   80 % probability, in the cause's typical configuration.
2. For each validated cause and each factor (``--factors``, default 0.5 and 1.5), the rig
   records the same 12 speeds with the cause hidden at factor x limit in that configuration,
   under keys ``--first-seed`` on (keys never used while the limits were built); the cause's
   typical extension (its ``SizeProbe``'s proposal, started at the probe's reference size) is
   refitted on half of the runs and judged on the other half, both ways (the diagnosis's
   refit and judgement, ``extension_gain``'s, quick budget, the scatter one value per channel
   as in the limits of step 1) under the base fit of step 1: *named* when the rule is
   decisive (held-out log density and J). With ``--full`` the whole diagnosis runs as
   well (``diagnose_campaign``, quick, under the same fit): *verdict* is its answer, which
   also needs the residual features to show the cause first.
3. The naming rates with Wilson 95 % intervals, against the computed power at that size; the
   figure puts every cause's power curve beside its observed rates.

The frame mode is not validated: the rig's mode (modal mass 20 kg lifting the rail, read by
each channel at its participation) is not the catalogue's output mode whose participation is
the limit's size, so no rig size corresponds to a stated limit.

Usage::

    .venv/bin/python scripts/diagnosis_limits.py [--seeds 10] [--first-seed 5000]
        [--causes mains_hum sensor_cross_axis rail_waviness wheel_eccentricity]
        [--factors 0.5 1.5] [--full] [--work out/diagnosis-limits]
        [--results results/diagnosis_limits.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
from _cases import ROOT, code_version, command_line, setup_jax, write_results

SPEEDS = tuple(float(v) for v in np.round(np.linspace(0.25, 0.50, 12), 3))
VALIDATED = ("mains_hum", "sensor_cross_axis", "rail_waviness", "wheel_eccentricity")


def rig_effect(cause: str, size: float, seed: int):
    """The rig's effect of ``cause`` at ``size`` in the catalogue's typical configuration
    (``DOOR_CATALOGUE``'s first ``SizeProbe``); phases drawn from ``seed``."""
    from bayesdoor.door import rig

    rng = np.random.default_rng(seed)
    if cause == "mains_hum":
        return rig.Effects(mains_hum=rig.MainsHum(frequency_hz=50.0, amplitude=size))
    if cause == "sensor_cross_axis":
        return rig.Effects(
            sensor_cross_axis=rig.SensorCrossAxis(sensor="A1", into="X", fraction=size)
        )
    if cause == "rail_waviness":
        return rig.Effects(
            rail_waviness=rig.RailWaviness(
                wavelength_m=25e-3, amplitude_m=size, phase=float(rng.uniform(0, 2 * np.pi))
            )
        )
    if cause == "wheel_eccentricity":
        k = np.arange(1, 7)
        return rig.Effects(
            wheel_eccentricity=rig.WheelEccentricity(
                "left",
                tuple(float(a) for a in size / k),
                tuple(float(p) for p in rng.uniform(0, 2 * np.pi, k.size)),
            )
        )
    raise ValueError(f"{cause!r} is not validated here; use one of {VALIDATED}")


def record(effects: Any, key: int, speeds: tuple[float, ...] = SPEEDS):
    import jax

    from bayesdoor.door.rig import VirtualRig

    rig = VirtualRig(effects=effects)
    return rig.run(["healthy"] * len(speeds), list(speeds), key=jax.random.key(key)).campaign


def quick_fit(campaign: Any) -> Any:
    """The base door fitted on a campaign's calibration runs (CMA-ES, the diagnosis tests'
    quick settings)."""
    from bayesdoor.door import ElevatorDoor
    from bayesdoor.inference import FitSettings, fit_campaign

    settings = FitSettings(max_motion_s=1.0, cmaes_max_evals=80, cmaes_restarts=0)
    return fit_campaign(ElevatorDoor(), campaign, settings=settings, seed=0, progress=False)


def limits_of(campaign: Any, fit: Any) -> dict[str, Any]:
    """Every catalogue cause's detection limit on a campaign under its base fit."""
    from bayesdoor.diagnose import detection_limits
    from bayesdoor.diagnose._measured import Measured, _band, _simulate_rows
    from bayesdoor.door import DOOR_CATALOGUE, ElevatorDoor
    from bayesdoor.inference import calibration_runs

    door = ElevatorDoor()
    measured = Measured.of(door, campaign, calibration_runs(campaign))
    sims, _, times = _simulate_rows(door, measured, [dict(fit.point)])
    setup = measured.setup(door, fit.point, sims[0], times, _band(fit), None)
    return dict(detection_limits(setup, DOOR_CATALOGUE))


def diagnose_quick(campaign: Any, fit: Any, seed: int) -> Any:
    """The whole diagnosis of a campaign under a given base fit (quick settings)."""
    from bayesdoor.diagnose import diagnose_campaign
    from bayesdoor.door import DOOR_CATALOGUE, ElevatorDoor

    return diagnose_campaign(
        ElevatorDoor(),
        campaign,
        fit=fit,
        seed=seed,
        quick=True,
        progress=False,
        catalogue=DOOR_CATALOGUE,
    )


def base(work: Path, key: int) -> tuple[Any, Any, dict[str, Any], float]:
    """The nothing-hidden campaign, its base fit and the limits computed on it (seconds)."""
    import xarray as xr

    from bayesdoor.inference import FitResult

    folder = work / f"base-{key}"
    if (folder / "fit" / "fit.json").is_file():
        campaign = xr.load_dataset(folder / "campaign.nc")
        fit = FitResult.load(folder / "fit")
    else:
        folder.mkdir(parents=True, exist_ok=True)
        campaign = record(_no_effects(), key)
        fit = quick_fit(campaign)
        fit.save(folder / "fit", force=True)
        campaign.to_netcdf(folder / "campaign.nc")
    t0 = time.perf_counter()
    limits = limits_of(campaign, fit)
    return campaign, fit, limits, time.perf_counter() - t0


def _no_effects():
    from bayesdoor.door.rig import Effects

    return Effects()


#: the base model's signals of a campaign's runs at the fit's point, by record length and
#: commanded speeds, simulated once each
_BASE: dict[tuple[int, tuple[float, ...]], Any] = {}


def _judge(campaign: Any, proposal: Any, fit: Any, seed: int, tracking: bool) -> Any:
    """``extension_gain`` with the base model's simulation shared between loops."""
    from bayesdoor.diagnose import DiagnosisSettings
    from bayesdoor.diagnose._held_out import _cross_validate, held_out_folds
    from bayesdoor.diagnose._measured import Measured, _band, _simulate_rows
    from bayesdoor.door import ElevatorDoor
    from bayesdoor.inference import calibration_runs

    door = ElevatorDoor()
    settings = DiagnosisSettings.quick()
    measured = Measured.of(door, campaign, calibration_runs(campaign))
    # the rig's records differ in length between keys
    at = (measured.signals.shape[-1], tuple(np.round(np.ravel(measured.operating), 6)))
    if at not in _BASE:
        sims, _, times = _simulate_rows(door, measured, [dict(fit.point)])
        _BASE[at] = (sims[0], times)
    signals, times = _BASE[at]
    setup = measured.setup(door, fit.point, signals, times, _band(fit), None)
    folds = held_out_folds(measured.operating, settings.folds)
    refits, gain = _cross_validate(
        setup,
        proposal,
        folds,
        seed=seed,
        max_evals=settings.refit_evals,
        tracking=tracking,
        workers=settings.workers,
    )
    return refits, gain


def loop(
    cause: str, size: float, seed: int, fit: Any, full: bool, speeds: tuple[float, ...] = SPEEDS
) -> dict[str, Any]:
    """One simulate-refit-judge loop: record, refit the typical extension, judge."""
    from bayesdoor.door import DOOR_CATALOGUE

    t0 = time.perf_counter()
    campaign = record(rig_effect(cause, size, seed), seed, speeds)
    candidate = next(c for c in DOOR_CATALOGUE.candidates if c.name == cause)
    band = (float(fit.feature_spec.f_low), float(fit.feature_spec.f_high))
    probe = candidate.refit.size(band=band).probes[0]
    start = {n: float(v[0]) for n, v in probe.values(probe.reference, 1).items()}
    proposal = dataclasses.replace(probe.proposal, start={**probe.proposal.start, **start})
    from bayesdoor.diagnose._held_out import tracks_speed

    refits, gain = _judge(campaign, proposal, fit, seed, tracks_speed(candidate.signature))
    row: dict[str, Any] = {
        "cause": cause,
        "size": size,
        "seed": seed,
        "named": bool(gain.decisive),
        "evidence_se": float(gain.elpd_difference / gain.elpd_se) if gain.elpd_se > 0 else None,
        "statistic": gain.statistic,
        "per_run": [float(x) for x in gain.per_run],
        "runs": [int(r) for r in gain.runs],
        "speeds": [float(v) for v in speeds],
        "refits": [{k: float(r.values[k]) for k in proposal.free if k in r.values} for r in refits],
    }
    if full:
        diagnosis = diagnose_quick(campaign, fit, seed)
        row["verdict"] = diagnosis.verdict
        row["confirmed"] = [c.name for c in diagnosis.confirmed]
    row["wall_s"] = time.perf_counter() - t0
    return row


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return float(max(0.0, centre - half)), float(min(1.0, centre + half))


def figure(limits: dict[str, Any], rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    causes = [c for c in limits if any(r["cause"] == c for r in rows)] or list(limits)
    fig, axes = plt.subplots(1, len(causes), figsize=(3.4 * len(causes), 3.2), sharey=True)
    for ax, cause in zip(np.atleast_1d(axes), causes, strict=True):
        limit = limits[cause]
        curve = limit.curves[0]
        scale, unit = limit.display[1], limit.display[0] or limit.unit
        ax.semilogx(curve.sizes * scale, curve.probability, "-", label="computed power")
        mine = [r for r in rows if r["cause"] == cause]
        for size in sorted({r["size"] for r in mine}):
            at = [r for r in mine if r["size"] == size]
            k = sum(r["named"] for r in at)
            lo, hi = wilson(k, len(at))
            ax.errorbar(
                size * scale,
                k / len(at),
                yerr=[[max(k / len(at) - lo, 0.0)], [max(hi - k / len(at), 0.0)]],
                fmt="o",
                color="C3",
                capsize=3,
                label="refit-judge loops" if size == min(r["size"] for r in mine) else None,
            )
        if limit.size is not None:
            ax.axvline(limit.size * scale, color="0.6", ls=":", lw=0.8)
        ax.axhline(limit.power, color="0.6", ls="--", lw=0.8)
        ax.set_title(cause, fontsize=9)
        ax.set_xlabel(f"{limit.quantity} ({unit})", fontsize=8)
    np.atleast_1d(axes)[0].set_ylabel("probability of naming")
    np.atleast_1d(axes)[0].legend(fontsize=7, frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=5000)
    parser.add_argument("--base-key", type=int, default=4999)
    parser.add_argument("--causes", nargs="+", default=list(VALIDATED))
    parser.add_argument("--factors", nargs="+", type=float, default=[0.5, 1.5])
    parser.add_argument("--full", action="store_true")
    parser.add_argument(
        "--work",
        type=Path,
        default=ROOT / "out" / "diagnosis-limits",
        help="where the base fit and each loop's outcome are kept, a subfolder per code version",
    )
    parser.add_argument("--results", type=Path, default=ROOT / "results" / "diagnosis_limits.md")
    parser.add_argument(
        "--follow-plan",
        nargs=2,
        metavar=("CAUSE", "SIZE"),
        help="plan the campaign that names CAUSE at SIZE (its unit, e.g. 15e-6 m) from the "
        "nothing-hidden campaign, record it on the rig with the cause hidden at SIZE, and "
        "judge the refit, per seed",
    )
    args = parser.parse_args(argv)
    setup_jax()
    started = time.time()
    # (the digest of the source, not this script's commit stamp, _cases.code_version)
    from bayesdoor._exported import code_version as source_digest

    # what the folder keeps (the base fit, each loop's outcome) was made by this code only: a
    # change of bayesdoor's source or of the tracing libraries starts a folder of its own
    args.work = args.work / f"code-{source_digest()[:12]}"
    args.work.mkdir(parents=True, exist_ok=True)
    if args.follow_plan:
        follow_plan(args, args.follow_plan[0], float(args.follow_plan[1]), started)
        return
    _, fit, limits, limit_s = base(args.work, args.base_key)
    rows: list[dict[str, Any]] = []
    # seed by seed, so that a run stopped early has every cause and factor alike
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        for cause in args.causes:
            limit = limits[cause]
            if limit.size is None:
                continue
            for factor in args.factors:
                size = float(factor * limit.size)
                path = args.work / f"{cause}-{factor:g}-{size:.4g}-{seed}.json"
                if path.is_file():
                    row = json.loads(path.read_text())
                else:
                    row = loop(cause, size, seed, fit, args.full)
                    path.write_text(json.dumps(row))
                row["factor"] = factor
                rows.append(row)
                print(cause, factor, seed, row["named"], row.get("evidence_se"), flush=True)
    png = args.results.with_suffix(".png")
    figure(limits, rows, png)
    write_results(args.results, table(args, limits, limit_s, rows, time.time() - started, png))


def follow_plan(args: Any, cause: str, size: float, started: float) -> None:
    """The planned campaign for ``cause`` at ``size``, recorded by the rig and judged."""
    from bayesdoor.diagnose import plan_campaign
    from bayesdoor.door import DOOR_CATALOGUE, ElevatorDoor

    campaign, fit, limits, _ = base(args.work, args.base_key)
    limit = limits[cause]
    plan = plan_campaign(ElevatorDoor(), campaign, cause, size, fit=fit, catalogue=DOOR_CATALOGUE)
    print(plan.describe(), flush=True)
    if plan.runs_per_condition is None:
        raise SystemExit(f"no campaign names {cause} at {size}: {plan.describe()}")
    speeds = tuple(float(c) for c in plan.conditions for _ in range(plan.runs_per_condition))
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        path = args.work / f"plan-{cause}-{size:.4g}-{len(speeds)}-{seed}.json"
        if path.is_file():
            row = json.loads(path.read_text())
        else:
            row = loop(cause, size, seed, fit, False, speeds)
            path.write_text(json.dumps(row))
        row["factor"] = size / limit.size
        rows.append(row)
        print(cause, seed, row["named"], row.get("evidence_se"), flush=True)
    k, n = sum(r["named"] for r in rows), len(rows)
    lo, hi = wilson(k, n)
    lines = [
        f"# Following the plan: {cause} at {limit.shown(size)}",
        "",
        f"Made by `{command_line('diagnosis_limits.py', None)}` "
        f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {platform.node()}, "
        f"{code_version()}; {time.time() - started:.0f} s).",
        "",
        f"From the nothing-hidden 12-run campaign (rig key {args.base_key}) and its base fit, "
        f"`plan_campaign` answers: {plan.describe()}. Each loop records that campaign on the "
        f"rig with the cause hidden at {limit.shown(size)} in its typical configuration (seeds "
        f"{args.first_seed}-{args.first_seed + args.seeds - 1}), refits the typical extension "
        "on half of the runs and judges it on the other half (both ways), under the base fit.",
        "",
        "| cause | size | planned runs | named | rate (95 % CI) | planned probability | "
        "mean evidence (SE) |",
        "|---|---|---|---|---|---|---|",
        f"| {cause} | {limit.shown(size)} | {len(speeds)} | {k} of {n} | {k / n:.2f} "
        f"({lo:.2f}-{hi:.2f}) | {plan.probability:.2f} | "
        f"{np.mean([r['evidence_se'] for r in rows if r['evidence_se'] is not None]):.1f} |",
        "",
        *_per_loop(rows, limits),
    ]
    write_results(args.results, "\n".join(lines))


def table(args, limits, limit_s, rows, wall, png) -> str:
    lines = [
        "# Detection limits on the rig: stated limits against refit-judge loops",
        "",
        f"Made by `{command_line('diagnosis_limits.py', None)}` "
        f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {platform.node()}, "
        f"{code_version()}; {wall:.0f} s).",
        "",
        f"The limits of every cause on the nothing-hidden 12-run campaign (rig key "
        f"{args.base_key}; computed in {limit_s:.1f} s, the base simulation included):",
        "",
        "| cause | size | configuration | limit (80 %) | other configurations | "
        "campaign for half the limit |",
        "|---|---|---|---|---|---|",
    ]
    for name, limit in limits.items():
        others = "; ".join(f"{c.label}: {limit.shown(c.limit)}" for c in limit.curves[1:])
        plan = "-" if limit.plan is None else limit.plan.describe()
        lines.append(
            f"| {name} | {limit.quantity} | {limit.curves[0].label} | "
            f"{limit.shown(limit.size)} | {others or '-'} | {plan} |"
        )
    lines += [
        "",
        f"Named in the loops (seeds {args.first_seed}-{args.first_seed + args.seeds - 1}; "
        "Wilson 95 % intervals; the computed power at that size beside it):",
        "",
        "| cause | factor x limit | size | named | rate (95 % CI) | computed power | "
        "computed evidence (SE) | mean evidence (SE) |"
        + (" full diagnosis: verdict = cause |" if args.full else ""),
        "|---|---|---|---|---|---|---|---|" + ("---|" if args.full else ""),
    ]
    for name in args.causes:
        limit = limits[name]
        for factor in args.factors:
            at = [r for r in rows if r["cause"] == name and r["factor"] == factor]
            if not at:
                continue
            k, n = sum(r["named"] for r in at), len(at)
            lo, hi = wilson(k, n)
            size = at[0]["size"]
            ev = [r["evidence_se"] for r in at if r["evidence_se"] is not None]
            line = (
                f"| {name} | {factor:g} | {limit.shown(size)} | {k} of {n} | "
                f"{k / n:.2f} ({lo:.2f}-{hi:.2f}) | {limit.curves[0].at(size):.2f} | "
                f"{_evidence_at(limit.curves[0], size):.1f} | {np.mean(ev):.1f} |"
            )
            if args.full:
                v = sum(r.get("verdict") == name for r in at)
                line += f" {v} of {n} |"
            lines.append(line)
    lines += ["", f"![power curves and observed naming rates]({png.name})", ""]
    lines += _per_loop(rows, limits)
    return "\n".join(lines)


def _per_loop(rows: list[dict[str, Any]], limits: dict[str, Any]) -> list[str]:
    """Each loop's held-out differences per run and the values its two folds refitted."""
    rows = [r for r in rows if r.get("per_run")]
    if not rows:
        return []
    lines = [
        "Per loop (the held-out log-density difference of each run, extended minus base; "
        "the run that loses most, at its commanded speed; the free values each fold refitted, "
        "in the unit of the limit):",
        "",
        "| cause | factor x limit | seed | named | evidence (SE) | per-run differences "
        "(median, smallest at run: speed m/s) | refitted per fold |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in sorted(rows, key=lambda r: (r["cause"], r["factor"], r["seed"])):
        diffs = np.asarray(r["per_run"])
        worst = int(np.argmin(diffs))
        run = r["runs"][worst]
        limit = limits[r["cause"]]
        scale = limit.display[1]
        fits = " / ".join(
            ", ".join(f"{k.split('.')[-1]} {v * scale:.3g}" for k, v in fold.items())
            for fold in r.get("refits", [])
        )
        ev = "-" if r["evidence_se"] is None else f"{r['evidence_se']:.1f}"
        lines.append(
            f"| {r['cause']} | {r['factor']:g} | {r['seed']} | {'yes' if r['named'] else 'no'} "
            f"| {ev} | {np.median(diffs):+.1f}, {diffs[worst]:+.1f} at run {run}: "
            f"{r.get('speeds', SPEEDS)[run]:.3f} | {fits or '-'} |"
        )
    return [*lines, ""]


def _evidence_at(curve: Any, size: float) -> float:
    """The computed expected held-out gain in standard errors at ``size`` (interpolated in
    log size)."""
    return float(np.interp(np.log(size), np.log(curve.sizes), curve.evidence))


if __name__ == "__main__":
    main()
