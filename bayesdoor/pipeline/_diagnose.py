"""The diagnosis of a campaign under a fit, written as JSON and a self-contained HTML report.

Shared by ``bayesdoor diagnose`` (one folder of its own) and the ``diagnose`` stage of the main
job (``OUT/diagnose/``), so both write the same two files:

``diagnosis.json``
    As ``docs/cli.md`` specifies it: ``verdict`` (a catalogue name, ``"none"``, or ``null``
    when nothing is decisive) and ``causes`` ranked, each with ``name``, ``evidence``,
    ``parameters`` and ``gain``; plus ``report``, the HTML's file name (next to the JSON).
``diagnosis.html``
    :func:`bayesdoor.report.write_diagnosis_report`.

The job's stage keeps the diagnosis object too (``diagnosis.pkl``, without the fit, which the
job keeps in ``OUT/fit/``): extending the system by the verdict
(:func:`bayesdoor.diagnose.extend_system`, the job's ``extend``) needs the refit's chosen
configuration, which the JSON gives only in words.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pickle
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import xarray as xr

from .._cluster import Pool
from ..diagnose import Catalogue, Features, diagnose_campaign
from ..inference import FitResult
from ..io import atomic_write
from ..report import write_diagnosis_report
from ..systems import AbstractSystem
from ._fit import Fitted
from ._stages import Finished, StageRecord, configuration_hash, stage_in

DIAGNOSIS_JSON = "diagnosis.json"
DIAGNOSIS_HTML = "diagnosis.html"
#: the diagnosis object the job's stage keeps beside the JSON (pickled, without its fit)
DIAGNOSIS_OBJECT = "diagnosis.pkl"
#: the files a diagnosis writes into its folder
DIAGNOSIS_FILES = (DIAGNOSIS_JSON, DIAGNOSIS_HTML)


class DiagnosisLike(Protocol):
    """What the writers read of a diagnosis (:class:`bayesdoor.diagnose.Diagnosis`)."""

    def to_json(self) -> dict[str, Any]: ...


def json_safe(value: Any) -> Any:
    """``value`` with NaN and infinities as ``None`` and numpy scalars and arrays as lists."""
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def features_of(diagnosis: Any) -> Features | None:
    """The residual features a diagnosis scored its causes on (``None`` when it keeps none)."""
    features = getattr(diagnosis, "features", None)
    if features is None:
        features = getattr(getattr(diagnosis, "ranking", None), "features", None)
    return features if isinstance(features, Features) else None


def catalogue_of(system: AbstractSystem, diagnosis: Any = None) -> Catalogue | None:
    """The catalogue of candidate causes: the diagnosis's, else the system's, else ``None``."""
    catalogue = getattr(diagnosis, "catalogue", None)
    if isinstance(catalogue, Catalogue):
        return catalogue
    return system.catalogue


def save_diagnosis(
    diagnosis: DiagnosisLike,
    folder: str | Path,
    *,
    catalogue: Catalogue | None = None,
    fit: Mapping[str, Any] | None = None,
    extra: Mapping[str, Any] | None = None,
    title: str = "Discrepancy diagnosis",
    overwrite: bool = False,
) -> dict[str, Any]:
    """Write ``diagnosis.json`` and ``diagnosis.html`` into ``folder``; return the JSON.

    Each file is written atomically, the HTML first, so a ``diagnosis.json`` on disk always
    has its report next to it.

    Parameters
    ----------
    diagnosis
        The diagnosis (its ``to_json()`` and, for the figures, its residual features).
    folder
        Where the two files go (created).
    catalogue
        The system's catalogue (chooses the figure of each cause's evidence).
    fit
        The base model's fit (``method``, ``j``, ``parameters``) for the report; ``None``:
        the diagnosis's own ``fit`` when it keeps one.
    extra
        Further entries of the JSON (for example the campaign's path).
    title
        The report's title.
    overwrite
        Replace files of a previous diagnosis.

    Returns
    -------
    dict
        The JSON written, with ``report`` the HTML's file name.

    Raises
    ------
    FileExistsError
        When a file exists and ``overwrite`` is false (nothing is written then).
    """
    folder = Path(folder)
    json_path, html_path = folder / DIAGNOSIS_JSON, folder / DIAGNOSIS_HTML
    if not overwrite:
        for path in (json_path, html_path):
            if path.exists():
                raise FileExistsError(
                    f"{path} already exists; pass --force (overwrite=True) to replace it"
                )
    payload = json_safe({**dict(extra or {}), **diagnosis.to_json(), "report": html_path.name})
    own_fit = getattr(diagnosis, "fit", None)
    if fit is None and own_fit is not None and hasattr(own_fit, "to_json"):
        fit = own_fit.to_json()
    write_diagnosis_report(
        html_path,
        payload,
        features=features_of(diagnosis),
        catalogue=catalogue,
        fit=fit,
        title=title,
        overwrite=overwrite,
    )
    text = json.dumps(payload, indent=1, allow_nan=False) + "\n"
    atomic_write(json_path, lambda tmp: tmp.write_text(text), overwrite=overwrite)
    return payload


def default_diagnose(
    system: AbstractSystem,
    campaign: xr.Dataset,
    fit_folder: Path,
    *,
    seed: int,
    quick: bool,
    progress: bool,
    catalogue: Catalogue | None = None,
    pool: Pool | None = None,
) -> DiagnosisLike:
    """:func:`bayesdoor.diagnose.diagnose_campaign` under the fit saved in ``fit_folder``.

    ``catalogue``: the system's causes (``None``: ``system.catalogue``); ``pool``: where its
    refits and limits run (``None``: this process).
    """
    fit = FitResult.load(fit_folder)
    return diagnose_campaign(
        system,
        campaign,
        fit=fit,
        seed=seed,
        quick=quick,
        progress=progress,
        catalogue=catalogue,
        pool=pool,
    )


@dataclasses.dataclass(frozen=True)
class Diagnosis(Finished):
    """The product of the ``diagnose`` stage: ``diagnosis.json`` (beside it the HTML report
    and the diagnosis object, :data:`DIAGNOSIS_OBJECT`), or why it could not be made.

    Attributes
    ----------
    payload
        The diagnosis JSON (``verdict``, ``causes``) with ``report`` the path of its HTML; of
        a diagnosis not made, ``error`` (the reason), no verdict and no report.
    stage
        The record of the stage that made it (``None`` when it was not made).
    """

    payload: dict[str, Any]
    stage: StageRecord | None = None

    @classmethod
    def load(cls, folder: Path) -> Diagnosis:
        """Read the JSON that :func:`diagnosis_stage` wrote into ``folder``."""
        payload = json.loads((folder / DIAGNOSIS_JSON).read_text())
        payload["report"] = str(folder / DIAGNOSIS_HTML)
        return cls(payload, stage_in(folder))

    @classmethod
    def not_made(cls, reason: str) -> Diagnosis:
        """The product of a diagnosis that could not be made, and why."""
        return cls({"verdict": None, "causes": [], "error": reason, "report": None})

    @property
    def key(self) -> str:
        """The stage's configuration hash; of a diagnosis not made, the hash of the reason
        (so that what reads it is made again when the reason changes)."""
        if self.stage is None:
            return configuration_hash({"error": self.payload["error"]})
        return self.stage.config_hash


def diagnosis_stage(
    system: AbstractSystem,
    campaign: xr.Dataset,
    fit: Fitted,
    folder: Path,
    *,
    diagnose: Callable[..., DiagnosisLike],
    seed: int,
    quick: bool,
    progress: bool,
) -> None:
    """The job's ``diagnose`` stage: diagnose the campaign under the job's fit, write both files
    and keep the diagnosis object (:data:`DIAGNOSIS_OBJECT`).

    ``diagnose`` is called as ``diagnose(system, campaign, fit_folder, seed=, quick=,
    progress=)`` with the folder of the full fit (:func:`default_diagnose` in a job). A
    diagnosis that cannot be pickled (a stand-in of local classes) leaves no object: the job
    then cannot extend the system by it.
    """
    diagnosis = diagnose(
        system, campaign, fit.result_folder, seed=seed, quick=quick, progress=progress
    )
    save_diagnosis(
        diagnosis,
        folder,
        catalogue=catalogue_of(system, diagnosis),
        fit=fit.summary.to_json(),
        title=f"{system.name}: discrepancy diagnosis",
        overwrite=True,
    )
    keep_diagnosis(diagnosis, folder)


def keep_diagnosis(diagnosis: Any, folder: Path) -> bool:
    """Pickle ``diagnosis`` (its ``fit`` left out) into ``folder``; ``False`` when it cannot be."""
    if dataclasses.is_dataclass(diagnosis) and not isinstance(diagnosis, type):
        if any(f.name == "fit" for f in dataclasses.fields(diagnosis)):
            diagnosis = dataclasses.replace(diagnosis, fit=None)  # type: ignore[call-arg]
    try:
        data = pickle.dumps(diagnosis)
    except (pickle.PicklingError, AttributeError, TypeError):
        return False
    atomic_write(folder / DIAGNOSIS_OBJECT, lambda tmp: tmp.write_bytes(data), overwrite=True)
    return True


def kept_diagnosis(folder: Path) -> Any:
    """The diagnosis object :func:`keep_diagnosis` kept in ``folder``.

    Raises
    ------
    FileNotFoundError
        When the folder keeps none.
    ValueError
        When it cannot be read back (made by another version of the library).
    """
    path = Path(folder) / DIAGNOSIS_OBJECT
    data = path.read_bytes()
    try:
        return pickle.loads(data)  # the job's own file, written by keep_diagnosis
    except (pickle.UnpicklingError, AttributeError, ImportError, TypeError, EOFError) as err:
        raise ValueError(
            f"{path} cannot be read back ({type(err).__name__}: {err}): delete "
            f"{path.parent} to diagnose again"
        ) from None
