"""The order spectra's segment length from the error rate of the located wavelength.

The door's diagnosis locates a tracking tone's wavelength in the order spectra (runs
resampled against travelled distance, Welch with segments of ``order_segment_m`` metres:
``bayesdoor.diagnose._order``). This Monte Carlo measures, for each candidate segment, how
often the located wavelength misses the truth by more than the tolerances the catalogue
relies on, on synthetic campaigns built the way the diagnosis sees them:

- each campaign has 6-12 runs (uniform), each at a peak speed drawn uniformly from
  0.25-0.50 m/s in steps of 0.01 m/s, with the door's own speed profile
  (``DOOR_CATALOGUE.speed_profile``), sampled at the door's rate, ``CHANNELS`` channels;
- the measured runs are white noise (unit variance, independent per channel and run) plus a
  rail tone ``a (v(t) / v_peak)^2 sin(2 pi z(t) / lambda + phase)`` in every channel (an
  acceleration from a spatial period grows as the speed squared), ``lambda`` log-uniform over
  the rig's 8-80 mm (``rig.RailWaviness.from_seed``), ``z`` the travelled distance;
- the predictive draws are ``DRAWS`` noise-only records of the same runs;
- the tone's strength is its SNR per cycle per metre at cruise: the tone's power ``a^2 / 2``
  over the noise's one-sided PSD against distance, ``2 v_peak / fs`` per cycle per metre,
  times 1 cycle per metre (``a`` set per run so that every run has the stated SNR). In the bin
  of Hann segments of ``L`` metres (noise bandwidth ``1.5 / L``) the tone stands ``L / 1.5``
  times that over the noise.

The diagnosis sees the tone only when the residual map finds it, so each campaign goes
through the library's own path: ``find_features`` (the residual map over ``BAND``, no
within-run test, no order spectra), then, for each segment, the order spectra of the measured
runs and of the draws (``order_log_psd``) and the catalogue's rail signature
(``SpeedTracking.match``), whose ``wavelength_m`` is the located wavelength (from the order
spectra, or the speed fit's where they show no peak). A campaign counts as detected when the
signature matches a region whose frequency follows the speed. The wheel comb
(``harmonic_comb`` with the catalogue's ``HarmonicComb`` settings) is measured on other
campaigns with the wheel's harmonics 4 and 6 at the same SNR each.

Usage::

    .venv/bin/python scripts/order_segment.py [--campaigns 200] [--comb-campaigns 100]
        [--seed 0] [--results results/order_segment.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from _cases import ROOT, code_version, command_line, write_results

#: candidate segments, m (the shortest stroke resampled, at 0.5 m/s, is 0.79 m)
SEGMENTS_M = (0.2, 0.25, 0.3, 0.4, 0.5, 0.6, 0.7)
#: the tone's SNR per cycle per metre at cruise, dB
SNRS_DB = (9.0, 11.0, 13.0, 16.0)
#: SNRs of the comb's campaigns, dB (each harmonic)
COMB_SNRS_DB = (3.0, 6.0, 10.0)
#: the wheel harmonics injected into the comb's campaigns (those the rig's wheel shows)
COMB_HARMONICS = (4, 6)
#: runs per campaign (uniform, inclusive)
RUNS = (6, 12)
#: peak speeds drawn from, m/s
SPEEDS = np.round(np.arange(0.25, 0.5001, 0.01), 2)
#: the rig's rail wavelengths (log-uniform), m
WAVELENGTHS_M = (8e-3, 80e-3)
#: channels per run (independent noise, the same tone)
CHANNELS = ("X", "Z")
#: predictive draws per campaign
DRAWS = 4
#: analysed band of the residual map, Hz (the tones lie at 3-63 Hz)
BAND = (2.0, 200.0)
#: the error rate the segment is derived from: the located wavelength outside the tolerance in
#: at most this share of the detected campaigns at the detection limit
RATE = 0.05
#: the detection limit: the lowest SNR of the grid at which at least this share is detected
DETECTED = 0.5
#: the rail refit's tolerance on the held wavelength: cycles of drift over the stroke
QUARTER = 0.25


@dataclasses.dataclass
class Cell:
    """The located wavelengths of one SNR and segment (NaN where not detected)."""

    errors: list[float] = dataclasses.field(default_factory=list)
    cycles: list[float] = dataclasses.field(default_factory=list)
    from_orders: list[bool] = dataclasses.field(default_factory=list)


def _profiles(fs: float) -> tuple[np.ndarray, dict[float, np.ndarray]]:
    """The time grid (long enough for the slowest stroke) and each speed's profile."""
    from bayesdoor.door import DOOR_CATALOGUE
    from bayesdoor.door._profile import record_duration

    t = np.arange(round(record_duration(SPEEDS.min()) * fs)) / fs
    speed_profile = DOOR_CATALOGUE.speed_profile
    assert speed_profile is not None
    table = speed_profile(SPEEDS, t)
    return t, {float(v): row for v, row in zip(SPEEDS, table, strict=True)}


def _tone(v: np.ndarray, peaks: np.ndarray, z: np.ndarray, kappa: float, snr_db: float, fs, rng):
    """A tone of ``kappa`` cycles per metre at the stated SNR per cycle per metre at cruise."""
    a = np.sqrt(4.0 * 10 ** (snr_db / 10) * peaks / fs)
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(peaks.size, 1))
    return a[:, None] * (v / peaks[:, None]) ** 2 * np.sin(2.0 * np.pi * kappa * z + phase)


def simulate(campaigns: int, comb_campaigns: int, seed: int):
    """Run the Monte Carlo; return the rail cells, detection counts and comb tallies."""
    from bayesdoor.diagnose import FeatureSettings, RunMotion, find_features
    from bayesdoor.diagnose._comb import harmonic_comb
    from bayesdoor.diagnose._order import order_log_psd, travelled_distance
    from bayesdoor.door import DOOR_CATALOGUE, WHEEL_CIRCUMFERENCE
    from bayesdoor.door import _geometry as g
    from bayesdoor.door._profile import motion_duration

    fs = g.SAMPLING_RATE_HZ
    t, profiles = _profiles(fs)
    by_name = {c.name: c for c in DOOR_CATALOGUE.candidates}
    rail = by_name["rail_waviness"].signature
    comb_signature = by_name["wheel_eccentricity"].signature.signatures[0]
    rng = np.random.default_rng(seed)
    cells = {(s, L): Cell() for s in SNRS_DB for L in SEGMENTS_M}
    detected = dict.fromkeys(SNRS_DB, 0)
    comb = {(s, L): np.zeros(3, dtype=int) for s in COMB_SNRS_DB for L in SEGMENTS_M}

    def campaign():
        n = int(rng.integers(RUNS[0], RUNS[1] + 1))
        peaks = rng.choice(SPEEDS, size=n)
        v = np.stack([profiles[float(p)] for p in peaks])
        t0 = np.full(n, g.REST_S)
        t1 = g.REST_S + motion_duration(peaks)
        noise = rng.standard_normal((DRAWS + 1, n, len(CHANNELS), t.size))
        orders_kw = {"t_start": t0, "t_stop": t1}
        predictive = {
            L: tuple(order_log_psd(s, fs, v, segment_m=L, **orders_kw) for s in noise[1:])
            for L in SEGMENTS_M
        }
        return peaks, v, t0, t1, noise, predictive, orders_kw

    for _ in range(campaigns):
        peaks, v, t0, t1, noise, predictive, orders_kw = campaign()
        z = travelled_distance(v, fs)
        lam = float(np.exp(rng.uniform(*np.log(WAVELENGTHS_M))))
        for snr in SNRS_DB:
            x = noise[0] + _tone(v, peaks, z, 1.0 / lam, snr, fs, rng)[:, None, :]
            features = find_features(
                x,
                noise[1:],
                fs,
                channels=CHANNELS,
                motion=RunMotion(t0, t1, peaks, v),
                settings=FeatureSettings(within_run=False, band=BAND),
            )
            match = rail.match(features)
            seen = match is not None and bool(match.checks[0].passed)
            detected[snr] += seen
            for L in SEGMENTS_M:
                cell = cells[(snr, L)]
                if not seen:
                    continue
                with_orders = dataclasses.replace(
                    features,
                    orders=order_log_psd(x, fs, v, segment_m=L, **orders_kw),
                    orders_predictive=predictive[L],
                )
                found = rail.match(with_orders)
                assert found is not None
                located = float(found.parameters["period"])
                cell.errors.append(located / lam - 1.0)
                cell.cycles.append(abs(1.0 / located - 1.0 / lam) * g.STROKE)
                cell.from_orders.append(found.parameters["period_source"] == "order tracking")

    for _ in range(comb_campaigns):
        peaks, v, t0, t1, noise, predictive, orders_kw = campaign()
        z = travelled_distance(v, fs)
        for snr in COMB_SNRS_DB:
            tones = sum(
                _tone(v, peaks, z, k / WHEEL_CIRCUMFERENCE, snr, fs, rng) for k in COMB_HARMONICS
            )
            x = noise[0] + tones[:, None, :]
            for L in SEGMENTS_M:
                test = harmonic_comb(
                    order_log_psd(x, fs, v, segment_m=L, **orders_kw),
                    predictive[L],
                    comb_signature.period_m,
                    comb_signature.harmonics,
                    alpha=comb_signature.alpha,
                    min_harmonics=comb_signature.min_harmonics,
                )
                wanted = [comb_signature.harmonics.index(k) for k in COMB_HARMONICS]
                strong = test.z[wanted] > test.threshold
                comb[(snr, L)] += [
                    int(test.significant and set(COMB_HARMONICS) <= set(test.found)),
                    int(strong.sum()),
                    int((strong & ~test.on_comb[wanted]).sum()),
                ]
    return cells, detected, comb


def _se(p: float, n: int) -> float:
    return float(np.sqrt(max(p * (1 - p), 1.0 / n) / n)) if n else float("nan")


def derive(cells, detected, comb, campaigns: int, comb_campaigns: int, tolerance: float):
    """The detection limits, each segment's rates there, the admissible segments, the derived one.

    The rule: at the rail's detection limit (the lowest SNR of the grid where at least
    ``DETECTED`` of the campaigns are detected) a segment's located wavelength may lie beyond
    the quarter cycle, and beyond ``tolerance``, in at most ``RATE`` of the detected campaigns;
    at the comb's detection limit (the lowest comb SNR where the best segment finds the comb in
    at least ``DETECTED`` of the campaigns) it must find the comb within one binomial standard
    error of the best segment's rate (the same segment serves both signatures). The derived
    segment is the shortest admissible one (the most segments averaged per run, the widest
    margin to the stroke). ``None`` where a limit or an admissible segment is missing.
    """
    rail_limit = next((s for s in SNRS_DB if detected[s] >= DETECTED * campaigns), None)
    comb_limit = next(
        (
            s
            for s in COMB_SNRS_DB
            if max(comb[(s, L)][0] for L in SEGMENTS_M) >= DETECTED * comb_campaigns
        ),
        None,
    )
    rail, found = {}, {}
    for L in SEGMENTS_M:
        if rail_limit is not None:
            c = cells[(rail_limit, L)]
            e = np.abs(c.errors)
            rail[L] = (
                float(np.mean(np.asarray(c.cycles) > QUARTER)),
                float(np.mean(e > tolerance)),
            )
        if comb_limit is not None:
            found[L] = comb[(comb_limit, L)][0] / comb_campaigns
    if not rail or not found:
        return rail_limit, comb_limit, rail, found, [], None
    best = max(found.values())
    floor = best - _se(best, comb_campaigns)
    admissible = [
        L for L in SEGMENTS_M if rail[L][0] <= RATE and rail[L][1] <= RATE and found[L] >= floor
    ]
    return rail_limit, comb_limit, rail, found, admissible, min(admissible, default=None)


def report(command: str, cells, detected, comb, args, seconds: float) -> str:
    from bayesdoor.door import DOOR_CATALOGUE
    from bayesdoor.door import _geometry as g
    from bayesdoor.door._catalogue import _WHEEL_MATCH

    rail_limit, comb_limit, rail, found, admissible, chosen = derive(
        cells, detected, comb, args.campaigns, args.comb_campaigns, _WHEEL_MATCH
    )
    when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    out = [
        "# The order spectra's segment length",
        "",
        f"Made by `{command}` ({when}; {code_version()}; {seconds:.0f} s).",
        "",
        f"{args.campaigns} rail campaigns (each at every SNR) and {args.comb_campaigns} comb "
        f"campaigns, seed {args.seed}. Each campaign: {RUNS[0]}-{RUNS[1]} runs at peak speeds "
        f"drawn from {SPEEDS.min():.2f}-{SPEEDS.max():.2f} m/s with the door's speed profile, "
        f"{g.SAMPLING_RATE_HZ:g} Hz, {len(CHANNELS)} channels of unit white noise, {DRAWS} "
        "noise-only predictive draws; a rail tone of wavelength log-uniform in "
        f"{1e3 * WAVELENGTHS_M[0]:g}-{1e3 * WAVELENGTHS_M[1]:g} mm whose amplitude grows as the "
        "speed squared. SNR: the tone's power over the noise's per cycle per metre at cruise "
        "(in the bin of Hann segments of L metres the tone stands L / 1.5 times higher). The "
        "located wavelength is the catalogue's rail signature's `wavelength_m` on the features of "
        f"the library's residual map (band {BAND[0]:g}-{BAND[1]:g} Hz) with the order spectra of "
        "each segment; a campaign is detected when that signature matches a region whose "
        "frequency follows the speed. The generator and the definitions: the docstring of "
        "`scripts/order_segment.py`.",
        "",
        "Tolerances: **4 %** (`_WHEEL_MATCH`, `bayesdoor/door/_catalogue.py`): a located "
        "wavelength within 4 % of a wheel harmonic is that harmonic for the signatures "
        "(`SpeedTracking.rel_tol`) and for the rail refit's alternatives; the rail refit holds the "
        "wavelength at the located value (no search box). **Quarter cycle**: the held wavelength "
        f"drifts from the true one by |1/lambda_hat - 1/lambda| x {g.STROKE:g} m cycles over the "
        f"stroke; at a quarter cycle the held tone's correlation with the true one over the "
        f"stroke falls to sinc(0.25) = 0.90 (relative: lambda / {g.STROKE / QUARTER:g} m, "
        "0.25 % at 8 mm, 2.5 % at 80 mm).",
        "",
        "## Detection",
        "",
        "| SNR per cycle/m (dB) | detected |",
        "|---|---|",
        *(
            f"| {s:+g} | {detected[s]} of {args.campaigns} "
            f"({100 * detected[s] / args.campaigns:.0f} %) |"
            for s in SNRS_DB
        ),
        "",
        "## Located wavelength, detected campaigns",
        "",
        "Per SNR and segment: the detected campaigns n; the median and 95th percentile of "
        "|relative error|; the share beyond 4 % and beyond the quarter cycle (each with its "
        "binomial standard error); the share located from the order spectra (the rest fell back "
        "to the speed fit).",
        "",
        "| SNR (dB) | segment (m) | n | median | 95th pct. | > 4 % | > quarter cycle | "
        "from orders |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for s in SNRS_DB:
        for L in SEGMENTS_M:
            c = cells[(s, L)]
            n = len(c.errors)
            if not n:
                out.append(f"| {s:+g} | {L:g} | 0 | | | | | |")
                continue
            e = np.abs(c.errors)
            p4 = float(np.mean(e > _WHEEL_MATCH))
            pq = float(np.mean(np.asarray(c.cycles) > QUARTER))
            out.append(
                f"| {s:+g} | {L:g} | {n} | {100 * np.median(e):.2f} % | "
                f"{100 * np.quantile(e, 0.95):.2f} % | {p4:.3f} +- {_se(p4, n):.3f} | "
                f"{pq:.3f} +- {_se(pq, n):.3f} | {np.mean(c.from_orders):.2f} |"
            )
    out += [
        "",
        f"## The wheel comb (harmonics {' and '.join(map(str, COMB_HARMONICS))}, each at the SNR)",
        "",
        "Share of campaigns whose comb is significant with both harmonics present; of the "
        "injected harmonics above the comb's z threshold, the share whose peak lies off the comb "
        "(more than `PEAK_TOLERANCE_BINS` of a resolution bin, 1 / segment, away).",
        "",
        "| SNR (dB) | segment (m) | comb found | off the comb |",
        "|---|---|---|---|",
    ]
    for s in COMB_SNRS_DB:
        for L in SEGMENTS_M:
            hits, strong, off = comb[(s, L)]
            p = hits / args.comb_campaigns
            share = f"{off / strong:.3f} of {strong}" if strong else "-"
            out.append(
                f"| {s:+g} | {L:g} | {p:.2f} +- {_se(p, args.comb_campaigns):.2f} | {share} |"
            )
    out += ["", "## The segment", ""]
    current = DOOR_CATALOGUE.order_segment_m
    if rail_limit is None or comb_limit is None:
        out.append(
            f"No SNR of a grid reaches {100 * DETECTED:.0f} % detected (rail) or found (comb): "
            "no derivation."
        )
    else:
        rows = "; ".join(
            f"{L:g} m: {rail[L][0]:.3f} beyond the quarter cycle, {rail[L][1]:.3f} beyond 4 %, "
            f"comb {found[L]:.2f}"
            for L in SEGMENTS_M
        )
        out.append(
            f"The rule (`derive` in the script): at the rail's detection limit, the lowest SNR of "
            f"the grid at which at least {100 * DETECTED:.0f} % of the campaigns are detected "
            f"({rail_limit:+g} dB per cycle/m, {detected[rail_limit]} of {args.campaigns}), a "
            f"segment's located wavelength may lie beyond the quarter cycle, and beyond 4 %, in "
            f"at most {100 * RATE:.0f} % of the detected campaigns; at the comb's detection limit "
            f"(the lowest comb SNR at which the best segment finds it in {100 * DETECTED:.0f} % "
            f"of the campaigns: {comb_limit:+g} dB) it must find the comb within one binomial "
            "standard error of the best segment's rate (one segment serves both signatures). The "
            "derived segment is the shortest admissible one (the most segments averaged per run, "
            f"the widest margin to the stroke). There: {rows}. Admissible: "
            + (", ".join(f"{L:g} m" for L in admissible) or "none")
            + ". "
            + (
                f"Derived: **{chosen:g} m** (the catalogue's `order_segment_m`: {current:g} m)."
                if chosen is not None
                else "No segment meets the rule."
            )
        )
    out.append("")
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--campaigns", type=int, default=200, help="rail campaigns")
    parser.add_argument("--comb-campaigns", type=int, default=100, help="wheel-comb campaigns")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--results", type=Path, default=ROOT / "results" / "order_segment.md")
    args = parser.parse_args(argv)
    if args.campaigns < 1 or args.comb_campaigns < 0:
        parser.error("--campaigns must be at least 1 and --comb-campaigns at least 0")
    start = time.perf_counter()
    cells, detected, comb = simulate(args.campaigns, args.comb_campaigns, args.seed)
    text = report(
        command_line("order_segment.py", argv),
        cells,
        detected,
        comb,
        args,
        time.perf_counter() - start,
    )
    write_results(args.results, text)


if __name__ == "__main__":
    main()
