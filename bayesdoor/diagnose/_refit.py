"""Confirming a candidate cause by fitting its model extension and testing it on held-out runs.

A system's catalogue attaches to a candidate a *refit recipe* (:class:`AbstractRefit`): from
the parameters its signature estimated (a resonance's frequency, a period, a leak's
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
import itertools
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import scipy.optimize

from .._types import Array, Bool, Float, Int
from ..features import windowed_log_psd
from ..inference import CMAESOptions, minimize_cmaes
from ..inference._surrogate import map_padded_chunks
from ._gain import Discrepancy, estimate_discrepancy, log_predictive
from ._transmission import Transmission

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
    linear
        Free parameters whose effect on the signals is linear, zero being "off" (an amplitude
        of a few micrometres on a contact preloaded by a fraction of a millimetre). For an
        extension that needs a new solve, naming them turns the refit into a few solves: each
        one's signal change is simulated once at its start value and scaled.
    grid
        For an extension that needs a new solve: the values searched of each free parameter
        that is not linear (a profile over the grid; each point costs one solve per linear
        parameter).
    held
        Parameters held at an estimate made from the residual features, as (value, standard
        error): reported with the refit, not refitted (their value is in ``start``).
    measured
        Free parameters that the data measure directly, without the base model (for
        example a leak fraction from the measured transfer function between two channels),
        as (value, standard error): refitted and judged as usual, but reported at the
        measured value, which does not absorb the base model's errors as the refit's does
        (the refit's value is reported next to it).
    gains
        Free parameters that each scale one signal added to one channel only, by the
        channel's name (a mode's participation: channel c reads s_c p''). For an extension
        that needs a new solve they are profiled exactly instead of searched: every
        candidate of the other free parameters is solved once for the signals O with the
        gains at 0 and the signal P each gain scales (``AbstractSystem.simulate_gains``), and
        since a Welch PSD is quadratic in s, PSD(O + s P) = PSD(O) + s (PSD(O + P) -
        PSD(O - P)) / 2 + s^2 ((PSD(O + P) + PSD(O - P)) / 2 - PSD(O)), each gain is fitted
        on its channel (the discrepancy is estimated channel by channel) without another
        solve.
    admissible
        A constraint on the free parameters besides their boxes, for a quantity that follows
        from them (a mode that carries the rail peaks at its installed frequency, which its
        lift moves away from the bare frequency the box holds): given the extended system and
        every parameter's value, whether a candidate lies in the region searched. The search
        gives the candidates it refuses no density (they are not simulated), so no refit
        leaves the region; ``None``: the boxes alone.
    on_measured
        The extension acts on the sensor: it mixes what the sensor measured (a leak between
        the channels of one sensor), not what the model predicts. It is then tested on the
        measured signals: the extended model's spectra are the base model's plus the change
        that undoing the extension makes to the measured run, ``log S(y) - log S(y - d(y))``
        with ``d(y)`` the extension's addition to the measured signals ``y``. The channels it
        reads from enter as measured, so the base model's own error in them stays out of the
        test (a leak's modelled change can be several times the machine's when the model
        gets the source channel wrong). Only for an extension that acts on the outputs and
        is affine in them, its free parameters at zero being off.
    """

    extension: Any
    start: Mapping[str, float]
    free: tuple[str, ...]
    bounds: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    key: tuple[str, ...] = ()
    label: str = ""
    linear: tuple[str, ...] = ()
    grid: Mapping[str, tuple[float, ...]] = dataclasses.field(default_factory=dict)
    held: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    measured: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    gains: Mapping[str, str] = dataclasses.field(default_factory=dict)
    admissible: Callable[[AbstractSystem, Mapping[str, float]], bool] | None = None
    on_measured: bool = False


@dataclasses.dataclass(frozen=True)
class SizeProbe:
    """One configuration of a cause at which its detectable size is computed.

    Attributes
    ----------
    label
        The configuration in words (``"typical: 50 Hz"``).
    proposal
        The extension and the values of its other parameters (in ``start``).
    scales
        Each free parameter of ``proposal`` as a multiple of the size (a mains line of
        amplitude ``s`` on every channel: 1 each). The cause's signal change must be affine
        in the size (amplitudes, participations, leak fractions): the probe is simulated at
        size 0 and at ``reference`` and scaled between.
    reference
        The size simulated (inside the parameters' bounds).
    off_at_zero
        Whether the extension at size 0 is the base model (its signals the base model's),
        so that only the size ``reference`` is simulated.
    """

    label: str
    proposal: ExtensionProposal
    scales: Mapping[str, float]
    reference: float
    off_at_zero: bool = True

    def values(self, size: float, runs: int) -> dict[str, np.ndarray]:
        """Every free parameter at ``size``, one value per run."""
        return {
            n: np.full(runs, float(self.scales.get(n, 0.0)) * float(size))
            for n in self.proposal.free
        }


@dataclasses.dataclass(frozen=True)
class CauseSize:
    """A catalogue cause's key size: what it is, its unit, the range scanned for its
    detection limit, and the configurations of its other parameters to scan it at (the
    first the typical one).

    Attributes
    ----------
    quantity
        The size in words (``"wheel run-out"``).
    unit
        Its SI unit (``"m"``, ``"m/s^2"``, ``"-"``).
    low, high
        The sizes scanned (log-spaced between them).
    probes
        The configurations, the typical one first.
    display
        A unit to show the size in and its factor from ``unit`` (``("um", 1e6)``).
    transmission
        How a family of machines transmits the cause against the model, in the typical
        configuration (``None``: not measured).
    """

    quantity: str
    unit: str
    low: float
    high: float
    probes: tuple[SizeProbe, ...]
    display: tuple[str, float] = ("", 1.0)
    transmission: Transmission | None = None

    def __post_init__(self) -> None:
        if not (0.0 < self.low < self.high) or not self.probes:
            raise ValueError(
                f"CauseSize {self.quantity!r}: need 0 < low < high and at least one probe, got "
                f"low={self.low!r}, high={self.high!r}, {len(self.probes)} probes"
            )


class Symptom(NamedTuple):
    """Whether a refitted extension explains the residual feature it was proposed for.

    Attributes
    ----------
    explained
        The recipe's answer.
    words
        Its reason in words.
    share
        The share of the feature's excess over the base model that the refit took away on
        held-out runs (1: all of it, 0: none, negative: the refit made it larger); ``None``
        where the recipe does not measure one.
    """

    explained: bool
    words: str
    share: float | None = None


class AbstractRefit(eqx.Module):
    """A catalogue candidate's recipe: extensions to refit from its signature's estimate."""

    @abc.abstractmethod
    def propose(
        self, parameters: Mapping[str, Any], *, band: tuple[float, float]
    ) -> tuple[ExtensionProposal, ...]:
        """The extensions worth refitting, given the parameters the signature estimated and
        the analysed band (Hz; what lies outside it cannot be fitted)."""

    def explains(
        self,
        parameters: Mapping[str, Any],
        freqs: Float[np.ndarray, " freq"],
        measured: Float[np.ndarray, "run channel freq"],
        base: Float[np.ndarray, "run channel freq"],
        extended: Float[np.ndarray, "run channel freq"],
        channels: tuple[str, ...],
        refitted: Sequence[Mapping[str, float]] = (),
    ) -> Symptom | tuple[bool, str]:
        """Whether the refitted extension explains the residual feature it was proposed for.

        A cause is named for its symptom: an extension that gains on held-out runs but leaves
        its own feature unexplained has absorbed some other misfit of the model (on the rig
        with nothing hidden, a rail-carrying mode at 90 Hz gained by softening the wheels'
        support, which moved the door's modes near 65 Hz). ``extended`` holds each run's
        spectra from the fold that held it out; ``refitted`` each fold's refitted values with
        the recipe's :meth:`derived` quantities (empty when not known). Returns a
        :class:`Symptom` (the answer, its reason in words, the share of the feature taken
        away; a plain ``(answer, words)`` pair is read as one without a share); the default
        recipe has no symptom test (``True``).
        """
        return Symptom(True, "")

    def derived(
        self,
        proposal: ExtensionProposal,
        system: AbstractSystem,
        values: Mapping[str, float],
    ) -> dict[str, float]:
        """Quantities a user reads off the refitted extension besides its parameters (for a
        mode that carries the rail, the frequency of its peak as installed in the door).
        ``system`` is the base system with the proposal's extension, ``values`` every one of
        its parameters at the refit on every run. The default recipe has none."""
        return {}

    def derived_sd(
        self,
        proposal: ExtensionProposal,
        values: Mapping[str, float],
        sd: Mapping[str, float],
    ) -> dict[str, float]:
        """Standard deviations of :meth:`derived`'s quantities where the recipe can give
        them, from the refitted ``values`` and their Laplace ``sd``; missing ones are
        reported without one. The default recipe gives none."""
        return {}

    def size(self, *, band: tuple[float, float]) -> CauseSize | None:
        """The cause's key size, its unit, the range to scan and the configurations to scan
        it at, for its detection limit (:func:`~bayesdoor.diagnose.detection_limits`);
        ``band`` is the analysed band (Hz). The default recipe declares none (no limit)."""
        return None

    def alternatives(self, parameters: Mapping[str, Any]) -> tuple[str, ...]:
        """Other catalogue causes that would give the same symptom as this refitted cause,
        each in words with the reason (for a rail irregularity at a wheel harmonic's
        wavelength, the out-of-round wheel: the spectra cannot tell them apart).
        ``parameters`` are the cause's, the signature's estimate and the refit's summaries
        (``{"mean", "sd"}``) together. The default recipe knows none."""
        return ()


def held_out_spectra(
    fits: Sequence[RefitResult], folds: Sequence[tuple[np.ndarray, np.ndarray]]
) -> Float[np.ndarray, "run channel freq"]:
    """Every run's spectra from the refit of the fold that held it out."""
    n_runs = sum(len(test) for _, test in folds)
    out = np.full((n_runs, *fits[0].spectra.shape[1:]), np.nan)
    for fit, (_, test) in zip(fits, folds, strict=True):
        out[test] = fit.spectra[test]
    return out


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
    local
        Per channel and bin, whether the discrepancy's scatter is local there
        (:func:`~bayesdoor.diagnose.feature_bins`: the residual features' bins, fixed before
        any refit and the same for every model); ``None``: one value per channel everywhere.
    """

    fs: float
    t_start: Float[np.ndarray, " run"]
    t_stop: Float[np.ndarray, " run"]
    nperseg: int
    keep: np.ndarray
    freqs: Float[np.ndarray, " freq"]
    measured: Float[np.ndarray, "run channel freq"]
    log_variance: Float[np.ndarray, " run"]
    local: Bool[np.ndarray, "channel freq"] | None = None

    @classmethod
    def of_measured(
        cls,
        signals: Float[np.ndarray, "run channel time"],
        fs: float,
        t_start: Float[np.ndarray, " run"],
        t_stop: Float[np.ndarray, " run"],
        band: tuple[float, float],
        nperseg: int,
        local: Bool[np.ndarray, "channel freq"] | None = None,
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
            local=local,
        )

    def model(
        self, signals: Float[np.ndarray, "*pop run channel time"], runs: Int[np.ndarray, " r"]
    ) -> Float[np.ndarray, "*pop run channel freq"]:
        """log10 PSDs of simulated ``runs`` (windows as the measured ones)."""
        t0, t1 = self.t_start[runs], self.t_stop[runs]
        out = windowed_log_psd(signals, self.fs, t0, t1, nperseg=self.nperseg)[1]
        return out[..., self.keep]


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
    speeds
        Each run's speed for an effect that tracks it (the catalogue's
        :meth:`~bayesdoor.diagnose.Catalogue.speeds`); ``None``: ``operating``.
    measured_signals
        The measured runs' signals (the spectra's), cut as ``base_signals``: what a
        proposal that acts on the sensor is tested on (``ExtensionProposal.on_measured``);
        ``None``: such proposals cannot be refitted.
    """

    system: AbstractSystem
    point: Mapping[str, float]
    operating: Float[np.ndarray, " run"] | Float[np.ndarray, "run condition"]
    duration: float
    time: Float[np.ndarray, " time"]
    base_signals: Float[np.ndarray, "run channel time"]
    spectra: Spectra
    speeds: Float[np.ndarray, " run"] | None = None
    measured_signals: Float[np.ndarray, "run channel time"] | None = None

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
    solves
        Simulated runs spent on new solves (0 for extensions that act on the outputs).
    box
        The search box ``(lower, upper)`` of each free parameter (the proposal's bounds
        within the extension's own).
    """

    proposal: ExtensionProposal
    values: dict[str, float]
    sd: dict[str, float]
    train: np.ndarray
    spectra: Float[np.ndarray, "run channel freq"]
    train_lpd: float
    evaluations: int
    solves: int = 0
    box: dict[str, tuple[float, float]] = dataclasses.field(default_factory=dict)

    def at_bound(self) -> dict[str, str]:
        """The free parameters whose optimum lies at an end of their search box
        (:func:`box_ends`): ``{name: "lower" | "upper"}``."""
        return box_ends(self.values, self.box)


#: a value lies at an end of its search box when it is within this fraction of the box's
#: width from it (CMA-ES's boundary handling leaves an optimum pushed against a bound a tiny
#: step inside it)
BOX_END_FRACTION = 1e-3


def box_ends(values: Mapping[str, float], box: Mapping[str, tuple[float, float]]) -> dict[str, str]:
    """Which of ``values`` lie at an end of their search box, ``{name: "lower" | "upper"}``.

    A fitted value at an end of its box is not an estimate: the data would move it further,
    and the parameters that trade off with it are biased too. Names without a finite box,
    or missing from ``values``, are left out.
    """
    ends: dict[str, str] = {}
    for name, (lo, hi) in box.items():
        if name not in values or not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
            continue
        step = BOX_END_FRACTION * (hi - lo)
        if values[name] <= lo + step:
            ends[name] = "lower"
        elif values[name] >= hi - step:
            ends[name] = "upper"
    return ends


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


def _admissible_rows(
    setup: RefitSetup, proposal: ExtensionProposal, model: _Model, x: np.ndarray
) -> np.ndarray:
    """Which rows of free parameters ``x`` the proposal's constraint admits (all, without
    one; never a row that is not finite)."""
    finite = np.all(np.isfinite(x), axis=-1)
    if proposal.admissible is None:
        return finite
    base = {**setup.point, **model.fixed}
    return np.array(
        [
            bool(ok)
            and bool(
                proposal.admissible(
                    model.extended, {**base, **dict(zip(model.free, map(float, row), strict=True))}
                )
            )
            for ok, row in zip(finite, x, strict=True)
        ]
    )


def tile_runs(operating: np.ndarray, n: int) -> np.ndarray:
    """The runs' operating points repeated ``n`` times along the run axis (``(run,)`` or
    ``(run, condition)``): the operating points of ``n`` rows of a batch of those runs."""
    operating = np.asarray(operating)
    return np.tile(operating, (n,) + (1,) * (operating.ndim - 1))


class _Model:
    """The extended model's signals for rows of free parameters, and the solves it spent.

    Output extensions act on the base signals. Extensions that need a solve are simulated
    directly, or, when the proposal names its linear parameters, as the base signals plus the
    scaled signal change of each linear parameter, simulated once per grid point (``bases``,
    shared by every fold of one proposal).
    """

    def __init__(
        self,
        setup: RefitSetup,
        proposal: ExtensionProposal,
        extended: AbstractSystem,
        fixed: Mapping[str, float],
        bases: dict[tuple[float, ...], np.ndarray],
        workers: int = 1,
    ):
        self.setup, self.proposal, self.extended, self.fixed = setup, proposal, extended, fixed
        self.workers = workers
        self._sizes: set[int] = set()
        self.free = list(proposal.free)
        self.output_only = (
            extended.without_output_extensions().extension_names == setup.system.extension_names
        )
        self.nonlinear = [n for n in self.free if n not in proposal.linear]
        self.surrogate = not self.output_only and bool(proposal.linear)
        missing = [n for n in self.nonlinear if n not in proposal.grid]
        if self.surrogate and missing:
            raise ValueError(
                f"the proposal's free parameters {missing} are neither linear nor gridded: a "
                "refit through linear signal changes needs a grid for every other parameter"
            )
        if proposal.on_measured and not self.output_only:
            raise ValueError(
                "a proposal tested on the measured signals (on_measured) must extend the "
                f"outputs only; {proposal.label or proposal.extension!r} needs a solve"
            )
        if proposal.on_measured and setup.measured_signals is None:
            raise ValueError(
                "the refit setup holds no measured signals, which a proposal tested on the "
                "measured signals (on_measured) needs"
            )
        self.reference = {n: float(proposal.start.get(n, 0.0)) or 1e-6 for n in proposal.linear}
        self.bases = bases
        self.solves = 0
        self._base_spectra: np.ndarray | None = None

    def values(self, x: np.ndarray, n_runs: int) -> dict[str, np.ndarray]:
        pop = x.shape[0]
        vals = {k: np.full((pop, n_runs), v) for k, v in self.fixed.items()}
        for i, name in enumerate(self.free):
            vals[name] = np.repeat(x[:, i : i + 1], n_runs, axis=1)
        return vals

    def _by_rows(
        self,
        solve: Callable[[Mapping[str, np.ndarray]], tuple[np.ndarray, ...]],
        vals: Mapping[str, np.ndarray],
    ) -> tuple[np.ndarray, ...]:
        """``solve`` of the rows of ``vals``, split into ``workers`` equal blocks run in
        threads (``map_padded_chunks``, the last block padded): XLA runs one vmapped solve
        on one core and releases the interpreter meanwhile. A block size not solved before
        runs its first block alone, so that the threads do not each compile it."""

        pop, n_runs = next(iter(vals.values())).shape
        self.solves += pop * n_runs
        if self.workers == 1 or pop < 2:
            return solve(vals)
        names = list(vals)
        size = -(-pop // self.workers)
        first_alone = size not in self._sizes
        self._sizes.add(size)
        return map_padded_chunks(
            lambda rows: solve(
                {n: rows[:, i * n_runs : (i + 1) * n_runs] for i, n in enumerate(names)}
            ),
            np.concatenate([np.asarray(vals[n], dtype=float) for n in names], axis=1),
            size,
            self.workers,
            first_alone=first_alone,
        )

    def _flat(self, vals: Mapping[str, np.ndarray], runs: np.ndarray) -> tuple[dict, Array]:
        """The rows of ``vals`` (row, run) flattened, the base point added, and the speeds."""
        pop, n_runs = next(iter(vals.values())).shape
        flat = {k: jnp.asarray(np.reshape(v, -1), dtype=float) for k, v in vals.items()}
        flat.update(
            {k: jnp.full(pop * n_runs, float(v), dtype=float) for k, v in self.setup.point.items()}
        )
        return flat, jnp.asarray(tile_runs(self.setup.operating[runs], pop))

    def solve(self, vals: Mapping[str, np.ndarray], runs: np.ndarray) -> np.ndarray:
        """Signals (row, run, channel, time) of a direct solve; NaN where it failed."""

        def block(vals: Mapping[str, np.ndarray]) -> tuple[np.ndarray, ...]:
            pop, n_runs = next(iter(vals.values())).shape
            flat, speeds = self._flat(vals, runs)
            result = self.extended.simulate_values(
                flat,
                speeds,
                state=self.extended.healthy,
                duration=self.setup.duration,
                check=False,
            )
            signals = np.asarray(result.signals)[..., : self.setup.base_signals.shape[-1]]
            failed = np.asarray(result.status) != 0
            signals = np.where(failed[:, None, None], np.nan, signals)
            return (signals.reshape(pop, n_runs, *signals.shape[1:]),)

        return self._by_rows(block, vals)[0]

    def solve_gains(
        self, vals: Mapping[str, np.ndarray], runs: np.ndarray, gains: Sequence[str]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Signals (row, run, channel, time) with the ``gains`` at zero, and the signal each
        gain scales (``AbstractSystem.simulate_gains``); NaN where the solve failed."""

        def block(vals: Mapping[str, np.ndarray]) -> tuple[np.ndarray, ...]:
            pop, n_runs = next(iter(vals.values())).shape
            flat, speeds = self._flat(vals, runs)
            result, slope = self.extended.simulate_gains(
                flat, speeds, tuple(gains), duration=self.setup.duration, check=False
            )
            n_time = self.setup.base_signals.shape[-1]
            failed = (np.asarray(result.status) != 0)[:, None, None]
            out = []
            for signals in (result.signals, slope):
                x = np.where(failed, np.nan, np.asarray(signals)[..., :n_time])
                out.append(x.reshape(pop, n_runs, *x.shape[1:]))
            return out[0], out[1]

        signals, slope = self._by_rows(block, vals)
        return signals, slope

    def measured_spectra(
        self, vals: Mapping[str, np.ndarray], runs: np.ndarray
    ) -> Float[np.ndarray, "row run channel freq"]:
        """Spectra (row, run, channel, freq) of a proposal tested on the measured signals
        (``ExtensionProposal.on_measured``) at the values ``vals`` (row, run): the base
        model's plus the change that undoing the extension makes to each measured run."""
        setup = self.setup
        assert setup.measured_signals is not None
        pop = next(iter(vals.values())).shape[0]
        measured = np.broadcast_to(
            setup.measured_signals[runs], (pop, *setup.measured_signals[runs].shape)
        )
        off = {k: (np.zeros_like(v) if k in self.free else v) for k, v in vals.items()}
        time = jnp.asarray(setup.time)
        added = np.asarray(
            self.extended.apply_output_extensions(
                jnp.asarray(measured), time, {k: jnp.asarray(v) for k, v in vals.items()}
            )
        ) - np.asarray(
            self.extended.apply_output_extensions(
                jnp.asarray(measured), time, {k: jnp.asarray(v) for k, v in off.items()}
            )
        )
        undone = setup.spectra.model(measured - added, runs)
        change = setup.spectra.measured[runs] - undone
        if self._base_spectra is None:
            self._base_spectra = setup.base_spectra
        return self._base_spectra[runs] + change

    def basis(self, point: tuple[float, ...]) -> np.ndarray:
        """Signal change per unit of each linear parameter at a grid point, every run."""
        if point not in self.bases:
            every = np.arange(len(self.setup.operating))
            rows = []
            for name in self.proposal.linear:
                x = np.array(
                    [
                        [
                            self.reference[n]
                            if n == name
                            else (point[self.nonlinear.index(n)] if n in self.nonlinear else 0.0)
                            for n in self.free
                        ]
                    ]
                )
                rows.append(
                    (self.solve(self.values(x, len(every)), every)[0] - self.setup.base_signals)
                    / self.reference[name]
                )
            self.bases[point] = np.stack(rows)
        return self.bases[point]

    def signals(self, x: np.ndarray, runs: np.ndarray, *, exact: bool = False) -> np.ndarray:
        """Signals (row, run, channel, time) of ``runs`` for every row of free parameters."""
        if self.output_only:
            base = np.broadcast_to(
                self.setup.base_signals[runs], (x.shape[0], *self.setup.base_signals[runs].shape)
            )
            vals = {k: jnp.asarray(v) for k, v in self.values(x, len(runs)).items()}
            extended = self.extended.apply_output_extensions(
                jnp.asarray(base), jnp.asarray(self.setup.time), vals
            )
            return np.asarray(extended)
        if exact or not self.surrogate:
            return self.solve(self.values(x, len(runs)), runs)
        rows = []
        lin = [self.free.index(n) for n in self.proposal.linear]
        for row in x:
            point = tuple(float(row[self.free.index(n)]) for n in self.nonlinear)
            b = self.basis(point)[:, runs]
            rows.append(self.setup.base_signals[runs] + np.tensordot(row[lin], b, axes=1))
        return np.stack(rows)


def _batched(
    model: _Model, spectra: Spectra, x: np.ndarray, runs: np.ndarray, *, exact: bool = False
) -> np.ndarray:
    """The model spectra of ``runs`` for every row of ``x``, in padded batches of POPULATION."""
    out = []
    for start in range(0, len(x), POPULATION):
        block = x[start : start + POPULATION]
        if not exact:
            block = np.concatenate([block, np.repeat(block[-1:], POPULATION - len(block), axis=0)])
        if model.proposal.on_measured:
            block_spectra = model.measured_spectra(model.values(block, len(runs)), runs)
        else:
            block_spectra = spectra.model(model.signals(block, runs, exact=exact), runs)
        out.append(block_spectra[: min(POPULATION, len(x) - start)])
    return np.concatenate(out)


def _profile_lpd(spectra: Spectra, model: np.ndarray, runs: np.ndarray) -> np.ndarray:
    """Training log predictive density of each row of ``model``, its discrepancy profiled."""
    y, lv = spectra.measured[runs], spectra.log_variance[runs]
    out = np.full(model.shape[0], -np.inf)
    for i, m in enumerate(model):
        if np.all(np.isfinite(m)):
            disc = estimate_discrepancy(m, y, lv, SMOOTH_BINS, local=spectra.local)
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
    pts = x + 0.02 * width * rng.uniform(-1.0, 1.0, (_laplace_evaluations(d), d))
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


def _laplace_evaluations(d: int) -> int:
    """Objective evaluations :func:`_laplace_sd` spends on ``d`` parameters."""
    return 3 * (1 + d + d * (d + 1) // 2)


@dataclasses.dataclass(frozen=True)
class RefitOptions:
    """How :func:`refit_extension` fits, beside its seed and budget.

    Attributes
    ----------
    uncertainty
        Also estimate each free parameter's Laplace standard deviation (gridded ones: from
        the profile's curvature).
    progress
        Show CMA-ES's progress bar.
    exact
        Solve the extended model exactly at the optimum for the spectra returned; ``False``:
        the spectra of the linear signal changes (no solve; the same for extensions that act
        on the outputs only), for a caller that judges held-out runs with
        :func:`exact_spectra`.
    workers
        Threads that solve at once, each a block of the population's rows (extensions that
        need a solve; 2 uses both cores of a 2-core machine). The block size moves the
        adaptive solver's round-off, so the fit may change at the solver's tolerance.
        Leave 1 where refits already run in threads.
    """

    uncertainty: bool = False
    progress: bool = False
    exact: bool = True
    workers: int = 1


@dataclasses.dataclass(frozen=True)
class _Problem:
    """One refit in hand: the campaign's setup, the proposal, its model, the search box of
    the free parameters (in ``model.free`` order) and the training runs."""

    setup: RefitSetup
    proposal: ExtensionProposal
    model: _Model
    lower: np.ndarray
    upper: np.ndarray
    train: np.ndarray

    def start(self) -> np.ndarray:
        """The proposal's start (the extension's nominal values where it names none), in
        the box."""
        free, fixed = self.model.free, self.model.fixed
        return np.clip(
            [float(self.proposal.start.get(n, fixed[n])) for n in free], self.lower, self.upper
        )


def _result(
    problem: _Problem,
    optimum: np.ndarray,
    sd: np.ndarray,
    spectra: np.ndarray,
    evaluations: int,
) -> RefitResult:
    """The refit's result at ``optimum`` (free parameters in ``model.free`` order), with the
    training density of ``spectra`` (every run's)."""
    model, train = problem.model, problem.train
    free = model.free
    return RefitResult(
        proposal=problem.proposal,
        values={**model.fixed, **dict(zip(free, map(float, optimum), strict=True))},
        sd=dict(zip(free, map(float, sd), strict=True)),
        train=train,
        spectra=spectra,
        train_lpd=float(_profile_lpd(problem.setup.spectra, spectra[None, train], train)[0]),
        evaluations=evaluations,
        solves=model.solves,
        box={
            n: (float(lo), float(hi))
            for n, lo, hi in zip(free, problem.lower, problem.upper, strict=True)
        },
    )


def _minimize_scalar(
    objective: Callable[[np.ndarray], np.ndarray], lower: float, upper: float, max_evals: int
) -> tuple[float, np.ndarray, int]:
    """One bounded parameter (pycma needs two or more): a grid of ``2 POPULATION`` points,
    then bounded Brent within the best point's neighbours."""
    grid = np.linspace(lower, upper, 2 * POPULATION)
    values = objective(grid[:, None])
    i = int(np.argmin(values))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    budget = max(max_evals - len(grid), 8)
    result = scipy.optimize.minimize_scalar(
        lambda u: float(objective(np.array([[u]]))[0]),
        bounds=(lo, hi),
        method="bounded",
        options={"maxiter": budget, "xatol": 1e-4 * (upper - lower)},
    )
    if result.fun <= values[i]:
        return float(result.fun), np.array([result.x]), len(grid) + int(result.nfev)
    return float(values[i]), np.array([grid[i]]), len(grid) + int(result.nfev)


def _search(
    objective: Callable[[np.ndarray], np.ndarray],
    start: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    seed: int,
    max_evals: int,
    progress: bool,
) -> tuple[float, np.ndarray, int]:
    """Minimise over a box: :func:`_minimize_scalar` for one parameter, else CMA-ES (the
    population of ``POPULATION`` evaluated in one call). Returns (value, point, evaluations)."""
    if len(start) == 1:
        return _minimize_scalar(objective, float(lower[0]), float(upper[0]), max_evals)
    result = minimize_cmaes(
        objective,
        start,
        lower=lower,
        upper=upper,
        seed=seed,
        options=CMAESOptions(sigma0=0.2, max_evals=max_evals, popsize=POPULATION),
        progress=progress,
    )
    return float(result.f_best), np.asarray(result.x_best, dtype=float), result.evaluations


def _parabola(points: np.ndarray, values: np.ndarray, best: int) -> tuple[float, float]:
    """Vertex and standard deviation of a negative log density sampled on a 1-D grid.

    The parabola through the best point and its two neighbours; the sd is the inverse square
    root of its curvature. At an edge of the grid (or without curvature): the best point and
    NaN.
    """
    if best == 0 or best == len(points) - 1:
        return float(points[best]), float("nan")
    x, y = points[best - 1 : best + 2], values[best - 1 : best + 2]
    a, b, _ = np.polyfit(x, y, 2)
    if not a > 0:
        return float(points[best]), float("nan")
    return float(np.clip(-b / (2 * a), x[0], x[2])), float(1.0 / np.sqrt(2.0 * a))


#: magnitudes of a gain's profile grid, as fractions of its box (both signs and 0 are tried)
_GAIN_GRID = np.geomspace(1e-3, 1.0, 25)


def _channel_lpd(
    spectra: Spectra, model: Float[np.ndarray, "run freq"], runs: np.ndarray, channel: int
) -> float:
    """Training log predictive density of one channel's model spectra (its discrepancy
    estimated on that channel alone, as :func:`_profile_lpd` estimates every channel's)."""
    return float(_channel_lpds(spectra, model[None], runs, channel)[0])


def _channel_lpds(
    spectra: Spectra, models: Float[np.ndarray, "row run freq"], runs: np.ndarray, channel: int
) -> Float[np.ndarray, " row"]:
    """:func:`_channel_lpd` of every row of ``models`` in one pass.

    The discrepancy's estimate treats each channel on its own, so the rows stand on the
    channel axis of one estimate, and each row's density is its own channel's sum: the same
    arithmetic in the same order as one row at a time.
    """
    rows = models.shape[0]
    y1 = spectra.measured[runs][:, channel : channel + 1]
    lv = spectra.log_variance[runs]
    local = None
    if spectra.local is not None:
        local = np.repeat(spectra.local[channel : channel + 1], rows, axis=0)
    stacked = np.moveaxis(models, 0, 1)  # (run, row, freq): each row a channel
    disc = estimate_discrepancy(stacked, np.repeat(y1, rows, axis=1), lv, SMOOTH_BINS, local=local)
    # back to one channel per row, the rows as a leading population axis
    per_row = Discrepancy(
        smooth=disc.smooth[:, None, None, :], variance=disc.variance[:, None, None, :]
    )
    return log_predictive(models[:, :, None, :], y1, lv, per_row).sum(axis=1)


def _profile_gain(
    spectra: Spectra,
    power: Float[np.ndarray, "3 run freq"],
    runs: Int[np.ndarray, " r"],
    channel: int,
    box: tuple[float, float],
) -> tuple[float, float]:
    """The gain s of one channel that maximises its training density, and that density.

    ``power`` holds the linear Welch PSDs of O, O + P and O - P of the channel's runs. The
    density is profiled over a grid of both signs (magnitudes log-spaced over the box, so a
    faint mode and a strong one are both resolved), refined by a bounded Brent search
    between the best point's neighbours.
    """
    a = power[0]
    b = (power[1] - power[2]) / 4.0
    c = (power[1] + power[2]) / 2.0 - a
    tiny = np.finfo(float).tiny

    def lpd(s: float) -> float:
        m = np.log10(np.maximum(a + 2.0 * s * b + s * s * c, tiny))
        return _channel_lpd(spectra, m, runs, channel)

    lo, hi = box
    grid = np.unique(
        np.clip(np.concatenate([-hi * _GAIN_GRID[::-1], [0.0], hi * _GAIN_GRID]), lo, hi)
    )
    grid = np.unique(np.concatenate([grid, np.clip(-lo * _GAIN_GRID, lo, hi)]))
    curves = a[None] + 2.0 * grid[:, None, None] * b[None] + grid[:, None, None] ** 2 * c[None]
    values = _channel_lpds(spectra, np.log10(np.maximum(curves, tiny)), runs, channel)
    i = int(np.argmax(values))
    left, right = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    if right > left:
        found = scipy.optimize.minimize_scalar(
            lambda s: -lpd(s),
            bounds=(left, right),
            method="bounded",
            options={"xatol": 1e-4 * (hi - lo)},
        )
        if -found.fun > values[i]:
            return float(found.x), float(-found.fun)
    return float(grid[i]), float(values[i])


def _gains_objective(
    problem: _Problem, search: list[int], profiles: dict[tuple[float, ...], dict[str, float]]
) -> Callable[[np.ndarray], np.ndarray]:
    """The negative training density of the searched parameters (rows of ``x``), each
    channel's gain profiled (:func:`_profile_gain`); each row's gains go to ``profiles``."""
    setup, proposal, model, train = problem.setup, problem.proposal, problem.model, problem.train
    free = model.free
    channels = list(setup.system.channels)

    def objective(x: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(x)
        full = np.zeros((len(x), len(free)))
        full[:, search] = x
        out = np.full(len(x), np.inf)
        admitted = np.flatnonzero(_admissible_rows(setup, proposal, model, full))
        if admitted.size == 0:
            return out
        off, slope = model.solve_gains(
            model.values(full[admitted], len(train)), train, list(proposal.gains)
        )
        power = 10.0 ** setup.spectra.model(
            np.stack([off, off + slope, off - slope], axis=1), train
        )
        # power's row r is the candidate x[admitted[r]]: its value goes to that candidate's row
        for r, (at, row) in enumerate(zip(admitted, x[admitted], strict=True)):
            if not np.all(np.isfinite(power[r])):
                continue
            total, gains = _profiled_channels(problem, power[r], channels)
            profiles[tuple(map(float, row))] = gains
            out[at] = -total
        return out

    return objective


def _profiled_channels(
    problem: _Problem, power: Float[np.ndarray, "3 run channel freq"], channels: list[str]
) -> tuple[float, dict[str, float]]:
    """The training density of one candidate, summed over channels, each gained channel's
    gain profiled (:func:`_profile_gain`); and those gains."""
    spectra, free, train = problem.setup.spectra, problem.model.free, problem.train
    total, gains = 0.0, {}
    for k, channel in enumerate(channels):
        names = [n for n, c in problem.proposal.gains.items() if c == channel]
        if names:
            i = free.index(names[0])
            s, value = _profile_gain(
                spectra,
                power[:, :, k],
                train,
                k,
                (float(problem.lower[i]), float(problem.upper[i])),
            )
            gains[names[0]] = s
        else:
            value = _channel_lpd(spectra, np.log10(power[0][:, k]), train, k)
        total += value
    return total, gains


def _refit_with_gains(
    problem: _Problem, *, seed: int, max_evals: int, options: RefitOptions
) -> RefitResult:
    """:func:`refit_extension` for a solved extension whose proposal names ``gains``."""
    setup, proposal, model = problem.setup, problem.proposal, problem.model
    free = model.free
    channels = list(setup.system.channels)
    unknown = {n: c for n, c in proposal.gains.items() if n not in free or c not in channels}
    if unknown:
        raise ValueError(
            f"the proposal's gains {unknown} must map free parameters to the system's "
            f"channels {channels}"
        )
    gained = [free.index(n) for n in proposal.gains]
    search = [i for i in range(len(free)) if i not in gained]
    profiles: dict[tuple[float, ...], dict[str, float]] = {}
    objective = _gains_objective(problem, search, profiles)
    lower, upper = problem.lower[search], problem.upper[search]
    _, x_best, evaluations = _search(
        objective, problem.start()[search], lower, upper, seed + 1, max_evals, options.progress
    )
    key = tuple(map(float, x_best))
    if key not in profiles:
        objective(x_best[None])
    if key not in profiles:
        raise ValueError(
            f"no candidate of {proposal.label or proposal.extension!r} inside its search boxes "
            "and constraint could be simulated"
        )
    optimum = np.empty(len(free))
    optimum[search] = x_best
    for n, s in profiles[key].items():
        optimum[free.index(n)] = s
    sd = np.full(len(free), np.nan)
    if options.uncertainty:
        sd[search] = _laplace_sd(objective, x_best, lower, upper, np.random.default_rng(seed))
        evaluations += _laplace_evaluations(len(search))
    every = np.arange(len(setup.operating))
    spectra = setup.spectra.model(
        model.solve(model.values(optimum[None], len(every)), every)[0], every
    )
    return _result(problem, optimum, sd, spectra, evaluations)


def refit_extension(
    setup: RefitSetup,
    proposal: ExtensionProposal,
    train: Int[np.ndarray, " run"],
    *,
    seed: int,
    max_evals: int,
    bases: dict[tuple[float, ...], np.ndarray] | None = None,
    options: RefitOptions = RefitOptions(),
) -> RefitResult:
    """Fit one extension's free parameters on the training runs (base parameters held).

    The objective is the training runs' log predictive density with the extended model's
    discrepancy estimated on the same runs (:func:`estimate_discrepancy`), maximised by
    CMA-ES from the proposal's start within its search boxes. For an extension that needs a
    new solve and names its linear parameters, the signals are the base signals plus the
    scaled signal change of each linear parameter (one solve of every run per linear
    parameter and grid point), CMA-ES fits the linear parameters at every grid point of the
    others, the best point is refined by a parabola (its curvature gives the sd), and the
    extended model is then solved exactly at the optimum: the spectra returned (and judged)
    are the exact ones.

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
        CMA-ES budget (per grid point).
    bases
        A cache of the linear signal changes, shared by refits of one proposal on one setup.
    options
        The uncertainty, the progress bar, the exact solve at the optimum and the threads
        (:class:`RefitOptions`).

    Returns
    -------
    RefitResult
    """
    extended, _, lower, upper, fixed = _boxes(setup.system, proposal)
    model = _Model(
        setup, proposal, extended, fixed, {} if bases is None else bases, options.workers
    )
    problem = _Problem(setup, proposal, model, lower, upper, np.asarray(train, dtype=int))
    if proposal.gains and not model.output_only:
        return _refit_with_gains(problem, seed=seed, max_evals=max_evals, options=options)
    return _refit_on_grid(problem, seed=seed, max_evals=max_evals, options=options)


def _grid_objective(
    problem: _Problem, search: list[int], point: Mapping[str, float]
) -> Callable[[np.ndarray], np.ndarray]:
    """The negative training density of the searched parameters (rows of ``x``), the gridded
    ones at ``point``, the discrepancy profiled (:func:`_profile_lpd`)."""
    setup, proposal, model, train = problem.setup, problem.proposal, problem.model, problem.train
    free = model.free

    def objective(x: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(x)
        full = np.empty((len(x), len(free)))
        full[:, search] = x
        for n, v in point.items():
            full[:, free.index(n)] = v
        out = np.full(len(x), np.inf)
        admitted = _admissible_rows(setup, proposal, model, full)
        if admitted.any():
            spectra = _batched(model, setup.spectra, full[admitted], train)
            out[admitted] = -_profile_lpd(setup.spectra, spectra, train)
        return out

    return objective


def _refit_on_grid(
    problem: _Problem, *, seed: int, max_evals: int, options: RefitOptions
) -> RefitResult:
    """:func:`refit_extension` searching the other parameters at every grid point of the
    gridded ones (a surrogate's nonlinear parameters; none: one search)."""
    setup, model = problem.setup, problem.model
    free = model.free
    gridded = model.nonlinear if model.surrogate else []
    search = [i for i, n in enumerate(free) if n not in gridded]
    lower, upper = problem.lower[search], problem.upper[search]
    grid = list(itertools.product(*(problem.proposal.grid[n] for n in gridded))) or [()]
    outcomes = []
    evaluations = 0
    for g_index, point in enumerate(grid):
        objective = _grid_objective(problem, search, dict(zip(gridded, point, strict=True)))
        f_best, x_best, spent = _search(
            objective,
            problem.start()[search],
            lower,
            upper,
            seed + 1 + g_index,
            max_evals,
            options.progress,
        )
        evaluations += spent
        outcomes.append((f_best, x_best, point))
    values_f = np.array([o[0] for o in outcomes])
    best = int(np.argmin(values_f))
    _, x_search, point = outcomes[best]
    optimum = np.empty(len(free))
    optimum[search] = x_search
    sd = np.full(len(free), np.nan)
    for n, v in zip(gridded, point, strict=True):
        optimum[free.index(n)] = v
    if len(gridded) == 1:
        axis = np.array([p[0] for p in grid])
        refined, sd_grid = _parabola(axis, values_f, best)
        optimum[free.index(gridded[0])] = refined
        sd[free.index(gridded[0])] = sd_grid
    if options.uncertainty and search:
        objective = _grid_objective(problem, search, dict(zip(gridded, point, strict=True)))
        sd[search] = _laplace_sd(objective, x_search, lower, upper, np.random.default_rng(seed))
        evaluations += _laplace_evaluations(len(search))
    every = np.arange(len(setup.operating))
    spectra = _batched(model, setup.spectra, optimum[None], every, exact=options.exact)[0]
    return _result(problem, optimum, sd, spectra, evaluations)


def _exact_values(
    setup: RefitSetup,
    proposal: ExtensionProposal,
    values: Mapping[str, Float[np.ndarray, " r"]],
    runs: Int[np.ndarray, " r"],
) -> tuple[_Model, dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """The model of :func:`exact_signals`, its values (1, run) with ``runs`` in ascending
    order, those runs, and the order that puts them back."""
    extended, free, _, _, fixed = _boxes(setup.system, proposal)
    model = _Model(setup, proposal, extended, fixed, {})
    runs = np.asarray(runs, dtype=int)
    missing = [n for n in free if n not in values]
    if missing:
        raise ValueError(f"values lacks the free parameters {missing} of the proposal")
    # the runs in ascending order, so that a campaign's runs simulated together sit where the
    # base signals had them (a simulator may draw its randomness by position in the batch)
    order = np.argsort(runs, kind="stable")
    back = np.argsort(order, kind="stable")
    runs = runs[order]
    vals = {k: np.full((1, len(runs)), v) for k, v in fixed.items()}
    vals.update(
        {n: np.asarray(values[n], dtype=float).reshape(1, len(runs))[:, order] for n in free}
    )
    return model, vals, runs, back


def exact_signals(
    setup: RefitSetup,
    proposal: ExtensionProposal,
    values: Mapping[str, Float[np.ndarray, " r"]],
    runs: Int[np.ndarray, " r"],
) -> Float[np.ndarray, "r channel time"]:
    """The extended model's exact signals of ``runs``, each run at its own parameter values
    (one simulation of all the runs together; the signals of :func:`exact_spectra`)."""
    model, vals, runs, back = _exact_values(setup, proposal, values, runs)
    extended = model.extended
    if model.output_only:
        base = setup.base_signals[runs][None]
        signals = np.asarray(
            extended.apply_output_extensions(
                jnp.asarray(base),
                jnp.asarray(setup.time),
                {k: jnp.asarray(v) for k, v in vals.items()},
            )
        )
    else:
        signals = model.solve(vals, runs)
    return signals[0][back]


def exact_spectra(
    setup: RefitSetup,
    proposal: ExtensionProposal,
    values: Mapping[str, Float[np.ndarray, " r"]],
    runs: Int[np.ndarray, " r"],
) -> Float[np.ndarray, "r channel freq"]:
    """The extended model's exact spectra of ``runs``, each run at its own parameter values.

    One simulation of all the runs together (for an extension that needs a solve: one
    vectorised solve), so that the held-out runs of several folds, each at the values fitted
    without it, cost one solve of the campaign.

    Parameters
    ----------
    setup
        The campaign's shared pieces.
    proposal
        The extension.
    values
        Per free parameter of ``proposal``, its value for each of ``runs``.
    runs
        The runs (indices into the setup's runs).

    Returns
    -------
    spectra
        log10 PSDs of the runs, as :meth:`Spectra.model` gives them (for a proposal tested
        on the measured signals, as ``ExtensionProposal.on_measured`` makes them).
    """
    runs = np.asarray(runs, dtype=int)
    if proposal.on_measured:
        model, vals, ordered, back = _exact_values(setup, proposal, values, runs)
        return model.measured_spectra(vals, ordered)[0][back]
    return setup.spectra.model(exact_signals(setup, proposal, values, runs), runs)
