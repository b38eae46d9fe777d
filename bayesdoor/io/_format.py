"""Shared pieces of the campaign format: allowed labels and units, and atomic file writes."""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..systems import AbstractSystem, get_system

#: the state every system has: the reference that calibration runs are measured in
HEALTHY = "healthy"
#: the state label of a run whose state is not known (to be classified)
UNKNOWN = "unknown"
#: the per-run ``split`` labels of the campaign format (docs/data.md)
SPLIT_LABELS = ("calibration", "test")
#: spellings of m/s^2 accepted in the ``units`` attributes
ACCELERATION_UNITS = ("m/s^2", "m s-2", "m/s**2")
#: units that are recognisably acceleration, with their factor to m/s^2
CONVERTIBLE_UNITS = {"g": 9.80665, "mg": 9.80665e-3}


def atomic_write(path: Path, write: Callable[[Path], object], *, overwrite: bool) -> Path:
    """Create ``path`` through ``write(temporary path)`` and a rename, so it appears whole.

    The temporary file sits in the same folder (a rename within one file system is atomic)
    and is removed when ``write`` fails, so a failed or interrupted write leaves the previous
    file, if any, as it was.

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is false; nothing is written then.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(
            f"{path} already exists; pass overwrite=True to replace it (nothing was written)"
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    try:
        write(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def system_of(campaign_or_name) -> AbstractSystem | None:
    """The registered system a campaign names in ``attrs['system']`` (or by name); ``None``
    when no system of that name is registered."""
    name = getattr(campaign_or_name, "attrs", {}).get("system", campaign_or_name)
    if not isinstance(name, str) or not name.strip():
        return None
    try:
        return get_system(name)
    except LookupError:
        return None


def state_labels(system: AbstractSystem) -> tuple[str, ...]:
    """The ``state`` labels a campaign of ``system`` may hold: its states and ``unknown``."""
    return (*system.states, UNKNOWN)


def operating(campaign, system: AbstractSystem | None = None, runs=None) -> np.ndarray:
    """The runs' operating conditions as ``system`` takes them: one value per run for a single
    condition (shape ``(run,)``), ``(run, condition)`` for several, in the order of
    ``system.conditions``; ``runs`` selects runs by position. ``system=None``: the registered
    system the campaign names.

    Raises
    ------
    ValueError
        When the campaign lacks one of the system's conditions, or names no registered system
        (and none is given).
    """
    if system is None:
        system = system_of(campaign)
        if system is None:
            raise ValueError(
                f"the campaign's system {campaign.attrs.get('system')!r} is not registered: "
                "pass the system (bayesdoor.systems.register_system adds one)"
            )
    names = [c.name for c in system.conditions]
    missing = [n for n in names if n not in campaign]
    if missing:
        raise ValueError(
            f"the campaign has no per-run {', '.join(missing)}: {system.name} runs are "
            f"described by {', '.join(names)}"
        )
    columns = [np.asarray(campaign[n].values, dtype=float) for n in names]
    if runs is not None:
        columns = [c[np.asarray(runs)] for c in columns]
    return columns[0] if len(columns) == 1 else np.stack(columns, axis=-1)
