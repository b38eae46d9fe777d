"""Transfer to doors bayesdoor did not simulate: the main job on a family of other doors.

Each door (``bayesdoor.door.rig.OtherDoor.from_seed(seed)``) differs from the reduced model in ways
it lacks: an extra structural mode at 8-40 Hz, a drive speed bias, wider friction scatter,
per-channel sensor gains, sensor mounting, coloured noise (``docs/transfer.md``). Each records
a campaign of healthy calibration runs and test runs of the three states at 0.3, 0.4 and
0.5 m/s. The main job (``bayesdoor.pipeline.run_job``, ``--quick`` sizes unless ``--full``)
fits the door once on its calibration runs, then for each training source simulates, trains,
classifies the test runs and judges its own trust (fit adequacy, the calibration runs'
recognition, the OOD rate). The test labels serve only for the scores.

Seeds from ``--held-out-from`` on were not looked at while the defaults were chosen; the
table reports them apart.

Usage::

    .venv/bin/python scripts/transfer.py [--doors 20] [--held-out-from 12] [--out out/transfer]
        [--calibration 10] [--test-per-state 20] [--sources ...] [--demo-seeds 0 1 2]
        [--tables-only]

``--doors 0 --demo-seeds 0`` runs the demo campaign only (both write into one results file).
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import time
from pathlib import Path
from typing import Any

from _cases import code_version, command_line, fmt, write_results

ROOT = Path(__file__).resolve().parent.parent
SOURCES = ("posterior+model_error", "posterior", "gaussian")
DEFAULT_SOURCE = "posterior+model_error"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--doors", type=int, default=20, help="seeds 0 .. DOORS-1")
    parser.add_argument("--held-out-from", type=int, default=12)
    parser.add_argument("--calibration", type=int, default=10)
    parser.add_argument("--test-per-state", type=int, default=20)
    parser.add_argument("--sources", nargs="+", default=list(SOURCES))
    parser.add_argument("--full", action="store_true", help="the paper's sizes, not --quick")
    parser.add_argument(
        "--full-training",
        action="store_true",
        help="the paper's generation and training sizes with the quick fit (reused from --out)",
    )
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "transfer")
    parser.add_argument("--results", type=Path, default=ROOT / "results" / "transfer.md")
    parser.add_argument("--only", type=int, nargs="*", default=None, help="run these seeds only")
    parser.add_argument("--tables-only", action="store_true", help="rewrite the table only")
    parser.add_argument(
        "--demo-seeds",
        type=int,
        nargs="*",
        default=None,
        help="also the demo campaign (the project's own rig) with these seeds (one fit each)",
    )
    args = parser.parse_args(argv)
    bad = [s for s in args.sources if s not in SOURCES]
    if bad:
        parser.error(f"unknown sources {bad}: allowed {', '.join(SOURCES)}")

    from bayesdoor import configure_jax

    configure_jax()
    args.out.mkdir(parents=True, exist_ok=True)
    rows_file = args.out / "rows.json"
    rows: list[dict[str, Any]] = json.loads(rows_file.read_text()) if rows_file.is_file() else []
    start = time.perf_counter()
    if args.demo_seeds is not None and not args.tables_only:
        demo_rows_file = args.out / "demo_rows.json"
        demo_rows = json.loads(demo_rows_file.read_text()) if demo_rows_file.is_file() else []
        for seed in args.demo_seeds:
            for row in run_demo(args, seed):
                demo_rows = _keep(demo_rows_file, demo_rows, row)
                print(
                    f"[{time.perf_counter() - start:7.1f} s] demo seed {seed} {row['source']}: "
                    f"accuracy {row['accuracy']:.3f}, ECE {row['ece']:.3f}, trust {row['trust']}",
                    flush=True,
                )
    if not args.tables_only and args.doors > 0:
        seeds = range(args.doors) if args.only is None else args.only
        for seed in seeds:
            for row in run_door(args, seed):
                rows = _keep(rows_file, rows, row)
                print(
                    f"[{time.perf_counter() - start:7.1f} s] door {seed} {row['source']}: "
                    f"accuracy {row['accuracy']:.3f}, ECE {row['ece']:.3f}, OOD "
                    f"{row['ood_rate']:.2f}, adequacy {row['adequacy']}, trust {row['trust']}",
                    flush=True,
                )
    write_results(args.results, markdown(args, rows, argv), echo=False)


def _keep(path: Path, rows: list[dict[str, Any]], row: dict[str, Any]) -> list[dict[str, Any]]:
    """``rows`` with ``row`` in place of any of its seed and source, sorted, saved to ``path``
    (after every job, so that an interrupted study keeps what it finished)."""
    rows = [r for r in rows if (r["seed"], r["source"]) != (row["seed"], row["source"])]
    rows.append(row)
    rows.sort(key=lambda r: (r["seed"], SOURCES.index(r["source"])))
    path.write_text(json.dumps(rows, indent=1))
    return rows


def _jobs(args, campaign, folder: Path, seed: int, label: str):
    """The job with each source on ``campaign`` in ``folder/SOURCE``, one fit serving all
    (the first job's fit stage is copied into the others, whose configuration hash reuses it);
    yields the source, the job's result and its seconds."""
    from bayesdoor.door import ElevatorDoor
    from bayesdoor.pipeline import JobConfig, Sizes, run_job

    shared_fit = folder / "fit"
    for source in args.sources:
        job = folder / source
        if shared_fit.is_dir() and not (job / "fit").exists():
            job.mkdir(parents=True, exist_ok=True)
            shutil.copytree(shared_fit, job / "fit")
        t0 = time.perf_counter()
        result = run_job(
            ElevatorDoor(),
            campaign,
            job,
            JobConfig(
                quick=not args.full,
                sizes=Sizes() if args.full_training else None,
                seed=seed,
                source=source,
                html=False,
                diagnosis=False,
            ),
            progress=False,
            report=lambda line, s=source: print(f"  {label} {s}: {line}", flush=True),
            overwrite=True,
        )
        if not shared_fit.is_dir():
            shutil.copytree(job / "fit", shared_fit)
        yield source, result, time.perf_counter() - t0


def job_row(result, source: str, seconds: float) -> dict[str, Any]:
    payload = result.to_json()
    metrics = payload["metrics"]
    adequacy = (payload.get("fit") or {}).get("adequacy") or {}
    trust = payload.get("trust") or {}
    return {
        "source": source,
        "accuracy": metrics["accuracy"],
        "ece": metrics["ece"],
        "ood_rate": metrics["ood_runs"] / metrics["runs"],
        "runs": metrics["runs"],
        "j": payload["fit"].get("j"),
        "adequacy": adequacy.get("verdict"),
        "adequacy_worst": adequacy.get("worst"),
        "trust": trust.get("verdict"),
        "trust_reasons": trust.get("reasons", []) + trust.get("warnings", []),
        "expected_accuracy": ((trust.get("checks") or {}).get("expected_accuracy") or {}).get(
            "simulated_validation"
        ),
        "seconds": seconds,
        "stage_seconds": {st["name"]: st["seconds"] for st in payload["stages"]},
    }


def run_demo(args, seed: int) -> list[dict[str, Any]]:
    """The demo campaign (the project's own rig): one fit per seed, every source."""
    from bayesdoor.door.datasets import load_demo_campaign

    campaign = load_demo_campaign()
    folder = args.out / f"demo-seed{seed}"
    return [
        {"seed": seed, **job_row(result, source, seconds)}
        for source, result, seconds in _jobs(args, campaign, folder, seed, f"demo {seed}")
    ]


def run_door(args, seed: int) -> list[dict[str, Any]]:
    """Record door ``seed`` (cached) and run the job with each source; one row per source."""
    import jax

    from bayesdoor.door.rig import OtherDoor, family_plan
    from bayesdoor.io import load_campaign, save_campaign

    folder = args.out / f"door-{seed:02d}"
    campaign_file = folder / "campaign.nc"
    if not campaign_file.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        states, speeds, split = family_plan(args.calibration, args.test_per_state, seed)
        t0 = time.perf_counter()
        recording = OtherDoor.from_seed(seed).record(
            states, speeds, key=jax.random.key(seed), split=split
        )
        (folder / "truth.json").write_text(json.dumps(recording.truth, indent=1, default=float))
        save_campaign(recording.campaign, campaign_file, overwrite=True)
        print(f"door {seed}: recorded in {time.perf_counter() - t0:.0f} s", flush=True)
    campaign = load_campaign(campaign_file)
    description = json.loads((folder / "truth.json").read_text())["other_door"]
    door = {
        "frame_mode_hz": description["frame_mode"]["frequency_hz"],
        "law": description["parameters"]["I"],
        "speed_bias": description["speed_bias"],
        "gains_db": description["gains_db"],
    }
    # every door is fitted and trained with seed 0: the doors differ, not the seeds
    return [
        {"seed": seed, **job_row(result, source, seconds), "door": door}
        for source, result, seconds in _jobs(args, campaign, folder, 0, f"door {seed}")
    ]


def _summary(values: list[float]) -> str:
    if not values:
        return "-"
    return f"{statistics.median(values):.3f} (worst {min(values):.3f}, best {max(values):.3f})"


def markdown(args, rows: list[dict[str, Any]], argv) -> str:
    """The results file: the distribution per source and split, then door by door."""
    rows = [r for r in rows if r["seed"] < args.doors]
    lines = [
        "# Transfer to other doors",
        "",
        f"Command: `{command_line('transfer.py', argv)}`  ",
        f"Date: {time.strftime('%Y-%m-%d')}  ",
        f"Code: {code_version()}  ",
        f"Machine: {sys.platform}, the job's `--quick` sizes: {not args.full}"
        + (", the paper's generation and training sizes" if args.full_training else ""),
        "",
        "Each door is `OtherDoor.from_seed(seed)` (docs/transfer.md): the rig varied in ways the "
        "reduced model lacks. "
        f"{args.calibration} healthy calibration runs fit the door; "
        f"{args.test_per_state} test runs per state are classified. "
        f"Seeds >= {args.held_out_from} were held out of development.",
        "",
        "## Distribution per source",
        "",
        "| doors | source | doors run | accuracy: median (worst, best) | ECE: median (worst, best)"
        " | OOD rate: median | fit adequate | job trusts itself | below 90 % and not warned |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for held, label in ((False, "development"), (True, "held out")):
        for source in SOURCES:
            sel = [
                r
                for r in rows
                if r["source"] == source and (r["seed"] >= args.held_out_from) == held
            ]
            if not sel:
                continue
            acc = [r["accuracy"] for r in sel]
            ece = [r["ece"] for r in sel]
            ood = [r["ood_rate"] for r in sel]
            adequate = sum(r["adequacy"] == "reproduces" for r in sel)
            trusted = sum(r["trust"] == "trusted" for r in sel)
            silent = sum(r["accuracy"] < 0.9 and r["trust"] == "trusted" for r in sel)
            worst_ece = f"{statistics.median(ece):.3f} (worst {max(ece):.3f}, best {min(ece):.3f})"
            lines.append(
                f"| {label} | `{source}` | {len(sel)} | {_summary(acc)} | {worst_ece} | "
                f"{statistics.median(ood):.3f} | {adequate} of {len(sel)} | "
                f"{trusted} of {len(sel)} | {silent} |"
            )
    demo_file = args.out / "demo_rows.json"
    demo = json.loads(demo_file.read_text()) if demo_file.is_file() else []
    if demo:
        lines += [
            "",
            "## The project's own rig (the demo campaign, 300 test runs)",
            "",
            "The same job on `bayesdoor demo`'s campaign, recorded by the project's rig, which "
            "shares the reduced model's reading of the design: the reference the family is "
            "held against. One fit per seed serves every source.",
            "",
            "| source | seeds | accuracy per seed | ECE per seed | trust |",
            "|---|---|---|---|---|",
        ]
        for source in SOURCES:
            sel = [r for r in demo if r["source"] == source]
            if not sel:
                continue
            accuracy = " ".join(format(r["accuracy"], ".3f") for r in sel)
            ece = " ".join(format(r["ece"], ".3f") for r in sel)
            lines.append(
                f"| `{source}` | {' '.join(str(r['seed']) for r in sel)} | {accuracy} | {ece} | "
                f"{', '.join(sorted({str(r['trust']) for r in sel}))} |"
            )
    shares = [
        (r["stage_seconds"].get("adequacy", 0.0) + r["stage_seconds"].get("trust", 0.0))
        / sum(r["stage_seconds"].values())
        for r in [*rows, *demo]
        if r.get("stage_seconds") and r["source"] == DEFAULT_SOURCE
    ]
    if shares:
        lines += [
            "",
            "## What the checks cost",
            "",
            "The adequacy and trust stages' share of the job's time (every stage's own compute "
            "time, the shared fit included; the job without the diagnosis and the HTML report), "
            f"default source, {len(shares)} jobs: median {100 * statistics.median(shares):.1f} %, "
            f"largest {100 * max(shares):.1f} %.",
        ]
    lines += [
        "",
        "## Door by door",
        "",
        "| seed | split | frame mode (Hz) | law | speed bias | gains (dB) | J | source "
        "| accuracy | ECE | OOD rate | expected accuracy | fit adequacy | trust | reasons |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        d = r["door"]
        gains = " ".join(f"{g:+.1f}" for g in d["gains_db"])
        lines.append(
            f"| {r['seed']} | {'held out' if r['seed'] >= args.held_out_from else 'dev'} | "
            f"{d['frame_mode_hz']:.1f} | {d['law']} | {d['speed_bias']:+.3f} | {gains} | "
            f"{fmt(r['j'], '.2f')} | `{r['source']}` | {r['accuracy']:.3f} | {r['ece']:.3f} | "
            f"{r['ood_rate']:.2f} | {fmt(r.get('expected_accuracy'), '.3f')} | "
            f"{r['adequacy'] or '-'} | {r['trust'] or '-'} | "
            f"{'; '.join(r['trust_reasons']) or '-'} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
