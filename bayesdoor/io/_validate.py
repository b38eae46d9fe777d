"""Checks of a campaign dataset against the format of ``docs/data.md``, one message each."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import xarray as xr

from ..systems import AbstractSystem, ConditionSpec, available_systems
from ._format import (
    ACCELERATION_UNITS,
    CONVERTIBLE_UNITS,
    SPLIT_LABELS,
    state_labels,
    system_of,
)

#: how far (in sample periods) a time may lie off the uniform grid of the sampling rate
_GRID_TOLERANCE = 0.01


@dataclasses.dataclass(frozen=True)
class Problem:
    """One thing wrong with a campaign.

    Attributes
    ----------
    code
        What kind of problem, a stable name (see :func:`validate_campaign`).
    message
        What was found, where, and what to do about it.
    run
        The run index (position along ``run``) the problem concerns, if one.
    channel
        The channel the problem concerns, if one.
    """

    code: str
    message: str
    run: int | None = None
    channel: str | None = None

    def __str__(self) -> str:
        return self.message


class CampaignError(ValueError):
    """A campaign that breaks the format; ``problems`` lists every problem found.

    Parameters
    ----------
    problems
        The problems, as :func:`validate_campaign` returns them.
    source
        Where the campaign came from (a file), named in the message.
    """

    def __init__(self, problems: Sequence[Problem], source: str | None = None):
        self.problems = list(problems)
        self.source = source
        where = f"campaign {source}" if source else "campaign"
        if len(self.problems) == 1:
            text = f"{where}: {self.problems[0].message}"
        else:
            lines = "\n".join(f"  - {p.message}" for p in self.problems)
            text = f"{where} has {len(self.problems)} problems:\n{lines}"
        super().__init__(text)


def _units_problems(ds: xr.Dataset) -> list[Problem]:
    problems = []
    for where, attrs in (("acceleration.attrs", ds["acceleration"].attrs), ("attrs", ds.attrs)):
        units = attrs.get("units")
        if units is None:
            problems.append(
                Problem(
                    "missing_units",
                    f"{where}['units'] is missing; set it to 'm/s^2' (samples must be in m/s^2)",
                )
            )
        elif str(units).strip() not in ACCELERATION_UNITS:
            factor = CONVERTIBLE_UNITS.get(str(units).strip())
            fix = (
                f"convert the samples to m/s^2 by multiplying by {factor} and set units to 'm/s^2'"
                if factor is not None
                else f"convert the samples to m/s^2 (accepted spellings: {ACCELERATION_UNITS})"
            )
            problems.append(Problem("wrong_units", f"{where}['units'] is {units!r}: {fix}"))
    return problems


def _channel_problems(ds: xr.Dataset, expected: Sequence[str] | None) -> list[Problem]:
    if "channel" not in ds.coords:
        return [
            Problem(
                "missing_channels",
                "the channel coordinate is missing: name the channels (e.g. A1X, A1Z, A2X, A2Z)",
            )
        ]
    found = [str(c) for c in ds["channel"].values]
    problems = []
    duplicated = sorted({c for c in found if found.count(c) > 1})
    if duplicated:
        problems.append(
            Problem("duplicate_channels", f"channels {duplicated} appear more than once")
        )
    if expected is not None:
        missing = [c for c in expected if c not in found]
        unknown = [c for c in found if c not in expected]
        if missing:
            problems.append(
                Problem(
                    "missing_channels",
                    f"channels {missing} are missing: found {found}, expected {list(expected)}",
                )
            )
        if unknown:
            problems.append(
                Problem(
                    "unknown_channels",
                    f"channels {unknown} are not expected: found {found}, expected "
                    f"{list(expected)}; rename or drop them",
                )
            )
    return problems


def _time_problems(
    ds: xr.Dataset, expected_fs: float | None, min_samples: int, nperseg: int
) -> tuple[list[Problem], float | None]:
    """Time, sampling rate and length; also returns the usable sampling rate, if any."""
    problems = []
    n = ds.sizes["time"]
    attr = ds.attrs.get("sampling_rate_hz")
    fs: float | None
    try:
        fs = float(attr)  # type: ignore[arg-type]
        if not (np.isfinite(fs) and fs > 0):
            raise ValueError
    except (TypeError, ValueError):
        got = "missing" if attr is None else f"{attr!r}, not a positive number"
        problems.append(
            Problem(
                "missing_sampling_rate",
                f"attrs['sampling_rate_hz'] is {got}: set it to the sampling rate in Hz",
            )
        )
        fs = None
    # 1e-6: time stamps rounded to microseconds and divided out stay within it
    if expected_fs is not None and fs is not None and abs(fs / expected_fs - 1.0) > 1e-6:
        problems.append(
            Problem(
                "unexpected_sampling_rate",
                f"sampling_rate_hz is {fs:.7g} Hz but {expected_fs:.7g} Hz is expected: "
                f"resample the records to {expected_fs:.7g} Hz",
            )
        )
    if n < min_samples:
        duration = f" ({n / fs:.4g} s at {fs:g} Hz)" if fs else ""
        problems.append(
            Problem(
                "too_short",
                f"the records have {n} samples{duration}, fewer than the {min_samples} the "
                f"spectral analysis needs (Welch segments of nperseg={nperseg} samples)",
            )
        )
    if "time" not in ds.coords:
        problems.append(Problem("missing_time", "the time coordinate (seconds) is missing"))
        return problems, fs
    t = np.asarray(ds["time"].values, dtype=float)
    steps = np.diff(t)
    bad = np.flatnonzero(~(steps > 0))
    if bad.size:
        i = int(bad[0]) + 1
        problems.append(
            Problem(
                "non_monotonic_time",
                f"time is not strictly increasing: {bad.size} step(s) go backwards, repeat or "
                f"are not finite, the first at index {i} (time[{i - 1}] = {float(t[i - 1])!r} s, "
                f"time[{i}] = {float(t[i])!r} s)",
            )
        )
    elif fs is not None and n >= 2:
        deviation = np.abs((t - t[0]) * fs - np.arange(n))
        worst = int(np.argmax(deviation))
        if deviation[worst] > _GRID_TOLERANCE:
            fs_time = 1.0 / float(np.median(steps))
            if abs(fs_time / fs - 1.0) > 1e-6:
                message = (
                    f"sampling_rate_hz is {fs:g} Hz but the time coordinate is spaced for "
                    f"{fs_time:.6g} Hz (median step {np.median(steps):.6g} s): fix the attribute "
                    "or the time coordinate"
                )
            else:
                message = (
                    f"the time coordinate is not uniform at {fs:g} Hz: time[{worst}] = "
                    f"{float(t[worst])!r} s lies {deviation[worst]:.3g} sample periods off the "
                    "grid (dropped or repeated samples?)"
                )
            problems.append(Problem("sampling_rate_mismatch", message))
            fs = None
    return problems, fs


def _sample_problems(ds: xr.Dataset, clip_run: int, clip_fraction: float) -> list[Problem]:
    """Non-finite, flat and clipped records, one problem per (run, channel)."""
    problems = []
    acc = np.asarray(ds["acceleration"].transpose("run", "channel", "time").values, dtype=float)
    channels = (
        [str(c) for c in ds["channel"].values]
        if "channel" in ds.coords
        else [str(i) for i in range(acc.shape[1])]
    )
    n = acc.shape[2]
    nan = np.isnan(acc).sum(axis=2)
    inf = np.isinf(acc).sum(axis=2)
    for r, c in zip(*np.nonzero(nan + inf), strict=True):
        problems.append(
            Problem(
                "non_finite",
                f"run {r}, channel {channels[c]}: {nan[r, c]} NaN and {inf[r, c]} Inf samples of "
                f"{n}; drop or repair the run",
                int(r),
                channels[c],
            )
        )
    finite = np.where(np.isfinite(acc), acc, 0.0)
    peak = np.abs(finite).max(axis=2)
    flat = (finite.max(axis=2) == finite.min(axis=2)) & (nan + inf == 0)
    for r, c in zip(*np.nonzero(flat), strict=True):
        problems.append(
            Problem(
                "flat",
                f"run {r}, channel {channels[c]}: all {n} samples equal "
                f"{float(finite[r, c, 0])!r}: (a) a dead or disconnected sensor, (b) a channel "
                "left unfilled",
                int(r),
                channels[c],
            )
        )
    at_peak = (np.abs(finite) == peak[..., None]) & (peak[..., None] > 0) & ~flat[..., None]
    counts = at_peak.sum(axis=2)
    for r, c in zip(*np.nonzero(counts >= clip_run), strict=True):
        # longest stretch of consecutive samples at +-peak
        edges = np.diff(np.concatenate([[0], at_peak[r, c].astype(np.int8), [0]]))
        longest = int(np.max(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)))
        if longest >= clip_run or counts[r, c] >= clip_fraction * n:
            problems.append(
                Problem(
                    "clipped",
                    f"run {r}, channel {channels[c]}: {counts[r, c]} samples sit at exactly "
                    f"+-{float(peak[r, c])!r} m/s^2 (longest stretch {longest} samples), a "
                    "saturated sensor or acquisition range: re-measure with a larger range or "
                    "drop the run",
                    int(r),
                    channels[c],
                )
            )
    return problems


def _per_run(ds: xr.Dataset, name: str, runs: int) -> tuple[np.ndarray | None, Problem | None]:
    if name not in ds.coords and name not in ds.data_vars:
        return None, None
    var = ds[name]
    if var.dims != ("run",):
        return None, Problem(
            f"bad_{name}",
            f"{name} must have one value per run (dims ('run',), {runs} values), got dims "
            f"{var.dims}",
        )
    return np.asarray(var.values), None


def _label_problems(labels, name: str, allowed) -> list[Problem]:
    """One ``unknown_<name>`` problem per run whose label is not in ``allowed``."""
    return [
        Problem(f"unknown_{name}", f"run {r}: {name} {str(s)!r} is not one of {allowed}", r)
        for r, s in enumerate(labels)
        if str(s) not in allowed
    ]


def _condition_problems(ds: xr.Dataset, spec: ConditionSpec, runs: int) -> list[Problem]:
    """``missing_<name>`` (absent or not finite) and ``bad_<name>`` (not positive, where the
    condition must be) for one of the system's operating conditions."""
    name, unit = spec.name, f" {spec.unit}" if spec.unit and spec.unit != "-" else ""
    what = f"{name} ({spec.description}{',' if spec.description else ''}{unit or ' -'})"
    values, problem = _per_run(ds, name, runs)
    if problem is not None:
        return [problem]
    if values is None:
        return [Problem(f"missing_{name}", f"the per-run coordinate {what} is missing")]
    v = np.asarray(values, dtype=float)
    problems = []
    missing = np.flatnonzero(~np.isfinite(v))
    if missing.size:
        problems.append(
            Problem(
                f"missing_{name}",
                f"{name} is missing (not finite) for runs {missing.tolist()}: give the "
                f"{what} of every run",
                int(missing[0]),
            )
        )
    for bad in np.flatnonzero(np.isfinite(v) & (v <= 0)) if spec.positive else ():
        problems.append(
            Problem(
                f"bad_{name}",
                f"run {bad}: {name} = {float(v[bad])!r}{unit} must be positive",
                int(bad),
            )
        )
    return problems


def _run_problems(
    ds: xr.Dataset, system: AbstractSystem | None, fs: float | None, nperseg: int
) -> list[Problem]:
    runs = ds.sizes["run"]
    problems: list[Problem] = []
    values = {}
    for name in ("state", "split", "t_start", "t_stop"):
        values[name], problem = _per_run(ds, name, runs)
        problems += [problem] if problem else []
    allowed = None if system is None else state_labels(system)
    if values["state"] is None and "state" not in ds:
        problems.append(
            Problem(
                "missing_state",
                "the per-run coordinate state is missing: label each run with its state"
                + ("" if allowed is None else f", one of {allowed}"),
            )
        )
    elif values["state"] is not None and allowed is not None:
        problems += _label_problems(values["state"], "state", allowed)
    for spec in () if system is None else system.conditions:
        problems += _condition_problems(ds, spec, runs)
    if values["split"] is not None:
        problems += _label_problems(values["split"], "split", SPLIT_LABELS)
    problems += _window_problems(ds, values["t_start"], values["t_stop"], fs, nperseg)
    return problems


def _window_problems(ds, t_start, t_stop, fs, nperseg) -> list[Problem]:
    if t_start is None or t_stop is None:
        return []
    problems = []
    t = np.asarray(ds["time"].values, dtype=float) if "time" in ds.coords else None
    for r, (a, b) in enumerate(zip(t_start.astype(float), t_stop.astype(float), strict=True)):
        if not (np.isfinite(a) and np.isfinite(b) and a < b):
            problems.append(
                Problem(
                    "bad_motion_window",
                    f"run {r}: t_start = {float(a)!r} s, t_stop = {float(b)!r} s must be "
                    "finite with t_start < t_stop",
                    r,
                )
            )
        elif t is not None and t.size and (a < t[0] or b > t[-1]):
            problems.append(
                Problem(
                    "bad_motion_window",
                    f"run {r}: the motion window [{float(a)!r}, {float(b)!r}] s reaches "
                    f"outside the record [{float(t[0])!r}, {float(t[-1])!r}] s",
                    r,
                )
            )
        elif fs is not None and (b - a) * fs + 1 < nperseg:
            problems.append(
                Problem(
                    "window_too_short",
                    f"run {r}: the motion window [{float(a)!r}, {float(b)!r}] s spans about "
                    f"{int((b - a) * fs) + 1} samples, fewer than one Welch segment "
                    f"(nperseg={nperseg}); a PSD of the motion window needs at least "
                    f"{nperseg / fs:.4g} s",
                    r,
                )
            )
    return problems


def validate_campaign(
    ds: xr.Dataset,
    *,
    channels: Sequence[str] | None = None,
    sampling_rate_hz: float | None = None,
    system: AbstractSystem | None = None,
    nperseg: int = 512,
    min_duration_s: float | None = None,
    clip_run: int = 5,
    clip_fraction: float = 0.02,
) -> list[Problem]:
    """Every way ``ds`` breaks the campaign format (``docs/data.md``); empty when valid.

    Each problem names the run index and channel it concerns and the value found. Codes:

    ``no_acceleration`` (no ``acceleration`` variable with dims (run, channel, time); nothing
    else is checked then), ``no_runs`` (an empty run dimension; nothing else is checked then),
    ``missing_channels``, ``unknown_channels``, ``duplicate_channels``,
    ``missing_units``, ``wrong_units`` (``g`` and ``mg`` name the factor to m/s^2),
    ``missing_sampling_rate``, ``sampling_rate_mismatch`` (the attribute against the time
    coordinate, whose samples must lie within 0.01 sample periods of a uniform grid),
    ``unexpected_sampling_rate``, ``missing_time``, ``non_monotonic_time``, ``too_short``,
    ``non_finite``, ``flat`` (every sample of a record equal: a dead sensor), ``clipped``,
    ``missing_state``, ``unknown_state`` (not one of the system's states or ``unknown``),
    ``missing_<condition>`` (one of the system's operating conditions absent or not finite,
    e.g. the door's ``missing_v_max``), ``bad_<condition>`` (not positive where it must be),
    ``unknown_split``, ``bad_motion_window``,
    ``window_too_short``, ``missing_system``, ``bad_system_settings`` (``system_settings``
    that are not JSON or that the system refuses), and ``bad_<name>`` for a per-run
    coordinate without dims ``('run',)``.

    The clipping rule: a record is clipped when the samples at exactly its largest absolute
    value (either sign) form a stretch of at least ``clip_run`` consecutive samples, or number
    at least ``clip_fraction`` of the record (and at least ``clip_run``). A continuous signal
    reaches its peak at a single sample; a quantised one repeats its peak level at a few
    isolated samples (a full-scale 12-bit sine of 4 Hz or more: at most 4 in a row and 1.6 %
    of its samples); a saturated sensor sits on its rail. Not caught: clipping at a rail
    below the opposite peak. Falsely caught: a slow, noise-free signal quantised so coarsely
    that its peak level lasts ``clip_run`` samples (raise ``clip_run`` for such data).

    Parameters
    ----------
    ds
        The campaign.
    channels
        The channels expected (e.g. ``["A1X", "A1Z", "A2X", "A2Z"]``); ``None`` accepts any.
    sampling_rate_hz
        The sampling rate expected; ``None`` accepts any (consistent with the time axis).
    system
        The system whose states and operating conditions the runs must carry; ``None``
        takes the registered system the campaign names in ``attrs['system']``, and checks
        neither for a system that is not registered.
    nperseg
        The Welch segment length the records must hold at least (also per motion window).
    min_duration_s
        A minimum record length in seconds, when longer than ``nperseg`` samples.
    clip_run, clip_fraction
        The thresholds of the clipping rule.

    Returns
    -------
    problems
        In the order of the checks above; an empty list for a valid campaign.
    """
    fatal = _fatal_problems(ds)
    if fatal:
        return fatal
    problems = _channel_problems(ds, channels)
    problems += _units_problems(ds)
    min_samples = _min_samples(ds, nperseg, min_duration_s)
    time_problems, fs = _time_problems(ds, sampling_rate_hz, min_samples, nperseg)
    problems += time_problems
    problems += _sample_problems(ds, clip_run, clip_fraction)
    if system is None:
        system, settings_problems = _named_system(ds)
        problems += settings_problems
    problems += _run_problems(ds, system, fs, nperseg)
    if not str(ds.attrs.get("system", "")).strip():
        problems.append(_missing_system())
    return problems


def _fatal_problems(ds: xr.Dataset) -> list[Problem]:
    """``no_acceleration`` or ``no_runs``, after which nothing else is checked; else none."""
    var = ds.get("acceleration")
    if var is None or set(var.dims) != {"run", "channel", "time"}:
        found = "no acceleration variable" if var is None else f"dims {var.dims}"
        return [
            Problem(
                "no_acceleration",
                f"a campaign needs a variable 'acceleration' with dims (run, channel, time); "
                f"found {found} (variables: {sorted(map(str, ds.data_vars))})",
            )
        ]
    if ds.sizes["run"] == 0:
        return [
            Problem(
                "no_runs",
                "the campaign holds no runs (the run dimension is empty): record runs, or "
                "check the selection that produced the file",
            )
        ]
    return []


def _min_samples(ds: xr.Dataset, nperseg: int, min_duration_s: float | None) -> int:
    """The samples a record must hold: ``nperseg``, or ``min_duration_s`` at the campaign's
    sampling rate when that is more."""
    fs_attr = ds.attrs.get("sampling_rate_hz")
    if min_duration_s is not None and isinstance(fs_attr, int | float | np.number):
        return max(nperseg, int(np.ceil(min_duration_s * float(fs_attr))))
    return nperseg


def _named_system(ds: xr.Dataset) -> tuple[AbstractSystem | None, list[Problem]]:
    """The registered system the campaign names, or ``bad_system_settings`` when its
    settings do not build it."""
    try:
        return system_of(ds), []
    except ValueError as err:
        return None, [Problem("bad_system_settings", str(err))]


def _missing_system() -> Problem:
    return Problem(
        "missing_system",
        "attrs['system'] is missing: name the system (one of "
        f"{', '.join(available_systems()) or 'the registered systems'})",
    )


def check_campaign(ds: xr.Dataset, *, source: str | None = None, **options) -> None:
    """Raise :class:`CampaignError` listing every problem :func:`validate_campaign` finds.

    Parameters
    ----------
    ds
        The campaign.
    source
        Where it came from (a file name), for the message.
    **options
        The keyword arguments of :func:`validate_campaign`.

    Raises
    ------
    CampaignError
        If there is any problem.
    """
    problems = validate_campaign(ds, **options)
    if problems:
        raise CampaignError(problems, source)
