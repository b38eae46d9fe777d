"""The full-size hidden-effect cases saved by ``scripts/full_size_case.py`` -> a results table.

Reads every ``NAME-SEED.json`` of a folder (default ``results/full_size``) and writes
``results/diagnosis_full_size.md``: per case the verdict, the held-out gain of the hidden
cause and of the strongest other candidate (in standard errors, with the runs that gain
where the case kept them), the key parameter against the rig's truth (drawn again from the
seed: ``from_seed`` is deterministic), whether the test's checks passed and the stage times;
then the detection rate per effect and the false alarms. Nothing is run: the cases are what
was saved.

Usage::

    .venv/bin/python scripts/full_size_table.py [--cases results/full_size]
        [--results results/diagnosis_full_size.md]
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from _cases import NONE, RIG_EFFECTS, ROOT, command_line, hidden_effect, write_results

from bayesdoor.diagnose import capped_t, rule_passes, rule_thresholds
from bayesdoor.diagnose._gain import DECISIVE_SE, t_statistic
from bayesdoor.diagnose._held_out import verdict_order


def fmt(value: Any, spec: str) -> str:
    """``value`` formatted by ``spec``, or ``-`` when it is missing or not finite."""
    if value is None or not np.isfinite(float(value)):
        return "-"
    return format(float(value), spec)


def _mean(value: Any) -> float:
    if isinstance(value, Mapping):
        value = value.get("mean")
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def _gain_words(cause: Mapping[str, Any] | None) -> str:
    """``+dELPD +- se (z SE)`` and the runs that gain, or ``-`` when not refitted."""
    gain = None if cause is None else cause.get("gain")
    if not gain:
        return "-"
    z = gain["delta_elpd"] / gain["elpd_se"] if gain["elpd_se"] else float("nan")
    words = f"{gain['delta_elpd']:+.0f} +- {gain['elpd_se']:.0f} ({z:.1f} SE)"
    per_run = gain.get("delta_elpd_per_run") or []
    if per_run:
        words += f", {sum(1 for d in per_run if d > 0)} of {len(per_run)} runs gain"
        d = np.asarray(per_run, dtype=float)
        on_t, on_capped = rule_thresholds(d.size)
        words += (
            f"; t {float(t_statistic(d)):.2f} against {on_t:.2f}, capped "
            f"{float(capped_t(d)):.2f} against {on_capped:.2f}"
        )
    return words


def current_verdict(case: Mapping[str, Any]) -> str | None:
    """The case's verdict under the rule of this code, from its saved gains (as
    ``diagnose_campaign`` decides: a refit is confirmed when it passes the rule, lowers J and
    does not fail to explain its feature; the first confirmed cause in ``verdict_order``);
    ``None`` when a refitted candidate lacks its per-run gains (cases saved by older code
    may lack them)."""
    causes = (case.get("diagnosis") or {}).get("causes", [])
    refitted = [c for c in causes if c.get("gain")]
    if any(not c["gain"].get("delta_elpd_per_run") for c in refitted):
        return None
    confirmed = [
        c
        for c in refitted
        if _passes(c)
        and c["gain"]["j_after"] < c["gain"]["j_before"]
        and "does not explain its own feature" not in c.get("evidence", "")
    ]
    if not confirmed:
        return NONE
    first = min(confirmed, key=lambda c: verdict_order(c["score"], c["gain"]["delta_elpd"]))
    return str(first["name"])


def _z(cause: Mapping[str, Any]) -> float:
    gain = cause.get("gain")
    return gain["delta_elpd"] / gain["elpd_se"] if gain and gain["elpd_se"] else float("-inf")


def _passes(cause: Mapping[str, Any]) -> bool:
    """Whether a refit's gain passes the rule's statistical part, computed again from the
    per-run gains where they were kept (so that cases saved under an earlier rule are judged
    alike), else the plain 4 SE (``DECISIVE_SE``) alone."""
    gain = cause.get("gain")
    if not gain:
        return False
    if gain.get("delta_elpd_per_run"):
        return rule_passes(np.asarray(gain["delta_elpd_per_run"], dtype=float))
    return _z(cause) > DECISIVE_SE


def key_parameter(name: str, seed: int, cause: Mapping[str, Any] | None) -> str:
    """The hidden effect's key parameter as the diagnosis estimated it, against the truth;
    marked when a refitted parameter of the cause stopped at an end of its search box."""
    words = _key_parameter(name, seed, cause)
    p: Mapping[str, Any] = {} if cause is None else cause.get("parameters") or {}
    ends = sorted(
        n.split(".")[-1] for n, v in p.items() if isinstance(v, Mapping) and v.get("at_bound")
    )
    if ends:
        words += f"; *at its box's end*: {', '.join(ends)}"
    return words


def _key_parameter(name: str, seed: int, cause: Mapping[str, Any] | None) -> str:
    if name == NONE:
        return "-"
    truth = getattr(hidden_effect(name, seed), name)
    p: Mapping[str, Any] = {} if cause is None else cause.get("parameters") or {}
    if name == "frame_mode":
        got = _mean(p.get("frame_mode.frequency_hz", p.get("frequency_hz")))
        words = f"{fmt(got, '.2f')} (rig {truth.frequency_hz:.2f}) Hz"
        installed = _mean(p.get("frame_mode.installed_frequency_hz"))
        if np.isfinite(installed):
            words += f"; installed {installed:.2f} Hz"
        return words
    if name == "rail_waviness":
        got = _mean(p.get("rail_waviness.wavelength_m", p.get("period")))
        return f"{fmt(1e3 * got, '.2f')} (rig {1e3 * truth.wavelength_m:.2f}) mm"
    if name == "sensor_cross_axis":
        got = _mean(p.get("sensor_cross_axis.fraction", p.get("fraction")))
        where = f"{p.get('receiver', '?')} reads {p.get('source', '?')}"
        rig = f"{truth.sensor}{truth.into}"
        return f"{where}, fraction {fmt(abs(got), '.3f')} (rig into {rig}, {truth.fraction:.3f})"
    if name == "mains_hum":
        return f"{fmt(_mean(p.get('frequency_hz')), '.0f')} (rig {truth.frequency_hz:.0f}) Hz"
    harmonic = p.get("label")
    return f"harmonic {harmonic}" if harmonic is not None else "-"


def case_row(case: Mapping[str, Any], where: Mapping[str, str]) -> list[str]:
    name, seed = case["name"], int(case["seed"])
    diagnosis = case.get("diagnosis") or {}
    causes = diagnosis.get("causes", [])
    hidden = next((c for c in causes if c["name"] == name), None)
    others = [c for c in causes if c["name"] not in (name, NONE) and c.get("gain")]
    best = max(others, key=_z, default=None)
    timings = diagnosis.get("timings", {})
    check = "pass" if case.get("passed") else "**fail**"
    if case.get("error"):
        check = "**error**"
    return [
        f"{name} {seed}",
        str(case.get("verdict")),
        str(current_verdict(case) or "-"),
        _gain_words(hidden) if name != NONE else "-",
        "-" if best is None else f"{best['name']}: {_gain_words(best)}",
        _gain_words({"gain": case["ceiling_gain"]}) if case.get("ceiling_gain") else "-",
        key_parameter(name, seed, hidden),
        check,
        fmt(case.get("seconds"), ".0f"),
        fmt(timings.get("fit"), ".0f"),
        fmt(timings.get("refits"), ".0f"),
        where.get(str(case.get("provenance")), "-"),
    ]


def summary(cases: Sequence[Mapping[str, Any]]) -> list[str]:
    lines = []
    for name in (*RIG_EFFECTS, NONE):
        mine = [c for c in cases if c["name"] == name]
        if not mine:
            continue
        right = sum(1 for c in mine if c.get("verdict") == name)
        passed = sum(1 for c in mine if c.get("passed"))
        seeds = ", ".join(str(c["seed"]) for c in mine)
        judged = [current_verdict(c) for c in mine]
        now = [v for v in judged if v is not None]
        again = (
            f" (this rule, on the {len(now)} with every per-run gain saved: "
            f"{sum(1 for v in now if v == name)} {'none' if name == NONE else 'named'})"
        )
        if name == NONE:
            lines.append(
                f"- nothing hidden: {right} of {len(mine)} answered `none` (seeds {seeds}); "
                f"false alarms: {len(mine) - right}{again}"
            )
        else:
            lines.append(
                f"- {name}: named in {right} of {len(mine)} (seeds {seeds}); the test's checks "
                f"(verdict and key parameter) passed in {passed}{again}"
            )
    ceilings = [
        (case, {"gain": case["ceiling_gain"]})
        for case in cases
        if case["name"] != NONE and case.get("ceiling_gain")
    ]
    if ceilings:
        over = [f"{c['name']} {c['seed']}" for c, g in ceilings if _passes(g)]
        under = [f"{c['name']} {c['seed']} ({_z(g):.1f} SE)" for c, g in ceilings if not _passes(g)]
        lines.append(
            f"- ceilings: {len(over)} of {len(ceilings)} cases with one pass the rule with the "
            f"rig's own effect ({', '.join(over) or 'none'}); not: {', '.join(under) or 'none'}"
        )
    wrong = [
        (
            _z(c),
            c["name"],
            case["name"],
            case["seed"],
            case["name"] != NONE and case.get("verdict") == case["name"],
            _passes(c),
        )
        for case in cases
        for c in (case.get("diagnosis") or {}).get("causes", [])
        if c["name"] not in (case["name"], NONE) and c.get("gain")
    ]
    if wrong:
        z, cause, name, seed, _, _ = max(wrong)
        passing = [w for w in wrong if w[5]]
        lines.append(
            f"- the strongest wrong candidate: {cause} in the case {name} {seed}, {z:.1f} SE; "
            f"{len(passing)} of {len(wrong)} wrong refits passed the rule (computed again "
            "where the per-run gains were kept, else 4 SE), "
            f"{sum(1 for w in passing if w[4])} of them beside a hidden cause that the verdict "
            "named (ranked first)"
        )
    return lines


def table(cases: Sequence[Mapping[str, Any]], command: str) -> str:
    header = [
        "case",
        "verdict",
        "verdict, this rule",
        "gain of the hidden cause",
        "strongest other candidate",
        "ceiling (the rig's own effect added)",
        "key parameter (estimate, truth)",
        "test",
        "wall (s)",
        "fit (s)",
        "refits (s)",
        "where",
    ]
    provenances = sorted({str(c.get("provenance")) for c in cases if c.get("provenance")})
    where = {p: chr(ord("A") + i) for i, p in enumerate(provenances)}
    rows = [case_row(c, where) for c in cases]
    out = [
        "# Diagnosis at full size: 12 runs, each campaign's own fit",
        "",
        f"Command: `{command}` (the table, from the saved cases); each case: "
        "`python scripts/full_size_case.py NAME SEED results/full_size` "
        "(tests/test_diagnose_job.py::test_full_size's campaign and checks: 12 healthy rig runs "
        "over 0.25-0.50 m/s, the effect drawn by `from_seed(seed)`, `diagnose_campaign` with its "
        "default sizes). Gains are held-out log predictive densities, extended minus base; the "
        "verdict needs the plain or the capped statistic over its threshold and a lower J (the "
        "decision rule of docs/diagnosis.md; a case saved by older code carries the plain rule's "
        "verdict, more than 4 SE); *verdict, this rule*: the saved gains judged by this code's "
        "rule. The rig's truth is drawn again from the "
        "seed. The ceiling (cases run with `--ceiling`) is the gain of the base model plus the "
        "rig's own effect (the same runs recorded without it), judged on the same folds: what a "
        "perfect extension would gain. A key parameter marked *at its box's end* "
        "stopped at an end of its search box (not an estimate).",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
        *("| " + " | ".join(r) + " |" for r in rows),
        "",
        *(f"- where {label}: {p}" for p, label in where.items()),
        "",
        "## Summary",
        "",
        *summary(cases),
        "",
    ]
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=Path, default=ROOT / "results" / "full_size")
    parser.add_argument("--results", type=Path, default=ROOT / "results" / "diagnosis_full_size.md")
    args = parser.parse_args(argv)
    files = sorted(args.cases.glob("*-*.json"))
    if not files:
        raise SystemExit(f"no NAME-SEED.json in {args.cases}")
    order = {name: i for i, name in enumerate((*RIG_EFFECTS, NONE))}
    cases = [json.loads(f.read_text()) for f in files]
    cases.sort(key=lambda c: (order.get(c["name"], 99), int(c["seed"])))
    write_results(args.results, table(cases, command_line("full_size_table.py", argv)))


if __name__ == "__main__":
    main()
