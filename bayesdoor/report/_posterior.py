"""Figures of a model update: posterior pairs and traces, posterior-predictive PSD bands."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import arviz as az
import numpy as np


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _point_label(conditions: Sequence[tuple[str, str]], point) -> str:
    """``name = value unit`` for each condition of an operating point, comma-separated."""
    values = np.atleast_1d(np.asarray(point, dtype=float))
    names = list(conditions) + [("", "")] * (values.size - len(conditions))
    return ", ".join(
        f"{name} = {v:g}{' ' + unit if unit and unit != '-' else ''}".strip(" =")
        for (name, unit), v in zip(names, values, strict=False)
    )


@dataclasses.dataclass(frozen=True)
class OperatingPoints:
    """The operating points of :func:`plot_predictive_bands`' runs.

    Parameters
    ----------
    points
        The distinct operating points.
    run_index
        The index into ``points`` of each run.
    conditions
        The name and unit of each operating condition, in the order of a point's values (a
        system's ``(c.name, c.unit) for c in system.conditions``).
    """

    points: np.ndarray
    run_index: np.ndarray
    conditions: Sequence[tuple[str, str]] = (("operating point", ""),)


def plot_predictive_bands(
    replicates: np.ndarray,
    measured: np.ndarray,
    operating: OperatingPoints,
    band_centres: np.ndarray,
    channels: Sequence[str],
    path: str | Path,
    *,
    title: str = "posterior-predictive log PSD",
) -> tuple[Path, float]:
    """Posterior-predictive 90 % bands of the log-PSD features against the measured ones.

    One panel per channel (rows) and operating point (columns): the shaded band holds 90 % of
    the replicates of the runs at that operating point (5 % to 95 % per feature), the dark line
    is their median, the dots are the measured features of each run.

    Parameters
    ----------
    replicates
        Replicated features, (draw, run, channel, band); NaN rows (failed simulations) skipped.
    measured
        Measured features, (run, channel, band).
    operating
        The distinct operating points, each run's among them, and the conditions' names.
    band_centres
        Band centre frequencies, Hz.
    channels
        Channel names.
    path
        The PNG to write (its folder is created).
    title
        Figure title.

    Returns
    -------
    path
        The file written.
    coverage
        The fraction of measured features inside their run's 90 % band.
    """
    plt = _pyplot()
    reps = replicates[np.all(np.isfinite(replicates), axis=(1, 2, 3))]
    lo, hi = np.quantile(reps, [0.05, 0.95], axis=0)
    inside = (measured >= lo) & (measured <= hi)
    coverage = float(np.mean(inside))
    n_ch, n_op = len(channels), len(operating.points)
    fig, axes = plt.subplots(
        n_ch, n_op, figsize=(3.6 * n_op + 0.6, 2.2 * n_ch + 0.8), sharex=True, squeeze=False
    )
    for o in range(n_op):
        runs = np.flatnonzero(np.asarray(operating.run_index) == o)
        pooled = reps[:, runs].reshape(-1, *reps.shape[2:])
        p_lo, p_mid, p_hi = np.quantile(pooled, [0.05, 0.5, 0.95], axis=0)
        for c in range(n_ch):
            ax = axes[c, o]
            ax.fill_between(band_centres, p_lo[c], p_hi[c], color="tab:blue", alpha=0.25)
            ax.plot(band_centres, p_mid[c], color="tab:blue", linewidth=1.2)
            _measured_dots(ax, band_centres, measured[runs, c], np.mean(inside[runs, c]))
            if o == 0:
                ax.set_ylabel(f"{channels[c]}\nlog10 PSD")
            if c == 0:
                point = _point_label(operating.conditions, operating.points[o])
                ax.set_title(f"{point} ({runs.size} runs)", fontsize=10)
            if c == n_ch - 1:
                ax.set_xlabel("frequency (Hz)")
    _band_legend(fig)
    fig.suptitle(f"{title}: {100 * coverage:.1f} % of measured features inside")
    fig.tight_layout(rect=(0, 0.04, 1, 0.97))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path, coverage


def _measured_dots(ax, band_centres: np.ndarray, measured: np.ndarray, share: float) -> None:
    """The measured features of a panel's runs as dots, and the share inside the band."""
    for row in measured:
        ax.plot(
            band_centres,
            row,
            linestyle="none",
            marker="o",
            markersize=2.5,
            color="black",
            alpha=0.7,
        )
    ax.text(
        0.98,
        0.95,
        f"{100 * share:.0f} % inside",
        transform=ax.transAxes,
        ha="right",
        va="top",
        fontsize=8,
    )
    ax.grid(alpha=0.3)


def _band_legend(fig) -> None:
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [
        Patch(color="tab:blue", alpha=0.25, label="90 % predictive band"),
        Line2D([], [], color="tab:blue", label="predictive median"),
        Line2D([], [], color="black", marker="o", linestyle="none", markersize=3, label="measured"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=3, frameon=False)


def plot_posterior_pairs(idata: az.InferenceData, names: Sequence[str], path: str | Path) -> Path:
    """Pairwise scatter and marginal densities of the parameters (``arviz.plot_pair``)."""
    plt = _pyplot()
    axes = az.plot_pair(
        idata,
        var_names=list(names),
        kind="scatter",
        marginals=True,
        scatter_kwargs={"alpha": 0.3, "s": 6},
        figsize=(2.0 * len(names), 2.0 * len(names)),
        textsize=9,
    )
    fig = np.ravel(axes)[0].figure
    fig.suptitle("posterior (pairs and marginals)")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_posterior_trace(idata: az.InferenceData, names: Sequence[str], path: str | Path) -> Path:
    """Per-chain densities and traces of the parameters and model errors (``plot_trace``)."""
    plt = _pyplot()
    var_names = [*names, "sigma_model"]
    axes = az.plot_trace(
        idata, var_names=var_names, compact=True, figsize=(10, 1.7 * len(var_names))
    )
    fig = np.ravel(axes)[0].figure
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def ablation_table(results: dict[Any, Any], name: str) -> tuple[list[dict[str, Any]], str]:
    """PSIS-LOO per value of a varied parameter and stacking weights (``arviz.compare``), and a
    Markdown table: a fit per value of ``name`` (the door's contact-law ablation: one per
    contact-law index ``I``).

    Parameters
    ----------
    results
        A fit (``bayesdoor.inference.FitResult``) per value of the varied parameter.
    name
        The varied parameter (``"I"``).

    Returns
    -------
    rows
        Per value: ``parameter`` (``name``), ``value``, ``j``, posterior ``mean`` and ``sd``
        per sampled parameter, ``elpd_loo``, ``se``, ``pareto_k_bad`` (Pareto k > 0.7),
        ``rank``, ``elpd_diff``, ``dse``, ``weight`` (stacking) and ``gates_passed``.
    table
        The rows as Markdown, the first column headed ``name``.
    """

    def label(value: Any) -> str:
        return f"{name}={value}"

    sampled = {label(k): r.idata for k, r in results.items() if r.idata is not None}
    compare = az.compare(sampled, ic="loo", method="stacking") if len(sampled) > 1 else None
    rows = []
    for value, r in results.items():
        row: dict[str, Any] = {"parameter": name, "value": value, "j": r.j, "mean": {}, "sd": {}}
        draws = r.posterior_draws()
        for n in r.names:
            row["mean"][n] = float(draws[n].mean())
            row["sd"][n] = float(draws[n].std())
        if r.idata is not None:
            loo = az.loo(r.idata)
            row["elpd_loo"] = float(loo.elpd_loo)
            row["se"] = float(loo.se)
            row["pareto_k_bad"] = int((loo.pareto_k.values > 0.7).sum())
        if compare is not None:
            entry = compare.loc[label(value)]
            row["rank"] = int(entry["rank"])
            row["elpd_diff"] = float(entry["elpd_diff"])
            row["dse"] = float(entry["dse"])
            row["weight"] = float(entry["weight"])
        if r.diagnostics is not None:
            row["gates_passed"] = r.diagnostics.passed
        rows.append(row)
    return rows, markdown_table(rows)


def markdown_table(rows: list[dict[str, Any]]) -> str:
    """One line per value of the varied parameter (the rows of :func:`ablation_table`): J,
    ELPD (SE), difference to the best, stacking weight, means (sd).

    Rows of CMA-ES fits (no posterior) show the optimum and no ELPD.
    """
    if not rows:
        return ""
    names = list(rows[0]["mean"])
    head = [str(rows[0]["parameter"]), "J", "ELPD-LOO (SE)", "dELPD (dSE)", "weight", "gates"]
    head += names
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [str(row["value"]), f"{row['j']:.4f}"]
        cells.append(f"{row['elpd_loo']:.1f} ({row['se']:.1f})" if "elpd_loo" in row else "-")
        cells.append(f"{row['elpd_diff']:.1f} ({row['dse']:.1f})" if "elpd_diff" in row else "-")
        cells.append(f"{row['weight']:.2f}" if "weight" in row else "-")
        gates = row.get("gates_passed")
        cells.append("-" if gates is None else ("pass" if gates else "FAIL"))
        sampled = "elpd_loo" in row  # a CMA-ES point has no spread to show
        cells += [
            f"{row['mean'][n]:.4g} ({row['sd'][n]:.2g})" if sampled else f"{row['mean'][n]:.4g}"
            for n in names
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
