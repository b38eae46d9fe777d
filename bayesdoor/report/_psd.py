"""PSDs of a campaign's runs within their motion windows, and figures of them per state."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import xarray as xr

from ..features import log_psd, motion_window, segment_weights, welch_psd
from ..io import UNKNOWN, atomic_write
from ..systems import HEALTHY
from ._colors import state_colors


@dataclasses.dataclass(frozen=True)
class RunPSDs:
    """The log10 Welch PSD of every run and channel of a campaign.

    Attributes
    ----------
    freqs
        Frequencies of the bins, Hz, shape (freq,).
    log_psd
        log10 of the PSD in (m/s^2)^2/Hz, shape (run, channel, freq).
    channels
        The channel names.
    states
        The state label of each run.
    runs
        The index (position along ``run`` in the campaign) of each run.
    nperseg
        The Welch segment length, samples.
    fs
        The sampling rate, Hz.
    """

    freqs: np.ndarray
    log_psd: np.ndarray
    channels: tuple[str, ...]
    states: tuple[str, ...]
    runs: tuple[int, ...]
    nperseg: int
    fs: float


def segments_in_window(
    ds: xr.Dataset, t_start: np.ndarray, t_stop: np.ndarray, *, nperseg: int = 512
) -> np.ndarray:
    """How many whole Welch segments (half overlap) lie inside each run's window.

    A PSD of the window needs at least one; a window of ``nperseg`` samples or more can still
    hold none when it does not start on a segment boundary.

    Parameters
    ----------
    ds
        A campaign with a usable ``sampling_rate_hz`` and ``time``.
    t_start, t_stop
        Per run, seconds.
    nperseg
        The Welch segment length.

    Returns
    -------
    counts
        One integer per run.
    """
    t = np.asarray(ds["time"].values, dtype=float)
    fs = float(ds.attrs["sampling_rate_hz"])
    weights = segment_weights(
        t.size, fs, jnp.asarray(t_start), jnp.asarray(t_stop), nperseg, t0=float(t[0])
    )
    return np.asarray(weights).sum(axis=-1).astype(int)


def motion_windows(ds: xr.Dataset, *, nperseg: int = 512) -> tuple[np.ndarray, np.ndarray, list]:
    """The motion window of every run: ``t_start``/``t_stop`` when present, else detected.

    Detection uses :func:`bayesdoor.features.motion_window` on all channels. A run whose
    motion cannot be detected, or whose detected window holds no whole Welch segment, gets
    its whole record, and a note says so.

    Parameters
    ----------
    ds
        A campaign (``docs/data.md``) with a usable ``sampling_rate_hz`` and ``time``.
    nperseg
        The Welch segment length the window must hold.

    Returns
    -------
    t_start, t_stop
        Per run, seconds.
    notes
        One line per run that fell back to its whole record (empty when none did).
    """
    t = np.asarray(ds["time"].values, dtype=float)
    runs = ds.sizes["run"]
    if "t_start" in ds and "t_stop" in ds:
        return (
            np.asarray(ds["t_start"].values, dtype=float),
            np.asarray(ds["t_stop"].values, dtype=float),
            [],
        )
    acc = np.asarray(ds["acceleration"].transpose("run", "channel", "time").values, dtype=float)
    start, stop, notes = np.full(runs, t[0]), np.full(runs, t[-1]), []
    for r in range(runs):
        try:
            start[r], stop[r] = motion_window(t, acc[r])
        except ValueError as err:
            notes.append(f"run {r}: motion not detected ({err}); its PSD uses the whole record")
    short = segments_in_window(ds, start, stop, nperseg=nperseg) == 0
    notes += [
        f"run {r}: the detected motion [{start[r]:.3f}, {stop[r]:.3f}] s holds no whole "
        f"Welch segment of {nperseg} samples; its PSD uses the whole record"
        for r in np.flatnonzero(short)
    ]
    start[short], stop[short] = t[0], t[-1]
    return start, stop, notes


def campaign_psds(
    ds: xr.Dataset,
    *,
    nperseg: int = 512,
    runs: Sequence[int] | None = None,
    windows: tuple[np.ndarray, np.ndarray] | None = None,
) -> RunPSDs:
    """log10 Welch PSD of each run and channel over its motion window.

    The PSD is :func:`bayesdoor.features.welch_psd` (Hann window, ``nperseg`` samples, half
    overlap) averaged over the segments that lie inside the run's motion window
    (:func:`bayesdoor.features.segment_weights`), as the paper's Figures 3-5 use the
    response during the door's motion.

    Parameters
    ----------
    ds
        A campaign with a usable sampling rate and time coordinate.
    nperseg
        Welch segment length; the resolution is ``sampling_rate_hz / nperseg``.
    runs
        Positions of the runs to use; ``None`` means all.
    windows
        Per-run (t_start, t_stop) in seconds for all runs of ``ds``; ``None`` means
        :func:`motion_windows`.

    Returns
    -------
    psds
        The spectra with their frequencies, channels and states.

    Raises
    ------
    ValueError
        For a run whose window holds no whole Welch segment.
    """
    fs = float(ds.attrs["sampling_rate_hz"])
    t = np.asarray(ds["time"].values, dtype=float)
    selected = list(range(ds.sizes["run"])) if runs is None else [int(r) for r in runs]
    start, stop = motion_windows(ds, nperseg=nperseg)[:2] if windows is None else windows
    start, stop = np.asarray(start)[selected], np.asarray(stop)[selected]
    empty = np.flatnonzero(segments_in_window(ds, start, stop, nperseg=nperseg) == 0)
    if empty.size:
        r = selected[int(empty[0])]
        raise ValueError(
            f"run {r}: its window [{start[empty[0]]!r}, {stop[empty[0]]!r}] s holds no whole "
            f"Welch segment of {nperseg} samples; widen the window or pass a smaller nperseg"
        )
    weights = segment_weights(
        t.size, fs, jnp.asarray(start), jnp.asarray(stop), nperseg, t0=float(t[0])
    )
    acc = ds["acceleration"].transpose("run", "channel", "time").values[selected]
    freqs, psd = welch_psd(
        jnp.asarray(acc, dtype=float), fs, nperseg, segment_weights=weights[:, None]
    )
    states = ds["state"].values[selected] if "state" in ds else [UNKNOWN] * len(selected)
    return RunPSDs(
        freqs=np.asarray(freqs),
        log_psd=np.asarray(log_psd(psd)),
        channels=tuple(str(c) for c in ds["channel"].values),
        states=tuple(str(s) for s in states),
        runs=tuple(selected),
        nperseg=nperseg,
        fs=fs,
    )


def _state_curves(axes, psds: RunPSDs, shown: np.ndarray, colors: dict, band) -> list:
    """Each state's mean log PSD and its band over runs on every channel's panel; the legend
    handles."""
    import matplotlib.pyplot as plt
    from matplotlib.artist import Artist
    from matplotlib.patches import Patch

    lo, hi = band
    freqs, values = psds.freqs[shown], psds.log_psd[..., shown]
    labels = [s for s in colors if s in psds.states]
    handles: list[Artist] = []
    for state in labels:
        member = np.array([s == state for s in psds.states])
        count = int(member.sum())
        runs = values[member]
        color = colors[state]
        for ax, ch in zip(axes.flat, range(len(psds.channels)), strict=False):
            if count > 1:
                ax.fill_between(
                    freqs,
                    np.percentile(runs[:, ch], lo, axis=0),
                    np.percentile(runs[:, ch], hi, axis=0),
                    color=color,
                    alpha=0.2,
                    lw=0,
                )
            ax.plot(freqs, runs[:, ch].mean(axis=0), color=color, lw=1.4)
        runs_text = "1 run" if count == 1 else f"mean of {count} runs"
        handles.append(plt.Line2D([], [], color=color, lw=1.6, label=f"{state} ({runs_text})"))
    if any(psds.states.count(s) > 1 for s in labels):
        handles.append(Patch(color="0.5", alpha=0.3, label=f"{lo:g}-{hi:g} percentile over runs"))
    return handles


def _decorate(fig, axes, psds: RunPSDs, fmax: float, title: str | None, handles: list) -> None:
    """Channel titles, axes' labels and limits, the analysis settings and the legend."""
    n_channels = len(psds.channels)
    for ax, name in zip(axes.flat, psds.channels, strict=False):
        ax.set_title(name, fontsize=11, fontweight="bold")
        ax.set_xlim(0, fmax)
        ax.grid(True, alpha=0.3)
    for ax in axes.flat[n_channels:]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("frequency (Hz)")
    for ax in axes[:, 0]:
        ax.set_ylabel("log$_{10}$ PSD ((m/s$^2$)$^2$/Hz)")
    settings = (
        f"Welch PSD within each run's motion window, Hann, {psds.nperseg} samples "
        f"({psds.fs / psds.nperseg:g} Hz bins), 50 % overlap, fs = {psds.fs:g} Hz"
    )
    fig.suptitle(f"{title}\n{settings}" if title else settings, fontsize=11)
    fig.legend(
        handles=handles,
        loc="lower center",
        ncol=min(len(handles), 4),
        frameon=False,
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.06 + 0.02 * (len(handles) > 4), 1, 1))


def plot_state_psds(
    psds: RunPSDs,
    path: str | os.PathLike,
    *,
    fmax: float | None = None,
    title: str | None = None,
    band: tuple[float, float] = (5.0, 95.0),
    states: Sequence[str] = (),
    healthy: str = HEALTHY,
) -> Path:
    """Mean log PSD per state with a band over its runs, one panel per channel.

    The paper's Figures 3-5 in one picture: for each state the mean over its runs of the
    log10 PSD, and the ``band`` percentiles of the runs around it (no band for a state with
    a single run); a linear frequency axis from 0 to ``fmax``.

    Parameters
    ----------
    psds
        The spectra (:func:`campaign_psds`).
    path
        The PNG to write (replaced atomically if it exists: the caller decides whether it
        may be).
    fmax
        Highest frequency shown, Hz; ``None`` means the Nyquist frequency.
    title
        The figure's title; the analysis settings are added below it.
    band
        Lower and upper percentile of the band over runs.
    states
        The system's states, in its order: the colours follow them
        (:func:`~bayesdoor.report.state_colors`), and the runs' other labels come after them.
    healthy
        The system's healthy state.

    Returns
    -------
    path
        The file written.

    Raises
    ------
    ValueError
        For an empty ``psds``, ``fmax`` not above the first bin, or a band that is not two
        increasing percentiles.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lo, hi = band
    if not 0 <= lo < hi <= 100:
        raise ValueError(f"band must be two increasing percentiles in [0, 100], got {band!r}")
    if not psds.runs:
        raise ValueError("psds holds no runs: there is nothing to plot")
    fmax = psds.fs / 2 if fmax is None else float(fmax)
    shown = psds.freqs <= fmax + 1e-9
    if shown.sum() < 2:
        raise ValueError(f"fmax={fmax} Hz shows fewer than two bins (spacing {psds.freqs[1]} Hz)")
    n_channels = len(psds.channels)
    ncols = 2 if n_channels > 1 else 1
    nrows = -(-n_channels // ncols)
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(6.2 * ncols, 3.6 * nrows + 1.1), sharex=True, squeeze=False
    )
    colors = state_colors([*states, *psds.states], healthy)
    handles = _state_curves(axes, psds, shown, colors, band)
    _decorate(fig, axes, psds, fmax, title, handles)
    try:
        atomic_write(
            Path(path), lambda tmp: fig.savefig(tmp, format="png", dpi=120), overwrite=True
        )
    finally:
        plt.close(fig)
    return Path(path)
