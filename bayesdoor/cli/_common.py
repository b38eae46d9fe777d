"""Shared plumbing of the command line: JSON output, one-line failures, checks."""

from __future__ import annotations

import contextlib
import errno
import functools
import json
import os
import sys
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, ParamSpec, TypeVar

import typer

if TYPE_CHECKING:
    import xarray as xr

    from ..systems import AbstractSystem

#: validation problems a job tolerates: the command names the system, extra channels are
#: ignored, and a clipped record is the user's call (``inspect`` reports it)
_TOLERATED = {"missing_system", "unknown_channels", "clipped"}
#: the errors of a write that the user can fix by writing elsewhere
_WRITE_ERRORS = (errno.EACCES, errno.EPERM, errno.ENOSPC, errno.EROFS, errno.EDQUOT)
P = ParamSpec("P")
R = TypeVar("R")


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print a one-line reason on stderr and return the exit to raise."""
    typer.echo(f"error: {' '.join(message.split(chr(10)))}", err=True)
    return typer.Exit(code)


def emit_json(payload: dict) -> None:
    """The JSON alone on stdout."""
    sys.stdout.write(json.dumps(payload, indent=2, default=float) + "\n")
    sys.stdout.flush()


def check_output_path(path: Path, force: bool) -> None:
    """Refuse to overwrite an existing result unless ``--force``."""
    if path.exists() and not force:
        raise fail(f"{path} already exists; pass --force to overwrite it")


def check_writable(path: Path, option: str = "--out") -> None:
    """Refuse, before any work, an output path that cannot be created or written.

    The nearest existing folder on the way to ``path`` must be a folder we may write in.
    """
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if existing != path and not existing.is_dir():
        raise fail(f"{option} {path}: {existing} is a file, so {path} cannot be created there")
    folder = existing if existing.is_dir() else existing.parent
    if not os.access(folder, os.W_OK | os.X_OK):
        raise fail(f"{option} {path}: no permission to write in {folder}; pass a writable path")


def parse_assignments(
    items: Sequence[str],
    option: str,
    known: Sequence[str] | None = None,
    *,
    several: bool = False,
) -> dict[str, list[float]]:
    """The ``NAME=VALUE`` items of a repeatable option as ``{name: values}``.

    ``several`` allows ``NAME=V1,V2,...`` (else each name gets one value); ``known``, when
    given, are the names the option accepts. Each name may be given once.

    Raises
    ------
    typer.Exit
        (through :func:`fail`, one line naming ``option``) for an item without ``=`` or a
        name, a name given twice, a name not in ``known`` (the line lists the known ones) or a
        value that is not a number.
    """
    form = "NAME=VALUE[,VALUE...]" if several else "NAME=VALUE"
    example = f" (e.g. {option} {known[0]}=...)" if known else ""
    out: dict[str, list[float]] = {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise fail(f"{option} takes {form}{example}, got {item!r}")
        if name in out:
            raise fail(f"{option} {name} is given twice: give each name once")
        if known is not None and name not in known:
            raise fail(f"{option} {name}: unknown name; the known names are {', '.join(known)}")
        parts = text.split(",") if several else [text]
        try:
            out[name] = [float(part) for part in parts]
        except ValueError:
            what = "a number or a list of numbers" if several else "a number"
            raise fail(f"{option} {name}: {text!r} is not {what}") from None
    return out


@contextlib.contextmanager
def interruptible(explain: Callable[[], str]) -> Iterator[None]:
    """Ctrl-C inside: one line on stderr, ``interrupted: <explain()>``, then exit 130.

    130 is 128 + SIGINT, the status a shell gives a command stopped by Ctrl-C. The line says
    what was stopped, what is kept and how to go on; no traceback.
    """
    try:
        yield
    except KeyboardInterrupt:
        if sys.stderr.isatty():
            typer.echo("", err=True)  # past the ^C the terminal echoed
        typer.echo(f"interrupted: {explain()}", err=True)
        raise typer.Exit(130) from None


@contextlib.contextmanager
def warnings_as_lines(echo: Callable[[str], None]) -> Iterator[None]:
    """Python warnings raised inside become one ``warning: ...`` line each, through ``echo``.

    Without the source file and line Python prints (the user did not write that code); the
    lines of a long message are joined with "; "; a message seen before is not repeated. The
    filters are left as they are.
    """
    seen: set[str] = set()

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        first, *rest = str(message).strip().splitlines() or [""]
        text = " ".join([first, "; ".join(part.strip() for part in rest)]).strip()
        if text not in seen:
            seen.add(text)
            echo(f"warning: {text}")

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield


def on_interrupt(explanation: str) -> Callable[[Callable[P, R]], Callable[P, R]]:
    """A command that prints ``interrupted: <explanation>`` and exits 130 on Ctrl-C."""

    def decorate(command: Callable[P, R]) -> Callable[P, R]:
        @functools.wraps(command)
        def wrapped(*args: P.args, **kwargs: P.kwargs) -> R:
            with interruptible(lambda: explanation):
                return command(*args, **kwargs)

        return wrapped

    return decorate


class StageLog:
    """The progress lines of a staged command, and what Ctrl-C leaves of its stages.

    Pass it as the ``report`` of :func:`bayesdoor.pipeline.run_job` or
    :func:`bayesdoor.pipeline.run_stage`: it follows which stages finished (computed or
    reused) and which one is running, and prints every line with ``echo``.
    """

    def __init__(self, out: Path, echo: Callable[[str], None], what: str = "job") -> None:
        self.out = out
        self.echo = echo
        self.what = what
        self.finished: list[str] = []
        self.running: str | None = None

    def __call__(self, text: str) -> None:
        name, _, status = text.partition(": ")
        if status.startswith(("done", "reused")):
            self.finished.append(name)
            self.running = None
        elif status.endswith("..."):
            self.running = name
        self.echo(text)

    def interrupted(self) -> str:
        """The line for Ctrl-C: the stage stopped, the stages kept, how to resume."""
        if self.running is not None:
            stopped = f"in its {self.running} stage"
        else:
            stopped = "between two stages" if self.finished else "before its first stage"
        if self.finished:
            kept = f"its finished stages ({', '.join(self.finished)}) are kept"
        else:
            kept = "no stage had finished"
        if self.running == "generate":
            kept += " with the training data chunks finished so far"
        return (
            f"the {self.what} in {self.out} was stopped {stopped}; {kept}, nothing "
            "half-written is left; run the same command again to resume from there"
        )


@contextlib.contextmanager
def writing(path: Path, option: str = "--out") -> Iterator[None]:
    """Write under ``path``: a failed write (no permission, a full disk) becomes a one-line exit,
    and a folder ``path`` created here is removed again when the command fails with it empty."""
    existed = path.exists()
    try:
        yield
    except BaseException as err:
        if not existed and path.is_dir() and not any(path.iterdir()):
            path.rmdir()
        if not isinstance(err, OSError) or err.errno not in _WRITE_ERRORS:
            raise
        raise fail(
            f"cannot write {err.filename or path}: {err.strerror}; pass a writable {option} "
            "with free space (files are written whole or not at all: nothing half-written is "
            "left)"
        ) from None


def system_named(campaign: xr.Dataset, name: str | None = None) -> AbstractSystem:
    """The system ``name`` (``--system``), else the one the campaign names in its ``system``
    attribute, found through the registry (:func:`bayesdoor.systems.get_system`), with the
    settings the campaign records for it (a bearing's geometry and sampling rate)."""
    from ..io import with_campaign_settings
    from ..systems import available_systems, get_system

    if "acceleration" not in campaign:
        where = campaign.encoding.get("source", "the file")
        raise fail(f"{where} has no 'acceleration' (run, channel, time) variable: not a campaign")
    if name is None:
        name = str(campaign.attrs.get("system", "")).strip()
        if not name:
            raise fail(
                "the campaign names no system (attrs['system'] is missing): pass --system "
                f"NAME, one of {', '.join(available_systems())}"
            )
    try:
        return with_campaign_settings(get_system(name), campaign)
    except (LookupError, ValueError) as err:
        raise fail(str(err)) from None


def check_for_job(
    campaign: xr.Dataset,
    system: AbstractSystem,
    source: str,
    fitted: Callable[[xr.Dataset, str], Iterable[int]],
) -> None:
    """Refuse a campaign a job cannot use, before it writes anything, in one line.

    Every problem of :func:`bayesdoor.io.validate_campaign` against the system's channels and
    sampling rate is fatal when it concerns the whole campaign or one of the runs the model is
    fitted on (``fitted(campaign, system.healthy)``, which raises ``ValueError`` when there
    are none); problems of other runs are left to the job, which reports them run by run.
    ``_TOLERATED`` lists the exceptions.
    """
    from ..io import validate_campaign

    problems = [
        p
        for p in validate_campaign(
            campaign,
            channels=list(system.channels),
            sampling_rate_hz=system.sampling_rate_hz,
        )
        if p.code not in _TOLERATED
    ]

    def refuse(found: list, what: str) -> None:
        if found:
            more = (
                f" (and {len(found) - 1} more: 'bayesdoor inspect' lists them)"
                if len(found) > 1
                else ""
            )
            raise fail(f"{source}: {what}: {found[0].message}{more}")

    refuse([p for p in problems if p.run is None], "not a usable campaign")
    try:
        runs = {int(r) for r in fitted(campaign, system.healthy)}
    except ValueError as err:
        raise fail(f"{source}: {err}") from None
    refuse([p for p in problems if p.run in runs], "a run the model is fitted on is unusable")
