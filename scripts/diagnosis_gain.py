"""The downstream gain of a diagnosed extension -> results/diagnosis_gain.md.

Each case hides one catalogue effect, drawn by the rig's ``from_seed(seed)`` (parameters the
seed's, not chosen to suit anything), in every run of a virtual-rig campaign planned like the
demo campaign (healthy calibration runs; healthy, D1 and D2 test runs at 0.3, 0.4 and 0.5 m/s,
severities from their priors), then:

1. the main job (``bayesdoor.pipeline.run_job``) with the base door: fit on the calibration
   runs, training data, ensemble; accuracy and ECE on the test runs;
2. ``bayesdoor.diagnose.diagnose_campaign`` under that job's fit: the verdict and its held-out
   J and ELPD gain on the calibration runs;
3. the main job again with ``bayesdoor.diagnose.extend_system(door, diagnosis)``: the
   verdict's extension as its refit configured it, held at the refitted values (the door's
   own parameters refitted); accuracy and ECE on the same test runs. A verdict ``none``
   leaves the door as it is (the base job's numbers are repeated).

The test runs are never used by the fits, the diagnosis or the training. Every step is saved
under ``--work`` (the campaign, both jobs' stages, the diagnosis, one JSON per finished case),
so an interrupted command continues where it stopped. Cases run in parallel processes
(``--jobs``), one CPU thread each.

Usage::

    .venv/bin/python scripts/diagnosis_gain.py [--quick] [--effects frame_mode ...]
        [--seeds 0 1 ...] [--test-per-state N] [--jobs N] [--work out/diagnosis_gain]
        [--out results/diagnosis_gain.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from _cases import (
    ROOT,
    attempt,
    code_version,
    command_line,
    digest,
    fmt,
    hidden_effect,
    run_cases,
    save_json,
    saved_diagnosis,
    setup_jax,
    write_results,
)

#: effects that act on what the classifier sees without a new solve (the ones named by the
#: issue first); the others can be asked for with --effects
EFFECTS = ("frame_mode", "sensor_cross_axis", "mains_hum", "wheel_eccentricity", "rail_waviness")
DEFAULT_EFFECTS = ("frame_mode", "sensor_cross_axis", "mains_hum")
SPEEDS = (0.3, 0.4, 0.5)
#: record length of the demo campaign (s): rest, the slowest stroke, rest
DURATION_S = 3.7


@dataclasses.dataclass(frozen=True)
class Settings:
    """What a case depends on (its hash names the case's folder)."""

    fit: str
    diagnosis: str
    calibration_runs: int
    test_per_state: int
    method: str
    source: str
    runs_per_state: int

    def digest(self) -> str:
        return digest(self, 10)


# ------------------------------------------------------------------------------ one case


def plan(settings: Settings, seed: int) -> tuple[list[str], np.ndarray, list[str]]:
    """States, commanded speeds and splits, as the demo campaign plans them (seeded)."""
    rng = np.random.default_rng(7_000 + seed)
    test = np.repeat(["healthy", "D1", "D2"], settings.test_per_state)
    test = test[rng.permutation(test.size)]
    states = ["healthy"] * settings.calibration_runs + [str(s) for s in test]
    speeds = np.resize(np.asarray(SPEEDS), len(states))
    speeds = speeds[rng.permutation(speeds.size)]
    split = ["calibration"] * settings.calibration_runs + ["test"] * test.size
    return states, speeds, split


def record(effect: str, seed: int, settings: Settings, path: Path):
    """The case's campaign (recorded by the rig once, then read) and the rig's truth."""
    import jax

    from bayesdoor.door.rig import VirtualRig
    from bayesdoor.io import load_campaign, save_campaign

    effects = hidden_effect(effect, seed)
    if not path.is_file():
        states, speeds, split = plan(settings, seed)
        index = EFFECTS.index(effect) + 1
        recording = VirtualRig(effects=effects).run(
            states,
            speeds,
            key=jax.random.key(100_000 * index + seed),
            split=split,
            duration=DURATION_S,
        )
        save_campaign(recording.campaign, path, overwrite=True)
    return load_campaign(path), effects.to_dict()[effect]


def job(system, campaign, out: Path, settings: Settings, seed: int, label: str):
    """The main job without its report or diagnosis stages; its metrics and wall time."""
    from bayesdoor.inference import FitSettings
    from bayesdoor.pipeline import JobConfig, Sizes, run_job

    start, cpu = time.perf_counter(), time.process_time()
    sizes = Sizes(runs_per_state=settings.runs_per_state, chunk_size=50)
    quick = settings.fit == "quick"
    result = run_job(
        system,
        campaign,
        out,
        JobConfig(
            quick=quick,
            seed=seed,
            fit_seed=seed,
            source=settings.source,  # type: ignore[arg-type]
            method=settings.method,
            sizes=sizes,
            fit_options={"settings": FitSettings.quick() if quick else FitSettings()},
            html=False,
            diagnosis=False,
        ),
        progress=False,
        report=lambda text: print(f"  {label}: {text}", flush=True),
        overwrite=True,
    )
    m = result.classification["metrics"]
    return {
        "accuracy": float(m["accuracy"]),
        "ece": float(m["ece"]),
        "runs": int(m["runs"]),
        "fit_j": result.fit.j,
        "seconds": time.perf_counter() - start,
        "cpu_seconds": time.process_time() - cpu,
        "reused": [s.name for s in result.stages if s.reused],
    }


def run_case(effect: str, seed: int, settings: Settings, folder: Path) -> dict[str, Any]:
    """Record, base job, diagnosis, extended job: the case's row."""
    setup_jax()

    from bayesdoor.diagnose import extend_system, verdict_extension
    from bayesdoor.door import ElevatorDoor
    from bayesdoor.pipeline import json_safe

    folder.mkdir(parents=True, exist_ok=True)
    name = f"{effect}-{seed}"
    start, cpu = time.perf_counter(), time.process_time()
    campaign, truth = record(effect, seed, settings, folder / "campaign.nc")
    recorded = (time.perf_counter() - start, time.process_time() - cpu)
    door = ElevatorDoor()
    base = job(door, campaign, folder / "base", settings, seed, f"{name} base")
    diagnosis, diagnose_seconds = saved_diagnosis(
        campaign,
        folder / "base" / "fit" / "result",
        folder / "diagnosis.pkl",
        quick=settings.diagnosis == "quick",
        seed=seed,
    )
    found = verdict_extension(door, diagnosis)
    if found is None:
        extended = dict(base, seconds=0.0, cpu_seconds=0.0, reused=["same as base: verdict none"])
        configuration, values = None, {}
    else:
        extended = job(
            extend_system(door, diagnosis), campaign, folder / "extended", settings, seed, name
        )
        configuration = {"label": found.proposal.label, "extension": repr(found.proposal.extension)}
        values = found.values
    cause = next((c for c in diagnosis.causes if c.name == diagnosis.verdict), None)
    return json_safe(
        {
            "effect": effect,
            "seed": seed,
            "truth": truth,
            "verdict": diagnosis.verdict,
            "signature_verdict": diagnosis.ranking.verdict,
            "configuration": configuration,
            "held": values,
            "gain": None if cause is None or cause.gain is None else cause.gain.to_json(),
            "notes": list(diagnosis.notes),
            "base": base,
            "extended": extended,
            "record_seconds": recorded[0],
            "record_cpu_seconds": recorded[1],
            "diagnose_seconds": diagnose_seconds[0],
            "diagnose_cpu_seconds": diagnose_seconds[1],
        }
    )


def _case_folder(work: Path, effect: str, seed: int, settings: Settings) -> Path:
    return work / f"{effect}-{seed}-{settings.digest()}"


def _run_and_save(effect: str, seed: int, settings: Settings, folder: str) -> dict[str, Any]:
    result = attempt(run_case, effect, seed, settings, Path(folder))
    if "error" in result:
        # not saved: the next call of the command tries the case again from its last stage
        print(result["traceback"], file=sys.stderr, flush=True)
    else:
        save_json(Path(folder) / "case.json", result)
    return result


# ---------------------------------------------------------------------------------- table


def _truth_text(effect: str, truth: Mapping[str, Any]) -> str:
    if effect == "frame_mode":
        return f"{truth['frequency_hz']:.1f} Hz, zeta {truth['damping_ratio']:.3f}"
    if effect == "sensor_cross_axis":
        other = "Z" if truth["into"] == "X" else "X"
        return f"{truth['sensor']}{truth['into']} reads {truth['fraction']:.3f} {other}"
    if effect == "mains_hum":
        return f"{truth['frequency_hz']:g} Hz, {1e3 * truth['amplitude']:.0f} mm/s^2"
    if effect == "rail_waviness":
        return f"wavelength {1e3 * truth['wavelength_m']:.1f} mm"
    return f"{truth.get('wheel', '')} wheel"


def table(cases: Sequence[Mapping[str, Any]], command: str, settings: Settings, wall: float) -> str:
    done = [c for c in cases if c.get("error") is None]
    failed = [c for c in cases if c.get("error") is not None]
    lines = [
        "# Downstream gain of a diagnosed extension",
        "",
        f"Command: `{command}`  ",
        f"Date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}  ",
        f"Code: {code_version()}",
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} CPUs; wall time of the command "
        f"{wall:.0f} s (cases in parallel; finished cases are read, not rerun). Settings: "
        f"{json.dumps(dataclasses.asdict(settings))}.",
        "",
        "Per case: a rig campaign with one effect (``from_seed(seed)``) in every run, "
        f"{settings.calibration_runs} healthy calibration runs and {settings.test_per_state} "
        "test runs per state (healthy, D1, D2); the main job with the base door; the diagnosis "
        "under its fit; the main job with the extended door (the verdict's extension held at "
        "its refitted values). Accuracy and ECE (15 bins) on the test runs; the jobs' fits' J "
        "on the calibration runs (the paper's objective at the fit's point); held-out J and "
        "ELPD on the calibration runs (the diagnosis's two folds; ELPD difference with its "
        "standard error). Times: wall (process CPU) seconds of the recording, the base job, the "
        "diagnosis and the extended job (0 where a step was read from an earlier run).",
        "",
        "| effect | seed | truth | verdict (configuration) | base acc. | base ECE | "
        "ext. acc. | ext. ECE | job's fit J base -> ext. | held-out J before -> after | "
        "ELPD gain +- se | times |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in done:
        gain = c.get("gain") or {}
        verdict = c["verdict"]
        if c.get("configuration"):
            verdict += f" ({c['configuration']['label']})"
        j = (
            f"{gain['j_before']:.4f} -> {gain['j_after']:.4f}"
            if gain.get("j_before") is not None
            else "-"
        )
        elpd = (
            f"{gain['delta_elpd']:+.1f} +- {gain['elpd_se']:.1f}"
            if gain.get("delta_elpd") is not None
            else "-"
        )
        b, e = c["base"], c["extended"]
        times = " / ".join(
            f"{wall:.0f} ({cpu:.0f})"
            for wall, cpu in (
                (c["record_seconds"], c["record_cpu_seconds"]),
                (b["seconds"], b["cpu_seconds"]),
                (c["diagnose_seconds"], c["diagnose_cpu_seconds"]),
                (e["seconds"], e["cpu_seconds"]),
            )
        )
        lines.append(
            f"| {c['effect']} | {c['seed']} | {_truth_text(c['effect'], c['truth'])} | "
            f"{verdict} | {100 * b['accuracy']:.1f} % | {fmt(b['ece'], '.3f')} | "
            f"{100 * e['accuracy']:.1f} % | {fmt(e['ece'], '.3f')} | "
            f"{fmt(b['fit_j'], '.4f')} -> {fmt(e['fit_j'], '.4f')} | {j} | {elpd} | {times} |"
        )
    for c in failed:
        lines.append(f"| {c['effect']} | {c['seed']} | failed: {c['error'][:200]} |")
    changed = [c for c in done if c.get("configuration")]
    if changed:
        d_acc = np.array([c["extended"]["accuracy"] - c["base"]["accuracy"] for c in changed])
        d_ece = np.array([c["extended"]["ece"] - c["base"]["ece"] for c in changed])
        lines += [
            "",
            f"Over the {len(changed)} cases with an extension: accuracy change "
            f"{100 * d_acc.mean():+.1f} points (range {100 * d_acc.min():+.1f} to "
            f"{100 * d_acc.max():+.1f}), ECE change {d_ece.mean():+.3f} (range "
            f"{d_ece.min():+.3f} to {d_ece.max():+.3f}); "
            f"{sum(c['verdict'] == c['effect'] for c in done)} of {len(done)} verdicts name the "
            f"hidden effect. With {changed[0]['base']['runs']} test runs per case, one run "
            f"is {100 / changed[0]['base']['runs']:.1f} points of accuracy.",
        ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--quick",
        action="store_true",
        help="quick fits and diagnosis, 10 test runs per state, 60 training runs per state",
    )
    parser.add_argument(
        "--fit",
        choices=("quick", "full"),
        default=None,
        help="sizes of the jobs' fits (FitSettings.quick or the default; default: quick with "
        "--quick, else full)",
    )
    parser.add_argument(
        "--diagnosis",
        choices=("quick", "full"),
        default=None,
        help="sizes of diagnose_campaign (default: quick with --quick, else full)",
    )
    parser.add_argument("--effects", nargs="+", default=None, choices=EFFECTS)
    parser.add_argument("--seeds", type=int, nargs="+", default=None, help="default 0-2 (quick 0)")
    parser.add_argument("--test-per-state", type=int, default=None, help="default 30 (quick 10)")
    parser.add_argument("--calibration-runs", type=int, default=10)
    parser.add_argument(
        "--runs-per-state", type=int, default=None, help="training runs (default 600, quick 60)"
    )
    parser.add_argument("--method", default="nuts", choices=("nuts", "emcee"))
    parser.add_argument("--source", default="posterior")
    parser.add_argument("--jobs", type=int, default=1, help="cases in parallel (processes)")
    parser.add_argument("--work", type=Path, default=ROOT / "out" / "diagnosis_gain")
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "diagnosis_gain.md")
    args = parser.parse_args(argv)

    effects = args.effects or (["sensor_cross_axis"] if args.quick else list(DEFAULT_EFFECTS))
    seeds = args.seeds if args.seeds is not None else ([0] if args.quick else [0, 1, 2])
    default = "quick" if args.quick else "full"
    settings = Settings(
        fit=args.fit or default,
        diagnosis=args.diagnosis or default,
        calibration_runs=args.calibration_runs,
        test_per_state=args.test_per_state or (10 if args.quick else 30),
        method=args.method,
        source=args.source,
        runs_per_state=args.runs_per_state or (60 if args.quick else 600),
    )
    cases = [(e, s) for e in effects for s in seeds]
    args.work.mkdir(parents=True, exist_ok=True)
    folders = {c: _case_folder(args.work, *c, settings) for c in cases}
    todo = [c for c in cases if not (folders[c] / "case.json").is_file()]
    print(f"{len(cases)} cases, {len(cases) - len(todo)} done, {args.jobs} jobs", flush=True)
    start = time.perf_counter()
    results: dict[tuple[str, int], dict[str, Any]] = {}

    def finished(case: tuple[str, int], row: dict[str, Any]) -> None:
        results[case] = row
        print(
            f"[{time.perf_counter() - start:6.0f} s] {case[0]} seed {case[1]}: verdict "
            f"{row.get('verdict')} {row.get('error', '')}",
            flush=True,
        )

    run_cases(
        _run_and_save, {c: (*c, settings, str(folders[c])) for c in todo}, args.jobs, finished
    )
    rows = [
        results[c] if c in results else json.loads((folders[c] / "case.json").read_text())
        for c in cases
    ]
    (args.work / "cases.json").write_text(json.dumps(rows, indent=1) + "\n")
    command = command_line("diagnosis_gain.py", argv)
    write_results(args.out, table(rows, command, settings, time.perf_counter() - start))


if __name__ == "__main__":
    main()
