"""The discrepancy-diagnosis report: one self-contained HTML page, figures embedded.

The page shows where the simulation departs from the measurements (the residual map, channel by
frequency, with the significant regions marked), the verdict, every ranked cause with its
evidence in words and in a figure chosen by the kind of its signature (the peak frequency of a
feature against the run speed for speed-tracking tones, the excess spectrum around a missing
resonance, the measured against simulated coherence for a cross-axis leak, the rest spectrum
for a line present while the system stands still), the fitted parameters with their
uncertainty and the gain of each extension. Matplotlib is used through
``matplotlib.figure.Figure`` only, so the caller's pyplot backend is left alone.
"""

from __future__ import annotations

import html
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from jaxtyping import Float

from ..diagnose import (
    Catalogue,
    CrossAxisCoherence,
    Features,
    FixedFrequency,
    Region,
    ResidualMap,
    RestLine,
    SpeedTracking,
)
from ..io import atomic_write
from . import _html as H

#: the colour scale of the residual map saturates at this combined statistic
_Z_CLIP = 8.0


def _figure(width: float, height: float) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), layout="constrained")


def _number(value: Any) -> str:
    if isinstance(value, bool) or value is None:
        return "-" if value is None else ("yes" if value else "no")
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        return "-" if not np.isfinite(value) else f"{float(value):.4g}"
    if isinstance(value, list | tuple):
        return ", ".join(_number(v) for v in value)
    return str(value)


def _first(value: Mapping[str, Any], *keys: str) -> Any:
    """The first of ``keys`` that ``value`` holds and is not ``None``."""
    return next((value[k] for k in keys if value.get(k) is not None), None)


def parameter_text(value: Any) -> str:
    """A parameter as text: a number, or ``mean ± sd [q5, q95]`` from a summary mapping.

    A summary's centre is its ``mean``, else its ``point`` (a CMA-ES optimum), else ``value``;
    a diagnosis refit's ``folds`` (each held-out fold's own fitted value) follow it, and its
    ``search_box`` when the fit stopped at one of its ends (``at_bound``).
    """
    if not isinstance(value, Mapping):
        return _number(value)
    centre = _first(value, "mean", "point", "value")
    if centre is None:
        return ", ".join(f"{k} {_number(v)}" for k, v in value.items())
    text = _number(centre)
    if value.get("sd") is not None:
        text += f" ± {_number(value['sd'])}"
    lo, hi = _first(value, "q5", "q05"), value.get("q95")
    if lo is not None and hi is not None:
        text += f" [{_number(lo)}, {_number(hi)}]"
    if value.get("folds"):
        text += f" (held-out folds: {_number(list(value['folds']))})"
    if value.get("at_bound") and value.get("search_box"):
        lo, hi = value["search_box"]
        text += (
            f", at the {value['at_bound']} end of its search box [{_number(lo)}, "
            f"{_number(hi)}]: not an estimate"
        )
    return text


# ------------------------------------------------------------------------------------ figures


def residual_map_figure(residuals: ResidualMap) -> bytes:
    """The combined residual statistic per channel and frequency, significant regions boxed.

    Top: the statistic combined over runs at fixed frequency as an image (red: the measurements
    hold more power than the model predicts), the bins Benjamini-Hochberg rejects dotted and
    the regions boxed and numbered. Below: each channel's excess of measured over predicted
    power averaged over runs (dB), significant bins shaded.
    """
    channels = residuals.channels
    f = residuals.freqs
    n = len(channels)
    fig = _figure(11.5, 2.2 + 1.25 * n + 0.9 * n)
    axes = fig.subplots(n + 1, 1, sharex=True, gridspec_kw={"height_ratios": [0.9 * n] + [1.0] * n})
    ax = axes[0]
    step = residuals.resolution_hz
    image = ax.imshow(
        np.clip(residuals.combined, -_Z_CLIP, _Z_CLIP),
        aspect="auto",
        cmap="RdBu_r",
        vmin=-_Z_CLIP,
        vmax=_Z_CLIP,
        extent=(f[0] - step / 2, f[-1] + step / 2, n - 0.5, -0.5),
        interpolation="nearest",
    )
    rows, cols = np.nonzero(residuals.significant)
    ax.plot(f[cols], rows, ".", color="black", ms=2.5)
    # numbered as the feature list under the figure lists them (wavenumber regions included)
    for k, region in enumerate(residuals.regions, start=1):
        if region.domain != "frequency":
            continue
        c = channels.index(region.channel)
        ax.add_patch(_box(region.low - step / 2, c, region.high - region.low + step))
        ax.annotate(str(k), (region.peak, c - 0.42), ha="center", va="top", fontsize=8)
    ax.set_yticks(range(n), channels)
    ax.set_title(
        f"combined residual Z over {residuals.z.shape[0]} runs "
        f"(dots: significant, {residuals.method} q = {residuals.q:g}, {residuals.n_tests} tests)",
        fontsize=10,
        loc="left",
    )
    fig.colorbar(image, ax=ax, label="Z", pad=0.01, aspect=12)
    mean_excess = np.mean(residuals.excess_db, axis=0)
    for c, (ax_c, name) in enumerate(zip(axes[1:], channels, strict=True)):
        ax_c.plot(f, mean_excess[c], color="0.25", lw=0.8)
        ax_c.axhline(0.0, color="0.6", lw=0.6)
        for lo, hi in _spans(f, residuals.significant[c]):
            ax_c.axvspan(lo - step / 2, hi + step / 2, color="tab:red", alpha=0.25, lw=0)
        ax_c.set_ylabel(f"{name}\ndB", fontsize=9)
    axes[-1].set_xlabel("frequency (Hz)")
    axes[1].set_title(
        "measured minus predicted power, mean over runs (shaded: significant)",
        fontsize=10,
        loc="left",
    )
    return H.png(fig, dpi=90)


def _box(x: float, row: int, width: float) -> Any:
    from matplotlib.patches import Rectangle

    return Rectangle((x, row - 0.5), width, 1.0, fill=False, edgecolor="black", lw=1.0)


def _spans(f: np.ndarray, mask: np.ndarray) -> list[tuple[float, float]]:
    """Contiguous ``True`` stretches of ``mask`` as ``(first, last)`` frequencies."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    return [(float(f[a]), float(f[b - 1])) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def speed_figure(region: Region, speeds: Float[np.ndarray, " run"] | Sequence[float]) -> bytes:
    """Each run's peak frequency of a feature against its speed, with both speed models.

    A tone from a spatial period lies on ``f = v / wavelength`` (through the origin); a
    resonance on ``f = c`` (flat). Filled markers: runs with a prominent peak (used in the
    fit); open markers: runs searched without one.
    """
    v = np.asarray(speeds, dtype=float)
    peaks = region.runs.frequency_hz
    affected = region.runs.affected
    fig = _figure(5.6, 3.8)
    ax = fig.subplots()
    ax.plot(v[affected], peaks[affected], "o", color="tab:blue", label="runs with a peak")
    other = np.isfinite(peaks) & ~affected
    if other.any():
        ax.plot(v[other], peaks[other], "o", mfc="none", color="tab:blue", label="other runs")
    grid = np.linspace(0.0, 1.1 * float(np.nanmax(v)), 50)
    fit = region.speed
    if np.isfinite(fit.period) and fit.period > 0:
        ax.plot(
            grid,
            grid / fit.period,
            color="tab:orange",
            label=f"f = v / {fit.period:.4g}",
        )
    if np.isfinite(fit.frequency_hz):
        ax.axhline(
            fit.frequency_hz, color="tab:green", ls="--", label=f"f = {fit.frequency_hz:.1f} Hz"
        )
    ax.set_xlim(0.0, grid[-1])
    ax.set_xlabel("run speed (operating condition)")
    ax.set_ylabel("peak frequency (Hz)")
    ax.set_title(f"{region.channel}: speed dependence: {fit.preferred}", fontsize=10, loc="left")
    ax.legend(fontsize=8, frameon=False)
    return H.png(fig, dpi=90)


def excess_figure(region: Region, residuals: ResidualMap) -> bytes:
    """The excess of measured over predicted power around a frequency region, run by run."""
    f = residuals.freqs
    c = residuals.channels.index(region.channel)
    half = max(10.0 * residuals.resolution_hz, region.high - region.low)
    keep = (f >= region.low - half) & (f <= region.high + half)
    fig = _figure(5.6, 3.8)
    ax = fig.subplots()
    for r in range(residuals.excess_db.shape[0]):
        ax.plot(f[keep], residuals.excess_db[r, c, keep], color="0.7", lw=0.7)
    ax.plot(f[keep], residuals.excess_db[:, c, keep].mean(axis=0), color="black", label="mean")
    ax.axvspan(region.low, region.high, color="tab:red", alpha=0.15, lw=0, label="region")
    if np.isfinite(region.centroid_hz):
        ax.axvline(region.centroid_hz, color="tab:red", lw=1.0, label="centroid")
    ax.axhline(0.0, color="0.5", lw=0.6)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("measured - predicted (dB)")
    ax.set_title(f"{region.channel}: excess around the feature, each run", fontsize=10, loc="left")
    ax.legend(fontsize=8, frameon=False)
    return H.png(fig, dpi=90)


def coherence_figure(features: Features, pair: tuple[str, str]) -> bytes:
    """Measured against simulated coherence of a channel pair, mean over runs."""
    found = (
        []
        if features.coherence is None
        else [p for p in features.coherence.pairs if p.pair == pair]
    )
    if not found or features.coherence is None:
        raise ValueError(f"pair={pair!r} was not examined: pass one of the coherence map's pairs")
    p = found[0]
    f = features.coherence.freqs
    fig = _figure(7.5, 3.6)
    ax = fig.subplots()
    ax.plot(f, p.measured.mean(axis=0), color="tab:blue", lw=0.9, label="measured")
    ax.plot(f, p.simulated.mean(axis=0), color="0.45", lw=0.9, label="simulated")
    step = float(f[1] - f[0])
    for lo, hi in _spans(f, p.significant):
        ax.axvspan(lo - step / 2, hi + step / 2, color="tab:red", alpha=0.2, lw=0)
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("coherence")
    ax.set_title(
        f"{pair[0]}-{pair[1]}: significant excess in {100 * p.fraction_significant:.0f} % of "
        f"bins (shaded); leak {p.leak:+.3f} of {p.source} into {p.receiver}",
        fontsize=10,
        loc="left",
    )
    ax.legend(fontsize=8, frameon=False)
    return H.png(fig, dpi=90)


def rest_figure(features: Features, frequency_hz: float | None = None) -> bytes:
    """The spectra at rest (before the motion, and after where recorded) against the model."""
    rests = [
        (when, rest)
        for when, rest in (("before", features.rest_before), ("after", features.rest_after))
        if rest is not None
    ]
    if not rests:
        raise ValueError("the features hold no rest spectra: nothing was recorded at rest")
    channels = rests[0][1].channels
    fig = _figure(11.5, 1.2 + 1.6 * len(channels))
    axes = fig.subplots(len(channels), len(rests), squeeze=False, sharex=True)
    for j, (when, rest) in enumerate(rests):
        for c, name in enumerate(channels):
            ax = axes[c, j]
            ax.semilogy(rest.freqs, rest.psd[c], color="tab:blue", lw=0.8, label="measured")
            ax.semilogy(rest.freqs, rest.floor[c], color="0.6", lw=0.7, label="floor")
            if np.isfinite(rest.simulated[c]).any():
                ax.semilogy(
                    rest.freqs, rest.simulated[c], color="tab:orange", lw=0.7, label="simulated"
                )
            for line in rest.lines:
                if line.channel == name:
                    ax.plot(
                        line.frequency_hz,
                        rest.at(name, line.frequency_hz)[0],
                        "v",
                        color="black" if line.in_simulated else "tab:red",
                        ms=5,
                    )
            if frequency_hz is not None:
                ax.axvline(frequency_hz, color="tab:red", lw=0.6, ls=":")
            ax.set_ylabel(f"{name}\nPSD", fontsize=9)
            if c == 0:
                ax.set_title(
                    f"at rest {when} the motion (red marks: lines the model lacks)",
                    fontsize=10,
                    loc="left",
                )
        axes[-1, j].set_xlabel("frequency (Hz)")
    axes[0, 0].legend(fontsize=8, frameon=False)
    return H.png(fig, dpi=90)


# ------------------------------------------------------------------------------- the causes


def _region_of(cause: Mapping[str, Any], residuals: ResidualMap) -> Region | None:
    """The residual region a cause was scored on: by its description, else by its parameters."""
    feature = str(cause.get("feature", ""))
    for region in residuals.regions:
        if feature and region.describe() == feature:
            return region
    params = cause.get("parameters") or {}
    centre = params.get("frequency_hz")
    centre = centre.get("mean") if isinstance(centre, Mapping) else centre
    if isinstance(centre, int | float) and residuals.regions:
        frequency = [r for r in residuals.regions if r.domain == "frequency"] or list(
            residuals.regions
        )
        return min(frequency, key=lambda r: abs(r.frequency_hz - float(centre)))
    return None


def _pair_of(cause: Mapping[str, Any], features: Features) -> tuple[str, str] | None:
    if features.coherence is None:
        return None
    params = cause.get("parameters") or {}
    receiver, source = params.get("receiver"), params.get("source")
    feature = str(cause.get("feature", ""))
    for p in features.coherence.pairs:
        if {receiver, source} == set(p.pair) or f"{p.pair[0]}-{p.pair[1]}" in feature:
            return p.pair
    return None


def cause_figures(
    cause: Mapping[str, Any], features: Features, signature: Any | None
) -> list[tuple[bytes, str]]:
    """The figures that show a cause's evidence, chosen by the kind of its signature.

    Without a known signature, a cause with a residual region gets the region's speed plot and
    excess spectrum.
    """
    residuals = features.residuals
    out: list[tuple[bytes, str]] = []
    if isinstance(signature, CrossAxisCoherence):
        pair = _pair_of(cause, features)
        if pair is not None:
            out.append((coherence_figure(features, pair), "coherence, measured and simulated"))
        return out
    if isinstance(signature, RestLine):
        if features.rest_before is not None or features.rest_after is not None:
            params = cause.get("parameters") or {}
            line = params.get("line_frequency_hz", params.get("frequency_hz"))
            line = line.get("mean") if isinstance(line, Mapping) else line
            out.append(
                (
                    rest_figure(features, float(line) if isinstance(line, int | float) else None),
                    "spectra at rest: a line the model lacks is present while nothing moves",
                )
            )
        return out
    region = _region_of(cause, residuals)
    if region is None:
        return out
    if residuals.speeds is not None:
        text = (
            "a tone from a spatial period tracks the speed (orange line through the origin)"
            if isinstance(signature, SpeedTracking)
            else "a resonance stays at one frequency at every speed (dashed line)"
        )
        out.append((speed_figure(region, residuals.speeds), text))
    if region.domain == "frequency" and (
        isinstance(signature, FixedFrequency) or signature is None
    ):
        out.append((excess_figure(region, residuals), "the excess power around the feature"))
    return out


def _signature_of(name: str, catalogue: Catalogue | None) -> Any | None:
    if catalogue is None:
        return None
    for candidate in catalogue.candidates:
        if candidate.name == name:
            return candidate.signature
    return None


def _evidence_list(evidence: Any) -> str:
    """Evidence text as a list: ``"feature; check: yes (detail); ..."`` one item per part."""
    if isinstance(evidence, list | tuple):
        parts = [str(e) for e in evidence]
    else:
        parts = [p.strip() for p in str(evidence).split("; ") if p.strip()]
    if not parts:
        return ""
    items = "".join(f"<li>{html.escape(p)}</li>" for p in parts)
    return f"<ul>{items}</ul>"


def _parameters_table(parameters: Mapping[str, Any]) -> str:
    if not parameters:
        return ""
    return H.table(("parameter", "value"), [(k, parameter_text(v)) for k, v in parameters.items()])


def gain_entries(gain: Mapping[str, Any]) -> dict[str, Any]:
    """A gain's JSON for a table or a line: the per-run differences summed up as
    ``runs_gaining`` ("k of n") instead of listed."""
    entries = {k: v for k, v in gain.items() if k not in ("delta_elpd_per_run", "delta_elpd_runs")}
    per_run = gain.get("delta_elpd_per_run")
    if per_run:
        entries["runs_gaining"] = f"{sum(1 for d in per_run if d > 0)} of {len(per_run)}"
    return entries


def gain_figure(
    causes: Sequence[Mapping[str, Any]], speeds: Float[np.ndarray, " run"] | Sequence[float]
) -> bytes | None:
    """Each refitted cause's held-out gain per run (log predictive density, extended minus
    base) against the run's speed: whether every run gains a little or a few gain much,
    which decides the gain's standard error. ``None`` when no cause has per-run gains."""
    v = np.asarray(speeds, dtype=float)
    series = []
    for cause in causes:
        gain = cause.get("gain")
        if not isinstance(gain, Mapping):
            continue
        d, runs = gain.get("delta_elpd_per_run") or [], gain.get("delta_elpd_runs") or []
        if d and len(runs) == len(d) and max(runs) < v.size:
            series.append((str(cause.get("name")), v[np.asarray(runs)], np.asarray(d, float)))
    if not series:
        return None
    fig = _figure(5.6, 3.8)
    ax = fig.subplots()
    for k, (name, x, d) in enumerate(series):
        ax.plot(x, d, "os^vDP"[k % 6], label=f"{name}: {int(np.sum(d > 0))} of {d.size} gain")
    ax.axhline(0.0, color="0.4", lw=0.8)
    ax.set_xlabel("run speed (operating condition)")
    ax.set_ylabel("held-out log predictive density, gain per run")
    ax.legend(fontsize=8, frameon=False)
    return H.png(fig, dpi=90)


def power_figure(limits: Mapping[str, Mapping[str, Any]]) -> bytes | None:
    """Each cause's power curve: the probability that the decision rule names it against its
    size, in its typical configuration (one panel per cause, the sizes in the cause's
    display unit when its words give one), the limit's power dashed. ``None`` when no cause
    has a curve."""
    shown = [
        (name, limit)
        for name, limit in limits.items()
        if isinstance(limit, Mapping) and limit.get("configurations")
    ]
    if not shown:
        return None
    fig = _figure(3.2 * len(shown), 3.0)
    axes = np.atleast_1d(fig.subplots(1, len(shown), sharey=True))
    for ax, (name, limit) in zip(axes, shown, strict=True):
        for k, curve in enumerate(limit["configurations"]):
            x = np.asarray(curve["sizes"], dtype=float)
            ax.semilogx(x, curve["probability"], "-" if k == 0 else ":", label=curve["label"])
        ax.axhline(float(limit.get("power", 0.8)), color="0.5", lw=0.8, ls="--")
        if limit.get("family_size") is not None:
            ax.axvline(float(limit["family_size"]), color="0.3", lw=0.8, ls="-.")
            ax.text(float(limit["family_size"]), 0.05, " family limit", fontsize=6, rotation=90)
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(f"{limit.get('quantity', 'size')} ({limit.get('unit', '')})", fontsize=8)
        ax.legend(fontsize=6, frameon=False)
    axes[0].set_ylabel("probability of naming")
    axes[0].set_ylim(-0.02, 1.02)
    return H.png(fig, dpi=90)


def limit_rows(limits: Mapping[str, Mapping[str, Any]]) -> tuple[list[str], list[list[str]]]:
    """The limits table: per cause its size, unit, the typical configuration's limit if the
    model transmits the cause as the machine does, the worst over its configurations, the
    typical limit across the family of machines its transmission was measured on, and the
    limit in words."""
    rows = [
        [
            name,
            str(limit.get("quantity", "")),
            str(limit.get("unit", "")),
            "above the range" if limit.get("size") is None else _number(limit["size"]),
            "above the range" if limit.get("worst") is None else _number(limit["worst"]),
            _family_cell(limit),
            str(limit.get("words", "")),
        ]
        for name, limit in limits.items()
        if isinstance(limit, Mapping)
    ]
    header = ["cause", "size", "unit", "limit (typical)", "limit (worst)", "limit (family)"]
    return [*header, "in words"], rows


def _family_cell(limit: Mapping[str, Any]) -> str:
    """A limit across the family, or why there is none."""
    t = limit.get("transmission")
    if limit.get("family_size") is not None:
        return _number(limit["family_size"])
    if not isinstance(t, Mapping):
        return "not measured"
    if not t.get("reliable"):
        return "not transmitted as the model does"
    return "above the range"


def plan_rows(limits: Mapping[str, Mapping[str, Any]]) -> tuple[list[str], list[list[str]]]:
    """The plans table: per cause with a planned campaign (``limits[cause]["plan"]``), the
    size planned for, the runs per condition and the conditions, the runs in all, the
    probability of naming in that campaign and in this one, and the plan in words."""
    rows = []
    for name, limit in limits.items():
        plan = limit.get("plan") if isinstance(limit, Mapping) else None
        if not isinstance(plan, Mapping):
            continue
        per = plan.get("runs_per_condition")
        rows.append(
            [
                name,
                f"{_number(plan.get('size'))} {plan.get('unit', '')}".strip(),
                "none reaches the power" if per is None else str(per),
                ", ".join(_number(c) for c in plan.get("conditions", [])),
                "-" if plan.get("runs") is None else str(plan["runs"]),
                _number(plan.get("probability")),
                _number(plan.get("current_probability")),
                str(plan.get("words", "")),
            ]
        )
    header = [
        "cause",
        "size planned for",
        "runs per condition",
        "conditions",
        "runs",
        "probability",
        "this campaign",
        "in words",
    ]
    return header, rows


def _plan_items(limits: Mapping[str, Any]) -> list[str]:
    """Per cause, its limit and its planned campaign in words (the causes with a plan)."""
    return [
        f"{limit.get('words', name)}. {str(limit['plan'].get('words', '')).capitalize()}."
        for name, limit in limits.items()
        if isinstance(limit, Mapping) and isinstance(limit.get("plan"), Mapping)
    ]


def gain_rows(causes: Sequence[Mapping[str, Any]]) -> tuple[list[str], list[list[str]]]:
    """The gain table: one row per cause that reports a gain, one column per gain entry."""
    kept = [
        (str(c["name"]), gain_entries(c["gain"]))
        for c in causes
        if isinstance(c.get("gain"), Mapping) and c["gain"]
    ]
    columns: list[str] = []
    for _, g in kept:
        columns += [k for k in g if k not in columns]
    rows = [[n, *(_number(g.get(k)) for k in columns)] for n, g in kept]
    return ["cause", *columns], rows


def diagnosis_page(
    diagnosis: Mapping[str, Any],
    *,
    features: Features | None = None,
    catalogue: Catalogue | None = None,
    fit: Mapping[str, Any] | None = None,
    title: str = "Discrepancy diagnosis",
) -> str:
    """The HTML of a diagnosis report.

    Parameters
    ----------
    diagnosis
        The diagnosis JSON (``docs/cli.md``): ``verdict`` and ``causes``, each cause with
        ``name``, ``evidence``, ``parameters`` (numbers or summaries with ``mean``, ``sd``,
        ``q5``, ``q95``) and ``gain``; optional per cause: ``description``, ``score``,
        ``feature``, ``confirmed``, ``configuration``, ``alternatives`` (other causes of the
        same symptom, in words); optional at the top: ``rule``, ``notes``.
    features
        The residual features the causes were scored on, for the figures (``None``: text and
        tables only).
    catalogue
        The system's catalogue: decides which figure shows each cause's evidence.
    fit
        The base model's fit: ``method``, ``j`` and ``parameters`` (a mapping of summaries,
        as :meth:`bayesdoor.inference.FitResult.to_json` writes, or rows with a
        ``parameter`` key).
    title
        The page title.

    Returns
    -------
    str
        A complete, self-contained HTML document.
    """
    verdict = diagnosis.get("verdict")
    causes = list(diagnosis.get("causes", []))
    stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    parts = _verdict_parts(diagnosis, features)
    if features is not None:
        parts.append(
            H.section(
                "Where the model is wrong",
                H.img(
                    residual_map_figure(features.residuals),
                    "residual map",
                    "posterior-predictive residuals of the measured runs, combined over runs",
                ),
                _feature_list(features),
            )
        )
    cause_parts = [
        _cause_part(rank, cause, features, catalogue) for rank, cause in enumerate(causes, 1)
    ]
    parts.append(H.section("Ranked causes", *cause_parts))
    parts += _gain_section(causes, features)
    parts += _limits_sections(diagnosis.get("limits") or {}, verdict)
    if fit is not None:
        parts.append(H.section("Base model", _fit_table(fit)))
    return H.page(title, f"bayesdoor diagnose, {stamp}", "".join(parts))


def _verdict_parts(diagnosis: Mapping[str, Any], features: Features | None) -> list[str]:
    """The headline cards, the verdict in words, the decision rule and the notes."""
    verdict = diagnosis.get("verdict")
    causes = list(diagnosis.get("causes", []))
    parts: list[str] = []
    named = verdict not in (None, "none")
    headline = [
        ("verdict", "undecided" if verdict is None else str(verdict), "bad" if named else "good")
    ]
    if features is not None:
        headline += [
            ("runs compared", str(features.n_runs), ""),
            ("significant features", str(len(features.summary())), ""),
        ]
    parts.append(H.cards(headline))
    if verdict is None:
        parts.append(
            H.warning(
                "Significant residuals exist, but no cause has decisive evidence: see the "
                "ranked causes and the residual map."
            )
        )
    elif verdict == "none":
        parts.append(H.note("The model explains the measurements within its uncertainty."))
    else:
        top = next((c for c in causes if c.get("name") == verdict), None)
        text = f"The most likely cause of the discrepancy is {verdict}"
        if top is not None and top.get("description"):
            text += f": {top['description']}"
        parts.append(H.note(text + "."))
    if diagnosis.get("rule"):
        parts.append(H.note(f"Decision rule: {diagnosis['rule']}"))
    for message in diagnosis.get("notes", []) or []:
        parts.append(H.warning(str(message)))
    return parts


def _cause_part(
    rank: int, cause: Mapping[str, Any], features: Features | None, catalogue: Catalogue | None
) -> str:
    """One ranked cause: its header, description, evidence, parameters and figures."""
    name = str(cause.get("name"))
    header = f"{rank}. {name}"
    if cause.get("score") is not None:
        header += f" (signature score {_number(cause['score'])})"
    if cause.get("confirmed"):
        header += ", confirmed by its refit"
    body = [f"<h3>{html.escape(header)}</h3>"]
    if cause.get("description"):
        body.append(H.note(str(cause["description"])))
    if cause.get("configuration"):
        body.append(H.note(f"Extension refitted: {cause['configuration']}"))
    body.append(_evidence_list(cause.get("evidence", "")))
    for alternative in cause.get("alternatives", []) or []:
        body.append(H.warning(f"The same symptom could come from {alternative}."))
    body.append(_parameters_table(cause.get("parameters") or {}))
    if features is not None and name != "none":
        signature = _signature_of(name, catalogue)
        for data, caption in cause_figures(cause, features, signature):
            body.append(H.img(data, f"{name} evidence", caption))
    return "".join(body)


def _gain_section(causes: list, features: Features | None) -> list[str]:
    """The held-out gain of each cause's extension, when the causes carry one."""
    gain_header, rows = gain_rows(causes)
    if not rows:
        return []
    speeds = None if features is None else features.residuals.speeds
    figure = None if speeds is None else gain_figure(causes, speeds)
    return [
        H.section(
            "Gain of the extensions",
            H.note(
                "Held-out measures of the base model and of the model extended with each "
                "cause (fitted on part of the healthy runs, judged on the others)."
            ),
            H.table(gain_header, rows),
            ""
            if figure is None
            else H.img(figure, "gain per run", "held-out gain of each run against its speed"),
        )
    ]


def _limits_sections(limits: Mapping[str, Any], verdict: Any) -> list[str]:
    """The detection limits of the causes and, after a verdict of none, the campaigns that
    would see smaller ones."""
    if not limits:
        return []
    limit_header, limit_table = limit_rows(limits)
    power = power_figure(limits)
    parts = [
        H.section(
            "Limits: what these runs could not have shown",
            H.note(
                "Per cause, the size of its key parameter that the decision rule would "
                "name with the stated probability in these runs, from the expected "
                "held-out gain of the extension at that size against the Welch variance "
                "and the base model's error (docs/diagnosis.md, Limits). A cause smaller "
                "than its limit is not excluded by a verdict of none."
            ),
            H.table(limit_header, limit_table),
            ""
            if power is None
            else H.img(power, "power curves", "probability of naming against size"),
        )
    ]
    plan_header, plan_table = plan_rows(limits)
    if verdict == "none" and plan_table:
        parts.append(
            H.section(
                "Campaigns that would see smaller causes",
                H.note(
                    "Per cause, the cheapest campaign at this campaign's operating "
                    "conditions that the decision rule would name the cause in, at half "
                    "its limit here (its typical configuration), with the stated "
                    "probability, the refit's estimation included (docs/diagnosis.md, "
                    "Planning a campaign; bayesdoor plan for another size)."
                ),
                H.table(plan_header, plan_table),
            )
        )
    return parts


def _feature_list(features: Features) -> str:
    """The significant features in words; the residual regions numbered as in the figure."""
    lines = features.summary()
    if not lines:
        return H.note("No significant residual: nothing departs from the predictive band.")
    n = len(features.residuals.regions)
    items = "".join(
        f"<li>{f'[{i + 1}] ' if i < n else ''}{html.escape(line)}</li>"
        for i, line in enumerate(lines)
    )
    return f"<ul>{items}</ul>"


def _fit_table(fit: Mapping[str, Any]) -> str:
    params = fit.get("parameters", {})
    if isinstance(params, Mapping):
        rows = [(str(k), parameter_text(v)) for k, v in params.items()]
    else:
        rows = [(str(r["parameter"]), parameter_text(r)) for r in params]
    caption = f"{fit.get('method', 'fit')}, J = {_number(fit.get('j'))}"
    return H.note(caption) + H.table(("parameter", "value ± sd [90 % interval]"), rows)


def diagnosis_section(diagnosis: Mapping[str, Any], href: str | None) -> str:
    """A short section for another page: the verdict, the leading causes, a link to the report.

    Parameters
    ----------
    diagnosis
        The diagnosis JSON (``verdict``, ``causes``; ``error`` when it could not be made).
    href
        The diagnosis report's address relative to the page that shows the section
        (``None``: no report to link).
    """
    verdict = diagnosis.get("verdict")
    if diagnosis.get("error"):
        text = f"The diagnosis could not be made: {diagnosis['error']}"
    elif verdict == "none":
        text = "The model explains the healthy measurements within its uncertainty (verdict none)."
    elif verdict is None:
        text = "Significant residuals, but no cause with decisive evidence (no verdict)."
    else:
        text = f"Verdict: {verdict}. The model misses a cause of the catalogue; see the report."
    rows = [
        (str(c.get("name")), _number(c.get("score")), str(c.get("evidence", ""))[:160])
        for c in list(diagnosis.get("causes", []))[:3]
    ]
    link = "" if href is None else f'<p><a href="{html.escape(href)}">the diagnosis report</a></p>'
    plans = _plan_items(diagnosis.get("limits") or {}) if verdict == "none" else []
    listed = "".join(f"<li>{html.escape(item)}</li>" for item in plans)
    return H.section(
        "Discrepancy diagnosis",
        H.note(text),
        H.table(("cause", "score", "evidence"), rows) if rows else "",
        H.note("What these runs could not have shown, and what would:") + f"<ul>{listed}</ul>"
        if plans
        else "",
        link,
    )


#: the section's statement of what the diagnosis saw (the extension's scores are fair)
EXTENSION_PROVENANCE = (
    "The test runs never informed the diagnosis: it saw the healthy calibration runs only, "
    "under the job's fit. Both jobs are scored on the same test runs."
)


def extension_section(extension: Mapping[str, Any]) -> str:
    """The section "with the diagnosed extension" of a job's campaign page.

    Parameters
    ----------
    extension
        ``verdict``, ``configuration`` and ``held`` (the extension's parameters and the values
        they are held at), ``before`` and ``after`` (each ``accuracy``, ``ece``, ``trust``;
        ``after``'s ``report`` the extended job's report relative to the page); or ``reason``,
        why nothing was extended (``after`` then ``None``).
    """
    title = "With the diagnosed extension"
    after = extension.get("after")
    if after is None:
        reason = extension.get("reason") or "the diagnosis names no cause"
        return H.section(title, H.note(f"Nothing was extended: {reason}."))
    held = extension.get("held") or {}
    said = ", ".join(f"{name} = {_number(value)}" for name, value in held.items())
    before = extension.get("before") or {}
    rows = [
        (label, _number(before.get(key)), _number(after.get(key)))
        for label, key in (("accuracy", "accuracy"), ("ECE", "ece"), ("trust", "trust"))
    ]
    link = after.get("report")
    anchor = ""
    if link:
        anchor = f'<p><a href="{html.escape(link)}">the extended job&#39;s report</a></p>'

    return H.section(
        title,
        H.note(
            f"The same job on the model extended by the verdict {extension.get('verdict')} "
            f"({extension.get('configuration')}), held at its refitted values: "
            f"{said or 'no parameters'}. {EXTENSION_PROVENANCE}"
        ),
        H.table(("", "the model", "with the extension"), rows),
        anchor,
    )


def write_diagnosis_report(
    path: str | Path,
    diagnosis: Mapping[str, Any],
    *,
    features: Features | None = None,
    catalogue: Catalogue | None = None,
    fit: Mapping[str, Any] | None = None,
    title: str = "Discrepancy diagnosis",
    overwrite: bool = False,
) -> Path:
    """Write :func:`diagnosis_page` to ``path`` atomically (never half-written).

    Raises
    ------
    FileExistsError
        When ``path`` exists and ``overwrite`` is false.
    """
    path = Path(path)
    text = diagnosis_page(diagnosis, features=features, catalogue=catalogue, fit=fit, title=title)
    atomic_write(path, lambda tmp: tmp.write_text(text), overwrite=overwrite)
    return path
