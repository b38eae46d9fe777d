"""The measurement-campaign format (``docs/data.md``): build, save atomically, load."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import xarray as xr

from ._format import SPLIT_LABELS, atomic_write, state_labels, system_of
from ._validate import check_campaign


def make_campaign(
    acceleration: np.ndarray,
    *,
    channels: Sequence[str],
    fs: float,
    state: Sequence[str] | np.ndarray,
    system: str,
    **run_coords,
) -> xr.Dataset:
    """Build a campaign dataset: the one constructor every producer of campaigns uses.

    Parameters
    ----------
    acceleration
        Samples in m/s^2, shape (run, channel, time); the time coordinate is
        ``arange(time) / fs``.
    channels
        Channel names, one per ``acceleration[:, i]``.
    fs
        Sampling rate in Hz.
    state
        Per run: one of the system's states (``healthy`` among them) or ``unknown``; a
        system that is not registered accepts any label.
    system
        The system's name (attribute ``system``), as the registry knows it.
    **run_coords
        Optional per-run coordinates: ``split`` (``calibration`` or ``test``), ``t_start``
        and ``t_stop`` (when the motion starts and stops, s), and further ones kept as
        given: the operating conditions under the names the system declares (the door's
        ``v_max``, NaN where unknown: :func:`validate_campaign` reports it), damage
        severities, record names.

    Returns
    -------
    campaign
        Variable ``acceleration`` (run, channel, time) with units m/s^2; coordinates ``run``
        (0, 1, ...), ``channel``, ``time`` (s) and the per-run ones; attributes
        ``sampling_rate_hz``, ``system`` and ``units``.

    Raises
    ------
    ValueError
        For a shape that does not match the channels or the runs, a non-positive ``fs``, or a
        state or split label outside the allowed ones.

    Examples
    --------
    >>> import numpy as np
    >>> ds = make_campaign(
    ...     np.zeros((2, 4, 1024)), channels=["A1X", "A1Z", "A2X", "A2Z"], fs=2048.0,
    ...     state=["healthy", "D1"], system="elevator_door", v_max=[0.3, 0.4],
    ... )
    >>> dict(ds.sizes)
    {'run': 2, 'channel': 4, 'time': 1024}
    """
    acc = np.asarray(acceleration, dtype=float)
    if acc.ndim != 3:
        raise ValueError(f"acceleration must be (run, channel, time), got shape {acc.shape}")
    runs = acc.shape[0]
    if acc.shape[1] != len(channels):
        raise ValueError(
            f"acceleration has {acc.shape[1]} channels (shape {acc.shape}) but "
            f"{len(channels)} names were given: {list(channels)}"
        )
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a positive sampling rate in Hz, got {fs!r}")
    per_run = _per_run(np.asarray(state, dtype=str), run_coords, runs)
    _check_labels(per_run, system)
    return xr.Dataset(
        {"acceleration": (("run", "channel", "time"), acc, {"units": "m/s^2"})},
        coords={
            "run": np.arange(runs),
            "channel": [str(c) for c in channels],
            "time": ("time", np.arange(acc.shape[2]) / float(fs), {"units": "s"}),
            **{k: ("run", v) for k, v in per_run.items()},
        },
        attrs={"sampling_rate_hz": float(fs), "system": system, "units": "m/s^2"},
    )


#: the optional per-run coordinates of the format, in their order, with their types
_RUN_TYPES = {"split": str, "t_start": float, "t_stop": float}


def _per_run(state: np.ndarray, given: dict, runs: int) -> dict[str, np.ndarray]:
    """The per-run coordinates as arrays: the state, the format's optional ones (as their
    types), then the others as given; a ``ValueError`` for one without one entry per run."""
    per_run = {"state": state}
    for name, dtype in _RUN_TYPES.items():
        if given.get(name) is not None:
            per_run[name] = np.asarray(given[name], dtype=dtype)
    per_run.update({k: np.asarray(v) for k, v in given.items() if k not in _RUN_TYPES})
    for name, value in per_run.items():
        if value.shape != (runs,):
            raise ValueError(f"{name} needs one entry per run ({runs}), got shape {value.shape}")
    return per_run


def _check_labels(per_run: dict[str, np.ndarray], system: str) -> None:
    """Refuse split labels outside the format's, and state labels outside a known system's."""
    known = system_of(system)
    labels: dict[str, tuple[str, ...]] = {"split": SPLIT_LABELS}
    if known is not None:
        labels["state"] = state_labels(known)
    for name, allowed in labels.items():
        bad = sorted(set(map(str, per_run.get(name, ()))) - set(allowed))
        if bad:
            raise ValueError(f"unknown {name} labels {bad}: allowed {', '.join(allowed)}")


def save_campaign(ds: xr.Dataset, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write a campaign to NetCDF (HDF5, through h5netcdf) atomically.

    The file is written under a temporary name in the same folder and renamed into place,
    so readers never see a partial file and a failed write leaves the old file as it was.
    The dataset is written as given; :func:`load_campaign` checks it on the way back.

    Parameters
    ----------
    ds
        The campaign.
    path
        The file to write.
    overwrite
        Replace an existing file.

    Returns
    -------
    path
        The path written.

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is false; nothing is written then.
    """
    return atomic_write(
        Path(path), lambda tmp: ds.to_netcdf(tmp, engine="h5netcdf"), overwrite=overwrite
    )


def load_campaign(path: str | os.PathLike, *, check: bool = True, **options) -> xr.Dataset:
    """Read a campaign file fully into memory; the file is opened read-only and closed.

    Times and attributes are read as stored (no CF time decoding), so the time coordinate
    stays in seconds.

    Parameters
    ----------
    path
        A NetCDF file (NetCDF-4/HDF5, or NetCDF-3 through scipy).
    check
        Run :func:`check_campaign` on the result; pass ``False`` to load a campaign that
        breaks the format, for example to list its problems with :func:`validate_campaign`.
    **options
        Keyword arguments of :func:`validate_campaign` for the check, for example
        ``channels=["A1X", "A1Z", "A2X", "A2Z"], sampling_rate_hz=2048.0``.

    Returns
    -------
    campaign
        The dataset with every variable, coordinate and attribute of the file.

    Raises
    ------
    FileNotFoundError
        If there is no file at ``path``.
    ValueError
        If the file is not readable as NetCDF.
    CampaignError
        If ``check`` and the campaign breaks the format.
    """
    path = Path(path)
    if path.is_dir():
        raise FileNotFoundError(
            f"{path} is a folder, not a campaign file: pass the .nc file (a folder of CSV files "
            "is read with from_csv)"
        )
    if not path.is_file():
        raise FileNotFoundError(f"no campaign file at {path}")
    try:
        ds = xr.load_dataset(path, decode_times=False, decode_timedelta=False)
    except (OSError, ValueError) as err:
        raise ValueError(_unreadable(path, err)) from None
    if check:
        check_campaign(ds, source=str(path), **options)
    return ds


#: the first bytes of NetCDF-3 (classic, 64-bit offset) and NetCDF-4 (HDF5) files
_NETCDF_MAGIC = (b"CDF\x01", b"CDF\x02", b"\x89HDF\r\n\x1a\n")
#: the first bytes of files users mistake for a campaign
_OTHER_MAGIC = {
    b"\x89PNG": "a PNG image",
    b"\xff\xd8\xff": "a JPEG image",
    b"%PDF": "a PDF document",
    b"PK\x03\x04": "a ZIP archive (an .xlsx, .npz or zipped folder)",
    b"\x1f\x8b": "a gzip archive",
    b"\x93NUMPY": "a NumPy .npy array",
}


def _unreadable(path: Path, err: Exception) -> str:
    """Why ``path`` cannot be read as NetCDF, from its first bytes, and what to do."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(512)
    start = f"{path} is not a readable NetCDF campaign file"
    if size == 0:
        return (
            f"{start}: it is empty (0 bytes): (a) an interrupted copy or download, (b) a failed "
            "write; copy or record it again"
        )
    if head.startswith(_NETCDF_MAGIC):
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        return (
            f"{start}: it is NetCDF but cannot be read ({reason}): (a) truncated by an "
            f"interrupted copy or download (it has {size} bytes), (b) corrupted; copy or "
            "record it again"
        )
    for magic, kind in _OTHER_MAGIC.items():
        if head.startswith(magic):
            return f"{start}: it is {kind}; pass the campaign's .nc file"
    # a cut multi-byte character at the end of the head is dropped, not a sign of binary
    text = head.decode("utf-8", errors="ignore")
    if all(c.isprintable() or c in "\t\r\n" for c in text):
        first = text.splitlines()[0][:40] if text.strip() else ""
        hint = (
            "; a campaign in CSV files is a folder of them: read it with from_csv (or "
            "'bayesdoor inspect FOLDER')"
            if "," in first
            else "; pass the campaign's .nc file"
        )
        return f"{start}: it is a text file (it starts {first!r}){hint}"
    return (
        f"{start}: its first bytes are {head[:8]!r}; pass a campaign written by "
        "save_campaign or 'bayesdoor simulate'"
    )
