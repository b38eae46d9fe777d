"""``bayesdoor inspect``: validate a campaign, summarise it and plot its PSDs per state."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from ._common import fail

#: problems that leave no usable time axis or sampling rate: no PSD can be computed
_BLOCKS_PSD = {
    "no_acceleration",
    "missing_sampling_rate",
    "sampling_rate_mismatch",
    "missing_time",
    "non_monotonic_time",
    "too_short",
}
#: problems of one run that make its PSD meaningless; the run is left out of the plots
_BAD_RUN = {"non_finite", "flat", "clipped", "bad_motion_window", "window_too_short"}
#: the bands of the two figures: the paper's 0-100 Hz and the full band up to Nyquist
_LOW_BAND_HZ = 100.0


def condition_names(system: str | None) -> list[str] | None:
    """The operating conditions of the registered system named ``system`` (``--system``), the
    names ``--condition`` accepts; None when no registered system is named."""
    from ..systems import available_systems, get_system

    if system is None or system not in available_systems():
        return None
    return list(get_system(system).condition_names())


def load(
    path: Path,
    *,
    system: str | None = None,
    conditions: dict[str, list[float]] | None = None,
    state: Sequence[str] = (),
) -> tuple[xr.Dataset | None, list]:
    """The campaign at ``path`` (NetCDF file or CSV folder), unchecked, or the problems that
    stop it from being read as one.

    ``system``, ``conditions`` (per operating condition, one value for every run or one per
    run in file-name order) and ``state`` (likewise) label the runs of a CSV folder without
    the ``campaign.json`` sidecar, which carries no metadata.
    """
    from ..io import SIDECAR, CampaignError, from_csv, load_campaign

    conditions = conditions or {}
    if not path.exists():
        raise fail(f"no campaign at {path}: give a NetCDF file or a folder of CSV files")
    given = {
        "--system": int(system is not None),
        **{f"--condition {k}": len(v) for k, v in conditions.items()},
        "--state": len(state),
    }
    options = " and ".join(name for name, n in given.items() if n)
    bare_csv = path.is_dir() and not (path / SIDECAR).is_file()
    if options and not bare_csv:
        where = f"its {SIDECAR}" if path.is_dir() else "the file"
        raise fail(
            f"{options} label the runs of a folder of CSV files without {SIDECAR}; {path} "
            f"holds its own metadata in {where}: leave out {options} (or edit the metadata)"
        )
    runs = len(list(path.glob("*.csv"))) if bare_csv else 0
    for name, n in given.items():
        if name != "--system" and n not in (0, 1, runs):
            raise fail(
                f"{name} takes one value for all {runs} runs of {path} or one per run (in "
                f"file-name order), got {n}"
            )
    per_run: dict[str, Any] = {k: list(v) * (runs // len(v)) for k, v in conditions.items()}
    try:
        if path.is_dir():
            campaign = from_csv(
                path,
                check=False,
                system=system,
                state=list(state) * (runs // len(state)) if state else None,
                **per_run,
            )
            return campaign, []
        return load_campaign(path, check=False), []
    except CampaignError as err:
        return None, err.problems
    except (OSError, ValueError) as err:
        raise fail(str(err)) from None


def expectations(ds: xr.Dataset) -> tuple[dict, list[str]]:
    """Validation options from the campaign's ``system`` (its channels and sampling rate)."""
    from ..io import system_of
    from ..systems import available_systems

    name = str(ds.attrs.get("system", ""))
    system = system_of(ds)
    if system is None:
        note = (
            f"system {name!r} is not one bayesdoor knows ({', '.join(available_systems())}): "
            "its channels and sampling rate were checked for consistency only"
        )
        return {}, [note] if name else []
    return {"channels": list(system.channels), "sampling_rate_hz": system.sampling_rate_hz}, []


def condition_notes(ds: xr.Dataset) -> list[str]:
    """Operating points the campaign's system cannot simulate (fitting and training skip
    those runs)."""
    from ..io import system_of

    system = system_of(ds)
    if system is None:
        return []
    notes = []
    for spec in system.conditions:
        if spec.name not in ds:
            continue
        values = np.atleast_1d(np.asarray(ds[spec.name].values, dtype=float))
        for v in sorted({float(v) for v in values if np.isfinite(v)}):
            try:
                spec.check(v)
            except ValueError as err:
                notes.append(f"the {system.name} model cannot simulate runs at {err}")
    return notes


def _value_order(item: tuple[str, int]) -> tuple[bool, float]:
    return item[0] == "unknown", 0.0 if item[0] == "unknown" else float(item[0])


def summary(ds: xr.Dataset | None) -> dict[str, Any]:
    """Runs per state and split, speeds, record length, channels, sampling rate, system.

    ``None`` (files that could not be assembled into a campaign) gives the same keys, empty.
    """
    if ds is None:
        ds = xr.Dataset()
    runs = int(ds.sizes.get("run", 0))

    def per_run(name: str, default: str) -> list[str]:
        values = ds[name].values if name in ds else None
        if values is None or np.shape(values) != (runs,):
            return [default] * runs
        return [str(v) for v in values]

    states, splits = per_run("state", "(none)"), per_run("split", "(none)")
    table: dict[str, dict[str, int]] = {}
    for state, split in zip(states, splits, strict=True):
        table.setdefault(state, {}).setdefault(split, 0)
        table[state][split] += 1
    from ..io import system_of

    system = system_of(ds) if ds.attrs else None
    conditions = {}
    for spec in () if system is None else system.conditions:
        counts = Counter(
            f"{float(v):g}" if np.isfinite(v) else "unknown"
            for v in np.ravel(
                np.asarray(ds[spec.name].values, dtype=float) if spec.name in ds else []
            )
        )
        conditions[spec.name] = {
            "unit": spec.unit,
            "runs": dict(sorted(counts.items(), key=_value_order)),
        }
    fs = ds.attrs.get("sampling_rate_hz")
    fs = float(fs) if isinstance(fs, int | float | np.number) else None
    n_time = int(ds.sizes.get("time", 0))
    windows = "t_start/t_stop" if "t_start" in ds and "t_stop" in ds else "detected"
    return {
        "system": str(ds.attrs.get("system", "")),
        "runs": runs,
        "channels": [str(c) for c in ds["channel"].values] if "channel" in ds.coords else [],
        "sampling_rate_hz": fs,
        "record_samples": n_time,
        "record_duration_s": n_time / fs if fs else None,
        "states": dict(Counter(states)),
        "splits": dict(Counter(splits)) if "split" in ds else {},
        "runs_by_state_and_split": table,
        "conditions": conditions,
        "motion_window": windows if runs else None,
    }


def plot_paths(out: Path, fs: float | None) -> list[Path]:
    """The figures ``inspect --out`` writes: 0-100 Hz and the full band."""
    full = f"{fs / 2:g}" if fs else "nyquist"
    return [out / f"psd_0-{_LOW_BAND_HZ:g}Hz.png", out / f"psd_0-{full}Hz.png"]


def plot(ds: xr.Dataset, problems: list, paths: list[Path], title: str) -> tuple[list, list]:
    """Write the PSD figures of the runs without problems of their own.

    Returns the paths written and notes (runs left out, windows detected, why nothing was
    plotted).
    """
    from ..report import campaign_psds, motion_windows, plot_state_psds, segments_in_window

    blocking = sorted({p.code for p in problems if p.code in _BLOCKS_PSD})
    if blocking:
        return [], [f"no PSD plots: the campaign has no usable time axis ({', '.join(blocking)})"]
    start, stop, notes = motion_windows(ds)
    flagged = sorted({p.run for p in problems if p.code in _BAD_RUN and p.run is not None})
    if flagged:
        notes.append(f"runs {flagged} are left out of the PSD plots (see their problems)")
    empty = [
        int(r) for r in np.flatnonzero(segments_in_window(ds, start, stop) == 0) if r not in flagged
    ]
    notes += [
        f"run {r}: its motion window [{start[r]!r}, {stop[r]!r}] s holds no whole Welch segment "
        "(512 samples, starting every 256); it is left out of the PSD plots"
        for r in empty
    ]
    good = [r for r in range(ds.sizes["run"]) if r not in flagged and r not in empty]
    if not good:
        return [], [*notes, "no PSD plots: no run is left to plot"]
    psds = campaign_psds(ds, runs=good, windows=(start, stop))
    low, full = paths
    title = f"{title}: mean log PSD per state and its spread over the runs"
    from ..io import system_of
    from ..systems import HEALTHY

    system = system_of(ds) if ds.attrs else None
    # the system's states, in its order, give the colours (as in the job's report)
    states = () if system is None else tuple(system.states)
    healthy = HEALTHY if system is None else system.healthy
    plot_state_psds(
        psds,
        low,
        fmax=_LOW_BAND_HZ,
        title=f"{title}, 0-{_LOW_BAND_HZ:g} Hz",
        states=states,
        healthy=healthy,
    )
    plot_state_psds(psds, full, title=f"{title}, full band", states=states, healthy=healthy)
    return [low, full], notes


def render(result: dict) -> str:
    """The human-readable summary."""
    lines = [
        f"campaign  {result['file']}",
        f"system    {result['system'] or '(none)'}",
        f"runs      {result['runs']}",
        f"channels  {', '.join(result['channels'])}",
    ]
    fs = result["sampling_rate_hz"]
    if fs:
        lines.append(f"sampling  {fs:g} Hz")
    if result["record_duration_s"] is not None:
        lines.append(
            f"records   {result['record_samples']} samples ({result['record_duration_s']:.3f} s)"
        )
    for name, c in result["conditions"].items():
        unit = f" {c['unit']}" if c["unit"] and c["unit"] != "-" else ""
        values = ", ".join(f"{v}{unit} x {n}" for v, n in c["runs"].items())
        lines.append(f"{name.ljust(9)} {values or '(none)'}")
    lines.append(f"motion    {result['motion_window']}")
    splits = sorted({s for row in result["runs_by_state_and_split"].values() for s in row})
    width = max([len(s) for s in splits] + [5])
    lines.append("runs by state and split:")
    lines.append("  " + "state".ljust(10) + "".join(s.rjust(width + 2) for s in splits))
    for state, row in result["runs_by_state_and_split"].items():
        cells = "".join(str(row.get(s, 0)).rjust(width + 2) for s in splits)
        lines.append("  " + state.ljust(10) + cells)
    lines += [f"warning: {w}" for w in result["warnings"]]
    lines += [f"plot: {p}" for p in result["plots"]]
    return "\n".join(lines)
