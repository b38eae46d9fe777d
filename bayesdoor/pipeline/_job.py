"""The main job: fit, generate, train, classify, report; each stage reused when unchanged.

Folder of a job::

    OUT/fit/        the model updating on the calibration runs (summary.json, draws.npz,
                    result/ with the full fit)
    OUT/generate/   the simulated training data (bayesdoor.datagen's layout)
    OUT/adequacy/   adequacy.json: do the simulations reproduce the measured healthy runs?
    OUT/train/      the calibrated ensemble (ensemble.eqx), training.json, bands.npz
    OUT/classify/   classification.json (docs/data.md) and features.npz
    OUT/trust/      trust.json: whether the classification can be trusted, and why not
    OUT/diagnose/   diagnosis.json (docs/data.md), diagnosis.html and diagnosis.pkl (the object)
    OUT/extended/   with ``extend``: the same job on the system extended by the diagnosis's
                    verdict (a job folder of its own, without a diagnosis)
    OUT/report/     index.html (the campaign, linking the diagnosis) and runs/run-NNNN.html
    OUT/job.json    the job's settings, the stages' hashes and the headline numbers
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import inspect
import json
from collections.abc import Callable, Iterator, Mapping
from importlib import metadata
from pathlib import Path
from typing import Any, Literal, NamedTuple, Protocol

import jax
import numpy as np
import xarray as xr

from .._cluster import Cluster, Pool
from .._exported import code_version
from ..classify import TrainConfig
from ..datagen import (
    DISCREPANCY_FORM,
    AbstractParameterSource,
    Execution,
    GaussianScatter,
    GenerationConfig,
    PosteriorDraws,
    TrainingData,
    describe_system,
    generate,
)
from ..diagnose import NONE, extend_system, verdict_extension
from ..features import CNNInputSpec
from ..inference import calibration_runs, fit_campaign
from ..io import atomic_write
from ..io import operating as campaign_operating
from ..systems import AbstractSystem
from ._classify import (
    BANDS,
    ENSEMBLE,
    SIGNATURES,
    Classification,
    JobFindings,
    classify_stage,
    ood_model_error,
    report_stage,
    signature_stage,
    train_stage,
)
from ._diagnose import (
    DIAGNOSIS_HTML,
    DIAGNOSIS_JSON,
    DIAGNOSIS_OBJECT,
    default_diagnose,
    diagnosis_stage,
    kept_diagnosis,
)
from ._fit import FitSummary, Fitted
from ._stages import StageRecord, configuration_hash, run_stage
from ._trust import (
    ADEQUACY_CHECK,
    ADEQUACY_JSON,
    TRUST_CHECKS,
    TRUST_JSON,
    Adequacy,
    check_adequacy,
    judge_classification,
    training_data,
)

Source = Literal["posterior", "posterior+model_error", "gaussian"]
SOURCES: tuple[str, ...] = ("posterior", "posterior+model_error", "gaussian")
#: the training source of a job on a sampled fit: the posterior's draws with the model error
#: the fit measured (results/transfer.md: the source that transfers to doors the model lacks)
DEFAULT_SOURCE: Source = "posterior+model_error"
#: the folder of the job on the extended system, inside the job's (``extend``)
EXTENDED = "extended"
#: the stages of a job, in order (each one a folder of the job)
STAGES: tuple[str, ...] = (
    "fit",
    "generate",
    "adequacy",
    "train",
    "classify",
    "trust",
    "diagnose",
    "report",
)


def default_source(method: str) -> Source:
    """The training source a job uses when none is given: :data:`DEFAULT_SOURCE` for a
    sampled fit, the paper's Gaussian scatter for a CMA-ES point (it has no posterior)."""
    return "gaussian" if method == "cmaes" else DEFAULT_SOURCE


@dataclasses.dataclass(frozen=True)
class Sizes:
    """How much a job simulates and trains.

    Parameters
    ----------
    runs_per_state
        Simulated training runs per state (the paper: 600, 70/30 train/validation).
    chunk_size
        Runs per saved chunk of the generation.
    validation_fraction
        Share of every state's runs held out for the temperature and the OOD threshold.
    train
        The ensemble's training settings (the paper's: 10 members, 80 epochs, batch 100).
    gaussian_sd
        Relative standard deviation of the Gaussian baseline around the point (the paper:
        "1-10 %"; 5 % is the middle of that range).
    ood_quantile
        Quantile of the simulated validation OOD scores that becomes the threshold.
    """

    runs_per_state: int = 600
    chunk_size: int = 100
    validation_fraction: float = 0.3
    train: TrainConfig = dataclasses.field(default_factory=TrainConfig)
    gaussian_sd: float = 0.05
    ood_quantile: float = 0.99

    @classmethod
    def quick(cls) -> Sizes:
        """Smaller training data (100 runs per state) for a first look in a few minutes."""
        return cls(runs_per_state=100, chunk_size=50)

    def to_json(self) -> dict[str, Any]:
        return {**dataclasses.asdict(self), "train": self.train.to_json()}


@dataclasses.dataclass(frozen=True)
class JobConfig:
    """Every setting of a job that changes what it computes, in one frozen record.

    :meth:`quick_look` and :meth:`paper_sizes` are the two usual starting points; change a
    setting with ``dataclasses.replace``. The fields left ``None`` are resolved when the
    record is made (so two records that mean the same job compare equal).

    Parameters
    ----------
    quick
        Smaller sizes (:meth:`Sizes.quick`) and the fit's quick mode.
    seed
        Seed of the generation and the training (and of the fit unless ``fit_seed``).
    method
        The fit's method (``"nuts"``, ``"emcee"``; ``"cmaes"`` for a point only).
    source
        Training-data parameters: ``"posterior+model_error"`` (posterior draws plus the
        fit's model-error offsets on the features), ``"posterior"`` draws alone, or the
        paper's ``"gaussian"`` scatter around the fit's point; ``None``:
        :func:`default_source` (the first for a sampled fit, the last for CMA-ES).
    fit_seed
        Seed of the fit; ``None`` means ``seed``.
    sizes
        Sizes of the generation and training; ``None``: the paper's, or the quick ones.
    fit_options
        Further keyword arguments of the fit (for example ``settings``, a
        :class:`bayesdoor.inference.FitSettings`, or ``problem=FitProblem(fixed={"I": 3})``); they
        enter the fit stage's configuration through their ``repr``.
    html
        Write the HTML report stage (``False`` for batch studies that need the metrics only;
        the JSON is always written).
    diagnosis
        Run the discrepancy diagnosis of the campaign under the job's fit (the ``diagnose``
        stage, linked from the report); ``None``: when ``html`` is true (and always with
        ``extend``).
    extend
        After the diagnosis, when its verdict names a cause: run the same job (seeds, sizes,
        source, method, fit; no diagnosis) on :func:`bayesdoor.diagnose.extend_system` of
        the system and the diagnosis (the cause held at its refitted values) in
        ``out/extended``, its stages reused alike; the report and :attr:`JobResult.extended`
        compare the two. The diagnosis sees the healthy calibration runs only: the test runs
        score both jobs and inform neither.

    Raises
    ------
    ValueError
        For an unknown source, or ``extend`` with ``diagnosis=False``.
    """

    quick: bool = False
    seed: int = 0
    method: str = "nuts"
    source: Source | None = None
    fit_seed: int | None = None
    sizes: Sizes | None = None
    fit_options: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    html: bool = True
    diagnosis: bool | None = None
    extend: bool = False

    def __post_init__(self) -> None:
        if self.extend and self.diagnosis is False:
            raise ValueError(
                "extend=True extends the system by the diagnosis's verdict, but "
                "diagnosis=False skips the diagnosis: pass diagnosis=True (or None) with "
                "extend=True"
            )
        if self.effective_source not in SOURCES:
            raise ValueError(
                f"source must be one of {', '.join(SOURCES)}, got {self.effective_source!r}"
            )
        object.__setattr__(self, "fit_options", dict(self.fit_options))

    # the settings left ``None`` read through these, so that ``dataclasses.replace`` of
    # ``quick`` or ``method`` changes the sizes or the source that follow from them
    @property
    def effective_source(self) -> Source:
        return default_source(self.method) if self.source is None else self.source

    @property
    def effective_fit_seed(self) -> int:
        return self.seed if self.fit_seed is None else self.fit_seed

    @property
    def effective_sizes(self) -> Sizes:
        if self.sizes is not None:
            return self.sizes
        return Sizes.quick() if self.quick else Sizes()

    @property
    def effective_diagnosis(self) -> bool:
        """The job diagnoses: with ``extend``, else as ``diagnosis`` says, else with the HTML."""
        if self.extend:
            return True
        return self.html if self.diagnosis is None else self.diagnosis

    @classmethod
    def quick_look(cls, **changes: Any) -> JobConfig:
        """A first look in minutes: :meth:`Sizes.quick` and the fit's quick mode."""
        return cls(quick=True, **changes)

    @classmethod
    def paper_sizes(cls, **changes: Any) -> JobConfig:
        """The paper's sizes (600 simulated runs per state, the full fit)."""
        return cls(quick=False, **changes)

    def settings(self, system_description: Mapping[str, Any], campaign: str) -> dict[str, Any]:
        """What a finished job folder is checked against (``job.json``'s settings)."""
        return {
            "system": dict(system_description),
            "campaign": campaign,
            "quick": self.quick,
            "seed": self.seed,
            "fit_seed": self.effective_fit_seed,
            "source": self.effective_source,
            "method": self.method,
            "fit_options": {k: repr(v) for k, v in self.fit_options.items()},
            "sizes": self.effective_sizes.to_json(),
        }


@dataclasses.dataclass(frozen=True)
class JobResult:
    """What a finished job produced.

    Attributes
    ----------
    out
        The job's folder.
    stages
        The record of each stage, in order.
    fit
        The fit's point, draws and model error.
    classification
        The JSON of docs/data.md (``classes``, ``runs``, ``metrics``).
    report
        The campaign's HTML report (``None`` when the job was run without it).
    diagnosis
        The diagnosis JSON (``verdict``, ``causes``) with ``report`` the path of its HTML
        (``None`` when the job was run without it).
    adequacy
        The fit-adequacy JSON (:func:`bayesdoor.datagen.fit_adequacy`: ``verdict``,
        ``summary``, the channel-bands that do not reproduce).
    trust
        The trust JSON (``verdict`` ``"trusted"`` or ``"not trusted"``, ``reasons``,
        ``flagged_runs``; :mod:`bayesdoor.pipeline._trust`).
    extended
        With ``extend``: the same job on the system extended by the diagnosis's verdict (in
        ``out/extended``); ``None`` when the job was run without ``extend`` or nothing was
        extended (:attr:`extension` says why).
    extends
        Of a job on an extended system: the ``verdict`` it extends, the refit's
        ``configuration`` and the ``held`` values.
    extension
        With ``extend``: :attr:`extends` of the extended job, or ``reason``, why nothing was
        extended (``None`` without ``extend``).
    """

    out: Path
    stages: tuple[StageRecord, ...]
    fit: FitSummary
    classification: dict[str, Any]
    report: Path | None
    diagnosis: dict[str, Any] | None = None
    adequacy: dict[str, Any] | None = None
    trust: dict[str, Any] | None = None
    extended: JobResult | None = None
    extends: dict[str, Any] | None = None
    extension: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        """The job's JSON: the fit's summary, the classification, the diagnosis, the stages,
        and ``extended``: the job on the extended system (``null`` when there is none)."""
        return {
            "out": str(self.out),
            "report": None if self.report is None else str(self.report),
            "fit": {**self.fit.to_json(), "adequacy": self.adequacy},
            "trust": self.trust,
            **self.classification,
            "diagnosis": self.diagnosis,
            "stages": _stages_json(self.stages),
            "extended": None if self.extended is None else self.extended.extended_json(),
        }

    def extended_json(self) -> dict[str, Any]:
        """The ``extended`` entry of the base job's JSON: what this job extends (``verdict``,
        ``configuration``, ``held``), its folder, report, fit, metrics, trust and stages."""
        return {
            **(self.extends or {}),
            "out": str(self.out),
            "report": None if self.report is None else str(self.report),
            "fit": {**self.fit.to_json(), "adequacy": self.adequacy},
            "metrics": self.classification.get("metrics"),
            "trust": self.trust,
            "stages": _stages_json(self.stages),
        }


def _stages_json(stages: tuple[StageRecord, ...]) -> list[dict[str, Any]]:
    return [
        {
            "name": s.name,
            "reused": s.reused,
            "seconds": s.seconds,
            "cpu_seconds": s.cpu_seconds,
            "peak_memory_mb": s.peak_memory_mb,
            "hash": s.config_hash,
        }
        for s in stages
    ]


def digest_runs(campaign: xr.Dataset) -> str:
    """SHA-256 of the runs' signals, time axis and per-run coordinates."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(campaign["acceleration"].values).tobytes())
    h.update(np.ascontiguousarray(campaign["time"].values).tobytes())
    for name in sorted(str(c) for c in campaign.coords if c not in ("time",)):
        h.update(name.encode())
        h.update(np.asarray(campaign[name].values).astype(str).tobytes())
    return h.hexdigest()


def runs_to_classify(campaign: xr.Dataset) -> xr.Dataset:
    """The runs to classify: ``split == "test"`` when there are any, else all runs."""
    if "split" in campaign.coords:
        keep = np.asarray(campaign["split"].values).astype(str) == "test"
        if keep.any():
            return campaign.isel(run=np.flatnonzero(keep))
    return campaign


def _versions() -> dict[str, str]:
    """What the stages' products depend on besides their settings: the libraries' versions
    and a digest of bayesdoor's own source (a changed module makes every stage recompute,
    as an installed package of the same version number with other code would not)."""
    out = {}
    for name in ("bayesdoor", "jax", "equinox", "diffrax", "numpyro"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    out["bayesdoor source"] = code_version()
    return out


def _default_fit(system: AbstractSystem, calibration: xr.Dataset, **options: Any) -> Any:
    return fit_campaign(system, calibration, **options)


def _check_folder(out: Path, settings: dict[str, Any], job_hash: str, overwrite: bool) -> None:
    """Refuse to replace a finished job of other settings, or to write into a foreign folder."""
    if not out.exists():
        return
    if not out.is_dir():
        raise FileExistsError(f"{out} is a file, not a job folder: pass a folder for the job")
    record = out / "job.json"
    if record.is_file():
        old = json.loads(record.read_text())
        if old.get("job_hash") != job_hash and not overwrite:
            changed = [
                k
                for k in ("campaign", "quick", "seed", "fit_seed", "source", "method", "sizes")
                if k in old and old.get(k) != settings.get(k)
            ]
            raise FileExistsError(
                f"{out} holds a finished job with other settings "
                f"({', '.join(changed) or 'the system or the campaign'} differ); pass --force "
                "(overwrite=True) to replace it (unchanged stages are reused), or use another "
                "folder"
            )
        return
    known = {*STAGES, EXTENDED, "job.json"}
    foreign = sorted(
        p.name for p in out.iterdir() if p.name not in known and not p.name.startswith(".")
    )
    if foreign and not overwrite:
        raise FileExistsError(
            f"{out} is not empty and is not a bayesdoor job folder (it holds {foreign[:5]}); "
            "pass an empty or new folder"
        )


def parameter_source(
    system: AbstractSystem, fit: FitSummary, source: Source, gaussian_sd: float
) -> AbstractParameterSource:
    """The parameter source of the training data for ``source``.

    ``posterior`` and ``posterior+model_error`` draw the same posterior; the latter's model
    error is the discrepancy the healthy calibration runs measure, added to every training
    run at the training stage (:func:`bayesdoor.datagen.with_measured_discrepancy`), and the
    fit's model-error posterior sets the OOD detector's reference. Its simulations carry no
    level offsets drawn from the model-error scale besides: the measured discrepancy already
    puts each channel's level where the machine has it, and offsets at the fitted scale
    (about 0.9 decades on the other doors of results/transfer.md, where the measured runs'
    levels scatter by 0.05-0.08 decades) would count the model error twice and bury the
    small faults' signatures (docs/transfer.md).

    Raises
    ------
    ValueError
        For an unknown ``source``, posterior sources on a fit without posterior draws, or
        ``posterior+model_error`` on a fit without a model-error posterior.
    """
    if source not in SOURCES:
        raise ValueError(f"source must be one of {', '.join(SOURCES)}, got {source!r}")
    if source == "gaussian":
        return GaussianScatter.around(system, fit.optimum, gaussian_sd)
    if not fit.draws:
        raise ValueError(
            f"source={source!r} needs posterior draws, but the {fit.method} fit holds a point "
            "only: fit with method 'nuts' or 'emcee', or use source='gaussian'"
        )
    fixed = {k: v for k, v in fit.point.items() if k not in fit.draws}
    if source == "posterior+model_error" and fit.sigma_model is None:
        raise ValueError(
            f"source={source!r} needs the model-error posterior, but the {fit.method} fit has "
            "none: use source='posterior'"
        )
    return PosteriorDraws(fit.draws, fixed=fixed)


class Generation(NamedTuple):
    """The training-data generation of a job: its stage configuration and its inputs."""

    config: dict[str, Any]
    source: AbstractParameterSource
    generation: GenerationConfig


def generation_settings(
    system: AbstractSystem,
    campaign: xr.Dataset,
    fit: FitSummary,
    fit_hash: str,
    source: Source,
    sizes: Sizes,
    seed: int,
) -> Generation:
    """What the generation stage simulates, and the configuration that decides its reuse.

    The operating points are the campaign's (its runs' operating conditions, not labels),
    extended by the system (:meth:`~bayesdoor.systems.AbstractSystem.training_points`); the
    parameters come from :func:`parameter_source`.
    """
    params = parameter_source(system, fit, source, sizes.gaussian_sd)
    points = np.unique(campaign_operating(campaign, system), axis=0)
    finite = np.isfinite(points.reshape(len(points), -1)).all(axis=1)
    config = GenerationConfig(
        system.training_points(points[finite]),
        runs_per_state=sizes.runs_per_state,
        validation_fraction=sizes.validation_fraction,
        chunk_size=sizes.chunk_size,
        spec=CNNInputSpec(
            fmax=system.features.classifier_fmax,
            nperseg=system.features.classifier_nperseg,
            envelope_band=system.features.classifier_envelope_band,
        ),
    )
    stage = {
        "fit": fit_hash,
        "source": source,
        "parameters": params.describe(),
        "model_error": None,
        "generation": config.to_dict(),
        "seed": seed,
    }
    return Generation(stage, params, config)


class FitFunction(Protocol):
    """The model-updating function of a job (:func:`run_job`'s ``fit``).

    Called as ``fit(system, calibration, method=, seed=, quick=, progress=,
    **config.fit_options)`` on the healthy calibration runs; returns a ``FitResult``-like
    object (``point``, ``j``, ``posterior_draws()``, ``model_error_draws()``,
    ``save(folder)``). The default, :func:`bayesdoor.inference.fit_campaign`, lets CMA-ES
    search the integer parameters (the door's contact-law index) unless the fit options
    hold them (``fixed={"I": 3}``).
    """

    def __call__(
        self,
        system: AbstractSystem,
        calibration: xr.Dataset,
        *,
        method: str,
        seed: int,
        quick: bool,
        progress: bool,
        **options: Any,
    ) -> Any: ...


class DiagnoseFunction(Protocol):
    """The diagnosis of a job (:func:`run_job`'s ``diagnose``).

    Called as ``diagnose(system, campaign, fit_folder, seed=, quick=, progress=)`` with the
    folder of the saved fit; returns an object with ``to_json()``
    (:class:`bayesdoor.diagnose.Diagnosis`). A function that takes a ``pool`` keyword gets
    the job's (where its refits and limits run). The default is
    :func:`bayesdoor.pipeline.default_diagnose`
    (:func:`bayesdoor.diagnose.diagnose_campaign`); a ``ValueError`` it raises (a campaign
    it cannot diagnose, for example too few runs) leaves the job without a verdict.
    """

    def __call__(
        self,
        system: AbstractSystem,
        campaign: xr.Dataset,
        fit_folder: Path,
        *,
        seed: int,
        quick: bool,
        progress: bool,
    ) -> Any: ...


def run_job(
    system: AbstractSystem,
    campaign: xr.Dataset,
    out: str | Path,
    config: JobConfig | None = None,
    *,
    fit: FitFunction | None = None,
    diagnose: DiagnoseFunction | None = None,
    cluster: Cluster | Pool | None = None,
    progress: bool = True,
    report: Callable[[str], None] = print,
    overwrite: bool = False,
) -> JobResult:
    """Fit on the calibration runs, simulate training data, train, classify the test runs, report.

    Every stage writes under ``out/<stage>/`` (the module docstring) and is reused when it is
    finished with the same configuration (a changed setting recomputes the stages it reaches).
    Fitting, training, calibration and thresholds never see the test runs.

    Parameters
    ----------
    system
        The simulated system (its parameters, states and simulator).
    campaign
        A measurement campaign (docs/data.md): fit on its healthy calibration runs
        (:func:`bayesdoor.inference.calibration_runs`), classify its test runs
        (:func:`runs_to_classify`).
    out
        The job's folder.
    config
        What the job computes (:class:`JobConfig`; ``None``: its defaults, the paper's sizes).
    fit
        The model-updating function (:class:`FitFunction`); ``None``:
        :func:`bayesdoor.inference.fit_campaign`.
    diagnose
        The diagnosis (:class:`DiagnoseFunction`); ``None``: :func:`default_diagnose`. When
        it raises ``ValueError`` the job goes on: the diagnosis JSON holds ``error`` and no
        verdict, the report says why, and the next run tries again.
    cluster
        Where the training-data generation and the diagnosis's refits and limits run
        (:class:`bayesdoor.Cluster`; ``None``: this process; an open
        :class:`~bayesdoor.Pool`, such as the extended job's, is used as it is). Neither the
        results nor the stages' cache keys depend on it: every task has its own seed.
    progress
        Show the progress bars of the stages.
    report
        Receives one line per stage event.
    overwrite
        Let a job of other settings replace the finished job in ``out`` (stages whose
        configuration did not change are still reused).

    Returns
    -------
    JobResult

    Raises
    ------
    ValueError
        For a campaign without a healthy run to fit on, or a source the fit cannot serve.
    FileExistsError
        When ``out`` holds a finished job of other settings (and ``overwrite`` is false), or
        files that are not a job's; nothing is written then.
    """
    config = JobConfig() if config is None else config
    out = Path(out)
    settings = config.settings(describe_system(system), digest_runs(campaign))
    job_hash = configuration_hash(settings)
    calibration = campaign.isel(run=calibration_runs(campaign, system.healthy))
    _check_folder(out, settings, job_hash, overwrite)
    out.mkdir(parents=True, exist_ok=True)
    stages = _Stages(out, report, progress, _versions())
    with _opened(cluster) as pool:
        result = _composed(stages, system, campaign, calibration, config, fit, diagnose, pool)
    _write_job_record(out, _job_record(job_hash, system.name, settings, result))
    return result


def _job_record(
    job_hash: str, system_name: str, settings: dict[str, Any], result: JobResult
) -> dict[str, Any]:
    """``job.json``: the settings, the stages' hashes and the verdicts of the finished job."""
    adequacy, trust, diagnosis = result.adequacy or {}, result.trust or {}, result.diagnosis
    return {
        "job_hash": job_hash,
        "system": system_name,
        **{k: v for k, v in settings.items() if k != "system"},
        "stages": {r.name: r.config_hash for r in result.stages},
        "metrics": result.classification.get("metrics"),
        "adequacy": adequacy.get("verdict"),
        "trust": trust["verdict"],
        "trust_reasons": trust["reasons"],
        "verdict": None if diagnosis is None else diagnosis.get("verdict"),
        "report": None if result.report is None else str(result.report),
        "extended": None
        if result.extended is None
        else {
            **(result.extended.extends or {}),
            "out": str(result.extended.out),
            "metrics": result.extended.classification.get("metrics"),
            "trust": (result.extended.trust or {}).get("verdict"),
        },
    }


def _write_job_record(out: Path, record: dict[str, Any]) -> None:
    text = json.dumps(record, indent=1, default=float) + "\n"
    atomic_write(out / "job.json", lambda tmp: tmp.write_text(text), overwrite=True)


@dataclasses.dataclass(frozen=True)
class _Stages:
    """How one job runs its stages: in its folder, with its progress lines and bars, keyed
    with the libraries' versions; the record of every stage made or reused, in order."""

    out: Path
    report: Callable[[str], None]
    progress: bool
    versions: dict[str, str]
    records: list[StageRecord] = dataclasses.field(default_factory=list)

    def run(
        self,
        name: str,
        config: dict[str, Any],
        compute: Callable[[Path], None],
        *,
        resumable: bool = False,
    ) -> StageRecord:
        """Make the stage ``name`` (or reuse it when finished with ``config``)."""
        record = run_stage(self.out, name, config, compute, resumable=resumable, report=self.report)
        self.records.append(record)
        return record


class _Made(NamedTuple):
    """A stage's product, the key that later stages' keys hold, and its folder (``None``
    for an optional stage that could not be made: its key is then its reason's)."""

    product: Any
    key: str
    path: Path | None = None

    @classmethod
    def of(cls, record: StageRecord, product: Any) -> _Made:
        return cls(product, record.config_hash, record.path)

    def folder(self) -> Path:
        """The stage's folder (a required stage always has one)."""
        assert self.path is not None, "a stage that was not made has no folder"
        return self.path


def _composed(
    stages: _Stages,
    system: AbstractSystem,
    campaign: xr.Dataset,
    calibration: xr.Dataset,
    config: JobConfig,
    fit: FitFunction | None,
    diagnose: DiagnoseFunction | None,
    pool: Pool,
) -> JobResult:
    """The job's stages in order, each given the products of the stages it reads (``fit``
    and ``diagnose``: ``None`` for the defaults)."""
    if pool.address is not None:
        stages.report(f"cluster: {pool.address}")
    fit = _default_fit if fit is None else fit
    diagnose = _with_pool(default_diagnose if diagnose is None else diagnose, pool)
    key = jax.random.key(config.seed)
    fitted = _fit(stages, system, calibration, config, fit)
    generated = _generated(stages, system, campaign, fitted, config, key, pool)
    adequacy = _adequacy(stages, system, calibration, generated, config)
    trained = _trained(stages, system, calibration, fitted, generated, config, key)
    classified = _classified(stages, system, campaign, trained)
    trust = _trusted(stages, system, calibration, generated, trained, classified, adequacy, config)
    diagnosis = None
    if config.effective_diagnosis:
        diagnosis = _diagnosed(stages, system, campaign, calibration, fitted, config, diagnose)
    extension = None
    if config.extend:
        extension = _extension(stages, system, campaign, config, fit, pool, diagnosis)
    findings = JobFindings(
        fit=fitted.product,
        diagnosis=None if diagnosis is None else diagnosis.product,
        adequacy=adequacy.product,
        trust=trust.product,
        extension=None if extension is None else _extension_report(extension, classified, trust),
    )
    report = None
    if config.html:
        made = (fitted, classified, trained, trust, diagnosis)
        report = _reported(stages, system, made, findings, extension)
    return JobResult(
        out=stages.out,
        stages=tuple(stages.records),
        fit=fitted.product,
        classification=classified.product,
        report=report,
        diagnosis=findings.diagnosis,
        adequacy=adequacy.product,
        trust=trust.product,
        extended=None if extension is None else extension.result,
        extension=None if extension is None else extension.summary,
    )


def _discrepancy(config: JobConfig) -> bool:
    """The default source carries the model error as measured: the calibration runs'
    discrepancy from the simulated healthy runs, added to every training run."""
    return config.effective_source == "posterior+model_error"


def _discrepancy_form(config: JobConfig) -> str | None:
    return DISCREPANCY_FORM if _discrepancy(config) else None


def _fit(
    stages: _Stages,
    system: AbstractSystem,
    calibration: xr.Dataset,
    config: JobConfig,
    fit: FitFunction,
) -> _Made:
    """The fit on the healthy calibration runs (:class:`FitSummary`)."""

    def compute(folder: Path) -> None:
        result = fit(
            system,
            calibration,
            method=config.method,
            seed=config.effective_fit_seed,
            quick=config.quick,
            progress=stages.progress,
            **config.fit_options,
        )
        result.save(folder / "result")
        FitSummary.from_result(result, config.method).save(folder)

    key = {
        "system": describe_system(system),
        "calibration_runs": digest_runs(calibration),
        "method": config.method,
        "seed": config.effective_fit_seed,
        "quick": config.quick,
        "options": {k: repr(v) for k, v in config.fit_options.items()},
        "versions": stages.versions,
    }
    record = stages.run("fit", key, compute)
    return _Made.of(record, FitSummary.load(record.path))


def _generated(
    stages: _Stages,
    system: AbstractSystem,
    campaign: xr.Dataset,
    fitted: _Made,
    config: JobConfig,
    key: jax.Array,
    pool: Pool,
) -> _Made:
    """The simulated training data (its folder; the product is the :class:`Generation`)."""
    generation = generation_settings(
        system,
        campaign,
        fitted.product,
        fitted.key,
        config.effective_source,
        config.effective_sizes,
        config.seed,
    )

    def compute(folder: Path) -> None:
        generate(
            system,
            generation.source,
            generation.generation,
            folder / "data",
            key=jax.random.fold_in(key, 1),
            progress=stages.progress,
            execution=Execution(scheduler=pool.address),
        )

    record = stages.run("generate", generation.config, compute, resumable=True)
    return _Made.of(record, generation)


def _training_data(
    system: AbstractSystem, calibration: xr.Dataset, generated: _Made, config: JobConfig
) -> TrainingData:
    return training_data(
        generated.folder() / "data",
        calibration,
        discrepancy=_discrepancy(config),
        seed=config.seed,
        system=system,
    )


def _adequacy(
    stages: _Stages,
    system: AbstractSystem,
    calibration: xr.Dataset,
    generated: _Made,
    config: JobConfig,
) -> _Made:
    """Whether the simulations reproduce the measured healthy runs (the adequacy JSON)."""

    def compute(folder: Path) -> None:
        check_adequacy(
            generated.folder() / "data",
            calibration,
            seed=config.seed,
            discrepancy=_discrepancy(config),
            system=system,
        ).save(folder)

    key = {
        "data": generated.key,
        "runs": digest_runs(calibration),
        "seed": config.seed,
        "discrepancy": _discrepancy_form(config),
        "check": ADEQUACY_CHECK,
    }
    record = stages.run("adequacy", key, compute)
    adequacy = json.loads((record.path / ADEQUACY_JSON).read_text())
    if adequacy.get("summary"):
        stages.report(f"adequacy: {adequacy['summary']}")
    return _Made.of(record, adequacy)


def _trained(
    stages: _Stages,
    system: AbstractSystem,
    calibration: xr.Dataset,
    fitted: _Made,
    generated: _Made,
    config: JobConfig,
    key: jax.Array,
) -> _Made:
    """The calibrated ensemble, its bands and the system's signature reference (a folder)."""

    def compute(folder: Path) -> None:
        data = _training_data(system, calibration, generated, config)
        train_stage(
            data,
            folder,
            key=jax.random.fold_in(key, 2),
            config=config.effective_sizes.train,
            ood_quantile=config.effective_sizes.ood_quantile,
            progress=stages.progress,
            ood_model_error=ood_model_error(
                data, calibration, fitted.product, key=jax.random.fold_in(key, 3), system=system
            ),
        )
        signature_stage(folder, calibration, system)

    stage_key = {
        "data": generated.key,
        "sizes": config.effective_sizes.to_json(),
        "seed": config.seed,
        "ood": "model-error draws",
        "discrepancy": _discrepancy_form(config),
        # the stage also writes the system's signature reference (from the calibration runs,
        # which the fit's hash, through the generation's, already follows)
        "writes": [ENSEMBLE, BANDS, SIGNATURES],
    }
    record = stages.run("train", stage_key, compute)
    return _Made.of(record, record.path)


def _classified(
    stages: _Stages, system: AbstractSystem, campaign: xr.Dataset, trained: _Made
) -> _Made:
    """The test runs classified (the classification JSON of docs/data.md)."""
    test = runs_to_classify(campaign)
    found = np.isin(campaign["run"].values, test["run"].values)
    indices = [int(i) for i in np.flatnonzero(found)]

    def compute(folder: Path) -> None:
        classify_stage(trained.folder(), test, folder, run_index=indices, system=system)

    key = {"model": trained.key, "runs": digest_runs(test), "indices": indices}
    record = stages.run("classify", key, compute)
    return _Made.of(record, json.loads((record.path / "classification.json").read_text()))


def _trusted(
    stages: _Stages,
    system: AbstractSystem,
    calibration: xr.Dataset,
    generated: _Made,
    trained: _Made,
    classified: _Made,
    adequacy: _Made,
    config: JobConfig,
) -> _Made:
    """Whether the classification can be trusted (the trust JSON)."""

    def compute(folder: Path) -> None:
        judge_classification(
            trained.folder(),
            Classification.load(classified.folder()),
            Adequacy.load(adequacy.folder()),
            _training_data(system, calibration, generated, config),
            calibration,
            seed=config.seed,
            system=system,
        ).save(folder)

    key = {
        "model": trained.key,
        "classification": classified.key,
        "adequacy": adequacy.key,
        "checks": TRUST_CHECKS,
        "runs": digest_runs(calibration),
        "seed": config.seed,
        "discrepancy": _discrepancy_form(config),
    }
    record = stages.run("trust", key, compute)
    trust = json.loads((record.path / TRUST_JSON).read_text())
    said = trust["reasons"] + trust.get("warnings", [])
    stages.report(f"trust: {trust['verdict']}" + (": " + "; ".join(said) if said else ""))
    return _Made.of(record, trust)


def _diagnosed(
    stages: _Stages,
    system: AbstractSystem,
    campaign: xr.Dataset,
    calibration: xr.Dataset,
    fitted: _Made,
    config: JobConfig,
    diagnose: DiagnoseFunction,
) -> _Made:
    """The diagnosis JSON (with ``report`` its HTML); a campaign the diagnosis cannot handle
    leaves the job going, with ``error`` in place of a verdict and its reason's key."""

    def compute(folder: Path) -> None:
        diagnosis_stage(
            system,
            campaign,
            Fitted.load(fitted.folder()),
            folder,
            diagnose=diagnose,
            seed=config.seed,
            quick=config.quick,
            progress=stages.progress,
        )

    key = {
        "fit": fitted.key,
        "runs": digest_runs(calibration),
        "seed": config.seed,
        "quick": config.quick,
        "versions": stages.versions,
        # the object beside the JSON (what extending the system reads): a diagnosis made
        # without it is made again
        "keeps": DIAGNOSIS_OBJECT,
    }
    try:
        record = stages.run("diagnose", key, compute)
    except ValueError as err:
        # the job stands without it: it reports why and tries again next time
        reason = " ".join(str(err).split())
        stages.report(f"diagnose: not made: {reason}")
        failed: dict[str, Any] = {"verdict": None, "causes": [], "error": reason, "report": None}
        return _Made(failed, configuration_hash({"error": reason}))
    diagnosis = json.loads((record.path / DIAGNOSIS_JSON).read_text())
    diagnosis["report"] = str(record.path / DIAGNOSIS_HTML)
    return _Made.of(record, diagnosis)


def _reported(
    stages: _Stages,
    system: AbstractSystem,
    made: tuple[_Made, _Made, _Made, _Made, _Made | None],
    findings: JobFindings,
    extension: _Extension | None,
) -> Path:
    """The campaign's HTML report (its ``index.html``), from the fit, the classification,
    the ensemble, the trust and the diagnosis (``made``, in that order) and what they found."""
    fitted, classified, trained, trust, diagnosis = made

    def compute(folder: Path) -> None:
        report_stage(
            classified.folder(),
            trained.folder(),
            folder,
            title=f"{system.name}: damage report",
            findings=findings,
        )

    key: dict[str, Any] = {
        "classification": classified.key,
        "fit": fitted.key,
        "diagnosis": None if diagnosis is None else diagnosis.key,
        "trust": trust.key,
        "versions": stages.versions,
    }
    if extension is not None:
        key["extended"] = extension.config()
    record = stages.run("report", key, compute)
    return record.path / "index.html"


class _Extension(NamedTuple):
    """The job on the system extended by the diagnosis's verdict, or why there is none."""

    #: the extended job (``None`` when nothing was extended)
    result: JobResult | None
    #: ``verdict``, ``configuration``, ``held`` of the extension, or ``reason``
    summary: dict[str, Any]

    def config(self) -> dict[str, Any]:
        """What the base job's report shows of it (for the report's configuration hash)."""
        stages = {} if self.result is None else {s.name: s.config_hash for s in self.result.stages}
        return {**self.summary, "stages": stages}


def _not_extended(diagnosis: Mapping[str, Any] | None) -> str | None:
    """Why a diagnosis extends nothing (``None`` when its verdict names a cause)."""
    if diagnosis is None:
        return "the job has no diagnosis"
    if diagnosis.get("error"):
        return f"the diagnosis could not be made ({diagnosis['error']})"
    verdict = diagnosis.get("verdict")
    if verdict is None:
        return "no cause of the diagnosis has decisive held-out evidence (no verdict)"
    if verdict == NONE:
        return "the diagnosis's verdict is none: the model explains the healthy calibration runs"
    return None


def _extension(
    stages: _Stages,
    system: AbstractSystem,
    campaign: xr.Dataset,
    config: JobConfig,
    fit: FitFunction,
    pool: Pool,
    diagnosis: _Made | None,
) -> _Extension:
    """Run the job on the system extended by the diagnosis's verdict (``out/extended``)."""
    reason = _not_extended(None if diagnosis is None else diagnosis.product)
    if reason is not None:
        stages.report(f"extend: nothing extended: {reason}")
        return _Extension(None, {"reason": reason})
    assert diagnosis is not None
    folder = diagnosis.folder()
    if not (folder / DIAGNOSIS_OBJECT).is_file():
        reason = (
            f"{folder} keeps no diagnosis object ({DIAGNOSIS_OBJECT}) to extend the system by "
            "(the diagnosis function returned one that cannot be pickled)"
        )
        stages.report(f"extend: nothing extended: {reason}")
        return _Extension(None, {"reason": reason})
    kept = kept_diagnosis(folder)
    found = verdict_extension(system, kept)
    if found is None:  # the JSON's verdict is the object's: a hand-edited folder
        raise ValueError(f"{folder}: {DIAGNOSIS_OBJECT} and {DIAGNOSIS_JSON} disagree")
    extends = {
        "verdict": found.name,
        "configuration": found.proposal.label,
        "held": dict(found.values),
    }
    held = ", ".join(f"{k} = {v:.4g}" for k, v in found.values.items())
    stages.report(f"extend: {found.name} ({found.proposal.label}), held at {held}")
    result = run_job(
        extend_system(system, kept),
        campaign,
        stages.out / EXTENDED,
        dataclasses.replace(config, diagnosis=False, extend=False),
        fit=fit,
        cluster=pool,
        progress=stages.progress,
        report=lambda line: stages.report(f"{EXTENDED}/{line}"),
        # the folder is this job's: it follows the diagnosis, whatever it held before
        overwrite=True,
    )
    return _Extension(dataclasses.replace(result, extends=extends), extends)


def _extension_report(extension: _Extension, classified: _Made, trust: _Made) -> dict[str, Any]:
    """What the report's section on the extension shows: before and after, or why not."""

    def scores(classification, trust, report):
        metrics = classification.get("metrics") or {}
        return {
            "accuracy": metrics.get("accuracy"),
            "ece": metrics.get("ece"),
            "trust": (trust or {}).get("verdict"),
            "report": report,
        }

    extended = extension.result
    # links are relative: the report is written in a temporary sibling of its folder
    return {
        **extension.summary,
        "before": scores(classified.product, trust.product, None),
        "after": None
        if extended is None
        else scores(
            extended.classification,
            extended.trust,
            None if extended.report is None else f"../{EXTENDED}/report/{extended.report.name}",
        ),
    }


@contextlib.contextmanager
def _opened(cluster: Cluster | Pool | None) -> Iterator[Pool]:
    """The pool of ``cluster`` for the length of a job (an open pool as it is)."""
    if isinstance(cluster, Pool):
        yield cluster
        return
    with (Cluster() if cluster is None else cluster).open() as pool:
        yield pool


def _with_pool(diagnose: Callable[..., Any], pool: Pool) -> Callable[..., Any]:
    """``diagnose`` given the job's pool, when it takes one."""
    try:
        takes = "pool" in inspect.signature(diagnose).parameters
    except (TypeError, ValueError):  # a callable without a signature
        takes = False
    return functools.partial(diagnose, pool=pool) if takes else diagnose
