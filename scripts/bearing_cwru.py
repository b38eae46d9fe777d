"""The bearing judged on the real CWRU records: fit on healthy segments, classify every record.

The CWRU folder becomes a campaign (``bayesdoor.bearing.read_cwru``: one run per 1 s segment;
the healthy record's first half of segments, a contiguous block, is the calibration split, its
second half and every fault segment the test split). The main job
(``bayesdoor.pipeline.run_job`` on ``get_system("bearing")``) fits the model to the healthy
calibration segments only, simulates training runs of all four states from the fit (the fault
classes come from simulations alone: no fault record is used for fitting, training,
calibration or thresholds), trains the ensemble and classifies every test segment: the healthy
test block and all fault records. The labels serve only for the scores. Each method runs in its
own job folder under ``--out`` (finished stages are reused by a second call).

Usage::

    .venv/bin/python scripts/bearing_cwru.py --data ../shared/data/cwru --out out/bearing_cwru
        --method cmaes nuts --quick

writes ``results/bearing_cwru.md`` (``--results``): the command, the date and the commit, then
per method the fit, the adequacy and trust verdicts, the scores, per state and per record, and
the stages' timings. Text under a ``## Notes`` heading of an existing results file is kept.
"""

from __future__ import annotations

import argparse
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
from _cases import command_line, setup_jax

ROOT = Path(__file__).resolve().parent.parent
METHODS = ("cmaes", "nuts", "emcee")
NOTES = "## Notes"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--data", type=Path, default=ROOT.parent / "shared" / "data" / "cwru", help="CWRU folder"
    )
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bearing_cwru")
    parser.add_argument(
        "--method",
        nargs="+",
        choices=METHODS,
        default=["cmaes"],
        help="the fit's methods, one job each (cmaes: the Gaussian source; nuts, emcee: the "
        "job's default source, posterior+model_error)",
    )
    parser.add_argument("--quick", action="store_true", help="the quick sizes of the job")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--html", action="store_true", help="also write the HTML report")
    parser.add_argument("--results", type=Path, default=ROOT / "results" / "bearing_cwru.md")
    args = parser.parse_args(argv)
    setup_jax()

    from bayesdoor.bearing import read_cwru
    from bayesdoor.pipeline import default_source, run_job
    from bayesdoor.systems import get_system

    system = get_system("bearing")
    started = time.perf_counter()
    campaign = read_cwru(args.data)
    read_s = time.perf_counter() - started
    runs = _runs(campaign)
    _check_split(runs)
    header = [
        "# The bearing on the real CWRU records",
        "",
        f"- command: `{command_line('bearing_cwru.py', argv)}`",
        f"- date: {_shell('date', '-u')}",
        f"- commit: {_shell('git', '-C', str(ROOT), 'rev-parse', '--short', 'HEAD')}" + _dirty(),
        "",
        _setup_text(campaign, runs, read_s),
    ]
    sections = []
    for method in args.method:
        source = default_source(method)
        t0 = time.perf_counter()
        result = run_job(
            system,
            campaign,
            args.out / method,
            quick=args.quick,
            seed=args.seed,
            method=method,
            source=source,
            progress=False,
            html=args.html,
            diagnosis=False,
            overwrite=True,
        )
        wall = time.perf_counter() - t0
        sections.append(_method_text(method, source, result, runs, wall))
    text = "\n".join(header + sections).rstrip() + "\n"
    old = args.results.read_text() if args.results.is_file() else ""
    if f"\n{NOTES}\n" in old:
        text += "\n" + old[old.index(f"\n{NOTES}\n") + 1 :]
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text(text)
    print(text)


def _shell(*words: str) -> str:
    done = subprocess.run(list(words), capture_output=True, text=True, check=False)
    return done.stdout.strip() if done.returncode == 0 else "unknown"


def _dirty() -> str:
    """A note when the package or the scripts differ from the commit."""
    changed = _shell("git", "-C", str(ROOT), "status", "--porcelain", "--", "bayesdoor", "scripts")
    return " (with uncommitted changes)" if changed and changed != "unknown" else ""


def _runs(campaign) -> list[dict[str, Any]]:
    """Per run of the campaign: its record, state, split, size, load and speed."""
    columns = ("record", "state", "split", "fault_size_in", "load_hp", "shaft_speed")
    values = {c: np.asarray(campaign[c].values) for c in columns}

    def value(c: str, i: int):
        return values[c][i].item() if values[c].dtype.kind in "fi" else str(values[c][i])

    return [{c: value(c, i) for c in columns} for i in range(campaign.sizes["run"])]


def _check_split(runs: list[dict[str, Any]]) -> None:
    """No fault segment may reach the fit or the training: every one is a test run."""
    for i, r in enumerate(runs):
        if r["state"] != "healthy" and r["split"] != "test":
            raise ValueError(f"run {i} ({r['record']}) is a fault segment outside the test split")


def _setup_text(campaign, runs: list[dict[str, Any]], read_s: float) -> str:
    records: dict[str, dict[str, Any]] = {}
    for r in runs:
        entry = records.setdefault(r["record"], {**r, "calibration": 0, "test": 0})
        entry[r["split"]] += 1
    lines = [
        "## Setup",
        "",
        f"{campaign.sizes['run']} runs of 1 s (12 kHz, channel DE) from {len(records)} records, "
        f"read in {read_s:.1f} s. The fit sees the calibration runs only (healthy); the "
        "classifier is trained on simulations only and scored on every test run.",
        "",
        "| record | state | size (in) | load (hp) | rpm | calibration runs | test runs |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in records.items():
        lines.append(
            f"| {name} | {r['state']} | {r['fault_size_in']:.3f} | {r['load_hp']:g} | "
            f"{r['shaft_speed']:g} | {r['calibration']} | {r['test']} |"
        )
    return "\n".join(lines) + "\n"


def _method_text(method: str, source: str, result, runs: list[dict[str, Any]], wall: float):
    classification = result.classification
    classes = list(classification["classes"])
    scored = [r for r in classification["runs"] if r["predicted"] is not None]
    metrics = classification.get("metrics") or {}
    lines = [
        f"## Method {method} (training source {source})",
        "",
        f"Job folder `{result.out}`; wall time {wall:.0f} s (stages reused from an earlier call "
        "count their original time below).",
        "",
        "### Fit (healthy calibration runs only)",
        "",
        f"J at the point: {_num(result.fit.j, '.4g')}. "
        + ("A CMA-ES point." if not result.fit.draws else "Posterior mean and 5-95 % range."),
        "",
        "| parameter | value | 5 % | 95 % |",
        "|---|---|---|---|",
    ]
    for name, value in result.fit.point.items():
        draws = result.fit.draws.get(name)
        low, high = ("-", "-") if draws is None else np.quantile(draws, [0.05, 0.95])
        lines.append(f"| {name} | {value:.4g} | {_num(low, '.4g')} | {_num(high, '.4g')} |")
    if result.fit.diagnostics:
        d = result.fit.diagnostics
        shown = {k: d[k] for k in ("passed", "rhat_max", "ess_bulk_min", "divergences") if k in d}
        if shown:
            lines += ["", "Sampling diagnostics: " + _pairs(shown) + "."]
    adequacy = result.adequacy or {}
    trust = result.trust or {}
    lines += [
        "",
        "### Verdicts",
        "",
        f"- fit adequacy: **{adequacy.get('verdict')}**: "
        f"{adequacy.get('summary') or adequacy.get('reason') or ''}",
    ]
    if adequacy.get("model") and adequacy["model"] is not adequacy:
        model = adequacy["model"]
        lines.append(
            f"- the fitted model alone (without the measured discrepancy): "
            f"**{model.get('verdict')}**: {model.get('summary', '')}"
        )
    lines.append(f"- trust: **{trust.get('verdict')}**")
    lines += [f"  - reason: {r}" for r in trust.get("reasons", [])]
    lines += [f"  - warning: {w}" for w in trust.get("warnings", [])]
    lines += [
        "",
        "### Scores on the test runs",
        "",
        f"{len(scored)} runs classified into {', '.join(classes)}. Chance: 25 % for a uniform "
        f"guess; {_majority(scored):.1%} for always calling the most frequent true state.",
        "",
        "| accuracy | ECE | ECE (equal mass) | NLL | Brier | healthy/fault detection | OOD |",
        "|---|---|---|---|---|---|---|",
        f"| {_num(metrics.get('accuracy'), '.3f')} | {_num(metrics.get('ece'), '.3f')} | "
        f"{_num(metrics.get('ece_mass'), '.3f')} | {_num(metrics.get('nll'), '.3f')} | "
        f"{_num(metrics.get('brier'), '.3f')} | {_detection(scored):.3f} | "
        f"{_ood_rate(scored)} |",
        "",
        "Confusion (rows: true state, columns: predicted):",
        "",
        "| true \\ predicted | " + " | ".join(classes) + " |",
        "|---|" + "---|" * len(classes),
    ]
    for i, row in enumerate(metrics.get("confusion") or []):
        lines.append(f"| {classes[i]} | " + " | ".join(str(v) for v in row) + " |")
    lines += ["", "Per state:", "", *_group_table(scored, classes, runs, key="state"), ""]
    lines += ["Per record:", "", *_group_table(scored, classes, runs, key="record"), ""]
    lines += [
        "### Timings",
        "",
        "| stage | seconds | reused |",
        "|---|---|---|",
    ]
    lines += [
        f"| {s.name} | {s.seconds:.1f} | {'yes' if s.reused else 'no'} |" for s in result.stages
    ]
    return "\n".join(lines) + "\n"


def _group_table(scored, classes, runs, *, key: str) -> list[str]:
    """Accuracy, mean probability of the true state, OOD rate and the predictions per group."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in scored:
        groups.setdefault(str(runs[r["run"]][key]), []).append(r)
    head = "| " + key + (" | state" if key == "record" else "") + " | runs | accuracy | "
    head += "mean p(true) | OOD | " + " | ".join(f"called {c}" for c in classes) + " |"
    rows = [head, "|---" * (head.count("|") - 1) + "|"]
    for name, members in groups.items():
        state = members[0]["state"]
        correct = np.mean([m["predicted"] == m["state"] for m in members])
        p_true = np.mean([m["probabilities"].get(m["state"], np.nan) for m in members])
        counts = [sum(m["predicted"] == c for m in members) for c in classes]
        rows.append(
            f"| {name}"
            + (f" | {state}" if key == "record" else "")
            + f" | {len(members)} | {correct:.2f} | {p_true:.2f} | {_ood_rate(members)} | "
            + " | ".join(str(c) for c in counts)
            + " |"
        )
    return rows


def _majority(scored) -> float:
    states = [r["state"] for r in scored]
    return max(states.count(s) for s in set(states)) / len(states) if states else float("nan")


def _detection(scored) -> float:
    """Share of runs whose healthy-or-faulty call is right (any fault state counts as faulty)."""
    right = [(r["predicted"] == "healthy") == (r["state"] == "healthy") for r in scored]
    return float(np.mean(right)) if right else float("nan")


def _ood_rate(members) -> str:
    flags = [r["ood"] for r in members if r["ood"] is not None]
    return f"{sum(flags)}/{len(flags)}" if flags else "-"


def _num(value, spec: str) -> str:
    if isinstance(value, str):
        return value
    if value is None or not np.isfinite(float(value)):
        return "-"
    return format(float(value), spec)


def _pairs(values: dict[str, Any]) -> str:
    return ", ".join(
        f"{k} {v}" if isinstance(v, bool) else f"{k} {_num(v, '.3g')}" for k, v in values.items()
    )


if __name__ == "__main__":
    main()
