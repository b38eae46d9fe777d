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
from typing import TYPE_CHECKING

import numpy as np
import xarray as xr

from ..inference import FitResult
from ._design import MAX_RUNS_PER_CONDITION as MAX_RUNS_PER_CONDITION
from ._design import CampaignPlan, PlanTarget, design_campaign
from ._limits import LIMIT_POWER, fold_order, run_gains
from ._measured import Measured, _band, base_setup
from ._rank import Catalogue

if TYPE_CHECKING:
    from ..systems import AbstractSystem


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


@dataclasses.dataclass(frozen=True)
class PlanSettings:
    """How a campaign is planned: the probability of naming asked for (``power``), the Monte
    Carlo draws of the per-run differences per campaign tried, and their seed."""

    power: float = LIMIT_POWER
    draws: int = 2000
    seed: int = 0


def plan_campaign(
    system: AbstractSystem,
    campaign: xr.Dataset,
    cause: str,
    size: float,
    *,
    fit: FitResult,
    catalogue: Catalogue | None = None,
    configuration: int = 0,
    settings: PlanSettings = PlanSettings(),
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
    configuration
        Which of the cause's configurations (0: the typical one).
    settings
        The power asked for, the draws and their seed (:class:`PlanSettings`).

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

    power = settings.power

    if not np.isfinite(size) or size <= 0:
        raise ValueError(f"size={size!r} must be a positive number")
    if not 0.0 < power < 1.0:
        raise ValueError(f"power={power!r} must lie in (0, 1)")
    catalogue = system.catalogue if catalogue is None else catalogue
    if not isinstance(catalogue, Catalogue):
        raise ValueError(f"{system.name} has no catalogue of discrepancy causes")
    measured = Measured.of(system, campaign, calibration_runs(campaign, system.healthy))
    if len(measured.runs) < 4:
        raise ValueError(f"{len(measured.runs)} calibration runs: need at least 4 to plan from")
    band = _band(fit)
    declared, probe = _probe(catalogue, cause, band, configuration)
    setup = base_setup(system, measured, fit, band)
    return design_campaign(
        run_gains(setup, probe, float(size)),
        np.asarray(measured.operating, dtype=float),
        fold_order(setup),
        target=PlanTarget(cause, float(size), declared.unit, probe.label, display=declared.display),
        power=power,
        record_s=float(measured.duration),
        draws=settings.draws,
        seed=settings.seed,
    )
