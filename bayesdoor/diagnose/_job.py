"""The diagnosis of a campaign: residual features, ranked causes, refits, held-out gain, verdict.

:func:`diagnose_campaign` is generic over systems: it needs the system's catalogue (causes,
signatures and refit recipes) and the generic extension hooks of
:class:`~bayesdoor.systems.AbstractSystem`.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

import jax.numpy as jnp
import numpy as np
import scipy.signal
import xarray as xr

from .._types import Float, Int
from ..features import motion_window as detect_motion_window
from ..inference import FitResult, calibration_runs, fit_campaign
from ..io import operating as campaign_operating
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
)
from ._signatures import AbstractSignature, FirstOf, HarmonicComb, SpeedTracking

if TYPE_CHECKING:
    from ..systems import AbstractSystem

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
    """

    predictive_draws: int = 8
    max_candidates: int = 5
    refit_evals: int = 240
    folds: int = 2
    workers: int = 2

    def __post_init__(self) -> None:
        least = {
            "predictive_draws": 1,
            "max_candidates": 0,
            "refit_evals": 1,
            "folds": 2,
            "workers": 1,
        }
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
        A catalogue name: the confirmed cause whose signature matched best (then the largest
        held-out gain; :func:`verdict_order`), or ``"none"``.
    causes
        Every candidate: the confirmed ones in the verdict's order, then the others by
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
        Seconds per stage.
    fit
        The base model's fit the diagnosis was made under (given, or made by
        :func:`diagnose_campaign`), so that a report can show it.
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

    @property
    def features(self) -> Features:
        return self.ranking.features

    def cause(self, name: str) -> Cause:
        for c in self.causes:
            if c.name == name:
                return c
        raise KeyError(f"no cause {name!r}; the causes are {[c.name for c in self.causes]}")

    def to_json(self) -> dict[str, Any]:
        """The JSON of docs/cli.md (``bayesdoor diagnose``): ``verdict`` and ``causes`` (each
        ``name``, ``evidence``, ``parameters``, ``gain``), plus the rule, the features in
        words, notes and timings."""
        return {
            "verdict": self.verdict,
            "causes": [c.to_json() for c in self.causes],
            "rule": self.rule,
            "signature_verdict": self.ranking.verdict,
            "features": self.features.summary(),
            "runs": self.runs.tolist(),
            "notes": list(self.notes),
            "timings": dict(self.timings),
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
class _Measured:
    """The diagnosed runs of a campaign: signals, operating points, motion windows."""

    runs: np.ndarray
    signals: np.ndarray
    operating: np.ndarray
    t_start: np.ndarray
    t_stop: np.ndarray
    fs: float
    channels: tuple[str, ...]

    @classmethod
    def of(cls, system: AbstractSystem, campaign: xr.Dataset, runs: np.ndarray) -> _Measured:
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
        )


def _simulate_rows(
    system: AbstractSystem, measured: _Measured, rows: Sequence[Mapping[str, float]]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signals (row, run, channel, time) of every run for each parameter row, success per row."""
    n_runs, n_time = len(measured.runs), measured.signals.shape[-1]
    values = {
        name: jnp.asarray(np.repeat([row[name] for row in rows], n_runs))
        for name in system.parameter_names()
    }
    result = system.simulate_values(
        values, jnp.asarray(np.tile(measured.operating, len(rows))), duration=measured.duration
    )
    ok = np.all(np.asarray(result.status).reshape(len(rows), n_runs) == 0, axis=1)
    signals = np.asarray(result.signals)[..., :n_time]
    return (
        signals.reshape(len(rows), n_runs, *signals.shape[1:]),
        ok,
        np.asarray(result.time)[:n_time],
    )


def _band(fit: FitResult) -> tuple[float, float]:
    """The analysed band: the fit's feature band (where the base model was fitted)."""
    return float(fit.feature_spec.f_low), float(fit.feature_spec.f_high)


def _noise_rms(signals: np.ndarray, fs: float, t_start: np.ndarray) -> np.ndarray:
    """Per channel, the rms of white noise at the median level of the spectra before motion.

    The median over frequency of the pooled rest PSD is robust to lines and to the few
    resonances that ring at rest; it stands in for the measurement chain's noise, which a
    simulator does not produce.
    """
    n = int(np.floor(np.min(t_start) * fs))
    if n < 16:
        return np.zeros(signals.shape[1])
    _, psd = scipy.signal.welch(signals[..., :n], fs, nperseg=min(n, int(fs) // 4), axis=-1)
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
    operating: Float[np.ndarray, " run"], k: int
) -> list[tuple[Int[np.ndarray, " train"], Int[np.ndarray, " test"]]]:
    """``k`` folds (train, test) of the held-out judgement.

    The runs sorted by operating point are dealt to the ``k`` test sets in turn, so each
    test set spans the operating range and every run is held out once (``k = 2``: alternate
    runs). ``k`` is capped at the number of runs.

    Parameters
    ----------
    operating
        Each run's operating point.
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
    order = np.argsort(np.asarray(operating), kind="stable")
    tests = [np.sort(order[i::k]) for i in range(k)]
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
) -> tuple[list[RefitResult], Gain]:
    """Refit on each fold's training runs, judge its held-out runs, both models alike.

    The held-out runs of every fold are simulated exactly at the values fitted without them,
    all in one simulation (:func:`exact_spectra`); the extended model's discrepancy is
    estimated on the training runs from the spectra it was fitted with. Both models' scatter
    is split by the bins where the extension changes the prediction (:func:`changed_bins` of
    the two models' spectra of every run in the fold: the training runs' as fitted, the
    held-out runs' as simulated), so the judgement asks where the extension predicts
    something different, does it predict better. For an extension whose effect ``tracking``
    the speed (a tone at ``f = v / lambda`` of each run's operating speed) the scatter in the
    changed bins is local in the order domain, else in frequency. ``workers`` threads refit
    folds at once; every fold has its own seed, so the fits do not depend on it.
    """

    def refit(k: int) -> RefitResult:
        return refit_extension(
            setup,
            proposal,
            folds[k][0],
            seed=seed + k,
            max_evals=max_evals,
            bases=bases,
            exact=False,
        )

    if workers > 1 and len(folds) > 1:
        with ThreadPoolExecutor(min(workers, len(folds))) as pool:
            fits = list(pool.map(refit, range(len(folds))))
    else:
        fits = [refit(k) for k in range(len(folds))]
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
    return fits, judge_folds(setup, models, folds, tracking=tracking)


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
    speeds = np.asarray(setup.operating, dtype=float) if tracking else None
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


def verdict_order(score: float, gain: float) -> tuple[float, float]:
    """The order of confirmed causes for the verdict (the first is named): the better
    signature match first, then the larger held-out gain.

    The held-out gain confirms a cause; it does not rank them. An extension can absorb the
    symptoms of another cause and then gain more than it: on the rig a leak between the two
    channels of a sensor that both feel a missing mode gains more than the mode (frame mode
    seed 3 at 8 runs), and a mode on A2Z near the frequency where a leak puts A2X's header
    mode gains more than the leak (cross-axis seed 0 at 8 runs;
    results/diagnosis_judgement.md). In both the cause whose signature the residual features
    show best is the hidden one.

    Parameters
    ----------
    score
        The signature score of :func:`rank_causes` (0-1).
    gain
        The held-out ELPD difference (nats).

    Returns
    -------
    tuple
        A sort key: sort ascending.
    """
    return (-float(score), -float(gain))


def _signature_cause(score: CauseScore) -> Cause:
    return Cause(
        name=score.name,
        description=score.description,
        score=score.score,
        evidence=score.evidence,
        parameters=dict(score.parameters),
        feature=score.feature,
    )


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
) -> Diagnosis:
    """Show where a model departs from a campaign, name the cause, measure the gain.

    1. The base model is fitted on the calibration runs (:func:`bayesdoor.inference.
       fit_campaign`, CMA-ES) unless ``fit`` is given; posterior-predictive simulations of
       those runs (plus white noise at the level the records show at rest) give the
       residual features (:func:`find_features`, over the fit's feature band, with the
       smooth discrepancy taken out) and the signature ranking (:func:`rank_causes`).
    2. Each plausible candidate (signature score at least ``PLAUSIBLE_SCORE``, at most
       ``max_candidates``) is confirmed by fitting: its catalogue recipe proposes a model
       extension started from the signature's estimate, whose parameters are fitted with the
       base parameters at the fit's point on one half of the runs and tested on the other
       half, both ways (two folds; halves alternate in speed).
    3. The verdict is the confirmed extension whose signature matched best, then the one
       with the largest held-out gain (:func:`verdict_order`), else ``none``
       (:data:`~bayesdoor.diagnose.RULE`); its parameters are refitted on all runs, with
       Laplace standard deviations.

    Parameters
    ----------
    system
        The base system (the catalogue's extensions are switched on by the refits).
    campaign
        The measurements (the campaign format, docs/data.md); the runs diagnosed are the
        healthy calibration
        runs (``bayesdoor.inference.calibration_runs``).
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
    settings = (
        (DiagnosisSettings.quick() if quick else DiagnosisSettings())
        if settings is None
        else settings
    )
    timings: dict[str, float] = {}
    notes: list[str] = []
    t0 = time.perf_counter()
    if fit is None:
        fit = fit_campaign(
            system, campaign, method="cmaes", seed=seed, quick=quick, progress=progress
        )
        timings["fit"] = time.perf_counter() - t0
    notes += base_fit_notes(system, fit)

    measured = _Measured.of(system, campaign, calibration_runs(campaign))
    runs, x, operating = measured.runs, measured.signals, measured.operating
    t_start, t_stop = measured.t_start, measured.t_stop

    t0 = time.perf_counter()
    draws = fit.posterior_draws()
    total = len(next(iter(draws.values())))
    pick = np.unique(np.linspace(0, total - 1, min(settings.predictive_draws, total)).round())
    fixed = {k: v for k, v in fit.point.items() if k not in fit.names}
    rows = [dict(fit.point)]
    if total > 1:
        rows += [{**fixed, **{n: float(draws[n][int(i)]) for n in fit.names}} for i in pick]
    sims, ok, sample_times = _simulate_rows(system, measured, rows)
    if not ok[0]:
        raise RuntimeError(
            "the base model failed to simulate the runs at the fit's point: (a) the fit is not "
            "of this system, (b) the records are longer than the solver's max_steps allow"
        )
    base_signals = sims[0]
    sims = sims[1:][ok[1:]] if total > 1 else sims[:1]
    sims = sims[np.resize(np.arange(len(sims)), settings.predictive_draws)]
    rng = np.random.default_rng(seed)
    noise = _noise_rms(x, measured.fs, t_start)
    predictive = sims + noise[None, None, :, None] * rng.standard_normal(sims.shape)
    band = _band(fit)
    profiles = None
    if catalogue.speed_profile is not None:
        profiles = np.asarray(
            catalogue.speed_profile(operating, np.arange(x.shape[-1]) / measured.fs), dtype=float
        )
    features = find_features(
        x,
        predictive,
        measured.fs,
        channels=measured.channels,
        t_start=t_start,
        t_stop=t_stop,
        speeds=operating,
        speed_profiles=profiles,
        within_run=False,
        order_segment_m=catalogue.order_segment_m,
        pairs=_pairs(catalogue),
        band=band,
        smooth_discrepancy_bins=SMOOTH_BINS,
    )
    ranking = rank_causes(features, catalogue)
    timings["features"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    setup = measured.setup(system, fit.point, base_signals, sample_times, band, features)
    recipes = {c.name: c.refit for c in catalogue.candidates}
    tracking = {c.name: tracks_speed(c.signature) for c in catalogue.candidates}
    plausible = [
        c
        for c in ranking.causes
        if c.name != NONE and c.score >= PLAUSIBLE_SCORE and recipes.get(c.name) is not None
    ][: settings.max_candidates]
    if ranking.verdict == NONE:
        plausible = []
    folds = held_out_folds(operating, settings.folds)
    if plausible and not folds:
        notes.append(
            f"{len(runs)} healthy runs: too few to fit on half and hold out the other half "
            "(need 4); no candidate could be confirmed"
        )
        plausible = []
    refitted: dict[str, Cause] = {}
    for rank, score in enumerate(plausible):
        try:
            proposals = recipes[score.name].propose(  # type: ignore[union-attr]
                score.parameters, band=band
            )
        except (KeyError, ValueError) as err:
            notes.append(f"{score.name}: its recipe proposed no extension ({err!r})")
            continue
        trials = []
        for k, proposal in enumerate(proposals):
            bases: dict[tuple[float, ...], np.ndarray] = {}
            try:
                fits, gain = _cross_validate(
                    setup,
                    proposal,
                    folds,
                    seed=seed + 101 * (rank + 1) + 7 * k,
                    max_evals=settings.refit_evals,
                    bases=bases,
                    tracking=tracking[score.name],
                    workers=settings.workers,
                )
            except (ValueError, RuntimeError) as err:
                notes.append(f"{score.name} ({proposal.label}): refit failed: {err}")
                continue
            trials.append((sum(f.train_lpd for f in fits), proposal, fits, gain, bases))
        if not trials:
            continue
        _, proposal, fits, gain, bases = max(trials, key=lambda t: t[0])
        held = {n: {"mean": m, "sd": sd} for n, (m, sd) in proposal.held.items()}
        # each fold's own value is kept: folds that disagree mark a refit to distrust
        by_fold = {n: [float(np.mean(f.values[n])) for f in fits] for n in proposal.free}
        parameters: dict[str, Any] = {
            n: {"mean": float(np.mean(v)), "sd": None, "folds": v} for n, v in by_fold.items()
        }
        recipe = recipes[score.name]
        extended_system = system.with_extensions(proposal.extension)
        # each fold's refit as the recipe reads it (a rail-carrying mode's installed peak)
        fold_values = [
            {
                **f.values,
                **recipe.derived(  # type: ignore[union-attr]
                    proposal, extended_system, {**setup.point, **f.values}
                ),
            }
            for f in fits
        ]
        explained, symptom = recipe.explains(  # type: ignore[union-attr]
            score.parameters,
            setup.spectra.freqs,
            setup.spectra.measured,
            setup.base_spectra,
            held_out_spectra(fits, folds),
            tuple(system.channels),
            refitted=fold_values,
        )
        confirmed_here = gain.decisive and explained
        if confirmed_here:
            every = np.arange(len(runs))
            final = refit_extension(
                setup,
                dataclasses.replace(
                    proposal,
                    start={**proposal.start, **{n: v["mean"] for n, v in parameters.items()}},
                ),
                every,
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
            derived = recipe.derived(  # type: ignore[union-attr]
                proposal, extended_system, {**setup.point, **final.values}
            )
            derived_sd = recipe.derived_sd(  # type: ignore[union-attr]
                proposal, final.values, final.sd
            )
            parameters.update({n: {"mean": v, "sd": derived_sd.get(n)} for n, v in derived.items()})
        # a value at an end of its search box is not an estimate: the all-runs fit's when
        # confirmed, else any fold's
        box = fits[0].box
        ends: dict[str, str] = {}
        for f in [final] if confirmed_here else fits:
            ends = {**f.at_bound(), **ends}
        for n in proposal.free:
            if n in box:
                parameters[n]["search_box"] = list(box[n])
            if n in ends:
                parameters[n]["at_bound"] = ends[n]
        parameters.update(held)
        for n, (value, sd) in proposal.measured.items():
            refit = parameters[n]
            parameters[n] = {"mean": value, "sd": sd, "refit": refit["mean"]}
            for key in ("folds", "search_box", "at_bound"):
                if key in refit:
                    parameters[n][key] = refit[key]
        words = (
            f"refit of {score.name} ({proposal.label}) on half of the runs, tested on the other "
            f"half both ways: {gain.describe()}"
        )
        if symptom:
            verb = "explains" if explained else "does not explain"
            words += f"; the refit {verb} its own feature: {symptom}"
        merged = {**dict(score.parameters), **parameters}
        refitted[score.name] = dataclasses.replace(
            _signature_cause(score),
            evidence=f"{score.evidence}. {words}",
            parameters=merged,
            gain=gain,
            confirmed=confirmed_here,
            label=proposal.label,
            proposal=proposal,
            alternatives=recipe.alternatives(merged),  # type: ignore[union-attr]
        )
    timings["refits"] = time.perf_counter() - t0

    confirmed = sorted(
        (c for c in refitted.values() if c.confirmed),
        key=lambda c: verdict_order(c.score, c.gain.elpd_difference),  # type: ignore[union-attr]
    )
    verdict = confirmed[0].name if confirmed else NONE
    if confirmed:
        notes += [
            f"{verdict}: {n} ended at the {value['at_bound']} end of its search box "
            f"[{value['search_box'][0]:.4g}, {value['search_box'][1]:.4g}]: the data would move "
            "it further, so it is not an estimate, nor are the parameters that trade off with it"
            for n, value in confirmed[0].parameters.items()
            if isinstance(value, dict) and value.get("at_bound")
        ]
    if confirmed and confirmed[0].alternatives:
        notes += [
            f"the verdict {verdict} could also be {alternative}"
            for alternative in confirmed[0].alternatives
        ]
    others = [refitted.get(s.name, _signature_cause(s)) for s in ranking.causes]
    causes = tuple(confirmed) + tuple(c for c in others if not c.confirmed)
    return Diagnosis(
        verdict=verdict,
        causes=causes,
        ranking=ranking,
        catalogue=catalogue,
        rule=RULE,
        runs=np.asarray(runs),
        notes=tuple(notes),
        timings=timings,
        fit=fit,
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
    measured = _Measured.of(system, campaign, calibration_runs(campaign))
    folds = held_out_folds(measured.operating, settings.folds)
    if not folds:
        raise ValueError(
            f"{len(measured.runs)} healthy calibration runs: need at least 4 to fit on half "
            "and test on the other half"
        )
    sims, ok, sample_times = _simulate_rows(system, measured, [dict(fit.point)])
    if not ok[0]:
        raise RuntimeError("the base model failed to simulate the runs at the fit's point")
    setup = measured.setup(system, fit.point, sims[0], sample_times, _band(fit), features)
    catalogue = system.catalogue if catalogue is None else catalogue
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
