"""The candidates of a diagnosis: which causes are refitted, their refits judged on held-out
runs, and the verdict among the confirmed ones."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .._cluster import Pool
from ._diagnosis import Cause, DiagnosisSettings
from ._gain import Contest, Gain, held_out_evidence
from ._held_out import (
    _Bases,
    _fold_tasks,
    contest,
    held_out_folds,
    held_out_models,
    judge_folds,
    refit_fold,
    tracks_speed,
    verdict_order,
)
from ._measured import Measured, _fold_order
from ._rank import NONE, Catalogue, CauseScore, Ranking
from ._refit import (
    ExtensionProposal,
    RefitOptions,
    RefitResult,
    RefitSetup,
    Symptom,
    held_out_spectra,
    refit_extension,
)

#: a candidate is refitted when its signature passes at least this share of its checks
PLAUSIBLE_SCORE = 0.5


@dataclasses.dataclass(frozen=True)
class Proposed:
    """One plausible candidate and the extensions its catalogue recipe proposed.

    Attributes
    ----------
    score
        The candidate's signature score.
    proposals
        The recipe's proposals, each refitted fold by fold.
    seeds
        Each proposal's seed (fold ``k`` of it is seeded ``seed + k``).
    """

    score: CauseScore
    proposals: tuple[ExtensionProposal, ...]
    seeds: tuple[int, ...]


@dataclasses.dataclass(frozen=True)
class Proposals:
    """The candidates to refit (:func:`propose`), in rank order, and the held-out folds.

    ``notes``: why no candidate could be refitted (too few runs), or which recipe proposed
    nothing.
    """

    folds: tuple[tuple[np.ndarray, np.ndarray], ...]
    candidates: tuple[Proposed, ...]
    notes: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class Refits:
    """The refitted causes by name, in rank order (:func:`refit_candidates`); every ordered
    pair of confirmed causes judged against each other (``contests``, :func:`contest`);
    ``notes``: the proposals whose refit failed."""

    causes: Mapping[str, Cause]
    notes: tuple[str, ...] = ()
    contests: tuple[Contest, ...] = ()


@dataclasses.dataclass(frozen=True)
class Judgement:
    """The verdict (:func:`judge`): a catalogue name or ``"none"``; every candidate, the
    confirmed ones first; ``notes``: what to read the verdict with; ``contests``: the
    confirmed causes judged against each other."""

    verdict: str
    causes: tuple[Cause, ...]
    notes: tuple[str, ...] = ()
    contests: tuple[Contest, ...] = ()


def _signature_cause(score: CauseScore) -> Cause:
    return Cause(
        name=score.name,
        description=score.description,
        score=score.score,
        evidence=score.evidence,
        parameters=dict(score.parameters),
        feature=score.feature,
    )


def propose(
    ranking: Ranking,
    measured: Measured,
    catalogue: Catalogue,
    band: tuple[float, float],
    settings: DiagnosisSettings,
    seed: int,
) -> Proposals:
    """The candidates worth a refit and their recipes' extensions.

    A candidate is plausible with a signature score at least ``PLAUSIBLE_SCORE`` and a
    recipe, at most ``max_candidates`` of them; none when nothing is significant or no run
    can be held out. The ``rank``-th plausible candidate's ``k``-th proposal is seeded
    ``seed + 101 (rank + 1) + 7 k``.
    """
    folds = tuple(held_out_folds(_fold_order(catalogue, measured.operating), settings.folds))
    recipes = {c.name: c.refit for c in catalogue.candidates}
    plausible = [
        c
        for c in ranking.causes
        if c.name != NONE and c.score >= PLAUSIBLE_SCORE and recipes.get(c.name) is not None
    ][: settings.max_candidates]
    if ranking.verdict == NONE:
        return Proposals(folds, ())
    if plausible and not folds:
        return Proposals(
            folds,
            (),
            (
                f"{len(measured.runs)} healthy runs: too few to fit on half and hold out the "
                "other half (need 4); no candidate could be confirmed",
            ),
        )
    candidates: list[Proposed] = []
    notes: list[str] = []
    for rank, score in enumerate(plausible):
        recipe = _candidate(catalogue, score.name).refit
        assert recipe is not None
        try:
            proposals = tuple(recipe.propose(score.parameters, band=band))
        except (KeyError, ValueError) as err:
            notes.append(f"{score.name}: its recipe proposed no extension ({err!r})")
            continue
        seeds = tuple(seed + 101 * (rank + 1) + 7 * k for k in range(len(proposals)))
        candidates.append(Proposed(score, proposals, seeds))
    return Proposals(folds, tuple(candidates), tuple(notes))


def refit_candidates(
    proposals: Proposals,
    setup: RefitSetup,
    catalogue: Catalogue,
    settings: DiagnosisSettings,
    seed: int,
    pool: Pool,
) -> Refits:
    """Each candidate's extensions refitted fold by fold and judged on held-out runs; a
    decisive one that explains its feature refitted on every run (seeded ``seed + 997``).

    The fold refits of every proposal of every candidate go to the pool at once (each has
    its own seed, so where they run changes nothing); the judgements follow in rank order.
    """
    folds = proposals.folds
    # the base solves a proposal's folds share (filled in this process; on a cluster each
    # worker fills its own)
    bases: list[list[_Bases]] = [[{} for _ in c.proposals] for c in proposals.candidates]
    tasks: list[tuple[Any, ...]] = []
    for candidate, shared in zip(proposals.candidates, bases, strict=True):
        for proposal, start, base in zip(candidate.proposals, candidate.seeds, shared, strict=True):
            tasks += _fold_tasks(setup, proposal, folds, start, settings.refit_evals, base)
    done = iter(pool.map(refit_fold, tasks))
    causes: dict[str, Cause] = {}
    notes: list[str] = []
    held: dict[str, tuple[str, list[np.ndarray], bool]] = {}
    for candidate, shared in zip(proposals.candidates, bases, strict=True):
        fitted = [[next(done) for _ in folds] for _ in candidate.proposals]
        cause, trial, failed = _refit_candidate(
            setup,
            _candidate(catalogue, candidate.score.name),
            candidate,
            folds,
            fitted,
            shared,
            settings,
            seed,
        )
        notes += failed
        if cause is not None:
            causes[candidate.score.name] = cause
            if cause.confirmed and trial is not None:
                held[cause.name] = (cause.name, trial.models, trial.tracking)
    contests = tuple(contest(setup, folds, held[a], held[b]) for a in held for b in held if a != b)
    return Refits(causes, tuple(notes), contests)


def _candidate(catalogue: Catalogue, name: str) -> Any:
    return next(c for c in catalogue.candidates if c.name == name)


@dataclasses.dataclass(frozen=True)
class _Trial:
    """One proposal of a candidate, refitted fold by fold and judged on held-out runs."""

    proposal: ExtensionProposal
    fits: list[RefitResult]
    gain: Gain
    bases: _Bases
    models: list[np.ndarray]
    tracking: bool

    @property
    def train_lpd(self) -> float:
        """The folds' training log predictive density, summed: what picks the best trial."""
        return sum(f.train_lpd for f in self.fits)


def _judged_trials(
    setup: RefitSetup,
    entry: Any,
    candidate: Proposed,
    folds: Sequence[tuple[np.ndarray, np.ndarray]],
    fitted: Sequence[Sequence[RefitResult | Exception]],
    shared_bases: Sequence[_Bases],
) -> tuple[list[_Trial], list[str]]:
    """Each proposal's fold refits judged on held-out runs, and a note for each proposal
    whose refit failed."""
    notes: list[str] = []
    trials = []
    for proposal, results, shared in zip(candidate.proposals, fitted, shared_bases, strict=True):
        fits = [f for f in results if isinstance(f, RefitResult)]
        failed = [f for f in results if not isinstance(f, RefitResult)]
        tracking = tracks_speed(entry.signature)
        try:
            if failed:
                raise failed[0]
            models = held_out_models(setup, proposal, folds, fits)
            gain = judge_folds(setup, models, folds, tracking=tracking)
        except (ValueError, RuntimeError) as err:
            notes.append(f"{candidate.score.name} ({proposal.label}): refit failed: {err}")
            continue
        trials.append(_Trial(proposal, fits, gain, shared, models, tracking))
    return trials, notes


def _final_refit(
    setup: RefitSetup,
    recipe: Any,
    extended_system: Any,
    trial: _Trial,
    by_fold: Mapping[str, list[float]],
    settings: DiagnosisSettings,
    seed: int,
) -> tuple[dict[str, Any], dict[str, str]]:
    """A confirmed trial refitted on every run from the folds' mean (seeded ``seed + 997``),
    with Laplace standard deviations: its parameters (the recipe's derived ones with them)
    and the ends of its search box it stopped at."""
    proposal = trial.proposal
    final = refit_extension(
        setup,
        dataclasses.replace(
            proposal,
            start={**proposal.start, **{n: float(np.mean(v)) for n, v in by_fold.items()}},
        ),
        np.arange(len(setup.operating)),
        seed=seed + 997,
        max_evals=settings.refit_evals,
        bases=trial.bases,
        options=RefitOptions(uncertainty=True, workers=settings.workers),
    )
    parameters: dict[str, Any] = {
        n: {"mean": final.values[n], "sd": final.sd[n], "folds": by_fold[n]} for n in proposal.free
    }
    derived = recipe.derived(proposal, extended_system, {**setup.point, **final.values})
    derived_sd = recipe.derived_sd(proposal, final.values, final.sd)
    parameters.update({n: {"mean": v, "sd": derived_sd.get(n)} for n, v in derived.items()})
    # a value at an end of its search box is not an estimate: the all-runs fit's
    return parameters, final.at_bound()


def _refit_candidate(
    setup: RefitSetup,
    entry: Any,
    candidate: Proposed,
    folds: Sequence[tuple[np.ndarray, np.ndarray]],
    fitted: Sequence[Sequence[RefitResult | Exception]],
    shared_bases: Sequence[_Bases],
    settings: DiagnosisSettings,
    seed: int,
) -> tuple[Cause | None, _Trial | None, list[str]]:
    """One candidate (``entry``: its catalogue entry): its proposals' fold refits judged on
    held-out runs, the best on the training runs kept (returned with the cause), its
    symptom checked, and, when confirmed, its final refit on every run; and a note for each
    proposal whose refit failed."""
    score, recipe = candidate.score, entry.refit
    trials, notes = _judged_trials(setup, entry, candidate, folds, fitted, shared_bases)
    if not trials:
        return None, None, notes
    trial = max(trials, key=lambda t: t.train_lpd)
    proposal, fits, gain = trial.proposal, trial.fits, trial.gain
    # each fold's own value is kept: folds that disagree mark a refit to distrust
    by_fold = {n: [float(np.mean(f.values[n])) for f in fits] for n in proposal.free}
    parameters: dict[str, Any] = {
        n: {"mean": float(np.mean(v)), "sd": None, "folds": v} for n, v in by_fold.items()
    }
    extended_system = setup.system.with_extensions(proposal.extension)
    # each fold's refit as the recipe reads it (a rail-carrying mode's installed peak)
    fold_values = [
        {**f.values, **recipe.derived(proposal, extended_system, {**setup.point, **f.values})}
        for f in fits
    ]
    symptom = Symptom(
        *recipe.explains(
            score.parameters,
            setup.spectra.freqs,
            setup.spectra.measured,
            setup.base_spectra,
            held_out_spectra(fits, folds),
            tuple(setup.system.channels),
            refitted=fold_values,
        )
    )
    confirmed = gain.decisive and symptom.explained
    ends: dict[str, str] = {}
    if confirmed:
        parameters, ends = _final_refit(
            setup, recipe, extended_system, trial, by_fold, settings, seed
        )
    else:
        # ... else any fold's
        for f in fits:
            ends = {**f.at_bound(), **ends}
    _mark_boxes(parameters, proposal, fits[0].box, ends)
    return _refitted_cause(score, recipe, trial, parameters, symptom), trial, notes


def _refitted_cause(
    score: CauseScore,
    recipe: Any,
    trial: _Trial,
    parameters: Mapping[str, Any],
    symptom: Symptom,
) -> Cause:
    """The candidate's :class:`Cause` after its refit: the refit's evidence in words after the
    signature's, the refitted parameters over the signature's estimate."""
    proposal, gain = trial.proposal, trial.gain
    words = (
        f"refit of {score.name} ({proposal.label}) on half of the runs, tested on the other "
        f"half both ways: {gain.describe()}"
    )
    if symptom.words:
        verb = "explains" if symptom.explained else "does not explain"
        words += f"; the refit {verb} its own feature: {symptom.words}"
        if symptom.share is not None:
            words += f" ({100.0 * symptom.share:.0f} % of its excess taken away)"
    merged = {**dict(score.parameters), **parameters}
    return dataclasses.replace(
        _signature_cause(score),
        evidence=f"{score.evidence}. {words}",
        parameters=merged,
        gain=gain,
        feature_share=symptom.share,
        confirmed=gain.decisive and symptom.explained,
        label=proposal.label,
        proposal=proposal,
        alternatives=recipe.alternatives(merged),
    )


def _mark_boxes(
    parameters: dict[str, Any],
    proposal: ExtensionProposal,
    box: Mapping[str, tuple[float, float]],
    ends: Mapping[str, str],
) -> None:
    """Each refitted parameter's search box and the end it stopped at, the held ones, and
    the measured ones reported at their measured value beside the refit's."""
    for n in proposal.free:
        if n in box:
            parameters[n]["search_box"] = list(box[n])
        if n in ends:
            parameters[n]["at_bound"] = ends[n]
    parameters.update({n: {"mean": m, "sd": sd} for n, (m, sd) in proposal.held.items()})
    for n, (value, sd) in proposal.measured.items():
        refit = parameters[n]
        parameters[n] = {"mean": value, "sd": sd, "refit": refit["mean"]}
        for key in ("folds", "search_box", "at_bound"):
            if key in refit:
                parameters[n][key] = refit[key]


def judge(ranking: Ranking, refits: Refits) -> Judgement:
    """The verdict: the confirmed cause that wins most of its contests against the others
    (:class:`Contest`: the two extended models judged against each other on the held-out
    runs by the decision rule), the stronger held-out evidence over the base model breaking
    ties (:func:`verdict_order`); then the other confirmed causes in that order, then the
    rest by signature score. The notes say, for the verdict against each other confirmed
    cause, whether the held-out runs tell the two apart."""
    wins = {
        name: sum(1 for k in refits.contests if k.challenger == name and k.gain.decisive)
        for name in refits.causes
    }
    confirmed = sorted(
        (c for c in refits.causes.values() if c.confirmed),
        key=lambda c: (-wins[c.name], *verdict_order(held_out_evidence(c.gain), c.score)),  # type: ignore[arg-type]
    )
    verdict = confirmed[0].name if confirmed else NONE
    notes: list[str] = []
    if confirmed:
        notes += _verdict_notes(confirmed[0])
    if len(confirmed) > 1:
        notes.append(
            f"{len(confirmed)} causes confirmed, the verdict first, then by held-out evidence "
            "over the base model: "
            + ", ".join(
                f"{c.name} ({held_out_evidence(c.gain):.1f} SE)"  # type: ignore[arg-type]
                for c in confirmed
            )
        )
        notes += _contest_notes(verdict, confirmed[1:], refits.contests)
    others = [refits.causes.get(s.name, _signature_cause(s)) for s in ranking.causes]
    causes = tuple(confirmed) + tuple(c for c in others if not c.confirmed)
    return Judgement(verdict, causes, tuple(notes), refits.contests)


def _verdict_notes(first: Cause) -> list[str]:
    """What to read a verdict with: parameters at an end of their box, alternatives, and the
    share of its feature it left."""
    verdict = first.name
    notes = [
        f"{verdict}: {n} ended at the {value['at_bound']} end of its search box "
        f"[{value['search_box'][0]:.4g}, {value['search_box'][1]:.4g}]: the data would move "
        "it further, so it is not an estimate, nor are the parameters that trade off with it"
        for n, value in first.parameters.items()
        if isinstance(value, dict) and value.get("at_bound")
    ]
    notes += [
        f"the verdict {verdict} could also be {alternative}" for alternative in first.alternatives
    ]
    if first.feature_share is not None and first.feature_share < 1.0:
        notes.append(
            f"{verdict} explains its residual feature in part: its refit took away "
            f"{100.0 * first.feature_share:.0f} % of the feature's excess over the base "
            "model on held-out runs; the rest is still unexplained"
        )
    return notes


def _contest_notes(verdict: str, others: Sequence[Cause], contests: Sequence[Contest]) -> list[str]:
    """For the verdict against each other confirmed cause: which of the two extended models
    the held-out runs prefer, or that they cannot tell them apart."""
    by_pair = {(k.challenger, k.holder): k for k in contests}
    notes = []
    for other in others:
        won, lost = by_pair.get((verdict, other.name)), by_pair.get((other.name, verdict))
        if won is None or lost is None:
            continue
        se = held_out_evidence(won.gain)
        if won.gain.decisive:
            notes.append(
                f"{verdict} against {other.name} on the held-out runs: {verdict}'s model "
                f"predicts them better ({se:+.1f} SE, decisive by the rule)"
            )
        elif lost.gain.decisive:
            notes.append(
                f"{verdict} against {other.name} on the held-out runs: {other.name}'s model "
                f"predicts them better ({held_out_evidence(lost.gain):+.1f} SE), but "
                f"{verdict} wins more of its contests with the other confirmed causes"
            )
        else:
            notes.append(
                f"the held-out runs cannot tell {verdict} from {other.name}: against each "
                f"other {verdict}'s model gains {se:+.1f} SE, short of the rule; either may "
                "explain what the other does, and both may be present"
            )
    return notes
