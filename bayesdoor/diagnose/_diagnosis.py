"""What a diagnosis is asked and what it answers: its settings, each judged cause, the result."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..inference import FitResult
from ._features import Features
from ._gain import Contest, Gain
from ._limits import CauseLimit
from ._rank import Catalogue, Ranking
from ._refit import ExtensionProposal


@dataclasses.dataclass(frozen=True)
class DiagnosisSettings:
    """Sizes of :func:`diagnose_campaign`.

    Attributes
    ----------
    predictive_draws
        Posterior draws simulated for the residual map (a CMA-ES fit has one point; its
        draws differ by the measurement noise only).
    max_candidates
        Most candidates refitted (best signature scores first).
    refit_evals
        CMA-ES budget of one extension refit (per fold).
    folds
        Folds of the held-out judgement (at most one per run): each fold's extension is
        fitted on the other runs and judged on its own.
    workers
        Folds refitted at once (threads; the solves release the interpreter), and the
        threads that solve the population of a confirmed cause's final refit on every run
        (:func:`refit_extension`'s ``workers``). The folds' results do not depend on it;
        the final refit's move with it at the adaptive solver's round-off.
    limits
        Compute every catalogue cause's detection limit (:func:`detection_limits`).
    limit_draws
        Monte Carlo draws of the held-out differences per size of a limit's power curve.
    """

    predictive_draws: int = 8
    max_candidates: int = 5
    refit_evals: int = 240
    folds: int = 2
    workers: int = 2
    limits: bool = True
    limit_draws: int = 2000

    def __post_init__(self) -> None:
        least = {
            "predictive_draws": 1,
            "max_candidates": 0,
            "refit_evals": 1,
            "folds": 2,
            "workers": 1,
            "limit_draws": 100,
        }
        if not isinstance(self.limits, bool):
            raise ValueError(f"DiagnosisSettings.limits={self.limits!r} must be True or False")
        for name, low in least.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"DiagnosisSettings.{name}={value!r} must be an integer >= {low}")

    @classmethod
    def quick(cls) -> DiagnosisSettings:
        """Small sizes for tests and demos: 4 draws, 4 candidates, 96 evaluations per refit."""
        return cls(predictive_draws=4, max_candidates=4, refit_evals=96)


@dataclasses.dataclass(frozen=True)
class Cause:
    """One catalogue cause as the diagnosis judged it.

    Attributes
    ----------
    name, description
        The catalogue's.
    score
        Share of its signature's checks passed (:func:`rank_causes`).
    evidence
        The signature's evidence and, when refitted, the refit's, in words.
    parameters
        The refitted parameters (``{"mean", "sd"}`` each) when refitted, else the signature's
        estimate.
    gain
        Held-out J and log predictive density before and after (``None``: not refitted).
    confirmed
        Whether the gain is decisive.
    feature
        The residual feature the signature matched.
    label
        The refitted configuration in words.
    proposal
        The catalogue recipe's proposal the refit chose (``None``: not refitted), so that
        :func:`~bayesdoor.diagnose.verdict_extension` need not ask the recipe again.
    alternatives
        Other catalogue causes that give the same symptom, in words with the reason (the
        recipe's :meth:`~bayesdoor.diagnose.AbstractRefit.alternatives`; refitted causes
        only): a confirmed cause with alternatives is the best extension of those the
        catalogue can fit, not a proof against them.
    feature_share
        The share of its own residual feature's excess the refit took away on held-out runs
        (:class:`~bayesdoor.diagnose.Symptom`; 1 all of it, below 0 it grew); ``None`` where
        the recipe measures none or the cause was not refitted.
    """

    name: str
    description: str
    score: float
    evidence: str
    parameters: Mapping[str, Any]
    gain: Gain | None = None
    confirmed: bool = False
    feature: str = ""
    label: str = ""
    proposal: ExtensionProposal | None = None
    alternatives: tuple[str, ...] = ()
    feature_share: float | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "description": self.description,
            "score": self.score,
            "evidence": self.evidence,
            "parameters": _plain(self.parameters),
            "gain": None if self.gain is None else self.gain.to_json(),
            "confirmed": self.confirmed,
            "feature": self.feature,
            "configuration": self.label,
            "alternatives": list(self.alternatives),
            "feature_share": self.feature_share,
        }


@dataclasses.dataclass(frozen=True)
class Diagnosis:
    """The outcome of :func:`diagnose_campaign`.

    Attributes
    ----------
    verdict
        A catalogue name: the confirmed cause that wins most of its contests with the other
        confirmed ones (their extended models judged against each other on the held-out
        runs), the strongest held-out evidence over the base model (gain in standard errors;
        :func:`verdict_order`) breaking ties; or ``"none"``.
    causes
        Every candidate: all the confirmed ones, the verdict first, then the others by
        signature score.
    ranking
        The signature ranking (with the residual features).
    catalogue
        The catalogue used.
    rule
        The decision rule, in words.
    runs
        Campaign indices of the runs diagnosed.
    notes
        What limited the diagnosis (too few runs to hold any out, a refit that failed).
    timings
        Seconds per step: ``"fit"`` (when fitted here), ``"features"`` (measure, residual
        map, ranking), ``"refits"`` (proposals, refits, judgement), ``"limits"``.
    fit
        The base model's fit the diagnosis was made under (given, or made by
        :func:`diagnose_campaign`), so that a report can show it.
    limits
        Per catalogue cause that declares its size, its detection limit in these runs
        (:func:`detection_limits`): the size the rule names with 80 % probability, and the
        power curve.
    contests
        Every ordered pair of confirmed causes, the challenger's extended model judged
        against the holder's on the held-out runs (``Contest``).
    """

    verdict: str
    causes: tuple[Cause, ...]
    ranking: Ranking
    catalogue: Catalogue
    rule: str
    runs: np.ndarray
    notes: tuple[str, ...] = ()
    timings: Mapping[str, float] = dataclasses.field(default_factory=dict)
    fit: FitResult | None = None
    limits: Mapping[str, CauseLimit] = dataclasses.field(default_factory=dict)
    contests: tuple[Contest, ...] = ()

    @property
    def confirmed(self) -> tuple[Cause, ...]:
        """The confirmed causes, the verdict first."""
        return tuple(c for c in self.causes if c.confirmed)

    @property
    def features(self) -> Features:
        return self.ranking.features

    def cause(self, name: str) -> Cause:
        for c in self.causes:
            if c.name == name:
                return c
        raise KeyError(f"no cause {name!r}; the causes are {[c.name for c in self.causes]}")

    def _cause_json(self, cause: Cause) -> dict[str, Any]:
        """A cause's JSON, with its detection limit beside it (``limit``: the typical
        configuration's size, ``unit``) when the cause declares one."""
        out = cause.to_json()
        limit = self.limits.get(cause.name)
        if limit is not None:
            out["limit"] = {"size": limit.size, "unit": limit.unit, "power": limit.power}
        return out

    def to_json(self) -> dict[str, Any]:
        """The JSON of docs/cli.md (``bayesdoor diagnose``): ``verdict`` and ``causes`` (each
        ``name``, ``evidence``, ``parameters``, ``gain``), plus the rule, the features in
        words, notes and timings; ``confirmed`` (every confirmed cause, the verdict first),
        ``contests`` (the confirmed causes judged against each other: challenger, holder,
        its gain over the holder's model in standard errors, decisive, and the gain's
        figures) and ``limits`` (per cause: its size's name, unit, the size named with the
        stated power, the power curve)."""
        return {
            "verdict": self.verdict,
            "confirmed": [c.name for c in self.confirmed],
            "causes": [self._cause_json(c) for c in self.causes],
            "rule": self.rule,
            "signature_verdict": self.ranking.verdict,
            "features": self.features.summary(),
            "runs": self.runs.tolist(),
            "notes": list(self.notes),
            "timings": dict(self.timings),
            "limits": {name: limit.to_json() for name, limit in self.limits.items()},
            "contests": [c.to_json() for c in self.contests],
        }


def _plain(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value
