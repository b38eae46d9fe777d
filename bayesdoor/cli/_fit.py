"""``bayesdoor fit``: model updating on a campaign's healthy calibration runs."""

from __future__ import annotations

import os
import shutil
import uuid
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console

from ._common import check_for_job, check_writable, fail, system_named, writing

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


def parse_law(law: str, lower: float, upper: float) -> list[int | None]:
    """``--law``: empty for a searched law, an index, or ``all`` for every index."""
    if law == "":
        return [None]
    if law == "all":
        return list(range(int(lower), int(upper) + 1))
    try:
        value = int(law)
    except ValueError:
        raise fail(f"--law {law!r}: give an integer in [{lower:g}, {upper:g}] or 'all'") from None
    if not lower <= value <= upper:
        raise fail(f"--law {value} lies outside [{lower:g}, {upper:g}]")
    return [value]


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
        FitResult.check_system(fit, system, source=f"--posterior {folder}: the fit")
    except ValueError as err:
        raise fail(str(err)) from None


def fit_folder(out: Path, law: int | None, several: bool) -> Path:
    """Where one fit goes: ``out`` itself, or ``out/law_I`` when several laws are fitted."""
    return out / f"law_{law}" if several else out


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
    from ..report import plot_posterior_pairs, plot_posterior_trace, plot_predictive_bands

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
        np.asarray(data.run_operating),
        np.asarray(data.operating),
        np.asarray(data.band_centres),
        system.channels,
        folder / "predictive_psd.png",
        title=f"{result.method} fit, law {result.law}, calibration runs",
        conditions=[(c.name, c.unit) for c in system.conditions],
    )
    files["predictive_psd"] = str(path)
    return {"files": files, "predictive_coverage_90": coverage}


def summary_text(result) -> str:
    """The posterior summary table (or the CMA-ES point) as text."""
    lines = [f"method {result.method}, law {result.law}, J = {result.j:.4f}"]
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


def run_fit(
    path: Path, out: Path, method: str, law: str, seed: int, quick: bool, force: bool, as_json: bool
) -> dict[str, Any]:
    """The ``fit`` command: load, fit each law, write the folder(s), return the JSON payload.

    Everything is computed in a hidden folder under ``out`` and moved into place when every
    fit is finished, so an interrupted fit leaves no partial result (a hidden folder left by a
    killed one is removed by the next).
    """
    import json as json_module
    import warnings

    from ..inference import METHODS, calibration_runs, fit_campaign
    from ..io import load_campaign

    if method not in METHODS:
        raise fail(f"--method {method!r}: use one of {', '.join(METHODS)}")
    if not path.exists():
        raise fail(f"no campaign file at {path}: give a NetCDF file written by bayesdoor")
    if out.exists() and not out.is_dir():
        raise fail(f"--out {out} is a file: give a folder")
    check_writable(out)
    try:
        campaign = load_campaign(path, check=False)
    except (ValueError, OSError) as err:
        raise fail(str(err)) from None
    system = system_named(campaign)
    integer = [p for p in system.parameters if p.integer]
    if law and not integer:
        raise fail(f"--law given, but {system.name} has no integer parameter")
    laws = parse_law(law, integer[0].lower, integer[0].upper) if integer else [None]
    check_for_job(campaign, system, str(path), calibration_runs)
    several = len(laws) > 1
    check_free([fit_folder(out, i, several) for i in laws], force)
    results: dict[Any, Any] = {}
    payload: dict[str, Any] = {"file": str(path), "method": method, "out": str(out), "fits": []}
    for stale in out.glob(".fit.*.tmp"):
        shutil.rmtree(stale)
    work = out / f".fit.{uuid.uuid4().hex}.tmp"
    with writing(out):
        try:
            work.mkdir(parents=True)
            for i in laws:
                if not as_json:
                    _err.print(
                        f"fitting {path.name} with {method}, law "
                        f"{i if i is not None else 'searched'}"
                    )
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore" if as_json else "default")
                        result = fit_campaign(
                            system,
                            campaign,
                            method=method,  # type: ignore[arg-type]
                            law=i,
                            seed=seed,
                            quick=quick,
                            progress=not as_json,
                        )
                except ValueError as err:
                    raise fail(str(err)) from None
                folder = fit_folder(work, i, several)
                result.save(folder, force=True)
                figures = write_figures(result, system, campaign, folder, seed)
                figures["files"] = {
                    k: str(fit_folder(out, i, several) / Path(v).name)
                    for k, v in figures["files"].items()
                }
                entry = {**result.to_json(), **figures, "folder": str(fit_folder(out, i, several))}
                results[result.law] = result
                payload["fits"].append(entry)
                if not as_json:
                    _err.print(summary_text(result))
                    coverage = 100 * figures["predictive_coverage_90"]
                    _err.print(f"predictive coverage (90 % band): {coverage:.1f} %")
            if several:
                from ..report import ablation_table

                rows, table = ablation_table(results)
                payload["ablation"] = rows
                (work / "ablation.md").write_text(table)
                payload["ablation_table"] = str(out / "ablation.md")
                if not as_json:
                    _err.print(table)
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
