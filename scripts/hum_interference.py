"""The mains hum's effect on each run's spectrum, rig against model -> results/hum_interference.md.

The hum's line adds to whatever the door itself puts into the same bins. Where the door has
no coherent content there, the two powers add; where it has a tone of comparable level, the
line interferes with it and the change in the log spectrum depends on their relative phase.
The rig draws the hum's phase at random per run; the catalogue's extension puts its line in
quadrature with the model's signal over the record (its power adds, the expectation over the
phase).

1. For each rig key (``--first-seed`` on, the keys of ``scripts/diagnosis_limits.py``'s
   loops), the 12-speed campaign is recorded twice, with the hum (50 Hz, ``--size`` m/s^2, its
   phases random per run) and without it: the difference of the measured log10 spectra is the
   rig's hum effect, the same noise in both.
2. On the nothing-hidden campaign (key ``--base-key``) and its base fit, read from ``--work``
   (made by ``scripts/diagnosis_limits.py``), the base model's signals get the same line at 8
   phases: the model's hum effect at each phase; and the catalogue's extension at that size
   on the X channels: the effect the refit's model gives.
3. Per run, the mean effect over the X channels in the line's bins (49-51 Hz); beside each
   key, the held-out log-density difference of the run that decides the loops' misses, from
   the loops' files in ``--work`` where they are there.

Usage::

    .venv/bin/python scripts/hum_interference.py [--seeds 10] [--first-seed 5000]
        [--size M_PER_S2] [--run 3] [--work out/diagnosis-limits]

``--size`` defaults to the size of the loops at 1.5 x the hum's limit in ``--work``.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
from _cases import ROOT, code_version, command_line, setup_jax, write_results
from diagnosis_limits import _no_effects, record, rig_effect

X_CHANNELS = (0, 2)
LINE_HZ = 50.0


def spectra(campaign):
    """The measured log10 spectra of a campaign and their bins, as the diagnosis reads them."""
    from bayesdoor.diagnose._measured import Measured
    from bayesdoor.diagnose._refit import Spectra
    from bayesdoor.door import ElevatorDoor
    from bayesdoor.inference import calibration_runs

    m = Measured.of(ElevatorDoor(), campaign, calibration_runs(campaign))
    s = Spectra.of_measured(m.signals, m.fs, m.t_start, m.t_stop, (1.0, 200.0), nperseg=int(m.fs))
    return s.freqs, s.measured


def line_mean(effect: np.ndarray, freqs: np.ndarray) -> np.ndarray:
    """Each run's mean effect over the X channels in the line's bins."""
    b = np.flatnonzero(np.abs(freqs - LINE_HZ) <= 1.0)
    return effect[:, X_CHANNELS][..., b].mean(axis=(-2, -1))


def model_effects(
    work: Path, base_key: int, size: float, phases: int = 8
) -> tuple[np.ndarray, np.ndarray]:
    """The base model's hum effect per run (rows) at ``phases`` phases of the line, and the
    catalogue extension's (its line in quadrature with each channel's signal)."""
    import xarray as xr

    from bayesdoor.diagnose._measured import Measured, _band, _simulate_rows
    from bayesdoor.door import ElevatorDoor
    from bayesdoor.inference import FitResult, calibration_runs

    door = ElevatorDoor()
    fit = FitResult.load(work / f"base-{base_key}" / "fit")
    campaign = xr.load_dataset(work / f"base-{base_key}" / "campaign.nc")
    measured = Measured.of(door, campaign, calibration_runs(campaign))
    sims, _, times = _simulate_rows(door, measured, [dict(fit.point)])
    setup = measured.setup(door, fit.point, sims[0], times, _band(fit), None)
    z = np.asarray(setup.base_signals)
    t = np.asarray(setup.time)[: z.shape[-1]]
    runs = np.arange(z.shape[0])
    p0 = setup.spectra.model(z, runs)
    out = np.empty((z.shape[0], phases))
    for k, phi in enumerate(np.linspace(0.0, 2.0 * np.pi, phases, endpoint=False)):
        line = size * np.cos(2.0 * np.pi * LINE_HZ * t + phi)
        p = setup.spectra.model(z + line[None, None, :], runs)
        out[:, k] = line_mean(p - p0, setup.spectra.freqs)
    hum = ElevatorDoor().with_extensions("mains_hum")
    values = {**hum.nominal(), "mains_hum.amplitude_A1X": size, "mains_hum.amplitude_A2X": size}
    extended = np.asarray(hum.apply_output_extensions(z, t, values))
    ext = line_mean(setup.spectra.model(extended, runs) - p0, setup.spectra.freqs)
    return out, ext


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=5000)
    parser.add_argument("--base-key", type=int, default=4999)
    # default: the size of the loops at 1.5 x the hum's limit in the work folder
    parser.add_argument("--size", type=float, default=None)
    parser.add_argument("--run", type=int, default=3)
    parser.add_argument("--work", type=Path, default=ROOT / "out" / "diagnosis-limits")
    parser.add_argument("--results", type=Path, default=ROOT / "results" / "hum_interference.md")
    args = parser.parse_args(argv)
    if args.size is None:
        loops = sorted(args.work.glob("mains_hum-1.5-*.json"))
        if not loops:
            parser.error(f"no mains_hum loops at 1.5 x in {args.work}: pass --size")
        args.size = float(json.loads(loops[0].read_text())["size"])
    setup_jax()
    started = time.time()
    from diagnosis_limits import SPEEDS

    model, extension = model_effects(args.work, args.base_key, args.size)
    rig = {}
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        freqs, with_hum = spectra(record(rig_effect("mains_hum", args.size, seed), seed))
        _, without = spectra(record(_no_effects(), seed))
        rig[seed] = line_mean(with_hum - without, freqs)
        print(seed, np.round(rig[seed], 2), flush=True)
    effects = np.array(list(rig.values()))
    lines = [
        "# The mains hum's effect on each run's spectrum: rig against model",
        "",
        f"Made by `{command_line('hum_interference.py', None)}` "
        f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {platform.node()}, "
        f"{code_version()}; {time.time() - started:.0f} s).",
        "",
        f"The change a 50 Hz line of {args.size * 1e3:.3g} mm/s^2 makes to each run's log10 "
        "spectrum, mean over A1X and A2X at 49-51 Hz (decades): on the rig, the same key "
        f"recorded with and without it (keys {args.first_seed}-"
        f"{args.first_seed + args.seeds - 1}, the rig's phase random per run); in the base "
        f"model at the nothing-hidden campaign's fit (key {args.base_key}), the line at 8 "
        "phases, and the catalogue's extension (its line in quadrature with the signal):",
        "",
        "| run | speed m/s | rig: min .. max over keys | model: min .. max over phases | "
        "the extension |",
        "|---|---|---|---|---|",
    ]
    for r, v in enumerate(SPEEDS):
        lines.append(
            f"| {r} | {v:.3f} | {effects[:, r].min():+.2f} .. {effects[:, r].max():+.2f} | "
            f"{model[r].min():+.2f} .. {model[r].max():+.2f} | {extension[r]:+.2f} |"
        )
    lines += [
        "",
        f"Run {args.run} per key, beside its held-out log-density difference in the loops at "
        f"this size (`scripts/diagnosis_limits.py`, files in the work folder):",
        "",
        f"| key | rig's effect on run {args.run} | run {args.run}'s held-out difference "
        "(nats) | named |",
        "|---|---|---|---|",
    ]
    for seed, e in rig.items():
        found = list(args.work.glob(f"mains_hum-*-{args.size:.4g}-{seed}.json"))
        diff, named = "-", "-"
        if found:
            row = json.loads(found[0].read_text())
            diff = f"{row['per_run'][row['runs'].index(args.run)]:+.1f}"
            named = "yes" if row["named"] else "no"
        lines.append(f"| {seed} | {e[args.run]:+.2f} | {diff} | {named} |")
    write_results(args.results, "\n".join([*lines, ""]))


if __name__ == "__main__":
    main()
