"""The other doors with the diagnosed extension: does extending the model help transfer?

For each door of ``scripts/transfer.py`` (its work folder: the door's campaign and the shared
fit of the base door), this script

1. runs the main job with the default training source on the base door (the stages that
   ``scripts/transfer.py`` saved are reused when their settings match);
2. diagnoses the calibration runs under that fit (``bayesdoor.diagnose.diagnose_campaign``,
   quick sizes, the door's catalogue);
3. when the verdict names a cause, runs the same job on
   ``bayesdoor.diagnose.extend_system(door, diagnosis)`` (the cause held at its refitted
   values, the door's own parameters fitted again) and scores it on the same test runs.

The test labels serve only for the scores; the diagnosis sees the calibration runs alone.
Each door's row is saved in its folder (``extended.json``), so an interrupted command goes on
where it stopped.

Usage::

    .venv/bin/python scripts/transfer_extend.py --only 12 13 14 15 [--jobs 2]
        [--work out/transfer] [--results results/transfer_extended.md]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path
from typing import Any

from _cases import (
    ROOT,
    code_version,
    command_line,
    run_cases,
    save_json,
    saved_diagnosis,
    setup_jax,
    write_results,
)
from transfer import DEFAULT_SOURCE, job_row


def _job(system, campaign, out: Path, label: str) -> dict[str, Any]:
    """The quick main job (no diagnosis, no HTML) with the default source: its row as
    ``scripts/transfer.py`` records one, and the stages it reused."""
    from bayesdoor.pipeline import JobConfig, run_job

    start = time.perf_counter()
    result = run_job(
        system,
        campaign,
        out,
        JobConfig.quick_look(seed=0, source=DEFAULT_SOURCE, html=False, diagnosis=False),
        progress=False,
        report=lambda line: print(f"  {label}: {line}", flush=True),
        overwrite=True,
    )
    row = job_row(result, DEFAULT_SOURCE, time.perf_counter() - start)
    return {**row, "reused": [s.name for s in result.stages if s.reused]}


def run_door(seed: int, work: str) -> dict[str, Any]:
    """Base job, diagnosis, extended job of door ``seed``: its row."""
    setup_jax()
    from bayesdoor.diagnose import extend_system, verdict_extension
    from bayesdoor.door import ElevatorDoor
    from bayesdoor.io import load_campaign
    from bayesdoor.pipeline import json_safe

    folder = Path(work) / f"door-{seed:02d}"
    if not (folder / "campaign.nc").is_file():
        raise FileNotFoundError(
            f"{folder}/campaign.nc: record the door first (scripts/transfer.py --only {seed})"
        )
    campaign = load_campaign(folder / "campaign.nc")
    truth = json.loads((folder / "truth.json").read_text())["other_door"]
    door = ElevatorDoor()
    base = _job(door, campaign, folder / DEFAULT_SOURCE, f"door {seed} base")
    diagnosis, (diagnose_seconds, _) = saved_diagnosis(
        campaign,
        folder / DEFAULT_SOURCE / "fit" / "result",
        folder / "diagnosis.pkl",
        quick=True,
        seed=0,
    )
    found = verdict_extension(door, diagnosis)
    if found is None:
        extended = None
    else:
        system = extend_system(door, diagnosis)
        extended = _job(system, campaign, folder / "extended", f"door {seed} extended")
    row = json_safe(
        {
            "seed": seed,
            "frame_mode_hz": truth["frame_mode"]["frequency_hz"],
            "mounting_deg": truth["mounting_deg"],
            "verdict": diagnosis.verdict,
            "confirmed": [c.name for c in diagnosis.confirmed],
            "held": {} if found is None else found.values,
            "gain": [
                None if c.gain is None else c.gain.to_json()
                for c in diagnosis.causes
                if c.name == diagnosis.verdict
            ],
            "base": base,
            "extended": extended,
            "diagnose_seconds": diagnose_seconds,
            "computed": f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {code_version()}",
        }
    )
    save_json(folder / "extended.json", row)
    return row


def _share(rows: list[dict[str, Any]], key: str, which: str) -> str:
    values = [r[which][key] for r in rows if r.get(which)]
    if not values:
        return "-"
    return f"{statistics.median(values):.3f} ({min(values):.3f}-{max(values):.3f})"


def markdown(rows: list[dict[str, Any]], command: str, wall: float) -> str:
    """The results file: per door, the verdict and the job before and after the extension."""
    lines = [
        "# The other doors with the diagnosed extension",
        "",
        f"Made by `{command}` (the table written with {code_version()}; each door's row was "
        f"computed when and at the commit its last column says; {wall / 60:.0f} min wall in this "
        "call).",
        "",
        "Each door is `OtherDoor.from_seed(seed)` of `scripts/transfer.py` (docs/transfer.md); "
        "every door has one structural mode the reduced model lacks (its frequency below) and "
        "sensors whose X-Z axes are rotated (the angle per sensor below: a cross-axis leak of "
        "sin(angle)), besides gain, drive, friction and noise changes. The base job is the "
        "quick main job "
        f"with the default source (`{DEFAULT_SOURCE}`) on the reduced door; the diagnosis "
        "(quick) sees the 10 healthy calibration runs under that job's fit; the extended job "
        "is the same job on `extend_system(door, diagnosis)`. Accuracy and ECE on the door's "
        "60 test runs (20 per state).",
        "",
        "| seed | frame mode (Hz) | sensor mounting (deg) | verdict | held values | held-out "
        "gain | base accuracy / ECE / "
        "trust | extended accuracy / ECE / trust | computed |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(rows, key=lambda r: r["seed"]):
        held = ", ".join(f"{k} {v:.4g}" for k, v in r["held"].items()) or "-"
        gain = r["gain"][0] if r["gain"] else None
        gain_text = "-" if not gain else f"{gain['delta_elpd'] / gain['elpd_se']:+.1f} SE"
        b, e = r["base"], r["extended"]
        ext = (
            "same (verdict none)"
            if e is None
            else (f"{e['accuracy']:.3f} / {e['ece']:.3f} / {e['trust']}")
        )
        lines.append(
            f"| {r['seed']} | {r['frame_mode_hz']:.1f} | "
            f"{' '.join(f'{a:+.1f}' for a in r['mounting_deg'])} | {r['verdict']} | {held} | "
            f"{gain_text} | "
            f"{b['accuracy']:.3f} / {b['ece']:.3f} / {b['trust']} | {ext} | "
            f"{r.get('computed', '-')} |"
        )
    extended = [dict(r, extended=r["extended"] or r["base"]) for r in rows]
    paired = sorted((r for r in rows if r["extended"]), key=lambda r: r["seed"])
    changes = {
        key: [r["extended"][key] - r["base"][key] for r in paired] for key in ("accuracy", "ece")
    }
    named = len(paired)
    lines += [
        "",
        f"Median (range) over {len(rows)} doors: accuracy {_share(rows, 'accuracy', 'base')} -> "
        f"{_share(extended, 'accuracy', 'extended')}; ECE {_share(rows, 'ece', 'base')} -> "
        f"{_share(extended, 'ece', 'extended')} (a door whose verdict is `none` keeps its base "
        f"figures). Paired change over the {named} doors with a named cause: accuracy "
        + ", ".join(f"{d:+.3f}" for d in changes["accuracy"])
        + "; ECE "
        + ", ".join(f"{d:+.3f}" for d in changes["ece"])
        + f". One test run of {rows[0]['base']['runs']} is {1 / rows[0]['base']['runs']:.3f} of "
        "accuracy.",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", type=int, nargs="+", required=True, help="door seeds")
    parser.add_argument("--jobs", type=int, default=1, help="doors in parallel (processes)")
    parser.add_argument("--work", type=Path, default=ROOT / "out" / "transfer")
    parser.add_argument("--results", type=Path, default=ROOT / "results" / "transfer_extended.md")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    rows: dict[int, dict[str, Any]] = {}
    todo = []
    for seed in args.only:
        saved = args.work / f"door-{seed:02d}" / "extended.json"
        if saved.is_file():
            rows[seed] = json.loads(saved.read_text())
        else:
            todo.append(seed)

    def finished(seed: int, row: dict[str, Any]) -> None:
        rows[seed] = row
        print(f"[{time.perf_counter() - start:6.0f} s] door {seed}: {row['verdict']}", flush=True)

    run_cases(run_door, {s: (s, str(args.work)) for s in todo}, args.jobs, finished)
    command = command_line("transfer_extend.py", argv)
    write_results(args.results, markdown(list(rows.values()), command, time.perf_counter() - start))


if __name__ == "__main__":
    main()
