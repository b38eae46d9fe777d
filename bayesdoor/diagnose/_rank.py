"""A system's catalogue of candidate causes, and ranking them against the residual features."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping

import equinox as eqx
import numpy as np

from ._features import Features
from ._refit import AbstractRefit
from ._signatures import AbstractSignature, Match, NoResidual

#: the catalogue name of "the model explains the data"
NONE = "none"
#: the verdict is the top candidate only when it passes at least this share of its checks
MIN_VERDICT_SCORE = 0.75


class Candidate(eqx.Module):
    """A candidate cause: a catalogue name, what it is, its signature in the data, and how to
    confirm it by refitting a model extension (``None``: it cannot be confirmed)."""

    name: str = eqx.field(static=True)
    description: str = eqx.field(static=True)
    signature: AbstractSignature
    refit: AbstractRefit | None = None


class Catalogue(eqx.Module):
    """The causes a system knows; names are part of the API. Must hold ``none``.

    ``speed_profile`` (optional) gives the speed (run, time) of runs at the given operating
    points at the given sample times; with it, the diagnosis computes order spectra
    (against travelled distance, segments of ``order_segment_m`` metres) and takes the
    periods of tracking features from them.

    ``speed`` (optional) gives each run's speed, in the units of ``speed_profile``, from
    its operating point (``(run,)`` or ``(run, condition)``): the speed the residual map's
    wavenumbers, the speed fits and the held-out folds use. Without it the operating point
    is the speed when the system has one condition, and a system with several conditions
    has no wavenumber map (its folds follow the conditions in order).

    ``band`` (optional) is the analysed band of the diagnosis, Hz; ``None``: the base fit's
    feature band. A system whose fit compares a band where its model is complete, while
    the causes of its catalogue show elsewhere (a machine's shaft and supply lines under its
    resonance region), names the wider band here.

    ``random_realisations``: the system's simulations are random realisations (a stochastic
    model whose runs draw their randomness by their position in the batch), so one
    simulation of a point is not its expected spectrum. A fit with one point (CMA-ES) then
    gives the residual map predictive draws that are that point simulated again at other
    positions of the batch: their spread holds the model's own scatter, which a
    deterministic simulator does not have.
    """

    candidates: tuple[Candidate, ...]
    speed_profile: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = eqx.field(
        static=True, default=None
    )
    order_segment_m: float = eqx.field(static=True, default=0.5)
    speed: Callable[[np.ndarray], np.ndarray] | None = eqx.field(static=True, default=None)
    band: tuple[float, float] | None = eqx.field(static=True, default=None)
    random_realisations: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        names = [c.name for c in self.candidates]
        if len(set(names)) != len(names):
            raise ValueError(f"catalogue names must be unique, got {names}")
        if NONE not in names:
            raise ValueError(f"a catalogue must hold {NONE!r} (with NoResidual()), got {names}")
        if self.band is not None and not 0 <= self.band[0] < self.band[1]:
            raise ValueError(f"band must be (low, high) Hz with 0 <= low < high, got {self.band}")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.candidates)

    def speeds(self, operating: np.ndarray) -> np.ndarray | None:
        """Each run's speed for the diagnosis (``speed``; else the operating point of a
        system with one condition; ``None`` for several conditions without ``speed``)."""
        operating = np.asarray(operating, dtype=float)
        if self.speed is not None:
            return np.asarray(self.speed(operating), dtype=float).reshape(len(operating))
        return operating if operating.ndim == 1 else None


@dataclasses.dataclass(frozen=True)
class CauseScore:
    """How well one candidate's signature matches the features.

    Attributes
    ----------
    name, description
        The candidate.
    score
        Share of the signature's decidable checks passed by its best feature (0 when no
        feature is of its kind).
    strength
        The best feature's combined statistic (tie-breaker).
    evidence
        The best feature and the outcome of every check, in words.
    parameters
        The parameter estimate the best feature implies.
    feature
        The best feature, in words (empty when there is none).
    """

    name: str
    description: str
    score: float
    strength: float
    evidence: str
    parameters: Mapping[str, float | str | tuple]
    feature: str = ""


@dataclasses.dataclass(frozen=True)
class Ranking:
    """Candidates ranked by signature score; the verdict and the features behind it.

    Attributes
    ----------
    verdict
        ``"none"`` when no significant residual exists; otherwise the top candidate when its
        score reaches ``MIN_VERDICT_SCORE`` and it is not tied with the runner-up on the same
        feature; ``None`` when residuals exist that no signature matches well, or one feature
        that two match equally well (see ``causes`` and ``features``).
    causes
        Every candidate, best first.
    features
        The features they were scored on.
    """

    verdict: str | None
    causes: tuple[CauseScore, ...]
    features: Features

    def cause(self, name: str) -> CauseScore:
        for c in self.causes:
            if c.name == name:
                return c
        raise KeyError(f"no candidate {name!r}; the candidates are {[c.name for c in self.causes]}")


def rank_causes(features: Features, catalogue: Catalogue) -> Ranking:
    """Score every candidate's signature on the features and rank them.

    The rule (documented in ``docs/diagnosis.md``): each signature picks the feature that
    passes the largest share of its checks (ties: the strongest); its score is that share.
    Candidates are ranked by score, then strength. ``none`` scores 1 exactly when nothing is
    significant in the maps, and then it is the verdict unless another signature scores at least
    ``MIN_VERDICT_SCORE`` (one that examines more than the maps: a harmonic comb in the order
    spectra); otherwise the verdict is the top candidate if it scores at least
    ``MIN_VERDICT_SCORE`` and is not tied with the runner-up (when the catalogue holds another
    cause) on the same feature, else ``None`` (nothing fits well, or two causes explain one
    feature equally well: the refit has to decide). Two causes that fully explain two
    different features may both be present; the stronger feature ranks first.

    Parameters
    ----------
    features
        From :func:`find_features` (or assembled from the maps).
    catalogue
        The system's candidates.

    Returns
    -------
    Ranking
    """
    scored = []
    for candidate in catalogue.candidates:
        match: Match | None = candidate.signature.match(features)
        if match is None:
            scored.append(
                CauseScore(
                    candidate.name, candidate.description, 0.0, 0.0, "no feature of this kind", {}
                )
            )
            continue
        scored.append(
            CauseScore(
                name=candidate.name,
                description=candidate.description,
                score=match.score,
                strength=match.strength,
                evidence=match.evidence(),
                parameters=dict(match.parameters),
                feature=match.feature,
            )
        )
    scored.sort(key=lambda c: (-c.score, -c.strength))
    nothing = NoResidual().match(features)
    # a signature may see what the residual maps do not (a harmonic comb in the order spectra)
    seen = any(c.score >= MIN_VERDICT_SCORE for c in scored if c.name != NONE)
    if nothing is not None and nothing.score == 1.0 and not seen:
        verdict: str | None = NONE
    else:
        # a catalogue may hold one cause besides ``none`` (no runner-up), or none at all
        causes = [c for c in scored if c.name != NONE]
        verdict = None
        if causes and causes[0].score >= MIN_VERDICT_SCORE:
            top, rest = causes[0], causes[1:2]
            if not rest or top.score > rest[0].score or top.feature != rest[0].feature:
                verdict = top.name
    return Ranking(verdict=verdict, causes=tuple(scored), features=features)
