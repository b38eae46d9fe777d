"""``bayesdoor run`` and ``bayesdoor demo``: the main job on a campaign, with a summary table."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import time
from pathlib import Path
from typing import Any, cast

import xarray as xr
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from .._cluster import Cluster
from .._memory import release_between_stages
from ._common import (
    StageLog,
    check_for_job,
    check_writable,
    emit_json,
    fail,
    interruptible,
    system_named,
    warnings_as_lines,
    writing,
)

_err = Console(stderr=True)


#: the system a campaign names (``bayesdoor diagnose`` imports it under this name)
system_for = system_named


def load(path: Path) -> xr.Dataset:
    """A campaign file for ``run`` or ``classify``; structural problems fail with one line.

    Runs with non-finite samples are kept (``classify`` reports them run by run; the fit
    refuses them among the calibration runs).
    """
    from ..io import load_campaign

    if not path.exists():
        raise fail(f"{path}: no such file; pass a campaign file (.nc)")
    try:
        campaign = load_campaign(path, check=False)
    except (OSError, ValueError) as err:
        raise fail(str(err)) from None
    if "acceleration" not in campaign or "run" not in campaign["acceleration"].dims:
        raise fail(f"{path} has no 'acceleration' (run, channel, time) variable: not a campaign")
    if campaign.sizes["run"] == 0:
        raise fail(f"{path} holds no runs")
    return campaign


def _fmt(value: Any, digits: int = 4) -> str:
    if value is None:
        return "-"
    return f"{value:.{digits}g}" if isinstance(value, float) else str(value)


def gates_line(diagnostics: dict[str, Any] | None, *, quick: bool = False) -> str | None:
    """One line on whether the posterior passed its sampling gates (``None`` for a point fit).

    The summary table of a posterior that failed them reads like any other, so the line
    says so under it, with what failed; with ``--quick`` it adds that short chains are
    expected to fail and how to get a posterior to report.
    """
    if not diagnostics:
        return None
    if diagnostics.get("passed"):
        return (
            f"sampling gates passed (R-hat {_fmt(diagnostics.get('rhat_max'), 4)}, bulk ESS "
            f"{_fmt(diagnostics.get('ess_bulk_min'), 3)}, {diagnostics.get('divergences', 0)} "
            "divergences)"
        )
    failed = "; ".join(m.split(":")[0] for m in diagnostics.get("messages", ()))
    text = f"sampling gates FAILED ({failed}): read the posterior as a first look"
    if quick:
        text += "; --quick samples short chains, run without it for a posterior to report"
    return text


def extension_lines(result: dict[str, Any]) -> list[str]:
    """The summary's lines on the job with the diagnosed extension (``run --extend``)."""
    from ..report import EXTENSION_PROVENANCE

    extended = result.get("extended")
    if extended is None:
        verdict = (result.get("diagnosis") or {}).get("verdict")
        why = "no verdict" if verdict is None else f"verdict {verdict}"
        return [f"with the diagnosed extension: nothing was extended ({why})"]
    held = ", ".join(f"{k} = {_fmt(v)}" for k, v in (extended.get("held") or {}).items())
    lines = [
        f"with the diagnosed extension: {extended['verdict']} ({extended.get('configuration')}),"
        f" held at {held or 'no values'} ({extended['out']})"
    ]
    before, after = result.get("metrics") or {}, extended.get("metrics") or {}
    for label, key in (("accuracy", "accuracy"), ("ECE", "ece")):
        lines.append(f"  {label}: {_fmt(before.get(key), 3)} -> {_fmt(after.get(key), 3)}")
    trust_before = (result.get("trust") or {}).get("verdict")
    trust_after = (extended.get("trust") or {}).get("verdict")
    lines.append(f"  trust: {_fmt(trust_before)} -> {_fmt(trust_after)}")
    lines.append(f"  {EXTENSION_PROVENANCE}")
    return lines


def print_summary(
    result: dict[str, Any], console: Console, *, quick: bool = False, extend: bool = False
) -> None:
    """The posterior summary, the accuracy and calibration, the diagnosis, the report's path
    (and with ``extend`` the job with the diagnosed extension beside it)."""
    fit = result.get("fit")
    if fit is not None:
        console.print(_fit_table(fit))
        gates = gates_line(fit.get("diagnostics"), quick=quick)
        if gates is not None:
            console.print(gates, markup=False, highlight=False)
    console.print(_classification_table(result))
    adequacy = (fit or {}).get("adequacy") or {}
    if adequacy.get("summary"):
        console.print(f"fit adequacy: {adequacy['summary']}", markup=False, highlight=False)
    model = adequacy.get("model") or {}
    if model.get("summary") and model.get("summary") != adequacy.get("summary"):
        console.print(f"the model alone: {model['summary']}", markup=False, highlight=False)
    trust = result.get("trust")
    if trust is not None:
        _print_trust(trust, console)
    diagnosis = result.get("diagnosis")
    if diagnosis is not None:
        verdict = diagnosis["verdict"]
        shown = "undecided (no cause has decisive evidence)" if verdict is None else verdict
        if diagnosis.get("error"):
            console.print(f"discrepancy diagnosis not made: {diagnosis['error']}")
        else:
            console.print(f"discrepancy diagnosis: {shown} ({diagnosis['report']})")
    if extend:
        for line in extension_lines(result):
            console.print(line, markup=False, highlight=False)
    console.print(f"report: {result['report']}")


def _fit_table(fit: dict[str, Any]) -> Table:
    """The model updating's parameters: optimum, posterior mean, sd and 90 % interval."""
    table = Table(title=f"model updating ({fit['method']}, J = {_fmt(fit['j'])})")
    for column in ("parameter", "CMA-ES optimum", "posterior mean", "sd", "90 % interval"):
        table.add_column(column, justify="left" if column == "parameter" else "right")
    for name, row in fit["parameters"].items():
        interval = "-" if row["q5"] is None else f"{row['q5']:.4g} .. {row['q95']:.4g}"
        table.add_row(name, _fmt(row["point"]), _fmt(row["mean"]), _fmt(row["sd"], 2), interval)
    return table


def _classification_table(result: dict[str, Any]) -> Table:
    """The classification's metrics and counts of called, flagged and failed runs."""
    metrics = result.get("metrics")
    table = Table(title=f"classification of {len(result['runs'])} runs")
    table.add_column("metric")
    table.add_column("value", justify="right")
    if metrics is not None:
        table.add_row("accuracy", f"{100 * metrics['accuracy']:.1f} %")
        table.add_row("ECE (15 bins)", _fmt(metrics["ece"], 3))
        table.add_row("NLL", _fmt(metrics["nll"], 3))
        table.add_row("Brier", _fmt(metrics["brier"], 3))
        table.add_row("runs with a known state", str(metrics["runs"]))
    selective = result.get("selective")
    if selective is not None:
        called = (metrics or {}).get("selective") or {}
        accuracy = called.get("accuracy")
        table.add_row(
            f"called at a selective risk of {100 * selective['target_risk']:g} %",
            f"{selective['called']} of {selective['runs']}"
            + ("" if accuracy is None else f" ({100 * accuracy:.1f} % right)"),
        )
    table.add_row("flagged out-of-distribution", str(result["n_ood"]))
    if "n_uncertain" in result:
        table.add_row(
            f"uncertain (call wrong with p > {result['max_error']:g})", str(result["n_uncertain"])
        )
    if any(r.get("corroborated") is not None for r in result["runs"]):
        table.add_row(
            "not corroborated (the signal disagrees with the call)",
            str(result.get("n_not_corroborated", 0)),
        )
    if result["n_failed"]:
        table.add_row("not classified (bad records)", str(result["n_failed"]))
    return table


def _print_trust(trust: dict[str, Any], console: Console) -> None:
    """The trust verdict: not trusted (with its reasons), limited (with its warnings) or passed."""
    if trust["verdict"] == "not trusted":
        console.print(
            "[bold red]the classification cannot be trusted:[/] "
            + escape("; ".join(trust["reasons"])),
            highlight=False,
        )
    elif trust["verdict"] == "limited":
        console.print(
            "[bold yellow]the classification is limited:[/] "
            + escape("; ".join(trust.get("warnings", []))),
            highlight=False,
        )
    else:
        console.print("trust: the checks passed (fit adequacy, known runs, OOD rate)")


def cluster_option(workers: int, scheduler: str | None) -> Cluster:
    """The cluster of ``--workers`` and ``--scheduler`` (checked before any data is read)."""
    if scheduler is not None and workers:
        raise fail(
            f"give --scheduler or --workers, not both (--scheduler {scheduler} --workers {workers})"
        )
    try:
        return Cluster(address=scheduler, workers=workers)
    except ValueError as err:
        raise fail(
            str(err)
            .replace("Cluster.address", "--scheduler")
            .replace("Cluster.workers", "--workers")
        ) from None


@dataclasses.dataclass(frozen=True)
class RunRequest:
    """What the job runs with: ``--quick``, ``--seed``, ``--source`` (``None``: the method's
    default), ``--method`` and ``--extend`` (when the diagnosis names a cause, the job on the
    extended system as well)."""

    quick: bool
    seed: int
    source: str | None
    method: str
    extend: bool = False


def run(
    campaign: xr.Dataset,
    out: Path,
    request: RunRequest,
    *,
    force: bool,
    json: bool,
    cluster: Cluster | None = None,
) -> None:
    """Run the job, print its summary (or its JSON).

    ``cluster``: where the simulation-heavy steps run (``None``: this process).
    """
    from ..pipeline import JobConfig, Source, calibration_runs, default_diagnose, run_job

    source = _checked_source(request.method, request.source)
    system = system_for(campaign)
    check_writable(out)
    check_for_job(
        campaign, system, str(campaign.encoding.get("source", "the campaign")), calibration_runs
    )
    line = _timed_lines(quiet=json)
    cluster = Cluster() if cluster is None else cluster
    stages = StageLog(out, line)
    opened = contextlib.ExitStack()
    try:
        pool = opened.enter_context(cluster.open())
    except OSError as err:
        raise fail(f"{cluster.describe()} cannot be reached: {err}") from None
    if cluster.distributed:
        line(f"simulation-heavy steps on {cluster.describe()} ({pool.address})")
    try:
        with (
            opened,
            interruptible(stages.interrupted),
            writing(out),
            warnings_as_lines(line),
            release_between_stages(),
        ):
            result = run_job(
                system,
                campaign,
                out,
                JobConfig(
                    quick=request.quick,
                    seed=request.seed,
                    source=cast(Source, source),
                    method=request.method,
                    extend=request.extend,
                ),
                diagnose=functools.partial(default_diagnose, catalogue=system.catalogue),
                cluster=pool,
                progress=not json,
                report=stages,
                overwrite=force,
            )
    except FileExistsError as err:
        raise fail(str(err)) from None
    except ValueError as err:
        raise fail(str(err).replace("\n", " ")) from None
    payload = result.to_json()
    if json:
        emit_json(payload)
    else:
        print_summary(payload, Console(), quick=request.quick, extend=request.extend)


def _checked_source(method: str, source: str | None) -> str | None:
    """The training-data source of ``--source`` (``None``: the method's default), after
    checking that it and ``--method`` are known and go together."""
    from ..pipeline import SOURCES, default_source

    if method in ("nuts", "emcee", "cmaes") and source is None:
        source = default_source(method)
    if source not in SOURCES:
        raise fail(f"--source {source!r}: use one of {', '.join(SOURCES)}")
    if method not in ("nuts", "emcee", "cmaes"):
        raise fail(f"--method {method!r}: use nuts, emcee or cmaes")
    if method == "cmaes" and source != "gaussian":
        raise fail(
            f"--method cmaes gives a point, not a posterior: use --source gaussian with it "
            f"(got --source {source})"
        )
    return source


def _timed_lines(*, quiet: bool):
    """A printer of progress lines to stderr, each with the seconds since it was made;
    silent when ``quiet``."""
    start = time.perf_counter()

    def line(text: str) -> None:
        if not quiet:
            _err.print(
                f"[{time.perf_counter() - start:6.1f} s] {text}",
                markup=False,
                highlight=False,
                soft_wrap=True,  # a long line stays one line in a log
            )

    return line
