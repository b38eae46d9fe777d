"""Campaigns as CSV: one file per run (``time`` plus one column per channel) and a JSON sidecar.

A folder written by :func:`to_csv` holds ``run_0000.csv``, ``run_0001.csv``, ... and
``campaign.json`` with everything else: the attributes, the acceleration's attributes, every
coordinate but ``time`` (values, dims, dtype, attributes), the time coordinate's attributes,
any other data variable without a time axis, and the file of each run. Floats are written
with Python's ``repr`` (the shortest string that reads back as the same float), so a round
trip is exact. The JSON is strict (no NaN tokens): NaN is ``null``, infinities are the
strings ``"inf"`` and ``"-inf"``.
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from ._campaign import make_campaign
from ._format import atomic_write, system_of
from ._validate import CampaignError, Problem, check_campaign

#: the sidecar's file name
SIDECAR = "campaign.json"
_FORMAT = "bayesdoor-campaign-csv"
_VERSION = 1


def _json_values(values: np.ndarray, name: str) -> tuple[str, Any]:
    """(dtype name, JSON-ready nested list or scalar) of an array."""
    if values.dtype.kind in "US" or (
        values.dtype.kind == "O" and all(isinstance(v, str) for v in values.ravel())
    ):
        return "str", values.astype(str).tolist()
    if values.dtype.kind == "f":
        special = {"nan": None, "inf": "inf", "-inf": "-inf"}
        out = [special.get(repr(v), v) for v in values.ravel().tolist()]
        return values.dtype.str, np.asarray(out, dtype=object).reshape(values.shape).tolist()
    if values.dtype.kind in "biu":
        return values.dtype.str, values.tolist()
    raise ValueError(
        f"{name} has dtype {values.dtype}, which the CSV sidecar cannot store (strings, "
        "booleans, integers and floats only): convert it or use save_campaign (NetCDF)"
    )


def _from_json(dtype: str, values: Any) -> np.ndarray:
    return np.asarray(values, dtype=str if dtype == "str" else np.dtype(dtype))


def _json_attrs(attrs: dict, name: str) -> dict[str, dict[str, Any]]:
    out = {}
    for key, value in attrs.items():
        dtype, values = _json_values(np.asarray(value), f"{name} attribute {key!r}")
        out[str(key)] = {"dtype": dtype, "values": values, "array": np.ndim(value) > 0}
    return out


def _from_json_attrs(attrs: dict[str, dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, entry in attrs.items():
        value = _from_json(entry["dtype"], entry["values"])
        if entry["array"]:
            out[key] = value
        else:
            out[key] = str(value) if entry["dtype"] == "str" else value[()]
    return out


def _variables(ds: xr.Dataset) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for group, names in (("coords", ds.coords), ("data_vars", ds.data_vars)):
        out[group] = {}
        for name in names:
            if name in ("time", "acceleration"):
                continue
            var = ds[name].variable
            if "time" in var.dims:
                raise ValueError(
                    f"{group[:-1]} {name!r} runs along time, which the per-run CSV files "
                    "cannot hold besides the channels: drop it or use save_campaign (NetCDF)"
                )
            dtype, values = _json_values(np.asarray(var.values), repr(name))
            out[group][str(name)] = {
                "dims": list(var.dims),
                "dtype": dtype,
                "values": values,
                "attrs": _json_attrs(var.attrs, repr(name)),
            }
    return out


def _write_text(path: Path, text: str) -> None:
    atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"), overwrite=True)


def to_csv(ds: xr.Dataset, folder: str | os.PathLike, *, overwrite: bool = False) -> list[Path]:
    """Write a campaign as one CSV file per run plus ``campaign.json`` (see module notes).

    Each file is written atomically; the sidecar is written last, so a folder with a sidecar
    is complete. :func:`from_csv` reads the folder back exactly.

    Parameters
    ----------
    ds
        The campaign.
    folder
        The folder to write into (created if needed).
    overwrite
        Replace existing files of the same names; run files of an earlier, longer campaign
        in the folder stay (``from_csv`` reads only the runs the sidecar lists).

    Returns
    -------
    paths
        The run files, then the sidecar.

    Raises
    ------
    FileExistsError
        If any file to write exists and ``overwrite`` is false; nothing is written then.
    ValueError
        If ``ds`` has no ``acceleration`` (run, channel, time), a channel name that cannot be a
        CSV column, or a variable the format cannot hold.
    """
    folder = Path(folder)
    if ds.get("acceleration") is None or set(ds["acceleration"].dims) != {
        "run",
        "channel",
        "time",
    }:
        raise ValueError("to_csv needs a variable 'acceleration' with dims (run, channel, time)")
    acc = ds["acceleration"].transpose("run", "channel", "time")
    channels = [str(c) for c in ds["channel"].values]
    for c in channels:
        if c == "time" or any(ch in c for ch in ',"\n\r') or c != c.strip():
            raise ValueError(f"channel name {c!r} cannot be a CSV column: rename it")
    files = [f"run_{i:04d}.csv" for i in range(ds.sizes["run"])]
    sidecar = {
        "format": _FORMAT,
        "version": _VERSION,
        "files": files,
        "attrs": _json_attrs(ds.attrs, "the dataset"),
        "acceleration_attrs": _json_attrs(acc.attrs, "acceleration"),
        "time_attrs": _json_attrs(ds["time"].attrs, "time"),
        **_variables(ds),
    }
    paths = [folder / f for f in [*files, SIDECAR]]
    existing = [p for p in paths if p.exists()]
    if existing and not overwrite:
        raise FileExistsError(
            f"{existing[0]} already exists ({len(existing)} of the files to write do); pass "
            "overwrite=True to replace them (nothing was written)"
        )
    time = np.asarray(ds["time"].values, dtype=float).tolist()
    header = ",".join(["time", *channels]) + "\n"
    values = np.asarray(acc.values, dtype=float)
    for path, run in zip(paths[:-1], values, strict=True):
        rows = zip(time, *run.tolist(), strict=True)
        text = header + "".join(",".join(map(repr, row)) + "\n" for row in rows)
        _write_text(path, text)
    _write_text(paths[-1], json.dumps(sidecar, indent=1, allow_nan=False))
    return paths


def _read_csv(path: Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(channel names, time, samples (channel, time)) of one run file."""
    if not path.is_file():
        raise FileNotFoundError(f"no CSV file at {path}")
    with open(path, encoding="utf-8") as f:
        header = [h.strip() for h in f.readline().strip().split(",")]
    if "time" not in header:
        raise CampaignError(
            [Problem("bad_csv", f"{path}: no 'time' column in the header {header}")]
        )
    try:
        with warnings.catch_warnings():
            # an empty file is reported below, as a CampaignError
            warnings.filterwarnings("ignore", "loadtxt: input contained no data")
            data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, dtype=float)
    except ValueError as err:
        raise CampaignError([Problem("bad_csv", f"{path}: unreadable CSV ({err})")]) from None
    if data.shape[0] == 0:
        raise CampaignError([Problem("bad_csv", f"{path}: no data rows under the header")])
    if data.shape[1] != len(header):
        raise CampaignError(
            [
                Problem(
                    "bad_csv",
                    f"{path}: {data.shape[1]} columns of numbers under a header of "
                    f"{len(header)} names",
                )
            ]
        )
    i = header.index("time")
    return header[:i] + header[i + 1 :], data[:, i], np.delete(data, i, axis=1).T


def _read_runs(
    paths: Sequence[Path], channels: Sequence[str] | None
) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Read run files onto one time grid, zero-padding shorter runs at the end."""
    if not paths:
        raise FileNotFoundError("no CSV files to read")
    runs = [_read_csv(p) for p in paths]
    names = list(channels) if channels is not None else runs[0][0]
    longest = max(range(len(runs)), key=lambda k: runs[k][1].size)
    time = runs[longest][1]
    acc = np.zeros((len(runs), len(names), time.size))
    for k, (path, (found, t, x)) in enumerate(zip(paths, runs, strict=True)):
        missing = [c for c in names if c not in found]
        extra = [c for c in found if c not in names]
        if missing or (channels is None and extra):
            raise CampaignError(
                [
                    Problem(
                        "missing_channels" if missing else "unknown_channels",
                        f"{path}: channels {found} differ from {names} (missing {missing}, "
                        f"extra {extra}); every run file needs the same channels",
                        k,
                    )
                ]
            )
        # a DAQ may round its time stamps: allow 1 % of a sample period
        tol = 0.01 * float(np.median(np.abs(np.diff(time)))) if time.size > 1 else 0.0
        off = np.flatnonzero(~(np.abs(t - time[: t.size]) <= tol))
        if off.size:
            j = int(off[0])
            raise CampaignError(
                [
                    Problem(
                        "sampling_rate_mismatch",
                        f"{path}: time[{j}] = {float(t[j])!r} s but {paths[longest]} has "
                        f"{float(time[j])!r} s: all runs must share one time grid",
                        k,
                    )
                ]
            )
        acc[k, :, : t.size] = x[[found.index(c) for c in names]]
    return names, time, acc


def from_csv(
    source: str | os.PathLike | Sequence[str | os.PathLike],
    *,
    channels: Sequence[str] | None = None,
    fs: float | None = None,
    state: Sequence[str] | None = None,
    system: str | None = None,
    check: bool = True,
    **run_coords,
) -> xr.Dataset:
    """Read a campaign from CSV files, one per run (``time`` plus one column per channel).

    A folder with ``campaign.json`` (as :func:`to_csv` writes it) is read back exactly,
    metadata from the sidecar; the metadata arguments are refused then. Otherwise (a folder
    of ``*.csv`` files, read in name order, or a list of files) the runs are assembled with
    :func:`make_campaign` from the arguments, keeping the files' time column. Runs shorter
    than the longest are padded with zeros (rest) at the end; all must share its time grid.

    Parameters
    ----------
    source
        A folder, or a sequence of CSV files (one per run, in run order).
    channels
        The channels to keep, in this order; ``None`` takes the first file's columns.
    fs
        Sampling rate in Hz; ``None`` infers it from the time column, as (samples - 1) /
        (last time - first time), which time stamps rounded by the acquisition do not upset.
    state
        Per run; ``None`` labels every run ``unknown``.
    **run_coords
        As in :func:`make_campaign`: ``split``, ``t_start``, ``t_stop`` and further per-run
        coordinates (the operating conditions among them, under the names the system
        declares; those not given are left NaN, which ``check`` reports).
    system
        The system's name, as the registry knows it.
    check
        Run :func:`check_campaign` (default options) on the result.

    Returns
    -------
    campaign
        The campaign dataset.

    Raises
    ------
    FileNotFoundError
        For a missing file or a folder without CSV files.
    CampaignError
        For a file without a ``time`` column, unreadable numbers, ragged rows, run files with
        different channels or time grids, a bad sidecar, or (with ``check``) a campaign that
        breaks the format.
    ValueError
        For metadata arguments together with a sidecar.
    """
    folder = Path(source) if isinstance(source, str | os.PathLike) else None
    if folder is not None and (folder / SIDECAR).is_file():
        _refuse_metadata(
            folder, dict(channels=channels, fs=fs, state=state, system=system, **run_coords)
        )
        ds = _from_sidecar(folder)
    else:
        paths = _csv_paths(source, folder)
        ds = _assemble(paths, channels, fs, state, system, run_coords)
    if check:
        check_campaign(
            ds,
            source=str(folder)
            if folder is not None
            else f"{paths[0].parent} ({len(paths)} CSV files)",
        )
    return ds


def _refuse_metadata(folder: Path, arguments: dict[str, Any]) -> None:
    """A ``ValueError`` when metadata arguments come with a folder whose sidecar has them."""
    given = {k: v for k, v in arguments.items() if v is not None}
    if given:
        raise ValueError(
            f"{folder / SIDECAR} defines the metadata; got {sorted(given)} as well: "
            "edit the sidecar, or pass the CSV files as a list to use the arguments"
        )


def _assemble(
    paths: list[Path],
    channels: Sequence[str] | None,
    fs: float | None,
    state: Sequence[str] | None,
    system: str | None,
    run_coords: dict[str, Any],
) -> xr.Dataset:
    """The campaign of the run files, through :func:`make_campaign`, with the files' times."""
    names, time, acc = _read_runs(paths, channels)
    runs = len(paths)
    known = system_of(system)
    for name in [] if known is None else known.condition_names():
        run_coords.setdefault(name, np.full(runs, np.nan))
    ds = make_campaign(
        acc,
        channels=names,
        fs=(time.size - 1) / float(time[-1] - time[0]) if fs is None else fs,
        state=["unknown"] * runs if state is None else state,
        system="" if system is None else system,
        **run_coords,
    )
    return ds.assign_coords(time=("time", time, ds["time"].attrs))


def _csv_paths(source, folder: Path | None) -> list[Path]:
    """The run files: the given list, a folder's ``*.csv`` files in name order, or one file."""
    if folder is None:
        return [Path(p) for p in source]
    if folder.is_dir():
        paths = sorted(folder.glob("*.csv"))
        if not paths:
            raise FileNotFoundError(f"no *.csv files in {folder}")
        return paths
    return [folder]


def _from_sidecar(folder: Path) -> xr.Dataset:
    path = folder / SIDECAR
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
        if meta.get("format") != _FORMAT or meta.get("version") != _VERSION:
            raise KeyError(f"format {meta.get('format')!r} version {meta.get('version')!r}")
        files = [folder / f for f in meta["files"]]
        channel = meta["coords"]["channel"]
        variables = {
            group: {
                name: xr.Variable(
                    v["dims"], _from_json(v["dtype"], v["values"]), _from_json_attrs(v["attrs"])
                )
                for name, v in meta[group].items()
            }
            for group in ("coords", "data_vars")
        }
        attrs = {
            key: _from_json_attrs(meta[key])
            for key in ("attrs", "acceleration_attrs", "time_attrs")
        }
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        raise CampaignError(
            [Problem("bad_sidecar", f"{path} is not a valid campaign sidecar ({err!r})")]
        ) from None
    _, time, acc = _read_runs(files, [str(c) for c in channel["values"]])
    coords = {
        **variables["coords"],
        "time": xr.Variable("time", time, attrs["time_attrs"]),
    }
    dims = ("run", "channel", "time")
    return xr.Dataset(
        {"acceleration": (dims, acc, attrs["acceleration_attrs"]), **variables["data_vars"]},
        coords=coords,
        attrs=attrs["attrs"],
    )
