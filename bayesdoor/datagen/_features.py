"""The one featurizer shared by simulated training runs and measured runs.

The classifier sees the paper's CNN input (the low-frequency log PSD of every channel,
:func:`bayesdoor.features.cnn_input`) computed over the run's motion window only, so that the
length of the rest before and after the motion does not change the features. Simulated runs
know their window; measured runs give it as ``t_start`` / ``t_stop`` or have it detected from
the signal envelope (:func:`bayesdoor.features.motion_window`).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._types import Array, Float
from ..features import CNNInputSpec, cnn_input, motion_window, segment_weights


@eqx.filter_jit
def _windowed_input(signals, t_start, t_stop, fs: float, spec: CNNInputSpec, t0: float):
    weights = segment_weights(signals.shape[-1], fs, t_start, t_stop, nperseg=spec.nperseg, t0=t0)
    return cnn_input(signals, fs, spec, segment_weights=weights[..., None, :])


def featurize(
    signals: Float[Array, "*batch channel time"] | Float[np.ndarray, "*batch channel time"],
    fs: float,
    t_start: float | Float[Array, "*batch"] | Float[np.ndarray, "*batch"],
    t_stop: float | Float[Array, "*batch"] | Float[np.ndarray, "*batch"],
    *,
    spec: CNNInputSpec | None = None,
    t0: float = 0.0,
) -> Float[Array, "*batch channel freq"]:
    """Classifier features of runs: the CNN input over each run's motion window.

    The Welch PSD averages only the segments that lie entirely inside ``[t_start, t_stop]``
    (:func:`bayesdoor.features.segment_weights`); the bins up to ``spec.fmax`` are kept, as
    log10 by default: with the default spec and 2048 Hz sampling, 25 bins (0-96 Hz at 4 Hz)
    per channel, the paper's 4 x 25 input for four channels.

    Parameters
    ----------
    signals
        Sensor signals, time last.
    fs
        Sampling rate in Hz.
    t_start, t_stop
        The motion window of each run (s), in the time of the samples.
    spec
        Resolution, band and scale; ``None`` means ``CNNInputSpec()``.
    t0
        The time of the first sample.

    Returns
    -------
    features
        One row per channel.

    Raises
    ------
    ValueError
        For a record shorter than ``spec.nperseg``; at run time for a window that holds no
        whole Welch segment (shorter than ``spec.nperseg / fs`` seconds).
    """
    spec = CNNInputSpec() if spec is None else spec
    signals = jnp.asarray(signals)
    dtype = signals.dtype
    return _windowed_input(
        signals,
        jnp.asarray(t_start, dtype=dtype),
        jnp.asarray(t_stop, dtype=dtype),
        float(fs),
        spec,
        float(t0),
    )


def measured_windows(
    time: Float[Array, " time"] | Float[np.ndarray, " time"],
    signals: Float[Array, "run channel time"] | Float[np.ndarray, "run channel time"],
    t_start: Float[Array, " run"] | Float[np.ndarray, " run"] | None = None,
    t_stop: Float[Array, " run"] | Float[np.ndarray, " run"] | None = None,
    **detect,
) -> tuple[np.ndarray, np.ndarray]:
    """Motion windows of measured runs: the given ``t_start`` / ``t_stop``, else detected.

    A missing value (``None`` or NaN for a run) is detected from the run's envelope with
    :func:`bayesdoor.features.motion_window` (keyword arguments ``detect`` are passed on,
    for example ``channels``).

    Returns
    -------
    t_start, t_stop
        One window per run (s).
    """
    x = np.asarray(signals, dtype=float)
    n_run = x.shape[0]
    given = [
        np.full(n_run, np.nan) if v is None else np.broadcast_to(np.asarray(v, float), (n_run,))
        for v in (t_start, t_stop)
    ]
    starts, stops = np.empty(n_run), np.empty(n_run)
    for i in range(n_run):
        a, b = (None if np.isnan(g[i]) else float(g[i]) for g in given)
        starts[i], stops[i] = motion_window(np.asarray(time), x[i], t_start=a, t_stop=b, **detect)
    return starts, stops


def measured_features(
    time: Float[Array, " time"] | Float[np.ndarray, " time"],
    signals: Float[Array, "run channel time"] | Float[np.ndarray, "run channel time"],
    fs: float,
    t_start: Float[Array, " run"] | Float[np.ndarray, " run"] | None = None,
    t_stop: Float[Array, " run"] | Float[np.ndarray, " run"] | None = None,
    *,
    spec: CNNInputSpec | None = None,
    **detect,
) -> Float[Array, "run channel freq"]:
    """:func:`featurize` for measured runs, with windows from :func:`measured_windows`.

    This is the path of a campaign's runs (``time``, ``acceleration`` and the optional
    ``t_start`` / ``t_stop`` coordinates); it computes exactly what the training data holds
    for a simulated run with the same signals and window.
    """
    starts, stops = measured_windows(time, signals, t_start, t_stop, **detect)
    t = np.asarray(time, dtype=float)
    return featurize(signals, fs, starts, stops, spec=spec, t0=float(t[0]))


def campaign_features(
    campaign, *, spec: CNNInputSpec | None = None, **detect
) -> Float[np.ndarray, "run channel freq"]:
    """:func:`measured_features` of every run of a campaign dataset (``docs/data.md``).

    Uses the ``acceleration`` variable, the ``time`` coordinate, the ``sampling_rate_hz``
    attribute and, where present, the per-run ``t_start`` / ``t_stop`` coordinates (NaN for
    a run means "detect its window").

    Raises
    ------
    ValueError
        For a dataset without ``acceleration`` (run, channel, time) or ``sampling_rate_hz``.
    """
    if "acceleration" not in campaign or "sampling_rate_hz" not in campaign.attrs:
        raise ValueError(
            "campaign must hold an 'acceleration' variable and a 'sampling_rate_hz' attribute "
            "(load it with bayesdoor.io.load_campaign)"
        )
    acc = campaign["acceleration"].transpose("run", "channel", "time")
    windows = [
        np.asarray(campaign[name].values, dtype=float) if name in campaign.coords else None
        for name in ("t_start", "t_stop")
    ]
    return np.asarray(
        measured_features(
            np.asarray(campaign["time"].values, dtype=float),
            np.asarray(acc.values, dtype=float),
            float(campaign.attrs["sampling_rate_hz"]),
            *windows,
            spec=spec,
            **detect,
        )
    )
