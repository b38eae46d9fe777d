"""The CWRU bearing records (``.mat``) as a campaign of the ``bearing`` system.

A record is one ``.mat`` file named after its condition: ``Normal_<L>`` (healthy),
``IR<sss>_<L>`` (inner race), ``OR<sss>@6_<L>`` (outer race at 6 o'clock), ``B<sss>_<L>``
(ball), with the defect's diameter ``0.<sss>`` inch and the motor load ``L`` hp. It holds
``X<nnn>_DE_time`` (drive-end accelerometer, g), usually ``X<nnn>_FE_time`` and
``X<nnn>_BA_time``, and ``X<nnn>RPM``. Each record is cut into non-overlapping segments, one run
each, of the drive-end channel in m/s^2.

The sampling rate of every record is read from its own spectrum (:func:`settle_sampling_rate`):
the rate that puts the strongest lines at the shaft's 1x, 2x and 3x (from the record's rpm).
A record sampled at 48 kHz is decimated to the campaign's 12 kHz.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import scipy.io
from scipy import signal

from ..io import make_campaign, save_campaign
from ._stand import FS

#: standard gravity, m/s^2 per g
G = 9.80665
#: the sampling rates a CWRU record may have been taken at, Hz
CANDIDATE_RATES_HZ = (12000.0, 48000.0)
#: the shaft speed (rpm) at each motor load (hp) of the stand, where a record lacks its rpm
NOMINAL_RPM = {0: 1797.0, 1: 1772.0, 2: 1750.0, 3: 1730.0}
#: the state of each defect code in a record's name
FAULT_CODES = {"IR": "inner_race", "OR": "outer_race", "B": "ball"}

_NAME = re.compile(
    r"^(?:Normal|(?P<code>IR|OR|B)(?P<size>\d{3})(?P<clock>@\d{1,2})?)_(?P<load>\d)$"
)
_KEY = re.compile(r"^X(?P<prefix>\d+)(?:_(?P<channel>DE|FE|BA)_time|(?P<rpm>RPM))$")
_STATED_RATE = re.compile(r"^(?P<khz>12|48)k(?:_|$)", re.IGNORECASE)


@dataclasses.dataclass(frozen=True)
class CwruRecord:
    """One CWRU record: what its name and its keys say, and its drive-end signal.

    Parameters
    ----------
    path
        The file.
    state
        ``healthy``, ``inner_race``, ``outer_race`` or ``ball``.
    fault_size_in
        The defect's diameter, inch (0 for ``healthy``).
    load_hp
        The motor load, hp.
    shaft_speed
        Shaft speed, rpm (the file's ``X<nnn>RPM``; the stand's nominal speed at that load
        when the file has none, see ``rpm_source``).
    rpm_source
        ``file`` or ``nominal``.
    prefix
        The record number ``nnn`` of its keys.
    drive_end_g
        The drive-end accelerometer's samples, g, as stored.
    """

    path: Path
    state: str
    fault_size_in: float
    load_hp: int
    shaft_speed: float
    rpm_source: str
    prefix: str
    drive_end_g: np.ndarray

    @property
    def name(self) -> str:
        return self.path.stem


def parse_name(path: str | Path) -> tuple[str, float, int]:
    """State, defect size (inch) and load (hp) of a record from its file name.

    Raises
    ------
    ValueError
        For a name that is none of ``Normal_L``, ``IRsss_L``, ``ORsss@6_L``, ``Bsss_L``, or an
        outer-race defect away from 6 o'clock (the model's outer-race defect sits in the load
        zone).
    """
    path = Path(path)
    m = _NAME.match(path.stem)
    if m is None:
        raise ValueError(
            f"{path}: cannot read the condition from the file name {path.name!r}; expected "
            "Normal_L.mat, IRsss_L.mat, ORsss@6_L.mat or Bsss_L.mat (defect 0.sss in, load L hp)"
        )
    load = int(m["load"])
    if m["code"] is None:
        return "healthy", 0.0, load
    code, clock = m["code"], m["clock"]
    if code == "OR" and clock != "@6":
        where = f"{clock[1:]} o'clock" if clock else "an unstated position"
        raise ValueError(
            f"{path}: an outer-race defect at {where}; only defects at 6 o'clock (in the load "
            "zone, ORsss@6_L.mat) are modelled"
        )
    if code != "OR" and clock is not None:
        raise ValueError(f"{path}: a clock position ({clock}) belongs to outer-race records only")
    return FAULT_CODES[code], int(m["size"]) / 1000.0, load


def read_record(path: str | Path) -> CwruRecord:
    """Read one CWRU ``.mat`` record (see the module docstring).

    Raises
    ------
    ValueError
        Naming the file, for a file that is not a ``.mat`` file scipy reads, an unparsable
        name, no ``X<nnn>_DE_time`` key, the keys of more than one record, or a drive-end
        signal that is empty or not finite.
    """
    path = Path(path)
    if path.suffix.lower() != ".mat":
        raise ValueError(f"{path}: not a .mat file")
    state, size, load = parse_name(path)
    try:
        content = scipy.io.loadmat(path)
    except Exception as exc:  # scipy raises several types for files of another layout
        raise ValueError(f"{path}: not a MATLAB .mat file that scipy can read ({exc})") from exc
    keys = sorted(k for k in content if not k.startswith("__"))
    found = {k: m for k in keys if (m := _KEY.match(k))}
    prefixes = sorted({m["prefix"] for m in found.values()})
    if len(prefixes) > 1:
        raise ValueError(
            f"{path}: holds the keys of {len(prefixes)} records "
            f"({', '.join('X' + p for p in prefixes)}); one record per file is expected"
        )
    de = [k for k, m in found.items() if m["channel"] == "DE"]
    if not de:
        raise ValueError(
            f"{path}: no X<nnn>_DE_time key (keys: {', '.join(keys) or 'none'}); not a CWRU "
            "drive-end record"
        )
    x = np.asarray(content[de[0]], dtype=float)
    if x.ndim > 2 or (x.ndim == 2 and min(x.shape) != 1):
        raise ValueError(f"{path}: {de[0]} has shape {x.shape}; one column of samples expected")
    x = x.ravel()
    if x.size == 0 or not np.isfinite(x).all():
        raise ValueError(f"{path}: {de[0]} is empty or holds values that are not finite")
    rpm_keys = [k for k, m in found.items() if m["rpm"]]
    rpm = np.asarray(content[rpm_keys[0]], dtype=float).ravel() if rpm_keys else np.array([])
    if rpm.size == 1 and np.isfinite(rpm[0]) and rpm[0] > 0:
        shaft, source = float(rpm[0]), "file"
    elif load in NOMINAL_RPM:
        shaft, source = NOMINAL_RPM[load], "nominal"
    else:
        raise ValueError(f"{path}: no usable X<nnn>RPM and no nominal speed for {load} hp")
    return CwruRecord(path, state, size, load, shaft, source, prefixes[0], x)


def shaft_lines(x: np.ndarray, fs: float, shaft_hz: float, harmonics: int = 3) -> np.ndarray:
    """Frequency (Hz) and amplitude of the strongest line within 3 % of each shaft harmonic.

    The amplitude spectrum of the whole record (Hann window, amplitude-corrected), read as
    sampled at ``fs``. Returns shape (harmonics, 2).
    """
    x = np.asarray(x, dtype=float) - np.mean(x)
    w = np.hanning(x.size)
    amplitude = 2 * np.abs(np.fft.rfft(x * w)) / w.sum()
    f = np.fft.rfftfreq(x.size, 1 / fs)
    rows = []
    for h in range(1, harmonics + 1):
        near = np.abs(f - h * shaft_hz) <= 0.03 * h * shaft_hz
        i = np.flatnonzero(near)[np.argmax(amplitude[near])]
        rows.append((f[i], amplitude[i]))
    return np.asarray(rows)


def settle_sampling_rate(
    x: np.ndarray,
    shaft_rpm: float,
    *,
    candidates: tuple[float, ...] = CANDIDATE_RATES_HZ,
    min_ratio: float = 2.0,
) -> tuple[float, dict]:
    """The candidate sampling rate that puts the strongest lines at the shaft's 1x, 2x, 3x.

    For each candidate the record is read as sampled at that rate and the strongest line
    within 3 % of each harmonic of ``shaft_rpm / 60`` is found (:func:`shaft_lines`); the rate
    whose three lines are strongest in sum wins, if by at least ``min_ratio``.

    Returns
    -------
    rate, evidence
        The rate (Hz) and, per candidate, the lines found (Hz, amplitude in the units of
        ``x``) and the winner's margin.

    Raises
    ------
    ValueError
        When no candidate wins by ``min_ratio``.
    """
    shaft_hz = shaft_rpm / 60.0
    lines = {fs: shaft_lines(x, fs, shaft_hz) for fs in candidates}
    score = {fs: float(v[:, 1].sum()) for fs, v in lines.items()}
    ranked = sorted(score, key=score.__getitem__, reverse=True)
    best = ranked[0]
    margin = score[best] / score[ranked[1]] if len(ranked) > 1 else float("inf")
    evidence = {
        "shaft_hz": shaft_hz,
        "candidates": {
            f"{fs:g}": {
                "line_hz": [round(float(v), 3) for v in lines[fs][:, 0]],
                "line_amplitude": [float(v) for v in lines[fs][:, 1]],
            }
            for fs in candidates
        },
        "margin": margin,
    }
    if margin < min_ratio:
        raise ValueError(
            f"cannot settle the sampling rate: the shaft lines read at {best:g} Hz are only "
            f"{margin:.2f} times those at {ranked[1]:g} Hz (at least {min_ratio} needed)"
        )
    return best, evidence


def _stated_rate(path: Path) -> float | None:
    for part in reversed(path.parent.parts):
        m = _STATED_RATE.match(part)
        if m:
            return float(m["khz"]) * 1000.0
    return None


def _record_rate(record: CwruRecord) -> tuple[float, dict]:
    rate, evidence = settle_sampling_rate(record.drive_end_g, record.shaft_speed)
    stated = _stated_rate(record.path)
    if stated is not None and stated != rate:
        raise ValueError(
            f"{record.path}: its folder says {stated:g} Hz but its spectrum puts the shaft lines "
            f"at {rate:g} Hz ({json.dumps(evidence['candidates'])})"
        )
    evidence["folder_rate_hz"] = stated
    return rate, evidence


def _at_campaign_rate(x: np.ndarray, rate: float) -> np.ndarray:
    if rate == FS:
        return x
    factor = round(rate / FS)
    if factor * FS != rate:
        raise ValueError(f"cannot bring a record at {rate:g} Hz to {FS:g} Hz by decimation")
    return signal.resample_poly(x, 1, factor)


def _records(folder: Path) -> list[CwruRecord]:
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder} is not a folder of CWRU records")
    paths = sorted(folder.rglob("*.mat"))
    if not paths:
        raise ValueError(f"{folder} holds no .mat files")
    records = [read_record(p) for p in paths]
    seen: dict[tuple, Path] = {}
    for r in records:
        condition = (r.state, r.fault_size_in, r.load_hp)
        if condition in seen:
            raise ValueError(f"{r.path} and {seen[condition]} are records of the same condition")
        seen[condition] = r.path
    order = ("healthy", "inner_race", "outer_race", "ball")
    return sorted(records, key=lambda r: (order.index(r.state), r.fault_size_in, r.load_hp))


def read_cwru_records(
    folder: str | Path, *, segment_s: float = 1.0, calibration_fraction: float = 0.5
) -> tuple[dict[str, np.ndarray], list[dict]]:
    """The runs' arrays and one summary per record (see :func:`read_cwru`)."""
    if not segment_s > 0:
        raise ValueError(f"segment_s must be positive, got {segment_s!r}")
    if not 0 < calibration_fraction < 1:
        raise ValueError(f"calibration_fraction must be in (0, 1), got {calibration_fraction!r}")
    folder = Path(folder)
    n = round(segment_s * FS)
    columns: dict[str, list] = {
        k: []
        for k in (
            "acceleration",
            "state",
            "split",
            "record",
            "shaft_speed",
            "load_hp",
            "fault_size_in",
            "segment_start_s",
        )
    }
    summaries = []
    for r in _records(folder):
        rate, evidence = _record_rate(r)
        x = _at_campaign_rate(r.drive_end_g, rate) * G
        segments = x.size // n
        if segments == 0:
            raise ValueError(
                f"{r.path}: {x.size / FS:.3f} s of signal is shorter than one {segment_s} s segment"
            )
        if r.state == "healthy":
            n_cal = min(max(round(calibration_fraction * segments), 1), max(segments - 1, 1))
            split = ["calibration"] * n_cal + ["test"] * (segments - n_cal)
        else:
            split = ["test"] * segments
        columns["acceleration"].append(x[: segments * n].reshape(segments, 1, n))
        columns["state"] += [r.state] * segments
        columns["split"] += split
        columns["record"] += [r.name] * segments
        columns["shaft_speed"] += [r.shaft_speed] * segments
        columns["load_hp"] += [float(r.load_hp)] * segments
        columns["fault_size_in"] += [r.fault_size_in] * segments
        columns["segment_start_s"] += list(np.arange(segments) * n / FS)
        summaries.append(
            {
                "record": r.name,
                "file": r.path.relative_to(folder).as_posix(),
                "key": f"X{r.prefix}_DE_time",
                "state": r.state,
                "fault_size_in": r.fault_size_in,
                "load_hp": r.load_hp,
                "shaft_speed_rpm": r.shaft_speed,
                "rpm_source": r.rpm_source,
                "sampling_rate_hz": rate,
                "sampling_rate_evidence": evidence,
                "runs": segments,
                "calibration_runs": split.count("calibration"),
                "seconds_dropped": (x.size - segments * n) / FS,
            }
        )
    arrays = {
        k: np.concatenate(v) if k == "acceleration" else np.asarray(v) for k, v in columns.items()
    }
    return arrays, summaries


def read_cwru(folder: str | Path, *, segment_s: float = 1.0, calibration_fraction: float = 0.5):
    """A campaign of the ``bearing`` system from a folder of CWRU records.

    Every ``.mat`` file under ``folder`` (searched recursively) is one record. Each record is
    cut into non-overlapping segments of ``segment_s``, one run each (the tail shorter than a
    segment is dropped); the healthy records' first ``calibration_fraction`` of segments (a
    contiguous block) are the ``calibration`` split, their rest and every fault segment
    ``test``. Segments of one record are not independent: split by record, not at random.

    Parameters
    ----------
    folder
        The folder (for example ``Normal/`` and ``12k_DE/`` below it).
    segment_s
        Segment length, s.
    calibration_fraction
        The fraction of each healthy record's segments in ``calibration``.

    Returns
    -------
    campaign
        Channel ``DE`` in m/s^2 at 12 kHz, system ``bearing``; per run ``state``, ``split``,
        ``record`` (file name without ``.mat``), ``shaft_speed`` (rpm), ``load_hp``,
        ``fault_size_in`` (0 for healthy), ``segment_start_s`` (within the record), and
        ``t_start``/``t_stop`` (the whole segment: its first and last sample). Attribute
        ``source``: the importer's summary as JSON.

    Raises
    ------
    ValueError
        For a bad file (naming it and what is wrong) or a sampling rate that cannot be settled.
    FileNotFoundError
        When ``folder`` is not a folder.
    """
    arrays, summaries = read_cwru_records(
        folder, segment_s=segment_s, calibration_fraction=calibration_fraction
    )
    runs = arrays["state"].size
    ds = make_campaign(
        arrays["acceleration"],
        channels=["DE"],
        fs=FS,
        state=arrays["state"].tolist(),
        system="bearing",
        split=arrays["split"].tolist(),
        t_start=np.zeros(runs),
        t_stop=np.full(runs, (arrays["acceleration"].shape[-1] - 1) / FS),
        shaft_speed=arrays["shaft_speed"],
        load_hp=arrays["load_hp"],
        record=arrays["record"],
        fault_size_in=arrays["fault_size_in"],
        segment_start_s=arrays["segment_start_s"],
    )
    ds.attrs["source"] = json.dumps(_summary(summaries, segment_s))
    return ds


def _summary(records: list[dict], segment_s: float) -> dict:
    runs: dict[str, int] = {}
    for r in records:
        runs[r["state"]] = runs.get(r["state"], 0) + r["runs"]
    rates = sorted({r["sampling_rate_hz"] for r in records})
    return {
        "importer": "cwru",
        "segment_s": segment_s,
        "sampling_rate_hz": FS,
        "runs": sum(runs.values()),
        "runs_per_state": runs,
        "records": [
            {k: v for k, v in r.items() if k != "sampling_rate_evidence"}
            | {
                "sampling_rate_lines_hz": r["sampling_rate_evidence"]["candidates"][
                    f"{r['sampling_rate_hz']:g}"
                ]["line_hz"],
                "sampling_rate_margin": round(r["sampling_rate_evidence"]["margin"], 2),
            }
            for r in records
        ],
        "sampling_rate_method": (
            "each record's rate is the candidate (12 or 48 kHz) that puts the strongest lines "
            "at the shaft's 1x, 2x and 3x (from its rpm); margin: the ratio of their summed "
            "amplitudes to the other candidate's"
        ),
        "records_settled_at_hz": [float(r) for r in rates],
    }


def import_cwru(
    folder: str | Path,
    out: str | Path,
    *,
    segment_s: float = 1.0,
    calibration_fraction: float = 0.5,
    overwrite: bool = False,
) -> dict:
    """Write the campaign of :func:`read_cwru` to ``out`` (NetCDF) and summarise it.

    Returns
    -------
    summary
        JSON-able: ``out``, ``runs``, ``runs_per_state``, ``sampling_rate_hz``, the method that
        settled each record's rate, and per record its file, state, load, rpm, rate, the shaft
        lines found at that rate, and runs.

    Raises
    ------
    FileExistsError
        When ``out`` exists and ``overwrite`` is false (nothing is read or written).
    """
    out = Path(out)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} already exists; pass overwrite=True to replace it")
    ds = read_cwru(folder, segment_s=segment_s, calibration_fraction=calibration_fraction)
    save_campaign(ds, out, overwrite=overwrite)
    return {"out": str(out), **json.loads(ds.attrs["source"])}
