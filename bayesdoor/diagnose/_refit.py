"""Confirming a candidate cause by fitting its model extension and testing it on held-out runs.

A system's catalogue attaches to a candidate a *refit recipe* (:class:`AbstractRefit`): from
the parameters its signature estimated (a resonance's frequency, a wavelength, a leak's
receiver), it proposes one or more model extensions with start values and search boxes
(:class:`ExtensionProposal`). :func:`refit_extension` fits the extension's parameters with the
base model's parameters held at the fit's point, on training runs, and returns the extended
model's spectra of every run. Extensions that act on the sensor signals only
(``AbstractSystem.apply_output_extensions``) are refitted on the base model's signals
simulated once; the others are simulated for every candidate.

The layer is generic: it knows the system by its parameter names, ``with_extensions``,
``without_output_extensions``, ``apply_output_extensions`` and ``simulate_values``.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._types import Float, Int
from ._gain import estimate_discrepancy, log_predictive
from ._welch_stats import windowed_log_psd

if TYPE_CHECKING:
    from ..systems import AbstractSystem

#: population members per vectorised simulation (fixed, so one compilation serves a refit)
POPULATION = 8
#: half-width (bins) of the smooth discrepancy's running median (the residual map's too)
SMOOTH_BINS = 15


@dataclasses.dataclass(frozen=True)
class ExtensionProposal:
    """One model extension to refit, as a catalogue's recipe proposes it.

    Attributes
    ----------
    extension
        What ``system.with_extensions`` accepts: a catalogue name or a configured module.
    start
        Start values of the refitted parameters and values of the extension's others, by
        full parameter name (missing ones: nominal).
    free
        The refitted parameters.
    bounds
        Search boxes narrower than a parameter's bounds (for example a few bins around the
        residual's frequency); missing ones: the parameter's bounds.
    key
        The parameters the verdict names (with their uncertainty).
    label
        The configuration in words (``"A2: Z reads X"``).
    """

    extension: Any
    start: Mapping[str, float]
    free: tuple[str, ...]
    bounds: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    key: tuple[str, ...] = ()
    label: str = ""


class AbstractRefit(eqx.Module):
    """A catalogue candidate's recipe: extensions to refit from its signature's estimate."""

    @abc.abstractmethod
    def propose(
        self, parameters: Mapping[str, Any], *, band: tuple[float, float]
    ) -> tuple[ExtensionProposal, ...]:
        """The extensions worth refitting, given the parameters the signature estimated and
        the analysed band (Hz; what lies outside it cannot be fitted)."""


@dataclasses.dataclass(frozen=True)
class Spectra:
    """The spectra both models are judged on: measured runs and how to make a model's.

    Attributes
    ----------
    fs
        Sampling rate, Hz.
    t_start, t_stop
        Each run's motion window, s.
    nperseg
        Welch segment (1 Hz bins for ``nperseg = fs``).
    keep
        The bins inside the analysed band.
    freqs
        Their frequencies, Hz.
    measured
        The measured runs' log10 PSDs.
    log_variance
        Welch variance of each measured run's log10 estimate.
    """

    fs: float
    t_start: Float[np.ndarray, " run"]
    t_stop: Float[np.ndarray, " run"]
    nperseg: int
    keep: np.ndarray
    freqs: Float[np.ndarray, " freq"]
    measured: Float[np.ndarray, "run channel freq"]
    log_variance: Float[np.ndarray, " run"]

    @classmethod
    def of_measured(
        cls,
        signals: Float[np.ndarray, "run channel time"],
        fs: float,
        t_start: Float[np.ndarray, " run"],
        t_stop: Float[np.ndarray, " run"],
        band: tuple[float, float],
        nperseg: int,
    ) -> Spectra:
        freqs, y, log_var = windowed_log_psd(signals, fs, t_start, t_stop, nperseg=nperseg)
        keep = (freqs >= band[0]) & (freqs <= band[1])
        return cls(
            fs=float(fs),
            t_start=np.asarray(t_start, dtype=float),
            t_stop=np.asarray(t_stop, dtype=float),
            nperseg=nperseg,
            keep=keep,
            freqs=freqs[keep],
            measured=y[..., keep],
            log_variance=log_var,
        )

    def model(
        self, signals: Float[np.ndarray, "*pop run channel time"], runs: Int[np.ndarray, " r"]
    ) -> Float[np.ndarray, "*pop run channel freq"]:
        """log10 PSDs of simulated ``runs`` (windows as the measured ones)."""
        x = np.asarray(signals, dtype=float)
        lead = x.shape[:-3]
        flat = x.reshape(-1, *x.shape[-3:])
        t0, t1 = self.t_start[runs], self.t_stop[runs]
        out = np.stack(
            [windowed_log_psd(f, self.fs, t0, t1, nperseg=self.nperseg)[1] for f in flat]
        )
        return out[..., self.keep].reshape(*lead, len(runs), *out.shape[-2:-1], -1)


@dataclasses.dataclass(frozen=True)
class RefitSetup:
    """What every refit of one campaign shares.

    Attributes
    ----------
    system
        The base system (its extensions, if any, stay on).
    point
        Every base parameter's value (the fit's point).
    operating
        Each run's operating point.
    duration
        The record length simulated, s.
    time
        The sample times of the simulated records.
    base_signals
        The base model's signals of every run at ``point`` (cut to the measured length).
    spectra
        The measured spectra and the analysis.
    """

    system: AbstractSystem
    point: Mapping[str, float]
    operating: Float[np.ndarray, " run"]
    duration: float
    time: Float[np.ndarray, " time"]
    base_signals: Float[np.ndarray, "run channel time"]
    spectra: Spectra

    @property
    def base_spectra(self) -> Float[np.ndarray, "run channel freq"]:
        return self.spectra.model(self.base_signals, np.arange(len(self.operating)))


@dataclasses.dataclass(frozen=True)
class RefitResult:
    """An extension fitted on some runs: its values, their uncertainty, its spectra.

    Attributes
    ----------
    proposal
        What was refitted.
    values
        Every extension parameter's value (free ones at the optimum).
    sd
        Laplace standard deviation of each free parameter (NaN where the curvature is not
        positive).
    train
        The runs fitted.
    spectra
        The extended model's spectra of every run.
    train_lpd
        Log predictive density of the training runs at the optimum (discrepancy profiled).
    evaluations
        Objective evaluations spent.
    """

    proposal: ExtensionProposal
    values: dict[str, float]
    sd: dict[str, float]
    train: np.ndarray
    spectra: Float[np.ndarray, "run channel freq"]
    train_lpd: float
    evaluations: int


def _boxes(
    system: AbstractSystem, proposal: ExtensionProposal
) -> tuple[AbstractSystem, list[str], np.ndarray, np.ndarray, dict[str, float]]:
    extended = system.with_extensions(proposal.extension)
    base_names = set(system.parameter_names())
    specs = {p.name: p for p in extended.parameters if p.name not in base_names}
    unknown = [n for n in (*proposal.free, *proposal.bounds) if n not in specs]
    if unknown:
        raise ValueError(
            f"the proposal names {unknown}, which are not parameters of the extension "
            f"{proposal.extension!r} (it has {', '.join(specs)})"
        )
    lower = np.array(
        [max(specs[n].lower, proposal.bounds.get(n, (-np.inf,))[0]) for n in proposal.free]
    )
    upper = np.array(
        [min(specs[n].upper, proposal.bounds.get(n, (0, np.inf))[1]) for n in proposal.free]
    )
    fixed = {n: float(proposal.start.get(n, s.nominal)) for n, s in specs.items()}
    return extended, list(proposal.free), lower, upper, fixed


def _simulator(
    setup: RefitSetup, extended: AbstractSystem, free: Sequence[str], fixed: Mapping[str, float]
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``f(X, runs)``: the extended model's signals of ``runs`` for each row of ``X``."""
    output_only = (
        extended.without_output_extensions().extension_names == setup.system.extension_names
    )
    n_time = setup.base_signals.shape[-1]

    def values_for(x: np.ndarray, n_runs: int) -> dict[str, Any]:
        pop = x.shape[0]
        vals: dict[str, Any] = {k: np.full((pop, n_runs), v) for k, v in fixed.items()}
        for i, name in enumerate(free):
            vals[name] = np.repeat(x[:, i : i + 1], n_runs, axis=1)
        return vals

    if output_only:

        def simulate(x: np.ndarray, runs: np.ndarray) -> np.ndarray:
            base = np.broadcast_to(
                setup.base_signals[runs], (x.shape[0], *setup.base_signals[runs].shape)
            )
            out = extended.apply_output_extensions(
                jnp.asarray(base), jnp.asarray(setup.time), values_for(x, len(runs))
            )
            return np.asarray(out)

        return simulate

    def simulate(x: np.ndarray, runs: np.ndarray) -> np.ndarray:
        pop, n_runs = x.shape[0], len(runs)
        vals = {k: np.asarray(v).reshape(-1) for k, v in values_for(x, n_runs).items()}
        vals.update({k: np.full(pop * n_runs, float(v)) for k, v in setup.point.items()})
        result = extended.simulate_values(
            vals,
            np.tile(setup.operating[runs], pop),
            duration=setup.duration,
            check=False,
        )
        signals = np.asarray(result.signals)[..., :n_time]
        failed = np.asarray(result.status) != 0
        signals = np.where(failed[:, None, None], np.nan, signals)
        return signals.reshape(pop, n_runs, *signals.shape[1:])

    return simulate


def _batched(
    simulate: Callable[[np.ndarray, np.ndarray], np.ndarray],
    spectra: Spectra,
    x: np.ndarray,
    runs: np.ndarray,
) -> np.ndarray:
    """The model spectra of ``runs`` for every row of ``x``, in padded batches of POPULATION."""
    out = []
    for start in range(0, len(x), POPULATION):
        block = x[start : start + POPULATION]
        padded = np.concatenate([block, np.repeat(block[-1:], POPULATION - len(block), axis=0)])
        out.append(spectra.model(simulate(padded, runs), runs)[: len(block)])
    return np.concatenate(out)


def _profile_lpd(spectra: Spectra, model: np.ndarray, runs: np.ndarray) -> np.ndarray:
    """Training log predictive density of each row of ``model``, its discrepancy profiled."""
    y, lv = spectra.measured[runs], spectra.log_variance[runs]
    out = np.full(model.shape[0], -np.inf)
    for i, m in enumerate(model):
        if np.all(np.isfinite(m)):
            disc = estimate_discrepancy(m, y, lv, SMOOTH_BINS)
            out[i] = float(log_predictive(m, y, lv, disc).sum())
    return out


def _laplace_sd(
    objective: Callable[[np.ndarray], np.ndarray],
    x: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """Standard deviations from a quadratic fitted to the objective around ``x``.

    ``objective`` is a negative log density; points are drawn within 2 % of each box width
    around ``x`` (inside the box) and a full quadratic is fitted by least squares, which
    averages over the solver's small step-to-step noise where finite differences would not.
    """
    d = len(x)
    width = upper - lower
    n_terms = 1 + d + d * (d + 1) // 2
    pts = x + 0.02 * width * rng.uniform(-1.0, 1.0, (3 * n_terms, d))
    pts = np.clip(pts, lower, upper)
    f = objective(pts)
    ok = np.isfinite(f)
    u = (pts[ok] - x) / width
    iu = np.triu_indices(d)
    quad = np.einsum("ni,nj->nij", u, u)[:, iu[0], iu[1]]
    design = np.concatenate([np.ones((len(u), 1)), u, quad], axis=1)
    coef, *_ = np.linalg.lstsq(design, f[ok], rcond=None)
    h = np.zeros((d, d))
    h[iu] = coef[1 + d :]
    hessian = h + h.T
    try:
        cov = np.linalg.inv(hessian)
    except np.linalg.LinAlgError:
        return np.full(d, np.nan)
    var = np.diag(cov)
    return np.where(var > 0, np.sqrt(np.abs(var)) * width, np.nan)


def refit_extension(
    setup: RefitSetup,
    proposal: ExtensionProposal,
    train: Int[np.ndarray, " run"],
    *,
    seed: int,
    max_evals: int,
    uncertainty: bool = False,
    progress: bool = False,
) -> RefitResult:
    """Fit one extension's free parameters on the training runs (base parameters held).

    The objective is the training runs' log predictive density with the extended model's
    discrepancy estimated on the same runs (:func:`estimate_discrepancy`), maximised by
    CMA-ES from the proposal's start within its search boxes.

    Parameters
    ----------
    setup
        The campaign's shared pieces.
    proposal
        The extension and its start.
    train
        The runs fitted.
    seed
        Seeds CMA-ES and the design of the uncertainty.
    max_evals
        CMA-ES budget.
    uncertainty
        Also estimate each free parameter's Laplace standard deviation.
    progress
        Show CMA-ES's progress bar.

    Returns
    -------
    RefitResult
    """
    from ..inference import minimize_cmaes

    extended, free, lower, upper, fixed = _boxes(setup.system, proposal)
    simulate = _simulator(setup, extended, free, fixed)
    train = np.asarray(train, dtype=int)

    def objective(x: np.ndarray) -> np.ndarray:
        model = _batched(simulate, setup.spectra, np.atleast_2d(x), train)
        return -_profile_lpd(setup.spectra, model, train)

    x0 = np.clip([float(proposal.start.get(n, fixed[n])) for n in free], lower, upper)
    result = minimize_cmaes(
        objective,
        x0,
        lower=lower,
        upper=upper,
        seed=seed + 1,
        sigma0=0.2,
        max_evals=max_evals,
        popsize=POPULATION,
        progress=progress,
    )
    best = np.asarray(result.x_best, dtype=float)
    sd = np.full(len(free), np.nan)
    evaluations = result.evaluations
    if uncertainty:
        sd = _laplace_sd(objective, best, lower, upper, np.random.default_rng(seed))
        d = len(free)
        evaluations += 3 * (1 + d + d * (d + 1) // 2)
    every = np.arange(len(setup.operating))
    spectra = _batched(simulate, setup.spectra, best[None], every)[0]
    values = {**fixed, **dict(zip(free, map(float, best), strict=True))}
    return RefitResult(
        proposal=proposal,
        values=values,
        sd=dict(zip(free, map(float, sd), strict=True)),
        train=train,
        spectra=spectra,
        train_lpd=float(-result.f_best),
        evaluations=evaluations,
    )
