"""A folder of bearing records, read as its manifest describes it, as a campaign.

Each file the manifest's glob finds is one record: its condition (state, defect size, load)
comes from its name, its signal and shaft speed from the variables the manifest names, its
sampling rate from the manifest (a number, or the candidate its spectrum settles on,
:func:`~bayesdoor.bearing.settle_sampling_rate`). A record is resampled to the campaign's
rate where the two differ, scaled to m/s^2 and cut into non-overlapping segments, one run
each. The campaign records the bearing's geometry and rate where they are not the default
bearing's (``attrs['system_settings']``), so :func:`bayesdoor.io.system_of` gives back the
bearing that the records come from.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
from fractions import Fraction
from pathlib import Path

import numpy as np
import scipy.io
from scipy import signal

from ..io import SYSTEM_SETTINGS, make_campaign, save_campaign
from ._envelope import FAMILIES, envelope_spectrum, line_strength
from ._manifest import Manifest, builtin_manifest, read_manifest
from ._rate import settle_sampling_rate
from ._stand import BAND_HZ
from ._system import STATES, BearingSystem

#: the largest numerator or denominator of the ratio of rates a record is resampled by
MAX_RESAMPLING_FACTOR = 1000


@dataclasses.dataclass(frozen=True)
class Record:
    """One record: what its name and its variables say, and its signal as stored.

    Parameters
    ----------
    path
        The file.
    state
        The system's state (``healthy``, ``inner_race``, ``outer_race`` or ``ball``).
    fault_size_in
        The defect's size, inch (0 for ``healthy``; NaN where the name gives none).
    load_hp
        The load, hp.
    shaft_speed
        Shaft speed, rpm: the file's (``rpm_source`` ``file``) or the manifest's
        (``nominal``).
    rpm_source
        ``file`` or ``nominal``.
    key
        The variable (or column) that holds the signal.
    samples
        The signal in the unit it is stored in.
    """

    path: Path
    state: str
    fault_size_in: float
    load_hp: int | float
    shaft_speed: float
    rpm_source: str
    key: str
    samples: np.ndarray

    @property
    def name(self) -> str:
        return self.path.stem


def _number(path: Path, what: str, text: str) -> int | float:
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        raise ValueError(
            f"{path}: the {what} {text!r} read from its name is not a number"
        ) from None


def parse_name(path: str | Path, manifest: Manifest) -> tuple[str, float, int | float]:
    """State, defect size (inch) and load (hp) of a record from its file name.

    Raises
    ------
    ValueError
        For a name that none of the manifest's patterns reads (with the reason of the
        ``unsupported`` entry that matches it, if one does), or a state code the manifest
        does not map.
    """
    path = Path(path)
    match = next((m for p in manifest.names if (m := p.search(path.stem))), None)
    if match is None:
        for pattern, reason in manifest.unsupported:
            if refused := pattern.search(path.stem):
                raise ValueError(f"{path}: {reason.format(**refused.groupdict())}")
        raise ValueError(
            f"{path}: cannot read the condition from the file name {path.name!r}; expected "
            f"{manifest.expected_name}"
        )
    groups = match.groupdict()
    code = groups["state"]
    if code not in manifest.states:
        raise ValueError(
            f"{path}: its name's state code {code!r} is none of the manifest's [states] "
            f"({', '.join(manifest.states)})"
        )
    state = manifest.states[code]
    load = (
        manifest.load_hp if manifest.load_hp is not None else _number(path, "load", groups["load"])
    )
    if state == "healthy":
        size = 0.0
    elif groups.get("size") is None:
        size = math.nan
    else:
        size = _number(path, "size", groups["size"]) * manifest.inch_per_size_unit
    return state, size, load


def _content(path: Path, fmt: str) -> dict[str, np.ndarray]:
    """The file's variables (columns for CSV) by name."""
    if fmt == "mat":
        try:
            content = scipy.io.loadmat(path)
        except Exception as exc:  # scipy raises several types for files of another layout
            raise ValueError(f"{path}: not a MATLAB .mat file that scipy can read ({exc})") from exc
        return {k: v for k, v in content.items() if not k.startswith("__")}
    if fmt == "npz":
        try:
            with np.load(path, allow_pickle=False) as archive:
                return {k: archive[k] for k in archive.files}
        except Exception as exc:  # numpy raises several types for files of another layout
            raise ValueError(f"{path}: not a numpy .npz archive ({exc})") from exc
    try:
        with open(path, newline="", encoding="utf-8") as f:
            header = [h.strip() for h in next(csv.reader(f))]
        table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, StopIteration, UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"{path}: not a CSV file of numbers under a header row ({exc})") from exc
    if table.shape[1] != len(header):
        raise ValueError(f"{path}: {len(header)} names in the header, {table.shape[1]} columns")
    return {h: table[:, i] for i, h in enumerate(header)}


def read_record(path: str | Path, manifest: Manifest) -> Record:
    """Read one record as ``manifest`` describes it.

    Raises
    ------
    ValueError
        Naming the file, for a file of another format or one that cannot be read, an
        unreadable name, no variable that matches ``[signal] key``, the variables of more
        than one record (their ``record`` groups differ), a signal that is not one column, is
        empty or not finite, or no shaft speed.
    """
    path = Path(path)
    if path.suffix.lower() != f".{manifest.format}":
        raise ValueError(f"{path}: not a .{manifest.format} file")
    state, size, load = parse_name(path, manifest)
    content = _content(path, manifest.format)
    keys = sorted(content)
    signal_keys = [k for k in keys if manifest.signal_key.search(k)]
    rpm_keys = [k for k in keys if manifest.rpm_key is not None and manifest.rpm_key.search(k)]
    patterns = [p for p in (manifest.signal_key, manifest.rpm_key) if p is not None]
    found = (p.search(k) for k in keys for p in patterns)
    records = sorted({m["record"] for m in found if m and m.groupdict().get("record")})
    if len(records) > 1:
        raise ValueError(
            f"{path}: holds the keys of {len(records)} records ({', '.join(records)}); one "
            "record per file is expected"
        )
    if not signal_keys:
        raise ValueError(
            f"{path}: no {manifest.expected_key} key (keys: {', '.join(keys) or 'none'})"
        )
    key = signal_keys[0]
    x = np.asarray(content[key], dtype=float)
    if x.ndim > 2 or (x.ndim == 2 and min(x.shape) != 1):
        raise ValueError(f"{path}: {key} has shape {x.shape}; one column of samples expected")
    x = x.ravel()
    if x.size == 0 or not np.isfinite(x).all():
        raise ValueError(f"{path}: {key} is empty or holds values that are not finite")
    rpm = np.asarray(content[rpm_keys[0]], dtype=float).ravel() if rpm_keys else np.array([])
    if rpm.size == 1 and np.isfinite(rpm[0]) and rpm[0] > 0:
        shaft, source = float(rpm[0]), "file"
    elif float(load) in manifest.rpm_at_load:
        shaft, source = manifest.rpm_at_load[float(load)], "nominal"
    elif manifest.rpm is not None:
        shaft, source = manifest.rpm, "nominal"
    else:
        usable = f"no usable {manifest.expected_rpm_key} and " if manifest.rpm_key else ""
        raise ValueError(f"{path}: {usable}no nominal speed for {load} hp ([shaft_speed] at_load)")
    return Record(path, state, size, load, shaft, source, key, x)


def _stated_rate(path: Path, manifest: Manifest) -> float | None:
    if manifest.rate_folder is None:
        return None
    for part in reversed(path.parent.parts):
        m = manifest.rate_folder.search(part)
        if m:
            return float(m["khz"]) * 1000.0
    return None


def record_rate(record: Record, manifest: Manifest) -> tuple[float, dict | None]:
    """A record's sampling rate (Hz), and the evidence that settled it (``None`` where the
    manifest states the rate).

    Raises
    ------
    ValueError
        When no candidate rate wins, or the winner contradicts the rate a folder states.
    """
    if manifest.rate_hz is not None:
        return manifest.rate_hz, None
    try:
        rate, evidence = settle_sampling_rate(
            record.samples, record.shaft_speed, candidates=manifest.candidate_rates_hz
        )
    except ValueError as err:
        raise ValueError(f"{record.path}: {err}") from None
    stated = _stated_rate(record.path, manifest)
    if stated is not None and stated != rate:
        raise ValueError(
            f"{record.path}: its folder says {stated:g} Hz but its spectrum puts the shaft lines "
            f"at {rate:g} Hz ({json.dumps(evidence['candidates'])})"
        )
    evidence["folder_rate_hz"] = stated
    return rate, evidence


def resampled(x: np.ndarray, rate: float, to: float) -> np.ndarray:
    """``x`` sampled at ``rate`` brought to the rate ``to`` (polyphase filtering,
    :func:`scipy.signal.resample_poly`); unchanged at the same rate.

    Raises
    ------
    ValueError
        When the ratio of the rates is not one of integers up to
        :data:`MAX_RESAMPLING_FACTOR`.
    """
    if rate == to:
        return x
    ratio = Fraction(to) / Fraction(rate)
    if max(ratio.numerator, ratio.denominator) > MAX_RESAMPLING_FACTOR:
        raise ValueError(
            f"cannot resample a record at {rate:g} Hz to {to:g} Hz: the ratio of the rates is "
            f"not one of integers up to {MAX_RESAMPLING_FACTOR}"
        )
    return signal.resample_poly(x, ratio.numerator, ratio.denominator)


def records(folder: str | Path, manifest: Manifest) -> list[Record]:
    """Every record below ``folder``, in the order of the system's states, size and load.

    Raises
    ------
    FileNotFoundError
        When ``folder`` is not a folder.
    ValueError
        When no file matches the manifest's glob, for a bad file (:func:`read_record`), or for
        two records of the same condition.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder} is not a folder of records")
    paths = sorted(p for p in folder.glob(manifest.glob) if p.is_file())
    if not paths:
        raise ValueError(
            f"{folder} holds no .{manifest.format} files matching {manifest.glob!r} ([files] "
            f"glob of {manifest.source})"
        )
    found = [read_record(p, manifest) for p in paths]
    seen: dict[tuple, Path] = {}
    for r in found:
        size = None if math.isnan(r.fault_size_in) else r.fault_size_in
        condition = (r.state, size, r.load_hp)
        if condition in seen:
            raise ValueError(f"{r.path} and {seen[condition]} are records of the same condition")
        seen[condition] = r.path
    order = tuple(STATES)

    def position(r: Record) -> tuple:
        size = r.fault_size_in
        return order.index(r.state), math.isnan(size), 0.0 if math.isnan(size) else size, r.load_hp

    return sorted(found, key=position)


def _as_manifest(manifest: Manifest | str | Path) -> Manifest:
    return manifest if isinstance(manifest, Manifest) else read_manifest(manifest)


def read_records(
    folder: str | Path,
    manifest: Manifest | str | Path,
    *,
    segment_s: float | None = None,
    calibration_fraction: float | None = None,
):
    """A campaign of the ``bearing`` system from a folder of records and its manifest.

    Every file below ``folder`` that the manifest's glob matches is one record. Each record
    is brought to the campaign's rate, scaled to m/s^2 and cut into non-overlapping segments
    of ``segment_s``, one run each (the tail shorter than a segment is dropped); the healthy
    records' first ``calibration_fraction`` of segments (a contiguous block) are the
    ``calibration`` split, their rest and every fault segment ``test``. Segments of one
    record are not independent: split by record, not at random.

    Parameters
    ----------
    folder
        The folder of records.
    manifest
        A :class:`Manifest` or the path of a manifest file.
    segment_s, calibration_fraction
        Override the manifest's ``[runs]``.

    Returns
    -------
    campaign
        Channel ``DE`` in m/s^2 at the manifest's campaign rate, system ``bearing``; per run
        ``state``, ``split``, ``record`` (file name without its suffix), ``shaft_speed`` (rpm),
        ``load_hp``, ``fault_size_in`` (0 for healthy), ``segment_start_s`` (within the
        record), and ``t_start``/``t_stop`` (the whole segment: its first and last sample).
        Attributes: ``source``, the importer's summary as JSON; ``system_settings``, the
        bearing's geometry and rate as JSON, where they are not the default bearing's.

    Raises
    ------
    ValueError
        For a bad manifest or file (naming it and what is wrong), or a sampling rate that
        cannot be settled.
    FileNotFoundError
        When ``folder`` is not a folder or the manifest file does not exist.
    """
    manifest = _as_manifest(manifest)
    segment_s = manifest.segment_s if segment_s is None else segment_s
    fraction = (
        manifest.calibration_fraction if calibration_fraction is None else calibration_fraction
    )
    if not segment_s > 0:
        raise ValueError(f"segment_s must be positive, got {segment_s!r}")
    if not 0 < fraction < 1:
        raise ValueError(f"calibration_fraction must be in (0, 1), got {fraction!r}")
    folder = Path(folder)
    fs = manifest.campaign_rate_hz
    n = round(segment_s * fs)
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
    for r in records(folder, manifest):
        rate, evidence = record_rate(r, manifest)
        try:
            x = resampled(r.samples, rate, fs) * manifest.scale
        except ValueError as err:
            raise ValueError(f"{r.path}: {err}") from None
        segments = x.size // n
        if segments == 0:
            raise ValueError(
                f"{r.path}: {x.size / fs:.3f} s of signal is shorter than one {segment_s} s segment"
            )
        if r.state == "healthy":
            n_cal = min(max(round(fraction * segments), 1), max(segments - 1, 1))
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
        columns["segment_start_s"] += list(np.arange(segments) * n / fs)
        summaries.append(
            {
                "record": r.name,
                "file": r.path.relative_to(folder).as_posix(),
                "key": r.key,
                "state": r.state,
                "fault_size_in": r.fault_size_in,
                "load_hp": r.load_hp,
                "shaft_speed_rpm": r.shaft_speed,
                "rpm_source": r.rpm_source,
                "sampling_rate_hz": rate,
                "sampling_rate_evidence": evidence,
                "runs": segments,
                "calibration_runs": split.count("calibration"),
                "seconds_dropped": (x.size - segments * n) / fs,
            }
        )
    arrays = {
        k: np.concatenate(v) if k == "acceleration" else np.asarray(v) for k, v in columns.items()
    }
    runs = arrays["state"].size
    ds = make_campaign(
        arrays["acceleration"],
        channels=["DE"],
        fs=fs,
        state=arrays["state"].tolist(),
        system="bearing",
        split=arrays["split"].tolist(),
        t_start=np.zeros(runs),
        t_stop=np.full(runs, (arrays["acceleration"].shape[-1] - 1) / fs),
        shaft_speed=arrays["shaft_speed"],
        load_hp=arrays["load_hp"],
        record=arrays["record"],
        fault_size_in=arrays["fault_size_in"],
        segment_start_s=arrays["segment_start_s"],
    )
    settings = manifest.system().settings()
    differs = settings != BearingSystem().settings()
    if differs:
        ds.attrs[SYSTEM_SETTINGS] = json.dumps(settings)
    ds.attrs["source"] = json.dumps(
        _summary(manifest, summaries, segment_s, settings if differs else None)
    )
    return ds


def _summary(
    manifest: Manifest, records: list[dict], segment_s: float, settings: dict | None
) -> dict:
    fs = manifest.campaign_rate_hz
    runs: dict[str, int] = {}
    for r in records:
        runs[r["state"]] = runs.get(r["state"], 0) + r["runs"]
    out = {
        "importer": manifest.name,
        "segment_s": segment_s,
        "sampling_rate_hz": fs,
        "runs": sum(runs.values()),
        "runs_per_state": runs,
        "records": [_record_summary(r) for r in records],
        "sampling_rate_method": _rate_method(manifest),
    }
    if manifest.rate_hz is None:
        out["records_settled_at_hz"] = [
            float(r) for r in sorted({r["sampling_rate_hz"] for r in records})
        ]
    moved = [r["record"] for r in records if r["sampling_rate_hz"] != fs]
    if moved:
        rates = ", ".join(f"{r:g}" for r in sorted({r["sampling_rate_hz"] for r in records} - {fs}))
        out["notes"] = [
            f"{len(moved)} record(s) at {rates} Hz resampled to the campaign's {fs:g} Hz "
            f"(scipy.signal.resample_poly): {', '.join(moved)}"
        ]
    if settings is not None:
        out["system_settings"] = settings
    return out


def _record_summary(r: dict) -> dict:
    out = {k: v for k, v in r.items() if k != "sampling_rate_evidence"}
    evidence = r["sampling_rate_evidence"]
    if evidence is None:
        return out
    return out | {
        "sampling_rate_lines_hz": evidence["candidates"][f"{r['sampling_rate_hz']:g}"]["line_hz"],
        "sampling_rate_margin": round(evidence["margin"], 2),
    }


def _rate_method(manifest: Manifest) -> str:
    if manifest.rate_hz is not None:
        return f"the manifest's rate, {manifest.rate_hz:g} Hz"
    khz = [f"{c / 1000:g}" for c in manifest.candidate_rates_hz]
    listed = f"{', '.join(khz[:-1])} or {khz[-1]} kHz"
    other = "the other candidate's" if len(khz) == 2 else "the next best candidate's"
    return (
        f"each record's rate is the candidate ({listed}) that puts the strongest lines "
        f"at the shaft's 1x, 2x and 3x (from its rpm); margin: the ratio of their summed "
        f"amplitudes to {other}"
    )


def import_records(
    manifest: Manifest | str | Path,
    folder: str | Path,
    out: str | Path,
    *,
    overwrite: bool = False,
    segment_s: float | None = None,
    calibration_fraction: float | None = None,
) -> dict:
    """Write the campaign of :func:`read_records` to ``out`` (NetCDF, atomically) and
    summarise it: the importer of a manifest (``bayesdoor import MANIFEST.toml FOLDER``).

    Returns
    -------
    summary
        JSON-able: ``out``, ``importer`` (the manifest's name), ``runs``, ``runs_per_state``,
        ``sampling_rate_hz`` (the campaign's), how each record's rate was found, per record
        its file, key, state, size, load, rpm, rate and runs; ``notes`` (records resampled)
        and ``system_settings`` (geometry and rate) where they apply.

    Raises
    ------
    FileExistsError
        When ``out`` exists and ``overwrite`` is false (nothing is read or written).
    """
    out = Path(out)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} already exists; pass overwrite=True to replace it")
    ds = read_records(
        folder, manifest, segment_s=segment_s, calibration_fraction=calibration_fraction
    )
    save_campaign(ds, out, overwrite=overwrite)
    return {"out": str(out), **json.loads(ds.attrs["source"])}


def fault_line_check(
    folder,
    *,
    manifest: Manifest | str | Path | None = None,
    band: tuple[float, float] = BAND_HZ,
    tolerance: float = 0.02,
    threshold_db: float = 10.0,
) -> list[dict]:
    """Which records show their fault frequency in the envelope spectrum.

    Each record under ``folder`` (read as :func:`read_records` reads it, at the campaign's
    rate, whole; ``manifest`` default the CWRU one) is band-passed to ``band``, enveloped and
    its envelope spectrum taken with 1 Hz resolution (:func:`envelope_spectrum`); at BPFO,
    BPFI, 2 BSF and BSF (from the manifest's geometry and the record's rpm) the strongest
    line within ``tolerance`` is compared with the median of the spectrum within 20 %
    (:func:`line_strength`). A fault record shows its fault when its own family's line
    (BPFO; BPFI; the stronger of 2 BSF and BSF for a ball) stands ``threshold_db`` or more
    above that background and above every other family's line.

    Returns
    -------
    rows
        Per record: ``record``, ``state``, ``shaft_speed_rpm``, per line its frequency found
        (``<line>_hz``) and prominence (``<line>_db``), and ``shows`` (``None`` for a healthy
        record).
    """
    manifest = builtin_manifest("cwru") if manifest is None else _as_manifest(manifest)
    fs = manifest.campaign_rate_hz
    rows = []
    for record in records(Path(folder), manifest):
        rate, _ = record_rate(record, manifest)
        x = resampled(record.samples, rate, fs)
        f, amplitude = envelope_spectrum(x, fs, band)
        hz = manifest.geometry.fault_frequencies(record.shaft_speed / 60.0)
        targets = {"bpfo": hz["bpfo"], "bpfi": hz["bpfi"], "2bsf": 2 * hz["bsf"], "bsf": hz["bsf"]}
        row: dict = {
            "record": record.name,
            "state": record.state,
            "shaft_speed_rpm": record.shaft_speed,
        }
        for name, target in targets.items():
            peak, ratio = line_strength(f, amplitude, target, tolerance=tolerance)
            row[f"{name}_hz"] = peak
            row[f"{name}_db"] = round(20 * float(np.log10(ratio)), 1)
        if record.state == "healthy":
            row["shows"] = None
        else:
            family = {k: max(row[f"{n}_db"] for n in v) for k, v in FAMILIES.items()}
            own = family.pop(record.state)
            row["shows"] = bool(own >= threshold_db and own > max(family.values()))
        rows.append(row)
    return rows
