"""The bearing judged on the real CWRU records: segment and record level, beside two baselines.

The CWRU folder becomes a campaign (``bayesdoor.bearing.read_cwru``: one run per 1 s segment;
the healthy record's first half of segments, a contiguous block, is the calibration split, its
second half and every fault segment the test split). Three classifiers are scored on the same
test segments and records:

* the main job (``bayesdoor.pipeline.run_job``, method ``nuts``, training source
  ``posterior+model_error``): fit on the healthy calibration segments only, training data
  simulated for the four states over the campaign's operating points and 1700-1800 rpm x
  0-3 hp (``BearingSystem.training_points``), ensemble, record-level votes;
* the paper's baseline: the same job with a CMA-ES point and the 5 % Gaussian scatter
  around it (source ``gaussian``);
* a physics rule without learning (``bayesdoor.bearing.EnvelopeRule``): envelope lines at
  harmonics of BPFO, BPFI and BSF against the healthy calibration segments, threshold from a
  stated false-alarm rate.

No fault segment reaches a fit, a training or a threshold; the labels serve only for the
scores. Each job runs in its own folder under ``--out`` (finished stages are reused).

Usage::

    .venv/bin/python scripts/cwru.py --data ../shared/data/cwru --out out/cwru --quick

writes ``results/cwru.md`` (``--results``): the command, the date and the commit, the
records, a summary of the three classifiers against the targets, then per classifier
the per-record table (file, class, size, load, predicted, mean probability, flagged), the
confusion matrices at segment and record level, and the timings. Text outside the generated
block of an existing results file is kept.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
from _cases import command_line, setup_jax, write_results

ROOT = Path(__file__).resolve().parent.parent
CLASSES = ("healthy", "inner_race", "outer_race", "ball")
#: the physics rule's stated false-alarm rate per healthy segment
FALSE_ALARM_RATE = 0.01


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--data", type=Path, default=ROOT.parent / "shared" / "data" / "cwru", help="CWRU folder"
    )
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "cwru")
    parser.add_argument("--quick", action="store_true", help="the quick sizes of the jobs")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--runs-per-state",
        type=int,
        default=None,
        help="simulated training runs per state (default: the job's, 100 with --quick)",
    )
    parser.add_argument(
        "--jobs",
        nargs="*",
        choices=("nuts", "cmaes"),
        default=["nuts", "cmaes"],
        help="the learned classifiers to run (the physics rule always runs)",
    )
    parser.add_argument(
        "--more-seeds",
        nargs="*",
        type=int,
        default=[],
        help="further seeds of the nuts job's generation and training, run in its folder before "
        "the main seed (the fit's seed stays --seed, so the fit is reused): their scores join "
        "the summary",
    )
    parser.add_argument(
        "--extend",
        action="store_true",
        help="close the diagnosis loop: each nuts job also runs on the bearing extended by the "
        "diagnosis's verdict on the healthy calibration segments (refit, training data, "
        "classifier), and the results compare the two",
    )
    parser.add_argument("--results", type=Path, default=ROOT / "results" / "cwru.md")
    args = parser.parse_args(argv)
    setup_jax()

    from bayesdoor.bearing import EnvelopeRule, read_cwru
    from bayesdoor.pipeline import JobConfig, Sizes, default_source, run_job
    from bayesdoor.systems import get_system

    system = get_system("bearing")
    started = time.perf_counter()
    campaign = read_cwru(args.data)
    read_s = time.perf_counter() - started
    runs = _runs(campaign)
    _check_split(runs)
    files = {r["record"]: r["file"] for r in json.loads(campaign.attrs["source"])["records"]}

    t0 = time.perf_counter()
    x = np.asarray(campaign["acceleration"].values)[:, 0, :]
    fs = float(campaign.attrs["sampling_rate_hz"])
    cal = [i for i, r in enumerate(runs) if r["split"] == "calibration"]
    rule = EnvelopeRule.from_healthy(
        x[cal],
        fs,
        np.array([runs[i]["shaft_speed"] for i in cal]),
        false_alarm_rate=FALSE_ALARM_RATE,
    )
    test = [i for i, r in enumerate(runs) if r["split"] == "test"]
    scores = [rule.scores(x[i], fs, runs[i]["shaft_speed"]) for i in test]
    rule_runs = [
        {
            "run": i,
            "state": runs[i]["state"],
            "record": runs[i]["record"],
            "predicted": _rule_call(z, rule.z_threshold),
            "z": z,
        }
        for i, z in zip(test, scores, strict=True)
    ]
    rule_result = _rule_result(rule, rule_runs, time.perf_counter() - t0)
    shows = {name: r["predicted"] for name, r in rule_result["records"].items()}

    sizes = Sizes.quick() if args.quick else Sizes()
    if args.runs_per_state is not None:
        sizes = dataclasses.replace(sizes, runs_per_state=args.runs_per_state)
    results: list[dict[str, Any]] = []
    loop: list[tuple[int, dict[str, Any], dict[str, Any] | None, str]] = []
    for method in args.jobs:
        source = default_source(method)
        # the further seeds first, the main one last: one folder, whose fit they share
        seeds = [*(args.more_seeds if method == "nuts" else []), args.seed]
        for seed in seeds:
            t0 = time.perf_counter()
            job = run_job(
                system,
                campaign,
                args.out / method,
                JobConfig(
                    quick=args.quick,
                    sizes=sizes,
                    seed=seed,
                    fit_seed=args.seed,
                    method=method,
                    source=source,
                    html=False,
                    # the diagnosis of the healthy calibration record: with the main seed, and
                    # with every seed when the loop is closed (the extension follows its verdict)
                    diagnosis=method == "nuts" and (seed == args.seed or args.extend),
                    extend=method == "nuts" and args.extend,
                ),
                progress=False,
                overwrite=True,
            )
            wall = time.perf_counter() - t0
            result = _job_result(method, source, job, runs, wall)
            _keep(args.out / method / f"classification-seed{seed}.json", job.classification)
            result["diagnosis"] = job.diagnosis
            if seed != args.seed:
                result["name"] += f", training seed {seed}"
                result["detail"] = False
            results.append(result)
            if method == "nuts" and args.extend:
                loop.append(_loop_entry(seed, result, job, runs, wall))
        # the main seed's row first, then the further seeds'
        results[len(results) - len(seeds) :] = [
            results[-1],
            *results[len(results) - len(seeds) : -1],
        ]

    results.append(rule_result)
    for r in results:
        r["scores"] = _scores(r, runs, shows)
    for _, _, extended, _ in loop:
        if extended is not None:
            extended["scores"] = _scores(extended, runs, shows)
    header = [
        "# The bearing on the real CWRU records: trained on simulations only",
        "",
        f"- command: `{command_line('cwru.py', argv)}`",
        f"- date: {_shell('date', '-u')}",
        f"- commit: {_shell('git', '-C', str(ROOT), 'rev-parse', '--short', 'HEAD')}" + _dirty(),
        f"- data: `{_relative(args.data)}` (not part of the repository)",
        f"- machine: {os.cpu_count()} CPU cores",
        "",
    ]
    text = "\n".join(
        header
        + [_setup_text(campaign, runs, files, read_s), _summary_text(results)]
        + [_classifier_text(r, runs, files, shows) for r in results if r.get("detail", True)]
        + [_diagnosis_text(r) for r in results if r.get("diagnosis")]
        + ([_loop_text(loop)] if loop else [])
    )
    write_results(args.results, text)


# ----------------------------------------------------------------------------------- inputs


def _loop_entry(
    seed: int, base: dict[str, Any], job, runs, wall: float
) -> tuple[int, dict[str, Any], dict[str, Any] | None, str]:
    """One seed of the loop: the base job's result, the extended job's (``None`` when nothing
    was extended) and the verdict or the reason nothing was."""
    verdict = (job.diagnosis or {}).get("verdict", "-")
    if job.extended is None:
        return seed, base, None, str((job.extension or {}).get("reason") or verdict)
    extended = _job_result("nuts", f"extended by {verdict}", job.extended, runs, wall)
    return seed, base, extended, verdict


def _loop_text(loop) -> str:
    """The base job against the job on the bearing extended by the diagnosis's verdict."""
    lines = [
        "## The diagnosis loop on the real records",
        "",
        "Per training seed: the diagnosis of the healthy calibration segments, the bearing "
        "extended by its verdict (refitted on the same segments, training data regenerated, "
        "classifier retrained, `JobConfig(extend=True)`), and the scores of the base job and the "
        "extended one on the same test segments. A loss is a loss.",
        "",
        "| seed | verdict | job | segment accuracy | segment ECE | record accuracy | record "
        "balanced accuracy | segments called at the selective risk: right |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for seed, base, extended, verdict in loop:
        for label, r in (("base", base), ("extended", extended)):
            if r is None:
                lines.append(f"| {seed} | {verdict} | extended | nothing extended | | | | |")
                continue
            s = r["scores"]
            sel = s["selective"]
            right = (
                f"{sel['segments_right'] / sel['segments_called']:.3f}"
                if sel["segments_called"]
                else "-"
            )
            lines.append(
                f"| {seed} | {verdict} | {label} | {s['segment_acc'][0]:.3f} | "
                f"{_num(r['ece'], '.3f')} | {s['record_acc'][0]:.3f} | {s['record_acc'][1]:.3f} "
                f"| {sel['segments_called']} of {len(r['segments'])}: {right} |"
            )
    return "\n".join(lines) + "\n"


def _keep(path: Path, classification: dict[str, Any]) -> None:
    """A job's classification under its seed's name (the job's folder keeps the last one)."""
    path.write_text(json.dumps(classification, default=float) + "\n")


def _shell(*words: str) -> str:
    done = subprocess.run(list(words), capture_output=True, text=True, check=False)
    return done.stdout.strip() if done.returncode == 0 else "unknown"


def _dirty() -> str:
    """A note when the package or the scripts differ from the commit."""
    changed = _shell("git", "-C", str(ROOT), "status", "--porcelain", "--", "bayesdoor", "scripts")
    return " (with uncommitted changes)" if changed and changed != "unknown" else ""


def _relative(path: Path) -> str:
    """The data folder as seen from the repository (``../shared/data/cwru``)."""
    return os.path.relpath(path.resolve(), ROOT)


def _runs(campaign) -> list[dict[str, Any]]:
    """Per run of the campaign: its record, state, split, size, load and speed."""
    columns = ("record", "state", "split", "fault_size_in", "load_hp", "shaft_speed")
    values = {c: np.asarray(campaign[c].values) for c in columns}

    def value(c: str, i: int):
        return values[c][i].item() if values[c].dtype.kind in "fi" else str(values[c][i])

    return [{c: value(c, i) for c in columns} for i in range(campaign.sizes["run"])]


def _check_split(runs: list[dict[str, Any]]) -> None:
    """No fault segment may reach a fit, a training or a threshold: every one is a test run."""
    for i, r in enumerate(runs):
        if r["state"] != "healthy" and r["split"] != "test":
            raise ValueError(f"run {i} ({r['record']}) is a fault segment outside the test split")


# ------------------------------------------------------------------------------ classifiers


def _job_result(method: str, source: str, job, runs, wall: float) -> dict[str, Any]:
    """A job's segment calls, record votes, metrics and timings, in the script's form."""
    from bayesdoor.pipeline._classify import record_votes, run_flagged

    c = job.classification
    classes = list(c["classes"])
    segments = [
        {
            "run": r["run"],
            "state": r["state"],
            "record": runs[r["run"]]["record"],
            # every segment's most probable state (full coverage); "called": kept at the
            # selective risk
            "predicted": r["most_probable"],
            "called": r["predicted"] is not None,
            "probabilities": r["probabilities"],
            "flagged": run_flagged(r),
            "not_corroborated": r.get("corroborated") is False,
        }
        for r in c["runs"]
    ]
    # the records' votes with every segment voting, and with the segments called only
    everyone = [r | {"predicted": r["most_probable"]} for r in c["runs"]]
    names = np.array([runs[r["run"]]["record"] for r in c["runs"]])
    full = record_votes(everyone, names, classes)
    selective = {r["record"]: r["majority"] for r in c["records"]}
    records = {
        r["record"]: {
            "predicted": r["majority"],
            "selective": selective[r["record"]],
            "probability": None
            if r["majority"] is None
            else r["mean_probabilities"][r["majority"]],
            "p_true": (r["mean_probabilities"] or {}).get(r["state"]),
            "flagged": r["flagged"],
            "share_flagged": r["share_flagged"],
            "votes": r["votes"],
        }
        for r in full
    }
    metrics = c.get("metrics") or {}
    trust = job.trust or {}
    adequacy = job.adequacy or {}
    return {
        "name": f"{method} / {source}",
        "kind": "job",
        "classes": classes,
        "segments": segments,
        "records": records,
        "ece": metrics.get("ece"),
        "ece_ensemble": (metrics.get("ensemble") or {}).get("ece"),
        "nll": metrics.get("nll"),
        "target_risk": (c.get("selective") or {}).get("target_risk"),
        "wall": wall,
        "stages": [(s.name, s.seconds, s.reused) for s in job.stages],
        "notes": [
            f"fit: {job.fit.method}, J {job.fit.j:.4g}",
            f"fit adequacy: {adequacy.get('verdict')}: "
            f"{adequacy.get('summary') or adequacy.get('reason') or ''}",
            f"trust: {trust.get('verdict')}" + "".join(f"; {r}" for r in trust.get("reasons", [])),
            _evidence_note(c.get("evidence")),
        ],
    }


def _evidence_note(evidence: dict[str, Any] | None) -> str:
    """What the weighing against the envelope check learned from the campaign."""
    if evidence is None:
        return "probabilities: the ensemble's (no signature check weighed)"

    def rate(v: list[float]) -> str:
        return f"{v[0]:.2f} ({v[1]:.2f}-{v[2]:.2f})"

    detection = ", ".join(f"{k} {rate(v)}" for k, v in evidence["detection"].items())
    leak = ", ".join(f"{k} {rate(v)}" for k, v in evidence["leak"].items())
    return (
        "probabilities weighed against the envelope check (docs/classification.md): share of "
        f"segments the ensemble holds for {rate(evidence['pi'])}; each family's line shows on "
        f"its own segments: {detection}; on other faults': {leak} (posterior means, 90 % "
        "intervals)"
    )


def _rule_call(z: dict[str, float], threshold: float) -> str:
    best = max(z, key=lambda k: z[k])
    return best if z[best] > threshold else "healthy"


def _rule_result(rule, segments, seconds: float) -> dict[str, Any]:
    """The physics rule's calls and record votes (majority; a tie: the larger mean z)."""
    records: dict[str, dict[str, Any]] = {}
    for name in dict.fromkeys(s["record"] for s in segments):
        members = [s for s in segments if s["record"] == name]
        votes = {c: sum(s["predicted"] == c for s in members) for c in CLASSES}
        mean_z = {k: float(np.mean([s["z"][k] for s in members])) for k in members[0]["z"]}
        order = {c: mean_z.get(c, rule.z_threshold) for c in CLASSES}
        records[name] = {
            "predicted": max(CLASSES, key=lambda c: (votes[c], order[c])),
            "probability": None,
            "p_true": None,
            "flagged": None,
            "votes": votes,
            "mean_z": mean_z,
        }
    for s in segments:
        s["flagged"] = None
    return {
        "name": "physics rule (envelope lines)",
        "kind": "rule",
        "classes": list(CLASSES),
        "segments": segments,
        "records": records,
        "ece": None,
        "ece_ensemble": None,
        "nll": None,
        "target_risk": None,
        "wall": seconds,
        "stages": [("reference and calls", seconds, False)],
        "notes": [
            f"band {rule.band[0]:g}-{rule.band[1]:g} Hz; stated false-alarm rate "
            f"{rule.false_alarm_rate:.0%} per healthy segment; z threshold "
            f"{rule.z_threshold:.2f} (t prediction bound, Bonferroni over 3 families); "
            "reference: the 10 healthy calibration segments",
        ],
    }


# ------------------------------------------------------------------------------------ scores


def _confusion(pairs, classes) -> np.ndarray:
    m = np.zeros((len(classes), len(classes)), dtype=int)
    for true, predicted in pairs:
        if true in classes and predicted in classes:
            m[classes.index(true), classes.index(predicted)] += 1
    return m


def _accuracy(m: np.ndarray) -> tuple[float, float]:
    """Accuracy and balanced accuracy (mean recall over the true states present)."""
    rows = m.sum(axis=1)
    recall = np.diag(m)[rows > 0] / rows[rows > 0]
    return float(np.trace(m) / m.sum()), float(recall.mean())


def _ece(segments: list[dict[str, Any]], classes: list[str]) -> float | None:
    """The segments' ECE (15 equal-width bins); ``None`` without probabilities or segments."""
    from bayesdoor.classify import expected_calibration_error

    segments = [s for s in segments if s.get("probabilities") and s["state"] in classes]
    if not segments:
        return None
    p = np.array([[s["probabilities"][c] for c in classes] for s in segments])
    return expected_calibration_error(p, np.array([classes.index(s["state"]) for s in segments]))


def _selective_scores(result: dict[str, Any], state: dict[str, str]) -> dict[str, Any]:
    """At the job's selective risk: the segments called and right, the records called and
    right (a record's vote from its called segments)."""
    called = [s for s in result["segments"] if s.get("called")]
    records = {n: r["selective"] for n, r in result["records"].items()}
    voted = [n for n, v in records.items() if v is not None]
    return {
        "segments_called": len(called),
        "segments_right": sum(s["predicted"] == s["state"] for s in called),
        "records_called": len(voted),
        "records_right": sum(records[n] == state[n] for n in voted),
    }


def _split_scores(
    result: dict[str, Any], state: dict[str, str], shows: dict[str, str]
) -> dict[str, Any]:
    """Per group of fault records by what their signal shows (the physics rule's majority,
    without labels): ``own`` (their own fault), ``other`` (another fault family), ``none``
    (no fault): records, records named, mean p(true) and segment ECE."""
    classes = result["classes"]
    out = {}
    for group in ("own", "other", "none"):
        names = [
            n
            for n in result["records"]
            if state[n] != "healthy"
            and {"own": shows[n] == state[n], "none": shows[n] == "healthy"}.get(
                group, shows[n] not in (state[n], "healthy")
            )
        ]
        segs = [s for s in result["segments"] if s["record"] in names]
        p_true = [s["probabilities"][s["state"]] for s in segs if s.get("probabilities")]
        out[group] = {
            "records": names,
            "named": [n for n in names if result["records"][n]["predicted"] == state[n]],
            "p_true": float(np.mean(p_true)) if p_true else None,
            "ece": _ece(segs, classes),
        }
    return out


def _scores(result: dict[str, Any], runs, shows: dict[str, str]) -> dict[str, Any]:
    classes = result["classes"]
    seg = _confusion([(s["state"], s["predicted"]) for s in result["segments"]], classes)
    state = {name: runs[s["run"]]["state"] for s in result["segments"] for name in [s["record"]]}
    rec = _confusion([(state[n], r["predicted"]) for n, r in result["records"].items()], classes)
    wrong = [n for n, r in result["records"].items() if r["predicted"] != state[n]]
    races = [n for n in result["records"] if state[n] in ("inner_race", "outer_race")]
    return {
        "segment": seg,
        "record": rec,
        "segment_acc": _accuracy(seg),
        "record_acc": _accuracy(rec),
        "races_named": sum(result["records"][n]["predicted"] == state[n] for n in races),
        "races": len(races),
        "misnamed": wrong,
        "misnamed_flagged": [n for n in wrong if result["records"][n]["flagged"]],
        "right_flagged": [
            n for n, r in result["records"].items() if n not in wrong and r["flagged"]
        ],
        "flagged_segments": sum(bool(s["flagged"]) for s in result["segments"]),
        "uncorroborated_segments": sum(bool(s.get("not_corroborated")) for s in result["segments"]),
        "ece_not_other": _ece(
            [s for s in result["segments"] if shows[s["record"]] in (s["state"], "healthy")],
            classes,
        ),
        "selective": _selective_scores(result, state) if result["kind"] == "job" else None,
        "split": _split_scores(result, state, shows),
    }


# ------------------------------------------------------------------------------------- text


def _setup_text(campaign, runs, files, read_s: float) -> str:
    records: dict[str, dict[str, Any]] = {}
    for r in runs:
        entry = records.setdefault(r["record"], {**r, "calibration": 0, "test": 0})
        entry[r["split"]] += 1
    lines = [
        "## Records",
        "",
        f"{campaign.sizes['run']} runs of 1 s (12 kHz, channel DE) from {len(records)} records, "
        f"read in {read_s:.1f} s. The fits and the rule's reference see the healthy "
        "calibration segments only; the classifiers are trained on simulations only and scored "
        "on every test segment, and each record's segments vote.",
        "",
        "| file | class | size (in) | load (hp) | rpm | calibration segments | test segments |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in records.items():
        lines.append(
            f"| {files.get(name, name)} | {r['state']} | {r['fault_size_in']:.3f} | "
            f"{r['load_hp']:g} | {r['shaft_speed']:g} | {r['calibration']} | {r['test']} |"
        )
    return "\n".join(lines) + "\n"


def _names_in(names: list[str], lead: str) -> str:
    """`` (lead: a, b)`` for a list of record names, nothing for none."""
    if not names:
        return ""
    return f" ({lead + ': ' if lead else ''}{', '.join(names)})"


def _summary_text(results) -> str:
    lines = [
        "## Summary",
        "",
        "Targets: every race record whose signal shows its own fault named; record balanced "
        "accuracy not below 0.75; segment ECE <= 0.10 over all records and <= 0.05 over the "
        "records whose signal shows no other fault family; at the selective risk, the calls "
        ">= 90 % right. What a record's signal shows is the physics rule's majority call over "
        "its segments (envelope lines at a 1 % false-alarm rate, no labels). Segment and "
        "record accuracy call every segment its most probable state; the selective columns "
        "call only the segments whose probabilities keep the expected share of wrong calls "
        "under the job's selective risk (5 %), and a record by the vote of its called "
        "segments. The probabilities are the ensemble's weighed against the envelope check "
        "(docs/classification.md); in brackets, the ensemble's own ECE.",
        "",
        "| classifier | segment accuracy | segment balanced accuracy | segment ECE (the "
        "ensemble alone) | segment ECE, no other family shown | record accuracy | record "
        "balanced accuracy | "
        "race records named | segments called at the selective risk: right | records "
        "called: right | misnamed records flagged | wall time (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        s = r["scores"]
        flagged = (
            "- (no flag)"
            if r["kind"] == "rule"
            else f"{len(s['misnamed_flagged'])} of {len(s['misnamed'])}"
            + _names_in(sorted(set(s["misnamed"]) - set(s["misnamed_flagged"])), "not")
        )
        sel = s["selective"]
        called = (
            "-"
            if sel is None
            else f"{sel['segments_called']} of {len(r['segments'])}: "
            + (
                f"{sel['segments_right'] / sel['segments_called']:.3f}"
                if sel["segments_called"]
                else "-"
            )
        )
        records_called = (
            "-"
            if sel is None
            else f"{sel['records_called']} of {len(r['records'])}: {sel['records_right']} right"
        )
        lines.append(
            f"| {r['name']} | {s['segment_acc'][0]:.3f} | {s['segment_acc'][1]:.3f} | "
            f"{_num(r['ece'], '.3f')}"
            + ("" if r["ece_ensemble"] is None else f" ({r['ece_ensemble']:.3f})")
            + f" | {_num(s['ece_not_other'], '.3f')} | "
            f"{s['record_acc'][0]:.3f} | {s['record_acc'][1]:.3f} | "
            f"{s['races_named']} of {s['races']} | {called} | {records_called} | {flagged} | "
            f"{r['wall']:.0f} |"
        )
    lines += [
        "",
        "By what the fault records' signals show (the physics rule's majority call, without "
        "labels): records named at record level, the mean probability of the true state over "
        "their segments, and the segments' ECE.",
        "",
        "| classifier | own fault shown: named | mean p(true) | ECE | another family shown: "
        "named | mean p(true) | ECE | no fault shown: named | mean p(true) | ECE |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        if r["kind"] != "job":
            continue
        cells = []
        for group in ("own", "other", "none"):
            g = r["scores"]["split"][group]
            cells += [
                f"{len(g['named'])} of {len(g['records'])}",
                _num(g["p_true"], ".2f"),
                _num(g["ece"], ".3f"),
            ]
        lines.append(f"| {r['name']} | " + " | ".join(cells) + " |")
    first = next((r for r in results if r["kind"] == "job"), None)
    if first is not None:
        split = first["scores"]["split"]
        lines += [""] + [
            f"- {label}: {', '.join(split[g]['records']) or 'none'}"
            for g, label in (
                ("own", "records whose signal shows their own fault"),
                ("other", "records whose signal shows another fault family"),
                ("none", "fault records whose signal shows no fault"),
            )
        ]
    return "\n".join(lines) + "\n"


def _classifier_text(result, runs, files, shows: dict[str, str]) -> str:
    classes = result["classes"]
    s = result["scores"]
    lines = [f"## {result['name']}", ""]
    lines += [f"- {n}" for n in result["notes"]]
    lines += [
        f"- segments flagged (out-of-distribution, uncertain, not corroborated by their "
        f"envelope lines, or not classified): {s['flagged_segments']} of "
        f"{len(result['segments'])}; not corroborated: {s['uncorroborated_segments']}"
        if result["kind"] == "job"
        else "- the rule flags nothing: it always names a state",
        "",
        (
            "Per record (predicted: the majority of its segments' calls, a tie broken by the "
            "mean probability; mean probability: of the predicted state over its segments; "
            "flagged: more than half of its segments out-of-distribution, uncertain (the "
            "probability of a wrong call above 0.1), not corroborated (the envelope lines of "
            "the called state absent, or for a healthy call a fault's present, at a 1 % "
            "false-alarm rate) or not classified):"
            if result["kind"] == "job"
            else "Per record (predicted: the majority of its segments' calls, a tie broken by "
            "the larger mean standardised indicator; z: each family's mean standardised "
            "envelope-line indicator over the record's segments, against the threshold above):"
        ),
        "",
    ]
    state = {r["record"]: r for r in runs}
    if result["kind"] == "job":
        lines += [
            "| file | class | size (in) | load (hp) | signal shows | predicted | mean "
            "probability | mean p(true) | called at the selective risk | flagged (share of "
            "segments) | votes |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
    else:
        lines += [
            "| file | class | size (in) | load (hp) | predicted | z outer race | z inner race "
            "| z ball | votes |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
    for name, r in result["records"].items():
        info = state[name]
        votes = ", ".join(f"{c} {v}" for c, v in r["votes"].items() if v)
        mark = "" if r["predicted"] == info["state"] else " (wrong)"
        lead = (
            f"| {files.get(name, name)} | {info['state']} | {info['fault_size_in']:.3f} | "
            f"{info['load_hp']:g} | "
        )
        head = lead + f"{r['predicted']}{mark} | "
        if result["kind"] == "job":
            chosen = r["selective"]
            called = (
                "uncalled"
                if chosen is None
                else chosen + ("" if chosen == info["state"] else " (wrong)")
            )
            lines.append(
                lead + f"{shows[name]} | {r['predicted']}{mark} | "
                f"{_num(r['probability'], '.2f')} | {_num(r['p_true'], '.2f')} | {called} | "
                f"{'yes' if r['flagged'] else 'no'} ({r['share_flagged']:.0%}) | {votes} |"
            )
        else:
            z = r["mean_z"]
            lines.append(
                head + f"{z['outer_race']:.1f} | {z['inner_race']:.1f} | {z['ball']:.1f} | "
                f"{votes} |"
            )
    for level in ("segment", "record"):
        lines += [
            "",
            f"Confusion, {level} level (rows: true state, columns: predicted):",
            "",
            "| true \\ predicted | " + " | ".join(classes) + " |",
            "|---|" + "---|" * len(classes),
        ]
        lines += [
            f"| {classes[i]} | " + " | ".join(str(v) for v in row) + " |"
            for i, row in enumerate(s[level])
        ]
    lines += ["", "| stage | seconds | reused |", "|---|---|---|"]
    lines += [
        f"| {n} | {sec:.1f} | {'yes' if reused else 'no'} |" for n, sec, reused in result["stages"]
    ]
    return "\n".join(lines) + "\n"


def _diagnosis_text(result) -> str:
    """What the diagnosis of the healthy calibration segments names, and its evidence."""
    d = result["diagnosis"]
    lines = [
        f"## Diagnosis of the healthy record ({result['name']})",
        "",
        "The generic diagnosis with the bearing's catalogue, on the healthy calibration segments "
        'only (docs/bearing.md, "Diagnosis"). Real data hold no hidden truth: what is named '
        "is a statement about the model against this record.",
        "",
        f"- verdict: `{d['verdict']}`; confirmed: {', '.join(d['confirmed']) or 'none'}",
        f"- rule: {d['rule']}",
        "",
        "| cause | evidence | held-out gain (ELPD) | statistic (SE) | threshold | confirmed |",
        "|---|---|---|---|---|---|",
    ]
    for c in d["causes"]:
        g = c.get("gain")
        gain = "-" if g is None else f"{g['delta_elpd']:+.1f} +- {g['elpd_se']:.1f}"
        stat = "-" if g is None else _num(g.get("statistic"), ".1f")
        threshold = "-" if g is None else _num(g.get("threshold"), ".2f")
        evidence = str(c["evidence"]).replace("|", "/")
        lines.append(
            f"| {c['name']} | {evidence} | {gain} | {stat} | {threshold} | "
            f"{'yes' if c['confirmed'] else 'no'} |"
        )
    lines += [""] + [f"- note: {n}" for n in d.get("notes", [])]
    return "\n".join(lines) + "\n"


def _num(value, spec: str) -> str:
    if value is None or not np.isfinite(float(value)):
        return "-"
    return format(float(value), spec)


if __name__ == "__main__":
    main()
