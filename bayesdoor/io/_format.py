"""Shared pieces of the campaign format: allowed labels and units, and atomic file writes."""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable
from pathlib import Path

#: the per-run ``state`` labels of the campaign format (docs/data.md)
STATE_LABELS = ("healthy", "D1", "D2", "unknown")
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
