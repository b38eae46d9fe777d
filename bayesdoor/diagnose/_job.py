"""The diagnosis of a campaign: residual features, ranked causes, refits, held-out gain, verdict.

:func:`diagnose_campaign` is generic over systems: it needs the system's catalogue (causes,
signatures and refit recipes) and the generic extension hooks of
:class:`~bayesdoor.systems.AbstractSystem`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Iterator, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import jax.numpy as jnp
import numpy as np
import xarray as xr

from .._cluster import Pool, in_process
from .._types import Float, Int
from ..features import motion_window as detect_motion_window
from ..features import welch_psd
from ..inference import FitResult, calibration_runs, fit_campaign
from ..io import operating as campaign_operating
from ._design import fold_labels
from ._features import Features, find_features
from ._gain import (
    RULE,
    Gain,
    changed_bins,
    compare_held_out,
    estimate_change_discrepancy,
    estimate_tracking_change_discrepancy,
    feature_bins,
    log_predictive,
)
from ._gain import objective_per_run as j_per_run
from ._limits import LIMIT_POWER, CauseLimit, cause_sizes, detection_limits
from ._rank import NONE, Catalogue, CauseScore, Ranking, rank_causes
from ._refit import (
    SMOOTH_BINS,
    ExtensionProposal,
    RefitResult,
    RefitSetup,
    Spectra,
    box_ends,
    exact_spectra,
    held_out_spectra,
    refit_extension,
    tile_runs,
)
from ._signatures import AbstractSignature, FirstOf, HarmonicComb, SpeedTracking

if TYPE_CHECKING:
    from ..systems import AbstractSystem

#: the base solves a refit keeps by grid point (shared by the folds of one proposal)
_Bases = dict[tuple[float, ...], np.ndarray]

#: a candidate is refitted when its signature passes at least this share of its checks
PLAUSIBLE_SCORE = 0.5


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
        }


@dataclasses.dataclass(frozen=True)
class Diagnosis:
    """The outcome of :func:`diagnose_campaign`.

    Attributes
    ----------
    verdict
        A catalogue name: the confirmed cause with the strongest held-out evidence (gain in
        standard errors; :func:`verdict_order`), or ``"none"``.
    causes
        Every candidate: all the confirmed ones, strongest evidence first, then the others
        by signature score.
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

    @property
    def confirmed(self) -> tuple[Cause, ...]:
        """The confirmed causes, strongest held-out evidence first."""
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
        words, notes and timings; ``confirmed`` (every confirmed cause, strongest first) and
        ``limits`` (per cause: its size's name, unit, the size named with the stated power,
        the power curve)."""
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
        }


def _plain(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


@dataclasses.dataclass(frozen=True)
class Measured:
    """The diagnosed runs of a campaign: signals, operating points, motion windows."""

    runs: np.ndarray
    signals: np.ndarray
    operating: np.ndarray
    t_start: np.ndarray
    t_stop: np.ndarray
    fs: float
    channels: tuple[str, ...]

    @classmethod
    def of(cls, system: AbstractSystem, campaign: xr.Dataset, runs: np.ndarray) -> Measured:
        fs = float(campaign.attrs.get("sampling_rate_hz", np.nan))
        if fs != system.sampling_rate_hz:
            raise ValueError(
                f"the campaign's sampling_rate_hz={fs} differs from {system.name}'s "
                f"{system.sampling_rate_hz} Hz: resample the measurements to the model's rate"
            )
        chosen = campaign.isel(run=np.asarray(runs))
        channels = tuple(system.channels)
        x = np.asarray(chosen["acceleration"].sel(channel=list(channels)).values, dtype=float)
        if "t_start" in chosen.variables and "t_stop" in chosen.variables:
            t0 = np.asarray(chosen["t_start"].values, dtype=float)
            t1 = np.asarray(chosen["t_stop"].values, dtype=float)
        else:
            t = np.arange(x.shape[-1]) / fs
            w = np.array([detect_motion_window(t, s) for s in x])
            t0, t1 = w[:, 0], w[:, 1]
        operating = campaign_operating(chosen, system)
        return cls(np.asarray(runs), x, operating, t0, t1, fs, channels)

    @property
    def duration(self) -> float:
        return self.signals.shape[-1] / self.fs

    def setup(
        self,
        system: AbstractSystem,
        point: Mapping[str, float],
        base_signals: np.ndarray,
        sample_times: np.ndarray,
        band: tuple[float, float],
        features: Features | None,
        speeds: np.ndarray | None = None,
    ) -> RefitSetup:
        spectra = Spectra.of_measured(
            self.signals, self.fs, self.t_start, self.t_stop, band, nperseg=int(self.fs)
        )
        if features is not None:
            local = feature_bins(features.residuals, spectra.freqs)
            spectra = dataclasses.replace(spectra, local=local)
        return RefitSetup(
            system=system,
            point=dict(point),
            operating=self.operating,
            duration=self.duration,
            time=sample_times,
            base_signals=base_signals,
            spectra=spectra,
            speeds=speeds,
        )


def _simulate_rows(
    system: AbstractSystem, measured: Measured, rows: Sequence[Mapping[str, float]]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signals (row, run, channel, time) of every run for each parameter row, success per row."""
    n_runs, n_time = len(measured.runs), measured.signals.shape[-1]
    values = {
        name: jnp.asarray(np.repeat([row[name] for row in rows], n_runs))
        for name in system.parameter_names()
    }
    result = system.simulate_values(
        values,
        jnp.asarray(tile_runs(measured.operating, len(rows))),
        state=system.healthy,
        duration=measured.duration,
    )
    ok = np.all(np.asarray(result.status).reshape(len(rows), n_runs) == 0, axis=1)
    signals = np.asarray(result.signals)[..., :n_time]
    return (
        signals.reshape(len(rows), n_runs, *signals.shape[1:]),
        ok,
        np.asarray(result.time)[:n_time],
    )


def _band(fit: FitResult, catalogue: Catalogue | None = None) -> tuple[float, float]:
    """The analysed band: the catalogue's ``band`` when it names one, else the fit's feature
    band (where the base model was fitted)."""
    if catalogue is not None and catalogue.band is not None:
        return float(catalogue.band[0]), float(catalogue.band[1])
    return float(fit.feature_spec.f_low), float(fit.feature_spec.f_high)


def _fold_order(catalogue: Catalogue, operating: np.ndarray) -> np.ndarray:
    """What :func:`held_out_folds` sorts the runs by: the catalogue's speed of each run, else
    the operating point (several conditions: their columns in order)."""
    speeds = catalogue.speeds(operating)
    return np.asarray(operating if speeds is None else speeds, dtype=float)


def _noise_rms(signals: np.ndarray, fs: float, t_start: np.ndarray) -> np.ndarray:
    """Per channel, the rms of white noise at the median level of the spectra before motion.

    The median over frequency of the pooled rest PSD is robust to lines and to the few
    resonances that ring at rest; it stands in for the measurement chain's noise, which a
    simulator does not produce.
    """
    n = int(np.floor(np.min(t_start) * fs))
    if n < 16:
        return np.zeros(signals.shape[1])
    _, psd = welch_psd(signals[..., :n], fs, nperseg=min(n, int(fs) // 4))
    level = np.median(psd.mean(axis=0), axis=-1)
    return np.sqrt(level * fs / 2.0)


def _pairs(catalogue: Catalogue) -> tuple[tuple[str, str], ...]:
    found: list[tuple[str, str]] = []
    for c in catalogue.candidates:
        for pair in getattr(c.signature, "pairs", ()):
            if tuple(pair) not in found:
                found.append(tuple(pair))
    return tuple(found)


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
    bases: dict[tuple[float, ...], np.ndarray],
    tracking: bool,
    workers: int = 1,
    pool: Pool | None = None,
) -> tuple[list[RefitResult], Gain]:
    """Refit on each fold's training runs, judge its held-out runs, both models alike
    (:func:`_fold_tasks`, then :func:`_judge_refits`).

    The folds are refitted on ``pool`` (``None``: ``workers`` threads of this process);
    every fold has its own seed, so the fits do not depend on where they ran.
    """
    pool = in_process(workers) if pool is None else pool
    results = pool.map(refit_fold, _fold_tasks(setup, proposal, folds, seed, max_evals, bases))
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
            setup, proposal, train, seed=seed, max_evals=max_evals, bases=bases, exact=False
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
    return judge_folds(setup, models, folds, tracking=tracking)


def judge_folds(
    setup: RefitSetup,
    models: Sequence[np.ndarray],
    folds: Sequence[tuple[np.ndarray, np.ndarray]],
    *,
    tracking: bool,
) -> Gain:
    """The held-out judgement of an extended model against the base model, fold by fold.

    ``models[k]`` holds the extended model's spectra of every run for fold ``k`` (its
    training runs as fitted, its held-out runs as predicted). Both models' scatter is split
    by the bins where they differ (:func:`changed_bins`), local in the order domain when the
    effect is ``tracking`` the speed, else in frequency; the folds' held-out runs together
    go to :func:`compare_held_out`. Also the judge of a model that knows an effect exactly
    (``scripts/full_size_case.py --ceiling``).
    """
    base = setup.base_spectra
    speeds = None
    if tracking:
        speeds = np.asarray(setup.operating if setup.speeds is None else setup.speeds, dtype=float)
    before, after = [], []
    for model, (train, test) in zip(models, folds, strict=True):
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


def base_fit_notes(system: AbstractSystem, fit: FitResult) -> list[str]:
    """A note for each continuous base parameter whose fitted value sits at an end of its
    bounds (an integer one, the contact law, is a choice, not an estimate).

    Such a value is not an estimate: the data would move it further. On the rig the base
    CMA-ES fit often ends at some bounds of the door's parameters (full-size campaigns,
    results/diagnosis_full_size.md: K at 2500, n at 1.5 or 2.2, c_r, mu_s or mu_d at an end,
    in 8 of 10 campaigns, also with a mains hum or a wheel hidden), so it is a warning to read
    the base model with, not evidence for any one cause: a missing effect the model bends
    itself to mimic, or bounds too narrow for this door.
    """
    lower, upper = (np.asarray(b, dtype=float) for b in fit.bounds)
    integer = {p.name for p in system.parameters if p.integer}
    box = {
        n: (float(lo), float(hi))
        for n, lo, hi in zip(fit.names, lower, upper, strict=True)
        if n not in integer
    }
    ends = box_ends({n: float(fit.point[n]) for n in fit.names if n in fit.point}, box)
    return [
        f"the base fit's {n} = {fit.point[n]:.4g} sits at the {end} end of its bounds "
        f"[{box[n][0]:.4g}, {box[n][1]:.4g}]: not an estimate; the base model may be bending "
        "to mimic a missing effect, or the bounds are too narrow for this system"
        for n, end in ends.items()
    ]


def held_out_evidence(gain: Gain) -> float:
    """A held-out gain in standard errors: ``elpd_difference / elpd_se`` (the plain
    statistic of the rule; ``inf`` for a positive gain without spread)."""
    if gain.elpd_se > 0:
        return float(gain.elpd_difference / gain.elpd_se)
    return float(np.sign(gain.elpd_difference) * np.inf) if gain.elpd_difference else 0.0


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


def _signature_cause(score: CauseScore) -> Cause:
    return Cause(
        name=score.name,
        description=score.description,
        score=score.score,
        evidence=score.evidence,
        parameters=dict(score.parameters),
        feature=score.feature,
    )


@dataclasses.dataclass(frozen=True)
class Residuals:
    """The residual map of the runs under the base fit (:func:`residual_map`).

    Attributes
    ----------
    features
        The residual features (:func:`find_features`).
    band
        The analysed band, Hz (:func:`_band`).
    setup
        What every refit and every detection limit of these runs shares.
    notes
        The base fit's parameters at an end of their bounds (:func:`base_fit_notes`): the
        map is read against that fit.
    """

    features: Features
    band: tuple[float, float]
    setup: RefitSetup
    notes: tuple[str, ...] = ()


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
    """The refitted causes by name, in rank order (:func:`refit_candidates`); ``notes``:
    the proposals whose refit failed."""

    causes: Mapping[str, Cause]
    notes: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class Judgement:
    """The verdict (:func:`judge`): a catalogue name or ``"none"``; every candidate, the
    confirmed ones first; ``notes``: what to read the verdict with."""

    verdict: str
    causes: tuple[Cause, ...]
    notes: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class Limits:
    """Each catalogue cause's detection limit in these runs (:func:`cause_limits`);
    ``notes``: the causes whose limit could not be computed."""

    limits: Mapping[str, CauseLimit] = dataclasses.field(default_factory=dict)
    notes: tuple[str, ...] = ()


@contextlib.contextmanager
def _timed(timings: dict[str, float], key: str) -> Iterator[None]:
    """Add the seconds of the block to ``timings[key]``."""
    t0 = time.perf_counter()
    yield
    timings[key] = timings.get(key, 0.0) + (time.perf_counter() - t0)


def measure(system: AbstractSystem, campaign: xr.Dataset) -> Measured:
    """The diagnosed runs of a campaign: its healthy calibration runs."""
    return Measured.of(system, campaign, calibration_runs(campaign, system.healthy))


def _predictive(
    system: AbstractSystem,
    fit: FitResult,
    measured: Measured,
    catalogue: Catalogue,
    draws_wanted: int,
    seed: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The base signals at the fit's point, ``draws_wanted`` posterior-predictive signals
    (with white noise at the level the records show at rest), and the simulated sample
    times."""
    draws = fit.posterior_draws()
    total = len(next(iter(draws.values())))
    pick = np.unique(np.linspace(0, total - 1, min(draws_wanted, total)).round())
    fixed = {k: v for k, v in fit.point.items() if k not in fit.names}
    rows = [dict(fit.point)]
    repeat = total == 1 and catalogue.random_realisations
    if total > 1:
        rows += [{**fixed, **{n: float(draws[n][int(i)]) for n in fit.names}} for i in pick]
    elif repeat:  # the point again at other batch positions: other realisations
        rows += [dict(fit.point)] * draws_wanted
    sims, ok, sample_times = _simulate_rows(system, measured, rows)
    if not ok[0]:
        raise RuntimeError(
            "the base model failed to simulate the runs at the fit's point: (a) the fit is not "
            "of this system, (b) the records are longer than the solver's max_steps allow"
        )
    base_signals = sims[0]
    sims = sims[1:][ok[1:]] if total > 1 or repeat else sims[:1]
    sims = sims[np.resize(np.arange(len(sims)), draws_wanted)]
    rng = np.random.default_rng(seed)
    noise = _noise_rms(measured.signals, measured.fs, measured.t_start)
    predictive = sims + noise[None, None, :, None] * rng.standard_normal(sims.shape)
    return base_signals, predictive, sample_times


def residual_map(
    system: AbstractSystem,
    fit: FitResult,
    measured: Measured,
    catalogue: Catalogue,
    settings: DiagnosisSettings,
    seed: int,
) -> Residuals:
    """The residual features of the runs against the posterior-predictive simulations, and
    the refits' shared setup."""
    notes = base_fit_notes(system, fit)
    base_signals, predictive, sample_times = _predictive(
        system, fit, measured, catalogue, settings.predictive_draws, seed
    )
    band = _band(fit, catalogue)
    speeds = catalogue.speeds(measured.operating)
    profiles = None
    if catalogue.speed_profile is not None:
        profiles = np.asarray(
            catalogue.speed_profile(
                measured.operating, np.arange(measured.signals.shape[-1]) / measured.fs
            ),
            dtype=float,
        )
    features = find_features(
        measured.signals,
        predictive,
        measured.fs,
        channels=measured.channels,
        t_start=measured.t_start,
        t_stop=measured.t_stop,
        speeds=speeds,
        speed_profiles=profiles,
        within_run=False,
        order_segment_m=catalogue.order_segment_m,
        pairs=_pairs(catalogue),
        band=band,
        smooth_discrepancy_bins=SMOOTH_BINS,
    )
    setup = measured.setup(system, fit.point, base_signals, sample_times, band, features, speeds)
    return Residuals(features, band, setup, tuple(notes))


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
    for candidate, shared in zip(proposals.candidates, bases, strict=True):
        fitted = [[next(done) for _ in folds] for _ in candidate.proposals]
        cause, failed = _refit_candidate(
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
    return Refits(causes, tuple(notes))


def _candidate(catalogue: Catalogue, name: str) -> Any:
    return next(c for c in catalogue.candidates if c.name == name)


def _refit_candidate(
    setup: RefitSetup,
    entry: Any,
    candidate: Proposed,
    folds: Sequence[tuple[np.ndarray, np.ndarray]],
    fitted: Sequence[Sequence[RefitResult | Exception]],
    shared_bases: Sequence[_Bases],
    settings: DiagnosisSettings,
    seed: int,
) -> tuple[Cause | None, list[str]]:
    """One candidate (``entry``: its catalogue entry): its proposals' fold refits judged on
    held-out runs, the best on the training runs kept, its symptom checked, and, when
    confirmed, its final refit on every run; and a note for each proposal whose refit
    failed."""
    score, proposals, recipe = candidate.score, candidate.proposals, entry.refit
    notes: list[str] = []
    trials = []
    for proposal, results, shared in zip(proposals, fitted, shared_bases, strict=True):
        fits = [f for f in results if isinstance(f, RefitResult)]
        failed = [f for f in results if not isinstance(f, RefitResult)]
        try:
            if failed:
                raise failed[0]
            gain = _judge_refits(
                setup, proposal, folds, fits, tracking=tracks_speed(entry.signature)
            )
        except (ValueError, RuntimeError) as err:
            notes.append(f"{score.name} ({proposal.label}): refit failed: {err}")
            continue
        trials.append((sum(f.train_lpd for f in fits), proposal, fits, gain, shared))
    if not trials:
        return None, notes
    _, proposal, fits, gain, bases = max(trials, key=lambda t: t[0])
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
    explained, symptom = recipe.explains(
        score.parameters,
        setup.spectra.freqs,
        setup.spectra.measured,
        setup.base_spectra,
        held_out_spectra(fits, folds),
        tuple(setup.system.channels),
        refitted=fold_values,
    )
    confirmed = gain.decisive and explained
    ends: dict[str, str] = {}
    if confirmed:
        final = refit_extension(
            setup,
            dataclasses.replace(
                proposal,
                start={**proposal.start, **{n: v["mean"] for n, v in parameters.items()}},
            ),
            np.arange(len(setup.operating)),
            seed=seed + 997,
            max_evals=settings.refit_evals,
            uncertainty=True,
            bases=bases,
            workers=settings.workers,
        )
        parameters = {
            n: {"mean": final.values[n], "sd": final.sd[n], "folds": by_fold[n]}
            for n in proposal.free
        }
        derived = recipe.derived(proposal, extended_system, {**setup.point, **final.values})
        derived_sd = recipe.derived_sd(proposal, final.values, final.sd)
        parameters.update({n: {"mean": v, "sd": derived_sd.get(n)} for n, v in derived.items()})
        # a value at an end of its search box is not an estimate: the all-runs fit's
        ends = final.at_bound()
    else:
        # ... else any fold's
        for f in fits:
            ends = {**f.at_bound(), **ends}
    _mark_boxes(parameters, proposal, fits[0].box, ends)
    words = (
        f"refit of {score.name} ({proposal.label}) on half of the runs, tested on the other "
        f"half both ways: {gain.describe()}"
    )
    if symptom:
        verb = "explains" if explained else "does not explain"
        words += f"; the refit {verb} its own feature: {symptom}"
    merged = {**dict(score.parameters), **parameters}
    cause = dataclasses.replace(
        _signature_cause(score),
        evidence=f"{score.evidence}. {words}",
        parameters=merged,
        gain=gain,
        confirmed=confirmed,
        label=proposal.label,
        proposal=proposal,
        alternatives=recipe.alternatives(merged),
    )
    return cause, notes


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
    """The verdict: every confirmed cause, strongest held-out evidence first
    (:func:`verdict_order`); then the others by signature score."""
    confirmed = sorted(
        (c for c in refits.causes.values() if c.confirmed),
        key=lambda c: verdict_order(held_out_evidence(c.gain), c.score),  # type: ignore[arg-type]
    )
    verdict = confirmed[0].name if confirmed else NONE
    notes: list[str] = []
    if confirmed:
        first = confirmed[0]
        notes += [
            f"{verdict}: {n} ended at the {value['at_bound']} end of its search box "
            f"[{value['search_box'][0]:.4g}, {value['search_box'][1]:.4g}]: the data would move "
            "it further, so it is not an estimate, nor are the parameters that trade off with it"
            for n, value in first.parameters.items()
            if isinstance(value, dict) and value.get("at_bound")
        ]
        notes += [
            f"the verdict {verdict} could also be {alternative}"
            for alternative in first.alternatives
        ]
    if len(confirmed) > 1:
        notes.append(
            f"{len(confirmed)} causes confirmed, strongest held-out evidence first: "
            + ", ".join(
                f"{c.name} ({held_out_evidence(c.gain):.1f} SE)"  # type: ignore[arg-type]
                for c in confirmed
            )
        )
    others = [refits.causes.get(s.name, _signature_cause(s)) for s in ranking.causes]
    causes = tuple(confirmed) + tuple(c for c in others if not c.confirmed)
    return Judgement(verdict, causes, tuple(notes))


def cause_limits(
    setup: RefitSetup,
    catalogue: Catalogue,
    band: tuple[float, float],
    settings: DiagnosisSettings,
    seed: int,
    pool: Pool,
) -> Limits:
    """Every catalogue cause's smallest size the rule names with the stated power in these
    runs (:func:`detection_limits`), one task per cause on the pool (each has its own draws
    from the same seed, so the limits do not depend on where they ran)."""
    names = list(cause_sizes(catalogue, band))
    tasks = [(setup, catalogue, settings.limit_draws, seed, name, band) for name in names]
    limits: dict[str, CauseLimit] = {}
    notes: list[str] = []
    for found, note in pool.map(cause_limit, tasks):
        limits.update(found)
        if note is not None:
            notes.append(note)
    return Limits(limits, tuple(notes))


def cause_limit(
    setup: RefitSetup,
    catalogue: Catalogue,
    draws: int,
    seed: int,
    name: str,
    band: tuple[float, float],
) -> tuple[Mapping[str, CauseLimit], str | None]:
    """One cause's detection limit (:func:`detection_limits`), or why there is none."""
    try:
        found = detection_limits(
            setup,
            catalogue,
            power=LIMIT_POWER,
            draws=draws,
            seed=seed,
            causes=(name,),
            band=band,
        )
    except (ValueError, RuntimeError) as err:
        return {}, f"{name}: its detection limit could not be computed ({err})"
    return found, None


def diagnose_campaign(
    system: AbstractSystem,
    campaign: xr.Dataset,
    *,
    fit: FitResult | None = None,
    seed: int = 0,
    quick: bool = False,
    progress: bool = True,
    catalogue: Catalogue | None = None,
    settings: DiagnosisSettings | None = None,
    pool: Pool | None = None,
) -> Diagnosis:
    """Show where a model departs from a campaign, name the cause, measure the gain, state
    what the campaign could not have shown.

    The steps, each a function of what the earlier ones made, returning a frozen product
    (their notes, in this order, are the diagnosis's):

    1. *fit*: the base model is fitted on the calibration runs (:func:`bayesdoor.inference.
       fit_campaign`, CMA-ES) unless ``fit`` is given.
    2. :func:`measure` (:class:`Measured`), :func:`residual_map` (:class:`Residuals`),
       :func:`rank_causes` (:class:`Ranking`): posterior-predictive simulations of those
       runs (plus white noise at the level the records show at rest) give the residual
       features (:func:`find_features`, over the fit's feature band, with the smooth
       discrepancy taken out) and the signature ranking.
    3. :func:`propose` (:class:`Proposals`): each plausible candidate (signature score at
       least ``PLAUSIBLE_SCORE``, at most ``max_candidates``) has its catalogue recipe propose
       model extensions started from the signature's estimate.
    4. :func:`refit_candidates` (:class:`Refits`): each extension's parameters are fitted
       with the base parameters at the fit's point on one half of the runs and tested on the
       other half, both ways (two folds; halves alternate in speed); a confirmed one is
       refitted on all runs, with Laplace standard deviations.
    5. :func:`judge` (:class:`Judgement`): every confirmed cause is reported, the strongest
       held-out evidence (gain in standard errors) first; the verdict names the first
       (:func:`verdict_order`), else ``none`` (:data:`~bayesdoor.diagnose.RULE`).
    6. :func:`cause_limits` (:class:`Limits`): for every catalogue cause that declares its
       size (:meth:`~bayesdoor.diagnose.AbstractRefit.size`), the smallest size the rule
       would name with 80 % probability in these runs (:func:`detection_limits`).

    Parameters
    ----------
    system
        The base system (the catalogue's extensions are switched on by the refits).
    campaign
        The measurements (the campaign format, docs/data.md); the runs diagnosed are the
        healthy calibration runs (``bayesdoor.inference.calibration_runs``).
    fit
        The base model's fit on this campaign; ``None``: fitted here.
    seed
        Seeds the fit, the predictive noise and the refits.
    quick
        Small sizes (:meth:`DiagnosisSettings.quick`, and a quick fit when fitting here).
    progress
        Show progress bars.
    catalogue
        The system's catalogue; ``None``: ``system.catalogue``.
    settings
        Sizes (overrides ``quick``).
    pool
        Where the refits and the limits run (:meth:`bayesdoor.Cluster.open`); ``None``:
        ``settings.workers`` threads of this process. The diagnosis does not depend on it.

    Returns
    -------
    Diagnosis

    Raises
    ------
    ValueError
        For a system without a catalogue, a campaign without healthy calibration runs, or a
        sampling rate that is not the system's.
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed={seed!r} must be an integer >= 0")
    catalogue = system.catalogue if catalogue is None else catalogue
    if not isinstance(catalogue, Catalogue):
        raise ValueError(
            f"{system.name} has no catalogue of discrepancy causes (system.catalogue is "
            f"{catalogue!r}): pass catalogue= (a bayesdoor.diagnose.Catalogue)"
        )
    if settings is None:
        settings = DiagnosisSettings.quick() if quick else DiagnosisSettings()
    pool = in_process(settings.workers) if pool is None else pool
    timings: dict[str, float] = {}
    if fit is None:
        with _timed(timings, "fit"):
            fit = fit_campaign(
                system, campaign, method="cmaes", seed=int(seed), quick=quick, progress=progress
            )
    with _timed(timings, "features"):
        measured = measure(system, campaign)
        residuals = residual_map(system, fit, measured, catalogue, settings, int(seed))
        ranking = rank_causes(residuals.features, catalogue)
    with _timed(timings, "refits"):
        proposals = propose(ranking, measured, catalogue, residuals.band, settings, int(seed))
        refits = refit_candidates(proposals, residuals.setup, catalogue, settings, int(seed), pool)
        judgement = judge(ranking, refits)
    limits = Limits()
    if settings.limits:
        with _timed(timings, "limits"):
            limits = cause_limits(
                residuals.setup, catalogue, residuals.band, settings, int(seed), pool
            )
    return Diagnosis(
        verdict=judgement.verdict,
        causes=judgement.causes,
        ranking=ranking,
        catalogue=catalogue,
        rule=RULE,
        runs=np.asarray(measured.runs),
        notes=residuals.notes + proposals.notes + refits.notes + judgement.notes + limits.notes,
        timings=timings,
        fit=fit,
        limits=limits.limits,
    )


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
    sims, ok, sample_times = _simulate_rows(system, measured, [dict(fit.point)])
    if not ok[0]:
        raise RuntimeError("the base model failed to simulate the runs at the fit's point")
    speeds = None if known is None else known.speeds(measured.operating)
    setup = measured.setup(
        system, fit.point, sims[0], sample_times, _band(fit, known), features, speeds
    )
    ext = proposal.extension
    name = ext if isinstance(ext, str) else getattr(ext, "name", None)
    signatures = (
        {c.name: c.signature for c in catalogue.candidates}
        if isinstance(catalogue, Catalogue)
        else {}
    )
    tracking = name in signatures and tracks_speed(signatures[name])
    fits, gain = _cross_validate(
        setup,
        proposal,
        folds,
        seed=seed,
        max_evals=settings.refit_evals,
        bases={},
        tracking=tracking,
        workers=settings.workers,
    )
    return gain, tuple(fits)
