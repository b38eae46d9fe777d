"""``bayesdoor diagnose``: what the model gets wrong on a campaign, its cause, and the gain."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer
import xarray as xr
from rich.console import Console

from ._common import check_for_job, check_writable, emit_json, fail, system_named, writing
from ._fit import check_fit_system

_err = Console(stderr=True)


def load_fit(folder: Path, system) -> Any:
    """The fit of ``--model FOLDER``: the --out folder of ``bayesdoor fit`` or the output
    folder of ``bayesdoor run`` (its fit), checked against the campaign's system.

    Raises
    ------
    typer.Exit
        (through :func:`fail`) for a missing folder, a folder of several fits (``bayesdoor
        fit --each``), a folder without a fit, an unreadable fit, or a fit of another
        system's parameters.
    """
    from ..inference import FitResult

    if not folder.is_dir():
        raise fail(
            f"--model {folder}: no such folder; pass the output folder of bayesdoor run or "
            "the --out folder of bayesdoor fit"
        )
    job_fit = folder / "fit" / "result"
    if not (folder / "fit.json").is_file() and (job_fit / "fit.json").is_file():
        folder = job_fit
    fits = sorted(p.name for p in folder.iterdir() if (p / "fit.json").is_file())
    if not (folder / "fit.json").is_file():
        if fits:
            raise fail(
                f"--model {folder} holds several fits, one per value of a parameter "
                f"({', '.join(fits)}): pass one of them, e.g. --model {folder / fits[0]}"
            )
        raise fail(
            f"--model {folder} holds no fit.json: pass the output folder of bayesdoor run or "
            "the --out folder of bayesdoor fit"
        )
    try:
        fit = FitResult.load(folder)
    except (OSError, ValueError, KeyError, TypeError) as err:
        reason = str(err).replace("\n", " ")
        raise fail(f"--model {folder}: the fit cannot be read ({reason}); refit it") from None
    expected = set(system.parameter_names())
    found = set(fit.point)
    if found != expected:
        extra, missing = sorted(found - expected), sorted(expected - found)
        raise fail(
            f"--model {folder} is a fit of another system (parameters not in "
            f"{system.name}: {extra or 'none'}; missing: {missing or 'none'}): pass a fit of "
            "this campaign's system, or leave out --model to fit here"
        )
    check_fit_system(fit, system, folder)
    return fit


def catalogue_for(system):
    """The system's catalogue of discrepancy causes (``None``: it has none)."""
    return system.catalogue


def compute(system, campaign: xr.Dataset, fit, *, seed: int, quick: bool, progress: bool):
    """The diagnosis (:func:`bayesdoor.diagnose.diagnose_campaign`); ``fit=None`` fits here."""
    from ..diagnose import diagnose_campaign

    return diagnose_campaign(
        system,
        campaign,
        fit=fit,
        seed=seed,
        quick=quick,
        progress=progress,
        catalogue=catalogue_for(system),
    )


def summary_lines(payload: dict[str, Any]) -> list[str]:
    """The verdict, the ranked causes with their evidence, parameters and gain, the report."""
    from ..report import gain_entries, parameter_text

    verdict = payload.get("verdict")
    shown = "undecided (no cause has decisive evidence)" if verdict is None else str(verdict)
    lines = [f"verdict: {shown}", "ranked causes:"]
    for rank, cause in enumerate(payload.get("causes", []), start=1):
        parameters = cause.get("parameters") or {}
        gain = cause.get("gain") or {}
        lines.append(f"{rank:3d}. {cause.get('name')}: {cause.get('evidence', '')}")
        if parameters:
            lines.append(
                "     parameters: "
                + ", ".join(f"{k} = {parameter_text(v)}" for k, v in parameters.items())
            )
        if gain:
            lines.append(
                "     gain: "
                + ", ".join(f"{k} = {parameter_text(v)}" for k, v in gain_entries(gain).items())
            )
    confirmed = payload.get("confirmed") or []
    if len(confirmed) > 1:
        lines.append("confirmed, strongest held-out evidence first: " + ", ".join(confirmed))
    limits = payload.get("limits") or {}
    if limits:
        lines.append("limits (a cause smaller than its limit would not be named):")
        for name, limit in limits.items():
            lines.append(f"  - {limit.get('words', name)}")
            plan = limit.get("plan")
            if verdict == "none" and isinstance(plan, dict) and plan.get("words"):
                half = "half the limit (the family's where the cause has one)"
                lines.append(f"    planned at {half}: {plan['words']}")
    lines.append(f"report: {payload['report']}")
    return lines


def diagnose(
    path: Path,
    out: Path,
    *,
    posterior: Path | None,
    seed: int,
    quick: bool,
    force: bool,
    json: bool,
) -> None:
    """The ``diagnose`` command: check the inputs, diagnose, write the two files, print."""
    from ..inference import calibration_runs
    from ..pipeline import DIAGNOSIS_FILES, catalogue_of, save_diagnosis
    from ._run import load

    campaign = load(path)
    system = system_named(campaign)
    check_for_job(campaign, system, str(path), calibration_runs)
    if out.exists() and not out.is_dir():
        raise fail(f"--out {out} is a file: pass a folder for the diagnosis")
    check_writable(out)
    for name in DIAGNOSIS_FILES:
        if (out / name).exists() and not force:
            raise fail(f"{out / name} already exists; pass --force to overwrite it")
    fit = None if posterior is None else load_fit(posterior, system)
    if not json:
        source = "a fit here" if fit is None else f"the fit in {posterior}"
        _err.print(f"diagnosing {path.name} ({system.name}) under {source}")
    try:
        diagnosis = compute(system, campaign, fit, seed=seed, quick=quick, progress=not json)
    except ValueError as err:
        raise fail(str(err).replace("\n", " ")) from None
    extra = {
        "file": str(path),
        "posterior": None if posterior is None else str(posterior),
        "seed": seed,
        "quick": quick,
    }
    with writing(out):
        payload = save_diagnosis(
            diagnosis,
            out,
            catalogue=catalogue_of(system, diagnosis),
            fit=None if fit is None else fit.to_json(),
            extra=extra,
            title=f"{path.name}: discrepancy diagnosis",
            overwrite=force,
        )
    payload = {**payload, "out": str(out), "report": str(out / payload["report"])}
    if json:
        emit_json(payload)
    else:
        typer.echo("\n".join(summary_lines(payload)))
