"""The diagnosis of a campaign: residual features, ranked causes, refits, held-out gain, verdict.

:func:`diagnose_campaign` is generic over systems: it needs the system's catalogue (causes,
signatures and refit recipes) and the generic extension hooks of
:class:`~bayesdoor.systems.AbstractSystem`. Its steps live beside it: the runs
(:mod:`._measured`), the candidates and the verdict (:mod:`._candidates`), the held-out
judgement (:mod:`._held_out`), the result (:mod:`._diagnosis`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING

import numpy as np
import xarray as xr

from .._cluster import Pool, in_process
from ..features import welch_psd
from ..inference import FitResult, fit_campaign
from ._candidates import judge, propose, refit_candidates
from ._diagnosis import Diagnosis, DiagnosisSettings
from ._features import Features, FeatureSettings, RunMotion, find_features
from ._gain import RULE
from ._limits import LIMIT_POWER, CauseLimit, cause_sizes, detection_limits
from ._measured import Measured, _band, _simulate_rows, measure
from ._rank import Catalogue, rank_causes
from ._refit import SMOOTH_BINS, RefitSetup, box_ends

if TYPE_CHECKING:
    from ..systems import AbstractSystem


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
        motion=RunMotion(measured.t_start, measured.t_stop, speeds, profiles),
        settings=FeatureSettings(
            pairs=_pairs(catalogue),
            band=band,
            smooth_discrepancy_bins=SMOOTH_BINS,
            within_run=False,
            order_segment_m=catalogue.order_segment_m,
        ),
    )
    setup = measured.setup(system, fit.point, base_signals, sample_times, band, features, speeds)
    return Residuals(features, band, setup, tuple(notes))


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
    5. :func:`judge` (:class:`Judgement`): every confirmed cause is reported; the verdict
       wins most contests with the others on held-out runs (:class:`Contest`), ties by
       :func:`verdict_order`; else ``none`` (:data:`~bayesdoor.diagnose.RULE`).
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
    catalogue = _checked_catalogue(system, catalogue, seed)
    if settings is None:
        settings = DiagnosisSettings.quick() if quick else DiagnosisSettings()
    pool = in_process(settings.workers) if pool is None else pool
    timings: dict[str, float] = {}
    if fit is None:
        fit = _fitted(system, campaign, int(seed), quick, progress, timings)
    return _diagnosed(system, campaign, fit, catalogue, settings, int(seed), pool, timings)


def _fitted(
    system: AbstractSystem,
    campaign: xr.Dataset,
    seed: int,
    quick: bool,
    progress: bool,
    timings: dict[str, float],
) -> FitResult:
    """Step 1 of :func:`diagnose_campaign`: the base model's CMA-ES fit, timed."""
    with _timed(timings, "fit"):
        return fit_campaign(
            system, campaign, method="cmaes", seed=seed, quick=quick, progress=progress
        )


def _checked_catalogue(
    system: AbstractSystem, catalogue: Catalogue | None, seed: object
) -> Catalogue:
    """The catalogue to diagnose with (``system.catalogue`` by default), after checking it
    and the seed."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed={seed!r} must be an integer >= 0")
    catalogue = system.catalogue if catalogue is None else catalogue
    if not isinstance(catalogue, Catalogue):
        raise ValueError(
            f"{system.name} has no catalogue of discrepancy causes (system.catalogue is "
            f"{catalogue!r}): pass catalogue= (a bayesdoor.diagnose.Catalogue)"
        )
    return catalogue


def _diagnosed(
    system: AbstractSystem,
    campaign: xr.Dataset,
    fit: FitResult,
    catalogue: Catalogue,
    settings: DiagnosisSettings,
    seed: int,
    pool: Pool,
    timings: dict[str, float],
) -> Diagnosis:
    """Steps 2-6 of :func:`diagnose_campaign` under the fit, each step's time in ``timings``."""
    with _timed(timings, "features"):
        measured = measure(system, campaign)
        residuals = residual_map(system, fit, measured, catalogue, settings, seed)
        ranking = rank_causes(residuals.features, catalogue)
    with _timed(timings, "refits"):
        proposals = propose(ranking, measured, catalogue, residuals.band, settings, seed)
        refits = refit_candidates(proposals, residuals.setup, catalogue, settings, seed, pool)
        judgement = judge(ranking, refits)
    limits = Limits()
    if settings.limits:
        with _timed(timings, "limits"):
            limits = cause_limits(residuals.setup, catalogue, residuals.band, settings, seed, pool)
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
        contests=judgement.contests,
    )
