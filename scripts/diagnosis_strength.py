"""How strong is each hidden rig effect? -> results/diagnosis_strength.md and .png.

For every hidden-effect case of the diagnosis table (``scripts/diagnosis.py``: 6 healthy runs
at speeds drawn in 0.25-0.5 m/s) and of the diagnosis tests (``tests/test_diagnose_job.py``:
8 runs over 0.30-0.50 m/s, seeds 0-1 and the validation seeds), the virtual rig records the
runs twice with the same key: with the effect and without it. In ``VirtualRig.run`` run i's
parameter scatter, actual speed, noise and hum phase come only from ``split(key, runs)[i]``,
and the effect only changes the equations and the acquisition chain, so the two recordings
differ by the effect's contribution alone (its own signal and what it does to the door's
motion), on the same noise.

The strength is measured where the diagnosis judges its refits: the log10 Welch PSD of each
run in its motion window, 1 Hz bins (``nperseg = fs``) over the base fit's feature band
(``FeatureSpec``'s 4-96 Hz), as ``bayesdoor.diagnose.Spectra.of_measured`` computes it. Per
run, channel and bin, ``z`` is the change of that log10 PSD caused by the effect over the
standard deviation of the run's Welch estimate (``trigamma(nu / 2) / ln(10)^2`` for its
equivalent degrees of freedom ``nu``). Per case: the largest ``|z|``; the largest ``|z|`` of
the change averaged over the runs (over the standard deviation of that mean, for changes at a
fixed frequency); and ``lambda = sum z^2`` over runs, channels and bins, the non-centrality an
ideal test of the measurements against the effect-free prediction would have (neighbouring
Hann bins are correlated, so it over-counts independent evidence by up to about 2x).

The verdicts come from the saved cases of ``scripts/diagnosis.py`` (``--verdicts``) and, for
the 8-run cases, from the test file's marks (a strict ``xfail`` is a measured failure).

Usage::

    .venv/bin/python scripts/diagnosis_strength.py [--quick] [--seeds 0 1]
        [--no-tests] [--verdicts out/diagnosis-s6b] [--jobs N]
        [--work out/diagnosis-strength] [--results results/diagnosis_strength.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
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
from diagnosis import EFFECTS_INDEX
from diagnosis import Settings as TableSettings

TEST_FILE = ROOT / "tests" / "test_diagnose_job.py"
#: the two sets of cases: the diagnosis table's and the diagnosis tests'
TABLE, TESTS = "table", "tests"
#: a change of 3 Welch standard deviations in one bin (the table's count of such bins)
Z_MARK = 3.0
#: the two-sided level at which one bin of a case stands out of all its bins (Bonferroni)
LEVEL = 0.05


def bonferroni_z(bins: int) -> float:
    """The ``|z|`` one bin needs to stand out of ``bins`` at ``LEVEL`` (two-sided Bonferroni).

    A reference for the largest ``|z|``: a test of each bin's measured PSD against an exact
    prediction, whose only scatter is the Welch estimator's, flags nothing weaker in any bin.
    """
    import scipy.stats

    return float(scipy.stats.norm.isf(LEVEL / (2.0 * bins)))


@dataclasses.dataclass(frozen=True)
class Settings:
    """What a case's strength depends on (its hash names the saved case)."""

    kind: str
    runs: int
    f_low: float
    f_high: float

    def digest(self) -> str:
        return digest(self, 10)


# ---------------------------------------------------------------------------- strength


def effect_z(
    with_effect: np.ndarray,
    without: np.ndarray,
    fs: float,
    t_start: np.ndarray,
    t_stop: np.ndarray,
    band: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The effect's change of each run's log10 Welch PSD in Welch standard deviations.

    Parameters
    ----------
    with_effect, without
        Signals (run, channel, time) recorded with and without the effect on the same noise.
    fs
        Sampling rate, Hz.
    t_start, t_stop
        Each run's motion window, s (the same for both recordings).
    band
        The analysed bins' frequency range, Hz (both ends included).

    Returns
    -------
    freqs
        Bin frequencies, Hz (1 Hz bins).
    z
        ``(log10 PSD with - log10 PSD without) / sd`` per run, channel and bin.
    sd
        Each run's Welch standard deviation of a log10 PSD bin, decades.
    """
    from bayesdoor.diagnose._refit import Spectra

    def spectra(x: np.ndarray) -> Any:
        return Spectra.of_measured(x, fs, t_start, t_stop, band, nperseg=int(fs))

    a, b = spectra(with_effect), spectra(without)
    sd = np.sqrt(np.asarray(b.log_variance))
    return np.asarray(b.freqs), (a.measured - b.measured) / sd[:, None, None], sd


def summarise(freqs: np.ndarray, z: np.ndarray, channels: Sequence[str]) -> dict[str, Any]:
    """The case's strength figures from ``z`` (run, channel, bin) of :func:`effect_z`.

    ``z_max``: the largest ``|z|`` (and where); ``z_mean_max``: the largest ``|z|`` of the
    run-averaged change, ``mean_r z * sqrt(runs)`` (every run's estimate has its own scatter,
    so the mean has the standard deviation ``sqrt(mean_r sd_r^2 / runs)``; the runs' standard
    deviations differ by their segment counts only, and the form used takes them as equal);
    ``lambda``: ``sum z^2``; per channel, ``lambda`` and the largest ``|z|``.
    """
    runs = z.shape[0]
    r, c, f = (int(i) for i in np.unravel_index(np.argmax(np.abs(z)), z.shape))
    pooled = z.mean(axis=0) * np.sqrt(runs)
    pc, pf = (int(i) for i in np.unravel_index(np.argmax(np.abs(pooled)), pooled.shape))
    return {
        "z_max": float(abs(z[r, c, f])),
        "z_max_at": {"run": r, "channel": channels[c], "hz": float(freqs[f])},
        "z_mean_max": float(abs(pooled[pc, pf])),
        "z_mean_max_at": {"channel": channels[pc], "hz": float(freqs[pf])},
        "lambda": float(np.sum(z**2)),
        "bins_over_3": int(np.sum(np.abs(z) > Z_MARK)),
        "bins": int(z.size),
        "per_channel": {
            ch: {
                "lambda": float(np.sum(z[:, i] ** 2)),
                "z_max": float(np.max(np.abs(z[:, i]))),
            }
            for i, ch in enumerate(channels)
        },
        "per_run_z_max": np.max(np.abs(z), axis=(1, 2)).tolist(),
    }


# ------------------------------------------------------------------------------ one case


def _load_tests():
    """``tests/test_diagnose_job.py`` as a module: its recording and its cases' marks."""
    spec = importlib.util.spec_from_file_location("test_diagnose_job", TEST_FILE)
    if spec is None or spec.loader is None:
        raise FileNotFoundError(f"cannot import {TEST_FILE}: the 8-run cases are defined there")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _record_pair(effect: str, seed: int, settings: Settings):
    """The case's recordings with and without the effect, the same key and speeds."""
    import jax

    from bayesdoor.door.rig import VirtualRig

    if settings.kind == TESTS:
        tests = _load_tests()
        return tests.record(effect, seed)[0], tests.record(NONE, seed)[0]
    # the recording of scripts/diagnosis.py's run_case
    rng = np.random.default_rng(1000 + seed)
    speeds = np.sort(rng.uniform(0.25, 0.5, settings.runs))
    key = jax.random.key(10_000 * EFFECTS_INDEX[effect] + seed)
    pair = [
        VirtualRig(effects=effects).run(["healthy"] * settings.runs, speeds, key=key)
        for effects in (hidden_effect(effect, seed), hidden_effect(NONE, seed))
    ]
    return pair[0], pair[1]


def run_case(effect: str, seed: int, settings: Settings) -> dict[str, Any]:
    """Record the case twice and measure the effect's strength."""
    setup_jax()
    from bayesdoor.pipeline import json_safe

    start = time.perf_counter()
    with_effect, without = _record_pair(effect, seed, settings)
    same = with_effect.truth["runs"] == without.truth["runs"]
    if not same:
        raise RuntimeError(
            f"{effect} seed {seed}: the two recordings' run scatter or speeds differ, so their "
            "difference is not the effect's alone; check VirtualRig.run's key use"
        )
    campaign = with_effect.campaign
    channels = [str(c) for c in campaign["channel"].values]
    freqs, z, sd = effect_z(
        np.asarray(campaign["acceleration"].values, dtype=float),
        np.asarray(without.campaign["acceleration"].values, dtype=float),
        float(campaign.attrs["sampling_rate_hz"]),
        np.asarray(campaign["t_start"].values, dtype=float),
        np.asarray(campaign["t_stop"].values, dtype=float),
        (settings.f_low, settings.f_high),
    )
    return {
        "effect": effect,
        "seed": seed,
        "kind": settings.kind,
        "speeds": np.asarray(campaign["v_max"].values, dtype=float).tolist(),
        "truth": json_safe(with_effect.truth["effects"][effect]),
        "welch_sd": sd.tolist(),
        **summarise(freqs, z, channels),
        "code": code_version(),
        "seconds": time.perf_counter() - start,
    }


def _case_file(work: Path, effect: str, seed: int, settings: Settings) -> Path:
    return work / f"{settings.kind}-{effect}-{seed}-{settings.digest()}.json"


def _run_and_save(effect: str, seed: int, settings: Settings, path: str) -> dict[str, Any]:
    result = attempt(run_case, effect, seed, settings)
    save_json(Path(path), result)
    return result


# ---------------------------------------------------------------------------- verdicts


def table_verdicts(folder: Path, runs: int) -> dict[tuple[str, int], dict[str, Any]]:
    """The verdicts of ``scripts/diagnosis.py``'s saved quick cases at ``runs`` runs."""
    name = TableSettings(runs=runs, v_low=0.25, v_high=0.5, quick=True).digest()
    out = {}
    for path in sorted(folder.glob(f"*-{name}.json")):
        row = json.loads(path.read_text())
        out[(row["effect"], int(row["seed"]))] = {
            "named": bool(row.get("named")),
            "verdict": str(row.get("verdict")),
            "speeds": row.get("speeds"),
            "source": str(path.relative_to(ROOT) if path.is_relative_to(ROOT) else path),
        }
    return out


def test_verdicts() -> dict[tuple[str, int], dict[str, Any]]:
    """The 8-run cases of the diagnosis tests: named (passes) or a strict expected failure."""
    out = {}
    for param in _load_tests().CASES:
        name, seed = param.values
        xfail = [m for m in param.marks if m.name == "xfail"]
        out[(str(name), int(seed))] = {
            "named": not xfail,
            "verdict": "fails: " + xfail[0].kwargs["reason"] if xfail else "named (test passes)",
            "source": str(TEST_FILE.relative_to(ROOT)),
        }
    return out


# ---------------------------------------------------------------------------- outputs


def figure(rows: Sequence[Mapping[str, Any]], path: Path) -> None:
    """Largest per-bin ``|z|`` against ``sqrt(lambda)``, named filled, not named open."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {e: plt.get_cmap("tab10")(i) for i, e in enumerate(RIG_EFFECTS)}
    fig, ax = plt.subplots(figsize=(7.5, 5.0))
    for row in rows:
        kind, named = row["kind"], row["verdict"]["named"]
        colour = colours[row["effect"]]
        ax.scatter(
            np.sqrt(row["lambda"]),
            row["z_max"],
            s=55,
            marker="o" if kind == TABLE else "s",
            facecolors=colour if named else "none",
            edgecolors=colour,
            linewidths=1.5,
        )
        ax.annotate(
            str(row["seed"]),
            (np.sqrt(row["lambda"]), row["z_max"]),
            xytext=(4, 3),
            textcoords="offset points",
            fontsize=7,
            color=colour,
        )
    bins = max(row["bins"] for row in rows)
    ax.axhline(bonferroni_z(bins), color="0.5", lw=0.8, ls=":")
    ax.annotate(
        f"one bin in {bins} at {LEVEL:g} (Bonferroni)",
        (ax.get_xlim()[1], bonferroni_z(bins)),
        xytext=(-4, -10),
        textcoords="offset points",
        ha="right",
        fontsize=7,
        color="0.4",
    )
    ax.set_xscale("log")
    ax.set_yscale("log")
    for axis, ticks in ((ax.xaxis, (5, 10, 20, 50, 100, 200)), (ax.yaxis, (2, 3, 5, 10, 20))):
        axis.set_major_locator(matplotlib.ticker.FixedLocator(ticks))
        axis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
        axis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel(r"$\sqrt{\lambda}$ = sqrt(sum of $z^2$ over runs, channels, 4-96 Hz bins)")
    ax.set_ylabel(r"largest $|z|$ in one run, channel and bin")
    ax.set_title("Hidden effects: strength against verdict (filled: named)", fontsize=10)
    handles = [
        plt.Line2D([], [], ls="", marker="o", color=c, label=e) for e, c in colours.items()
    ] + [
        plt.Line2D([], [], ls="", marker="o", mfc="none", color="k", label="6 runs (table)"),
        plt.Line2D([], [], ls="", marker="s", mfc="none", color="k", label="8 runs (tests)"),
    ]
    ax.legend(handles=handles, fontsize=7, loc="upper left")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _truth_text(effect: str, truth: Mapping[str, Any]) -> str:
    """The effect's size in the rig's terms."""
    if effect == "frame_mode":
        return f"{truth['frequency_hz']:.1f} Hz, lift {truth['rail_lift']:.3f}"
    if effect == "wheel_eccentricity":
        return f"{truth['wheel']}, a1 {1e6 * truth['amplitudes'][0]:.1f} um"
    if effect == "rail_waviness":
        return f"{1e3 * truth['wavelength_m']:.1f} mm, {1e6 * truth['amplitude_m']:.1f} um"
    if effect == "sensor_cross_axis":
        return f"{truth['sensor']} into {truth['into']}, {truth['fraction']:.3f}"
    return f"{truth['frequency_hz']:.0f} Hz, {1e3 * truth['amplitude']:.1f} mm/s^2"


def markdown(rows: Sequence[Mapping[str, Any]], command: str, wall: float, figure_name: str) -> str:
    """The text of ``results/diagnosis_strength.md`` (the discussion is written by hand)."""
    codes = sorted({str(r.get("code")) for r in rows if "error" not in r})
    lines = [
        "# How strong is each hidden effect?",
        "",
        f"Made by `{command}` ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
        f"{platform.node() or 'this machine'}, {os.cpu_count()} CPUs; {len(rows)} cases, "
        f"{wall / 60:.1f} min wall in the last call, which computed the cases not already "
        f"saved). The recordings were made by {' and '.join(codes) or 'no code'}.",
        "",
        "Each case is recorded twice by the virtual rig with the same key, with and without "
        "its effect: run by run the same parameter scatter, speed and noise, so the difference "
        "is the effect's. `z` is the change of each run's log10 Welch PSD (motion window, 1 Hz "
        "bins, 4-96 Hz: the spectra the diagnosis judges its refits on) in units of that "
        "run's Welch standard deviation. Columns: the largest `|z|` (channel, Hz); the largest "
        "`|z|` of the change averaged over the runs (its own standard deviation); "
        "`sqrt(lambda)`, `lambda` = the sum of `z^2` over runs, channels and bins; the number "
        f"of run-channel-bins with `|z| > {Z_MARK:g}`. Verdicts: the 6-run cases from "
        "`scripts/diagnosis.py`'s saved cases, the 8-run cases from the marks of "
        f"`tests/test_diagnose_job.py`. Figure: [{figure_name}]({figure_name}).",
        "",
        "| runs | effect | seed | effect size (rig truth) | largest z (where) | "
        "largest run-mean z (where) | sqrt(lambda) | bins over 3 | named | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    order = {TABLE: 0, TESTS: 1}
    for r in sorted(rows, key=lambda r: (order[r["kind"]], EFFECTS_INDEX[r["effect"]], r["seed"])):
        runs = "6" if r["kind"] == TABLE else "8"
        if "error" in r:
            lines.append(f"| {runs} | {r['effect']} | {r['seed']} | failed: {r['error'][:100]} |")
            continue
        at, mean_at = r["z_max_at"], r["z_mean_max_at"]
        v = r["verdict"]
        lines.append(
            f"| {runs} | {r['effect']} | {r['seed']} | {_truth_text(r['effect'], r['truth'])} | "
            f"{r['z_max']:.1f} ({at['channel']} {at['hz']:.0f}) | "
            f"{r['z_mean_max']:.1f} ({mean_at['channel']} {mean_at['hz']:.0f}) | "
            f"{np.sqrt(r['lambda']):.1f} | {r['bins_over_3']} of {r['bins']} | "
            f"{fmt({True: 'yes', False: 'no'}.get(v['named']), 's')} | {v['verdict'][:90]} |"
        )
    lines += ["", "## What the numbers show (written by the script)", ""]
    for kind in (TABLE, TESTS):
        mine = [r for r in rows if r["kind"] == kind and "error" not in r]
        if mine:
            lines += [f"{'6-run table' if kind == TABLE else '8-run test'} cases:", ""]
            lines += [f"- {text}" for text in separation(mine)]
            lines.append("")
    return "\n".join(lines)


#: the strength figures compared with the verdicts, and how each is named in the text
FIGURES = {
    "sqrt_lambda": "sqrt(lambda)",
    "z_max": "largest z",
    "z_mean_max": "largest run-mean z",
}


def _figure_value(row: Mapping[str, Any], name: str) -> float:
    return float(np.sqrt(row["lambda"])) if name == "sqrt_lambda" else float(row[name])


def separation(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """Per strength figure: the weakest named case, and the cases not named above it.

    Every case weaker than the weakest named one is, by construction, not named; the
    sentences count them and list the stronger cases that were not named either.
    """
    rows = [r for r in rows if r["verdict"]["named"] is not None]
    named = [r for r in rows if r["verdict"]["named"]]
    missed = [r for r in rows if not r["verdict"]["named"]]
    if not rows:
        return ["no verdicts for these cases (see --verdicts)"]
    if not named:
        return [f"nothing named in {len(rows)} cases; the strongest missed: {_strongest(missed)}"]
    bins = max(r["bins"] for r in rows)
    limit = bonferroni_z(bins)
    faint = [r for r in rows if r["z_max"] < limit]
    out = [
        f"{len(named)} of {len(rows)} named. One bin stands out of {bins} at {LEVEL:g} "
        f"(two-sided Bonferroni) from |z| = {limit:.2f}; {len(faint)} cases change no bin "
        f"that much ({', '.join(_label(r) for r in faint) or '-'}), "
        f"{sum(bool(r['verdict']['named']) for r in faint)} of them named."
    ]
    for name, label in FIGURES.items():
        floor = min(named, key=lambda r: _figure_value(r, name))
        low = _figure_value(floor, name)
        below = [r for r in missed if _figure_value(r, name) < low]
        above = sorted(
            (r for r in missed if _figure_value(r, name) >= low),
            key=lambda r: -_figure_value(r, name),
        )
        out.append(
            f"{label}: the weakest named case is {_label(floor)} at {low:.1f}; "
            f"{len(below)} cases lie below it (none named), {len(above)} not named lie above it"
            + (
                ": " + ", ".join(f"{_label(r)} {_figure_value(r, name):.1f}" for r in above)
                if above
                else ""
            )
            + "."
        )
    return out


def _label(row: Mapping[str, Any]) -> str:
    return f"{row['effect']} {row['seed']}"


def _strongest(rows: Sequence[Mapping[str, Any]]) -> str:
    if not rows:
        return "-"
    best = max(rows, key=lambda r: r["lambda"])
    return f"{_label(best)}, sqrt(lambda) {np.sqrt(best['lambda']):.1f}"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the table's seed 0 only")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="the table's seeds")
    parser.add_argument("--runs", type=int, default=6, help="runs per table case")
    parser.add_argument(
        "--no-tests", action="store_true", help="leave out the 8-run cases of the tests"
    )
    parser.add_argument(
        "--verdicts",
        type=Path,
        default=ROOT / "out" / "diagnosis",
        help="scripts/diagnosis.py's work folder of the table's (quick) cases",
    )
    parser.add_argument("--jobs", type=int, default=1, help="cases in parallel (processes)")
    parser.add_argument("--work", type=Path, default=ROOT / "out" / "diagnosis-strength")
    parser.add_argument("--results", type=Path, default=ROOT / "results" / "diagnosis_strength.md")
    args = parser.parse_args(argv)

    from bayesdoor.inference import FeatureSpec

    spec = FeatureSpec()
    seeds = [0] if args.quick else args.seeds
    table_settings = Settings(TABLE, args.runs, spec.f_low, spec.f_high)
    cases = [(e, s, table_settings) for s in seeds for e in RIG_EFFECTS]
    verdicts = {TABLE: table_verdicts(args.verdicts, args.runs)}
    if not (args.quick or args.no_tests):
        tested = test_verdicts()
        verdicts[TESTS] = tested
        test_settings = Settings(TESTS, 8, spec.f_low, spec.f_high)
        cases += [(e, s, test_settings) for e, s in tested]
    args.work.mkdir(parents=True, exist_ok=True)
    files = {(e, s, st.kind): _case_file(args.work, e, s, st) for e, s, st in cases}
    todo = {
        (e, s, st.kind): (e, s, st, str(files[e, s, st.kind]))
        for e, s, st in cases
        if not files[e, s, st.kind].is_file()
    }
    start = time.perf_counter()
    print(f"{len(cases)} cases, {len(cases) - len(todo)} already done", flush=True)

    def finished(case: tuple[str, int, str], row: dict[str, Any]) -> None:
        strength = row.get("lambda", 0.0) ** 0.5
        what = row.get("error") or f"z_max {row.get('z_max', 0.0):.1f}, sqrt(lambda) {strength:.1f}"
        print(f"[{time.perf_counter() - start:6.0f} s] {case}: {what}", flush=True)

    run_cases(_run_and_save, todo, args.jobs, finished)
    rows = []
    for (effect, seed, kind), path in files.items():
        row = json.loads(path.read_text())
        known = verdicts[kind].get((effect, seed))
        row["verdict"] = known or {"named": None, "verdict": "not diagnosed", "source": None}
        if known and known.get("speeds") is not None:
            if not np.allclose(known["speeds"], row["speeds"]):
                raise RuntimeError(
                    f"{effect} seed {seed}: the speeds differ from the diagnosed case's "
                    f"({known['source']}): not the same case; rerun scripts/diagnosis.py"
                )
        rows.append(row)
    figure_path = args.results.with_suffix(".png")
    figure([r for r in rows if "error" not in r], figure_path)
    command = command_line("diagnosis_strength.py", argv)
    write_results(
        args.results, markdown(rows, command, time.perf_counter() - start, figure_path.name)
    )


if __name__ == "__main__":
    main()
