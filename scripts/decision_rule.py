"""The held-out decision rule against a monotone version at the same false-alarm rate.

``bayesdoor.diagnose.compare_held_out`` calls an extension decisive when the per-run
held-out log predictive density differences ``d`` (one per held-out run) have
``sum(d) > 4 SE`` with ``SE = sqrt(n var(d))``: a one-sample t statistic above 4 (and a
lower J, left out here). That rule is not monotone in the gains: one run that gains far
more than the others widens the SE. The monotone version here is the closure

    T(d) = max over caps c >= median(d) of t(min(d, c)),

the largest t left when the gains above the median are lowered to a common level. It is
at least t, and raising the largest of three or more gains never lowers it. Raising another
gain can: when n is even and the gain is the upper of the two middle ones, the median (the
lowest cap) moves up with it (``tests/test_decision_rule.py`` has an example).

The script estimates, from seeded draws, the false-alarm rates of ``t > 4`` and ``T > 4``
under three kinds of noise; the thresholds ``T_n`` at which ``T`` has the false-alarm rate
of ``t > 4`` under normal noise; and the verdicts of the three rules on the saved full-size
cases (``results/full_size/*.json``). It writes a markdown table (default
``results/decision_rule.md``).

Usage::

    .venv/bin/python scripts/decision_rule.py [--draws 200000] [--seed 0]
        [--cases results/full_size] [--results results/decision_rule.md]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from _cases import ROOT, command_line, write_results
from scipy import stats

from bayesdoor.diagnose import capped_t, rule_passes, rule_thresholds
from bayesdoor.diagnose._gain import _runs, t_statistic

#: the threshold on t of the plain rule (``bayesdoor.diagnose.DECISIVE_SE``)
THRESHOLD = 4.0
#: held-out runs of the null false-alarm table
NULL_RUNS = (6, 8, 12)
#: held-out runs of the calibrated-threshold table
CALIBRATION_RUNS = (6, 8, 10, 12, 16, 24)
#: held-out runs of the library's threshold table (``--thresholds``)
TABLE_RUNS = tuple(range(2, 41))
#: the calibration's draws are this many batches of ``--draws`` each
BATCHES = 10
#: caps per interval between consecutive sorted values of the grid reference
GRID_CAPS = 21
#: the calibration keeps this upper fraction of its draws, for the saved cases' tail probabilities
TAIL = 0.01

#: mean-zero noise of one held-out difference per run: name -> draw(rng, shape)
NOISES: dict[str, Callable[[np.random.Generator, tuple[int, ...]], np.ndarray]] = {
    "normal": lambda rng, shape: rng.standard_normal(shape),
    "Student t, 3 dof": lambda rng, shape: rng.standard_t(3, shape),
    "lognormal(0, 1) - exp(0.5)": lambda rng, shape: rng.lognormal(0.0, 1.0, shape) - np.exp(0.5),
}


#: the statistics, as the library computes them
monotone_statistic = capped_t


def monotone_statistic_on_grid(d: np.ndarray, caps: int = GRID_CAPS) -> np.ndarray:
    """The closure of :func:`monotone_statistic` on a grid of caps: a reference for it.

    The caps are ``caps`` evenly spaced points between every pair of consecutive sorted
    values at or above the median (each sorted value included), and the median. The grid
    misses the maximum between its points, so it is at most the exact statistic.
    """
    d = np.asarray(d, dtype=float)
    n = _runs(d)
    x = np.sort(d, axis=-1)
    median = np.median(x, axis=-1)[..., None]
    lo = np.maximum(x[..., :-1], median)
    hi = np.maximum(x[..., 1:], median)
    steps = np.linspace(0.0, 1.0, caps)
    grid = (lo[..., None] + (hi - lo)[..., None] * steps).reshape(*x.shape[:-1], (n - 1) * caps)
    grid = np.concatenate([median, grid], axis=-1)
    return np.nanmax(t_statistic(np.minimum(d[..., None, :], grid[..., None])), axis=-1)


def _generator(seed: int, *cell: int) -> np.random.Generator:
    """A generator of its own for each table cell, so that a cell does not depend on the order."""
    return np.random.default_rng([seed, *cell])


@dataclass(frozen=True)
class Threshold:
    """``T_n``: ``P_normal(T > T_n) = P(t_{n-1} > 4)``, with a Monte Carlo standard error.

    ``tail`` holds the largest ``TAIL`` of the draws, sorted, for :meth:`tail_probability`.
    """

    runs: int
    alarm: float
    value: float
    se: float
    draws: int
    tail: np.ndarray

    def tail_probability(self, statistic: float) -> float | None:
        """The fraction of the draws whose T exceeds ``statistic``; ``None`` above ``TAIL``."""
        if statistic < self.tail[0]:
            return None
        above = self.tail.size - np.searchsorted(self.tail, statistic, side="right")
        return float(above / self.draws)


def calibrate(runs: int, draws: int, seed: int) -> Threshold:
    """``T_n`` from ``BATCHES`` batches of ``draws`` normal samples of ``runs`` runs.

    The threshold is the pooled draws' ``1 - alarm`` quantile; its standard error is the
    spread of the batches' quantiles over ``sqrt(BATCHES)``.
    """
    alarm = float(stats.t.sf(THRESHOLD, runs - 1))
    batches = [
        monotone_statistic(_generator(seed, 0, runs, i).standard_normal((draws, runs)))
        for i in range(BATCHES)
    ]
    per_batch = [np.quantile(t, 1.0 - alarm) for t in batches]
    pooled = np.sort(np.concatenate(batches))
    value = float(np.quantile(pooled, 1.0 - alarm))
    se = float(np.std(per_batch, ddof=1) / np.sqrt(BATCHES))
    tail = pooled[-max(1, int(TAIL * pooled.size)) :]
    return Threshold(runs, alarm, value, se, pooled.size, tail)


def union_scale(runs: int, draws: int, seed: int, capped: float) -> tuple[float, float]:
    """``k_n`` with ``P_normal(t > 4 k_n or T > capped k_n) = P(t_{n-1} > 4)``, and its
    Monte Carlo standard error (the spread of the batches' ``k`` over ``sqrt(BATCHES)``).

    The union of the plain and the capped test, both thresholds scaled by one factor, at
    the false-alarm rate of ``t > 4`` alone; ``capped`` is the library's ``T_n``. The draws
    are those of :func:`calibrate` (the same generators).
    """
    alarm = float(stats.t.sf(THRESHOLD, runs - 1))
    pairs = []
    for i in range(BATCHES):
        d = _generator(seed, 0, runs, i).standard_normal((draws, runs))
        pairs.append((t_statistic(d), monotone_statistic(d)))

    def solve(t: np.ndarray, big_t: np.ndarray) -> float:
        lo, hi = 0.5, 3.0
        for _ in range(50):
            k = 0.5 * (lo + hi)
            rate = np.mean((t > THRESHOLD * k) | (big_t > capped * k))
            lo, hi = (k, hi) if rate > alarm else (lo, k)
        return 0.5 * (lo + hi)

    per_batch = [solve(t, big_t) for t, big_t in pairs]
    pooled = solve(np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs]))
    return pooled, float(np.std(per_batch, ddof=1) / np.sqrt(BATCHES))


@dataclass(frozen=True)
class NullRate:
    """False-alarm rates of the three rules under one noise and one number of runs."""

    noise: str
    runs: int
    draws: int
    t_rate: float
    monotone_rate: float
    calibrated_rate: float
    library_rate: float


def null_rate(noise: str, runs: int, draws: int, seed: int, threshold: float) -> NullRate:
    """``P(t > 4)``, ``P(T > 4)`` and ``P(T > threshold)`` from ``draws`` noise samples."""
    d = NOISES[noise](_generator(seed, 1 + list(NOISES).index(noise), runs), (draws, runs))
    monotone = monotone_statistic(d)
    t = t_statistic(d)
    on_t, on_capped = rule_thresholds(runs)
    return NullRate(
        noise,
        runs,
        draws,
        float(np.mean(t > THRESHOLD)),
        float(np.mean(monotone > THRESHOLD)),
        float(np.mean(monotone > threshold)),
        float(np.mean((t > on_t) | (monotone > on_capped))),
    )


@dataclass(frozen=True)
class Verdict:
    """The three rules on one candidate of one saved case."""

    case: str
    candidate: str
    hidden: bool
    runs: int
    t: float
    monotone: float
    grid: float
    threshold: float
    tail: float | None
    saved: bool | None
    library: bool

    @property
    def current(self) -> bool:
        return self.t > THRESHOLD

    @property
    def calibrated(self) -> bool:
        return self.monotone > self.threshold

    @property
    def at_four(self) -> bool:
        return self.monotone > THRESHOLD


def judge(row: dict[str, Any], threshold: Threshold) -> Verdict:
    """The three rules on one row of :func:`saved_gains`."""
    d = row["per_run"]
    monotone = float(monotone_statistic(d))
    return Verdict(
        case=row["case"],
        candidate=row["candidate"],
        hidden=row["hidden"],
        runs=d.size,
        t=float(t_statistic(d)),
        monotone=monotone,
        grid=float(monotone_statistic_on_grid(d)),
        threshold=threshold.value,
        tail=threshold.tail_probability(monotone),
        saved=row["saved"],
        library=rule_passes(d),
    )


def saved_gains(folder: Path) -> tuple[list[dict[str, Any]], int, int, int]:
    """The candidates with per-run gains of every ``*.json`` case in ``folder``.

    Returns
    -------
    rows, files, not_refitted, no_per_run
        One dict per candidate (``case``, ``candidate``, ``hidden``, ``per_run``,
        ``saved``: the saved ``decisive``, which also needs J), the files read, and the
        candidates skipped because they were not refitted (``gain`` null) or have no
        per-run gains.
    """
    files = sorted(folder.glob("*.json"))
    if not files:
        raise SystemExit(f"no saved case (*.json) in {folder}")
    rows, not_refitted, no_per_run = [], 0, 0
    for path in files:
        case = json.loads(path.read_text())
        for cause in case["diagnosis"]["causes"]:
            gain = cause.get("gain")
            if not gain:
                not_refitted += 1
                continue
            per_run = gain.get("delta_elpd_per_run") or []
            if not per_run:
                no_per_run += 1
                continue
            rows.append(
                {
                    "case": f"{case['name']}-{case['seed']}",
                    "candidate": cause["name"],
                    "hidden": cause["name"] == case["name"],
                    "per_run": np.asarray(per_run, dtype=float),
                    "saved": gain.get("decisive"),
                }
            )
    return rows, len(files), not_refitted, no_per_run


def _tail(probability: float | None) -> str:
    return f"> {TAIL}" if probability is None else f"{probability:.5f}"


def _yes(flag: bool | None) -> str:
    return "-" if flag is None else ("yes" if flag else "no")


def _stamp() -> str:
    def git(*words: str) -> str:
        done = subprocess.run(
            ["git", "-C", str(ROOT), *words], capture_output=True, text=True, check=False
        )
        return done.stdout.strip() if done.returncode == 0 else ""

    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    changed = (
        "with uncommitted changes" if git("status", "--porcelain") else "no uncommitted changes"
    )
    when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    return (
        f"{when}, {platform.node() or 'this machine'}, {os.cpu_count()} CPUs; commit {commit}, "
        f"{changed}"
    )


def _factor(numerator: float, denominator: float) -> str:
    return f"{numerator / denominator:.1f}" if denominator > 0 else "-"


def _findings(
    rates: Sequence[NullRate],
    thresholds: dict[int, Threshold],
    verdicts: Sequence[Verdict],
    skipped: tuple[int, int, int],
) -> list[str]:
    """The bullet list "What the numbers show", each fact computed from the tables."""
    lines = []
    for noise in NOISES:
        rows = [r for r in rates if r.noise == noise]
        lines.append(
            f"Under {noise} noise, `T > 4` raises the false alarms of `t > 4` by a factor "
            + ", ".join(f"{_factor(r.monotone_rate, r.t_rate)} (n = {r.runs})" for r in rows)
            + "; `T > T_n` has "
            + ", ".join(f"{_factor(r.calibrated_rate, r.t_rate)} (n = {r.runs})" for r in rows)
            + " times the false alarms of `t > 4`; the library's rule (`t > 4 k_n` or `T > T_n "
            "k_n`) has "
            + ", ".join(f"{_factor(r.library_rate, r.t_rate)} (n = {r.runs})" for r in rows)
            + "."
        )
    lines.append(
        "The thresholds that give `T` the normal-noise false-alarm rate of `t > 4` are "
        + ", ".join(f"{th.value:.2f} (n = {n})" for n, th in sorted(thresholds.items()))
        + "."
    )
    for label, rule in (
        ("`T > T_n`", "calibrated"),
        ("`T > 4`", "at_four"),
        ("the library's rule", "library"),
    ):
        changed = [v for v in verdicts if getattr(v, rule) != v.current]
        if not changed:
            lines.append(f"{label} changes none of the {len(verdicts)} verdicts of `t > 4`.")
            continue
        words = "; ".join(
            f"{v.case} {v.candidate} ({'the hidden effect' if v.hidden else 'not hidden'}, "
            f"t = {v.t:.2f}, T = {v.monotone:.2f}): "
            f"{'decisive' if getattr(v, rule) else 'not decisive'}"
            for v in changed
        )
        lines.append(
            f"{label} changes {len(changed)} of the {len(verdicts)} verdicts of `t > 4`: {words}."
        )
    if verdicts:
        near = min(verdicts, key=lambda v: abs(v.monotone - v.threshold))
        calibration = thresholds[near.runs]
        tail = _tail(near.tail)
        if near.tail is not None:
            tail += f" +- {np.sqrt(near.tail * (1 - near.tail) / calibration.draws):.5f}"
        lines.append(
            f"The candidate nearest the calibrated threshold is {near.case} {near.candidate}: "
            f"T = {near.monotone:.3f} against T_{near.runs} = {near.threshold:.3f} +- "
            f"{calibration.se:.3f}, {(near.monotone - near.threshold) / calibration.se:+.1f} "
            f"standard errors; under normal noise T exceeds it with probability {tail} against "
            f"{calibration.alarm:.5f} for t > 4."
        )
        gap = max(v.monotone - v.grid for v in verdicts)
        lines.append(
            f"On the saved cases the grid of {GRID_CAPS} caps per interval falls at most "
            f"{gap:.1e} below the exact statistic."
        )
    files, not_refitted, no_per_run = skipped
    lines.append(
        f"Of the {files} saved cases, {len(verdicts)} candidates have per-run gains; "
        f"{no_per_run} refitted candidates were skipped for want of per-run gains and "
        f"{not_refitted} candidates were not refitted."
    )
    return [f"- {line}" for line in lines]


def report(
    command: str,
    rates: Sequence[NullRate],
    thresholds: dict[int, Threshold],
    verdicts: Sequence[Verdict],
    skipped: tuple[int, int, int],
    seconds: float,
) -> str:
    """The markdown of the results."""
    draws = rates[0].draws
    out = [
        "# The held-out decision rule against a monotone version",
        "",
        f"Made by `{command}` ({_stamp()}; {seconds:.0f} s).",
        "",
        "The plain rule calls an extension decisive when the per-run held-out log "
        "predictive density differences d have t = sum(d) / sqrt(n var(d)) > 4 (and J falls, "
        "left out here). The library's rule is the union t > 4 k_n or "
        "T > T_n k_n (T_n from `--thresholds`, bayesdoor.diagnose.CAPPED_THRESHOLDS; k_n from "
        "`--union`, UNION_SCALE), at the false-alarm rate of t > 4 under normal noise. "
        "The monotone version is T(d) = max over caps c >= median(d) of t(min(d, c)), "
        "computed exactly (the maximum over each interval between sorted values lies at an end "
        "or where sum of squares = c sum of the uncapped values). Null draws are n independent "
        "mean-zero noise values per sample; T_n is the threshold with "
        "P_normal(T > T_n) = P(t_{n-1} > 4). The saved cases' verdicts ignore J.",
        "",
        f"## False alarms under noise ({draws} draws per row)",
        "",
        "Each rate is followed by its binomial standard error sqrt(p (1 - p) / draws).",
        "",
        "| noise | n | P(t > 4) | P(T > 4) | P(T > T_n) | P(library rule) "
        "| P(t_{n-1} > 4), scipy |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rates:
        cells = [
            f"{p:.5f} +- {np.sqrt(p * (1 - p) / r.draws):.5f}"
            for p in (r.t_rate, r.monotone_rate, r.calibrated_rate, r.library_rate)
        ]
        exact = stats.t.sf(THRESHOLD, r.runs - 1)
        out.append(f"| {r.noise} | {r.runs} | {' | '.join(cells)} | {exact:.5f} |")
    first = next(iter(thresholds.values()))
    out += [
        "",
        f"## Calibrated thresholds ({first.draws} normal draws per n, in {BATCHES} batches)",
        "",
        "The standard error is the spread of the batches' quantiles over sqrt(batches).",
        "",
        "| n | P(t_{n-1} > 4) | T_n | MC SE of T_n |",
        "|---|---|---|---|",
    ]
    for n, th in sorted(thresholds.items()):
        out.append(f"| {n} | {th.alarm:.5f} | {th.value:.3f} | {th.se:.3f} |")
    out += [
        "",
        "## Saved full-size cases",
        "",
        "Decisive under t > 4 (the plain rule, ignoring J), T > T_n and T > 4; "
        "the last column is the saved verdict, which also needs a lower J. "
        "P_normal(T above it) is the fraction of the calibration's normal draws whose T "
        "exceeds the case's.",
        "",
        "| case | candidate | hidden effect | n | t | T | T_n | P_normal(T above it) "
        "| t > 4 | T > T_n | T > 4 | library rule | saved |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for v in verdicts:
        out.append(
            f"| {v.case} | {v.candidate} | {_yes(v.hidden)} | {v.runs} | {v.t:.2f} | "
            f"{v.monotone:.2f} | {v.threshold:.2f} | {_tail(v.tail)} | {_yes(v.current)} | "
            f"{_yes(v.calibrated)} | {_yes(v.at_four)} | {_yes(v.library)} | {_yes(v.saved)} |"
        )
    out += [
        "",
        "## What the numbers show",
        "",
        *_findings(rates, thresholds, verdicts, skipped),
        "",
    ]
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=200_000, help="null draws per table row")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cases", type=Path, default=ROOT / "results" / "full_size")
    parser.add_argument("--results", type=Path, default=ROOT / "results" / "decision_rule.md")
    parser.add_argument(
        "--thresholds",
        action="store_true",
        help="print T_n for n = 2..40 held-out runs as bayesdoor.diagnose's "
        "CAPPED_THRESHOLDS table (nothing else is computed or written)",
    )
    parser.add_argument(
        "--union",
        action="store_true",
        help="print k_n for n = 2..40 held-out runs as bayesdoor.diagnose's UNION_SCALE table "
        "(the union t > 4 k_n or T > T_n k_n at t > 4's rate; nothing else is written)",
    )
    args = parser.parse_args(argv)
    if args.union:
        from bayesdoor.diagnose._gain import capped_threshold

        scales = {n: union_scale(n, args.draws, args.seed, capped_threshold(n)) for n in TABLE_RUNS}
        print(f"# {command_line('decision_rule.py', argv)}; Monte Carlo standard errors:")
        print("# " + ", ".join(f"{n}: {se:.4f}" for n, (_, se) in scales.items()))
        print("{" + ", ".join(f"{n}: {k:.4f}" for n, (k, _) in scales.items()) + "}")
        return
    if args.thresholds:
        rows = [calibrate(n, args.draws, args.seed) for n in TABLE_RUNS]
        print(f"# {command_line('decision_rule.py', argv)}; Monte Carlo standard errors:")
        print("# " + ", ".join(f"{t.runs}: {t.se:.3f}" for t in rows))
        print("{" + ", ".join(f"{t.runs}: {t.value:.3f}" for t in rows) + "}")
        return
    if args.draws < 100:
        parser.error(f"--draws {args.draws}: use at least 100 (a tail of 1e-3 needs many more)")
    start = time.perf_counter()
    rows, files, not_refitted, no_per_run = saved_gains(args.cases)
    wanted = sorted({*CALIBRATION_RUNS, *NULL_RUNS, *(r["per_run"].size for r in rows)})
    thresholds = {n: calibrate(n, args.draws, args.seed) for n in wanted}
    rates = [
        null_rate(noise, n, args.draws, args.seed, thresholds[n].value)
        for noise in NOISES
        for n in NULL_RUNS
    ]
    verdicts = [judge(r, thresholds[r["per_run"].size]) for r in rows]
    text = report(
        command_line("decision_rule.py", argv),
        rates,
        thresholds,
        verdicts,
        (files, not_refitted, no_per_run),
        time.perf_counter() - start,
    )
    write_results(args.results, text)


if __name__ == "__main__":
    main()
