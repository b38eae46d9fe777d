"""Damage reports: one HTML page per campaign and one per run, figures embedded.

The figures follow the paper: probability bars per run (its Figure 6) and the confusion
matrix (its Figure 7), plus what a calibrated classifier adds: the reliability diagram, the
uncertainty of every run (predictive entropy, mutual information between the ensemble's
members, out-of-distribution score) and each run's features against the posterior-predictive
band of every state. Matplotlib is used through ``matplotlib.figure.Figure`` only, so the
caller's pyplot backend is left alone.
"""

from __future__ import annotations

import dataclasses
import html
import io
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from jaxtyping import Float
from matplotlib.ticker import MaxNLocator

from ..io import UNKNOWN, atomic_write
from ..systems import HEALTHY
from . import _html as H
from ._calibration import plot_reliability
from ._colors import UNKNOWN_COLOR, state_colors


def _figure(width: float, height: float, **kw: Any) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), layout="constrained", **kw)


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def probability_bars(
    runs: Sequence[Mapping[str, Any]], classes: Sequence[str], healthy: str = HEALTHY
) -> bytes:
    """Stacked class probabilities of every run, one panel per true state (paper, Figure 6);
    when no run's state is known, one panel per predicted state. ``healthy``: the system's
    healthy state (its colour, :func:`~bayesdoor.report.state_colors`)."""
    colors = state_colors(classes, healthy)
    valid = [r for r in runs if r["probabilities"] is not None]
    known = _labelled(valid, classes)

    def key(r: Mapping[str, Any]) -> str | None:
        return r["state"] if known else _leaning(r)

    groups = [s for s in (*classes, UNKNOWN) if any(key(r) == s for r in valid)]
    groups += sorted({str(key(r)) for r in valid} - set(groups))
    fig = _figure(11.5, 1.7 + 1.55 * max(len(groups), 1))
    axes = fig.subplots(max(len(groups), 1), 1, squeeze=False)[:, 0]
    for ax, group in zip(axes, groups, strict=False):
        members = [r for r in valid if str(key(r)) == group]
        p = np.array([[r["probabilities"][c] for c in classes] for r in members])
        x = np.arange(len(members))
        bottom = np.zeros(len(members))
        for k, c in enumerate(classes):
            ax.bar(x, p[:, k], 1.0, bottom=bottom, color=colors[c], label=c, linewidth=0)
            bottom += p[:, k]
        wrong = [i for i, r in enumerate(members) if known and _leaning(r) != group]
        if group in classes and wrong:
            ax.plot(wrong, np.full(len(wrong), 1.06), "v", color="black", ms=4, clip_on=False)
        ood = [i for i, r in enumerate(members) if r["ood"]]
        if ood:
            # hollow and black: a filled colour could be a state's
            ax.plot(
                ood, np.full(len(ood), -0.08), "^", color="black", mfc="none", ms=4, clip_on=False
            )
        ax.set_xlim(-0.5, len(members) - 0.5)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylim(0, 1)
        ax.set_yticks([0, 0.5, 1])
        if not known:
            label, n_wrong = f"called {group}", ""
        else:
            label = f"true {group}" if group in classes else group
            n_wrong = f", {len(wrong)} misclassified (black marks)" if group in classes else ""
        ax.set_title(f"{label}: {len(members)} runs{n_wrong}", fontsize=10, loc="left", pad=11)
        ax.set_ylabel("probability")
    axes[0].legend(
        ncol=len(classes), loc="lower right", bbox_to_anchor=(1, 1.12), frameon=False, fontsize=9
    )
    what = "of each true state" if known else "called each state"
    axes[-1].set_xlabel(f"runs {what}, in campaign order (hollow marks below: flagged OOD)")
    return H.png(fig, dpi=90)


def _leaning(run: Mapping[str, Any]) -> str | None:
    """The state a classified run is called, or leans to when it is left uncalled."""
    return run["predicted"] if run["predicted"] is not None else run.get("most_probable")


def _called_text(run: Mapping[str, Any]) -> str:
    """What a run was called, as the tables show it (an uncalled run: what it leans to)."""
    if run["predicted"] is None and run.get("abstained"):
        return f"uncalled (leans {run.get('most_probable')})"
    return run["predicted"] or "-"


def _labelled(runs: Sequence[Mapping[str, Any]], classes: Sequence[str]) -> bool:
    """Whether any of ``runs`` has a known true state (else they are grouped as called)."""
    return any(r["state"] in classes for r in runs)


def confusion_figure(confusion: Sequence[Sequence[int]], classes: Sequence[str]) -> bytes:
    """The confusion matrix with counts and row percentages (paper, Figure 7)."""
    m = np.asarray(confusion, dtype=float)
    rows = m.sum(axis=1, keepdims=True)
    share = np.divide(m, rows, out=np.zeros_like(m), where=rows > 0)
    fig = _figure(4.8, 4.2)
    ax = fig.subplots()
    ax.imshow(share, cmap="Blues", vmin=0, vmax=1)
    for i in range(m.shape[0]):
        for j in range(m.shape[1]):
            ax.text(
                j,
                i,
                f"{int(m[i, j])}\n{100 * share[i, j]:.1f} %",
                ha="center",
                va="center",
                fontsize=10,
                color="white" if share[i, j] > 0.6 else "black",
            )
    ax.set_xticks(range(len(classes)), classes)
    ax.set_yticks(range(len(classes)), classes)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    return H.png(fig, dpi=100)


def uncertainty_figure(
    runs: Sequence[Mapping[str, Any]],
    classes: Sequence[str],
    threshold: float | None,
    healthy: str = HEALTHY,
) -> bytes:
    """Entropy against mutual information per run, and the OOD scores against the threshold
    (``healthy``: the system's healthy state, for the colours)."""
    valid = [r for r in runs if r["probabilities"] is not None]
    fig = _figure(11.5, 3.8)
    ax, ax_ood = fig.subplots(1, 2)
    known = [r for r in valid if r["state"] in classes]
    right = [r for r in known if _leaning(r) == r["state"]]
    wrong = [r for r in known if _leaning(r) != r["state"]]
    unknown = [r for r in valid if r["state"] not in classes]
    for group, style, label in (
        (right, dict(color="tab:green", alpha=0.5, s=14), "correct"),
        (wrong, dict(color="black", marker="x", s=28), "misclassified"),
        (unknown, dict(color="0.4", alpha=0.6, s=14), "true state unknown"),
    ):
        if group:
            ax.scatter(
                [r["entropy"] for r in group],
                [r["mutual_information"] for r in group],
                label=f"{label} ({len(group)})",
                **style,
            )
    ax.set_xlabel("predictive entropy (nats)")
    ax.set_ylabel("mutual information (nats)")
    ax.set_title("uncertainty per run", fontsize=10, loc="left")
    ax.axvline(np.log(len(classes)), color="0.6", lw=0.8, ls=":")
    ax.legend(fontsize=8.5, frameon=False, loc="upper left")
    ax.grid(True, alpha=0.3)
    scores = np.array([r["ood_score"] for r in valid if r["ood_score"] is not None])
    if scores.size:
        labels = sorted({r["state"] for r in valid})
        colors = state_colors([*classes, *labels], healthy)
        bins = np.linspace(0, max(scores.max(), threshold or 0) * 1.05, 40)
        for state in labels:
            s = [
                r["ood_score"] for r in valid if r["state"] == state and r["ood_score"] is not None
            ]
            ax_ood.hist(s, bins=bins, alpha=0.55, label=state, color=colors[state])
        if threshold is not None:
            ax_ood.axvline(threshold, color="darkorange", lw=2, label="OOD threshold")
        ax_ood.legend(fontsize=8.5, frameon=False, loc="upper right")
    ax_ood.set_xlabel("Mahalanobis distance to the nearest simulated state")
    ax_ood.set_ylabel("runs")
    ax_ood.set_title("out-of-distribution score", fontsize=10, loc="left")
    ax_ood.grid(True, alpha=0.3)
    return H.png(fig, dpi=90)


def _band_axes(n_channels: int, width: float = 11.5, height: float = 2.4):
    fig = _figure(width, height * ((n_channels + 1) // 2))
    axes = fig.subplots((n_channels + 1) // 2, 2, squeeze=False, sharex=True).ravel()
    return fig, axes


def _draw_bands(ax, frequencies, bands: np.ndarray, classes: Sequence[str], colors) -> None:
    """Bands ``(state, quantile, freq)`` of one channel: 90 % band and median."""
    for k, c in enumerate(classes):
        lo, mid, hi = bands[k]
        if np.all(np.isnan(mid)):
            continue
        ax.fill_between(frequencies, lo, hi, color=colors[c], alpha=0.18, lw=0)
        ax.plot(frequencies, mid, color=colors[c], lw=1.0, label=f"{c} (simulated 90 %)")


def bands_figure(
    features: Float[np.ndarray, "run channel freq"],
    states: Sequence[str],
    frequencies: np.ndarray,
    channels: Sequence[str],
    bands: np.ndarray,
    classes: Sequence[str],
    speed: float | np.ndarray,
    healthy: str = HEALTHY,
) -> bytes:
    """Every channel: the simulated band of each state and the measured runs' features
    (``healthy``: the system's healthy state, for the colours)."""
    labels = sorted(set(states))
    colors = state_colors([*classes, *labels], healthy)
    fig, axes = _band_axes(len(channels))
    for ch, ax in enumerate(axes[: len(channels)]):
        _draw_bands(ax, frequencies, bands[:, :, ch], classes, colors)
        for state in labels:
            rows = [i for i, s in enumerate(states) if s == state]
            if rows:
                ax.plot(
                    frequencies,
                    np.median(features[rows, ch], axis=0),
                    color=colors[state],
                    lw=1.6,
                    ls="--",
                    label=f"{state} measured (median of {len(rows)})",
                )
        ax.set_title(channels[ch], fontsize=10, loc="left")
        ax.set_ylabel("log10 PSD")
        ax.grid(True, alpha=0.3)
    for ax in axes[len(channels) :]:
        ax.set_visible(False)
    for ax in axes[-2:]:
        ax.set_xlabel("frequency (Hz)")
    fig.legend(
        *axes[0].get_legend_handles_labels(),
        loc="outside lower center",
        ncol=3,
        fontsize=8,
        frameon=False,
    )
    fig.suptitle(f"posterior-predictive bands at operating point {_point_text(speed)}", fontsize=10)
    return H.png(fig, dpi=90)


class _RunFigure:
    """The bands of one speed drawn once; each run's line blitted onto them (fast for many runs).

    The axes limits are fixed (``ylims`` per channel, common to all runs), so the background
    with the bands, axes and legend is rendered once and only the run's lines are drawn per run.
    """

    def __init__(self, frequencies, channels, bands_at_speed, classes, healthy, ylims):
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        self.fig, axes = _band_axes(len(channels), width=10.0, height=2.2)
        colors = state_colors(classes, healthy)
        self.lines = []
        for ch, ax in enumerate(axes[: len(channels)]):
            if bands_at_speed is not None:
                _draw_bands(ax, frequencies, bands_at_speed[:, :, ch], classes, colors)
            (line,) = ax.plot(
                frequencies,
                np.full_like(frequencies, np.nan),
                color="black",
                lw=1.8,
                label="this run",
                animated=True,
            )
            self.lines.append((ax, line))
            ax.set_ylim(*ylims[ch])
            ax.set_xlim(frequencies[0], frequencies[-1])
            ax.set_title(channels[ch], fontsize=10, loc="left")
            ax.set_ylabel("log10 PSD")
            ax.grid(True, alpha=0.3)
        for ax in axes[len(channels) :]:
            ax.set_visible(False)
        self.fig.legend(
            *axes[0].get_legend_handles_labels(),
            loc="outside lower center",
            ncol=len(classes) + 1,
            fontsize=8,
            frameon=False,
        )
        for ax in axes[-2:]:
            ax.set_xlabel("frequency (Hz)")
        self.fig.set_dpi(72)
        self.canvas = FigureCanvasAgg(self.fig)
        self.canvas.draw()
        self.background = self.canvas.copy_from_bbox(self.fig.bbox)

    def render(self, features: np.ndarray) -> bytes:
        from PIL import Image

        self.canvas.restore_region(self.background)
        for ch, (ax, line) in enumerate(self.lines):
            line.set_ydata(features[ch])
            ax.draw_artist(line)
        buffer = io.BytesIO()
        # the figure is opaque: RGB loses nothing; zlib's fastest level encodes in about half
        # the time of the default for some 10 % more bytes (a report holds a page per run)
        rgb = np.asarray(self.canvas.buffer_rgba())[..., :3]
        Image.fromarray(rgb).save(buffer, format="png", compress_level=1)
        return buffer.getvalue()


def _ylims(features: np.ndarray, band_values: np.ndarray | None) -> list[tuple[float, float]]:
    """Per channel, limits that hold every run's features and every band, padded by 5 %."""
    limits = []
    for ch in range(features.shape[1]):
        values = [features[:, ch].ravel()]
        if band_values is not None:
            values.append(band_values[:, :, :, ch].ravel())
        v = np.concatenate(values)
        v = v[np.isfinite(v)]
        lo, hi = (float(v.min()), float(v.max())) if v.size else (0.0, 1.0)
        pad = 0.05 * (hi - lo) or 1.0
        limits.append((lo - pad, hi + pad))
    return limits


def _tag(state: str | None, colors: Mapping[str, str]) -> str:
    if state is None:
        return "-"
    color = colors.get(state, UNKNOWN_COLOR)
    return f'<span class="tag" style="background:{color}">{html.escape(state)}</span>'


def _row_class(run: Mapping[str, Any], classes: Sequence[str]) -> str:
    if run["probabilities"] is None:
        return "failed"
    if run["state"] in classes and _leaning(run) != run["state"]:
        return "wrong"
    return "ood" if run["ood"] else ""


def _verdict(run: Mapping[str, Any], threshold: float | None) -> str:
    if run["probabilities"] is None:
        return f"Not classified: {run['problem']}."
    p = run["probabilities"][_leaning(run)]
    text = f"The classifier says {_leaning(run)} with probability {p:.2f}."
    if run.get("abstained"):
        text += f" It leaves the run uncalled: {run['abstained']}."
    if run["ood"]:
        text += (
            f" But the run is unlike every simulated state (OOD score {run['ood_score']:.1f} >"
            f" threshold {threshold:.1f}): treat the prediction with suspicion and check the"
            " sensors or the model."
        )
    elif p < 0.8:
        text += " The classifier is unsure: look at the probabilities of the other states."
    return text


@dataclasses.dataclass(frozen=True)
class _Inputs:
    """What every section of a damage report reads: the classification and the features."""

    classes: list[str]
    #: the system's healthy state (it may not be one of the classes)
    healthy: str
    runs: list[Mapping[str, Any]]
    metrics: Mapping[str, Any] | None
    threshold: float | None
    temperature: float
    n_failed: int
    features: np.ndarray
    frequencies: np.ndarray
    channels: Sequence[str]
    #: posterior-predictive bands ``(state, speed, quantile, channel, freq)``, their speeds
    #: and states (the classes when there are no bands)
    band_values: np.ndarray | None
    speeds: np.ndarray | None
    band_classes: list[str]

    @property
    def valid(self) -> list[Mapping[str, Any]]:
        """The classified runs."""
        return [r for r in self.runs if r["probabilities"] is not None]

    @property
    def colors(self) -> dict[str, str]:
        """A colour per class, and per other label of the runs' true states."""
        return state_colors([*self.classes, *(r["state"] for r in self.runs)], self.healthy)


@dataclasses.dataclass(frozen=True)
class ReportContext:
    """What a job adds to a damage report besides the classification, each part optional.

    Parameters
    ----------
    bands
        Posterior-predictive bands: ``states``, ``speeds`` and ``values`` of shape
        ``(state, speed, quantile, channel, freq)`` with quantiles (0.05, 0.5, 0.95).
    training
        The training record (simulated validation metrics, temperature), shown when given.
    fit
        The model updating's ``method``, ``j`` and parameter ``table``, shown when given.
    adequacy
        The fit-adequacy JSON (:func:`bayesdoor.datagen.fit_adequacy`), shown first.
    trust
        The trust JSON of the job (``verdict``, ``reasons``, ``flagged_runs``): when it is
        ``"not trusted"`` the page opens with a warning and its reasons, and the
        classification below is marked as not to be relied on.
    sections
        Further HTML sections of the campaign page (for example the discrepancy diagnosis's
        verdict and link), placed after the model updating.
    """

    bands: Mapping[str, Any] | None = None
    training: Mapping[str, Any] | None = None
    fit: Mapping[str, Any] | None = None
    adequacy: Mapping[str, Any] | None = None
    trust: Mapping[str, Any] | None = None
    sections: Sequence[str] = ()


def write_damage_report(
    folder: str | Path,
    classification: Mapping[str, Any],
    *,
    features: Float[np.ndarray, "run channel freq"],
    frequencies: Float[np.ndarray, " freq"],
    channels: Sequence[str],
    title: str = "Damage report",
    context: ReportContext = ReportContext(),
) -> Path:
    """Write ``index.html`` (the campaign) and ``runs/run-NNNN.html`` (each run) into ``folder``.

    Parameters
    ----------
    folder
        Output folder (created).
    classification
        The classification JSON (``classes``, ``healthy_state``, ``runs``, ``metrics``,
        ``ood_threshold``, ``temperature``) of :func:`bayesdoor.pipeline.classify_stage`; one
        without ``healthy_state`` is read with :data:`~bayesdoor.systems.HEALTHY`.
    features
        The classifier's input of each run, in the order of ``classification["runs"]``.
    frequencies, channels
        The feature bins (Hz) and channel names.
    title
        The page title.
    context
        The predictive bands, training record, fit, adequacy, trust and further sections
        (:class:`ReportContext`).

    Returns
    -------
    path
        The campaign page.
    """
    folder = Path(folder)
    (folder / "runs").mkdir(parents=True, exist_ok=True)
    bands = context.bands
    inputs = _Inputs(
        classes=list(classification["classes"]),
        healthy=str(classification.get("healthy_state", HEALTHY)),
        runs=list(classification["runs"]),
        metrics=classification.get("metrics"),
        threshold=classification.get("ood_threshold"),
        temperature=classification.get("temperature", float("nan")),
        n_failed=classification.get("n_failed") or 0,
        features=features,
        frequencies=frequencies,
        channels=channels,
        band_values=None if bands is None else np.asarray(bands["values"]),
        speeds=None if bands is None else np.asarray(bands["speeds"], dtype=float),
        band_classes=list(classification["classes"] if bands is None else bands["states"]),
    )
    stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    index = folder / "index.html"
    subtitle = f"{len(inputs.runs)} runs, generated {stamp}"
    body = "".join(_campaign_sections(inputs, classification, context))
    _write_text(index, H.page(title, subtitle, body))
    _write_run_pages(folder / "runs", inputs, f"{title}, generated {stamp}")
    return index


def _campaign_sections(
    inputs: _Inputs, classification: Mapping[str, Any], context: ReportContext
) -> list[str]:
    """The campaign page's sections, in their order."""
    adequacy, trust, fit = context.adequacy, context.trust, context.fit
    opening = [] if adequacy is None and trust is None else [trust_section(adequacy, trust)]
    return [
        _answer_section(inputs, trust),
        *opening,
        *_summary(inputs),
        _probabilities_section(inputs),
        *([] if inputs.metrics is None else [_calibration_section(inputs, context.training)]),
        *_selective_section(classification, context.training),
        _uncertainty_section(inputs),
        *_bands_section(inputs),
        *([] if fit is None else [_fit_section(fit)]),
        *context.sections,
        _runs_section(inputs),
    ]


#: the runs the answer lists first, at most
RUNS_TO_LOOK_AT = 10


def _answer_section(inputs: _Inputs, trust: Mapping[str, Any] | None) -> str:
    """The page's opening: how many runs were called each state, and the runs to look at
    first (those called a fault, most probable first, and those the classifier cannot
    vouch for), each linked to its page."""
    classes, colors, valid = inputs.classes, inputs.colors, inputs.valid
    counts = [
        (f"called {c}", str(sum(1 for r in valid if r["predicted"] == c)), "") for c in classes
    ]
    uncalled = sum(1 for r in valid if r["predicted"] is None)
    if uncalled:
        counts.append(("left uncalled (selective risk)", str(uncalled), "bad"))
    if inputs.n_failed:
        counts.append(("not classified", str(inputs.n_failed), "bad"))
    if trust is not None and trust.get("verdict"):
        verdict = str(trust["verdict"])
        counts.append(("trust (below)", verdict, "good" if verdict == "trusted" else "bad"))
    flagged = [(r, _reasons(r, classes, inputs.healthy)) for r in valid]
    looked = sorted(
        ((r, why) for r, why in flagged if why),
        key=lambda item: -_concern(item[0], classes, inputs.healthy),
    )
    parts = [H.cards(counts)]
    if not looked:
        parts.append(H.note("No run was called a fault, and the classifier vouches for every one."))
        return H.section("What the runs were called", *parts)
    rows = [
        [
            f'<a href="runs/{_run_file(r["run"])}">{r["run"]}</a>',
            _tag(_leaning(r), colors) + ("" if r["predicted"] else " (uncalled)"),
            f"{r['probabilities'][_leaning(r)]:.3f}",
            html.escape("; ".join(why)),
        ]
        for r, why in looked[:RUNS_TO_LOOK_AT]
    ]
    more = len(looked) - RUNS_TO_LOOK_AT
    caption = (
        f"The {min(len(looked), RUNS_TO_LOOK_AT)} runs to look at first, of {len(looked)} called "
        "a fault or not vouched for: the most probably faulty first"
        + (f"; the other {more} are in the table of every run below." if more > 0 else ".")
    )
    parts += [
        H.note(caption),
        H.table(["run", "called", "probability", "why"], rows, left=1, raw=True),
    ]
    return H.section("What the runs were called", *parts)


def _concern(run: Mapping[str, Any], classes: Sequence[str], healthy: str) -> float:
    """The probability that the run is not ``healthy`` (without a healthy class: that it is
    not what it was called)."""
    p = run["probabilities"]
    if healthy in classes:
        return 1.0 - float(p[healthy])
    return 1.0 - float(p[_leaning(run)])


def _reasons(run: Mapping[str, Any], classes: Sequence[str], healthy: str) -> list[str]:
    """Why a classified run is worth a look (none: called healthy, and vouched for)."""
    reasons = []
    if run["predicted"] is None:
        reasons.append(f"left uncalled, leaning {_leaning(run)}")
    elif healthy in classes and run["predicted"] != healthy:
        reasons.append(f"called {run['predicted']}")
    if run["ood"]:
        reasons.append("unlike every simulated state (OOD)")
    if run.get("uncertain"):
        reasons.append("uncertain")
    if run.get("corroborated") is False:
        reasons.append("its signal does not back the call")
    return reasons


def _summary(inputs: _Inputs) -> list[str]:
    """The headline cards, a warning when most runs are OOD, and how to read the page."""
    metrics, valid = inputs.metrics, inputs.valid
    headline = [("runs classified", f"{len(valid)} / {len(inputs.runs)}", "")]
    if metrics is not None:
        acc = metrics["accuracy"]
        headline += [
            ("accuracy", f"{100 * acc:.1f} %", "good" if acc >= 0.95 else "bad"),
            ("ECE", _fmt(metrics["ece"]), "good" if metrics["ece"] <= 0.05 else "bad"),
            ("NLL", _fmt(metrics["nll"]), ""),
            ("Brier", _fmt(metrics["brier"]), ""),
        ]
    n_ood = sum(1 for r in valid if r["ood"])
    headline.append(("flagged OOD", str(n_ood), "bad" if n_ood else "good"))
    n_uncertain = sum(1 for r in valid if r.get("uncertain"))
    headline.append(("uncertain", str(n_uncertain), "bad" if n_uncertain else "good"))
    if any(r.get("corroborated") is not None for r in valid):
        n_against = sum(1 for r in valid if r.get("corroborated") is False)
        headline.append(("not corroborated", str(n_against), "bad" if n_against else "good"))
    if inputs.n_failed:
        headline.append(("not classified", str(inputs.n_failed), "bad"))
    parts = [H.cards(headline)]
    if valid and n_ood > len(valid) / 2:
        parts.append(
            H.warning(
                f"{n_ood} of {len(valid)} runs lie outside the simulated training data (OOD): the "
                "model does not reproduce these measurements well, so the classifier "
                "extrapolates and its probabilities, calibrated on simulations, may be "
                "overconfident here. The band figures below show where the measurements leave "
                "the simulated bands; consider diagnosing the discrepancy before trusting the "
                "verdicts."
            )
        )
    parts.append(
        H.note(
            f"Classes: {', '.join(inputs.classes)}. Probabilities are the ensemble's, calibrated "
            f"by temperature scaling (T = {inputs.temperature:.3f}, "
            "fitted on simulated validation runs only). Runs whose features lie farther from "
            "every simulated state than 99 % of the simulated validation runs are flagged "
            "out-of-distribution (OOD)."
        )
    )
    return parts


def _probabilities_section(inputs: _Inputs) -> str:
    """The stacked class probabilities of every run (the paper's Figure 6)."""
    return H.section(
        "Class probabilities per run",
        H.img(
            probability_bars(inputs.runs, inputs.classes, inputs.healthy),
            "probability bars",
            (
                "Stacked calibrated probabilities of each run, grouped by true state (as in the "
                "paper's Figure 6). A bar entirely in the colour of its panel's state is a "
                "confident, correct prediction."
                if _labelled(inputs.valid, inputs.classes)
                else "Stacked calibrated probabilities of each run, grouped by the state it was "
                "called (no run's true state is known). A bar entirely in the colour of its "
                "panel's state is a confident call."
            ),
        ),
    )


def _calibration_section(inputs: _Inputs, training: Mapping[str, Any] | None) -> str:
    """The metrics table, the confusion matrix and the reliability diagram."""
    metrics, classes = inputs.metrics, inputs.classes
    assert metrics is not None
    known = [r for r in inputs.valid if r["state"] in classes]
    labels = np.array([classes.index(r["state"]) for r in known])
    probs = np.array([[r["probabilities"][c] for c in classes] for r in known])
    metric_rows = [
        [name, _fmt(metrics[key], 4)]
        for name, key in (
            ("accuracy", "accuracy"),
            ("expected calibration error (15 equal-width bins)", "ece"),
            ("expected calibration error (15 equal-mass bins)", "ece_mass"),
            ("negative log-likelihood (nats per run)", "nll"),
            ("Brier score", "brier"),
        )
    ]
    metric_rows.append(["runs with a known true state", str(metrics["runs"])])
    if training is not None:
        val = training["validation"]["calibrated"]
        metric_rows.append(
            ["simulated validation accuracy / ECE", f"{val['accuracy']:.4f} / {val['ece']:.4f}"]
        )
    with tempfile.TemporaryDirectory() as tmp:
        reliability = plot_reliability(
            probs,
            labels,
            Path(tmp) / "reliability.png",
            n_bins=min(15, max(1, len(labels))),
            title="Reliability on the classified runs",
        ).read_bytes()
    return H.section(
        "Accuracy and calibration",
        H.table(["metric", "value"], metric_rows),
        H.img(
            confusion_figure(metrics["confusion"], classes),
            "confusion matrix",
            "Confusion matrix (paper, Figure 7): counts and share of each true state.",
        ),
        H.img(
            reliability,
            "reliability diagram",
            "Accuracy against confidence. Points on the diagonal mean the stated "
            "probabilities can be taken at face value.",
        ),
    )


def risk_coverage_figure(
    curves: Sequence[tuple[str, Mapping[str, Sequence[float]]]],
    target_risk: float,
    threshold: float | None,
) -> bytes:
    """Selective risk against coverage, one line per labelled set of runs, with the target
    risk and each curve's point at the threshold."""
    fig = _figure(6.4, 3.8)
    ax = fig.subplots()
    for (label, curve), color in zip(curves, ("tab:blue", "black"), strict=False):
        coverage = np.asarray(curve["coverage"], dtype=float)
        risk = np.asarray(curve["risk"], dtype=float)
        ax.step(coverage, risk, where="post", color=color, label=label)
        if threshold is not None and coverage.size:
            at = np.flatnonzero(np.asarray(curve["threshold"], dtype=float) >= threshold)
            if at.size:
                ax.plot(coverage[at[-1]], risk[at[-1]], "o", color=color, ms=6)
    ax.axhline(target_risk, color="tab:red", lw=1, ls="--", label=f"target {100 * target_risk:g} %")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, None)
    ax.set_xlabel("coverage (share of runs called, most probable first)")
    ax.set_ylabel("selective risk (share of calls wrong)")
    ax.legend(frameon=False, fontsize=9)
    return H.png(fig, dpi=100)


def _selective_section(
    classification: Mapping[str, Any], training: Mapping[str, Any] | None
) -> list[str]:
    """The selective threshold, what it left uncalled and the risk-coverage curves (on the
    held-out simulations it was chosen on and on the campaign's labelled runs)."""
    selective = classification.get("selective")
    if not selective:
        return []
    from ..classify import risk_coverage

    curves: list[tuple[str, Mapping[str, Sequence[float]]]] = []
    validation = None if training is None else training.get("validation")
    if validation and validation.get("labels"):
        c = risk_coverage(np.asarray(validation["probabilities"]), np.asarray(validation["labels"]))
        curves.append(
            (
                "held-out simulations",
                {
                    "coverage": c.coverage.tolist(),
                    "risk": c.risk.tolist(),
                    "threshold": c.threshold.tolist(),
                },
            )
        )
    labelled = (classification.get("metrics") or {}).get("selective")
    if labelled and labelled["curve"]["coverage"]:
        curves.append(("this campaign's labelled runs", labelled["curve"]))
    threshold = selective["threshold"]
    rows = [
        ["target selective risk", f"{100 * selective['target_risk']:g} %"],
        [
            "lowest probability called",
            "none (no run called)" if threshold is None else f"{threshold:.3f}",
        ],
        [
            "runs called / expected share of wrong calls",
            f"{selective['called']} of {selective['runs']} / "
            f"{100 * selective['expected_risk']:.1f} %",
        ],
    ]
    if labelled and labelled["accuracy"] is not None:
        rows.append(
            [
                "labelled runs called: accuracy (95 % upper bound of the risk)",
                f"{labelled['accuracy']:.3f} ({100 * labelled['risk_upper_95']:.1f} %)",
            ]
        )
    parts = [
        H.note(
            "Runs are called from the most probable down while the share of wrong calls their "
            "probabilities promise stays under the target; the others are left uncalled (each "
            "run's page says which state it leans to). The promise holds as far as the "
            "probabilities are calibrated: where true states are known, the curve shows the "
            "share of calls actually wrong."
        ),
        H.table(["", "value"], rows),
    ]
    if curves:
        parts.append(
            H.img(
                risk_coverage_figure(curves, selective["target_risk"], threshold),
                "risk-coverage curve",
                "Selective risk against coverage, runs called from the most probable down; "
                "dots: the threshold's point.",
            )
        )
    return [H.section("Selective classification: which runs are called", *parts)]


def _uncertainty_section(inputs: _Inputs) -> str:
    """Entropy against mutual information, and the OOD scores against the threshold."""
    return H.section(
        "Uncertainty and out-of-distribution runs",
        H.img(
            uncertainty_figure(inputs.runs, inputs.classes, inputs.threshold, inputs.healthy),
            "uncertainty",
            "Left: total uncertainty (entropy) against disagreement between the ensemble's "
            "members (mutual information); the dotted line is the entropy of a uniform "
            "guess. Right: OOD scores by true state against the threshold.",
        ),
    )


def _bands_section(inputs: _Inputs) -> list[str]:
    """The measured features against the posterior-predictive bands, one figure per
    operating point with classified runs (none without bands)."""
    runs, band_values, speeds = inputs.runs, inputs.band_values, inputs.speeds
    if band_values is None or speeds is None or not inputs.valid:
        return []
    figures = []
    for j, v in enumerate(speeds):
        at = [
            i
            for i, r in enumerate(runs)
            if r["probabilities"] is not None and np.allclose(_point(r), v)
        ]
        if not at:
            continue
        figures.append(
            H.img(
                bands_figure(
                    inputs.features[at],
                    [runs[i]["state"] for i in at],
                    inputs.frequencies,
                    inputs.channels,
                    band_values[:, j],
                    inputs.band_classes,
                    float(v) if v.ndim == 0 else v,
                    inputs.healthy,
                ),
                f"bands at operating point {_point_text(v)}",
            )
        )
    return [
        H.section(
            "Measured features against the posterior-predictive bands",
            H.note(
                "Shaded: the 5-95 % range of the simulated training features of each state "
                "(the posterior-predictive distribution the classifier learned from); "
                "dashed: the median of the measured runs of each true state at that speed. "
                "Where a measured line leaves its own state's band, the model and the "
                "measurements disagree there."
            ),
            *figures,
        )
    ]


def _fit_section(fit: Mapping[str, Any]) -> str:
    """The model updating's method, objective and parameter table."""
    rows = [
        [
            row["parameter"],
            _fmt(row["point"], 4),
            _fmt(row.get("mean"), 4),
            _fmt(row.get("sd"), 4),
            "-" if "q05" not in row else f"{row['q05']:.4g} to {row['q95']:.4g}",
        ]
        for row in fit["table"]
    ]
    return H.section(
        "Model updating on the calibration runs",
        H.note(
            f"Method: {fit['method']}; objective J at the point: {_fmt(fit['j'], 4)}. "
            "The training runs were simulated from these parameters. They are effective "
            "values: the reduced model's best description of this machine, which it "
            "does not describe exactly (see the fit adequacy above), not the machine's "
            "physical values."
        ),
        H.table(["parameter", "point", "posterior mean", "sd", "90 % interval"], rows),
    )


def _runs_section(inputs: _Inputs) -> str:
    """Every run in one table, each linked to its own page."""
    classes, colors = inputs.classes, inputs.colors
    run_rows, row_classes = [], []
    for r in inputs.runs:
        p = r["probabilities"]
        run_rows.append(
            [
                f'<a href="runs/{_run_file(r["run"])}">{r["run"]}</a>',
                _tag(r["state"], colors),
                _point_text(_point(r)),
                _tag(r["predicted"], colors)
                if r["predicted"] is not None or not r.get("abstained")
                else "uncalled, leans " + _tag(_leaning(r), colors),
                *[("-" if p is None else f"{p[c]:.3f}") for c in classes],
                _fmt(r["entropy"]),
                _fmt(r["mutual_information"]),
                "-" if r["ood"] is None else ("OOD" if r["ood"] else "no"),
                html.escape(r["problem"] or ""),
            ]
        )
        row_classes.append(_row_class(r, classes))
    return H.section(
        "Every run",
        H.note(
            "Red rows: misclassified; yellow: flagged OOD; grey: not classified. Each run "
            "number links to its own report."
        ),
        H.table(
            [
                "run",
                "true",
                "operating point",
                "predicted",
                *[f"p({c})" for c in classes],
                "entropy",
                "MI",
                "OOD",
                "problem",
            ],
            run_rows,
            row_classes=row_classes,
            left=1,
            raw=True,
        ),
    )


def _write_run_pages(folder: Path, inputs: _Inputs, subtitle: str) -> None:
    """One page per run: its cards, verdict, probabilities and features against the bands.

    The bands of each operating point are drawn once and every run's lines on top of them.
    """
    renderers: dict[int, _RunFigure] = {}
    ylims = _ylims(inputs.features, inputs.band_values)
    for i, r in enumerate(inputs.runs):
        body = [_run_cards(r, inputs), H.note(_verdict(r, inputs.threshold))]
        if r["probabilities"] is not None:
            j = _nearest_speed(r, inputs.speeds)
            if j not in renderers:
                renderers[j] = _RunFigure(
                    inputs.frequencies,
                    inputs.channels,
                    None if inputs.band_values is None else inputs.band_values[:, j],
                    inputs.band_classes,
                    inputs.healthy,
                    ylims,
                )
            body += _run_figures(r, inputs, j, renderers[j].render(inputs.features[i]))
        body.append('<p><a href="../index.html">back to the campaign report</a></p>')
        page = H.page(f"Run {r['run']}", subtitle, "".join(body))
        _write_text(folder / _run_file(r["run"]), page)


def _run_cards(r: Mapping[str, Any], inputs: _Inputs) -> str:
    """A run's true and predicted state and its uncertainty, as cards."""
    return H.cards(
        [
            ("true state", r["state"], ""),
            ("predicted", _called_text(r), "bad" if _row_class(r, inputs.classes) else ""),
            ("entropy (nats)", _fmt(r["entropy"]), ""),
            ("mutual information", _fmt(r["mutual_information"]), ""),
            ("OOD score", _fmt(r["ood_score"], 2), "bad" if r["ood"] else ""),
        ]
    )


def _nearest_speed(r: Mapping[str, Any], speeds: np.ndarray | None) -> int:
    """The index of the bands' operating point nearest the run's (0 without bands, or for a
    run whose point is not known)."""
    point = _point(r)
    if speeds is None or not np.all(np.isfinite(point)):
        return 0
    return int(np.argmin(np.abs(speeds - point).reshape(len(speeds), -1).sum(1)))


def _run_figures(r: Mapping[str, Any], inputs: _Inputs, j: int, figure: bytes) -> list[str]:
    """A classified run's probability table and its features against the bands at ``j``."""
    speeds = inputs.speeds
    speed_note = "" if speeds is None else f" at operating point {_point_text(speeds[j])}"
    return [
        H.table(
            ["state", "probability"],
            [[c, f"{r['probabilities'][c]:.4f}"] for c in inputs.classes],
        ),
        H.img(
            figure,
            "features against bands",
            "The run's log-PSD features (black) against the 5-95 % posterior-predictive "
            f"band of each state{speed_note} (simulated training runs).",
        ),
    ]


def _run_file(run: int) -> str:
    return f"run-{int(run):04d}.html"


def _write_text(path: Path, text: str) -> None:
    atomic_write(path, lambda tmp: tmp.write_text(text), overwrite=True)


def trust_section(adequacy: Mapping[str, Any] | None, trust: Mapping[str, Any] | None) -> str:
    """The report's opening section: can the classification below be trusted, and why not."""
    parts: list[str] = []
    if trust is not None and trust.get("verdict") == "not trusted":
        parts.append(
            H.warning(
                "The classification below cannot be trusted: "
                + "; ".join(str(r) for r in trust.get("reasons", []))
                + ". Its probabilities are calibrated on simulations that do not describe "
                "these measurements; read them as the simulations' view, not as the machine's "
                "state. Diagnose the discrepancy, or train on the source that carries the "
                "model error (posterior+model_error)."
            )
        )
    elif trust is not None and trust.get("verdict") == "limited":
        parts.append(
            H.warning(
                "The classification below is limited: "
                + "; ".join(str(w) for w in trust.get("warnings", []))
                + ". The fit's adequacy and the recognition of the measured healthy runs "
                "passed, and fewer than half of the runs are flagged."
            )
        )
    elif trust is not None:
        parts.append(
            H.note(
                "Trusted: the training simulations reproduce the measured healthy runs, the "
                "ensemble recognises them, and the share of runs flagged out-of-distribution "
                f"is what its threshold admits (each check at a false-alarm rate of "
                f"{100 * float(trust.get('alpha', 0.01)):.0f} %)."
            )
        )
    if adequacy is not None and adequacy.get("verdict") is not None:
        rows = [
            [
                c["channel"],
                f"{c['band_hz'][0]:.0f}-{c['band_hz'][1]:.0f}",
                f"{c['offset_db']:+.1f}",
                f"{c['offset_sd']:+.1f}",
                f"{c['statistic']:+.1f}",
            ]
            for c in adequacy.get("failing", [])
        ]
        parts.append(H.note(f"Fit adequacy: {adequacy.get('summary', adequacy['verdict'])}."))
        model = adequacy.get("model")
        if model is not None and model is not adequacy and model.get("summary"):
            parts.append(
                H.note(
                    f"The fitted model alone (without the measured discrepancy): "
                    f"{model['summary']}. Its parameters are effective values of the reduced "
                    "model on this machine, not the machine's physical values."
                )
            )
        if rows:
            parts.append(
                H.table(
                    ["channel", "band (Hz)", "offset (dB)", "offset (SD)", "S"],
                    rows,
                )
            )
    if trust is not None and trust.get("flagged_runs"):
        flagged = ", ".join(str(r) for r in trust["flagged_runs"][:40])
        more = len(trust["flagged_runs"]) - 40
        parts.append(
            H.note(
                f"Flagged runs (out-of-distribution, called healthy but unlike the simulated "
                f"healthy runs, or called a state the system's signature check does not "
                f"find): {flagged}{f' and {more} more' if more > 0 else ''}."
            )
        )
    return H.section("Can these results be trusted?", *parts)


def _point(run: Mapping[str, Any]) -> np.ndarray:
    """A classified run's operating point (NaN where unknown), from its JSON entry."""
    point = run.get("operating")
    values = np.atleast_1d(np.asarray(point if point is not None else np.nan, dtype=object))
    return np.array([np.nan if v is None else float(v) for v in values], dtype=float)


def _point_text(point) -> str:
    """An operating point as text: its value, or its values separated by ' / '."""
    values = np.atleast_1d(np.asarray(point, dtype=float))
    return " / ".join("-" if not np.isfinite(v) else f"{v:g}" for v in values)
