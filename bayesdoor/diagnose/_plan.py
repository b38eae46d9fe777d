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
from ._refit import CauseSize

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


#: the machines a plan can hold for: every machine of the family the cause's transmission
#: was measured on, or a machine that transmits it as the model does
MACHINES = ("family", "model")


@dataclasses.dataclass(frozen=True)
class PlanSettings:
    """How a campaign is planned: the probability of naming asked for (``power``), the Monte
    Carlo draws of the per-run differences per campaign tried, their seed, and the machines
    it must hold for (``machines``, one of :data:`MACHINES`: ``"family"`` plans for the
    least-transmitting machine of the family where the cause declares its
    :class:`~bayesdoor.diagnose.Transmission`, ``"model"`` as if the machine transmits the
    cause as the model does)."""

    power: float = LIMIT_POWER
    draws: int = 2000
    seed: int = 0
    machines: str = "family"

    def __post_init__(self) -> None:
        if self.machines not in MACHINES:
            raise ValueError(f"machines={self.machines!r}: use one of {MACHINES}")


def family_ratio(declared: CauseSize, cause: str, configuration: int, machines: str):
    """The transmission a plan of ``cause`` holds for (``None``: the model's): the family's
    least ratio in the typical configuration, where the cause declares it and the settings
    ask for the family. A family the model does not transmit the cause to is refused."""
    t = declared.transmission
    if machines != "family" or t is None or configuration != 0:
        return None
    if t.ratio is None:
        raise ValueError(
            f"{cause}: {t.describe()}, so no campaign is planned to hold on its family; "
            "plan for a machine that transmits it as the model does (machines='model', "
            "--machines model)"
        )
    return t.ratio


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
        The power asked for, the draws, their seed and the machines the plan holds for
        (:class:`PlanSettings`). For the family (the default), a cause that declares its
        :class:`~bayesdoor.diagnose.Transmission` is planned in its typical configuration at
        ``size`` times the family's least ratio (what the least-transmitting machine shows
        of it); other configurations and causes without one as the model transmits them.

    Returns
    -------
    CampaignPlan

    Raises
    ------
    ValueError
        For an unknown cause or one without a size, a size that is not positive, a power
        outside (0, 1), fewer than 4 calibration runs, or a plan for the family of a cause
        whose family the model does not transmit it to.
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
    ratio = family_ratio(declared, cause, configuration, settings.machines)
    setup = base_setup(system, measured, fit, band)
    plan = design_campaign(
        run_gains(setup, probe, float(size) * (1.0 if ratio is None else ratio)),
        np.asarray(measured.operating, dtype=float),
        fold_order(setup),
        target=PlanTarget(cause, float(size), declared.unit, probe.label, display=declared.display),
        power=power,
        record_s=float(measured.duration),
        draws=settings.draws,
        seed=settings.seed,
    )
    return dataclasses.replace(plan, ratio=ratio)
