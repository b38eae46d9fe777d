"""``bayesdoor plan``: the campaign that would name a cause of a given size."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer
from rich.console import Console

from ._common import emit_json, fail, system_named

if TYPE_CHECKING:
    from ..diagnose import PlanSettings

_err = Console(stderr=True)


def plan(
    path: Path,
    *,
    cause: str,
    size: float,
    posterior: Path | None,
    configuration: int,
    settings: PlanSettings,
    json: bool,
    quick: bool = False,
) -> None:
    """The ``plan`` command: load the campaign and its fit (or fit here), plan, print."""
    from ..diagnose import plan_campaign
    from ..inference import fit_campaign
    from ._diagnose import load_fit
    from ._run import load

    seed = settings.seed
    campaign = load(path)
    system = system_named(campaign)
    if posterior is None:
        if not json:
            kind = "a quick" if quick else "a"
            _err.print(f"fitting {path.name} ({system.name}) first ({kind} CMA-ES fit)")
        fit = fit_campaign(system, campaign, method="cmaes", seed=seed, quick=quick, progress=False)
    else:
        fit = load_fit(posterior, system)
    try:
        result = plan_campaign(
            system,
            campaign,
            cause,
            size,
            fit=fit,
            configuration=configuration,
            settings=settings,
        )
    except ValueError as err:
        raise fail(str(err).replace("\n", " ")) from None
    if json:
        emit_json({"file": str(path), **result.to_json()})
    else:
        typer.echo(result.describe())
