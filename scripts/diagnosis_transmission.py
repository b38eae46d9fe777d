"""How the door family transmits each catalogue cause against the model: the family limits.

A model limit (``bayesdoor.diagnose.detection_limits``) is the size named with 80 %
probability *if the model transmits the cause to the sensors as the machine does*. On each
door of the transfer benchmark's family (``bayesdoor.door.rig.OtherDoor.from_seed``, varied
in ways the model lacks):

1. the door's nothing-hidden base campaign (12 healthy runs at 0.30-0.50 m/s, key
   ``BASE_KEY`` + door), the base model fitted on it and its model limits: the same as
   ``scripts/diagnosis_family.py`` (shared work folder, reused when there);
2. per validated cause, the same campaign recorded again with the same key (the same noise)
   and the cause hidden at ``--factor`` times the door's model limit in its typical
   configuration, on top of what the door carries;
3. ``bayesdoor.diagnose.read_transmission``: the model size whose change of the spectra best
   reproduces the door's change (ratio to the size hidden) and the share of the door's change
   it explains.

Per cause, over the development doors (seeds below ``--held-out-from``): the smallest and
largest ratio and the smallest share explained, which the door's catalogue declares
(``bayesdoor.door._catalogue.FAMILY_TRANSMISSION``; the family limit is the model limit over
the smallest ratio). On the held-out doors: how many read a ratio at or above the
development doors' smallest (the family limit holds for them), and their shares explained.

Usage::

    .venv/bin/python scripts/diagnosis_transmission.py [--doors 0 1 2 3 4 5 12 13 14 15]
        [--held-out-from 12] [--factor 3] [--work out/diagnosis-family]
        [--results results/diagnosis_transmission.md]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
from _cases import ROOT, code_version, command_line, setup_jax, write_results
from diagnosis_family import BASE_KEY, base, other_door, record, with_hidden
from diagnosis_limits import VALIDATED


def machine_setup(door: Any, fit: Any):
    """The base setup of a door's nothing-hidden campaign under its base fit."""
    from bayesdoor.diagnose._measured import _band, base_setup, measure
    from bayesdoor.door import ElevatorDoor

    model = ElevatorDoor()
    measured = measure(model, record(door, BASE_KEY + door.seed))
    return base_setup(model, measured, fit, _band(fit))


def machine_spectra(setup: Any, door: Any) -> np.ndarray:
    """The log10 spectra of ``door``'s base campaign recorded again (same key), analysed as
    ``setup``'s measured runs."""
    from bayesdoor.diagnose._measured import measure
    from bayesdoor.door import ElevatorDoor

    measured = measure(ElevatorDoor(), record(door, BASE_KEY + door.seed))
    return setup.spectra.model(measured.signals, np.arange(len(setup.operating)))


def read_door(work: Path, seed: int, factor: float) -> dict[str, Any]:
    """Every validated cause's transmission on one door (JSON-ready; cached in ``work``)."""
    from bayesdoor.diagnose import read_transmission
    from bayesdoor.diagnose._limits import _declared_sizes
    from bayesdoor.door import DOOR_CATALOGUE

    path = work / f"door-{seed}" / f"transmission-{factor:g}.json"
    if path.is_file():
        return json.loads(path.read_text())
    fit, limits = base(work, seed)
    t0 = time.perf_counter()
    door = other_door(seed)
    setup = machine_setup(door, fit)
    again = machine_spectra(setup, door)
    repeat = float(np.max(np.abs(again - setup.spectra.measured)))
    declared = _declared_sizes(setup, DOOR_CATALOGUE, VALIDATED, None)
    out: dict[str, Any] = {"door": seed, "repeat_max_log10": repeat, "causes": {}}
    for cause in VALIDATED:
        limit = limits["limits"][cause]["size"]
        if limit is None or cause not in declared:
            continue
        size = factor * limit
        try:
            hidden = with_hidden(door, cause, size, seed)
        except ValueError as err:  # beyond what the rig can hide
            out.setdefault("skipped", {})[cause] = str(err)
            print(f"door {seed} {cause}: skipped, {err}", flush=True)
            continue
        machine = machine_spectra(setup, hidden)
        r = read_transmission(
            setup, declared[cause].probes[0], machine, size, high=declared[cause].high
        )
        out["causes"][cause] = {
            "limit": limit,
            "size": size,
            "model_size": r.model_size,
            "ratio": r.ratio,
            "explained": r.explained,
            "bins": r.bins,
        }
        print(f"door {seed} {cause}: ratio {r.ratio:.3g}, explained {r.explained:.2f}", flush=True)
    out["wall_s"] = time.perf_counter() - t0
    path.write_text(json.dumps(out, indent=1))
    return out


def summary(doors: list[dict[str, Any]], development: list[int]) -> dict[str, Any]:
    """Per cause, over the development doors: ratio range, smallest share explained; over
    the others: how many hold the family limit (ratio at or above the development's
    smallest) and their smallest share explained."""
    out = {}
    for cause in VALIDATED:
        dev = [
            d["causes"][cause] for d in doors if d["door"] in development and cause in d["causes"]
        ]
        rest = [
            d["causes"][cause]
            for d in doors
            if d["door"] not in development and cause in d["causes"]
        ]
        if not dev:
            continue
        low = min(c["ratio"] for c in dev)
        out[cause] = {
            "low": low,
            "high": max(c["ratio"] for c in dev),
            "explained": min(c["explained"] for c in dev),
            "machines": len(dev),
            "held_out": len(rest),
            "held_out_covered": sum(c["ratio"] >= low for c in rest),
            "held_out_explained": min((c["explained"] for c in rest), default=None),
        }
    return out


def markdown(args: Any, doors: list[dict[str, Any]], table: dict[str, Any], wall: float) -> str:
    from bayesdoor.diagnose import Transmission

    dev = [d for d in args.doors if d < args.held_out_from]
    lines = [
        "# How the door family transmits each cause: the family limits",
        "",
        f"Made by `{command_line('diagnosis_transmission.py', None)}` "
        f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {platform.node()}, "
        f"{code_version()}; {wall:.0f} s in this call).",
        "",
        "On each door of the family, the base model is fitted on the door's nothing-hidden "
        "campaign (12 runs at 0.30-0.50 m/s; as `scripts/diagnosis_family.py`), then the same "
        "campaign is recorded again with the same noise and one cause hidden at "
        f"{args.factor:g} times the door's model limit, on top of what the door carries. "
        "`read_transmission` finds the model size whose change of the spectra best "
        "reproduces the door's (ratio: that size over the size hidden; below 1 the door shows "
        "less of the cause than the model) and the share of the door's change it explains. "
        "A door that shows a cause of size s as the model shows r s needs s = L / r to be "
        "named where the model limit is L; over the development doors the family limit is "
        "L / (smallest ratio), declared when every development door's change is at least "
        "half explained.",
        "",
        "## Per door",
        "",
        "| door | group | " + " | ".join(VALIDATED) + " | s |",
        "|---|---|" + "---|" * len(VALIDATED) + "---|",
    ]
    for d in doors:
        group = "development" if d["door"] in dev else "held-out"
        cells = []
        for cause in VALIDATED:
            c = d["causes"].get(cause)
            if c is None:
                c_skip = d.get("skipped", {}).get(cause)
                cells.append("beyond the rig" if c_skip else "-")
            else:
                cells.append(f"{c['ratio']:.2f} ({c['explained']:.2f})")
        lines.append(f"| {d['door']} | {group} | " + " | ".join(cells) + f" | {d['wall_s']:.0f} |")
    lines += [
        "",
        "Each cell: ratio (share of the door's change explained); beyond the rig: the size "
        "to hide lies outside what the rig's effect allows.",
        "",
        "## Per cause: what the catalogue declares, and the held-out doors",
        "",
        "| cause | development doors | ratio | smallest share explained | family limit / model "
        "limit | held-out doors at or above the smallest ratio | held-out: smallest share |",
        "|---|---|---|---|---|---|---|",
    ]
    for cause, t in table.items():
        declared = Transmission(t["low"], t["high"], t["explained"], t["machines"])
        factor = f"{1 / t['low']:.2f}" if declared.reliable else "not reproduced"
        held = "-" if t["held_out_explained"] is None else f"{t['held_out_explained']:.2f}"
        lines.append(
            f"| {cause} | {t['machines']} | {t['low']:.2f}-{t['high']:.2f} | "
            f"{t['explained']:.2f} | {factor} | {t['held_out_covered']} of {t['held_out']} | "
            f"{held} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--doors", type=int, nargs="+", default=[0, 1, 2, 3, 4, 5, 12, 13, 14, 15])
    parser.add_argument("--held-out-from", type=int, default=12)
    parser.add_argument("--factor", type=float, default=3.0)
    parser.add_argument("--work", type=Path, default=ROOT / "out" / "diagnosis-family")
    parser.add_argument(
        "--results", type=Path, default=ROOT / "results" / "diagnosis_transmission.md"
    )
    args = parser.parse_args(argv)
    setup_jax()
    args.work.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    doors = [read_door(args.work, seed, args.factor) for seed in args.doors]
    table = summary(doors, [d for d in args.doors if d < args.held_out_from])
    wall = time.perf_counter() - t0
    args.results.with_suffix(".json").write_text(
        json.dumps({"doors": doors, "causes": table, "factor": args.factor}, indent=1) + "\n"
    )
    write_results(args.results, markdown(args, doors, table, wall))
    print(args.results.read_text())


if __name__ == "__main__":
    main()
