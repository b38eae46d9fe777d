"""The ``bayesdoor`` command line (one entry point; DESIGN.md section 5)."""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from ._common import check_output_path, configure_jax, emit_json, fail

app = typer.Typer(
    name="bayesdoor",
    help="Probabilistic model updating and damage classification of mechanical systems.",
    no_args_is_help=True,
    add_completion=False,
)
_err = Console(stderr=True)


def _progress(quiet: bool):
    @contextlib.contextmanager
    def stage(label: str):
        t0 = time.perf_counter()
        if quiet:
            yield
            return
        with _err.status(f"{label} ..."):
            yield
        _err.print(f"[green]done[/] {label} ({time.perf_counter() - t0:.1f} s)")

    return stage


@app.command()
def simulate(
    out: Annotated[Path, typer.Option("--out", help="campaign file to write (.nc)")],
    state: Annotated[
        list[str], typer.Option("--state", help="healthy, D1 or D2; repeat for several runs")
    ] = ["healthy"],  # noqa: B006
    v_max: Annotated[
        list[float], typer.Option("--v-max", help="peak door speed (m/s); one or one per state")
    ] = [0.4],  # noqa: B006
    seed: Annotated[int, typer.Option(help="seed of the damage severity draws")] = 0,
    param: Annotated[
        list[str], typer.Option("--param", help="override a Table 2 parameter, NAME=VALUE")
    ] = [],  # noqa: B006
    dtype: Annotated[str, typer.Option(help="float64 or float32")] = "float64",
    force: Annotated[bool, typer.Option(help="overwrite an existing file")] = False,
    json: Annotated[bool, typer.Option("--json", help="print the result as JSON only")] = False,
) -> None:
    """Simulate runs of the reduced door model (paper's optimum unless --param) to a campaign."""
    configure_jax()
    from ..io import save_campaign
    from ..systems.door import STATES, V_MAX_RANGE
    from ._simulate import simulate_campaign

    for s in state:
        if s not in STATES:
            raise fail(f"unknown state {s!r}: allowed {', '.join(STATES)}")
    if len(v_max) not in (1, len(state)):
        raise fail(f"give one --v-max or one per --state ({len(state)}), got {len(v_max)}")
    speeds = v_max * len(state) if len(v_max) == 1 else v_max
    lo, hi = V_MAX_RANGE
    for v in speeds:
        if not lo <= v <= hi:
            raise fail(f"--v-max {v} m/s is outside the allowed range [{lo}, {hi}] m/s")
    if dtype not in ("float64", "float32"):
        raise fail(f"--dtype must be float64 or float32, got {dtype!r}")
    if out.suffix != ".nc":
        raise fail(f"--out must be a NetCDF file ending in .nc, got {out}")
    check_output_path(out, force)
    from ._simulate import _parse_overrides

    ds = simulate_campaign(
        state,
        speeds,
        seed=seed,
        params=_parse_overrides(param),
        dtype=dtype,
        progress=_progress(json),
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    save_campaign(ds, out, overwrite=force)
    result = {
        "file": str(out),
        "runs": int(ds.sizes["run"]),
        "channels": [str(c) for c in ds.channel.values],
        "states": [str(s) for s in ds.state.values],
        "sampling_rate_hz": float(ds.attrs["sampling_rate_hz"]),
        "duration_s": float(ds.sizes["time"] / ds.attrs["sampling_rate_hz"]),
    }
    if json:
        emit_json(result)
    else:
        _err.print(f"wrote {result['runs']} runs to {out}")


@app.command()
def demo(
    out: Annotated[Path, typer.Option("--out", help="output folder")] = Path("out/demo"),
    seed: Annotated[int, typer.Option(help="seed of the damage severity draws")] = 0,
    force: Annotated[bool, typer.Option(help="overwrite previous results")] = False,
    json: Annotated[bool, typer.Option("--json", help="print the result as JSON only")] = False,
) -> None:
    """The main job (for now): simulate the healthy door, D1 and D2, and plot their PSDs."""
    configure_jax()
    from ..io import save_campaign
    from ._simulate import plot_psds, simulate_campaign

    campaign, figure = out / "campaign.nc", out / "psd.png"
    for path in (campaign, figure):
        check_output_path(path, force)
    stage = _progress(json)
    ds = simulate_campaign(
        ["healthy", "D1", "D2"],
        [0.4, 0.4, 0.4],
        seed=seed,
        params={},
        dtype="float64",
        progress=stage,
    )
    out.mkdir(parents=True, exist_ok=True)
    save_campaign(ds, campaign, overwrite=force)
    with stage("plotting PSDs"):
        plot_psds(ds, figure)
    result = {"campaign": str(campaign), "psd_plot": str(figure), "runs": int(ds.sizes["run"])}
    if json:
        emit_json(result)
    else:
        _err.print(f"campaign: {campaign}\nPSD plot: {figure}")
