"""``bayesdoor fit``: model updating on a campaign's healthy calibration runs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console

from ._common import fail

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


def system_of(campaign):
    """The simulated system a campaign names in its ``system`` attribute."""
    from ..systems import ElevatorDoor

    systems = {"elevator_door": ElevatorDoor}
    name = str(campaign.attrs.get("system", ""))
    if name not in systems:
        raise fail(
            f"the campaign's system attribute is {name!r}; bayesdoor fits {', '.join(systems)}: "
            "set the attribute or pass a campaign of a supported system"
        )
    return systems[name]()


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


def run_fit(
    path: Path, out: Path, method: str, law: str, seed: int, quick: bool, force: bool, as_json: bool
) -> dict[str, Any]:
    """The ``fit`` command: load, fit each law, write the folder(s), return the JSON payload."""
    import json as json_module
    import warnings

    from ..inference import METHODS, fit_campaign
    from ..io import CampaignError, atomic_write, load_campaign

    if method not in METHODS:
        raise fail(f"--method {method!r}: use one of {', '.join(METHODS)}")
    if not path.is_file():
        raise fail(f"no campaign file at {path}: give a NetCDF file written by bayesdoor")
    if out.exists() and not out.is_dir():
        raise fail(f"--out {out} is a file: give a folder")
    try:
        campaign = load_campaign(path)
    except (CampaignError, ValueError, OSError) as err:
        raise fail(f"{path} is not a valid campaign: {err}") from None
    system = system_of(campaign)
    integer = [p for p in system.parameters if p.integer]
    if law and not integer:
        raise fail(f"--law given, but {system.name} has no integer parameter")
    laws = parse_law(law, integer[0].lower, integer[0].upper) if integer else [None]
    several = len(laws) > 1
    folders = [fit_folder(out, i, several) for i in laws]
    check_free(folders, force)
    results: dict[Any, Any] = {}
    payload: dict[str, Any] = {"file": str(path), "method": method, "out": str(out), "fits": []}
    for i, folder in zip(laws, folders, strict=True):
        if not as_json:
            _err.print(
                f"fitting {path.name} with {method}, law {i if i is not None else 'searched'}"
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
        result.save(folder, force=force)
        figures = write_figures(result, system, campaign, folder, seed)
        entry = {**result.to_json(), **figures, "folder": str(folder)}
        results[result.law] = result
        payload["fits"].append(entry)
        if not as_json:
            _err.print(summary_text(result))
            _err.print(
                f"predictive coverage (90 % band): {100 * figures['predictive_coverage_90']:.1f} %"
            )
            _err.print(f"wrote {folder}")
    if several:
        from ..report import ablation_table

        rows, table = ablation_table(results)
        payload["ablation"] = rows
        atomic_write(out / "ablation.md", lambda tmp: tmp.write_text(table), overwrite=force)
        payload["ablation_table"] = str(out / "ablation.md")
        if not as_json:
            _err.print(table)
    if len(payload["fits"]) == 1:
        payload.update(payload["fits"][0])
    text = json_module.dumps(payload, indent=2, default=float) + "\n"
    atomic_write(out / "fit_summary.json", lambda tmp: tmp.write_text(text), overwrite=True)
    return payload
