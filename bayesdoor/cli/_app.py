"""The ``bayesdoor`` command line (one entry point; ``docs/cli.md``)."""

from __future__ import annotations

import contextlib
import json as json_module
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from .._jax_config import configure_jax
from ._common import (
    check_output_path,
    check_writable,
    emit_json,
    fail,
    interruptible,
    on_interrupt,
    parse_assignments,
    writing,
)

app = typer.Typer(
    name="bayesdoor",
    help="Probabilistic model updating and damage classification of mechanical systems.",
    no_args_is_help=True,
    add_completion=False,
)
_err = Console(stderr=True)

#: the metavar of every NAME=VALUE option
ASSIGNMENT = "NAME=VALUE"


def _version(value: bool) -> None:
    if value:
        from importlib.metadata import version

        typer.echo(f"bayesdoor {version('bayesdoor')}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_version, is_eager=True, help="print the version and exit"
        ),
    ] = False,
) -> None:
    """Probabilistic model updating and damage classification of mechanical systems."""


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
@on_interrupt(
    "nothing was written (the campaign file is written whole at the end or not at all); "
    "run the same command again"
)
def simulate(
    out: Annotated[Path, typer.Option("--out", help="campaign file to write (.nc)")],
    system: Annotated[str, typer.Option("--system", help="the system's registered name")],
    state: Annotated[
        list[str],
        typer.Option(
            "--state",
            help="a state of the system, one run each; repeat for several runs (the default: "
            "one run of the system's healthy state, as a simulation needs a state)",
        ),
    ] = [],  # noqa: B006
    condition: Annotated[
        list[str],
        typer.Option(
            "--condition",
            metavar=ASSIGNMENT,
            help="an operating condition, NAME=VALUE (all runs) or NAME=V1,V2,... (one per "
            "--state); repeat for each of the system's conditions",
        ),
    ] = [],  # noqa: B006
    seed: Annotated[int, typer.Option(help="seed of the damage severity draws")] = 0,
    param: Annotated[
        list[str],
        typer.Option(
            "--param",
            metavar=ASSIGNMENT,
            help="override a parameter's reference value, NAME=VALUE (repeatable)",
        ),
    ] = [],  # noqa: B006
    force: Annotated[bool, typer.Option(help="overwrite an existing file")] = False,
    json: Annotated[bool, typer.Option("--json", help="print the result as JSON only")] = False,
) -> None:
    """Simulate runs of a system's model to a campaign file.

    The model runs at its reference parameters unless --param overrides them.
    """
    configure_jax()
    from ..io import save_campaign
    from ..systems import get_system
    from ._simulate import operating_points, simulate_campaign

    try:
        model = get_system(system)
    except LookupError as err:
        raise fail(str(err)) from None
    state = state or [model.healthy]
    for s in state:
        if s not in model.states:
            raise fail(f"unknown state {s!r}: allowed {', '.join(model.states)}")
    conditions = parse_assignments(condition, "--condition", model.condition_names(), several=True)
    params = parse_assignments(param, "--param", [p.name for p in model.parameters])
    operating = operating_points(model, conditions, len(state))
    if out.suffix != ".nc":
        raise fail(f"--out must be a NetCDF file ending in .nc, got {out}")
    check_output_path(out, force)
    check_writable(out)
    ds = simulate_campaign(
        model,
        state,
        operating,
        seed=seed,
        params={name: values[0] for name, values in params.items()},
        progress=_progress(json),
    )
    with writing(out):
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


#: the job's options, alike in ``run`` and ``demo``
_Source = Annotated[
    str | None,
    typer.Option(
        help="training parameters: posterior+model_error (the default with nuts or emcee), "
        "posterior or gaussian (the default with cmaes)"
    ),
]
_JobMethod = Annotated[
    str,
    typer.Option(
        help="fit method: nuts (the default: the job draws its training data from the "
        "posterior), emcee or cmaes"
    ),
]
_Extend = Annotated[
    bool,
    typer.Option(
        help="when the diagnosis names a cause, run the job again on the model extended by "
        "it (in OUT/extended) and compare"
    ),
]
_Workers = Annotated[
    int,
    typer.Option(
        metavar="N",
        help="run the simulation-heavy steps (training data, the diagnosis's refits and "
        "limits) on a local Dask cluster of N worker processes; 0: in this process",
    ),
]
_Scheduler = Annotated[
    str | None,
    typer.Option(
        metavar="ADDRESS",
        help="run the simulation-heavy steps on the Dask scheduler at ADDRESS "
        "(tcp://HOST:PORT; its workers need bayesdoor installed)",
    ),
]
#: small sizes, alike in the commands that fit without training (fit, diagnose, plan)
_Quick = Annotated[bool, typer.Option(help="small sizes (demos, tests; not converged)")]
#: a previous job's products, alike in every command that reuses them
_Model = Annotated[
    Path | None,
    typer.Option(
        "--model",
        "--posterior",
        help="the fit to use: the output folder of 'bayesdoor run' or the --out folder of "
        "'bayesdoor fit' (else fit here)",
    ),
]


@app.command()
@on_interrupt(
    "the job was stopped before its first stage: nothing was written; run the same command again"
)
def run(
    path: Annotated[Path, typer.Argument(help="campaign file (.nc)")],
    out: Annotated[Path, typer.Option("--out", help="output folder of the job")],
    quick: Annotated[bool, typer.Option(help="small sizes: a first look in minutes")] = False,
    seed: Annotated[int, typer.Option(help="seed of the fit, the simulations and training")] = 0,
    source: _Source = None,
    method: _JobMethod = "nuts",
    force: Annotated[bool, typer.Option(help="replace a finished job of other settings")] = False,
    extend: _Extend = False,
    workers: _Workers = 0,
    scheduler: _Scheduler = None,
    json: Annotated[bool, typer.Option("--json", help="print the result as JSON only")] = False,
) -> None:
    """The main job: fit, simulate training data, train, classify the test runs, report.

    Stages finished with the same settings are reused, so a second run is immediate.
    """
    configure_jax()
    from . import _run

    cluster = _run.cluster_option(workers, scheduler)
    _run.run(
        _run.load(path),
        out,
        _run.RunRequest(quick=quick, seed=seed, source=source, method=method, extend=extend),
        force=force,
        json=json,
        cluster=cluster,
    )


_DEMO_STOPPED = (
    "the demo was stopped before its first stage: nothing was written; run the same command again"
)


@app.command()
@on_interrupt(_DEMO_STOPPED)
def demo(
    out: Annotated[
        Path,
        typer.Option(
            "--out",
            help="output folder of the job (the default: out/demo, as the demo has no campaign "
            "file to name one after)",
        ),
    ] = Path("out/demo"),
    quick: Annotated[bool, typer.Option(help="small sizes: a first look in minutes")] = False,
    seed: Annotated[int, typer.Option(help="seed of the fit, the simulations and training")] = 0,
    force: Annotated[bool, typer.Option(help="replace a finished job of other settings")] = False,
    system: Annotated[
        str | None,
        typer.Option(help="the system whose demo campaign to use (default: the first shipped)"),
    ] = None,
    source: _Source = None,
    method: _JobMethod = "nuts",
    extend: _Extend = False,
    workers: _Workers = 0,
    scheduler: _Scheduler = None,
    json: Annotated[bool, typer.Option("--json", help="print the result as JSON only")] = False,
) -> None:
    """`run` on a system's demo campaign (recorded by its virtual rig on first use)."""
    configure_jax()
    from ..systems import get_demo
    from . import _run

    cluster = _run.cluster_option(workers, scheduler)
    try:
        shipped = get_demo(system)
    except LookupError as err:
        raise fail(str(err)) from None

    def demo_paths():
        return (shipped.cached_path(),)

    def load_demo_campaign(show_progress: bool):
        return shipped.load(show_progress=show_progress)

    def recording_stopped() -> str:
        if demo_paths()[0].is_file():  # stopped while reading the cached campaign
            return _DEMO_STOPPED
        return (
            f"the recording of the demo campaign was stopped: nothing of it is kept in "
            f"{demo_paths()[0].parent}; run the same command again to record it (a few minutes)"
        )

    recorded = not demo_paths()[0].is_file()
    started = time.perf_counter()
    try:
        with interruptible(recording_stopped):
            campaign = load_demo_campaign(show_progress=not json)
    except (OSError, ValueError) as err:
        raise fail(
            f"the cached demo campaign cannot be read ({err}): delete {demo_paths()[0]} and run "
            "the demo again to record it anew"
        ) from None
    if recorded and not json:  # the bar is gone: say where the minutes went (first use only)
        _err.print(
            f"recorded the demo campaign ({campaign.sizes['run']} runs) in "
            f"{time.perf_counter() - started:.0f} s: cached in {demo_paths()[0]}",
            soft_wrap=True,  # a path broken over lines cannot be copied
            markup=False,
        )
    _run.run(
        campaign,
        out,
        _run.RunRequest(quick=quick, seed=seed, source=source, method=method, extend=extend),
        force=force,
        json=json,
        cluster=cluster,
    )


@app.command("import")
@on_interrupt("nothing was written (the campaign file is written whole or not at all)")
def import_(
    format: Annotated[
        str,
        typer.Argument(
            help="the data's format: the name of an importer a package declares (a "
            "bayesdoor.importers entry point), or a manifest file (.toml) that describes the "
            "records"
        ),
    ],
    source: Annotated[Path, typer.Argument(help="the measured data (a file or a folder)")],
    out: Annotated[Path, typer.Option("--out", help="campaign file to write (.nc)")],
    force: Annotated[bool, typer.Option(help="overwrite an existing file")] = False,
    json: Annotated[bool, typer.Option("--json", help="print the result as JSON only")] = False,
) -> None:
    """Turn measured data into a campaign file, through its format's importer or a manifest."""
    configure_jax()
    from ..systems import get_importer

    try:
        if format.endswith(".toml"):
            importer = _manifest_importer(Path(format))
        else:
            importer = get_importer(format)
    except LookupError as err:
        raise fail(str(err)) from None
    if not source.exists():
        raise fail(f"{source}: no such file or folder")
    if out.suffix != ".nc":
        raise fail(f"--out must be a NetCDF file ending in .nc, got {out}")
    check_output_path(out, force)
    check_writable(out)
    with _progress(json)(f"importing {source}"), writing(out):
        try:
            summary = importer(source, out, overwrite=force)
        except (ValueError, OSError) as err:
            raise fail(str(err)) from None
    if json:
        emit_json(summary)
    else:
        per_state = summary.get("runs_per_state", {})
        states = ", ".join(f"{k} {v}" for k, v in per_state.items())
        _err.print(f"wrote {summary.get('runs', '?')} runs ({states}) to {out}", soft_wrap=True)
        for note in summary.get("notes", []):
            _err.print(f"note: {note}", soft_wrap=True, markup=False)


def _manifest_importer(manifest: Path):
    """The importer of the records a manifest describes: the reader of manifests of the
    system it names (``system = "NAME"``), bound to the manifest."""
    import functools
    import tomllib

    from ..systems import get_manifest_importer

    if not manifest.is_file():
        raise fail(f"{manifest}: no such manifest file")
    try:
        data = tomllib.loads(manifest.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise fail(f"{manifest}: not TOML ({err})") from None
    system = data.get("system")
    if not isinstance(system, str):
        raise fail(
            f'{manifest}: the manifest names no system (a line system = "NAME" at its top, '
            "NAME the system whose records it describes)"
        )
    return functools.partial(get_manifest_importer(system), manifest)


@app.command()
@on_interrupt(
    "the classification was stopped before it started: nothing was written; run the same "
    "command again"
)
def classify(
    path: Annotated[Path, typer.Argument(help="campaign file (.nc)")],
    model: Annotated[
        Path, typer.Option("--model", help="a job folder of 'bayesdoor run' or its train/")
    ],
    out: Annotated[Path, typer.Option("--out", help="output folder of the report")],
    selective_risk: Annotated[
        float | None,
        typer.Option(
            "--selective-risk",
            metavar="RISK",
            help="the share of wrong calls the runs called may carry; the others are left "
            "uncalled (default 0.05; 0: call every run)",
        ),
    ] = None,
    force: Annotated[bool, typer.Option(help="replace a previous classification")] = False,
    json: Annotated[bool, typer.Option("--json", help="print the result as JSON only")] = False,
) -> None:
    """Damage report for every run: probabilities, uncertainty, OOD flag, HTML and JSON."""
    configure_jax()
    from . import _classify, _run

    _classify.classify(
        _run.load(path), model, out, force=force, json=json, selective_risk=selective_risk
    )


@app.command()
@on_interrupt(
    "inspect was stopped: every plot and inspect.json is written whole or not at all, so "
    "--out holds no half-written file; run the same command again"
)
def inspect(
    path: Annotated[Path, typer.Argument(help="campaign: a NetCDF file or a folder of CSV files")],
    out: Annotated[
        Path | None,
        typer.Option(
            "--out",
            help="folder for the PSD plots and the summary (the default: none, as the check "
            "alone writes nothing)",
        ),
    ] = None,
    force: Annotated[bool, typer.Option(help="overwrite previous plots in --out")] = False,
    json: Annotated[bool, typer.Option("--json", help="print the result as JSON only")] = False,
    system: Annotated[
        str | None,
        typer.Option(
            "--system", help="CSV folder without campaign.json: the system's registered name"
        ),
    ] = None,
    condition: Annotated[
        list[str],
        typer.Option(
            "--condition",
            metavar=ASSIGNMENT,
            help="CSV folder without campaign.json: an operating condition, NAME=VALUE (one "
            "for all runs) or NAME=V1,V2,... (one per run); repeat for each condition",
        ),
    ] = [],  # noqa: B006
    state: Annotated[
        list[str],
        typer.Option(
            "--state",
            help="CSV folder without campaign.json: a state of the system or unknown, one or "
            "one per run (the default: none, as measured runs may have no known state)",
        ),
    ] = [],  # noqa: B006
) -> None:
    """Validate a campaign, summarise it and (with --out) plot its PSDs per channel and state.

    Exits 1 when the campaign breaks the format (every problem on its own line), 0 otherwise
    (warnings do not fail).
    """
    configure_jax()
    from ..io import validate_campaign
    from . import _inspect

    known = _inspect.condition_names(system)
    conditions = parse_assignments(condition, "--condition", known, several=True)
    ds, problems = _inspect.load(path, system=system, conditions=conditions, state=state)
    warnings: list[str] = []
    if ds is not None:
        options, warnings = _inspect.expectations(ds)
        problems = validate_campaign(ds, **options)
        warnings += _inspect.condition_notes(ds)
    info = _inspect.summary(ds)
    written: list[Path] = []
    if out is not None and out.exists() and not out.is_dir():
        raise fail(f"--out {out} is a file: give a folder for the plots")
    if out is not None and ds is not None:
        written, notes = _inspect_plots(ds, problems, path, out, info, force)
        warnings += notes
    result = {
        "file": str(path),
        **info,
        "valid": not problems,
        "problems": [p.message for p in problems],
        "problem_codes": [p.code for p in problems],
        "warnings": warnings,
        "plots": [str(p) for p in written],
        "summary_file": None,
    }
    if out is not None and ds is not None:
        _write_inspect_summary(result, out)
    if json:
        emit_json(result)
    elif ds is not None:
        typer.echo(_inspect.render(result))
    for message in result["problems"]:
        typer.echo(f"problem: {message}", err=True)
    if problems:
        raise fail(f"{path} is not a valid campaign: {len(problems)} problem(s) found", code=1)


def _write_inspect_summary(result: dict, out: Path) -> None:
    """``inspect --out``: ``inspect.json``, the result, which names itself."""
    from ..io import atomic_write

    result["summary_file"] = str(out / "inspect.json")
    text = json_module.dumps(result, indent=2) + "\n"
    with writing(out):
        atomic_write(out / "inspect.json", lambda tmp: tmp.write_text(text), overwrite=True)


def _inspect_plots(ds, problems, path: Path, out: Path, info: dict, force: bool):
    """``inspect --out``: the PSD plots of a loaded campaign, after checking that they and
    the summary may be written; the files written and the notes of the plotting."""
    from . import _inspect

    targets = [*_inspect.plot_paths(out, info["sampling_rate_hz"]), out / "inspect.json"]
    for target in targets:
        check_output_path(target, force)
    check_writable(out)
    title = f"{path.name} ({info['system'] or 'no system'})"
    with writing(out):
        return _inspect.plot(ds, problems, targets[:2], title)


@app.command()
@on_interrupt(
    "the fit was stopped: it is computed in a hidden folder that is moved into --out only "
    "when complete, so --out is as it was; run the same command again to fit anew"
)
def fit(
    path: Annotated[Path, typer.Argument(help="campaign NetCDF file")],
    out: Annotated[Path, typer.Option("--out", help="output folder")],
    method: Annotated[
        str,
        typer.Option(
            help="fit method: cmaes (the default here: the point estimate, in seconds), or nuts "
            "or emcee (the posterior, from CMA-ES's start)"
        ),
    ] = "cmaes",
    fix: Annotated[
        list[str] | None,
        typer.Option(
            "--fix",
            metavar=ASSIGNMENT,
            help="hold a parameter at a value, NAME=VALUE (repeatable; integer parameters "
            "not held are searched by CMA-ES)",
        ),
    ] = None,
    each: Annotated[
        str,
        typer.Option(
            "--each",
            metavar="NAME",
            help="one fit per value of the integer parameter NAME over its bounds (an "
            "ablation of that parameter), into --out/NAME_VALUE",
        ),
    ] = "",
    seed: Annotated[int, typer.Option(help="seed of CMA-ES, surrogate and sampler")] = 0,
    quick: _Quick = False,
    force: Annotated[bool, typer.Option(help="overwrite a previous result in --out")] = False,
    json: Annotated[bool, typer.Option("--json", help="print the result as JSON only")] = False,
) -> None:
    """Update the model on the healthy calibration runs: CMA-ES, then NUTS or emcee."""
    configure_jax()
    from ._fit import FitRequest, run_fit

    request = FitRequest(method=method, fix=fix or [], each=each, seed=seed, quick=quick)
    payload = run_fit(path, out, request, force=force, as_json=json)
    if json:
        emit_json(payload)


@app.command()
@on_interrupt(
    "the diagnosis was stopped: its files are written whole, only once it is complete, so "
    "--out holds no half-written file; run the same command again to diagnose anew"
)
def diagnose(
    path: Annotated[Path, typer.Argument(help="campaign file (.nc)")],
    out: Annotated[Path, typer.Option("--out", help="folder for diagnosis.json and .html")],
    model: _Model = None,
    seed: Annotated[int, typer.Option(help="seed of the fit, the simulations and refits")] = 0,
    quick: _Quick = False,
    force: Annotated[bool, typer.Option(help="overwrite a previous diagnosis in --out")] = False,
    json: Annotated[bool, typer.Option("--json", help="print the result as JSON only")] = False,
) -> None:
    """Where the model departs from the healthy runs, the catalogue cause, the refit's gain."""
    configure_jax()
    from ._diagnose import diagnose as run_diagnosis

    run_diagnosis(path, out, posterior=model, seed=seed, quick=quick, force=force, json=json)


@app.command()
def plan(
    path: Annotated[Path, typer.Argument(help="campaign file (.nc)")],
    cause: Annotated[str, typer.Option("--cause", help="a catalogue cause (frame_mode, ...)")],
    size: Annotated[float, typer.Option("--size", help="its size, in the cause's unit")],
    model: _Model = None,
    configuration: Annotated[
        int, typer.Option(help="which of the cause's configurations (0: the typical one)")
    ] = 0,
    seed: Annotated[int, typer.Option(help="seed of the draws (and of a fit here)")] = 0,
    machines: Annotated[
        str,
        typer.Option(
            help="family: hold on every machine of the family the cause's transmission was "
            "measured on; model: as if the machine transmits the cause as the model does"
        ),
    ] = "family",
    quick: _Quick = False,
    json: Annotated[bool, typer.Option("--json", help="print the result as JSON only")] = False,
) -> None:
    """The cheapest campaign that names a cause of this size with 80 % probability.

    It states the runs per condition, the conditions and the record length, its cost in
    runs, and the machines it holds for.
    """
    configure_jax()
    from ..diagnose import PlanSettings
    from ._plan import plan as run_plan

    try:
        settings = PlanSettings(seed=seed, machines=machines)
    except ValueError as err:
        raise fail(str(err)) from None
    run_plan(
        path,
        cause=cause,
        size=size,
        posterior=model,
        configuration=configuration,
        settings=settings,
        quick=quick,
        json=json,
    )
