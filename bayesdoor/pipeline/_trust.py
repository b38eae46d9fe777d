"""Whether a job's classification can be trusted: fit adequacy, known runs, OOD rate.

A classifier trained on simulations is only as good as the simulations' likeness to the
measurements. Three checks hold the job's own evidence against that, each a test at a stated
false-alarm rate (:data:`TRUST_ALPHA` per check unless said otherwise):

1. **Fit adequacy** (:func:`bayesdoor.datagen.fit_adequacy`): do the simulated healthy runs
   (the training data of the job's source, plus the Welch scatter of a measured record)
   reproduce the measured healthy calibration runs, per channel and band?
2. **Known runs**: the ensemble classifies the healthy calibration runs (they informed the
   fit and, with the default source, the discrepancy the training runs carry, but the
   ensemble never trained on them). Fewer called healthy than the simulated validation's healthy
   recall makes plausible (binomial, one-sided) means the classifier does not recognise the
   measured healthy state.
3. **Out-of-distribution rate**: the detector's threshold flags a share ``1 - quantile`` of
   the reference runs; many more flagged test runs than that (binomial, one-sided) means
   some measurements lie outside what the classifier was trained on: their probabilities
   extrapolate. Runs called healthy are also held against the simulated healthy runs at their
   speed (:func:`bayesdoor.datagen.healthy_outliers`, 1 % per run), and counted alike. An
   excess of either is a warning (``"limited"``, the runs listed); more than half of the
   runs flagged fails the check, a run whose call the system's signature check contradicts
   (``corroborated`` false, for a system with such a check) counted flagged too.

A failed fit adequacy, known-runs or majority check makes the verdict ``"not trusted"``, with
its reasons; the report then leads with them instead of a confident table.

4. **Expected accuracy**: with the passing checks, the simulated validation runs (which carry
   the measured discrepancy with the default source) estimate the accuracy to expect on the
   measurements. Below the required accuracy (:data:`REQUIRED_ACCURACY`, a requirement, not
   a fitted threshold) the verdict is ``"limited"``: the states overlap at this machine's
   measured floor, and faults of the smaller severities are expected to be missed.

5. **Uncertain rate**: a run is uncertain when its calibrated probability of a wrong call
   exceeds the classification's ``max_error``; many more uncertain test runs than the
   simulated validation's share (binomial, one-sided) is a warning: the measurements are
   harder to place than the simulations the calibration was fitted on.

6. **Not corroborated**: for a system whose signature check states its false-alarm rate
   (:meth:`~bayesdoor.systems.AbstractSystem.signature_reference`), many more calls the
   check contradicts than that rate (binomial, one-sided) is a warning: the signals do not
   show the called states' signatures.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
from scipy import stats

from ..datagen import (
    AdequacyCheck,
    TrainingData,
    campaign_features,
    fit_adequacy,
    healthy_outliers,
    load_training_data,
    measurement_variance,
    with_measured_discrepancy,
)
from ..datagen._points import point_key
from ..io import operating as campaign_operating
from ..systems import AbstractSystem
from ._classify import (
    SIGNATURES,
    Classification,
    _write_json,
    as_saved,
    classify,
    data_spec,
    healthy_state,
    runs_in_state,
)
from ._stages import Finished, StageRecord, stage_in

ADEQUACY_JSON = "adequacy.json"
TRUST_JSON = "trust.json"
#: false-alarm rate of each trust check
TRUST_ALPHA = 0.01
#: what the adequacy stage computes (its configuration: a change reruns it)
ADEQUACY_CHECK = {"alpha": TRUST_ALPHA, "bands": 6, "order": "|S|, then the offset in SD"}
#: the accuracy a classification must be expected to reach to be reported without a warning
REQUIRED_ACCURACY = 0.9
#: what the trust stage checks, at which rates (its configuration: a change reruns it)
TRUST_CHECKS = {
    "checks": ("adequacy", "known runs", "most flagged", "expected accuracy"),
    "warnings": ("ood rate", "unlike healthy", "expected accuracy", "not corroborated"),
    "alpha": TRUST_ALPHA,
    "required_accuracy": REQUIRED_ACCURACY,
}


def training_data(
    data_folder: Path,
    calibration: xr.Dataset,
    *,
    discrepancy: bool,
    seed: int,
    system: AbstractSystem | None = None,
) -> TrainingData:
    """The job's training data: the generated runs, with the measured discrepancy of the
    healthy calibration runs added when the source carries it
    (:func:`bayesdoor.datagen.with_measured_discrepancy`). ``system``: the campaign's system
    (``None``: the registered one it names)."""
    data = load_training_data(data_folder)
    known = runs_in_state(calibration, data.healthy)
    if not discrepancy or data.healthy not in data.states or known.sizes["run"] == 0:
        return data
    return with_measured_discrepancy(
        data,
        campaign_features(known, spec=data_spec(data)),
        campaign_operating(known, system),
        seed=seed,
        state=data.healthy,
    )


@dataclasses.dataclass(frozen=True)
class Adequacy(Finished):
    """The product of the ``adequacy`` stage: ``adequacy.json``.

    Attributes
    ----------
    payload
        :func:`bayesdoor.datagen.fit_adequacy` of the calibration runs as JSON (``verdict``,
        ``summary``, ...), or ``verdict: null`` with the ``reason``.
    stage
        The record of the stage that made it (``None`` before it is saved by one).
    """

    payload: dict[str, Any]
    stage: StageRecord | None = None

    def save(self, folder: Path) -> None:
        """Write ``adequacy.json`` into ``folder``."""
        _write_json(folder / ADEQUACY_JSON, self.payload)

    @classmethod
    def load(cls, folder: Path) -> Adequacy:
        """Read what :meth:`save` wrote."""
        return cls(json.loads((folder / ADEQUACY_JSON).read_text()), stage_in(folder))


def check_adequacy(
    data_folder: Path,
    calibration: xr.Dataset,
    *,
    seed: int,
    discrepancy: bool = False,
    system: AbstractSystem | None = None,
) -> Adequacy:
    """:func:`bayesdoor.datagen.fit_adequacy` of the calibration runs against the training
    data in ``data_folder``.

    With ``discrepancy`` (the source adds the calibration runs' measured discrepancy to the
    simulations) the check leaves each run's own discrepancy out. Without healthy
    calibration runs, or training data without a healthy state, the product holds
    ``verdict: null`` and the reason.
    """
    data = load_training_data(data_folder)
    known = runs_in_state(calibration, data.healthy)
    if data.healthy not in data.states or known.sizes["run"] == 0:
        return Adequacy(
            {"verdict": None, "reason": f"no measured {data.healthy} runs to check the fit on"}
        )
    try:
        payload = _adequacy(data, known, campaign_operating(known, system), seed, discrepancy)
    except ValueError as err:  # too few simulated runs at a speed, for example
        payload = {"verdict": None, "reason": " ".join(str(err).split())}
    return Adequacy(as_saved(payload))


def _adequacy(
    data: TrainingData, known: xr.Dataset, speeds: np.ndarray, seed: int, discrepancy: bool
) -> dict[str, Any]:
    features = campaign_features(known, spec=data_spec(data))
    variance = measurement_variance(data)
    check = AdequacyCheck(alpha=TRUST_ALPHA)
    model = fit_adequacy(data, features, speeds, variance, seed=seed, check=check)
    payload = model.to_json()
    if discrepancy and known.sizes["run"] >= 2:
        payload = fit_adequacy(
            data,
            features,
            speeds,
            variance,
            seed=seed,
            discrepancy=True,
            check=check,
        ).to_json()
        payload["summary"] = (
            "with the measured discrepancy (each run left out of its own), " + payload["summary"]
        )
    # the fitted model alone, without the measured discrepancy: what the physics misses
    payload["model"] = model.to_json()
    return payload


def _jeffreys_centre(k: int, n: int) -> float:
    """A rate of ``k`` in ``n`` shrunk away from 0 and 1: the centre ``(k + 1/2) / (n + 1)``
    of the Jeffreys posterior."""
    return (k + 0.5) / (n + 1.0)


def _binomial_low(k: int, n: int, p: float) -> float:
    """P(X <= k) for X ~ Binomial(n, p)."""
    return float(stats.binom.cdf(k, n, p))


def _binomial_high(k: int, n: int, p: float) -> float:
    """P(X >= k) for X ~ Binomial(n, p)."""
    return float(stats.binom.sf(k - 1, n, p))


def judge_trust(
    adequacy: dict[str, Any],
    known: dict[str, Any] | None,
    classification: dict[str, Any],
    training: dict[str, Any],
    unlike_healthy: list[int],
    *,
    alpha: float = TRUST_ALPHA,
    required: float = REQUIRED_ACCURACY,
    signature_rate: float | None = None,
) -> dict[str, Any]:
    """The trust verdict from the checks' evidence (see the module docstring).

    Parameters
    ----------
    adequacy
        ``adequacy.json``.
    known
        The classification JSON of the healthy calibration runs (``None``: there are none).
    classification
        The classification JSON of the test runs.
    training
        ``training.json`` of the ensemble (its states, healthy state, simulated validation and
        OOD quantile).
    unlike_healthy
        Test runs (their ``run`` numbers) called healthy but unlike the simulated healthy runs.
    signature_rate
        The system's signature check's false-alarm rate (the share of right calls it
        contradicts; ``None``: no check, or none stated).
    """
    healthy = healthy_state(training)
    reasons: list[str] = []
    checks: dict[str, Any] = {}
    if adequacy.get("verdict") == "does not reproduce":
        reasons.append(f"fit inadequate: {adequacy['summary']}")
    checks["adequacy"] = adequacy.get("verdict")
    if known is not None and known["runs"]:
        _known_runs(known, training, healthy, checks, reasons, alpha)
    runs = [r for r in classification["runs"] if _call(r) is not None]
    warnings: list[str] = []
    flagged = _flagged(runs, training, unlike_healthy, checks, warnings, alpha)
    _uncertain_rate(classification, training, runs, checks, warnings, alpha)
    contradicted = {r["run"] for r in runs if r.get("corroborated") is False}
    if signature_rate is not None and runs:
        _not_corroborated(len(runs), len(contradicted), signature_rate, checks, warnings, alpha)
    n = len(runs)
    if n and len(flagged) > n / 2:
        reasons.append(f"most runs are flagged ({len(flagged)} of {n})")
    expected = (training.get("validation", {}).get("calibrated") or {}).get("accuracy")
    checks["expected_accuracy"] = {"simulated_validation": expected, "required": required}
    if expected is not None and expected < required:
        warnings.append(
            f"the accuracy to expect is about {100 * expected:.0f} % (simulated validation runs "
            f"that carry the measured discrepancy), below the required {100 * required:.0f} %: "
            "the states overlap at this machine's measured floor, so faults of the smaller "
            "severities will be missed"
        )
    verdict = "not trusted" if reasons else ("limited" if warnings else "trusted")
    return {
        "verdict": verdict,
        "alpha": alpha,
        "reasons": reasons,
        "warnings": warnings,
        "checks": checks,
        "flagged_runs": sorted(flagged),
        "unlike_healthy_runs": sorted(unlike_healthy),
    }


def _known_runs(
    known: dict[str, Any],
    training: dict[str, Any],
    healthy: str,
    checks: dict[str, Any],
    reasons: list[str],
    alpha: float,
) -> None:
    """Check 2: fewer measured healthy runs called healthy than the simulated validation's
    recall makes plausible (binomial, one-sided) means the classifier does not recognise the
    measured healthy state."""
    classes = list(training["states"])
    validation = training["validation"]
    labels = np.asarray(validation["labels"])
    probs = np.asarray(validation["probabilities"])
    h = classes.index(healthy)
    own = labels == h
    hits = int(np.sum(np.argmax(probs[own], axis=1) == h))
    # the simulated recall, shrunk away from 1: a perfect validation of a few dozen runs
    # does not make one miss impossible
    recall = _jeffreys_centre(hits, int(own.sum()))
    called = [c for c in map(_call, known["runs"]) if c is not None]
    k = sum(p == healthy for p in called)
    p_value = _binomial_low(k, len(called), recall)
    checks["known_runs"] = {
        "state": healthy,
        "runs": len(called),
        "called_right": k,
        "simulated_recall": recall,
        "p_value": p_value,
    }
    if called and p_value < alpha:
        others = sorted({p for p in called if p != healthy})
        reasons.append(
            f"{k} of {len(called)} measured {healthy} calibration runs were called "
            f"{healthy} (the others: {', '.join(others)}); the simulated validation's "
            f"recall {recall:.3f} makes that improbable (p = {p_value:.1e})"
        )


def _flagged(
    runs: list[dict[str, Any]],
    training: dict[str, Any],
    unlike_healthy: list[int],
    checks: dict[str, Any],
    warnings: list[str],
    alpha: float,
) -> set[int]:
    """Check 3: the runs flagged (OOD, unlike the simulated healthy runs, or contradicted by
    the system's signature check), with a warning for an excess of either of the first two."""
    ood = {r["run"] for r in runs if r.get("ood")}
    # a confident call that the system's own signature check contradicts is as unlike the
    # simulations as an OOD run (only a system with a check has ``corroborated``)
    contradicted = {r["run"] for r in runs if r.get("corroborated") is False}
    flagged = ood | set(unlike_healthy) | contradicted
    nominal = 1.0 - float(training.get("ood_quantile", 0.99))
    n = len(runs)
    p_ood = _binomial_high(len(ood), n, nominal) if n else 1.0
    checks["ood"] = {
        "runs": n,
        "flagged_ood": len(ood),
        "unlike_healthy": len(unlike_healthy),
        "not_corroborated": len(contradicted),
        "nominal_rate": nominal,
        "p_value": p_ood,
    }
    if n and len(ood) and p_ood < alpha:
        warnings.append(
            f"{len(ood)} of {n} runs lie outside every simulated state (OOD), against "
            f"{100 * nominal:.0f} % expected (p = {p_ood:.1e}): their probabilities extrapolate"
        )
    healthy = healthy_state(training)
    called_healthy = sum(_call(r) == healthy for r in runs)
    p_h = _binomial_high(len(unlike_healthy), called_healthy, alpha) if called_healthy else 1.0
    checks["unlike_healthy"] = {"called_healthy": called_healthy, "p_value": p_h}
    if unlike_healthy and p_h < alpha:
        warnings.append(
            f"{len(unlike_healthy)} of {called_healthy} runs called {healthy} are unlike "
            f"the simulated {healthy} runs at their speed (p = {p_h:.1e})"
        )
    return flagged


def _not_corroborated(
    n: int,
    contradicted: int,
    rate: float,
    checks: dict[str, Any],
    warnings: list[str],
    alpha: float,
) -> None:
    """Check 6: many more calls the signature check contradicts than its false-alarm rate."""
    p_sig = _binomial_high(contradicted, n, rate)
    checks["not_corroborated"] = {
        "runs": n,
        "not_corroborated": contradicted,
        "false_alarm_rate": rate,
        "p_value": p_sig,
    }
    if contradicted and p_sig < alpha:
        warnings.append(
            f"{contradicted} of {n} calls are not backed by the system's signature "
            f"check, which contradicts {100 * rate:g} % of right calls "
            f"(p = {p_sig:.1e}): the signals do not show the called states' signatures, "
            "so the probabilities rest on the learned features alone"
        )


def _uncertain_rate(
    classification: dict[str, Any],
    training: dict[str, Any],
    runs: list[dict[str, Any]],
    checks: dict[str, Any],
    warnings: list[str],
    alpha: float,
) -> None:
    """Check 5: many more uncertain runs than the simulated validation has (binomial,
    one-sided) means the measurements are harder to place than the simulations: their
    calibration, fitted on the simulations, promises more than they hold."""
    max_error = classification.get("max_error")
    probabilities = (training.get("validation") or {}).get("probabilities")
    if max_error is None or not probabilities or not runs:
        return
    top = np.max(np.asarray(probabilities, dtype=float), axis=1)
    # the simulated share, shrunk away from 0, as the recall of the known runs
    share = _jeffreys_centre(int(np.sum(top < 1.0 - max_error)), top.size)
    uncertain = sum(bool(r.get("uncertain")) for r in runs)
    p_value = _binomial_high(uncertain, len(runs), share)
    checks["uncertain"] = {
        "runs": len(runs),
        "uncertain": uncertain,
        "max_error": max_error,
        "simulated_share": share,
        "p_value": p_value,
    }
    if uncertain and p_value < alpha:
        warnings.append(
            f"{uncertain} of {len(runs)} runs are uncertain (a wrong call more probable than "
            f"{max_error:g}), against {100 * share:.1f} % of the simulated validation runs "
            f"(p = {p_value:.1e}): the measurements are harder to place than the simulations, "
            "so the probabilities promise more than they hold"
        )


@dataclasses.dataclass(frozen=True)
class Trust(Finished):
    """The product of the ``trust`` stage: ``trust.json`` and, in ``known/``, the
    classification of the healthy calibration runs.

    Attributes
    ----------
    payload
        :func:`judge_trust`'s verdict (``verdict``, ``reasons``, ``warnings``, ``checks``,
        ``flagged_runs``, ...).
    known
        The classification of the healthy calibration runs (``None``: there are none).
    stage
        The record of the stage that made it (``None`` before it is saved by one).
    """

    payload: dict[str, Any]
    known: Classification | None = None
    stage: StageRecord | None = None

    def save(self, folder: Path) -> None:
        """Write ``known/`` (:meth:`Classification.save`) and ``trust.json`` into ``folder``."""
        if self.known is not None:
            (folder / "known").mkdir(parents=True, exist_ok=True)
            self.known.save(folder / "known")
        _write_json(folder / TRUST_JSON, self.payload)

    @classmethod
    def load(cls, folder: Path) -> Trust:
        """Read what :meth:`save` wrote."""
        known = None
        if (folder / "known" / "classification.json").is_file():
            known = Classification.load(folder / "known")
        return cls(json.loads((folder / TRUST_JSON).read_text()), known, stage_in(folder))


def judge_classification(
    model: Path,
    classification: Classification,
    adequacy: Adequacy,
    data: TrainingData,
    calibration: xr.Dataset,
    *,
    seed: int,
    system: AbstractSystem | None = None,
) -> Trust:
    """Whether ``classification`` (of the test runs, by the ensemble in ``model``) can be
    trusted: :func:`judge_trust` of the checks' evidence.

    ``data``: the job's training data (:func:`training_data`: with the calibration runs'
    measured discrepancy when the source carries it); the runs called healthy are held
    against its healthy runs.
    """
    training = json.loads((model / "training.json").read_text())
    healthy = healthy_state(training, system)
    known_runs = runs_in_state(calibration, healthy)
    known = None
    if known_runs.sizes["run"]:
        known = classify(model, known_runs, system=system)
    judged = None
    if known is not None:
        runs = [r for r in known.payload["runs"] if _call(r) is not None]
        judged = {**known.payload, "runs": runs}
    signatures = model / SIGNATURES
    rate = None
    if signatures.is_file():
        rate = json.loads(signatures.read_text())["reference"].get("false_alarm_rate")
    verdict = judge_trust(
        adequacy.payload,
        judged,
        classification.payload,
        training,
        _unlike_healthy(classification, data, healthy, seed),
        signature_rate=None if rate is None else float(rate),
    )
    return Trust(as_saved(verdict), known)


def _unlike_healthy(
    classification: Classification, data: TrainingData, healthy: str, seed: int
) -> list[int]:
    """The runs called healthy whose features are unlike the simulated healthy runs at their
    operating point (:func:`bayesdoor.datagen.healthy_outliers`)."""
    picks = [
        (i, r)
        for i, r in enumerate(classification.payload["runs"])
        if _call(r) == healthy and _known(r["operating"])
    ]
    if not picks or healthy not in data.states:
        return []
    features = classification.features[[i for i, _ in picks]]
    simulated = {point_key(s) for s in np.asarray(data.speeds)}
    at = [j for j, (_, r) in enumerate(picks) if point_key(r["operating"]) in simulated]
    try:
        scores, bounds = healthy_outliers(
            data,
            features[at],
            np.asarray([picks[j][1]["operating"] for j in at], dtype=float),
            measurement_variance(data),
            seed=seed,
            check=AdequacyCheck(alpha=TRUST_ALPHA),
        )
    except ValueError:  # too few simulated healthy runs at a speed: no per-run check
        at, scores, bounds = [], np.zeros(0), np.zeros(0)
    return [int(picks[j][1]["run"]) for j, s, b in zip(at, scores, bounds, strict=True) if s > b]


def _call(run: dict[str, Any]) -> str | None:
    """The state a classified run is called, or leans to when the selective risk leaves it
    uncalled (the trust checks judge the classifier's calls, before any abstention)."""
    return run["predicted"] if run["predicted"] is not None else run.get("most_probable")


def _known(point) -> bool:
    """Whether a run's operating point (a number or a list) is known in full."""
    return point is not None and all(v is not None for v in np.atleast_1d(point))
