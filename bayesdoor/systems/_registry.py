"""Systems found by name: the ``bayesdoor.systems`` entry points, and systems registered here.

A package adds a system by declaring an entry point in its ``pyproject.toml``::

    [project.entry-points."bayesdoor.systems"]
    my_machine = "my_package:MyMachine"

where ``MyMachine`` is an :class:`~bayesdoor.systems.AbstractSystem` whose ``name`` is
``my_machine``. :func:`register_system` adds one for the running process only (a notebook, a
test).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Protocol

from ._base import AbstractSystem

#: the entry-point group that names systems
ENTRY_POINT_GROUP = "bayesdoor.systems"
#: the entry-point group of demo campaigns, named after their system
DEMO_GROUP = "bayesdoor.demos"
#: the entry-point group of importers of measured data (``bayesdoor import NAME``)
IMPORTER_GROUP = "bayesdoor.importers"
#: the entry-point group of the readers of manifests (``bayesdoor import MANIFEST.toml``),
#: named after the system a manifest names
MANIFEST_IMPORTER_GROUP = "bayesdoor.manifest_importers"
_REGISTERED: dict[str, Callable[[], AbstractSystem]] = {}


def register_system(name: str, factory: Callable[[], AbstractSystem]) -> None:
    """Make ``factory()`` the system called ``name`` in this process (before entry points)."""
    if not name or not isinstance(name, str):
        raise ValueError(f"a system's name must be a non-empty string, got {name!r}")
    _REGISTERED[name] = factory


def available_systems() -> tuple[str, ...]:
    """The names of every system found: registered here and through entry points, sorted."""
    found = {ep.name for ep in entry_points(group=ENTRY_POINT_GROUP)}
    return tuple(sorted(found | set(_REGISTERED)))


def get_system(name: str) -> AbstractSystem:
    """The system called ``name``, built with its defaults: once per name and factory, later
    calls return the same (immutable) object.

    Raises
    ------
    LookupError
        For a name that no registered system or entry point carries; the message lists the
        names available.
    """
    if name in _REGISTERED:
        return _built(name, _REGISTERED[name])
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name == name:
            return _built(name, ep.load())
    raise LookupError(
        f"no system called {name!r}: available {', '.join(available_systems()) or 'none'} "
        f"(a package adds one through the {ENTRY_POINT_GROUP!r} entry points)"
    )


@functools.cache
def _built(name: str, factory: Callable[[], AbstractSystem]) -> AbstractSystem:
    """``factory()``, built once: a factory registered again under the name builds anew."""
    return _check(name, factory())


def _check(name: str, system) -> AbstractSystem:
    if not isinstance(system, AbstractSystem):
        raise TypeError(f"the system {name!r} is a {type(system).__name__}, not an AbstractSystem")
    return system


class DemoCampaign(Protocol):
    """A campaign that a system ships for ``bayesdoor demo``: recorded on first use, cached."""

    def cached_path(self) -> Path:
        """Where the campaign is cached (it exists once recorded)."""
        ...

    def load(self, *, show_progress: bool) -> Any:
        """The campaign (an ``xarray.Dataset``), recorded first when not cached."""
        ...


def available_demos() -> tuple[str, ...]:
    """The systems that ship a demo campaign (``bayesdoor.demos`` entry points), sorted."""
    return tuple(sorted({ep.name for ep in entry_points(group=DEMO_GROUP)}))


def get_demo(name: str | None = None) -> DemoCampaign:
    """The demo campaign of system ``name`` (``None``: the first available, by name).

    Raises
    ------
    LookupError
        When no such demo is declared; the message lists those available.
    """
    names = available_demos()
    if name is None and names:
        name = names[0]
    for ep in entry_points(group=DEMO_GROUP):
        if ep.name == name:
            return ep.load()
    raise LookupError(
        f"no demo campaign for {name!r}: available {', '.join(names) or 'none'} (a package "
        f"declares one through the {DEMO_GROUP!r} entry points)"
    )


def available_importers() -> tuple[str, ...]:
    """The formats ``bayesdoor import`` reads (``bayesdoor.importers`` entry points), sorted."""
    return tuple(sorted({ep.name for ep in entry_points(group=IMPORTER_GROUP)}))


def get_importer(name: str) -> Callable[..., dict]:
    """The importer ``name``: ``importer(source, out, *, overwrite=False) -> summary`` writes
    a campaign file from measured data at ``source`` and returns a JSON-able summary.

    Raises
    ------
    LookupError
        When no such importer is declared; the message lists those available.
    """
    for ep in entry_points(group=IMPORTER_GROUP):
        if ep.name == name:
            return ep.load()
    raise LookupError(
        f"no importer called {name!r}: available {', '.join(available_importers()) or 'none'} "
        f"(a package declares one through the {IMPORTER_GROUP!r} entry points)"
    )


def get_manifest_importer(system: str) -> Callable[..., dict]:
    """The reader of manifests of ``system``: ``importer(manifest, source, out, *,
    overwrite=False) -> summary`` writes a campaign file from the records at ``source`` that
    the manifest file describes, and returns a JSON-able summary.

    Raises
    ------
    LookupError
        When no system of that name reads manifests; the message lists those that do.
    """
    group = entry_points(group=MANIFEST_IMPORTER_GROUP)
    for ep in group:
        if ep.name == system:
            return ep.load()
    names = ", ".join(sorted({ep.name for ep in group})) or "none"
    raise LookupError(
        f"no reader of manifests of the system {system!r} (systems with one: {names}; a "
        f"package declares one through the {MANIFEST_IMPORTER_GROUP!r} entry points)"
    )
