"""The CWRU bearing records (``.mat``) as a campaign of the ``bearing`` system.

The records are read by the built-in manifest ``cwru`` (``manifests/cwru.toml``). A record is
one ``.mat`` file named after its condition: ``Normal_<L>`` (healthy), ``IR<sss>_<L>`` (inner
race), ``OR<sss>@6_<L>`` (outer race at 6 o'clock), ``B<sss>_<L>`` (ball), with the defect's
diameter ``0.<sss>`` inch and the motor load ``L`` hp. It holds ``X<nnn>_DE_time``
(drive-end accelerometer, g), usually ``X<nnn>_FE_time`` and ``X<nnn>_BA_time``, and
``X<nnn>RPM``. Each record is cut into non-overlapping segments, one run each, of the
drive-end channel in m/s^2.

The sampling rate of every record is read from its own spectrum
(:func:`~bayesdoor.bearing.settle_sampling_rate`): the rate that puts the strongest lines at
the shaft's 1x, 2x and 3x (from the record's rpm). A record sampled at 48 kHz is decimated to
the campaign's 12 kHz.
"""

from __future__ import annotations

from pathlib import Path

from . import _records
from ._manifest import builtin_manifest


def read_record(path: str | Path) -> _records.Record:
    """Read one CWRU ``.mat`` record (see the module docstring).

    Raises
    ------
    ValueError
        Naming the file, for a file that is not a ``.mat`` file scipy reads, an unparsable
        name, no ``X<nnn>_DE_time`` key, the keys of more than one record, or a drive-end
        signal that is empty or not finite.
    """
    return _records.read_record(path, builtin_manifest("cwru"))


def read_cwru(folder: str | Path, *, segment_s: float = 1.0, calibration_fraction: float = 0.5):
    """A campaign of the ``bearing`` system from a folder of CWRU records.

    Every ``.mat`` file under ``folder`` (searched recursively) is one record. Each record is
    cut into non-overlapping segments of ``segment_s``, one run each (the tail shorter than a
    segment is dropped); the healthy records' first ``calibration_fraction`` of segments (a
    contiguous block) are the ``calibration`` split, their rest and every fault segment
    ``test``. Segments of one record are not independent: split by record, not at random.
    :func:`~bayesdoor.bearing.read_records` with the built-in manifest ``cwru``.

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
    return _records.read_records(
        folder,
        builtin_manifest("cwru"),
        segment_s=segment_s,
        calibration_fraction=calibration_fraction,
    )


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
    return _records.import_records(
        builtin_manifest("cwru"),
        folder,
        out,
        overwrite=overwrite,
        segment_s=segment_s,
        calibration_fraction=calibration_fraction,
    )
