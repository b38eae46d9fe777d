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
``Delta`` less its broad part, which each model's smooth discrepancy takes alike),
less ``p / n`` per held-out run for the ``p`` parameters fitted on the other half of ``n``
runs (the expected excess loss of an estimate, ``p / 2`` per fold's ``n / 2`` training runs).
The per-run differences are drawn ``N(m_r, q_r)`` and judged by the decision rule itself
(:func:`~bayesdoor.diagnose.rule_passes`' statistics and thresholds): the share named is the
power at ``s``; the limit is the smallest ``s`` with power at least :data:`LIMIT_POWER`.

What it leaves out: the residual features must show the cause before it is refitted (the
signature's gate), and the base fit may absorb part of a cause; both only lower the power
(``results/diagnosis_limits.md`` measures it on the rig).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from .._types import Float
from ..features import LOG_FLOOR
from ._gain import (
    capped_t,
    changed_bins,
    estimate_discrepancy,
    rule_thresholds,
    t_statistic,
)
from ._rank import Catalogue
from ._refit import SMOOTH_BINS, CauseSize, RefitSetup, SizeProbe, exact_signals
from ._residual import smooth_discrepancy

#: the probability of naming a cause that defines its detection limit
LIMIT_POWER = 0.8
#: the smallest PSD a size's spectra take (the features' floor of a log10 PSD)
_PSD_FLOOR = LOG_FLOOR
#: sizes scanned per configuration (log-spaced over the cause's declared range)
_GRID = 33


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
    """

    cause: str
    quantity: str
    unit: str
    display: tuple[str, float]
    power: float
    runs: int
    curves: tuple[PowerCurve, ...]

    @property
    def size(self) -> float | None:
        """The typical configuration's limit (``None``: above the scanned range)."""
        return self.curves[0].limit

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
            "words": self.describe(),
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
    the truth (the module's formulas), ``parameters`` fitted on the other half of the runs;
    the variance times ``correlation`` (:func:`bin_variance_factor`).

    Each model is judged with its own smooth discrepancy (the running median over
    ``2 smooth_bins + 1`` bins of its run-mean residual), which takes the broad part of a
    change into both models alike: the change that tells them apart is ``Delta`` less the
    running median of its run mean (``None``: the whole change)."""
    delta = np.asarray(extended) - np.asarray(base)
    if smooth_bins is not None:
        delta = delta - smooth_discrepancy(delta.mean(axis=0), smooth_bins)
    changed = changed_bins(base, extended, welch)
    d2 = np.where(changed, delta**2, 0.0)
    count = np.maximum(changed.sum(axis=(0, 2), keepdims=True), 1)
    v = variance
    vb = v + d2.sum(axis=(0, 2), keepdims=True) / count
    m = np.where(changed, 0.5 * np.log(vb / v) + 0.5 * (d2 + v) / vb - 0.5, 0.0)
    q = np.where(changed, d2 * v / vb**2 + 0.5 * (1.0 - v / vb) ** 2, 0.0)
    n = base.shape[0]
    return m.sum(axis=(1, 2)) - parameters / n, correlation * q.sum(axis=(1, 2))


def naming_probability(
    mean: Float[np.ndarray, "*size run"],
    variance: Float[np.ndarray, "*size run"],
    normals: Float[np.ndarray, "draw run"],
) -> Float[np.ndarray, "*size"]:
    """The share of draws ``d = mean + sqrt(variance) z`` that the rule's statistics pass (the
    plain or the capped over its threshold for as many held-out runs)."""
    mean, variance = np.asarray(mean, dtype=float), np.asarray(variance, dtype=float)
    on_t, on_capped = rule_thresholds(mean.shape[-1])
    d = mean[..., None, :] + np.sqrt(variance)[..., None, :] * normals
    named = (t_statistic(d) > on_t) | (capped_t(d) > on_capped)
    return named.mean(axis=-1)


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


def probe_changes(
    setup: RefitSetup, probe: SizeProbe
) -> tuple[Float[np.ndarray, "run channel time"], Float[np.ndarray, "run channel time"]]:
    """The probe's signals at size 0 and their change per unit size (one simulation, two
    when the extension at size 0 is not the base model)."""
    n = len(setup.operating)
    runs = np.arange(n)
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
    P(z - r c)) / 2 - P(z))`` with ``u = s / r`` exactly (``r`` the probe's reference)."""
    zero, per_unit = probe_changes(setup, probe)
    runs = np.arange(len(setup.operating))
    r = probe.reference
    p0, up, down = (
        10.0 ** setup.spectra.model(x, runs)
        for x in (zero, zero + r * per_unit, zero - r * per_unit)
    )
    linear, quadratic = (up - down) / 2.0, (up + down) / 2.0 - p0

    def at(size: float) -> np.ndarray:
        u = float(size) / r
        return np.log10(np.maximum(p0 + u * linear + u * u * quadratic, _PSD_FLOOR))

    return at


def power_curve(
    setup: RefitSetup,
    probe: SizeProbe,
    sizes: Float[np.ndarray, " size"],
    *,
    power: float = LIMIT_POWER,
    normals: Float[np.ndarray, "draw run"],
    noise: _Noise | None = None,
) -> PowerCurve:
    """The probability that the rule names the probe's cause at each size, in these runs."""
    noise = _noise(setup) if noise is None else noise
    spectra = size_spectra(setup, probe)
    welch = np.asarray(setup.spectra.log_variance)
    p = len(probe.proposal.free)
    means, variances = [], []
    for s in sizes:
        extended = spectra(float(s))
        m, q = expected_differences(
            noise.base, extended, noise.variance, welch, p, noise.correlation
        )
        means.append(m)
        variances.append(q)
    mean, var = np.array(means), np.array(variances)
    probability = naming_probability(mean, var, normals)
    return PowerCurve(
        label=probe.label,
        sizes=np.asarray(sizes, dtype=float),
        probability=probability,
        evidence=_evidence(mean, var),
        limit=_limit(np.asarray(sizes, dtype=float), probability, power),
    )


def cause_sizes(catalogue: Catalogue, band: tuple[float, float]) -> dict[str, CauseSize]:
    """Every catalogue cause that declares its size (its recipe's
    :meth:`~bayesdoor.diagnose.AbstractRefit.size`), by name."""
    out = {}
    for c in catalogue.candidates:
        size = None if c.refit is None else c.refit.size(band=band)
        if size is not None:
            out[c.name] = size
    return out


def detection_limits(
    setup: RefitSetup,
    catalogue: Catalogue,
    *,
    power: float = LIMIT_POWER,
    draws: int = 2000,
    seed: int = 0,
    causes: tuple[str, ...] | None = None,
    band: tuple[float, float] | None = None,
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

    Returns
    -------
    dict
        :class:`CauseLimit` by cause name.
    """
    if not 0.0 < power < 1.0:
        raise ValueError(f"power={power!r} must lie in (0, 1)")
    n = len(setup.operating)
    freqs = setup.spectra.freqs
    band = (float(freqs[0]), float(freqs[-1])) if band is None else band
    declared = cause_sizes(catalogue, band)
    if causes is not None:
        declared = {k: v for k, v in declared.items() if k in causes}
    if n < 4 or not declared:
        return {}
    normals = np.random.default_rng(seed).standard_normal((draws, n))
    noise = _noise(setup)
    out = {}
    for name, size in declared.items():
        sizes = np.geomspace(size.low, size.high, _GRID)
        curves = tuple(
            power_curve(setup, probe, sizes, power=power, normals=normals, noise=noise)
            for probe in size.probes
        )
        out[name] = CauseLimit(
            cause=name,
            quantity=size.quantity,
            unit=size.unit,
            display=size.display,
            power=power,
            runs=n,
            curves=curves,
        )
    return out
