"""Measurement design: the campaign that would name a cause of a given size.

From a diagnosed campaign's runs the expected held-out log-density difference of each run,
were the cause there at that size, is known (:func:`~bayesdoor.diagnose._limits.
expected_differences`); a campaign of ``m`` runs at each of ``k`` of its operating conditions
holds each condition's difference ``m`` times, judged by the decision rule for ``m k``
held-out runs. The plan is the cheapest such campaign (fewest runs, then fewest conditions)
that the rule names with the stated probability; the conditions tried are the campaign's own,
best first by their runs' expected evidence (a condition the campaign never ran is not
predicted: its Welch variance and model error are unknown). The record length is the
campaign's: the motion window a run's spectra come from is set by the system's operation at
that condition, not chosen.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import numpy as np
import xarray as xr

from ..inference import FitResult
from ._job import _band, _Measured, _simulate_rows
from ._limits import (
    LIMIT_POWER,
    _noise,
    expected_differences,
    naming_probability,
    size_spectra,
)
from ._rank import Catalogue
from ._refit import SizeProbe

if TYPE_CHECKING:
    from ..systems import AbstractSystem

#: most runs per condition a plan proposes
MAX_RUNS_PER_CONDITION = 40


@dataclasses.dataclass(frozen=True)
class CampaignPlan:
    """The campaign that names a cause at a size with the stated probability.

    Attributes
    ----------
    cause, size, unit, configuration
        What is to be named (the cause's typical configuration unless chosen).
    power
        The probability asked for.
    conditions
        The operating conditions to run (the campaign's own values).
    runs_per_condition
        Runs at each; ``None`` when no plan up to :data:`MAX_RUNS_PER_CONDITION` runs per
        condition reaches the power.
    probability
        The probability that the rule names the cause in that campaign (in the largest
        campaign tried when none reaches the power).
    record_s
        The record length of each run, s (the campaign's).
    current
        The probability in the campaign as it is.
    """

    cause: str
    size: float
    unit: str
    configuration: str
    power: float
    conditions: tuple[float, ...]
    runs_per_condition: int | None
    probability: float
    record_s: float
    current: float

    @property
    def runs(self) -> int | None:
        """The cost: runs in all (``None``: no plan reaches the power)."""
        if self.runs_per_condition is None:
            return None
        return self.runs_per_condition * len(self.conditions)

    def describe(self) -> str:
        where = ", ".join(f"{c:g}" for c in self.conditions)
        if self.runs_per_condition is None:
            return (
                f"no campaign of up to {MAX_RUNS_PER_CONDITION} runs per condition at these "
                f"conditions names {self.cause} at {self.size:g} {self.unit} with "
                f"{100 * self.power:.0f} % probability (best {100 * self.probability:.0f} %)"
            )
        return (
            f"{self.runs_per_condition} runs at each of {len(self.conditions)} conditions "
            f"({where}; {self.runs} runs of {self.record_s:.3g} s) name {self.cause} at "
            f"{self.size:g} {self.unit} ({self.configuration}) with "
            f"{100 * self.probability:.0f} % probability (this campaign: "
            f"{100 * self.current:.0f} %)"
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "size": self.size,
            "unit": self.unit,
            "configuration": self.configuration,
            "power": self.power,
            "conditions": list(self.conditions),
            "runs_per_condition": self.runs_per_condition,
            "runs": self.runs,
            "probability": self.probability,
            "record_s": self.record_s,
            "current_probability": self.current,
            "words": self.describe(),
        }


def _probe(catalogue: Catalogue, cause: str, band: tuple[float, float], configuration: int):
    candidates = {c.name: c for c in catalogue.candidates}
    if cause not in candidates:
        raise ValueError(f"no cause {cause!r}; the catalogue holds {sorted(candidates)}")
    refit = candidates[cause].refit
    declared = None if refit is None else refit.size(band=band)
    if declared is None:
        raise ValueError(f"the cause {cause!r} declares no size to plan for")
    if not 0 <= configuration < len(declared.probes):
        raise ValueError(
            f"configuration={configuration!r}: {cause} has {len(declared.probes)} "
            f"({', '.join(p.label for p in declared.probes)})"
        )
    return declared, declared.probes[configuration]


def plan_campaign(
    system: AbstractSystem,
    campaign: xr.Dataset,
    cause: str,
    size: float,
    *,
    fit: FitResult,
    catalogue: Catalogue | None = None,
    power: float = LIMIT_POWER,
    configuration: int = 0,
    draws: int = 2000,
    seed: int = 0,
) -> CampaignPlan:
    """The cheapest campaign at this campaign's operating conditions that names ``cause`` at
    ``size`` with probability ``power`` (the module's computation).

    Parameters
    ----------
    system
        The base system.
    campaign
        The campaign planned from (its healthy calibration runs).
    cause
        A catalogue name whose recipe declares its size.
    size
        The size to name, in the cause's unit (``CauseSize.unit``).
    fit
        The base model's fit on the campaign.
    catalogue
        The system's catalogue (``None``: ``system.catalogue``).
    power
        The probability of naming asked for.
    configuration
        Which of the cause's configurations (0: the typical one).
    draws
        Monte Carlo draws of the per-run differences per campaign tried.
    seed
        Seeds the draws.

    Returns
    -------
    CampaignPlan

    Raises
    ------
    ValueError
        For an unknown cause or one without a size, a size that is not positive, a power
        outside (0, 1), or fewer than 4 calibration runs.
    """
    from ..inference import calibration_runs

    if not np.isfinite(size) or size <= 0:
        raise ValueError(f"size={size!r} must be a positive number")
    if not 0.0 < power < 1.0:
        raise ValueError(f"power={power!r} must lie in (0, 1)")
    catalogue = system.catalogue if catalogue is None else catalogue
    if not isinstance(catalogue, Catalogue):
        raise ValueError(f"{system.name} has no catalogue of discrepancy causes")
    measured = _Measured.of(system, campaign, calibration_runs(campaign))
    if len(measured.runs) < 4:
        raise ValueError(f"{len(measured.runs)} calibration runs: need at least 4 to plan from")
    band = _band(fit)
    declared, probe = _probe(catalogue, cause, band, configuration)
    sims, ok, times = _simulate_rows(system, measured, [dict(fit.point)])
    if not ok[0]:
        raise RuntimeError("the base model failed to simulate the runs at the fit's point")
    setup = measured.setup(system, fit.point, sims[0], times, band, None)
    mean, variance = _per_run(setup, probe, size)
    p = len(probe.proposal.free)
    n = len(measured.runs)
    # the parameters' penalty of the campaign as it is taken out: it depends on the runs
    mean = mean + p / n
    conditions = np.unique(measured.operating)
    by = [measured.operating == c for c in conditions]
    m_c = np.array([mean[b].mean() for b in by])
    q_c = np.array([variance[b].mean() for b in by])
    order = np.argsort(-(m_c / np.sqrt(np.maximum(q_c, 1e-300))))

    def probability(mu: np.ndarray, q: np.ndarray) -> float:
        normals = np.random.default_rng([seed, mu.size]).standard_normal((draws, mu.size))
        return float(naming_probability(mu, q, normals))

    current = probability(mean - p / n, variance)
    best: tuple[int, int, float, np.ndarray] | None = None
    largest = (0.0, conditions[order[:1]])
    for k in range(1, len(conditions) + 1):
        chosen = order[:k]

        def at(m: int, chosen: np.ndarray = chosen) -> float:
            runs = m * len(chosen)
            return probability(np.repeat(m_c[chosen], m) - p / runs, np.repeat(q_c[chosen], m))

        low, high = max(1, -(-4 // k)), MAX_RUNS_PER_CONDITION
        top = at(high)
        if top > largest[0]:
            largest = (top, conditions[chosen])
        if top < power:
            continue
        while low < high:  # the fewest runs per condition that reach the power
            mid = (low + high) // 2
            if at(mid) >= power:
                high = mid
            else:
                low = mid + 1
        if best is None or low * k < best[0] * best[1]:
            best = (low, k, at(low), conditions[chosen])
    if best is None:
        chosen_conditions, per, prob = largest[1], None, largest[0]
    else:
        per, _, prob, chosen_conditions = best
    return CampaignPlan(
        cause=cause,
        size=float(size),
        unit=declared.unit,
        configuration=probe.label,
        power=power,
        conditions=tuple(float(c) for c in np.sort(chosen_conditions)),
        runs_per_condition=per,
        probability=prob,
        record_s=float(measured.duration),
        current=current,
    )


def _per_run(setup: Any, probe: SizeProbe, size: float) -> tuple[np.ndarray, np.ndarray]:
    """Each run's expected held-out difference and its variance at ``size``."""
    noise = _noise(setup)
    extended = size_spectra(setup, probe)(float(size))
    return expected_differences(
        noise.base,
        extended,
        noise.variance,
        np.asarray(setup.spectra.log_variance),
        len(probe.proposal.free),
        noise.correlation,
    )
