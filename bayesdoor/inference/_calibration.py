"""The campaign side of a fit: the calibration runs, their features, and the precision of J
the data support."""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp
import numpy as np
import xarray as xr

from .._types import Int
from ..features import motion_window as detect_motion_window
from ..features import objective_j
from ..io import operating as campaign_operating
from ..systems import HEALTHY, AbstractSystem
from ._features import FeatureSpec
from ._likelihood import CalibrationData


def calibration_runs(campaign: xr.Dataset, healthy: str = HEALTHY) -> Int[np.ndarray, " run"]:
    """Indices of the runs a model is updated on.

    The runs with ``split == "calibration"`` when the campaign has such runs, else every run;
    of those, the ones in the state ``healthy`` (the system's
    :attr:`~bayesdoor.systems.AbstractSystem.healthy`).

    Raises
    ------
    ValueError
        When no such run is healthy.
    """
    state = np.asarray(campaign["state"].values).astype(str)
    chosen = np.ones(state.shape, dtype=bool)
    if "split" in campaign.variables:
        split = np.asarray(campaign["split"].values).astype(str)
        if np.any(split == "calibration"):
            chosen = split == "calibration"
    runs = np.flatnonzero(chosen & (state == healthy))
    if runs.size == 0:
        labels, counts = np.unique(state[chosen], return_counts=True)
        found = ", ".join(f"{n} {s}" for s, n in zip(labels, counts, strict=True)) or "no runs"
        where = "calibration runs" if not chosen.all() else "runs"
        raise ValueError(
            f"the campaign has no {healthy} run to update the model on (its {where}: {found}): "
            "model updating needs measurements of the undamaged system; (a) label them "
            f"state={healthy!r}, (b) mark them split='calibration', (c) pass another campaign"
        )
    return runs


def campaign_data(
    system: AbstractSystem,
    campaign: xr.Dataset,
    runs: Sequence[int] | Int[np.ndarray, " run"],
    *,
    spec: FeatureSpec | None = None,
    max_motion_s: float | None = None,
) -> tuple[CalibrationData, float]:
    """The features of some runs of a campaign, and the record length to simulate them with.

    The simulated record holds the system's motion at every operating point of the runs
    (truncated to ``max_motion_s`` of motion); each measured window (``t_start``/``t_stop``
    of the campaign, else detected from the signals) is clipped to the length of the
    simulated window at its operating point, so that both average the same stretch.

    Parameters
    ----------
    system
        The system the campaign measured.
    campaign
        A campaign (docs/data.md); the system's per-run operating conditions are the
        operating points.
    runs
        The runs to use.
    spec
        The feature definition; ``None`` means the system's (``FeatureSpec.of(system)``).
    max_motion_s
        Longest stretch of motion (s) to use; ``None``: all of it.

    Returns
    -------
    data
        Features, Welch scatter and operating points of the runs.
    duration
        The simulated record length (s).

    Raises
    ------
    ValueError
        For a sampling rate or channels that differ from the system's, or no runs.
    """
    spec = FeatureSpec.of(system) if spec is None else spec
    runs = np.asarray(runs, dtype=int)
    if runs.size == 0:
        raise ValueError("runs is empty: pass the indices of at least one run")
    fs = _check_campaign(system, campaign)
    selected = campaign.isel(run=runs)
    signals = np.asarray(
        selected["acceleration"].sel(channel=list(system.channels)).values, dtype=float
    )
    operating = campaign_operating(selected, system)
    t_start, t_stop = _measured_windows(selected, signals, fs)
    unique, index = np.unique(operating, axis=0, return_inverse=True)
    index = index.reshape(-1)
    duration = _simulated_duration(system, unique, max_motion_s)
    sim_start, sim_stop = system.motion_window(unique, duration=duration)
    length = (np.asarray(sim_stop) - np.asarray(sim_start))[index.reshape(-1)]
    t_stop = np.minimum(t_stop, t_start + length)
    data = CalibrationData.from_signals(
        jnp.asarray(signals),
        fs,
        jnp.asarray(operating),
        jnp.asarray(t_start),
        jnp.asarray(t_stop),
        spec,
    )
    return data, duration


def _check_campaign(system: AbstractSystem, campaign: xr.Dataset) -> float:
    """The campaign's sampling rate, checked to be the system's, and its channels to hold the
    system's."""
    fs = float(campaign.attrs.get("sampling_rate_hz", np.nan))
    if fs != system.sampling_rate_hz:
        raise ValueError(
            f"the campaign's sampling_rate_hz={fs} differs from {system.name}'s "
            f"{system.sampling_rate_hz} Hz: resample the measurements to the model's rate"
        )
    channels = [str(c) for c in campaign["channel"].values]
    missing = [c for c in system.channels if c not in channels]
    if missing:
        raise ValueError(
            f"the campaign lacks the channels {missing} of {system.name} (it has {channels})"
        )
    return fs


def _measured_windows(
    selected: xr.Dataset, signals: np.ndarray, fs: float
) -> tuple[np.ndarray, np.ndarray]:
    """Each run's motion window: the campaign's ``t_start``/``t_stop``, else detected from
    the signals."""
    if "t_start" in selected.variables and "t_stop" in selected.variables:
        t_start = np.asarray(selected["t_start"].values, dtype=float)
        t_stop = np.asarray(selected["t_stop"].values, dtype=float)
        return t_start, t_stop
    t = np.arange(signals.shape[-1]) / fs
    windows = np.array([detect_motion_window(t, s) for s in signals])
    return windows[:, 0], windows[:, 1]


def _simulated_duration(
    system: AbstractSystem, unique: np.ndarray, max_motion_s: float | None
) -> float:
    """The simulated record length of the operating points ``unique``: the system's, cut to
    ``max_motion_s`` of motion after the latest start when given."""
    duration = float(system.record_duration(unique))
    if max_motion_s is not None:
        start, _ = system.motion_window(unique)
        duration = min(duration, float(np.max(start)) + float(max_motion_s))
    return duration


def j_standard_error(data: CalibrationData) -> float | None:
    """The standard error of J (the mean over the runs) from the run-to-run scatter alone.

    For each run at an operating point measured ``k >= 2`` times, the residual against the
    mean of the other ``k - 1`` runs there, scaled by ``sqrt((k - 1) / k)`` to one run's
    scatter, is what a perfect model would leave on that run; its J (eq. 2) is a draw of
    J's run-to-run fluctuation. The standard deviation of these over the runs, over the
    square root of the number of runs, is the precision of the mean J the data support.
    Data only: no simulation. (On the demo campaign, 10 runs at three speeds, it gives
    0.017, against 0.014 from the spread of the runs' own J about their speed's mean at the
    CMA-ES optimum.)

    Parameters
    ----------
    data
        The calibration features.

    Returns
    -------
    se
        The standard error, or ``None`` when fewer than two runs have a replicate.
    """
    y = np.asarray(data.y)
    index = np.asarray(data.run_operating)
    residuals = []
    for i in range(len(y)):
        others = np.flatnonzero((index == index[i]) & (np.arange(len(y)) != i))
        if others.size:
            k = others.size + 1
            residuals.append((y[i] - y[others].mean(axis=0)) * np.sqrt((k - 1) / k))
    if len(residuals) < 2:
        return None
    scatter = np.asarray(objective_j(jnp.asarray(np.stack(residuals)), jnp.zeros_like(y[0])))
    return float(np.std(scatter, ddof=1) / np.sqrt(len(y)))


def welch_j_standard_error(data: CalibrationData, draws: int = 512, seed: int = 0) -> float:
    """The standard error of J (the mean over the runs) if the runs scattered only as the
    Welch estimator does: a lower bound on :func:`j_standard_error`, for campaigns without
    replicate runs.

    Each run's residual at a perfect model is drawn ``draws`` times as independent Gaussian
    noise of the run's Welch variance in every bin (``data.welch_variance``), and J (eq. 2)
    taken of each draw; the standard deviation of one run's J over the draws is its
    fluctuation, and the root of their summed variances over the number of runs is that of
    the mean J. Measured runs scatter more than the estimator alone (the rig's run-to-run
    variation, sensor noise): on the demo campaign it gives 0.0090 against 0.017 from the
    replicates. Data only, no simulation; deterministic for a given ``seed``.

    Parameters
    ----------
    data
        The calibration features.
    draws
        Noise draws per run (512: the standard error is known to about 3 %).
    seed
        Seeds the draws.

    Returns
    -------
    se
        The standard error, decades (J's units).

    Raises
    ------
    ValueError
        When ``draws`` is not an integer of at least 2.
    """
    if isinstance(draws, bool) or not isinstance(draws, int) or draws < 2:
        raise ValueError(f"draws={draws!r} must be an integer >= 2 (the sd of J over the draws)")
    y = np.asarray(data.y)
    sd = np.sqrt(np.asarray(data.welch_variance, dtype=np.float64))
    noise = np.random.default_rng(seed).standard_normal((draws, *y.shape)) * sd[:, None, None]
    j = np.asarray(objective_j(jnp.asarray(noise), jnp.zeros_like(y[0])))
    return float(np.sqrt(np.sum(np.var(j, axis=0, ddof=1))) / len(y))
