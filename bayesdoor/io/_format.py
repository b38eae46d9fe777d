"""Shared pieces of the campaign format: allowed labels and units, and atomic file writes."""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..systems import AbstractSystem, get_system

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


#: the campaign attribute that holds the system's settings (JSON), where they differ from
#: the registered system's (:meth:`~bayesdoor.systems.AbstractSystem.settings`)
SYSTEM_SETTINGS = "system_settings"


def system_of(campaign_or_name) -> AbstractSystem | None:
    """The registered system a campaign names in ``attrs['system']`` (or by name), with the
    settings the campaign records (:func:`with_campaign_settings`); ``None`` when no system of
    that name is registered.

    Raises
    ------
    ValueError
        When the campaign's ``system_settings`` are not JSON or the system refuses them.
    """
    name = getattr(campaign_or_name, "attrs", {}).get("system", campaign_or_name)
    if not isinstance(name, str) or not name.strip():
        return None
    try:
        system = get_system(name)
    except LookupError:
        return None
    return with_campaign_settings(system, campaign_or_name)


def with_campaign_settings(system: AbstractSystem, campaign) -> AbstractSystem:
    """``system`` with the settings of ``attrs['system_settings']`` (a bearing's geometry and
    sampling rate) when the campaign names that system; else ``system`` as given.

    Raises
    ------
    ValueError
        When the settings are not a JSON object or the system refuses them, naming both.
    """
    attrs = getattr(campaign, "attrs", {})
    text = attrs.get(SYSTEM_SETTINGS)
    if text is None or attrs.get("system") != system.name:
        return system
    try:
        settings = json.loads(text)
    except (TypeError, ValueError) as err:
        raise ValueError(f"attrs[{SYSTEM_SETTINGS!r}] is not JSON ({err}): {text!r}") from None
    if not isinstance(settings, dict):
        raise ValueError(f"attrs[{SYSTEM_SETTINGS!r}] must be a JSON object, got {text!r}")
    try:
        return system.with_settings(settings)
    except ValueError as err:
        raise ValueError(f"attrs[{SYSTEM_SETTINGS!r}] of the campaign: {err}") from None


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
