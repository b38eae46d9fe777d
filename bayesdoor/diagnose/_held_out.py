"""The held-out judgement: folds of the runs, refits on each fold's training runs, and the
gain of the extended model over the base model on the runs each refit did not see."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import xarray as xr

from .._cluster import Pool, in_process
from .._types import Float, Int
from ..inference import FitResult
from ._design import fold_labels
from ._diagnosis import DiagnosisSettings
from ._features import Features
from ._gain import (
    Contest,
    Gain,
    changed_bins,
    compare_held_out,
    estimate_change_discrepancy,
    estimate_tracking_change_discrepancy,
    log_predictive,
)
from ._gain import objective_per_run as j_per_run
from ._measured import _band, _fold_order, base_setup, measure
from ._rank import Catalogue
from ._refit import (
    SMOOTH_BINS,
    ExtensionProposal,
    RefitOptions,
    RefitResult,
    RefitSetup,
    Spectra,
    exact_spectra,
    refit_extension,
)
from ._signatures import AbstractSignature, FirstOf, HarmonicComb, SpeedTracking

if TYPE_CHECKING:
    from ..systems import AbstractSystem

#: the base solves a refit keeps by grid point (shared by the folds of one proposal)
_Bases = dict[tuple[float, ...], np.ndarray]


def held_out_folds(
    operating: Float[np.ndarray, " run"] | Float[np.ndarray, "run condition"], k: int
) -> list[tuple[Int[np.ndarray, " train"], Int[np.ndarray, " test"]]]:
    """``k`` folds (train, test) of the held-out judgement.

    The runs sorted by operating point are dealt to the ``k`` test sets in turn, so each
    test set spans the operating range and every run is held out once (``k = 2``: alternate
    runs). ``k`` is capped at the number of runs.

    Parameters
    ----------
    operating
        Each run's operating point (``(run, condition)``: sorted by the first condition,
        ties by the next).
    k
        Number of folds.

    Returns
    -------
    folds
        ``(train, test)`` run indices, sorted; empty when a training set would have fewer
        than 2 runs.

    Raises
    ------
    ValueError
        For ``k < 2``.
    """
    if int(k) < 2:
        raise ValueError(f"k={k!r}: the held-out judgement needs at least 2 folds")
    n = len(operating)
    k = min(int(k), n)
    if n - int(np.ceil(n / k)) < 2:
        return []
    labels = fold_labels(operating, k)
    tests = [np.flatnonzero(labels == i) for i in range(k)]
    return [(np.setdiff1d(np.arange(n), test), test) for test in tests]


@dataclasses.dataclass(frozen=True)
class _HeldOut:
    lpd: np.ndarray
    j: np.ndarray


def tracks_speed(signature: AbstractSignature) -> bool:
    """Whether a cause with this signature is a tone at a fixed wavenumber, ``f = v / lambda``.

    True for :class:`SpeedTracking` and :class:`HarmonicComb` (the comb of a revolution in the
    order spectra), and for a :class:`FirstOf` all of whose signatures are; such a cause's
    extension is judged with its scatter local in the order domain
    (:func:`estimate_tracking_change_discrepancy`), every other one's local in frequency.
    """
    if isinstance(signature, FirstOf):
        return all(tracks_speed(s) for s in signature.signatures)
    return isinstance(signature, SpeedTracking | HarmonicComb)


def _held_out(
    spectra: Spectra,
    model: np.ndarray,
    changed: np.ndarray,
    train: np.ndarray,
    test: np.ndarray,
    speeds: np.ndarray | None,
) -> _HeldOut:
    """One model's held-out density and J; ``speeds``: its changed bins local in order."""
    y, lv = spectra.measured, spectra.log_variance
    if speeds is None:
        disc = estimate_change_discrepancy(
            model[train], y[train], lv[train], SMOOTH_BINS, changed[train]
        ).at(changed[test])
    else:
        disc = estimate_tracking_change_discrepancy(
            model[train],
            y[train],
            lv[train],
            SMOOTH_BINS,
            changed[train],
            spectra.freqs,
            speeds[train],
        ).at(changed[test], speeds[test])
    return _HeldOut(
        lpd=log_predictive(model[test], y[test], lv[test], disc),
        j=j_per_run(model[test] + disc.smooth, y[test]),
    )


def _cross_validate(
    setup: RefitSetup,
    proposal: ExtensionProposal,
    folds: Sequence[tuple[np.ndarray, np.ndarray]],
    *,
    seed: int,
    max_evals: int,
    tracking: bool,
    workers: int = 1,
    pool: Pool | None = None,
) -> tuple[list[RefitResult], Gain]:
    """Refit on each fold's training runs, judge its held-out runs, both models alike
    (:func:`_fold_tasks`, then :func:`_judge_refits`).

    The folds are refitted on ``pool`` (``None``: ``workers`` threads of this process),
    sharing one cache of base solves; every fold has its own seed, so the fits do not depend
    on where they ran.
    """
    pool = in_process(workers) if pool is None else pool
    results = pool.map(refit_fold, _fold_tasks(setup, proposal, folds, seed, max_evals, {}))
    fits = [f for f in results if isinstance(f, RefitResult)]
    for failed in results:
        if not isinstance(failed, RefitResult):
            raise failed
    return fits, _judge_refits(setup, proposal, folds, fits, tracking=tracking)


def _fold_tasks(
    setup: RefitSetup,
    proposal: ExtensionProposal,
    folds: Sequence[tuple[np.ndarray, np.ndarray]],
    seed: int,
    max_evals: int,
    bases: _Bases,
) -> list[tuple[Any, ...]]:
    """The arguments of :func:`refit_fold` for each fold (fold ``k`` seeded ``seed + k``)."""
    return [
        (setup, proposal, train, seed + k, max_evals, bases) for k, (train, _) in enumerate(folds)
    ]


def refit_fold(
    setup: RefitSetup,
    proposal: ExtensionProposal,
    train: np.ndarray,
    seed: int,
    max_evals: int,
    bases: _Bases,
) -> RefitResult | ValueError | RuntimeError:
    """One fold's refit on its training runs (:func:`refit_extension`, spectra of the
    approximate solve), or the error that stopped it, so that one failed proposal does not
    stop the others refitted beside it."""
    try:
        return refit_extension(
            setup,
            proposal,
            train,
            seed=seed,
            max_evals=max_evals,
            bases=bases,
            options=RefitOptions(exact=False),
        )
    except (ValueError, RuntimeError) as err:
        return err


def _judge_refits(
    setup: RefitSetup,
    proposal: ExtensionProposal,
    folds: Sequence[tuple[np.ndarray, np.ndarray]],
    fits: Sequence[RefitResult],
    *,
    tracking: bool,
) -> Gain:
    """The held-out judgement of one proposal's fold refits.

    The held-out runs of every fold are simulated exactly at the values fitted without them,
    all in one simulation (:func:`exact_spectra`); the extended model's discrepancy is
    estimated on the training runs from the spectra it was fitted with. Both models' scatter
    is split by the bins where the extension changes the prediction (:func:`changed_bins` of
    the two models' spectra of every run in the fold: the training runs' as fitted, the
    held-out runs' as simulated), so the judgement asks where the extension predicts
    something different, does it predict better. For an extension whose effect ``tracking``
    the speed (a tone at ``f = v / lambda`` of each run's operating speed) the scatter in the
    changed bins is local in the order domain, else in frequency.
    """
    models = held_out_models(setup, proposal, folds, fits)
    return judge_folds(setup, models, folds, tracking=tracking)


def held_out_models(
    setup: RefitSetup,
    proposal: ExtensionProposal,
    folds: Sequence[tuple[np.ndarray, np.ndarray]],
    fits: Sequence[RefitResult],
) -> list[Float[np.ndarray, "run channel freq"]]:
    """Each fold's extended model spectra of every run: its training runs as fitted, its
    held-out runs simulated exactly at the values fitted without them (every fold's in one
    simulation, :func:`exact_spectra`)."""
    tests = np.concatenate([test for _, test in folds])
    values = {
        n: np.concatenate(
            [np.full(len(test), f.values[n]) for f, (_, test) in zip(fits, folds, strict=True)]
        )
        for n in proposal.free
    }
    held = exact_spectra(setup, proposal, values, tests)
    models, start = [], 0
    for fit, (_, test) in zip(fits, folds, strict=True):
        model = fit.spectra.copy()
        model[test] = held[start : start + len(test)]
        start += len(test)
        models.append(model)
    return models


def judge_folds(
    setup: RefitSetup,
    models: Sequence[np.ndarray],
    folds: Sequence[tuple[np.ndarray, np.ndarray]],
    *,
    tracking: bool,
    reference: Sequence[np.ndarray] | None = None,
) -> Gain:
    """The held-out judgement of an extended model against the base model, fold by fold.

    ``models[k]`` holds the extended model's spectra of every run for fold ``k`` (its
    training runs as fitted, its held-out runs as predicted). Both models' scatter is split
    by the bins where they differ (:func:`changed_bins`), local in the order domain when the
    effect is ``tracking`` the speed, else in frequency; the folds' held-out runs together
    go to :func:`compare_held_out`. Also the judge of a model that knows an effect exactly
    (``scripts/full_size_case.py --ceiling``). ``reference``: per fold, the spectra of
    another extended model (as ``models``) to judge against instead of the base model
    (:func:`contest`).
    """
    base = setup.base_spectra
    speeds = None
    if tracking:
        speeds = np.asarray(setup.operating if setup.speeds is None else setup.speeds, dtype=float)
    before, after = [], []
    for k, (model, (train, test)) in enumerate(zip(models, folds, strict=True)):
        if reference is not None:
            base = reference[k]
        changed = changed_bins(base, model, setup.spectra.log_variance)
        before.append(_held_out(setup.spectra, base, changed, train, test, speeds))
        after.append(_held_out(setup.spectra, model, changed, train, test, speeds))
    gain = compare_held_out(
        np.concatenate([h.lpd for h in before]),
        np.concatenate([h.lpd for h in after]),
        np.concatenate([h.j for h in before]),
        np.concatenate([h.j for h in after]),
    )
    tests = np.concatenate([test for _, test in folds])
    return dataclasses.replace(gain, runs=tuple(int(r) for r in tests))


def contest(
    setup: RefitSetup,
    folds: Sequence[tuple[np.ndarray, np.ndarray]],
    challenger: tuple[str, Sequence[np.ndarray], bool],
    holder: tuple[str, Sequence[np.ndarray], bool],
) -> Contest:
    """The challenger's extended model judged against the holder's on the held-out runs.

    Each is ``(name, per-fold spectra as held_out_models gives them, tracking)``; the scatter
    in the changed bins is local in the order domain only when both effects track the speed
    (the bins where the two differ hold a fixed effect's otherwise).
    """
    name, models, tracks = challenger
    other, reference, other_tracks = holder
    gain = judge_folds(setup, models, folds, tracking=tracks and other_tracks, reference=reference)
    return Contest(name, other, gain)


def verdict_order(evidence: float, score: float) -> tuple[float, float]:
    """The order of confirmed causes (the first is the verdict): the stronger held-out
    evidence first, then the better signature match.

    Every confirmed cause passed the rule on runs its refit did not see, so each is reported;
    the evidence (the held-out gain in standard errors, :func:`held_out_evidence`) ranks them
    because it is what the rule judges, on the same runs and the same folds for all. The
    signature score only breaks ties: it measures how well a residual feature fits a
    description, not how much of the data an extension explains, and ordering by it first
    named a frame mode confirmed at 14.8 SE before a cross-axis leak confirmed at 18.9 SE
    (the leak hidden, on an independent implementation of the door). An extension can still
    absorb the symptoms of another cause and gain more than it (a leak beside a missing mode
    that both channels of its sensor feel): then both are confirmed and both are listed, and
    the notes say so.

    Parameters
    ----------
    evidence
        The held-out gain in standard errors.
    score
        The signature score of :func:`rank_causes` (0-1).

    Returns
    -------
    tuple
        A sort key: sort ascending.
    """
    return (-float(evidence), -float(score))


def _tracks_the_speed(known: Catalogue | None, proposal: ExtensionProposal) -> bool:
    """Whether ``known`` holds a cause named as the extension whose signature tracks the speed
    (:func:`tracks_speed`)."""
    ext = proposal.extension
    name = ext if isinstance(ext, str) else getattr(ext, "name", None)
    signatures = {c.name: c.signature for c in known.candidates} if known is not None else {}
    return name in signatures and tracks_speed(signatures[name])


def extension_gain(
    system: AbstractSystem,
    campaign: xr.Dataset,
    proposal: ExtensionProposal,
    *,
    fit: FitResult,
    seed: int = 0,
    quick: bool = False,
    features: Features | None = None,
    catalogue: Catalogue | None = None,
) -> tuple[Gain, tuple[RefitResult, ...]]:
    """The held-out gain of one model extension forced onto a campaign's healthy runs.

    The refit and the test of :func:`diagnose_campaign`'s step 2 for an extension chosen by
    the caller, whatever the residual features say: for example to check that a wrong
    extension buys nothing.

    Parameters
    ----------
    system
        The base system.
    campaign
        The measurements; the healthy calibration runs are used.
    proposal
        The extension, its start and search boxes.
    fit
        The base model's fit.
    seed
        Seeds the refits.
    quick
        The refit budget of :meth:`DiagnosisSettings.quick`.
    features
        The residual features of these runs under ``fit`` (``Diagnosis.features``): the
        refit's discrepancy scatter is local in their bins, as in :func:`diagnose_campaign`;
        ``None``: one value per channel everywhere. The held-out judgement splits it by the
        bins the extension changes either way.
    catalogue
        The system's catalogue (``None``: ``system.catalogue``): when it holds a cause named
        as the extension (``proposal.extension``, a name or a module with a ``name``) whose
        signature tracks the speed (:func:`tracks_speed`), the judgement's scatter in the
        changed bins is local in the order domain, as in :func:`diagnose_campaign`; otherwise
        local in frequency.

    Returns
    -------
    gain
        Held-out J and log predictive density, both folds together.
    refits
        The refit of each fold.

    Raises
    ------
    ValueError
        For fewer than 4 healthy calibration runs.
    """
    settings = DiagnosisSettings.quick() if quick else DiagnosisSettings()
    measured = measure(system, campaign)
    catalogue = system.catalogue if catalogue is None else catalogue
    known = catalogue if isinstance(catalogue, Catalogue) else None
    order = measured.operating if known is None else _fold_order(known, measured.operating)
    folds = held_out_folds(order, settings.folds)
    if not folds:
        raise ValueError(
            f"{len(measured.runs)} healthy calibration runs: need at least 4 to fit on half "
            "and test on the other half"
        )
    speeds = None if known is None else known.speeds(measured.operating)
    setup = base_setup(system, measured, fit, _band(fit, known), features, speeds)
    tracking = _tracks_the_speed(known, proposal)
    fits, gain = _cross_validate(
        setup,
        proposal,
        folds,
        seed=seed,
        max_evals=settings.refit_evals,
        tracking=tracking,
        workers=settings.workers,
    )
    return gain, tuple(fits)
