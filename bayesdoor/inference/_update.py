"""Model updating of a system on a measurement campaign: CMA-ES on J, then a posterior.

The pipeline of :func:`fit_campaign`:

1. the calibration runs of the campaign (``split == "calibration"`` when present, else every
   ``healthy`` run) become feature vectors (:class:`CalibrationData`), with each run's motion
   window clipped to the length of the simulated one, so both sides average the same stretch;
2. CMA-ES minimises the paper's objective J over the bounds of the parameters not held fixed,
   every integer parameter (a contact-law index) as an integer variable, each population
   simulated as one vmapped batch over all operating points; the integer parameters are then
   held at the optimum's values;
3. for ``nuts`` and ``emcee``, over the continuous parameters not held: a quadratic surrogate
   of the features is fitted in a box around the optimum (parameters the data cannot move
   span their whole range), its held-out error enters the likelihood, the sampling
   coordinates are whitened by a Laplace approximation, and the sampler starts at the
   optimum; the convergence gates are checked and a failure is reported loudly.
"""

from __future__ import annotations

import dataclasses
import json
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import arviz as az
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr
from numpyro.infer import Predictive

from .._cacheable import errors_as_nan
from .._types import Array, Bool, Float, Int
from ..features import motion_window as detect_motion_window
from ..features import objective_j, segment_weights
from ..io import atomic_write
from ..io import operating as campaign_operating
from ..systems import HEALTHY, AbstractSystem
from ._cmaes import CMAESHistory, CMAESResult, minimize_cmaes
from ._diagnostics import SamplingDiagnostics, diagnose_sampling
from ._features import FeatureSpec, run_features
from ._likelihood import (
    AbstractForward,
    CalibrationData,
    CorrelatedDiscrepancyNormal,
    DiscrepancyNormal,
    ForwardOutput,
    ModelError,
    band_correlation,
    log_likelihood,
    make_model,
)
from ._parameterisation import SamplingTransform
from ._posterior import load_posterior, record_system, save_posterior
from ._samplers import _NUTS, _Emcee, _Sampler
from ._surrogate import box_around, fit_surrogate, map_padded_chunks

Method = Literal["cmaes", "nuts", "emcee"]
METHODS: tuple[str, ...] = ("cmaes", "nuts", "emcee")
"""The values of :func:`fit_campaign`'s ``method``: the CMA-ES optimum alone, or a posterior
sampled with NUTS or emcee."""

#: smallest model-error scale (decades) used to start the sampler and for a CMA-ES point
_SIGMA_FLOOR = 0.01

#: a surrogate box face that is not a bound must lie this many posterior sds from the mean;
#: a moved box reaches at least _BOX_NEW_SD sds each side (the quadratic is fitted where the
#: posterior lives, and a Gaussian's mass beyond 4 sd is 6e-5)
_BOX_ROOM_SD = 4.0
_BOX_NEW_SD = 6.0


@dataclasses.dataclass(frozen=True)
class FitSettings:
    """Sizes of every stage of :func:`fit_campaign`.

    Attributes
    ----------
    max_motion_s
        Longest stretch of motion (s) that enters the features; ``None``: the whole motion.
    cmaes_max_evals, cmaes_restarts, cmaes_popsize, cmaes_sigma0
        CMA-ES budget, IPOP restarts, first population (``None``: pycma's default) and
        initial step (fraction of each range). A restart starts only while the budget left
        is at least what the previous run used (one cut off by the budget before it
        converges only costs time).
    cmaes_tolerance
        CMA-ES stops when its best J of the last iterations spans less than this fraction of
        J's standard error from the run-to-run scatter (pycma's
        ``tolfun`` and ``tolfunhist``): a finer optimum of J is below what the data resolve.
        A campaign without replicate runs takes the standard error from the Welch scatter
        alone (a lower bound, so a tighter stop), and says
        so in the fit's notes. ``None``: pycma's default tolerances (1e-11 and 1e-12), so
        the budget stops it.
    workers
        Threads that simulate at once: each CMA-ES population (and every later batch of
        the exact simulator) is split into this many vmapped chunks. XLA runs a vmapped
        solve on one core, so 2 uses both cores of a 2-core machine. The batch size moves
        the adaptive solver's round-off, so features change with it at the solver's
        tolerance (5e-5 decades between one batch of 12 and two of 6 on the demo).
    box_fraction
        Half-width of the surrogate's box around the optimum, as a fraction of each range.
    box_moves
        How often the box may move to the posterior mean and widen (surrogate refitted,
        posterior resampled) when a face of the box that is not a bound lies within 4
        posterior sds of a parameter's mean, or more than 5 % of its draws lie at such a
        face.
    insensitive
        A parameter whose move from its lower to its upper bound changes no feature by more
        than this many Welch standard deviations spans its whole range in the surrogate's box
        (the data cannot constrain it, so its posterior must be free to be its prior).
    train_per_term, n_test
        Surrogate training simulations per polynomial term, and held-out simulations.
    num_warmup, num_samples, num_chains, target_accept
        NUTS settings.
    chain_method
        How NUTS runs its chains (:func:`sample_nuts`): ``"vectorized"`` (one vmapped
        program, the fastest on a CPU) or ``"sequential"`` (one chain after another; a
        likelihood with a Cholesky per step, ``ModelError(correlation=...)``, deadlocked
        inside XLA with vectorised chains on the demo fit).
    emcee_walkers, emcee_steps, emcee_max_steps, emcee_burn, emcee_thin
        emcee settings (:func:`sample_emcee`): walkers per ensemble (``None``: twice the
        sampled dimension plus two, the fewest the stretch move needs; fewer is an error),
        steps of a fixed-length run (``None``: run until the kept steps reach 50
        autocorrelation times and the estimate has settled to 1 %, at most
        ``emcee_max_steps``), burn-in and thinning (``None``: half the smallest
        autocorrelation time, emcee's documented choice).
    predictive_draws
        Posterior draws kept in the ``posterior_predictive`` group.
    """

    max_motion_s: float | None = None
    cmaes_max_evals: int = 1500
    cmaes_restarts: int = 2
    cmaes_popsize: int | None = None
    cmaes_sigma0: float = 0.25
    cmaes_tolerance: float | None = 0.1
    workers: int = 2
    box_fraction: float = 0.25
    box_moves: int = 2
    insensitive: float = 0.5
    train_per_term: int = 7
    n_test: int = 64
    num_warmup: int = 500
    num_samples: int = 500
    num_chains: int = 4
    target_accept: float = 0.9
    chain_method: str = "vectorized"
    emcee_walkers: int | None = None
    emcee_steps: int | None = None
    emcee_max_steps: int = 40000
    emcee_burn: int = 1000
    emcee_thin: int | None = None
    predictive_draws: int = 400

    def __post_init__(self) -> None:
        if self.chain_method not in ("vectorized", "sequential"):
            raise ValueError(
                f"chain_method={self.chain_method!r}: use 'vectorized' or 'sequential'"
            )
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 1:
            raise ValueError(
                f"workers={self.workers!r} must be an integer >= 1 (threads simulating at once; "
                "2 for a 2-core machine)"
            )
        if self.cmaes_tolerance is not None and not self.cmaes_tolerance > 0:
            raise ValueError(
                f"cmaes_tolerance={self.cmaes_tolerance!r} must be positive (a fraction of J's "
                "standard error, e.g. 0.1) or None for pycma's default tolerances"
            )

    @classmethod
    def quick(cls) -> FitSettings:
        """Small sizes for tests and demos (minutes on a loaded 2-core CPU, not converged).

        1 s of motion per run; CMA-ES 120 evaluations, no restart; a surrogate on twice as
        many simulations as terms and 16 held-out ones; NUTS 2 chains x (300 + 1200), the
        fewest draws that passed the sampling gates on the demo campaign's fit (seeds 0-2;
        2 x (150 + 150) failed them on every seed), for a few seconds more on the surrogate;
        emcee 600 steps (200 burn-in, a fixed length) with the fewest walkers; 100 predictive
        draws.
        """
        return cls(
            max_motion_s=1.0,
            cmaes_max_evals=120,
            cmaes_restarts=0,
            train_per_term=2,
            n_test=16,
            num_warmup=300,
            num_samples=1200,
            num_chains=2,
            emcee_steps=600,
            emcee_burn=200,
            emcee_thin=1,
            predictive_draws=100,
        )


# ---------------------------------------------------------------------------------------------
# the campaign side


def calibration_runs(campaign: xr.Dataset, healthy: str = HEALTHY) -> Int[np.ndarray, " run"]:
    """Indices of the runs a model is updated on.

    The runs with ``split == "calibration"`` when the campaign has such runs, else every run;
    of those, the ones in the state ``healthy`` (the system's
    :attr:`~bayesdoor.systems.AbstractSystem.healthy`).

    Raises
    ------
    ValueError
        When no such run is healthy.
    """
    state = np.asarray(campaign["state"].values).astype(str)
    chosen = np.ones(state.shape, dtype=bool)
    if "split" in campaign.variables:
        split = np.asarray(campaign["split"].values).astype(str)
        if np.any(split == "calibration"):
            chosen = split == "calibration"
    runs = np.flatnonzero(chosen & (state == healthy))
    if runs.size == 0:
        labels, counts = np.unique(state[chosen], return_counts=True)
        found = ", ".join(f"{n} {s}" for s, n in zip(labels, counts, strict=True)) or "no runs"
        where = "calibration runs" if not chosen.all() else "runs"
        raise ValueError(
            f"the campaign has no {healthy} run to update the model on (its {where}: {found}): "
            "model updating needs measurements of the undamaged system; (a) label them "
            f"state={healthy!r}, (b) mark them split='calibration', (c) pass another campaign"
        )
    return runs


def campaign_data(
    system: AbstractSystem,
    campaign: xr.Dataset,
    runs: Sequence[int] | Int[np.ndarray, " run"],
    *,
    spec: FeatureSpec | None = None,
    max_motion_s: float | None = None,
) -> tuple[CalibrationData, float]:
    """The features of some runs of a campaign, and the record length to simulate them with.

    The simulated record holds the system's motion at every operating point of the runs
    (truncated to ``max_motion_s`` of motion); each measured window (``t_start``/``t_stop``
    of the campaign, else detected from the signals) is clipped to the length of the
    simulated window at its operating point, so that both average the same stretch.

    Parameters
    ----------
    system
        The system the campaign measured.
    campaign
        A campaign (docs/data.md); the system's per-run operating conditions are the
        operating points.
    runs
        The runs to use.
    spec
        The feature definition; ``None`` means the system's (``FeatureSpec.of(system)``).
    max_motion_s
        Longest stretch of motion (s) to use; ``None``: all of it.

    Returns
    -------
    data
        Features, Welch scatter and operating points of the runs.
    duration
        The simulated record length (s).

    Raises
    ------
    ValueError
        For a sampling rate or channels that differ from the system's, or no runs.
    """
    spec = FeatureSpec.of(system) if spec is None else spec
    runs = np.asarray(runs, dtype=int)
    if runs.size == 0:
        raise ValueError("runs is empty: pass the indices of at least one run")
    fs = float(campaign.attrs.get("sampling_rate_hz", np.nan))
    if fs != system.sampling_rate_hz:
        raise ValueError(
            f"the campaign's sampling_rate_hz={fs} differs from {system.name}'s "
            f"{system.sampling_rate_hz} Hz: resample the measurements to the model's rate"
        )
    channels = [str(c) for c in campaign["channel"].values]
    missing = [c for c in system.channels if c not in channels]
    if missing:
        raise ValueError(
            f"the campaign lacks the channels {missing} of {system.name} (it has {channels})"
        )
    selected = campaign.isel(run=runs)
    signals = np.asarray(
        selected["acceleration"].sel(channel=list(system.channels)).values, dtype=float
    )
    operating = campaign_operating(selected, system)
    if "t_start" in selected.variables and "t_stop" in selected.variables:
        t_start = np.asarray(selected["t_start"].values, dtype=float)
        t_stop = np.asarray(selected["t_stop"].values, dtype=float)
    else:
        t = np.arange(signals.shape[-1]) / fs
        windows = np.array([detect_motion_window(t, s) for s in signals])
        t_start, t_stop = windows[:, 0], windows[:, 1]
    unique, index = np.unique(operating, axis=0, return_inverse=True)
    index = index.reshape(-1)
    duration = float(system.record_duration(unique))
    if max_motion_s is not None:
        start, _ = system.motion_window(unique)
        duration = min(duration, float(np.max(start)) + float(max_motion_s))
    sim_start, sim_stop = system.motion_window(unique, duration=duration)
    length = (np.asarray(sim_stop) - np.asarray(sim_start))[index.reshape(-1)]
    t_stop = np.minimum(t_stop, t_start + length)
    data = CalibrationData.from_signals(
        jnp.asarray(signals),
        fs,
        jnp.asarray(operating),
        jnp.asarray(t_start),
        jnp.asarray(t_stop),
        spec,
    )
    return data, duration


def j_standard_error(data: CalibrationData) -> float | None:
    """The standard error of J (the mean over the runs) from the run-to-run scatter alone.

    For each run at an operating point measured ``k >= 2`` times, the residual against the
    mean of the other ``k - 1`` runs there, scaled by ``sqrt((k - 1) / k)`` to one run's
    scatter, is what a perfect model would leave on that run; its J (eq. 2) is a draw of
    J's run-to-run fluctuation. The standard deviation of these over the runs, over the
    square root of the number of runs, is the precision of the mean J the data support.
    Data only: no simulation. (On the demo campaign, 10 runs at three speeds, it gives
    0.017, against 0.014 from the spread of the runs' own J about their speed's mean at the
    CMA-ES optimum.)

    Parameters
    ----------
    data
        The calibration features.

    Returns
    -------
    se
        The standard error, or ``None`` when fewer than two runs have a replicate.
    """
    y = np.asarray(data.y)
    index = np.asarray(data.run_operating)
    residuals = []
    for i in range(len(y)):
        others = np.flatnonzero((index == index[i]) & (np.arange(len(y)) != i))
        if others.size:
            k = others.size + 1
            residuals.append((y[i] - y[others].mean(axis=0)) * np.sqrt((k - 1) / k))
    if len(residuals) < 2:
        return None
    scatter = np.asarray(objective_j(jnp.asarray(np.stack(residuals)), jnp.zeros_like(y[0])))
    return float(np.std(scatter, ddof=1) / np.sqrt(len(y)))


def welch_j_standard_error(data: CalibrationData, draws: int = 512, seed: int = 0) -> float:
    """The standard error of J (the mean over the runs) if the runs scattered only as the
    Welch estimator does: a lower bound on :func:`j_standard_error`, for campaigns without
    replicate runs.

    Each run's residual at a perfect model is drawn ``draws`` times as independent Gaussian
    noise of the run's Welch variance in every bin (``data.welch_variance``), and J (eq. 2)
    taken of each draw; the standard deviation of one run's J over the draws is its
    fluctuation, and the root of their summed variances over the number of runs is that of
    the mean J. Measured runs scatter more than the estimator alone (the rig's run-to-run
    variation, sensor noise): on the demo campaign it gives 0.0090 against 0.017 from the
    replicates. Data only, no simulation; deterministic for a given ``seed``.

    Parameters
    ----------
    data
        The calibration features.
    draws
        Noise draws per run (512: the standard error is known to about 3 %).
    seed
        Seeds the draws.

    Returns
    -------
    se
        The standard error, decades (J's units).

    Raises
    ------
    ValueError
        When ``draws`` is not an integer of at least 2.
    """
    if isinstance(draws, bool) or not isinstance(draws, int) or draws < 2:
        raise ValueError(f"draws={draws!r} must be an integer >= 2 (the sd of J over the draws)")
    y = np.asarray(data.y)
    sd = np.sqrt(np.asarray(data.welch_variance, dtype=np.float64))
    noise = np.random.default_rng(seed).standard_normal((draws, *y.shape)) * sd[:, None, None]
    j = np.asarray(objective_j(jnp.asarray(noise), jnp.zeros_like(y[0])))
    return float(np.sqrt(np.sum(np.var(j, axis=0, ddof=1))) / len(y))


# ---------------------------------------------------------------------------------------------
# the population simulator


#: candidates per vmapped simulation outside a fit (posterior predictive draws); a fit pads
#: every batch to a multiple of its first CMA-ES population, so one compilation serves it all
_CHUNK = 10

#: samples simulated past the end of the last Welch segment any run uses: the solver's last
#: step is clipped to the end of the record, so it must lie beyond every sample used (a step
#: is about 1 ms; 128 samples are 62.5 ms at 2048 Hz)
_HORIZON_MARGIN = 128


def simulation_horizon(
    system: AbstractSystem, data: CalibrationData, duration: float, spec: FeatureSpec
) -> float:
    """How long a record the features of ``data`` need simulated (s), at most ``duration``.

    The features average only the Welch segments that lie entirely inside a run's window (the
    system's motion window clipped to ``duration``), so the samples after the last such
    segment of any operating point never enter them. The horizon is the end of that segment
    plus :data:`_HORIZON_MARGIN` samples, so that the solver's last step, which is clipped to
    the end of the record, lies past every sample used and those come out as a full record
    gives them. On the demo campaign (0.3-0.5 m/s, 3.64 s records) it is 3.44 s.

    Parameters
    ----------
    system
        The simulated system.
    data
        The calibration features (their operating points).
    duration
        The record length the windows are clipped to (s).
    spec
        The feature definition (segment length and overlap).

    Returns
    -------
    horizon
        Seconds, a whole number of samples.
    """
    t_start, t_stop = system.motion_window(np.asarray(data.operating), duration=duration)
    fs = system.sampling_rate_hz
    n_time = round(duration * fs)
    used = np.asarray(
        segment_weights(
            n_time, fs, jnp.asarray(t_start), jnp.asarray(t_stop), spec.nperseg, spec.noverlap
        )
    ).any(axis=0)
    end = int(np.flatnonzero(used).max()) * spec.step + spec.nperseg if used.any() else n_time
    return min(n_time, end + _HORIZON_MARGIN) / fs


class _Population(eqx.Module):
    """Features of a batch of full parameter vectors at every operating point, simulated up
    to :func:`simulation_horizon`."""

    system: AbstractSystem
    operating: Float[Array, " op"]
    t_start: Float[Array, " op"]
    t_stop: Float[Array, " op"]
    horizon: float = eqx.field(static=True)
    spec: FeatureSpec

    @classmethod
    def build(
        cls, system: AbstractSystem, data: CalibrationData, duration: float, spec: FeatureSpec
    ) -> _Population:
        t_start, t_stop = system.motion_window(np.asarray(data.operating), duration=duration)
        horizon = simulation_horizon(system, data, duration, spec)
        # the simulations' features are traced without run-time checks (_simulate_chunk): a
        # window that holds no Welch segment is refused here, with the check's own words
        fs = system.sampling_rate_hz
        counts = np.asarray(
            segment_weights(
                round(horizon * fs),
                fs,
                jnp.asarray(t_start),
                jnp.asarray(t_stop),
                spec.nperseg,
                spec.noverlap,
            )
        ).sum(axis=-1)
        if np.any(counts < 1):
            bad = int(np.argmin(counts))
            raise ValueError(
                f"segment_weights sum to zero for operating point {bad}: no segment of "
                f"nperseg={spec.nperseg} lies inside its simulated motion window "
                f"[{float(np.ravel(t_start)[bad]):.3f}, {float(np.ravel(t_stop)[bad]):.3f}] s of "
                f"a {horizon:.3f} s record"
            )
        return cls(
            system,
            data.operating,
            jnp.asarray(t_start),
            jnp.asarray(t_stop),
            horizon,
            spec,
        )

    def __call__(
        self, x: Float[Array, "pop param"]
    ) -> tuple[Float[Array, "pop op channel band"], Bool[Array, " pop"]]:
        pop, n_op = x.shape[0], self.operating.shape[0]
        values = {p.name: jnp.repeat(x[:, i], n_op) for i, p in enumerate(self.system.parameters)}
        # every candidate at every operating point (a row for several conditions)
        reps = (pop,) + (1,) * (self.operating.ndim - 1)
        result = self.system.simulate_values(
            values,
            jnp.tile(self.operating, reps),
            state=self.system.healthy,
            duration=self.horizon,
            check=False,
        )
        features, _ = run_features(
            result.signals,
            self.system.sampling_rate_hz,
            jnp.tile(self.t_start, pop),
            jnp.tile(self.t_stop, pop),
            self.spec,
        )
        features = features.reshape(pop, n_op, *features.shape[1:])
        ok = jnp.all((result.status == 0).reshape(pop, n_op), axis=-1)
        return features, ok & jnp.all(jnp.isfinite(features), axis=(1, 2, 3))


@eqx.filter_jit
def _simulate_chunk(
    population: _Population, x: Float[Array, "pop param"]
) -> tuple[Float[Array, "pop op channel band"], Bool[Array, " pop"]]:
    # traced without host callbacks, so that the program enters the persistent cache: a
    # check that fails gives NaN features, which ``ok`` reports as a failed simulation (the
    # windows are checked when the population is built)
    with errors_as_nan():
        return population(x)


def _simulate(
    population: _Population,
    x: Float[np.ndarray, "pop param"],
    chunk: int = _CHUNK,
    workers: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Features and success of any number of full parameter vectors, in padded chunks.

    Each chunk of ``chunk`` candidates is one vmapped simulation (the last padded by
    repeating its last row; one compilation per chunk size); ``workers`` threads run chunks
    at once. XLA runs one vmapped solve on one core and releases the GIL meanwhile, so two
    threads use both cores of a 2-core machine. The first call of a chunk size should run
    with one worker: threads that all miss the compilation cache each compile.
    """
    features, ok = map_padded_chunks(
        lambda padded: _simulate_chunk(population, jnp.asarray(padded)),
        x,
        chunk,
        workers,
        first_alone=False,
    )
    return features, ok


class _PartialForward(AbstractForward):
    """The population simulator as a forward model of some parameters, the rest held.

    The held values (for example the contact-law index) are traced, not static, so a fit per
    held value reuses one compilation of the vmapped simulation.
    """

    population: _Population
    names: tuple[str, ...] = eqx.field(static=True)
    operating: Float[Array, " op"]
    index: Int[Array, " param"]
    base: Float[Array, " full"]

    @classmethod
    def build(
        cls,
        system: AbstractSystem,
        population: _Population,
        names: Sequence[str],
        held: dict[str, float],
    ) -> _PartialForward:
        order = [p.name for p in system.parameters]
        base = _full(system, np.zeros(len(names)), names, held)[0]
        return cls(
            population=population,
            names=tuple(names),
            operating=population.operating,
            index=jnp.asarray([order.index(n) for n in names]),
            base=jnp.asarray(base),
        )

    def __call__(self, theta: Float[Array, " param"]) -> ForwardOutput:
        features, ok = self.population(self.base.at[self.index].set(theta)[None])
        return ForwardOutput(features[0], jnp.zeros_like(features[0]), ok[0])


def _j(features: np.ndarray, ok: np.ndarray, data: CalibrationData) -> np.ndarray:
    """The paper's J of each candidate, averaged over the runs; ``inf`` for a failed one."""
    sim = features[:, np.asarray(data.run_operating)]
    j = np.asarray(objective_j(jnp.asarray(sim), data.y[None])).mean(axis=-1)
    return np.where(ok & np.isfinite(j), j, np.inf)


def _full(
    system: AbstractSystem, x: np.ndarray, names: Sequence[str], fixed: dict[str, float]
) -> np.ndarray:
    """Full parameter vectors (the system's order) from the columns ``names`` and ``fixed``."""
    x = np.atleast_2d(x)
    columns = {n: x[:, i] for i, n in enumerate(names)}
    return np.stack(
        [
            columns[p.name] if p.name in columns else np.full(len(x), fixed[p.name])
            for p in system.parameters
        ],
        axis=-1,
    )


# ---------------------------------------------------------------------------------------------
# the result


@dataclasses.dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit_campaign`.

    Attributes
    ----------
    method
        ``cmaes``, ``nuts`` or ``emcee``.
    held
        Every parameter held fixed, by name: those the fit was given (``fixed``) and the
        integer ones (the door's contact-law index ``I``) at the CMA-ES optimum's value;
        empty when every parameter was sampled or optimised.
    point
        Every parameter by name: the CMA-ES optimum (``cmaes``) or the posterior mean, with
        the held parameters at ``held``.
    j
        The paper's objective J at ``point`` (exact simulator), averaged over the runs.
    idata
        The posterior (``nuts``/``emcee``), with ``posterior_predictive``; ``None`` for
        ``cmaes``.
    diagnostics
        The sampling gates (``None`` for ``cmaes``).
    cmaes
        The CMA-ES run (optimum, history).
    feature_spec
        The features used.
    settings
        The stage sizes.
    names
        The sampled (continuous, not held) parameters, in order.
    sigma_point
        Model-error (discrepancy) scale at the CMA-ES optimum (decades), per operating point
        (in the order of the calibration runs' distinct operating points) and channel, or per
        channel (``ModelError(per_operating=False)``); a moment estimate from the residuals
        there.
    scatter_point
        Run scatter per channel at the CMA-ES optimum (Welch standard deviations; 1 for the
        independent model error), likewise.
    model_error
        The model-error prior and structure of the likelihood.
    bounds
        Lower and upper bounds of ``names``.
    surrogate_box
        The surrogate's training box (``None`` for ``cmaes``).
    surrogate_rms
        The surrogate's held-out RMS error over all features (decades), or ``None``.
    runs
        Indices (in the campaign) of the runs fitted.
    duration
        Simulated record length (s).
    notes
        Warnings raised during the fit (failed gates, a posterior cut by the surrogate box).
    timings
        Seconds spent per stage.
    seed
        The seed.
    system
        The fitted system's :meth:`~bayesdoor.systems.AbstractSystem.describe` (its
        extensions and their configuration); ``None`` for fits written before it was recorded.
    """

    method: str
    held: dict[str, float]
    point: dict[str, float]
    j: float
    idata: az.InferenceData | None
    diagnostics: SamplingDiagnostics | None
    cmaes: CMAESResult
    feature_spec: FeatureSpec
    settings: FitSettings
    names: tuple[str, ...]
    sigma_point: np.ndarray
    scatter_point: np.ndarray
    model_error: ModelError
    bounds: tuple[np.ndarray, np.ndarray]
    surrogate_box: tuple[np.ndarray, np.ndarray] | None
    surrogate_rms: float | None
    runs: np.ndarray
    duration: float
    notes: tuple[str, ...]
    timings: dict[str, float]
    seed: int
    system: dict[str, Any] | None = None

    def check_system(self, system: AbstractSystem, *, source: str = "the fit") -> None:
        """Refuse a fit of another system configuration (an extended system for a base one).

        Fits recorded without a description are compared by their parameter names.

        Raises
        ------
        ValueError
            In one line, naming both descriptions' extensions and the fix.
        """
        if self.system is None:
            if set(self.point) == set(system.parameter_names()):
                return
            recorded: Any = sorted(self.point)
            expected: Any = list(system.parameter_names())
        else:
            recorded, expected = _described(self.system), _described(system.describe())
            if recorded == expected:
                return
        raise ValueError(
            f"{source} was made for {system.name} {_extensions_text(recorded)}, not "
            f"{_extensions_text(expected)} as given: refit with this system, or use the fit "
            "only with the system it was made for"
        )

    def posterior_draws(self) -> dict[str, np.ndarray]:
        """Draws of every continuous parameter, chains flattened (``cmaes``: the point once)."""
        if self.idata is None:
            return {n: np.asarray([self.point[n]]) for n in self.names}
        post = self.idata["posterior"]
        return {n: np.asarray(post[n].values).reshape(-1) for n in self.names}

    def model_error_draws(self) -> np.ndarray | None:
        """Model-error scales per channel, (draw, channel), decades (``cmaes``: the point once).

        With scales per operating point, their root mean square over the operating points;
        with a part common to every operating point, that and the common scale in quadrature.
        """
        sigma = self.discrepancy_draws()
        sigma = np.sqrt(np.mean(sigma**2, axis=1)) if sigma.ndim == 3 else sigma
        tau = self.common_draws()
        return sigma if tau is None else np.sqrt(sigma**2 + tau**2)

    def common_draws(self) -> np.ndarray | None:
        """Scales of the discrepancy common to every operating point, (draw, channel), decades;
        ``None`` without one (``ModelError(common=False)``, or a CMA-ES point)."""
        if self.idata is None or "sigma_common" not in self.idata["posterior"]:
            return None
        tau = np.asarray(self.idata["posterior"]["sigma_common"].values)
        return tau.reshape(-1, tau.shape[-1])

    def discrepancy_draws(self) -> np.ndarray:
        """Discrepancy scales as fitted: (draw, op, channel) per operating point, else
        (draw, channel); decades (``cmaes``: the point once)."""
        if self.idata is None:
            return np.asarray(self.sigma_point)[None]
        post = self.idata["posterior"]
        name = "sigma_operating" if "sigma_operating" in post else "sigma_model"
        sigma = np.asarray(post[name].values)
        return sigma.reshape(-1, *sigma.shape[2:])

    def run_scatter_draws(self) -> np.ndarray:
        """Run scatter in Welch sds, (draw, channel) (``cmaes`` or independent: one row)."""
        if self.idata is None or "run_scatter" not in self.idata["posterior"]:
            return np.asarray(self.scatter_point)[None]
        rho = np.asarray(self.idata["posterior"]["run_scatter"].values)
        return rho.reshape(-1, rho.shape[-1])

    def to_json(self) -> dict[str, Any]:
        """Per parameter: point (or mean), sd and 90 % interval; diagnostics; J."""
        draws = self.posterior_draws()
        parameters: dict[str, Any] = {}
        for name, value in self.point.items():
            if name in draws and self.idata is not None:
                d = draws[name]
                q5, q95 = np.quantile(d, [0.05, 0.95])
                parameters[name] = {
                    "mean": float(np.mean(d)),
                    "sd": float(np.std(d)),
                    "q5": float(q5),
                    "q95": float(q95),
                }
            else:
                parameters[name] = {"point": float(value), "sd": None, "q5": None, "q95": None}
        sigma = self.model_error_draws()
        return {
            "method": self.method,
            "held": self.held,
            "j": self.j,
            "parameters": parameters,
            "model_error": None if sigma is None else np.mean(sigma, axis=0).tolist(),
            "run_scatter": np.mean(self.run_scatter_draws(), axis=0).tolist(),
            "diagnostics": None if self.diagnostics is None else self.diagnostics.to_json(),
            "cmaes": {
                "f_best": self.cmaes.f_best,
                "evaluations": self.cmaes.evaluations,
                "restarts": self.cmaes.restarts,
                "stop": list(self.cmaes.stop),
            },
            "surrogate_rms": self.surrogate_rms,
            "runs": self.runs.tolist(),
            "notes": list(self.notes),
            "timings": self.timings,
        }

    def save(self, folder: str | Path, *, force: bool = False) -> Path:
        """Write ``fit.json`` (everything but the posterior) and ``posterior.nc`` to a folder.

        Raises
        ------
        FileExistsError
            When the folder already holds a fit and ``force`` is false (nothing is written).
        """
        folder = Path(folder)
        target = folder / "fit.json"
        nc = folder / "posterior.nc"
        if not force and (target.exists() or nc.exists()):
            raise FileExistsError(
                f"{folder} already holds a fit ({target.name} or {nc.name}); pass force=True "
                "to overwrite it"
            )
        folder.mkdir(parents=True, exist_ok=True)
        if self.idata is not None:
            save_posterior(self.idata, nc, overwrite=True)
        h = self.cmaes.history
        record = {
            "method": self.method,
            "held": self.held,
            "point": self.point,
            "j": self.j,
            "feature_spec": {
                f: getattr(self.feature_spec, f)
                for f in ("f_low", "f_high", "band_width", "nperseg", "noverlap", "window")
            },
            "settings": dataclasses.asdict(self.settings),
            "names": list(self.names),
            "sigma_point": np.asarray(self.sigma_point).tolist(),
            "scatter_point": np.asarray(self.scatter_point).tolist(),
            "model_error": {
                f: getattr(self.model_error, f)
                for f in (
                    "scale",
                    "slope",
                    "slope_scale",
                    "shared",
                    "per_operating",
                    "scatter_scale",
                    "correlation",
                    "infer_correlation",
                    "correlation_scale",
                    "common",
                )
            },
            "bounds": [np.asarray(b).tolist() for b in self.bounds],
            "surrogate_box": None
            if self.surrogate_box is None
            else [np.asarray(b).tolist() for b in self.surrogate_box],
            "surrogate_rms": self.surrogate_rms,
            "runs": self.runs.tolist(),
            "duration": self.duration,
            "notes": list(self.notes),
            "timings": self.timings,
            "seed": self.seed,
            "system": self.system,
            "diagnostics": None if self.diagnostics is None else self.diagnostics.to_json(),
            "cmaes": {
                "x_best": self.cmaes.x_best.tolist(),
                "f_best": self.cmaes.f_best,
                "evaluations": self.cmaes.evaluations,
                "restarts": self.cmaes.restarts,
                "failed": self.cmaes.failed,
                "stop": list(self.cmaes.stop),
                "seed": self.cmaes.seed,
                "history": {
                    f.name: np.asarray(getattr(h, f.name)).tolist() for f in dataclasses.fields(h)
                },
            },
        }
        text = json.dumps(record, indent=1, default=_json_default) + "\n"
        atomic_write(target, lambda tmp: tmp.write_text(text), overwrite=True)
        return folder

    @classmethod
    def load(cls, folder: str | Path) -> FitResult:
        """Read a fit written by :meth:`save`.

        Fits written before ``held`` recorded the one integer parameter's value as ``law``;
        that parameter is the one of ``point`` that ``names`` (the sampled ones) lacks.

        Raises
        ------
        FileNotFoundError
            When the folder holds no ``fit.json`` (or a sampled fit lacks ``posterior.nc``).
        ValueError
            For an old record whose ``law`` cannot be told to which parameter it belongs.
        """
        folder = Path(folder)
        target = folder / "fit.json"
        if not target.is_file():
            raise FileNotFoundError(f"{target} not found: pass a folder written by fit.save")
        r = json.loads(target.read_text())
        c = r["cmaes"]
        history = CMAESHistory(
            **{
                k: np.asarray(v, dtype=float if k in ("best_f", "median_f", "sigma") else int)
                for k, v in c["history"].items()
            }
        )
        cmaes = CMAESResult(
            x_best=np.asarray(c["x_best"], dtype=float),
            f_best=_float(c["f_best"]),
            evaluations=c["evaluations"],
            restarts=c["restarts"],
            failed=c["failed"],
            stop=tuple(c["stop"]),
            history=history,
            seed=c["seed"],
        )
        diagnostics = None
        if r["diagnostics"] is not None:
            d = dict(r["diagnostics"])
            for k in ("rhat_max", "ess_bulk_min", "ess_tail_min"):
                d[k] = _float(d[k])
            d["ebfmi"] = None if d["ebfmi"] is None else tuple(_float(e) for e in d["ebfmi"])
            d["messages"] = tuple(d["messages"])
            diagnostics = SamplingDiagnostics(**d)
        return cls(
            method=r["method"],
            held=_held_of(r, target),
            point={k: float(v) for k, v in r["point"].items()},
            j=_float(r["j"]),
            idata=None if r["method"] == "cmaes" else load_posterior(folder / "posterior.nc"),
            diagnostics=diagnostics,
            cmaes=cmaes,
            feature_spec=FeatureSpec(**r["feature_spec"]),
            settings=FitSettings(**r["settings"]),
            names=tuple(r["names"]),
            sigma_point=np.asarray(r["sigma_point"], dtype=float),
            scatter_point=np.asarray(
                r.get("scatter_point", np.ones(len(r["sigma_point"]))), dtype=float
            ),
            # fits written before the shared discrepancy existed had the independent form
            model_error=ModelError(**r.get("model_error", {"shared": False})),
            bounds=tuple(np.asarray(b, dtype=float) for b in r["bounds"]),  # type: ignore[arg-type]
            surrogate_box=None
            if r["surrogate_box"] is None
            else tuple(np.asarray(b, dtype=float) for b in r["surrogate_box"]),  # type: ignore[arg-type]
            surrogate_rms=r["surrogate_rms"],
            runs=np.asarray(r["runs"], dtype=int),
            duration=float(r["duration"]),
            notes=tuple(r["notes"]),
            timings=dict(r["timings"]),
            seed=int(r["seed"]),
            system=r.get("system"),
        )


def _held_of(record: dict[str, Any], target: Path) -> dict[str, float]:
    """The held parameters of a ``fit.json`` record; of an old one (``law`` instead of
    ``held``), the parameter of ``point`` that ``names`` lacks at the value ``law``."""
    if "held" in record:
        return {str(k): float(v) for k, v in record["held"].items()}
    law = record.get("law")
    held = {str(k): float(v) for k, v in record["point"].items() if k not in record["names"]}
    if law is None and not held:
        return {}
    if law is not None and len(held) == 1 and next(iter(held.values())) == float(law):
        return held
    raise ValueError(
        f"{target} is an old fit record (law={law!r}, no 'held') whose held parameter cannot be "
        f"told from its point and names (parameters not sampled: {sorted(held) or 'none'}): "
        "refit it"
    )


def _described(description: dict[str, Any]) -> Any:
    """A description as plain JSON values (tuples as lists), for comparison."""
    return json.loads(json.dumps(description, sort_keys=True, default=_json_default))


def _extensions_text(described: Any) -> str:
    """The extensions (and held values) of a description, or its parameter names, in words."""
    if not isinstance(described, dict):
        return f"with the parameters {described}"
    parts = [
        f"{e['name']}({', '.join(f'{k}={v!r}' for k, v in e.get('config', {}).items())})"
        for e in described.get("extensions", [])
    ]
    text = f"with extensions [{', '.join(parts)}]" if parts else "without extensions"
    held = described.get("held")
    return f"{text} held at {held}" if held else text


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot write {type(value).__name__} as JSON")


def _float(value: float | None) -> float:
    return float("nan") if value is None else float(value)


# ---------------------------------------------------------------------------------------------
# the fit


def _held_parameters(system: AbstractSystem, fixed: Mapping[str, float] | None) -> dict[str, float]:
    """The values ``fixed`` holds, checked against the system's parameters (in their order).

    Raises
    ------
    ValueError
        Naming the unknown names, or the parameter whose value is not a number, lies outside
        its bounds or is not integral for an integer parameter.
    """
    if fixed is None:
        return {}
    specs = {p.name: p for p in system.parameters}
    unknown = [str(n) for n in fixed if n not in specs]
    if unknown:
        raise ValueError(
            f"fixed names {unknown}, which are not parameters of {system.name}: use some of "
            f"{list(specs)}"
        )
    held = {}
    for name, spec in specs.items():
        if name not in fixed:
            continue
        value = fixed[name]
        try:
            if isinstance(value, bool | str):
                raise TypeError
            number = float(value)
        except (TypeError, ValueError):
            raise ValueError(
                f"fixed[{name!r}]={value!r} must be a number in [{spec.lower:g}, "
                f"{spec.upper:g}] ({spec.description})"
            ) from None
        spec.check(number)
        held[name] = number
    return held


def _box_room(
    draws: Float[np.ndarray, "sample param"],
    box: tuple[np.ndarray, np.ndarray],
    bounds: tuple[np.ndarray, np.ndarray],
) -> np.ndarray:
    """Per parameter: posterior sds from the mean to the nearer box face that is not a bound."""
    mean, sd = draws.mean(axis=0), np.maximum(draws.std(axis=0), 1e-300)
    lo, hi = np.asarray(box[0]), np.asarray(box[1])
    width = np.asarray(bounds[1]) - np.asarray(bounds[0])
    below = np.where(lo > np.asarray(bounds[0]) + 1e-12 * width, (mean - lo) / sd, np.inf)
    above = np.where(hi < np.asarray(bounds[1]) - 1e-12 * width, (hi - mean) / sd, np.inf)
    return np.minimum(below, above)


def _point_error(
    residual: Float[np.ndarray, "run channel band"],
    data: CalibrationData,
    error: ModelError,
) -> tuple[np.ndarray, np.ndarray]:
    """The discrepancy scales and the run scatter the residuals at a point call for.

    Moment estimates. Shared: the run scatter (in Welch sds, per channel) from the spread of
    the runs about their operating point's mean (1 without replicate runs), the discrepancy
    (per operating point and channel, or per channel) from the operating points' mean
    residuals less the part of their variance the scatter explains. Independent: the excess
    of the mean squared residual over the Welch variance, scatter 1. The discrepancy scale is
    floored at ``_SIGMA_FLOOR``.
    """
    welch = np.asarray(data.welch_variance)
    index = np.asarray(data.run_operating)
    n_op = data.operating.shape[0]
    rho = np.ones(residual.shape[1])
    if not error.shared:
        excess = np.mean(residual**2, axis=(0, 2)) - np.mean(welch)
        return np.sqrt(np.maximum(excess, _SIGMA_FLOOR**2)), rho
    counts = np.bincount(index, minlength=n_op)
    means = _operating_means(residual, data)
    spread = residual - means[index]
    replicated = counts[index] > 1
    if replicated.any():
        dof = np.sum(1.0 - 1.0 / counts[index][replicated])
        ratio = (spread[replicated] ** 2 / welch[replicated, None, None]).sum(axis=(0, 2))
        rho = np.sqrt(np.maximum(ratio / (dof * residual.shape[2]), _SIGMA_FLOOR**2))
    scatter = rho[None, :] ** 2 * np.array([welch[index == o].mean() for o in range(n_op)])[:, None]
    excess = np.mean(means**2, axis=2) - scatter / counts[:, None]
    if not error.per_operating:
        excess = excess.mean(axis=0)
    return np.sqrt(np.maximum(excess, _SIGMA_FLOOR**2)), rho


def _operating_means(
    residual: Float[np.ndarray, "run channel band"], data: CalibrationData
) -> Float[np.ndarray, "op channel band"]:
    """The mean residual of the runs at each operating point."""
    index = np.asarray(data.run_operating)
    return np.stack([residual[index == o].mean(axis=0) for o in range(data.operating.shape[0])])


def _common_point(
    residual: Float[np.ndarray, "run channel band"], data: CalibrationData
) -> np.ndarray:
    """A start for the common discrepancy's scale per channel: the root mean square over the
    bands of the operating points' mean residuals averaged over the operating points (what
    every speed misses alike), floored at ``_SIGMA_FLOOR``."""
    means = _operating_means(residual, data)
    return np.maximum(np.sqrt(np.mean(means.mean(axis=0) ** 2, axis=-1)), _SIGMA_FLOOR)


def _start_point(
    x0: dict[str, float] | None,
    search: Sequence[str],
    specs: dict[str, Any],
    lower: np.ndarray,
    upper: np.ndarray,
) -> np.ndarray:
    """CMA-ES's start: ``x0``'s values of the searched parameters, else mid-range."""
    start = 0.5 * (lower + upper)
    if x0 is None:
        return start
    unknown = sorted(set(x0) - set(specs))
    if unknown:
        raise ValueError(
            f"x0 names {unknown}, which are not parameters of the system: use some of {list(specs)}"
        )
    outside = {
        n: v for n, v in x0.items() if n in search and not specs[n].lower <= v <= specs[n].upper
    }
    if outside:
        raise ValueError(
            f"x0 holds {outside}, outside the bounds "
            f"{ {n: (specs[n].lower, specs[n].upper) for n in outside} }: clip it to them"
        )
    for i, n in enumerate(search):
        if n in x0:
            start[i] = float(x0[n])
    return start


def _sigma_site(error: ModelError) -> str:
    """The sampled site of the discrepancy scales."""
    return "sigma_operating" if error.shared and error.per_operating else "sigma_model"


def fit_campaign(
    system: AbstractSystem,
    campaign: xr.Dataset,
    *,
    method: Method = "cmaes",
    fixed: Mapping[str, float] | None = None,
    seed: int = 0,
    quick: bool = False,
    progress: bool = True,
    settings: FitSettings | None = None,
    spec: FeatureSpec | None = None,
    error: ModelError | None = None,
    x0: dict[str, float] | None = None,
) -> FitResult:
    """Update a system's parameters on the healthy calibration runs of a campaign.

    The steps: the campaign's calibration features; CMA-ES on J (:func:`_optimise`); for
    ``nuts`` and ``emcee``, a surrogate in a box around the optimum and the posterior sampled
    on it (:func:`_sample_posterior`, the box moved when it cuts the posterior); the gates
    and the predictive draws (:func:`_summarise`).

    Parameters
    ----------
    system
        The simulated system.
    campaign
        The measurements (docs/data.md): runs with ``split == "calibration"`` when
        present, else every run of the system's healthy state, are fitted.
    method
        ``cmaes`` (the optimum of J only), ``nuts`` or ``emcee`` (a posterior on a surrogate
        of the simulator, started at the CMA-ES optimum).
    fixed
        Parameters held at these values by name (for example ``{"I": 3}``, the door's
        contact-law index): they are neither searched nor sampled. Every integer parameter
        not in it is searched by CMA-ES as an integer variable and then held at the
        optimum's value, so the posterior is conditional on it; a continuous one in it leaves
        the search and the posterior. ``None``: nothing given.
    seed
        Seeds CMA-ES (``seed + 1``, pycma needs a positive seed), the surrogate design and
        the sampler.
    quick
        Use :meth:`FitSettings.quick` (small sizes for tests and demos).
    progress
        Show progress bars.
    settings
        The stage sizes (overrides ``quick``).
    spec
        The feature definition; ``None`` means the system's (``FeatureSpec.of(system)``).
    error
        The model-error prior; ``None`` means ``ModelError()``.
    x0
        CMA-ES start point by parameter name (a warm start, e.g. another fit's ``point``,
        with a smaller ``settings.cmaes_sigma0``); a searched parameter it lacks starts in
        the middle of its range, and one in ``fixed`` is ignored. ``None``: the middle of
        every range.

    Returns
    -------
    result
        The fit: point, J, posterior, diagnostics, CMA-ES history.

    Raises
    ------
    ValueError
        For an unknown method or ``seed``; a ``fixed`` with an unknown name, a value outside
        its bounds or a non-integral value of an integer parameter, or one that leaves nothing
        to search (or, for ``nuts``/``emcee``, nothing continuous to sample); an ``x0`` with
        an unknown name or a value outside its bounds; or a campaign without a usable healthy
        run (see :func:`calibration_runs`).
    RuntimeError
        When every CMA-ES candidate failed to simulate.

    References
    ----------
    The objective (eq. 2) and parameter bounds (Table 2) of "Real-time condition monitoring
    of mechanical systems using CNNs trained by multibody simulations", X ECCOMAS Thematic
    Conference on Smart Structures and Materials (SMART 2023), 2023; ``docs/inference.md``.
    """
    if method not in METHODS:
        raise ValueError(f"method={method!r}: use one of {', '.join(METHODS)}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed={seed!r} must be an integer >= 0")
    settings = (FitSettings.quick() if quick else FitSettings()) if settings is None else settings
    spec = FeatureSpec.of(system) if spec is None else spec
    error = ModelError() if error is None else error
    search = _SearchSpace.of(system, fixed, method)
    t0 = time.perf_counter()
    runs = calibration_runs(campaign, system.healthy)
    data, duration = campaign_data(
        system, campaign, runs, spec=spec, max_motion_s=settings.max_motion_s
    )
    timings = {"features": time.perf_counter() - t0}
    population = _Population.build(system, data, duration, spec)

    optimum = _optimise(search, population, data, settings, x0=x0, seed=seed, progress=progress)
    timings["cmaes"] = optimum.seconds
    notes = list(optimum.notes)
    described = system.describe()
    sigma_point, scatter_point = _point_error(optimum.residual, data, error)
    common = dict(
        held=optimum.held,
        cmaes=optimum.cmaes,
        feature_spec=spec,
        settings=settings,
        names=search.free,
        sigma_point=sigma_point,
        scatter_point=scatter_point,
        model_error=error,
        bounds=search.bounds(),
        runs=runs,
        duration=duration,
        seed=seed,
        system=described,
    )
    if method == "cmaes":
        return FitResult(
            method=method,
            point=optimum.point,
            j=float(optimum.cmaes.f_best),
            idata=None,
            diagnostics=None,
            surrogate_box=None,
            surrogate_rms=None,
            notes=tuple(notes),
            timings=timings,
            **common,  # type: ignore[arg-type]
        )

    key_sur, key_sample, key_pred = jax.random.split(jax.random.key(seed), 3)
    start = _ErrorStart.at_point(sigma_point, scatter_point, optimum.residual, data, error)
    posterior = _sample_posterior(
        search,
        population,
        data,
        optimum,
        start,
        _SAMPLERS[method](settings),
        error,
        settings,
        keys=(key_sur, key_sample),
        progress=progress,
    )
    timings.update(posterior.timings)
    notes.extend(posterior.notes)
    summary = _summarise(posterior, search, population, data, optimum, settings, key_pred)
    notes.extend(summary.notes)
    record_system(posterior.idata, described)
    return FitResult(
        method=method,
        point=summary.point,
        j=summary.j,
        idata=posterior.idata,
        diagnostics=summary.diagnostics,
        surrogate_box=posterior.box,
        surrogate_rms=posterior.surrogate_rms,
        notes=tuple(notes),
        timings=timings,
        **common,  # type: ignore[arg-type]
    )


# ---------------------------------------------------------------------------------------------
# the steps of fit_campaign


@dataclasses.dataclass(frozen=True)
class _SearchSpace:
    """The parameters of a fit: those held by the caller, the continuous ones (searched, then
    sampled) and the integer ones (searched, then held at the optimum)."""

    system: AbstractSystem
    given: dict[str, float]
    free: tuple[str, ...]
    integer: tuple[str, ...]

    @classmethod
    def of(
        cls, system: AbstractSystem, fixed: Mapping[str, float] | None, method: str
    ) -> _SearchSpace:
        """The search of ``system`` with ``fixed`` held, for a fit by ``method``.

        Raises
        ------
        ValueError
            When ``fixed`` is invalid (:func:`_held_parameters`), holds every parameter, or
            holds every continuous one when a posterior is to be sampled.
        """
        given = _held_parameters(system, fixed)
        specs = {p.name: p for p in system.parameters}
        free = tuple(p.name for p in system.parameters if not p.integer and p.name not in given)
        integer = tuple(p.name for p in system.parameters if p.integer and p.name not in given)
        if not free + integer:
            raise ValueError(
                f"fixed holds every parameter of {system.name} ({', '.join(given)}): nothing "
                "is left to fit; leave at least one out"
            )
        if method != "cmaes" and not free:
            raise ValueError(
                f"method={method!r} samples the continuous parameters, but fixed holds all "
                f"of them ({', '.join(n for n in given if not specs[n].integer)}): leave one "
                "out, or use method='cmaes'"
            )
        return cls(system, given, free, integer)

    @property
    def names(self) -> tuple[str, ...]:
        """The search vector: the continuous parameters, then the integer ones."""
        return (*self.free, *self.integer)

    def bounds(self, names: Sequence[str] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of ``names`` (``None``: the continuous parameters)."""
        specs = {p.name: p for p in self.system.parameters}
        names = self.free if names is None else names
        return np.array([specs[n].lower for n in names]), np.array([specs[n].upper for n in names])


@dataclasses.dataclass(frozen=True)
class _Optimum:
    """CMA-ES's optimum of J: the run, the parameters held from now on (given and integer),
    the continuous optimum, every parameter's value, and the residuals there."""

    cmaes: CMAESResult
    held: dict[str, float]
    theta: Float[np.ndarray, " free"]
    point: dict[str, float]
    residual: Float[np.ndarray, "run channel band"]
    chunk: int
    notes: tuple[str, ...]
    seconds: float


def _cmaes_tolerance(data: CalibrationData, settings: FitSettings) -> tuple[float | None, str]:
    """CMA-ES's tolerance on J (``settings.cmaes_tolerance`` times J's standard error) and a
    note when the standard error comes from the Welch scatter alone."""
    if settings.cmaes_tolerance is None:
        return None, ""
    se = j_standard_error(data)
    note = ""
    if se is None:
        se = welch_j_standard_error(data)
        note = (
            f"no replicate runs: CMA-ES stops at {settings.cmaes_tolerance:g} x J's standard "
            f"error from the Welch scatter alone ({se:.2g}, a lower bound)"
        )
    return settings.cmaes_tolerance * se, note


def _optimise(
    search: _SearchSpace,
    population: _Population,
    data: CalibrationData,
    settings: FitSettings,
    *,
    x0: dict[str, float] | None,
    seed: int,
    progress: bool,
) -> _Optimum:
    """CMA-ES on J over the search, each population one vmapped batch per worker.

    Raises
    ------
    ValueError
        For an ``x0`` with an unknown name or a value outside its bounds.
    RuntimeError
        When every candidate failed to simulate.
    """
    system, names = search.system, search.names
    lower, upper = search.bounds(names)
    compiled: set[int] = set()

    def batch(x: np.ndarray) -> np.ndarray:
        """J of a population, split into one chunk per worker (the first call of a size
        compiles on one thread)."""
        chunk = -(-len(x) // settings.workers)
        workers = settings.workers if chunk in compiled else 1
        compiled.add(chunk)
        full = _full(system, x, names, search.given)
        return _j(*_simulate(population, full, chunk, workers), data)

    integers = list(range(len(search.free), len(names)))
    specs = {p.name: p for p in system.parameters}
    start = _start_point(x0, names, specs, lower, upper)
    start[integers] = np.round(start[integers])
    tolerance, note = _cmaes_tolerance(data, settings)
    t0 = time.perf_counter()
    cmaes = minimize_cmaes(
        batch,
        start,
        lower=lower,
        upper=upper,
        seed=seed + 1,
        sigma0=settings.cmaes_sigma0,
        integer_variables=integers,
        max_evals=settings.cmaes_max_evals,
        restarts=settings.cmaes_restarts,
        popsize=settings.cmaes_popsize,
        options=None if tolerance is None else {"tolfun": tolerance, "tolfunhist": tolerance},
        affordable_restarts=True,
        progress=progress,
    )
    seconds = time.perf_counter() - t0
    chunk = -(-int(cmaes.history.popsize[0]) // settings.workers)
    if not cmaes.success:
        raise RuntimeError(
            f"every one of {cmaes.evaluations} CMA-ES candidates failed to simulate: (a) the "
            "bounds reach where the solver breaks down, (b) the record is too long for the "
            "solver's max_steps"
        )
    optimum = dict(zip(names, (float(v) for v in cmaes.x_best), strict=True))
    found = {n: float(round(optimum.pop(n))) for n in search.integer}
    values = {**search.given, **found}
    held = {p.name: values[p.name] for p in system.parameters if p.name not in search.free}
    theta = np.array([optimum[n] for n in search.free])
    sim, _ = _simulate(population, _full(system, theta, search.free, held), chunk)
    residual = np.asarray(data.y) - sim[0][np.asarray(data.run_operating)]
    return _Optimum(
        cmaes=cmaes,
        held=held,
        theta=theta,
        point={**optimum, **held},
        residual=residual,
        chunk=chunk,
        notes=(note,) if note else (),
        seconds=seconds,
    )


@dataclasses.dataclass(frozen=True)
class _ErrorStart:
    """Start values of the model-error sites: the discrepancy scales, the run scatter, the
    correlation length and the common discrepancy's scales (``None`` without one)."""

    sigma: Array
    rho: Array
    length: float | None
    tau: Array | None

    @classmethod
    def at_point(
        cls,
        sigma_point: np.ndarray,
        scatter_point: np.ndarray,
        residual: np.ndarray,
        data: CalibrationData,
        error: ModelError,
    ) -> _ErrorStart:
        """The moment estimates at the CMA-ES optimum."""
        tau = jnp.asarray(_common_point(residual, data)) if error.common else None
        return cls(
            jnp.asarray(sigma_point), jnp.asarray(scatter_point), error.correlation_length(), tau
        )

    def moved(self, posterior: xr.Dataset, error: ModelError) -> _ErrorStart:
        """The posterior means of the sampled model-error sites (the others kept)."""

        def mean(name: str, trailing: int) -> Array:
            draws = np.asarray(posterior[name].values)
            return jnp.asarray(draws.reshape(-1, *draws.shape[2:][-trailing:]).mean(axis=0))

        sigma = np.asarray(posterior[_sigma_site(error)].values)
        return _ErrorStart(
            sigma=jnp.asarray(sigma.reshape(-1, *sigma.shape[2:]).mean(axis=0)),
            rho=mean("run_scatter", 1) if error.shared else self.rho,
            length=(
                float(np.mean(posterior["discrepancy_length"].values))
                if error.infer_correlation
                else self.length
            ),
            tau=mean("sigma_common", 1) if error.common else self.tau,
        )

    def values(self, error: ModelError) -> dict[str, Any]:
        """The start values by sampled site (the sampling coordinate ``z`` aside)."""
        init: dict[str, Any] = {_sigma_site(error): self.sigma}
        if error.shared:
            init["run_scatter"] = self.rho
        if error.infer_correlation:
            init["discrepancy_length"] = jnp.asarray(self.length)
        if self.tau is not None:
            init["sigma_common"] = self.tau
        return init


def _box_fractions(
    search: _SearchSpace,
    population: _Population,
    data: CalibrationData,
    optimum: _Optimum,
    settings: FitSettings,
) -> Array:
    """The surrogate box's half-width per parameter, as a fraction of its range: the whole
    range for a parameter whose move across its bounds (the others at the optimum) changes no
    feature by ``settings.insensitive`` Welch sds, else ``settings.box_fraction``."""
    d, (lower, upper) = len(search.free), search.bounds()
    ends = np.repeat(optimum.theta[None], 2 * d, axis=0)
    ends[2 * np.arange(d), np.arange(d)] = lower
    ends[2 * np.arange(d) + 1, np.arange(d)] = upper
    full = _full(search.system, ends, search.free, optimum.held)
    end_features, _ = _simulate(population, full, optimum.chunk, settings.workers)
    reach = np.max(np.abs(end_features[0::2] - end_features[1::2]), axis=(1, 2, 3))
    welch_sd = float(np.sqrt(np.median(np.asarray(data.welch_variance))))
    loose = reach < settings.insensitive * welch_sd
    return jnp.asarray(np.where(loose, 1.0, settings.box_fraction))


def _surrogate_in_box(
    forward: _PartialForward,
    centre: np.ndarray,
    fractions: Array,
    bounds: tuple[np.ndarray, np.ndarray],
    settings: FitSettings,
    key: jax.Array,
):
    """The box around ``centre`` and the quadratic surrogate fitted in it."""
    d = len(centre)
    n_terms = 1 + d + d * (d + 1) // 2
    box = box_around(jnp.asarray(centre), jnp.asarray(bounds[0]), jnp.asarray(bounds[1]), fractions)
    surrogate = fit_surrogate(
        forward,
        jnp.asarray(box[0]),
        jnp.asarray(box[1]),
        key=key,
        n_train=settings.train_per_term * n_terms,
        n_test=settings.n_test,
        workers=settings.workers,
    )
    return box, surrogate


def _whitened_model(
    names: tuple[str, ...],
    data: CalibrationData,
    surrogate,
    box,
    centre: np.ndarray,
    start: _ErrorStart,
    error: ModelError,
) -> tuple[Any, dict[str, Any], str | None]:
    """The numpyro model on the surrogate in Laplace-whitened box coordinates, its start
    values (``centre`` moved 2 % of the box inside it), and a note when the whitening fails
    (then the coordinates are the plain logits of the box)."""
    inside = box[0] + np.clip((centre - box[0]) / (box[1] - box[0]), 0.02, 0.98) * (box[1] - box[0])
    transform = SamplingTransform.box(names, box[0].tolist(), box[1].tolist())

    def density(theta):
        return log_likelihood(
            theta,
            start.sigma,
            data,
            surrogate,
            run_scatter=start.rho,
            shared=error.shared,
            correlation_length=start.length,
            common=start.tau,
        )

    note = None
    try:
        transform = transform.whitened_at(density, jnp.asarray(inside))
    except ValueError as err:
        note = f"Laplace whitening failed ({err}); sampling in plain logit coordinates"
    model = make_model(data, surrogate, transform, error)
    init = {"z": transform.to_sampling(jnp.asarray(inside)), **start.values(error)}
    return model, init, note


def _box_cuts(
    names: tuple[str, ...],
    draws: Float[np.ndarray, "sample param"],
    box,
    bounds: tuple[np.ndarray, np.ndarray],
    surrogate,
) -> list[str]:
    """The parameters whose posterior the box may cut: a face that is not a bound within
    ``_BOX_ROOM_SD`` posterior sds of the mean, or more than 5 % of the draws at it."""
    room = _box_room(draws, box, bounds)
    edge = surrogate.edge_fraction(jnp.asarray(draws), bounds)
    return [
        f"{n} ({r:.1f} sd, {100 * e:.0f} % of the draws at the face)"
        for n, r, e in zip(names, room, edge, strict=True)
        if r < _BOX_ROOM_SD or e > 0.05
    ]


@dataclasses.dataclass(frozen=True)
class _Posterior:
    """The samples of the last box, the model they came from, and the box's surrogate."""

    idata: az.InferenceData
    model: Any
    draws: Float[np.ndarray, "sample free"]
    box: tuple[np.ndarray, np.ndarray]
    surrogate_rms: float
    notes: tuple[str, ...]
    timings: dict[str, float]


def _sample_posterior(
    search: _SearchSpace,
    population: _Population,
    data: CalibrationData,
    optimum: _Optimum,
    start: _ErrorStart,
    sampler: _Sampler,
    error: ModelError,
    settings: FitSettings,
    *,
    keys: tuple[jax.Array, jax.Array],
    progress: bool,
) -> _Posterior:
    """The posterior of the continuous parameters on a surrogate around the optimum.

    A surrogate is fitted in a box around the optimum, the posterior sampled on it from the
    optimum; while the box may cut the posterior (:func:`_box_cuts`) and moves are left
    (``settings.box_moves``), the box moves to the posterior mean, widens to ``_BOX_NEW_SD``
    posterior sds each side, and the posterior is sampled again from the posterior means.
    """
    key_sur, key_sample = keys
    names, bounds = search.free, search.bounds()
    notes: list[str] = []
    t0 = time.perf_counter()
    fractions = _box_fractions(search, population, data, optimum, settings)
    forward = _PartialForward.build(search.system, population, names, optimum.held)
    timings = {"sensitivity": time.perf_counter() - t0, "surrogate": 0.0, "sampling": 0.0}
    centre = optimum.theta
    for stage in range(settings.box_moves + 1):
        t0 = time.perf_counter()
        box, surrogate = _surrogate_in_box(
            forward, centre, fractions, bounds, settings, jax.random.fold_in(key_sur, stage)
        )
        surrogate_rms = float(np.sqrt(np.mean(np.asarray(surrogate.error_variance))))
        timings["surrogate"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        model, init, note = _whitened_model(names, data, surrogate, box, centre, start, error)
        if note is not None:
            notes.append(note)
        idata = sampler.sample(
            model, key=jax.random.fold_in(key_sample, stage), init_values=init, progress=progress
        )
        timings["sampling"] += time.perf_counter() - t0
        post = idata["posterior"]
        draws = np.stack([np.asarray(post[n].values).reshape(-1) for n in names], axis=-1)
        cut = _box_cuts(names, draws, box, bounds, surrogate)
        if not cut:
            break
        message = (
            f"surrogate box {stage + 1}: a face of the box that is not a bound lies within "
            f"{_BOX_ROOM_SD:g} posterior sds of the mean for {', '.join(cut)}: the box, not "
            "the data, may cut the posterior"
        )
        if stage < settings.box_moves:
            message += (
                "; the box was moved to the posterior mean, widened to at least "
                f"{_BOX_NEW_SD:g} sds each side, and the posterior resampled"
            )
            centre = draws.mean(axis=0)
            wider = np.minimum(1.0, _BOX_NEW_SD * draws.std(axis=0) / (bounds[1] - bounds[0]))
            fractions = jnp.maximum(fractions, jnp.asarray(wider))
            start = start.moved(post, error)
        else:
            message += "; raise box_fraction or box_moves"
            # stacklevel 3: the caller of fit_campaign
            warnings.warn(message, UserWarning, stacklevel=3)
        notes.append(message)
    return _Posterior(idata, model, draws, box, surrogate_rms, tuple(notes), timings)


@dataclasses.dataclass(frozen=True)
class _Summary:
    """The posterior's gates, its mean as the point (held parameters included), J there."""

    diagnostics: SamplingDiagnostics
    point: dict[str, float]
    j: float
    notes: tuple[str, ...]


def _summarise(
    posterior: _Posterior,
    search: _SearchSpace,
    population: _Population,
    data: CalibrationData,
    optimum: _Optimum,
    settings: FitSettings,
    key: jax.Array,
) -> _Summary:
    """The sampling gates (their warnings passed on when they fail), the posterior predictive
    draws added to ``posterior.idata``, the posterior mean and its J (exact simulator)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        diagnostics = diagnose_sampling(posterior.idata)
    notes: tuple[str, ...] = ()
    if not diagnostics.passed:
        notes = tuple(f"SAMPLING GATES FAILED: {m}" for m in diagnostics.messages)
        for w in caught:
            # stacklevel 3: the caller of fit_campaign
            warnings.warn(w.message, w.category, stacklevel=3)
    _add_predictive(posterior.idata, posterior.model, settings.predictive_draws, key)
    names = search.free
    point = {n: float(np.mean(posterior.draws[:, i])) for i, n in enumerate(names)}
    point.update(optimum.held)
    x_mean = _full(search.system, np.array([point[n] for n in names]), names, optimum.held)
    j = float(_j(*_simulate(population, x_mean, optimum.chunk), data)[0])
    return _Summary(diagnostics, point, j, notes)


#: the sd of emcee's start ball in the sampled coordinates: a tenth of the posterior sd where
#: the Laplace whitening succeeds (:func:`_whitened_model`), which makes that sd about 1
_EMCEE_INIT_SCALE = 0.1

#: the samplers of the posterior, by the method's name
_SAMPLERS: dict[str, Callable[[FitSettings], _Sampler]] = {
    "nuts": lambda s: _NUTS(
        num_warmup=s.num_warmup,
        num_samples=s.num_samples,
        num_chains=s.num_chains,
        target_accept=s.target_accept,
        chain_method=s.chain_method,
    ),
    "emcee": lambda s: _Emcee(
        n_walkers=s.emcee_walkers,
        n_steps=s.emcee_steps,
        max_steps=s.emcee_max_steps,
        burn=s.emcee_burn,
        thin=s.emcee_thin,
        init_scale=_EMCEE_INIT_SCALE,
    ),
}


def _add_predictive(idata: az.InferenceData, model, n_draws: int, key: jax.Array) -> None:
    """A ``posterior_predictive`` group from about ``n_draws`` draws, thinned evenly."""
    post = idata["posterior"]
    n_chain, n_draw = post.sizes["chain"], post.sizes["draw"]
    step = max(1, (n_chain * n_draw) // max(n_draws, 1))
    keep = slice(None, None, step)
    samples = {
        name: jnp.asarray(np.asarray(post[name].values)[:, keep]).reshape(-1, *post[name].shape[2:])
        for name in (
            "z",
            "sigma_model",
            "sigma_operating",
            "run_scatter",
            "discrepancy_length",
            "sigma_common",
        )
        if name in post
    }
    kept = len(range(n_draw)[keep])
    replicate = Predictive(model, posterior_samples=samples, return_sites=["y"])(key, y=None)
    y = np.asarray(replicate["y"]).reshape(n_chain, kept, *replicate["y"].shape[1:])
    observed = idata["observed_data"]["y"]
    coords: dict[str, Any] = {"chain": post["chain"].values, "draw": post["draw"].values[keep]}
    coords.update({str(dim): observed[dim].values for dim in observed.dims})
    idata.add_groups(
        posterior_predictive=xr.Dataset(
            {"y": (("chain", "draw", *observed.dims), y)}, coords=coords
        )
    )


def posterior_predictive(
    result: FitResult,
    system: AbstractSystem,
    campaign: xr.Dataset,
    runs: Sequence[int] | Int[np.ndarray, " run"] | None = None,
    *,
    key: jax.Array,
    n_draws: int = 100,
) -> tuple[Float[np.ndarray, "draw run channel band"], CalibrationData, Bool[np.ndarray, " draw"]]:
    """Replicated features of some runs under a fit, through the exact simulator.

    Each replicate takes one posterior draw (``cmaes``: the point), simulates the runs'
    operating points and adds the model's discrepancy and the run's own scatter: the
    distribution the fit predicts for a new measurement of the run. With a shared discrepancy
    (``ModelError(shared=True)``), at an operating point the fit's calibration runs measured
    the discrepancy is drawn from its posterior given those runs (their features are taken
    from ``campaign`` at ``result.runs``), elsewhere from its prior ``Normal(0, sigma_c^2)``;
    the run's scatter has variance ``rho_c^2`` times its Welch variance. With the independent
    model error, the scatter is ``Normal(0, s_r^2 + sigma_c^2)``. With a discrepancy correlated
    over the bands (``ModelError(correlation=...)``) its posterior given the calibration runs
    is the correlated one; each replicate feature has the right marginal, drawn independently
    over the bands.

    Parameters
    ----------
    result
        A fit.
    system
        The system fitted.
    campaign
        The campaign that was fitted, holding the runs (for example its held-out healthy
        runs).
    runs
        Which runs; ``None``: the runs fitted.
    key
        Seeds the choice of draws and the scatter.
    n_draws
        Replicates (draws are taken evenly from the posterior).

    Returns
    -------
    replicates
        Replicated features; rows whose simulation failed are NaN.
    data
        The measured features of the runs (same windows as the fit).
    ok
        Whether each replicate's simulation succeeded.
    """
    runs = result.runs if runs is None else np.asarray(runs, dtype=int)
    data, duration = campaign_data(
        system,
        campaign,
        runs,
        spec=result.feature_spec,
        max_motion_s=result.settings.max_motion_s,
    )
    draws = result.posterior_draws()
    total = len(next(iter(draws.values())))
    pick = np.resize(np.linspace(0, total - 1, min(n_draws, total)).round().astype(int), n_draws)
    sigma = np.asarray(result.model_error_draws())
    sigma = sigma[pick % len(sigma)]
    sigma_op = result.discrepancy_draws()
    sigma_op = sigma_op[pick % len(sigma_op)]
    rho = np.asarray(result.run_scatter_draws())
    rho = rho[pick % len(rho)]
    mean, ok = _draw_features(result, system, data, duration, draws, pick)
    welch = np.asarray(data.welch_variance)[None, :, None, None]
    if result.model_error.shared:
        calibration, cal_duration = campaign_data(
            system,
            campaign,
            result.runs,
            spec=result.feature_spec,
            max_motion_s=result.settings.max_motion_s,
        )
        cal_mean, cal_ok = _draw_features(result, system, calibration, cal_duration, draws, pick)
        length = _length_draws(result)
        length = length[pick % len(length)]
        tau = result.common_draws()
        tau = None if tau is None else tau[pick % len(tau)]
        delta_mean, delta_var, common_mean, common_var = _discrepancy_posterior(
            calibration, cal_mean, sigma_op, rho, length, tau
        )
        ok = ok & cal_ok
        ops = np.asarray(data.operating)[np.asarray(data.run_operating)]
        measured = np.asarray(calibration.operating)
        own = sigma_op if sigma_op.ndim == 2 else np.sqrt(np.mean(sigma_op**2, axis=1))
        shift = np.broadcast_to(common_mean[:, None], mean.shape).copy()
        spread = np.broadcast_to(
            own[:, None, :, None] ** 2 + common_var[:, None], mean.shape
        ).copy()
        for i, op in enumerate(ops):
            same = np.isclose(measured, op)
            match = np.flatnonzero(same if measured.ndim == 1 else np.all(same, axis=-1))
            if match.size:
                shift[:, i] = delta_mean[:, match[0]]
                spread[:, i] = delta_var[:, match[0]]
        mean = mean + shift
        variance = spread + rho[:, None, :, None] ** 2 * welch
    else:
        variance = welch + sigma[:, None, :, None] ** 2
    noise = np.asarray(jax.random.normal(key, mean.shape, dtype=jnp.float64))
    replicates = np.where(ok[:, None, None, None], mean + np.sqrt(variance) * noise, np.nan)
    return replicates, data, ok


def _draw_features(
    result: FitResult,
    system: AbstractSystem,
    data: CalibrationData,
    duration: float,
    draws: dict[str, np.ndarray],
    pick: np.ndarray,
) -> tuple[Float[np.ndarray, "draw run channel band"], Bool[np.ndarray, " draw"]]:
    """The simulated features of the runs of ``data`` at the posterior draws ``pick``."""
    unique, inverse = np.unique(pick, return_inverse=True)
    thetas = np.stack([draws[n][unique] for n in result.names], axis=-1)
    fixed = {k: v for k, v in result.point.items() if k not in result.names}
    population = _Population.build(system, data, duration, result.feature_spec)
    features, ok = _simulate(population, _full(system, thetas, result.names, fixed))
    features, ok = features[inverse.reshape(-1)], ok[inverse.reshape(-1)]
    return features[:, np.asarray(data.run_operating)], ok


def _length_draws(result: FitResult) -> Float[np.ndarray, " draw"]:
    """The discrepancy's correlation length over the bands per draw (NaN: independent bands)."""
    post = None if result.idata is None else result.idata["posterior"]
    if post is not None and "discrepancy_length" in post:
        return np.asarray(post["discrepancy_length"].values).reshape(-1)
    return np.array([result.model_error.correlation_length() or np.nan])


def _discrepancy_posterior(
    data: CalibrationData,
    simulated: Float[np.ndarray, "draw run channel band"],
    sigma: Float[np.ndarray, "draw *op channel"],
    rho: Float[np.ndarray, "draw channel"],
    length: Float[np.ndarray, " draw"],
    tau: Float[np.ndarray, "draw channel"] | None = None,
) -> tuple[
    Float[np.ndarray, "draw op channel band"],
    Float[np.ndarray, "draw op channel band"],
    Float[np.ndarray, "draw channel band"],
    Float[np.ndarray, "draw channel band"],
]:
    """Per draw, mean and marginal variance of the discrepancy at each operating point of
    ``data`` (correlated over the bands where ``length`` is not NaN), and of its part common
    to every operating point (``tau``, its scale; zero without it): the discrepancy at an
    operating point ``data`` did not measure is that part plus a fresh one of its own."""
    shape = (data.operating.shape[0], *data.y.shape[1:])
    correlated = bool(np.all(np.isfinite(length)))
    common = tau is not None
    tau = np.zeros(rho.shape) if tau is None else tau

    def one(loc, s, r, ell, t):
        run_variance = data.welch_variance[:, None, None] * r[None, :, None] ** 2
        variance = jnp.broadcast_to(s[..., None] ** 2, shape)
        if correlated:
            scale = jnp.sqrt(variance)
            covariance = (
                scale[..., :, None] * band_correlation(shape[-1], ell) * scale[..., None, :]
            )
            features: DiscrepancyNormal = CorrelatedDiscrepancyNormal(
                jnp.asarray(loc), run_variance, covariance, data.run_operating
            )
        else:
            features = DiscrepancyNormal(
                jnp.asarray(loc),
                run_variance,
                variance,
                data.run_operating,
                common_variance=jnp.broadcast_to(t[:, None] ** 2, shape[1:]) if common else None,
            )
        return (*features.discrepancy_posterior(data.y), *features.common_posterior(data.y))

    simulated = np.where(np.isfinite(simulated), simulated, np.asarray(data.y)[None])
    out = jax.vmap(one)(
        jnp.asarray(simulated),
        jnp.asarray(sigma),
        jnp.asarray(rho),
        jnp.asarray(length),
        jnp.asarray(tau),
    )
    return tuple(np.asarray(o) for o in out)  # type: ignore[return-value]
