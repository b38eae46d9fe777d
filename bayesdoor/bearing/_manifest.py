"""A folder of bearing records described as data: the manifest that :func:`read_records` reads.

A manifest (TOML) says which files are records, how a record's condition (state, defect size,
load) is read from its file name, where the signal and the shaft speed are in a file, the
signal's unit, the sampling rate, and the bearing's geometry: a bearing other than CWRU's
needs a manifest, not code. The CWRU records are one built-in manifest
(``manifests/cwru.toml``, :func:`builtin_manifest`). docs/bearing.md, "Importing records",
lists the keys.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
import string
import tomllib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any, NoReturn

from ..io import ACCELERATION_UNITS, CONVERTIBLE_UNITS
from ._geometry import CWRU_DRIVE_END, CWRU_FAN_END, INCH, BearingGeometry
from ._system import STATES, BearingSystem

#: the bearings a manifest may name by ``[geometry] known``
KNOWN_GEOMETRIES = {"cwru_drive_end": CWRU_DRIVE_END, "cwru_fan_end": CWRU_FAN_END}
#: the file formats a manifest reads: MATLAB files (scipy.io.loadmat), numpy archives and CSV
#: files with a header row; in each the signal and the speed are found by their variable's
#: (or column's) name
FORMATS = ("mat", "npz", "csv")
#: the system whose records a manifest of this reader describes
SYSTEM = "bearing"


class ManifestError(ValueError):
    """A manifest that cannot be used: the message names the file, the key and what was
    expected."""


@dataclasses.dataclass(frozen=True)
class Manifest:
    """A folder of records as a manifest describes it (:func:`read_manifest`).

    Attributes
    ----------
    name
        The importer's name in a campaign's summary (``name``; default the file's stem).
    source
        Where the manifest was read from.
    glob
        The records below the folder (``[files] glob``).
    format
        ``mat``, ``npz`` or ``csv`` (``[files] format``; default the glob's suffix).
    names
        The patterns a file name (without its suffix) is read with, the first that matches
        (``[files] name``): groups ``state``, and ``size`` and ``load`` where given.
    expected_name
        What a name should look like, in words, for errors (``[files] expected``).
    unsupported
        Names that are refused, each with its reason (``[[files.unsupported]]``).
    states
        The system's state of each ``state`` code (``[states]``).
    signal_key
        The variable (column) that holds the samples (``[signal] key``).
    expected_key
        The variable in words, for errors (``[signal] expected``).
    scale
        m/s^2 per stored unit (``[signal] unit`` or ``scale``).
    rate_hz
        The records' sampling rate, Hz (``[sampling_rate] hz``), or ``None``.
    candidate_rates_hz
        The rates a record's spectrum chooses among (``[sampling_rate] candidates_hz``).
    rate_folder
        A folder name that states its files' rate, group ``khz`` (``[sampling_rate] folder``).
    campaign_rate_hz
        The campaign's rate (``[sampling_rate] campaign_hz``); records at another are resampled.
    rpm_key
        The variable that holds the shaft speed, rpm (``[shaft_speed] key``).
    expected_rpm_key
        The variable in words, for errors (``[shaft_speed] expected``).
    rpm_at_load
        The shaft speed (rpm) at each load (hp) (``[shaft_speed] at_load``).
    rpm
        One shaft speed for every record, rpm (``[shaft_speed] rpm``).
    load_hp
        One load for every record, hp (``[load] hp``); else the name's ``load`` group.
    inch_per_size_unit
        Inches per unit of the name's ``size`` group (``[fault_size] inch_per_unit``).
    segment_s, calibration_fraction
        Run length, s, and the share of each healthy record's runs in ``calibration``
        (``[runs]``).
    geometry
        The bearing (``[geometry]``).
    """

    name: str
    source: str
    glob: str
    format: str
    names: tuple[re.Pattern[str], ...]
    expected_name: str
    unsupported: tuple[tuple[re.Pattern[str], str], ...]
    states: Mapping[str, str]
    signal_key: re.Pattern[str]
    expected_key: str
    scale: float
    rate_hz: float | None
    candidate_rates_hz: tuple[float, ...]
    rate_folder: re.Pattern[str] | None
    campaign_rate_hz: float
    rpm_key: re.Pattern[str] | None
    expected_rpm_key: str
    rpm_at_load: Mapping[float, float]
    rpm: float | None
    load_hp: int | float | None
    inch_per_size_unit: float
    segment_s: float
    calibration_fraction: float
    geometry: BearingGeometry

    def system(self) -> BearingSystem:
        """The bearing of these records: its geometry, at the campaign's rate."""
        return BearingSystem(geometry=self.geometry, sampling_rate_hz=self.campaign_rate_hz)


@functools.cache
def builtin_manifest(name: str) -> Manifest:
    """The manifest shipped with bayesdoor under ``name`` (``cwru``).

    Raises
    ------
    ManifestError
        For a name without a shipped manifest; the message lists those shipped.
    """
    folder = resources.files(__package__).joinpath("manifests")
    shipped = sorted(p.name[: -len(".toml")] for p in folder.iterdir() if p.name.endswith(".toml"))
    if name not in shipped:
        raise ManifestError(f"no built-in manifest {name!r}: shipped {', '.join(shipped)}")
    text = folder.joinpath(f"{name}.toml").read_text(encoding="utf-8")
    return parse_manifest(text, source=f"the built-in manifest {name!r}", default_name=name)


def read_manifest(path: str | Path) -> Manifest:
    """Read and check a manifest file (TOML; the keys: docs/bearing.md, "Importing records").

    Raises
    ------
    FileNotFoundError
        When there is no file at ``path``.
    ManifestError
        For a file that is not TOML, or a key that is missing, unknown or holds a value of
        the wrong kind: the message names the key and what was expected.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such manifest file")
    return parse_manifest(
        path.read_text(encoding="utf-8"), source=str(path), default_name=path.stem
    )


def parse_manifest(
    text: str, *, source: str = "the manifest", default_name: str = "manifest"
) -> Manifest:
    """The manifest of TOML ``text`` (see :func:`read_manifest`); ``source`` names it in
    errors."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ManifestError(f"{source}: not TOML ({err})") from None
    top = _Table(data, "", source)
    name = top.take("name", str, "a name for the importer", default=default_name)
    system = top.take("system", str, f"the system's name, {SYSTEM!r}")
    if system != SYSTEM:
        top.fail("system", f"{SYSTEM!r} (this reader reads bearing records)", system)
    required = ("files", "states", "signal", "sampling_rate", "shaft_speed", "geometry")
    missing = [f"[{key}]" for key in required if key not in data]
    tables = {key: top.table(key) for key in (*required, "fault_size", "load", "runs")}
    top.done()
    if missing:
        needed = ", ".join(f"[{key}]" for key in required)
        raise ManifestError(
            f"{source}: no {' and no '.join(missing)} table (a manifest needs {needed})"
        )
    files = _files(tables["files"])
    geometry = _geometry(tables["geometry"])
    return Manifest(
        name=name,
        source=source,
        **files,
        states=_states(tables["states"]),
        inch_per_size_unit=_one_number(
            tables["fault_size"], "inch_per_unit", "inches per unit of the name's size", 1.0
        ),
        **_signal(tables["signal"]),
        **_rate(tables["sampling_rate"], geometry),
        **_speed(tables["shaft_speed"]),
        load_hp=_load(tables["load"], files["names"]),
        **_runs(tables["runs"]),
        geometry=geometry,
    )


def _files(files: _Table) -> dict[str, Any]:
    glob = files.take("glob", str, "a glob pattern below the folder, such as '**/*.mat'")
    suffix = Path(glob).suffix.lower().lstrip(".")
    fmt = files.take(
        "format", str, f"one of {', '.join(FORMATS)}", default=suffix if suffix in FORMATS else None
    )
    if fmt not in FORMATS:
        files.fail("format", f"one of {', '.join(FORMATS)} (the glob's suffix names none)", fmt)
    patterns = files.take("name", (str, list), "a regular expression or a list of them")
    patterns = [patterns] if isinstance(patterns, str) else patterns
    if not patterns:
        files.fail("name", "at least one regular expression", patterns)
    names = tuple(files.pattern(f"name[{i}]", p) for i, p in enumerate(patterns))
    for i, p in enumerate(names):
        if "state" not in p.groupindex:
            files.fail(f"name[{i}]", "a pattern with a (?P<state>...) group", p.pattern)
    expected = files.take(
        "expected", str, "the names in words", default=" or ".join(p.pattern for p in names)
    )
    entries = files.take("unsupported", list, "a list of tables", default=[])
    unsupported = tuple(_unsupported(files, i, entry) for i, entry in enumerate(entries))
    files.done()
    return {
        "glob": glob,
        "format": fmt,
        "names": names,
        "expected_name": expected,
        "unsupported": unsupported,
    }


def _states(states: _Table) -> dict[str, str]:
    allowed = f"a state of {SYSTEM}: {', '.join(STATES)}"
    codes = {code: states.take(code, str, allowed) for code in list(states.data)}
    for code, state in codes.items():
        if state not in STATES:
            states.fail(code, allowed, state)
    if not codes:
        states.need('the state of each code of the names, such as OR = "outer_race"')
    return codes


def _signal(signal: _Table) -> dict[str, Any]:
    key = signal.pattern("key", signal.take("key", str, "a regular expression"))
    expected = signal.take("expected", str, "the variable in words", default=key.pattern)
    units = [*ACCELERATION_UNITS, *CONVERTIBLE_UNITS]
    unit = signal.take("unit", str, f"one of {', '.join(units)}", default=None)
    scale = signal.take("scale", (int, float), "m/s^2 per stored unit", default=None)
    if (unit is None) == (scale is None):
        signal.need(f"one of unit ({', '.join(units)}) and scale (m/s^2 per stored unit)")
    if scale is not None:
        scale = _positive(signal, "scale", scale)
    elif unit in ACCELERATION_UNITS:
        scale = 1.0
    elif unit in CONVERTIBLE_UNITS:
        scale = CONVERTIBLE_UNITS[unit]
    else:
        signal.fail("unit", f"one of {', '.join(units)}", unit)
    signal.done()
    return {"signal_key": key, "expected_key": expected, "scale": scale}


def _rate(rate: _Table, geometry: BearingGeometry) -> dict[str, Any]:
    hz = rate.take("hz", (int, float), "the sampling rate, Hz", default=None)
    candidates = rate.take("candidates_hz", list, "a list of sampling rates, Hz", default=None)
    if (hz is None) == (candidates is None):
        rate.need("one of hz (the records' rate) and candidates_hz (rates to settle among)")
    if hz is not None:
        hz = _positive(rate, "hz", hz)
        candidates = []
    else:
        candidates = [_positive(rate, "candidates_hz", c) for c in candidates]
        if len(set(candidates)) < 2:
            rate.fail("candidates_hz", "two or more different rates", candidates)
    text = rate.take("folder", str, "a regular expression with a (?P<khz>...) group", default=None)
    folder = None if text is None else rate.pattern("folder", text)
    if folder is not None and "khz" not in folder.groupindex:
        rate.fail("folder", "a pattern with a (?P<khz>...) group", text)
    if folder is not None and hz is not None:
        rate.fail(
            "folder", "no folder rule with hz (it checks rates settled among candidates)", text
        )
    campaign = rate.take(
        "campaign_hz",
        (int, float),
        "the campaign's sampling rate, Hz",
        default=hz if hz is not None else min(candidates),
    )
    campaign = _positive(rate, "campaign_hz", campaign)
    rate.done()
    try:
        BearingSystem(geometry=geometry, sampling_rate_hz=campaign)
    except ValueError as err:
        rate.fail("campaign_hz", f"a rate the bearing model takes ({err})", campaign)
    return {
        "rate_hz": hz,
        "candidate_rates_hz": tuple(candidates),
        "rate_folder": folder,
        "campaign_rate_hz": campaign,
    }


def _speed(speed: _Table) -> dict[str, Any]:
    text = speed.take("key", str, "a regular expression", default=None)
    key = None if text is None else speed.pattern("key", text)
    expected = speed.take("expected", str, "the variable in words", default=text or "")
    at_load = {}
    for load, rpm in speed.take("at_load", dict, "a table of load (hp) = rpm", default={}).items():
        try:
            hp = float(load)
        except ValueError:
            speed.fail("at_load", "loads (hp) as keys", load)
        at_load[hp] = _positive(speed, f"at_load.{load}", rpm)
    rpm = speed.take("rpm", (int, float), "the shaft speed, rpm", default=None)
    rpm = None if rpm is None else _positive(speed, "rpm", rpm)
    if key is None and not at_load and rpm is None:
        speed.need("key (the file's variable), at_load (rpm at each load) or rpm (one speed)")
    speed.done()
    return {"rpm_key": key, "expected_rpm_key": expected, "rpm_at_load": at_load, "rpm": rpm}


def _load(load: _Table, names: tuple[re.Pattern[str], ...]) -> int | float | None:
    hp = load.take("hp", (int, float), "the load of every record, hp", default=None)
    load.done()
    if hp is None:
        for i, p in enumerate(names):
            if "load" not in p.groupindex:
                load.need(f"hp (the load), since [files] name[{i}] has no (?P<load>...) group")
    return hp


def _runs(runs: _Table) -> dict[str, Any]:
    segment_s = runs.take("segment_s", (int, float), "the run length, s", default=1.0)
    segment_s = _positive(runs, "segment_s", segment_s)
    fraction = runs.take("calibration_fraction", (int, float), "a number in (0, 1)", default=0.5)
    if isinstance(fraction, bool) or not 0 < fraction < 1:
        runs.fail("calibration_fraction", "a number in (0, 1)", fraction)
    runs.done()
    return {"segment_s": segment_s, "calibration_fraction": float(fraction)}


def _one_number(table: _Table, key: str, expected: str, default: float) -> float:
    value = _positive(table, key, table.take(key, (int, float), expected, default=default))
    table.done()
    return value


_REQUIRED = object()


class _Table:
    """One table of a manifest: its keys taken one at a time, any left over refused."""

    def __init__(self, data: dict, where: str, source: str) -> None:
        self.data = dict(data)
        self.where = where
        self.source = source
        self.allowed: list[str] = []

    def _key(self, key: str) -> str:
        return f"[{self.where}] {key}" if self.where else key

    def fail(self, key: str, expected: str, got: Any) -> NoReturn:
        raise ManifestError(f"{self.source}: {self._key(key)}: expected {expected}, got {got!r}")

    def need(self, what: str) -> NoReturn:
        where = f"[{self.where}]" if self.where else "the manifest"
        raise ManifestError(f"{self.source}: {where} needs {what}")

    def take(self, key: str, kind, expected: str, *, default: Any = _REQUIRED) -> Any:
        self.allowed.append(key)
        if key not in self.data:
            if default is _REQUIRED:
                raise ManifestError(f"{self.source}: {self._key(key)} is missing: {expected}")
            return default
        value = self.data.pop(key)
        kinds = kind if isinstance(kind, tuple) else (kind,)
        if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
            self.fail(key, expected, value)
        return value

    def table(self, key: str) -> _Table:
        name = key if not self.where else f"{self.where}.{key}"
        return _Table(self.take(key, dict, "a table", default={}), name, self.source)

    def pattern(self, key: str, text: Any) -> re.Pattern[str]:
        if not isinstance(text, str):
            self.fail(key, "a regular expression (a string)", text)
        try:
            return re.compile(text)
        except re.error as err:
            self.fail(key, f"a regular expression ({err})", text)

    def done(self) -> None:
        if self.data:
            unknown = ", ".join(sorted(self.data))
            where = f"[{self.where}]" if self.where else "the top level"
            raise ManifestError(
                f"{self.source}: unknown key(s) {unknown} in {where}: allowed "
                f"{', '.join(self.allowed)}"
            )


def _positive(table: _Table, key: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        table.fail(key, "a positive number", value)
    if not (math.isfinite(value) and value > 0):
        table.fail(key, "a positive number", value)
    return float(value)


def _unsupported(files: _Table, i: int, entry) -> tuple[re.Pattern[str], str]:
    if not isinstance(entry, dict):
        files.fail(f"unsupported[{i}]", "a table with name and reason", entry)
    table = _Table(entry, f"files.unsupported[{i}]", files.source)
    pattern = table.pattern("name", table.take("name", str, "a regular expression"))
    reason = table.take("reason", str, "why such a record is refused")
    table.done()
    fields = {f for _, f, _, _ in string.Formatter().parse(reason) if f is not None}
    missing = sorted(fields - set(pattern.groupindex))
    if missing:
        groups = ", ".join(pattern.groupindex) or "none"
        table.fail("reason", f"fields {{...}} among the name's groups ({groups})", reason)
    return pattern, reason


def _geometry(table: _Table) -> BearingGeometry:
    known = table.take("known", str, f"one of {', '.join(KNOWN_GEOMETRIES)}", default=None)
    if known is not None:
        table.done()
        if known not in KNOWN_GEOMETRIES:
            table.fail("known", f"one of {', '.join(KNOWN_GEOMETRIES)}", known)
        return KNOWN_GEOMETRIES[known]
    values: dict[str, Any] = {
        "n_balls": table.take("n_balls", int, "the number of rolling elements"),
        "contact_angle_deg": table.take("contact_angle_deg", (int, float), "degrees", default=0.0),
        "designation": table.take("designation", str, "a name for the bearing", default=""),
    }
    for what in ("ball_diameter", "pitch_diameter"):
        inch = table.take(f"{what}_in", (int, float), "inches", default=None)
        mm = table.take(f"{what}_mm", (int, float), "millimetres", default=None)
        if (inch is None) == (mm is None):
            table.need(f"one of {what}_in and {what}_mm (or known, a known bearing)")
        values[f"{what}_in"] = float(inch) if inch is not None else mm / (INCH * 1000.0)
    table.done()
    try:
        return BearingGeometry(**values)
    except ValueError as err:
        raise ManifestError(f"{table.source}: [geometry]: {err}") from None
