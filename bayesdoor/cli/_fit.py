"""``bayesdoor fit``: model updating on a campaign's healthy calibration runs."""

from __future__ import annotations

import dataclasses
import json as json_module
import os
import shutil
import uuid
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console

from ._common import (
    check_for_job,
    check_writable,
    fail,
    parse_assignments,
    system_named,
    writing,
)

_err = Console(stderr=True)

#: the files one fit writes into its folder
FIT_FILES = (
    "fit.json",
    "posterior.nc",
    "cmaes_history.png",
    "pairs.png",
    "trace.png",
    "predictive_psd.png",
)


def parse_fixed(items: list[str], system: Any) -> dict[str, float]:
    """``--fix NAME=VALUE`` (repeatable): the parameters held, checked against the system.

    Raises
    ------
    typer.Exit
        (through :func:`~bayesdoor.cli._common.parse_assignments`) for an item without ``=``
        or a number, a name given twice or an unknown name; (through :func:`fail`) for a value
        outside the parameter's bounds or a non-integral value of an integer parameter.
    """
    names = [p.name for p in system.parameters]
    fixed = {name: values[0] for name, values in parse_assignments(items, "--fix", names).items()}
    for name, value in fixed.items():
        try:
            system.check_parameters({name: value})
        except ValueError as err:
            raise fail(f"--fix {name}={value:g}: {err}") from None
    return fixed


def parse_each(each: str, system: Any, fixed: dict[str, float]) -> list[int]:
    """``--each NAME``: every integer value of an integer parameter over its bounds.

    Raises
    ------
    typer.Exit
        (through :func:`fail`) for a name that is not an integer parameter of the system, or
        one that ``--fix`` holds.
    """
    specs = {p.name: p for p in system.parameters}
    integer = [p.name for p in system.parameters if p.integer]
    if each not in specs or not specs[each].integer:
        what = "not a parameter" if each not in specs else "not an integer parameter"
        raise fail(
            f"--each {each}: {what} of {system.name}; give one of its integer parameters "
            f"({', '.join(integer) or 'it has none'})"
        )
    if each in fixed:
        raise fail(f"--each {each} and --fix {each}=... both given: give one of them")
    spec = specs[each]
    return list(range(int(np.ceil(spec.lower)), int(np.floor(spec.upper)) + 1))


def held_text(held: dict[str, float]) -> str:
    """The held parameters as ``I = 3, K = 1e+06``."""
    return ", ".join(f"{k} = {v:g}" for k, v in held.items())


def check_fit_system(fit: Any, system: Any, folder: Path) -> None:
    """Refuse, in one line, a saved fit made for another configuration of the system.

    A fit of a door with a model extension held at values (``bayesdoor.diagnose.
    extend_system``) has the base door's parameter names, so only the system description the
    fit recorded (:attr:`bayesdoor.inference.FitResult.system`) tells them apart. Fits
    written before descriptions were recorded pass (their parameter names are compared by
    the caller).

    Raises
    ------
    typer.Exit
        (through :func:`fail`) when the recorded description is not ``system.describe()``.
    """
    from ..inference import FitResult

    if getattr(fit, "system", None) is None:
        return
    try:
        FitResult.check_system(fit, system, source=f"--model {folder}: the fit")
    except ValueError as err:
        raise fail(str(err)) from None


def fit_folder(out: Path, each: str, value: int | None, several: bool) -> Path:
    """Where one fit goes: ``out`` itself, or ``out/NAME_VALUE`` (``out/I_3``) when several
    values of the ``--each`` parameter are fitted."""
    return out / f"{each}_{value}" if several else out


def check_free(folders: list[Path], force: bool) -> None:
    """Refuse (before any work) to overwrite a previous result unless ``--force``."""
    for folder in folders:
        for name in FIT_FILES:
            if (folder / name).exists() and not force:
                raise fail(f"{folder / name} already exists; pass --force to overwrite it")


def write_figures(result, system, campaign, folder: Path, seed: int) -> dict[str, Any]:
    """The CMA-ES history, pair and trace plots and the predictive PSD bands of a fit."""
    import jax

    from ..inference import plot_cmaes_history, posterior_predictive
    from ..report import (
        OperatingPoints,
        plot_posterior_pairs,
        plot_posterior_trace,
        plot_predictive_bands,
    )

    files = {"history": str(plot_cmaes_history(result.cmaes, folder / "cmaes_history.png"))}
    if result.idata is not None:
        files["pairs"] = str(plot_posterior_pairs(result.idata, result.names, folder / "pairs.png"))
        files["trace"] = str(plot_posterior_trace(result.idata, result.names, folder / "trace.png"))
    n_draws = result.settings.predictive_draws if result.idata is not None else 64
    replicates, data, _ = posterior_predictive(
        result, system, campaign, key=jax.random.key(seed + 7), n_draws=n_draws
    )
    path, coverage = plot_predictive_bands(
        replicates,
        np.asarray(data.y),
        OperatingPoints(
            np.asarray(data.operating),
            np.asarray(data.run_operating),
            [(c.name, c.unit) for c in system.conditions],
        ),
        np.asarray(data.band_centres),
        system.channels,
        folder / "predictive_psd.png",
        title=", ".join(
            [f"{result.method} fit", *([held_text(result.held)] if result.held else [])]
        )
        + ", calibration runs",
    )
    files["predictive_psd"] = str(path)
    return {"files": files, "predictive_coverage_90": coverage}


def summary_text(result) -> str:
    """The posterior summary table (or the CMA-ES point) as text."""
    held = f", {held_text(result.held)}" if result.held else ""
    lines = [f"method {result.method}{held}, J = {result.j:.4f}"]
    if result.idata is None:
        lines += [f"  {k:8s} {v:.6g}" for k, v in result.point.items()]
        lines.append(
            "  model error (decades): " + ", ".join(f"{s:.3f}" for s in result.sigma_point)
        )
        return "\n".join(lines)
    from ..inference import summary_table

    table = summary_table(result.idata, var_names=[*result.names, "sigma_model"])
    lines.append(table.to_string())
    if result.diagnostics is not None:
        lines.append(str(result.diagnostics))
    return "\n".join(lines)


def _move_into(work: Path, out: Path) -> None:
    """Move the files of a finished fit from ``work`` into ``out``, then drop ``work``.

    Files of a previous fit that the new one does not write (a ``posterior.nc`` after a
    CMA-ES fit replaced a sampled one) are removed, so the folder describes one fit.
    """
    new = {f.relative_to(work) for f in work.rglob("*") if f.is_file()}
    for folder in {f.parent for f in new}:
        for name in FIT_FILES:
            if folder / name not in new:
                (out / folder / name).unlink(missing_ok=True)
    for relative in sorted(new):
        target = out / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(work / relative, target)
    shutil.rmtree(work)


@dataclasses.dataclass(frozen=True)
class FitRequest:
    """What the ``fit`` command fits: ``--method``, ``--fix`` items, ``--each`` (empty: one
    fit), ``--seed`` and ``--quick``."""

    method: str
    fix: list[str]
    each: str
    seed: int
    quick: bool


def run_fit(
    path: Path, out: Path, request: FitRequest, *, force: bool, as_json: bool
) -> dict[str, Any]:
    """The ``fit`` command: load, fit (once per value of ``request.each``), write the
    folder(s), return the JSON payload.

    Everything is computed in a hidden folder under ``out`` and moved into place when every
    fit is finished, so an interrupted fit leaves no partial result (a hidden folder left by a
    killed one is removed by the next).
    """
    from ..inference import calibration_runs

    campaign = _load_for_fit(path, out, request.method)
    system = system_named(campaign)
    each = request.each
    fixed = parse_fixed(request.fix, system)
    values: list[int | None] = list(parse_each(each, system, fixed)) if each else [None]
    check_for_job(campaign, system, str(path), calibration_runs)
    several = len(values) > 1
    check_free([fit_folder(out, each, v, several) for v in values], force)
    results: dict[Any, Any] = {}
    payload: dict[str, Any] = {
        "file": str(path),
        "method": request.method,
        "out": str(out),
        "fixed": fixed,
        "each": each or None,
        "fits": [],
    }
    for stale in out.glob(".fit.*.tmp"):
        shutil.rmtree(stale)
    work = out / f".fit.{uuid.uuid4().hex}.tmp"
    with writing(out):
        try:
            work.mkdir(parents=True)
            for value in values:
                given = fixed if value is None else {**fixed, each: float(value)}
                if not as_json:
                    _err.print(
                        f"fitting {path.name} with {request.method}"
                        + (f", {held_text(given)}" if given else "")
                    )
                result = _fit(system, campaign, given, request, as_json)
                results[value] = result
                entry = _save_fit(result, system, campaign, work, out, request, value, several)
                payload["fits"].append(entry)
                if not as_json:
                    _err.print(summary_text(result))
                    coverage = 100 * entry["predictive_coverage_90"]
                    _err.print(f"predictive coverage (90 % band): {coverage:.1f} %")
            if several:
                _write_ablation(results, each, work, out, payload, as_json)
            if len(payload["fits"]) == 1:
                payload.update(payload["fits"][0])
            text = json_module.dumps(payload, indent=2, default=float) + "\n"
            (work / "fit_summary.json").write_text(text)
            _move_into(work, out)
        finally:
            shutil.rmtree(work, ignore_errors=True)
    if not as_json:
        _err.print(f"wrote {out}")
    return payload


def _load_for_fit(path: Path, out: Path, method: str):
    """The campaign at ``path``, after checking the method and that ``out`` may be written."""
    from ..inference import METHODS
    from ..io import load_campaign

    if method not in METHODS:
        raise fail(f"--method {method!r}: use one of {', '.join(METHODS)}")
    if not path.exists():
        raise fail(f"no campaign file at {path}: give a NetCDF file written by bayesdoor")
    if out.exists() and not out.is_dir():
        raise fail(f"--out {out} is a file: give a folder")
    check_writable(out)
    try:
        return load_campaign(path, check=False)
    except (ValueError, OSError) as err:
        raise fail(str(err)) from None


def _fit(system, campaign, given: dict[str, float], request: FitRequest, as_json: bool):
    """One fit with the parameters ``given`` held (warnings shown unless ``as_json``)."""
    import warnings

    from ..inference import FitProblem, fit_campaign

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore" if as_json else "default")
            return fit_campaign(
                system,
                campaign,
                method=request.method,  # type: ignore[arg-type]
                problem=FitProblem(fixed=given or None),
                seed=request.seed,
                quick=request.quick,
                progress=not as_json,
            )
    except ValueError as err:
        raise fail(str(err)) from None


def _save_fit(
    result,
    system,
    campaign,
    work: Path,
    out: Path,
    request: FitRequest,
    value: int | None,
    several: bool,
) -> dict[str, Any]:
    """Save one fit and its figures into its folder under ``work``; its JSON entry, whose
    files name where they will be under ``out``."""
    folder = fit_folder(work, request.each, value, several)
    result.save(folder, force=True)
    figures = write_figures(result, system, campaign, folder, request.seed)
    target = fit_folder(out, request.each, value, several)
    figures["files"] = {k: str(target / Path(v).name) for k, v in figures["files"].items()}
    return {**result.to_json(), **figures, "folder": str(target)}


def _write_ablation(
    results: dict[Any, Any], each: str, work: Path, out: Path, payload: dict, as_json: bool
) -> None:
    """The comparison of the fits of every ``--each`` value: ``ablation.md`` and the payload's
    ``ablation`` rows."""
    from ..report import ablation_table

    rows, table = ablation_table(results, each)
    payload["ablation"] = rows
    (work / "ablation.md").write_text(table)
    payload["ablation_table"] = str(out / "ablation.md")
    if not as_json:
        _err.print(table)
