"""``bayesdoor classify``: a damage report for every run of a campaign with a trained model."""

from __future__ import annotations

import hashlib
import json as json_module
from pathlib import Path

import xarray as xr
from rich.console import Console
from rich.table import Table

from ._common import StageLog, check_writable, emit_json, fail, interruptible, writing
from ._run import print_summary

_err = Console(stderr=True)


def _checked_model(model: Path, campaign: xr.Dataset) -> Path:
    """The ensemble file of ``model``, its header and weights read, its channels the
    campaign's; a failure that says which otherwise."""
    from ..classify import load_ensemble
    from ..pipeline import model_file

    try:
        ensemble = model_file(model)
        # the header's version and the weights, before any work
        expected = load_ensemble(ensemble).network.input_shape[0]
    except ValueError as err:
        raise fail(str(err)) from None
    channels = [str(c) for c in campaign["channel"].values]
    if len(channels) != expected:
        raise fail(
            f"the model in {ensemble.parent} takes {expected} channels, the campaign has "
            f"{len(channels)} ({', '.join(channels)}): pass a campaign with the channels the "
            "model was trained on"
        )
    return ensemble


def _check_out(out: Path, config: dict, force: bool) -> None:
    """Refuse an existing ``out`` that is a file, holds other files, or holds the
    classification of another configuration (unless ``force``)."""
    from ..pipeline import configuration_hash

    record = out / "classify" / "stage.json"
    if not out.is_dir():
        raise fail(f"--out {out} is a file: pass a folder")
    foreign = sorted(p.name for p in out.iterdir() if p.name not in ("classify", "report"))
    if foreign and not force:
        raise fail(
            f"--out {out} holds other files ({', '.join(foreign[:5])}); pass an empty or new "
            "folder, or --force"
        )
    if record.is_file() and not force:
        if json_module.loads(record.read_text()).get("config_hash") != configuration_hash(config):
            raise fail(
                f"{out} holds a classification by another model or of other runs; pass "
                "--force to replace it, or use another folder"
            )


def classify(
    campaign: xr.Dataset,
    model: Path,
    out: Path,
    *,
    force: bool,
    json: bool,
    selective_risk: float | None = None,
) -> None:
    """Classify every run with the ensemble of ``model`` and write the report under ``out``.

    ``selective_risk``: the share of wrong calls the runs called may carry (``None``: the
    default, :data:`bayesdoor.classify.SELECTIVE_RISK`; 0: call every run).

    ``out/classify`` (the JSON and the features) and ``out/report`` (the HTML) are stages:
    the same model and runs reuse them; other ones replace them only with ``force``.
    """
    from ..classify import SELECTIVE_RISK
    from ..pipeline import classify_stage, digest_runs, report_stage, run_stage

    ensemble = _checked_model(model, campaign)
    risk = SELECTIVE_RISK if selective_risk is None else selective_risk
    if not 0 <= risk < 1:
        raise fail(f"--selective-risk must lie in [0, 1), got {risk:g} (0: call every run)")
    check_writable(out)
    config = {
        "model": hashlib.sha256(ensemble.read_bytes()).hexdigest(),
        "runs": digest_runs(campaign),
        "selective_risk": risk,
    }
    if out.exists():
        _check_out(out, config, force)

    def line(text: str) -> None:
        if not json:
            _err.print(text)

    stages = StageLog(out, line, what="classification")
    try:
        with interruptible(stages.interrupted), writing(out):
            classified = run_stage(
                out,
                "classify",
                config,
                lambda folder: classify_stage(
                    ensemble.parent, campaign, folder, selective_risk=risk or None
                ),
                report=stages,
            )
            reported = run_stage(
                out,
                "report",
                {"classification": classified.config_hash},
                lambda folder: report_stage(classified.path, ensemble.parent, folder),
                report=stages,
            )
    except ValueError as err:
        raise fail(str(err)) from None
    payload = json_module.loads((classified.path / "classification.json").read_text())
    payload = {"model": str(ensemble), "report": str(reported.path / "index.html"), **payload}
    if json:
        emit_json(payload)
    else:
        console = Console()
        print_summary(payload, console)
        if payload.get("records"):
            console.print(_records_table(payload["records"], payload["classes"]))


def _records_table(records: list[dict], classes: list[str]) -> Table:
    """The records' votes: true state, what the signal shows, majority of the runs called, its
    mean probability, share flagged."""
    table = Table(title=f"votes of {len(records)} records")
    checked = any(r.get("shows") for r in records)
    columns = ["record", "state", "runs", *(["signal shows"] if checked else [])]
    columns += ["majority", "mean p(majority)", "flagged"]
    for column in columns:
        table.add_column(column, justify="left" if column in ("record", "state") else "right")
    for r in records:
        mean = r["mean_probabilities"]
        shown = r.get("shows") or {}
        # the states whose signature shows in most of the record's runs
        most = [c for c in classes if shown.get(c, 0.0) > 0.5]
        table.add_row(
            r["record"],
            str(r["state"]),
            str(r["runs"]),
            *([", ".join(most) or "-"] if checked else []),
            "uncalled" if r["majority"] is None else str(r["majority"]),
            "-" if mean is None else f"{mean[r['majority']]:.2f}",
            f"{100 * r['share_flagged']:.0f} %" + (" (flagged)" if r["flagged"] else ""),
        )
    return table
