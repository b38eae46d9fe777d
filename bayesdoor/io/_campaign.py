"""The measurement-campaign format (DESIGN.md section 5): build, save atomically, load."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import xarray as xr

STATES = ("healthy", "D1", "D2", "unknown")


def make_campaign(
    acceleration: np.ndarray,
    *,
    channels: Sequence[str],
    fs: float,
    state: Sequence[str],
    v_max: Sequence[float] | np.ndarray,
    split: Sequence[str] | None = None,
    t_start: Sequence[float] | np.ndarray | None = None,
    t_stop: Sequence[float] | np.ndarray | None = None,
    system: str = "elevator_door",
    **extra_run_coords,
) -> xr.Dataset:
    """The one constructor of campaign datasets.

    Parameters
    ----------
    acceleration
        Samples in m/s^2 with shape (run, channel, time).
    channels, fs, state, v_max, split, t_start, t_stop, system
        As in DESIGN.md section 5; per-run sequences have one entry per run.
    **extra_run_coords
        Further per-run coordinates (for example damage severities), kept as given.

    Raises
    ------
    ValueError
        For a shape that does not match the channels or the per-run entries.
    """
    acc = np.asarray(acceleration, dtype=float)
    if acc.ndim != 3:
        raise ValueError(f"acceleration must be (run, channel, time), got shape {acc.shape}")
    runs = acc.shape[0]
    if acc.shape[1] != len(channels):
        raise ValueError(
            f"acceleration has {acc.shape[1]} channels but {len(channels)} names were given"
        )
    per_run = {"state": np.asarray(state, dtype=str), "v_max": np.asarray(v_max, dtype=float)}
    for name, value in (("split", split), ("t_start", t_start), ("t_stop", t_stop)):
        if value is not None:
            per_run[name] = np.asarray(value)
    per_run.update({k: np.asarray(v) for k, v in extra_run_coords.items()})
    for name, value in per_run.items():
        if value.shape != (runs,):
            raise ValueError(f"{name} needs one entry per run ({runs}), got shape {value.shape}")
    bad = sorted(set(per_run["state"]) - set(STATES))
    if bad:
        raise ValueError(f"unknown state labels {bad}: allowed {', '.join(STATES)}")
    ds = xr.Dataset(
        {"acceleration": (("run", "channel", "time"), acc, {"units": "m/s^2"})},
        coords={
            "run": np.arange(runs),
            "channel": list(channels),
            "time": ("time", np.arange(acc.shape[2]) / float(fs), {"units": "s"}),
            **{k: ("run", v) for k, v in per_run.items()},
        },
        attrs={"sampling_rate_hz": float(fs), "system": system, "units": "m/s^2"},
    )
    return ds


def save_campaign(ds: xr.Dataset, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write a campaign to NetCDF atomically (temporary file, then rename).

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is false; nothing is written then.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} already exists; pass overwrite=True to replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        ds.to_netcdf(tmp, engine="h5netcdf")
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def load_campaign(path: str | os.PathLike) -> xr.Dataset:
    """Read a campaign file fully into memory (the file is closed and left untouched)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no campaign file at {path}")
    try:
        return xr.load_dataset(path, engine="h5netcdf")
    except (OSError, ValueError) as err:
        raise ValueError(f"{path} is not a readable NetCDF campaign file: {err}") from None
