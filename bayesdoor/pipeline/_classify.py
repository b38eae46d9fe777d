"""The stages after the training data: train and calibrate, classify runs, write the report."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr

from ..classify import (
    SELECTIVE_RISK,
    Ensemble,
    FitOptions,
    TrainConfig,
    classification_metrics,
    combine_evidence,
    fit_classifier,
    load_ensemble,
    predict,
    risk_coverage,
    risk_upper_bound,
    save_ensemble,
    select_calls,
)
from ..datagen import (
    TrainingData,
    calibration_residuals,
    campaign_features,
    measurement_variance,
    model_error_draws,
)
from ..datagen._points import point_key
from ..features import CNNInputSpec
from ..io import atomic_write, system_of
from ..io import operating as campaign_operating
from ..report import ReportContext, diagnosis_section, extension_section, write_damage_report
from ..systems import HEALTHY, AbstractSystem
from ._bands import PredictiveBands
from ._fit import FitSummary
from ._stages import Finished, StageRecord, stage_in

ENSEMBLE = "ensemble.eqx"
BANDS = "bands.npz"
#: the system's signature reference beside the ensemble (systems with a signature check)
SIGNATURES = "signatures.json"


#: the largest probability of a wrong call a run may carry and still count as placed: a run
#: whose calibrated probability of its predicted state is below 1 - MAX_ERROR is flagged
#: ``uncertain`` (with calibrated probabilities, 1 - p is the chance that the call is wrong)
MAX_ERROR = 0.1


def _write_json(path: Path, payload: Any) -> None:
    text = json.dumps(payload, indent=1, default=float, allow_nan=False) + "\n"
    atomic_write(path, lambda tmp: tmp.write_text(text), overwrite=True)


def as_saved(payload: Any) -> Any:
    """``payload`` as :func:`_write_json` saves it and ``json.load`` reads it back (numpy
    scalars as Python numbers, tuples as lists), so that a product computed now and one read
    from its folder are the same."""
    return json.loads(json.dumps(payload, default=float, allow_nan=False))


def _clean(value: float) -> float | None:
    """A float for JSON: NaN and infinities become ``None``."""
    value = float(value)
    return value if math.isfinite(value) else None


def _operating(value) -> float | list[float | None] | None:
    """A run's operating point for the JSON: a number, or a list for several conditions."""
    value = np.asarray(value, dtype=float)
    return _clean(float(value)) if value.ndim == 0 else [_clean(float(v)) for v in value]


def _named(conditions: tuple[str, ...], point) -> dict[str, float | None]:
    """A run's operating conditions by name (none when the system is not known)."""
    values = np.broadcast_to(np.asarray(point, dtype=float), (len(conditions),))
    return {c: _clean(float(v)) for c, v in zip(conditions, values, strict=True)}


def _metrics(probabilities: np.ndarray, labels: np.ndarray) -> dict[str, Any]:
    metrics = classification_metrics(probabilities, labels)
    return {k: (v if isinstance(v, list) else _clean(v)) for k, v in metrics.items()} | {
        "runs": int(labels.size)
    }


@dataclasses.dataclass(frozen=True)
class Trained(Finished):
    """The product of the ``train`` stage: the folder of the calibrated ensemble
    (:data:`ENSEMBLE`), its ``training.json``, the predictive bands (:data:`BANDS`) and the
    system's signature reference (:data:`SIGNATURES`), written by :func:`train_stage` and
    :func:`signature_stage`.

    Attributes
    ----------
    training
        ``training.json`` (states, healthy state, temperature, OOD threshold, simulated
        validation).
    stage
        The record of the stage that made it.
    """

    training: dict[str, Any]
    stage: StageRecord | None = None

    @classmethod
    def load(cls, folder: Path) -> Trained:
        """Read ``training.json`` of the ensemble in ``folder``."""
        return cls(json.loads((folder / "training.json").read_text()), stage_in(folder))


def train_stage(
    data: TrainingData,
    folder: Path,
    *,
    key,
    config: TrainConfig,
    ood_quantile: float,
    progress: bool,
    ood_model_error: np.ndarray | None = None,
) -> None:
    """Train the ensemble on the training split, calibrate it and fit its OOD detector.

    ``ood_model_error`` (draws from :func:`ood_model_error`) makes the detector compare
    inputs with measurements of the simulated states rather than with simulations alone.

    Writes ``ensemble.eqx``, ``training.json`` (counts, temperature, OOD threshold, loss
    history, simulated validation metrics before and after the temperature) and ``bands.npz``
    (the posterior-predictive bands of the features).
    """
    train, val = data.subset("train"), data.subset("validation")
    if val.labels.size == 0:
        raise ValueError(
            "the training data has no validation runs: the temperature and the OOD threshold "
            "need held-out simulated runs; use a validation_fraction > 0"
        )
    training = fit_classifier(
        jnp.asarray(train.features),
        jnp.asarray(train.labels),
        jnp.asarray(val.features),
        jnp.asarray(val.labels),
        data.states,
        key=key,
        config=config,
        options=FitOptions(
            ood_quantile=ood_quantile,
            ood_model_error=ood_model_error,
            progress="rich" if progress else "none",
        ),
    )
    ensemble = training.ensemble
    save_ensemble(folder / ENSEMBLE, ensemble)
    x_val = jnp.asarray(val.features)
    calibrated = np.asarray(predict(ensemble, x_val).probabilities)
    raw = np.asarray(predict(_with_temperature(ensemble, 1.0), x_val).probabilities)
    PredictiveBands.from_training_data(data).save(folder / BANDS)
    _write_json(
        folder / "training.json",
        {
            "states": list(data.states),
            "healthy_state": data.healthy,
            "spec": data.manifest["config"]["spec"],
            "counts": data.counts(),
            "temperature": float(ensemble.temperature),
            "ood_threshold": None if ensemble.ood is None else float(ensemble.ood.threshold),
            "ood_quantile": ood_quantile,
            "ood_model_error_draws": 0 if ensemble.ood is None else ensemble.ood.model_error_draws,
            "train_config": config.to_json(),
            "final_loss": np.asarray(training.loss[-1], dtype=float).tolist(),
            "validation": {
                "uncalibrated": _metrics(raw, val.labels),
                "calibrated": _metrics(calibrated, val.labels),
                "probabilities": calibrated.tolist(),
                "labels": val.labels.tolist(),
            },
        },
    )


def _system_signals(campaign: xr.Dataset, system: AbstractSystem) -> np.ndarray | None:
    """The campaign's records ``(run, channel, time)`` in the system's channel order (``None``
    when a channel of the system is missing)."""
    names = [str(c) for c in campaign["channel"].values]
    if not all(c in names for c in system.channels):
        return None
    acc = campaign["acceleration"].sel(channel=list(system.channels))
    return np.asarray(acc.transpose("run", "channel", "time").values, dtype=float)


def signature_stage(
    folder: Path, calibration: xr.Dataset, system: AbstractSystem | None = None
) -> None:
    """Write the system's signature reference from the healthy calibration runs.

    ``signatures.json`` beside the ensemble (``system``, ``runs``, ``reference``), read by
    :func:`classify_stage` to check each call against the signal
    (:meth:`~bayesdoor.systems.AbstractSystem.signatures`). Nothing is written for a system
    without a signature check, or when its channels are not in the records.
    """
    system = system_of(calibration) if system is None else system
    if system is None:
        return
    signals = _system_signals(calibration, system)
    if signals is None:
        return
    reference = system.signature_reference(signals, campaign_operating(calibration, system))
    if reference is None:
        return
    _write_json(
        folder / SIGNATURES,
        {"system": system.name, "runs": int(signals.shape[0]), "reference": reference},
    )


def _signature_agreement(
    model_dir: Path, campaign: xr.Dataset, system: AbstractSystem | None, ok: np.ndarray
) -> tuple[list[dict[str, bool | None] | None], float | None]:
    """Per run, the system's signature check (``None`` for a run not checked: no reference
    beside the ensemble, no system, a channel missing, or a run not classified), and the
    check's stated false-alarm rate (``None`` when the reference states none)."""
    checks: list[dict[str, bool | None] | None] = [None] * len(ok)
    path = model_dir / SIGNATURES
    if system is None or not path.is_file() or not ok.any():
        return checks, None
    stored = json.loads(path.read_text())
    if stored["system"] != system.name:
        raise ValueError(
            f"the ensemble's signature reference ({path}) is of system {stored['system']!r}, "
            f"the campaign's is {system.name!r}: classify a campaign of the system it was "
            "trained for"
        )
    signals = _system_signals(campaign, system)
    if signals is None:
        return checks, None
    good = np.flatnonzero(ok)
    operating = np.asarray(campaign_operating(campaign, system))[good]
    checked = system.signatures(stored["reference"], signals[good], operating)
    for i, agreement in zip(good, checked, strict=True):
        checks[i] = agreement
    alpha = stored["reference"].get("false_alarm_rate")
    return checks, None if alpha is None else float(alpha)


def _with_evidence(
    probabilities: np.ndarray,
    agreement: list[dict[str, bool | None] | None],
    alpha: float | None,
    classes: list[str],
    healthy_state: str,
    ok: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any] | None]:
    """The runs' probabilities weighed against the signature check
    (:func:`bayesdoor.classify.combine_evidence`), each run's probability that the ensemble's
    probabilities hold, and the campaign's summary; the ensemble's probabilities unchanged
    without a check, a stated false-alarm rate or the class ``healthy_state``."""
    applies = np.full(len(probabilities), np.nan)
    if alpha is None or healthy_state not in classes or all(a is None for a in agreement):
        return probabilities, applies, None
    healthy = classes.index(healthy_state)
    shows = np.full(probabilities.shape, np.nan)
    for i, check in enumerate(agreement):
        for k, c in enumerate(classes):
            value = None if check is None else check.get(c)
            if k != healthy and value is not None:
                shows[i, k] = float(value)
    good = np.flatnonzero(ok)
    evidence = combine_evidence(probabilities[good], shows[good], healthy, alpha)
    combined = probabilities.copy()
    combined[good] = evidence.probabilities
    applies[good] = evidence.applies
    summary = {
        "model": (
            "per run, either the ensemble's probabilities hold (the check then adds nothing "
            "to them) or only its healthy share does and the damage states share the rest, "
            "the check then the only evidence of which; a damage state's signature shows "
            "with rate d on its own runs, l on other damage, the false-alarm rate on healthy "
            "runs; the share pi of runs the ensemble holds for, d and l learned from the "
            "campaign's checked runs without labels (docs/classification.md)"
        ),
        "false_alarm_rate": evidence.alpha,
        "checked_runs": evidence.checked,
        "pi": list(evidence.pi),
        "detection": {classes[k]: list(v) for k, v in evidence.detection.items()},
        "leak": {classes[k]: list(v) for k, v in evidence.leak.items()},
    }
    return combined, applies, summary


def _selective(probabilities: np.ndarray, ok: np.ndarray, risk: float | None):
    """The runs called at the selective ``risk`` (:func:`bayesdoor.classify.select_calls` over
    the classified runs) and its JSON summary; every classified run called when ``risk`` is
    ``None``."""
    called = ok.copy()
    if risk is None or not ok.any():
        return called, None
    selection = select_calls(probabilities[ok], risk)
    called[ok] = selection.called
    return called, {
        "target_risk": risk,
        "threshold": selection.threshold,
        "expected_risk": selection.expected_risk,
        "called": int(selection.called.sum()),
        "runs": int(ok.sum()),
        "rule": (
            "the runs are called from the most probable down while the mean of 1 - p over the "
            "calls (their expected share of wrong calls) stays at most the target"
        ),
    }


def healthy_state(record: dict[str, Any] | None, system: AbstractSystem | None = None) -> str:
    """The healthy state a job's products were made for: the ``healthy_state`` of
    ``record`` (``training.json`` or ``classification.json``), else ``system``'s, else
    :data:`~bayesdoor.systems.HEALTHY`."""
    if record is not None and "healthy_state" in record:
        return str(record["healthy_state"])
    return HEALTHY if system is None else system.healthy


def runs_in_state(campaign: xr.Dataset, state: str) -> xr.Dataset:
    """The runs of ``campaign`` whose ``state`` is ``state``."""
    states = np.asarray(campaign["state"].values).astype(str)
    return campaign.isel(run=np.flatnonzero(states == state))


def data_spec(data: TrainingData) -> CNNInputSpec:
    """The classifier input the training data were computed with (its generation's spec)."""
    spec = data.manifest.get("config", {}).get("spec")
    return CNNInputSpec() if spec is None else CNNInputSpec(**spec)


def ood_model_error(
    data: TrainingData,
    calibration: xr.Dataset,
    fit: FitSummary,
    *,
    key: jax.Array,
    draws: int = 4000,
    system: AbstractSystem | None = None,
) -> np.ndarray:
    """Draws of the model error for the OOD detector, from the fit and its calibration runs.

    Each draw is the residual of one healthy calibration run about the simulated healthy mean
    at its speed (:func:`bayesdoor.datagen.calibration_residuals`: the structured
    discrepancy the model leaves) plus independent per-feature scatter with the variance the
    fit's likelihood gives a measured feature (Welch scatter and the posterior of the model
    error, :func:`bayesdoor.datagen.measurement_variance`). Without healthy calibration runs,
    or when a calibration run's operating point has no simulated healthy training run, only
    the scatter is drawn.
    """
    healthy = runs_in_state(calibration, data.healthy)
    speeds = campaign_operating(healthy, system)
    # operating points as keys: numbers for one condition, tuples (rows) for several; the
    # residuals need simulated healthy runs at every calibration run's point
    train = data.subset("train")
    simulated = (
        {
            point_key(p)
            for p, label in zip(np.asarray(train.speeds), train.labels, strict=True)
            if data.states[int(label)] == data.healthy
        }
        if data.healthy in data.states
        else set()
    )
    measured = {point_key(p) for p in np.asarray(speeds)}
    residuals = None
    if healthy.sizes["run"] and simulated and measured <= simulated:
        residuals = calibration_residuals(
            data, campaign_features(healthy, spec=data_spec(data)), speeds, state=data.healthy
        )
    return model_error_draws(
        draws,
        key=key,
        residuals=residuals,
        variance=measurement_variance(data, fit.sigma_model),
    )


def _with_temperature(ensemble: Ensemble, temperature: float) -> Ensemble:
    """The ensemble with another temperature (1 shows the uncalibrated probabilities)."""
    return eqx.tree_at(
        lambda e: e.temperature, ensemble, jnp.asarray(temperature, dtype=ensemble.dtype)
    )


def model_file(model: Path) -> Path:
    """The ensemble of a model folder: ``model/ensemble.eqx`` or ``model/train/ensemble.eqx``.

    Raises
    ------
    ValueError
        When neither exists.
    """
    for candidate in (model / ENSEMBLE, model / "train" / ENSEMBLE, model):
        if candidate.is_file():
            return candidate
    raise ValueError(
        f"--model {model}: no {ENSEMBLE} there or in {model / 'train'}; pass the output "
        "folder of 'bayesdoor run' (or its train/ folder)"
    )


@dataclasses.dataclass(frozen=True)
class Classification(Finished):
    """The product of the ``classify`` stage: ``classification.json`` and ``features.npz``.

    Attributes
    ----------
    payload
        The JSON of docs/data.md (``classes``, ``runs``, ``metrics``, ...).
    features
        The classifier input of each run ``(run, channel, frequency)`` (NaN for a run without).
    frequencies
        The frequency of each feature bin, Hz.
    channels
        The campaign's channel names.
    stage
        The record of the stage that made it (``None`` before it is saved by one).
    """

    payload: dict[str, Any]
    features: np.ndarray
    frequencies: np.ndarray
    channels: tuple[str, ...]
    stage: StageRecord | None = None

    def save(self, folder: Path) -> None:
        """Write ``classification.json`` and ``features.npz`` into ``folder``."""
        _write_json(folder / "classification.json", self.payload)

        def write(tmp: Path) -> None:
            with open(tmp, "wb") as f:
                np.savez(
                    f,
                    features=self.features,
                    frequencies=self.frequencies,
                    channels=np.asarray(self.channels),
                )

        atomic_write(folder / "features.npz", write, overwrite=True)

    @classmethod
    def load(cls, folder: Path) -> Classification:
        """Read what :meth:`save` wrote."""
        payload = json.loads((folder / "classification.json").read_text())
        with np.load(folder / "features.npz", allow_pickle=False) as f:
            features, frequencies = f["features"], f["frequencies"]
            channels = tuple(str(c) for c in f["channels"])
        return cls(payload, features, frequencies, channels, stage_in(folder))


def classify_stage(
    model: Path,
    campaign: xr.Dataset,
    folder: Path,
    *,
    run_index: list[int] | None = None,
    system: AbstractSystem | None = None,
    max_error: float = MAX_ERROR,
    selective_risk: float | None = SELECTIVE_RISK,
) -> None:
    """Write :func:`classify` of ``campaign`` with the ensemble in ``model`` into ``folder``
    (:meth:`Classification.save`)."""
    classify(
        model,
        campaign,
        run_index=run_index,
        system=system,
        max_error=max_error,
        selective_risk=selective_risk,
    ).save(folder)


def classify(
    model: Path,
    campaign: xr.Dataset,
    *,
    run_index: list[int] | None = None,
    system: AbstractSystem | None = None,
    max_error: float = MAX_ERROR,
    selective_risk: float | None = SELECTIVE_RISK,
) -> Classification:
    """Classify every run of ``campaign`` with the ensemble in ``model``.

    The product holds ``classification.json`` (docs/cli.md, the job's JSON: the ensemble's
    ``classes`` and ``healthy_state``, the system's healthy state; per run ``predicted``,
    ``most_probable``, ``abstained``, ``probabilities``, ``entropy``, ``mutual_information``,
    ``ood``, ``uncertain``, ``signatures``, ``corroborated``; ``metrics`` over the runs whose
    true state is one of the classes) and the features. A run is ``uncertain`` when its call
    would be wrong with a probability above ``max_error``: the calibrated probability of the
    predicted state is below ``1 - max_error`` (:data:`MAX_ERROR`; docs/classification.md).
    With a signature reference beside the ensemble (:func:`signature_stage`), each run also
    carries the system's ``signatures`` check and ``corroborated``: whether its signal agrees
    with the call (``False`` flags the run, :func:`run_flagged`). A run whose record is not
    finite, or whose features cannot be computed, is reported with its ``problem`` and no
    prediction; it does not stop the others. Each run's operating conditions are reported
    under their names (``system``: the campaign's; ``None``: the registered one it names).

    With a signature check whose reference states its false-alarm rate, the reported
    ``probabilities`` weigh the ensemble's (``ensemble_probabilities``) against the check
    (:func:`bayesdoor.classify.combine_evidence`; ``applies``: the probability that the
    ensemble's probabilities hold for the run; ``evidence``: what the campaign said of the
    model's rates; ``metrics["ensemble"]``: the ensemble's own metrics). With
    ``selective_risk`` (default :data:`~bayesdoor.classify.SELECTIVE_RISK`; ``None``:
    call every run), the runs are called from the most probable down while their expected
    share of wrong calls stays under that level (:func:`bayesdoor.classify.select_calls`); a
    run left uncalled has ``predicted`` ``None``, ``abstained`` saying why and
    ``most_probable`` naming the state it leans to; ``metrics["selective"]`` holds the
    risk-coverage curve of the labelled runs and the accuracy of those called.
    """
    path = model_file(model)
    ensemble = load_ensemble(path)
    classes = list(ensemble.class_names)
    system = system_of(campaign) if system is None else system
    runs = _campaign_runs(campaign, system, run_index)
    training = path.parent / "training.json"
    record = json.loads(training.read_text()) if training.is_file() else None
    spec = CNNInputSpec() if record is None else CNNInputSpec(**record["spec"])
    healthy = healthy_state(record, system)
    features = _run_features(campaign, runs.problems, spec, ensemble.network.input_shape)
    ok = np.array([p is None for p in runs.problems])
    calls = _calls(ensemble, features, ok, path.parent, campaign, system)
    calls = _weighed(calls, classes, healthy, ok, selective_risk)
    n_run = len(runs.numbers)
    entries = [_run_entry(i, runs, calls, classes, max_error, ok[i]) for i in range(n_run)]
    payload = {
        "classes": classes,
        "healthy_state": healthy,
        "temperature": float(ensemble.temperature),
        "ood_threshold": None if ensemble.ood is None else float(ensemble.ood.threshold),
        "n_runs": n_run,
        "n_failed": int((~ok).sum()),
        "n_ood": int(calls.flags.sum()),
        "max_error": max_error,
        "n_uncertain": sum(bool(r["uncertain"]) for r in entries),
        "n_not_corroborated": sum(r["corroborated"] is False for r in entries),
        "n_abstained": sum(r["abstained"] is not None for r in entries),
        "selective": calls.selective,
        "evidence": calls.evidence,
        "runs": entries,
        "metrics": _campaign_metrics(runs.states, calls, classes, ok),
    }
    if "record" in campaign.variables and campaign["record"].dims == ("run",):
        records = record_votes(entries, np.asarray(campaign["record"].values).astype(str), classes)
        payload["records"] = records
        payload["record_metrics"] = record_metrics(records, classes)
    step = float(campaign.attrs["sampling_rate_hz"]) / spec.nperseg
    return Classification(
        as_saved(payload),
        features,
        np.arange(ensemble.network.input_shape[-1]) * step,
        tuple(str(c) for c in campaign["channel"].values),
    )


class _Runs(NamedTuple):
    """What a classification reports of each run before it is classified."""

    numbers: list[int]
    states: np.ndarray
    conditions: tuple[str, ...]
    speeds: np.ndarray
    #: why a run cannot be classified (``None``: it can), filled in as the features are made
    problems: list[str | None]


def _campaign_runs(
    campaign: xr.Dataset, system: AbstractSystem | None, run_index: list[int] | None
) -> _Runs:
    n_run = campaign.sizes["run"]
    states = (
        np.asarray(campaign["state"].values).astype(str)
        if "state" in campaign.coords
        else np.full(n_run, "unknown")
    )
    conditions = () if system is None else system.condition_names()
    speeds = (
        campaign_operating(campaign, system)
        if system is not None and all(c in campaign for c in conditions)
        else np.full(n_run, np.nan)
    )
    # per run, whether every sample is finite (a boolean reduction: the records are not
    # copied, the signature check reads the system's channels itself)
    acceleration = campaign["acceleration"]
    others = tuple(i for i, d in enumerate(acceleration.dims) if d != "run")
    finite = np.isfinite(acceleration.values).all(axis=others)
    problems: list[str | None] = [
        None if bool(f) else "the record holds non-finite samples" for f in finite
    ]
    index = list(range(n_run)) if run_index is None else list(run_index)
    return _Runs(index, states, conditions, speeds, problems)


def _run_features(
    campaign: xr.Dataset, problems: list[str | None], spec: CNNInputSpec, shape: tuple[int, ...]
) -> np.ndarray:
    """The classifier input of every run, as ``spec`` (the training data's; the default for a
    bare ensemble file) makes it: NaN where it cannot be made, ``problems`` says why."""
    n_run = len(problems)
    features = np.full((n_run, *shape), np.nan)
    good = [i for i in range(n_run) if problems[i] is None]
    if good:
        try:
            features[good] = campaign_features(campaign.isel(run=good), spec=spec)
        except ValueError:
            for i in good:
                try:
                    features[i] = campaign_features(campaign.isel(run=[i]), spec=spec)[0]
                except ValueError as err:
                    problems[i] = f"features failed: {err}"
    for i in range(n_run):
        if problems[i] is None and not np.all(np.isfinite(features[i])):
            problems[i] = "non-finite features (a silent channel or a too short motion window)"
    return features


class _Calls(NamedTuple):
    """The ensemble's view of each run, weighed against the system's signature check."""

    probabilities: np.ndarray
    info: dict[str, np.ndarray]
    flags: np.ndarray
    detector: bool
    agreement: list[dict[str, bool | None] | None]
    alpha: float | None
    ensemble_probabilities: np.ndarray | None = None
    applies: np.ndarray | None = None
    evidence: dict[str, Any] | None = None
    called: np.ndarray | None = None
    selective: dict[str, Any] | None = None


def _calls(
    ensemble: Ensemble,
    features: np.ndarray,
    ok: np.ndarray,
    model_dir: Path,
    campaign: xr.Dataset,
    system: AbstractSystem | None,
) -> _Calls:
    """The ensemble's probabilities, uncertainties and OOD flags of the classifiable runs, and
    the system's signature check of them."""
    n_run = len(ok)
    probabilities = np.full((n_run, len(ensemble.class_names)), np.nan)
    info = {k: np.full(n_run, np.nan) for k in ("entropy", "mi", "expected", "score")}
    flags = np.zeros(n_run, dtype=bool)
    if ok.any():
        pred = predict(ensemble, jnp.asarray(features[ok]))
        probabilities[ok] = np.asarray(pred.probabilities)
        info["entropy"][ok] = np.asarray(pred.entropy)
        info["mi"][ok] = np.asarray(pred.mutual_information)
        info["expected"][ok] = np.asarray(pred.expected_entropy)
        if pred.ood is not None and pred.ood_score is not None:
            info["score"][ok] = np.asarray(pred.ood_score)
            flags[ok] = np.asarray(pred.ood)
    agreement, alpha = _signature_agreement(model_dir, campaign, system, ok)
    return _Calls(probabilities, info, flags, ensemble.ood is not None, agreement, alpha)


def _weighed(
    calls: _Calls, classes: list[str], healthy: str, ok: np.ndarray, risk: float | None
) -> _Calls:
    """``calls`` with the probabilities weighed against the signature check and the runs
    called at the selective ``risk``."""
    probabilities, applies, evidence = _with_evidence(
        calls.probabilities, calls.agreement, calls.alpha, classes, healthy, ok
    )
    called, selective = _selective(probabilities, ok, risk)
    return calls._replace(
        probabilities=probabilities,
        ensemble_probabilities=calls.probabilities,
        applies=applies,
        evidence=evidence,
        called=called,
        selective=selective,
    )


def _run_entry(
    i: int, runs: _Runs, calls: _Calls, classes: list[str], max_error: float, ok: bool
) -> dict[str, Any]:
    """Run ``i``'s entry of ``classification.json``."""
    entry: dict[str, Any] = {
        "run": runs.numbers[i],
        "state": str(runs.states[i]),
        "operating": _operating(runs.speeds[i]),
        **_named(runs.conditions, runs.speeds[i]),
        "predicted": None,
        "most_probable": None,
        "abstained": None,
        "probabilities": None,
        "ensemble_probabilities": None,
        "applies": None,
        "entropy": None,
        "expected_entropy": None,
        "mutual_information": None,
        "ood": None,
        "ood_score": None,
        "uncertain": None,
        "signatures": None,
        "corroborated": None,
        "problem": runs.problems[i],
    }
    if not ok:
        return entry
    assert calls.called is not None and calls.ensemble_probabilities is not None
    probabilities = calls.probabilities[i]
    top = float(np.max(probabilities))
    most = classes[int(np.argmax(probabilities))]
    entry.update(
        predicted=most,
        most_probable=most,
        probabilities={c: float(p) for c, p in zip(classes, probabilities, strict=True)},
        entropy=_clean(calls.info["entropy"][i]),
        expected_entropy=_clean(calls.info["expected"][i]),
        mutual_information=_clean(calls.info["mi"][i]),
        ood=bool(calls.flags[i]) if calls.detector else None,
        ood_score=_clean(calls.info["score"][i]),
        uncertain=bool(top < 1.0 - max_error),
    )
    if calls.evidence is not None and calls.applies is not None:
        ensemble = calls.ensemble_probabilities[i]
        entry.update(
            ensemble_probabilities={c: float(p) for c, p in zip(classes, ensemble, strict=True)},
            applies=_clean(calls.applies[i]),
        )
    if not calls.called[i]:
        entry.update(predicted=None, abstained=_abstention(top, most, calls.selective))
    check = calls.agreement[i]
    if check is not None:
        entry.update(signatures=check, corroborated=check.get(most))
    return entry


def _campaign_metrics(
    states: np.ndarray, calls: _Calls, classes: list[str], ok: np.ndarray
) -> dict[str, Any] | None:
    """The metrics of the classified runs whose true state is one of ``classes``."""
    known = ok & np.isin(states, classes)
    if not known.any():
        return None
    assert calls.called is not None and calls.ensemble_probabilities is not None
    labels = np.array([classes.index(s) for s in states[known]])
    metrics = _metrics(calls.probabilities[known], labels)
    metrics["ood_runs"] = int(calls.flags[known].sum())
    metrics["classes"] = classes
    metrics["selective"] = _selective_metrics(
        calls.probabilities[known], labels, calls.called[known]
    )
    if calls.evidence is not None:
        metrics["ensemble"] = _metrics(calls.ensemble_probabilities[known], labels)
    return metrics


def _abstention(top: float, most: str, selective: dict[str, Any] | None) -> str:
    """Why a classified run is left uncalled at the selective risk."""
    assert selective is not None
    risk = f"{100 * selective['target_risk']:g} %"
    if selective["threshold"] is None:
        return (
            f"its probability of {most}, {top:.3f}, is too low: no run's call keeps the "
            f"expected share of wrong calls under {risk}"
        )
    return (
        f"its probability of {most}, {top:.3f}, is below {selective['threshold']:.3f}, the "
        f"lowest called while the expected share of wrong calls stays under {risk}"
    )


def _selective_metrics(
    probabilities: np.ndarray, labels: np.ndarray, called: np.ndarray
) -> dict[str, Any]:
    """The risk-coverage curve of labelled runs (at most 101 points) and, for the runs called,
    the coverage, their accuracy, their number and the 95 % upper bound of their risk."""
    curve = risk_coverage(probabilities, labels)
    keep = np.unique(np.linspace(0, max(curve.coverage.size - 1, 0), 101).round().astype(int))
    right = probabilities[called].argmax(axis=1) == labels[called]
    return {
        "aurc": _clean(curve.aurc),
        "curve": {
            "threshold": curve.threshold[keep].tolist() if curve.coverage.size else [],
            "coverage": curve.coverage[keep].tolist() if curve.coverage.size else [],
            "risk": curve.risk[keep].tolist() if curve.coverage.size else [],
        },
        "coverage": float(called.mean()),
        "called": int(called.sum()),
        "accuracy": float(right.mean()) if called.any() else None,
        "risk_upper_95": risk_upper_bound(int((~right).sum()), int(called.sum()), 0.05),
    }


def run_flagged(run: dict[str, Any]) -> bool:
    """Whether a run of ``classification.json`` is flagged: not classified, out of
    distribution, uncertain, or not corroborated by the system's signature check (a
    classification without the ``uncertain`` or ``corroborated`` key counts none)."""
    return (
        run["predicted"] is None
        or bool(run["ood"])
        or bool(run.get("uncertain"))
        or run.get("corroborated") is False
    )


def record_votes(
    runs: list[dict[str, Any]], record: np.ndarray, classes: list[str]
) -> list[dict[str, Any]]:
    """Per-record votes of the classified runs, in the order records first appear.

    Parameters
    ----------
    runs
        The runs of ``classification.json`` (``state``, ``predicted``, ``probabilities``,
        ``ood``, ``problem``), in campaign order.
    record
        Each run's record name.
    classes
        The ensemble's classes.

    Returns
    -------
    records
        Per record: ``record``; ``state`` (its runs' true state when they share one, else
        ``None``); ``runs`` and ``classified`` (runs with a prediction); ``votes`` (runs
        called each class); ``majority`` (the class with most votes, a tie broken by the
        higher mean probability; ``None`` when no run is classified); ``mean_probabilities``
        (the classified runs' mean probability of each class); ``share_flagged`` (runs flagged
        out-of-distribution or uncertain, or not classified, per run); ``flagged`` (more than
        half of its runs flagged: the record's vote is not to be relied on); ``shows`` (with
        the system's signature check: per state, the share of its checked runs whose signal
        shows that state's signature, at the check's stated false-alarm rate, read without
        labels; ``None`` without a check).
    """
    order = list(dict.fromkeys(str(r) for r in record))
    out = []
    for name in order:
        members = [runs[i] for i in np.flatnonzero(record == name)]
        done = [m for m in members if m["predicted"] is not None]
        votes = {c: sum(m["predicted"] == c for m in done) for c in classes}
        mean = (
            {c: float(np.mean([m["probabilities"][c] for m in done])) for c in classes}
            if done
            else None
        )
        majority = (
            None if mean is None else max(classes, key=lambda c: (votes[c], mean[c]))  # type: ignore[index]
        )
        flagged = sum(run_flagged(m) for m in members)
        states = {m["state"] for m in members}
        checked = [m["signatures"] for m in members if m.get("signatures")]
        shows = (
            {
                c: float(np.mean([bool(g.get(c)) for g in checked]))
                for c in classes
                if any(g.get(c) is not None for g in checked)
            }
            if checked
            else None
        )
        out.append(
            {
                "record": name,
                "state": states.pop() if len(states) == 1 else None,
                "runs": len(members),
                "classified": len(done),
                "votes": votes,
                "majority": majority,
                "mean_probabilities": mean,
                "share_flagged": flagged / len(members),
                "flagged": flagged > len(members) / 2,
                "shows": shows,
            }
        )
    return out


def record_metrics(records: list[dict[str, Any]], classes: list[str]) -> dict[str, Any] | None:
    """Accuracy, balanced accuracy and confusion of the records' majority votes.

    Over the records whose true state is one of ``classes`` and that have a vote (a record
    none of whose runs is called has none: ``uncalled`` counts them); the balanced accuracy
    is the mean over the true states present of their records' accuracy.
    ``misnamed_flagged`` counts the misnamed records that are flagged.
    """
    labelled = [r for r in records if r["state"] in classes]
    known = [r for r in labelled if r["majority"] is not None]
    if not known:
        return None
    confusion = np.zeros((len(classes), len(classes)), dtype=int)
    for r in known:
        confusion[classes.index(r["state"]), classes.index(r["majority"])] += 1
    present = confusion.sum(axis=1) > 0
    recall = np.diag(confusion)[present] / confusion.sum(axis=1)[present]
    wrong = [r for r in known if r["majority"] != r["state"]]
    return {
        "records": len(known),
        "accuracy": float(np.trace(confusion) / confusion.sum()),
        "balanced_accuracy": float(recall.mean()),
        "confusion": confusion.tolist(),
        "misnamed": len(wrong),
        "misnamed_flagged": sum(r["flagged"] for r in wrong),
        "uncalled": len(labelled) - len(known),
    }


@dataclasses.dataclass(frozen=True)
class JobFindings:
    """What a job found besides the classification, for its damage report; each optional.

    Parameters
    ----------
    fit
        The model updating's summary: the page shows its method, J and parameter table.
    diagnosis
        The diagnosis JSON (its ``report`` the HTML's path): the page shows its verdict and
        links it.
    adequacy, trust
        The job's fit-adequacy and trust JSON: the page opens with them (and says so plainly
        when the classification cannot be trusted).
    extension
        :func:`bayesdoor.report.extension_section`'s input: the job on the system extended by
        the diagnosis's verdict, or why nothing was extended.
    """

    fit: FitSummary | None = None
    diagnosis: dict[str, Any] | None = None
    adequacy: dict[str, Any] | None = None
    trust: dict[str, Any] | None = None
    extension: dict[str, Any] | None = None


def report_stage(
    classified: Path,
    model: Path,
    folder: Path,
    *,
    title: str = "Damage report",
    findings: JobFindings = JobFindings(),
) -> None:
    """Write the HTML damage reports from a classification and its model folder, with what
    the job found besides (:class:`JobFindings`)."""
    fit, diagnosis, extension = findings.fit, findings.diagnosis, findings.extension
    classification = json.loads((classified / "classification.json").read_text())
    with np.load(classified / "features.npz", allow_pickle=False) as f:
        features, frequencies = f["features"], f["frequencies"]
        channels = tuple(str(c) for c in f["channels"])
    model_folder = model_file(model).parent
    bands = PredictiveBands.load(model_folder / BANDS) if (model_folder / BANDS).is_file() else None
    training_path = model_folder / "training.json"
    training = json.loads(training_path.read_text()) if training_path.is_file() else None
    write_damage_report(
        folder,
        classification,
        features=features,
        frequencies=frequencies,
        channels=channels,
        title=title,
        context=ReportContext(
            bands=None
            if bands is None
            else {
                "states": bands.states,
                "speeds": bands.speeds,
                "values": bands.values,
            },
            training=training,
            fit=None if fit is None else {"method": fit.method, "j": fit.j, "table": fit.table()},
            adequacy=findings.adequacy,
            trust=findings.trust,
            sections=(
                *(
                    ()
                    if diagnosis is None
                    else (diagnosis_section(diagnosis, _sibling(diagnosis)),)
                ),
                *(() if extension is None else (extension_section(extension),)),
            ),
        ),
    )


def _sibling(diagnosis: dict[str, Any]) -> str | None:
    """The diagnosis report's address from the report's page: both are stages of one job."""
    if diagnosis.get("report") is None:
        return None
    target = Path(diagnosis["report"])
    return f"../{target.parent.name}/{target.name}"
