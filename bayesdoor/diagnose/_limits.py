"""What a campaign could not have shown: each catalogue cause's detection limit.

A cause hidden at size ``s`` changes the base model's log10 spectra by ``Delta(s)`` (the
extension simulated at ``s`` on the campaign's runs, against the base model at the fit's
point). In a bin with Welch variance ``w`` (the measured run's) and model error ``e^2`` (the
base model's scatter, :func:`~bayesdoor.diagnose._gain.estimate_discrepancy`), ``v = w + e^2``,
the held-out log density of the extension at the truth exceeds the base model's, whose scatter
in the changed bins the judgement estimates as ``v_b = v + mean(Delta^2)`` (per channel), by

    m = log(v_b / v) / 2 + (Delta^2 + v) / (2 v_b) - 1/2        (expectation)
    q = Delta^2 v / v_b^2 + (1 - v / v_b)^2 / 2                  (variance)

summed over the bins the extension changes (:func:`~bayesdoor.diagnose._gain.changed_bins`;
``Delta`` less its broad part, which each model's smooth discrepancy takes alike). The refit
does not know the cause's values: it fits its ``p`` free parameters on the other fold's runs,
which costs each held-out run ``c_r / 2`` of its difference and adds ``kappa c_r`` to its
variance, ``c_r`` drawn per fold from the estimate's sandwich covariance
(:mod:`~bayesdoor.diagnose._design`: ``kappa p / 2`` per fold in expectation, ``kappa`` the
Welch bins' correlation factor, :func:`bin_variance_factor`). The per-run differences are
drawn so and judged by the decision rule itself (:func:`~bayesdoor.diagnose.rule_passes`'
statistics and thresholds): the share named is the power at ``s``; the limit is the smallest
``s`` with power at least :data:`LIMIT_POWER`. Beside each limit, the campaign that would
name the cause at :data:`PLAN_FACTOR` times it (:func:`~bayesdoor.diagnose._design.
design_campaign`, as :func:`~bayesdoor.diagnose.plan_campaign` plans).

A cause tested on the measured signals (``ExtensionProposal.on_measured``: a sensor's
leak) is sized on them too: ``Delta`` is the change the cause would make to the measured runs.

What it leaves out: the residual features must show the cause before it is refitted (the
signature's gate), the base fit may absorb part of a cause, and the base model may carry the
cause to the sensors other than the system does (the computation takes the model's
``Delta`` for the truth); the first two only lower the power, the third either way
(``results/diagnosis_limits.md`` measures it on the rig). The third is what a cause's
:class:`~bayesdoor.diagnose.Transmission` states, measured across a family of machines
(:func:`read_transmission`): the family limit divides the model limit by the smallest ratio.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from .._types import Float
from ..features import LOG_FLOOR
from ._design import (
    FOLDS,
    CampaignPlan,
    PlanTarget,
    RunGains,
    design_campaign,
    estimation_cost,
    fold_labels,
    naming_probability,
)
from ._gain import changed_bins, estimate_discrepancy
from ._rank import Catalogue
from ._refit import (
    SMOOTH_BINS,
    CauseSize,
    RefitSetup,
    SizeProbe,
    _boxes,
    exact_signals,
)
from ._residual import smooth_discrepancy
from ._transmission import Transmission

#: the probability of naming a cause that defines its detection limit
LIMIT_POWER = 0.8
#: the smallest PSD a size's spectra take (the features' floor of a log10 PSD)
_PSD_FLOOR = LOG_FLOOR
#: sizes scanned per configuration (log-spaced over the cause's declared range)
_GRID = 33
#: the size, as a multiple of a cause's limit, that the campaign beside the limit is planned
#: for: the campaign that would see a cause half the size these runs can
PLAN_FACTOR = 0.5


@dataclasses.dataclass(frozen=True)
class PowerCurve:
    """The probability that the decision rule names a cause, against its size, in one
    configuration of its other parameters.

    Attributes
    ----------
    label
        The configuration (:class:`SizeProbe`'s).
    sizes
        The sizes scanned, in the cause's unit.
    probability
        The share of draws the rule names at each size.
    evidence
        The expected held-out gain in standard errors at each size.
    limit
        The smallest size named with the stated power (interpolated in log size); ``None``
        when no size of the range reaches it.
    """

    label: str
    sizes: Float[np.ndarray, " size"]
    probability: Float[np.ndarray, " size"]
    evidence: Float[np.ndarray, " size"]
    limit: float | None

    def at(self, size: float) -> float:
        """The probability of naming at ``size`` (interpolated in log size; 0 below the
        range, the last value above)."""
        if size <= 0 or size < self.sizes[0]:
            return 0.0
        return float(np.interp(np.log(size), np.log(self.sizes), self.probability))


@dataclasses.dataclass(frozen=True)
class CauseLimit:
    """A cause's detection limit in one campaign.

    Attributes
    ----------
    cause
        The catalogue name.
    quantity, unit, display
        The size (:class:`CauseSize`'s).
    power
        The probability of naming that defines the limit.
    runs
        The held-out runs the rule would judge.
    curves
        One power curve per configuration, the typical one first.
    plan
        The campaign that would name the cause at :data:`PLAN_FACTOR` times its limit in the
        typical configuration, its family limit where it has one (``None``: not planned, or
        no limit in the range).
    transmission
        How a family of machines transmits the cause against the model (the cause's
        declared :class:`Transmission`; ``None``: not measured).
    """

    cause: str
    quantity: str
    unit: str
    display: tuple[str, float]
    power: float
    runs: int
    curves: tuple[PowerCurve, ...]
    plan: CampaignPlan | None = None
    transmission: Transmission | None = None

    @property
    def size(self) -> float | None:
        """The typical configuration's limit if the model transmits the cause as the
        machine does (``None``: above the scanned range)."""
        return self.curves[0].limit

    @property
    def family(self) -> float | None:
        """The typical configuration's limit on every machine of the family the cause's
        transmission was measured on: the model limit over the smallest ratio (``None``:
        no model limit, no transmission measured, or one the model does not reproduce). The
        least-transmitting machine shows a cause at the family limit as the model shows one
        at the model limit, so the refit reaches it wherever it reaches the model limit."""
        ratio = None if self.transmission is None else self.transmission.ratio
        if self.size is None or ratio is None:
            return None
        return self.size / ratio

    @property
    def worst(self) -> float | None:
        """The largest limit over the configurations (``None``: one is above its range)."""
        limits = [c.limit for c in self.curves]
        return None if any(v is None for v in limits) else max(limits)  # type: ignore[type-var]

    def shown(self, size: float | None) -> str:
        """A size in the display unit, in words."""
        if size is None:
            top = self.curves[0].sizes[-1]
            return f"above {top * self.display[1]:.3g} {self.display[0] or self.unit}"
        return f"{size * self.display[1]:.3g} {self.display[0] or self.unit}"

    def describe(self) -> str:
        """The limit in words."""
        words = (
            f"{self.cause}: a {self.quantity} under {self.shown(self.size)} "
            f"({self.curves[0].label}) would not be named with {100 * self.power:.0f} % "
            f"probability in these {self.runs} runs"
        )
        if len(self.curves) > 1:
            words += "; " + ", ".join(f"{c.label}: {self.shown(c.limit)}" for c in self.curves[1:])
        t = self.transmission
        if t is not None and self.size is not None:
            if self.family is None:
                words += f"; across the family of machines, no limit: {t.describe()}"
            else:
                words += (
                    f"; across the family of machines, under {self.shown(self.family)} "
                    f"({t.describe()})"
                )
        return words

    def to_json(self) -> dict[str, Any]:
        return {
            "quantity": self.quantity,
            "unit": self.unit,
            "power": self.power,
            "size": self.size,
            "worst": self.worst,
            "runs": self.runs,
            "configurations": [
                {
                    "label": c.label,
                    "size": c.limit,
                    "sizes": c.sizes.tolist(),
                    "probability": c.probability.tolist(),
                    "evidence_se": c.evidence.tolist(),
                }
                for c in self.curves
            ],
            "family_size": self.family,
            "transmission": None
            if self.transmission is None
            else {
                **dataclasses.asdict(self.transmission),
                "reliable": self.transmission.reliable,
            },
            "words": self.describe(),
            "plan": None if self.plan is None else self.plan.to_json(),
        }


@dataclasses.dataclass(frozen=True)
class _Noise:
    """The per-bin variance a change is judged against: Welch's plus the model error, and the
    neighbouring bins' correlation."""

    base: np.ndarray
    variance: np.ndarray
    correlation: float


def _noise(setup: RefitSetup) -> _Noise:
    spectra = setup.spectra
    base = setup.base_spectra
    error = estimate_discrepancy(
        base, spectra.measured, spectra.log_variance, SMOOTH_BINS, local=spectra.local
    ).variance
    return _Noise(
        base,
        np.asarray(spectra.log_variance)[:, None, None] + error[None],
        bin_variance_factor(spectra.nperseg),
    )


def bin_variance_factor(nperseg: int, window: str = "hann") -> float:
    """How much more variance a sum over neighbouring bins of a Welch spectrum has than the
    same sum over independent bins: ``1 + 2 sum_k rho_k^2`` for the correlation ``rho_k`` of
    the window's DFT coefficients ``k`` bins apart (white noise; Hann: 2/3 and 1/6, so 1.94).
    The log-density difference's noise part is summed over the bins an extension changes,
    mostly contiguous."""
    import scipy.signal

    h2 = scipy.signal.get_window(window, nperseg) ** 2
    n = np.arange(nperseg)
    rho = [abs(np.sum(h2 * np.exp(-2j * np.pi * k * n / nperseg))) / np.sum(h2) for k in (1, 2, 3)]
    return float(1.0 + 2.0 * np.sum(np.square(rho)))


def expected_differences(
    base: Float[np.ndarray, "run channel freq"],
    extended: Float[np.ndarray, "run channel freq"],
    variance: Float[np.ndarray, "run channel freq"],
    welch: Float[np.ndarray, " run"],
    parameters: int,
    correlation: float = 1.0,
    smooth_bins: int | None = SMOOTH_BINS,
) -> tuple[Float[np.ndarray, " run"], Float[np.ndarray, " run"]]:
    """Mean and variance of each run's held-out log-density difference when ``extended`` is
    the truth (the module's formulas), the variance times ``correlation``
    (:func:`bin_variance_factor`); ``parameters`` fitted on the other half of the runs cost
    the mean their expectation, ``correlation p / n`` per run (:mod:`~bayesdoor.diagnose.
    _design`; the power draws it instead, with ``parameters=0`` here).

    Each model is judged with its own smooth discrepancy (the running median over
    ``2 smooth_bins + 1`` bins of its run-mean residual), which takes the broad part of a
    change into both models alike: the change that tells them apart is ``Delta`` less the
    running median of its run mean (``None``: the whole change)."""
    delta = np.asarray(extended) - np.asarray(base)
    if smooth_bins is not None:
        delta = _detrended(delta, smooth_bins)
    changed = changed_bins(base, extended, welch)
    d2 = np.where(changed, delta**2, 0.0)
    count = np.maximum(changed.sum(axis=(0, 2), keepdims=True), 1)
    v = variance
    vb = v + d2.sum(axis=(0, 2), keepdims=True) / count
    m = np.where(changed, 0.5 * np.log(vb / v) + 0.5 * (d2 + v) / vb - 0.5, 0.0)
    q = np.where(changed, d2 * v / vb**2 + 0.5 * (1.0 - v / vb) ** 2, 0.0)
    n = base.shape[0]
    return m.sum(axis=(1, 2)) - correlation * parameters / n, correlation * q.sum(axis=(1, 2))


def information(
    spectra: Callable[[float], Float[np.ndarray, "run channel freq"]],
    size: float,
    base: Float[np.ndarray, "run channel freq"],
    variance: Float[np.ndarray, "run channel freq"],
    welch: Float[np.ndarray, " run"],
    smooth_bins: int | None = SMOOTH_BINS,
) -> Float[np.ndarray, " run"]:
    """Each run's information about the size at ``size``: ``sum J^2 / v`` over the bins the
    extension changes, ``J`` the derivative of its log10 spectra in the size (central, 1 %
    of the size; less the running median of its run mean, as ``Delta`` in
    :func:`expected_differences`)."""
    step = 0.01 * float(size)
    up, down = spectra(float(size) + step), spectra(float(size) - step)
    slope = (up - down) / (2.0 * step)
    if smooth_bins is not None:
        slope = _detrended(slope, smooth_bins)
    changed = changed_bins(base, spectra(float(size)), welch)
    return np.where(changed, slope**2 / variance, 0.0).sum(axis=(1, 2))


def _detrended(delta: np.ndarray, smooth_bins: int = SMOOTH_BINS) -> np.ndarray:
    """A change (run, channel, bin) less the running median over ``2 smooth_bins + 1`` bins
    of its run mean: the part each model's smooth discrepancy takes alike."""
    return delta - smooth_discrepancy(delta.mean(axis=0), smooth_bins)


def _evidence(mean: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """The expected held-out gain in standard errors: the sum of the means over the standard
    error the rule would see (the runs' spread of means and their own variance)."""
    n = mean.shape[-1]
    spread = variance.mean(axis=-1) + mean.var(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(spread > 0, mean.sum(axis=-1) / np.sqrt(n * spread), 0.0)


def _limit(sizes: np.ndarray, probability: np.ndarray, power: float) -> float | None:
    above = np.flatnonzero(probability >= power)
    if above.size == 0:
        return None
    i = int(above[0])
    if i == 0:
        return float(sizes[0])
    x0, x1 = np.log(sizes[i - 1]), np.log(sizes[i])
    p0, p1 = probability[i - 1], probability[i]
    w = (power - p0) / (p1 - p0) if p1 > p0 else 1.0
    return float(np.exp(x0 + w * (x1 - x0)))


def _on_measured(setup: RefitSetup, probe: SizeProbe) -> bool:
    """Whether the probe's cause is sized on the measured signals, as it is tested
    (``ExtensionProposal.on_measured``; a setup without them: on the model's)."""
    return probe.proposal.on_measured and setup.measured_signals is not None


def probe_changes(
    setup: RefitSetup, probe: SizeProbe
) -> tuple[Float[np.ndarray, "run channel time"], Float[np.ndarray, "run channel time"]]:
    """The probe's signals at size 0 and their change per unit size (one simulation, two
    when the extension at size 0 is not the base model). A cause tested on the measured
    signals acts on them here too: its signals at size 0 are the measured runs."""
    n = len(setup.operating)
    runs = np.arange(n)
    if setup.measured_signals is not None and probe.proposal.on_measured:
        setup = dataclasses.replace(setup, base_signals=setup.measured_signals)
    elif probe.proposal.on_measured:
        probe = dataclasses.replace(
            probe, proposal=dataclasses.replace(probe.proposal, on_measured=False)
        )
    if probe.off_at_zero:
        zero = np.asarray(setup.base_signals)
    else:
        zero = exact_signals(setup, probe.proposal, probe.values(0.0, n), runs)
    at = exact_signals(setup, probe.proposal, probe.values(probe.reference, n), runs)
    return zero, (at - zero) / probe.reference


def size_spectra(
    setup: RefitSetup, probe: SizeProbe
) -> Callable[[float], Float[np.ndarray, "run channel freq"]]:
    """The probe's log10 spectra of every run as a function of its size, from one simulation
    and three Welch estimates: the signals are ``z + s c`` and a Welch PSD is quadratic in
    the signal, so ``P(s) = P(z) + u (P(z + r c) - P(z - r c)) / 2 + u^2 ((P(z + r c) +
    P(z - r c)) / 2 - P(z))`` with ``u = s / r`` exactly (``r`` the probe's reference).

    A cause tested on the measured signals (``ExtensionProposal.on_measured``) is sized as
    it is tested: ``z`` the measured runs, the spectra the base model's plus ``log P(s) -
    log P(0)``, the change the cause at ``s`` would make to what was measured."""
    zero, per_unit = probe_changes(setup, probe)
    runs = np.arange(len(setup.operating))
    r = probe.reference
    p0, up, down = (
        10.0 ** setup.spectra.model(x, runs)
        for x in (zero, zero + r * per_unit, zero - r * per_unit)
    )
    linear, quadratic = (up - down) / 2.0, (up + down) / 2.0 - p0
    offset: float | np.ndarray = 0.0
    if _on_measured(setup, probe):
        offset = setup.base_spectra - np.log10(np.maximum(p0, _PSD_FLOOR))

    def at(size: float) -> np.ndarray:
        u = float(size) / r
        return offset + np.log10(np.maximum(p0 + u * linear + u * u * quadratic, _PSD_FLOOR))

    return at


def run_gains(
    setup: RefitSetup,
    probe: SizeProbe,
    size: float,
    *,
    noise: _Noise | None = None,
    spectra: Callable[[float], np.ndarray] | None = None,
) -> RunGains:
    """Each run's expected held-out difference at ``size`` with the probe's extension at its
    true values, its variance and its information about the size."""
    noise = _noise(setup) if noise is None else noise
    spectra = size_spectra(setup, probe) if spectra is None else spectra
    welch = np.asarray(setup.spectra.log_variance)
    m, q = expected_differences(
        noise.base, spectra(float(size)), noise.variance, welch, 0, noise.correlation
    )
    h = information(spectra, float(size), noise.base, noise.variance, welch)
    return RunGains(m, q, h, len(probe.proposal.free), noise.correlation)


def fold_order(setup: RefitSetup) -> np.ndarray:
    """What the judgement's folds sort the runs by: their speeds, else operating points."""
    return np.asarray(setup.operating if setup.speeds is None else setup.speeds, dtype=float)


def power_curve(
    setup: RefitSetup,
    probe: SizeProbe,
    sizes: Float[np.ndarray, " size"],
    *,
    power: float = LIMIT_POWER,
    normals: Float[np.ndarray, "draw run"],
    chi2: Float[np.ndarray, "draw fold"] | None = None,
    noise: _Noise | None = None,
    spectra: Callable[[float], np.ndarray] | None = None,
) -> PowerCurve:
    """The probability that the rule names the probe's cause at each size, in these runs,
    its free parameters refitted on the other fold (``chi2``: the estimate's ``chi2_p``
    draws per fold, ``p`` the probe's free parameters; ``None``: judged at the truth)."""
    noise = _noise(setup) if noise is None else noise
    spectra = size_spectra(setup, probe) if spectra is None else spectra
    gains = [run_gains(setup, probe, float(s), noise=noise, spectra=spectra) for s in sizes]
    mean = np.array([g.mean for g in gains])
    var = np.array([g.variance for g in gains])
    kappa = noise.correlation
    if chi2 is None:
        cost, expected = None, np.zeros_like(mean)
    else:
        folds = fold_labels(fold_order(setup))
        h = np.array([g.information for g in gains])
        cost = estimation_cost(h, folds, chi2, kappa)
        expected = estimation_cost(h, folds, np.full((1, chi2.shape[1]), chi2.mean()), kappa)
        expected = expected[..., 0, :]
    probability = naming_probability(mean, var, normals, cost, kappa)
    return PowerCurve(
        label=probe.label,
        sizes=np.asarray(sizes, dtype=float),
        probability=probability,
        evidence=_evidence(mean - expected / 2.0, var + kappa * expected),
        limit=_limit(np.asarray(sizes, dtype=float), probability, power),
    )


def reachable(setup: RefitSetup, probe: SizeProbe) -> float:
    """The largest size whose free parameters (``probe.scales`` times the size) lie inside
    the extension's parameter bounds and the proposal's boxes: the largest size the refit
    can reach."""
    _, free, lower, upper, _ = _boxes(setup.system, probe.proposal)
    out = np.inf
    for name, lo, hi in zip(free, lower, upper, strict=True):
        scale = float(probe.scales.get(name, 0.0))
        if scale > 0:
            out = min(out, hi / scale)
        elif scale < 0:
            out = min(out, lo / scale)
    return float(out)


def cause_sizes(catalogue: Catalogue, band: tuple[float, float]) -> dict[str, CauseSize]:
    """Every catalogue cause that declares its size (its recipe's
    :meth:`~bayesdoor.diagnose.AbstractRefit.size`), by name."""
    out = {}
    for c in catalogue.candidates:
        size = None if c.refit is None else c.refit.size(band=band)
        if size is not None:
            out[c.name] = size
    return out


@dataclasses.dataclass(frozen=True)
class _Scan:
    """What every cause's scan shares: the power that defines a limit, the Monte Carlo draws
    and their seed, the standard normals drawn per run, and the noise."""

    power: float
    draws: int
    seed: int
    normals: np.ndarray
    noise: _Noise


def _declared_sizes(
    setup: RefitSetup,
    catalogue: Catalogue,
    causes: tuple[str, ...] | None,
    band: tuple[float, float] | None,
) -> dict[str, CauseSize]:
    """The declared sizes of the causes asked for (``band`` ``None``: the spectra's own)."""
    freqs = setup.spectra.freqs
    band = (float(freqs[0]), float(freqs[-1])) if band is None else band
    declared = cause_sizes(catalogue, band)
    if causes is not None:
        declared = {k: v for k, v in declared.items() if k in causes}
    return declared


def _cause_curves(
    setup: RefitSetup, size: CauseSize, scan: _Scan
) -> tuple[tuple[PowerCurve, ...], Callable[[float], np.ndarray] | None]:
    """A cause's power curve in each configuration, and its typical configuration's spectra
    as a function of size. Each configuration is scanned up to the largest size its refit
    can reach (:func:`reachable`): a cause larger than the extension's parameters allow
    cannot be refitted at its size, so no limit is stated beyond it."""
    curves, typical = [], None
    for probe in size.probes:
        high = min(size.high, reachable(setup, probe))
        sizes = np.geomspace(size.low, max(high, 1.01 * size.low), _GRID)
        spectra = size_spectra(setup, probe)
        typical = spectra if typical is None else typical
        p = len(probe.proposal.free)
        curves.append(
            power_curve(
                setup,
                probe,
                sizes,
                power=scan.power,
                normals=scan.normals,
                chi2=_chi2(p, scan.draws, scan.seed),
                noise=scan.noise,
                spectra=spectra,
            )
        )
    return tuple(curves), typical


def _plan(
    setup: RefitSetup,
    name: str,
    size: CauseSize,
    target: float,
    typical: Callable[[float], np.ndarray] | None,
    scan: _Scan,
) -> CampaignPlan:
    """The campaign that would name the cause at size ``target`` in its typical
    configuration, on every machine of its family where it declares a transmission the
    model reproduces (designed for what the least-transmitting machine shows of it)."""
    ratio = None if size.transmission is None else size.transmission.ratio
    designed = target * (1.0 if ratio is None else ratio)
    plan = design_campaign(
        run_gains(setup, size.probes[0], designed, noise=scan.noise, spectra=typical),
        np.asarray(setup.operating, dtype=float),
        fold_order(setup),
        target=PlanTarget(name, target, size.unit, size.probes[0].label, display=size.display),
        power=scan.power,
        record_s=setup.duration,
        draws=scan.draws,
        seed=scan.seed,
    )
    return dataclasses.replace(plan, ratio=ratio)


def detection_limits(
    setup: RefitSetup,
    catalogue: Catalogue,
    *,
    power: float = LIMIT_POWER,
    draws: int = 2000,
    seed: int = 0,
    causes: tuple[str, ...] | None = None,
    band: tuple[float, float] | None = None,
    plan_factor: float | None = PLAN_FACTOR,
) -> Mapping[str, CauseLimit]:
    """Each catalogue cause's detection limit in a campaign: the smallest size of its key
    parameter that the decision rule names with probability ``power`` (the module's
    computation), in every configuration the cause declares.

    Parameters
    ----------
    setup
        The campaign's refit setup (measured spectra, base model at the fit's point).
    catalogue
        The system's catalogue; causes whose recipe declares no size are left out.
    power
        The probability of naming that defines the limit.
    draws
        Monte Carlo draws of the per-run differences per size.
    seed
        Seeds the draws.
    causes
        Only these causes (``None``: all).
    band
        The analysed band (Hz) the causes' sizes are declared for (``None``: the spectra's
        first and last bin).
    plan_factor
        Plan, beside each limit, the campaign that names the cause at this multiple of its
        typical configuration's limit, the family limit where the cause has one
        (``CauseLimit.plan``; ``None``: no plan).

    Returns
    -------
    dict
        :class:`CauseLimit` by cause name.
    """
    if not 0.0 < power < 1.0:
        raise ValueError(f"power={power!r} must lie in (0, 1)")
    n = len(setup.operating)
    declared = _declared_sizes(setup, catalogue, causes, band)
    if n < 4 or not declared:
        return {}
    rng = np.random.default_rng(seed)
    scan = _Scan(power, draws, seed, rng.standard_normal((draws, n)), _noise(setup))
    out = {}
    for name, size in declared.items():
        curves, typical = _cause_curves(setup, size, scan)
        limit = CauseLimit(
            cause=name,
            quantity=size.quantity,
            unit=size.unit,
            display=size.display,
            power=power,
            runs=n,
            curves=curves,
            transmission=size.transmission,
        )
        target = limit.size if limit.family is None else limit.family
        if plan_factor is not None and target is not None and np.ndim(setup.operating) == 1:
            plan = _plan(setup, name, size, plan_factor * target, typical, scan)
            limit = dataclasses.replace(limit, plan=plan)
        out[name] = limit
    return out


@dataclasses.dataclass(frozen=True)
class TransmissionReading:
    """One machine's transmission of a cause against the model (:func:`read_transmission`).

    Attributes
    ----------
    size
        The size the machine carries.
    model_size
        The model size whose change best reproduces the machine's (0: none does better than
        no change).
    explained
        The share of the machine's change (weighted by the runs' Welch variance) that the
        model's change at ``model_size`` explains.
    bins
        The bins (run, channel, bin) the two changes were compared in.
    """

    size: float
    model_size: float
    explained: float
    bins: int

    @property
    def ratio(self) -> float:
        """``model_size / size``: below 1 the machine shows less of the cause than the model."""
        return self.model_size / self.size


def read_transmission(
    setup: RefitSetup,
    probe: SizeProbe,
    machine: Float[np.ndarray, "run channel freq"],
    size: float,
    *,
    high: float,
    grid: int = 8 * _GRID,
) -> TransmissionReading:
    """How one machine transmits a cause against the model: the model size whose change of
    the log10 spectra best reproduces the machine's.

    ``setup`` is a campaign of the machine without the cause (its measured spectra and the
    base model at the fit's point); ``machine`` the log10 spectra (``setup.spectra``'s
    analysis) of the same runs recorded again with the cause at ``size`` in the probe's
    configuration, with the same noise, so that their difference is the cause's change. The
    model's change is the probe's (:func:`size_spectra`) at each size of a log grid up to
    ``high``. Both changes are taken less their broad part, and compared in the bins either
    changes (:func:`~bayesdoor.diagnose._gain.changed_bins` at ``size``), each run weighted
    by its Welch variance; the size with the least squared difference is the reading.
    """
    if not np.isfinite(size) or size <= 0 or not high > 0:
        raise ValueError(f"size={size!r} and high={high!r} must be positive")
    measured = np.asarray(setup.spectra.measured)
    machine = np.asarray(machine, dtype=float)
    if machine.shape != measured.shape:
        raise ValueError(f"machine spectra of shape {machine.shape}: need {measured.shape}")
    welch = np.asarray(setup.spectra.log_variance)
    at = size_spectra(setup, probe)
    zero = at(0.0)
    mask = changed_bins(zero, at(float(size)), welch) | changed_bins(measured, machine, welch)
    weight = np.where(mask, 1.0 / welch[:, None, None], 0.0)
    target = _detrended(machine - measured)
    sizes = np.concatenate([[0.0], np.geomspace(high * 1e-4, high, grid)])
    sse = np.array(
        [np.sum(weight * (target - _detrended(at(float(s)) - zero)) ** 2) for s in sizes]
    )
    best = int(np.argmin(sse))
    explained = 1.0 - sse[best] / sse[0] if sse[0] > 0 else 0.0
    return TransmissionReading(float(size), float(sizes[best]), float(explained), int(mask.sum()))


def _chi2(p: int, draws: int, seed: int) -> np.ndarray | None:
    """``chi2_p`` draws per fold of the judgement, the same for every probe of ``p`` free
    parameters (``None`` for none)."""
    if p < 1:
        return None
    return np.random.default_rng([seed, p]).chisquare(float(p), (draws, FOLDS))
