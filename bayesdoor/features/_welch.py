"""Welch power spectral density in JAX, whole-record or weighted over a window of the record."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import scipy.signal

from .._types import Array, Float

#: how far (in sample periods) a time may lie from a sample and still count as on it
_TIME_TOLERANCE = 1e-6


def _segment_layout(n_time: int, nperseg: int, noverlap: int | None) -> tuple[int, int]:
    """Check the segmentation options; return (noverlap, number of segments)."""
    if isinstance(nperseg, bool) or not isinstance(nperseg, int | np.integer) or nperseg < 1:
        raise ValueError(f"nperseg must be a positive integer, got {nperseg!r}")
    noverlap = nperseg // 2 if noverlap is None else noverlap
    if not 0 <= noverlap < nperseg:
        raise ValueError(
            f"noverlap must lie in [0, nperseg) = [0, {nperseg}), got {noverlap!r}; "
            "pass None for the default nperseg // 2"
        )
    if n_time < nperseg:
        raise ValueError(
            f"the record has {n_time} samples, fewer than nperseg={nperseg}: pass a smaller "
            "nperseg or a longer record (scipy would silently shrink nperseg; a static JAX "
            "shape cannot)"
        )
    return int(noverlap), (n_time - noverlap) // (nperseg - noverlap)


def _window(window, nperseg: int) -> np.ndarray:
    if isinstance(window, str | tuple):
        return scipy.signal.get_window(window, nperseg)
    win = np.asarray(window, dtype=float)
    if win.shape != (nperseg,):
        raise ValueError(
            f"a window array must have shape (nperseg,) = ({nperseg},), got {win.shape}; "
            "pass nperseg=len(window)"
        )
    return win


def _detrend(segments, detrend):
    if detrend is False or detrend is None:
        return segments
    centred = segments - jnp.mean(segments, axis=-1, keepdims=True)
    if detrend == "constant":
        return centred
    if detrend == "linear":
        n = segments.shape[-1]
        ramp = np.arange(n) - 0.5 * (n - 1)
        ramp = jnp.asarray(ramp / np.sqrt(np.sum(ramp * ramp)), dtype=segments.dtype)
        return centred - jnp.sum(centred * ramp, axis=-1, keepdims=True) * ramp
    raise ValueError(f"detrend must be 'constant', 'linear' or False, got {detrend!r}")


def welch_psd(
    x: Float[Array, "*batch time"],
    fs: float,
    nperseg: int = 512,
    noverlap: int | None = None,
    window: str | tuple | Float[Array, " nperseg"] = "hann",
    detrend: str | bool | None = "constant",
    axis: int = -1,
    *,
    segment_weights: Float[Array, "*#batch segment"] | None = None,
) -> tuple[Float[Array, " freq"], Float[Array, "*batch freq"]]:
    """One-sided Welch power spectral density, as ``scipy.signal.welch`` computes it.

    The record is cut into segments of ``nperseg`` samples that start every
    ``nperseg - noverlap`` samples (a trailing partial segment is dropped), each segment is
    detrended and windowed, and the periodograms (``scaling="density"``, one-sided) are
    averaged. Works under ``jit``, ``grad`` and ``vmap``; the options are static.

    Parameters
    ----------
    x
        Signals; any leading dimensions, for example (run, channel, time).
    fs
        Sampling rate in Hz (a Python number: it fixes the static frequency grid).
    nperseg
        Samples per segment; at most the record length.
    noverlap
        Samples shared by consecutive segments; ``None`` means ``nperseg // 2``.
    window
        A ``scipy.signal.get_window`` specification or an array of ``nperseg`` values.
    detrend
        ``"constant"`` (remove each segment's mean), ``"linear"`` (remove its least-squares
        line) or ``False``.
    axis
        The time axis of ``x``; the frequency axis of the result takes its place.
    segment_weights
        Optional non-negative weight of each segment, for a weighted Welch average
        ``sum_k w_k P_k / sum_k w_k`` instead of the mean. Its last axis runs over the
        segments (see :func:`segment_weights`, which makes 0/1 weights that select the
        segments inside a time window); its other axes broadcast against the shape of ``x``
        with ``axis`` removed. The number of segments stays static, only the weights are
        traced, so a per-run motion window works inside ``jit`` and ``vmap``. With all
        weights equal it is plain Welch.

    Returns
    -------
    freqs
        The frequencies, ``k fs / nperseg`` for ``k = 0 .. nperseg // 2``.
    psd
        The power spectral density in (units of ``x``)^2 / Hz.

    Raises
    ------
    ValueError
        For a record shorter than ``nperseg``, ``noverlap`` outside ``[0, nperseg)``, an
        unknown ``detrend``, a window of the wrong length or weights with the wrong number of
        segments. At run time (``eqx.error_if``): for weights that sum to zero somewhere.

    References
    ----------
    P. D. Welch, "The use of fast Fourier transform for the estimation of power spectra",
    IEEE Trans. Audio Electroacoustics 15(2), 1967.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> x = jnp.sin(2 * jnp.pi * 100.0 * jnp.arange(4096) / 2048.0)
    >>> freqs, psd = welch_psd(x, 2048.0)
    >>> float(freqs[jnp.argmax(psd)])
    100.0
    """
    x = jnp.moveaxis(jnp.asarray(x), axis, -1)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    fs = float(fs)
    noverlap, n_segments = _segment_layout(x.shape[-1], nperseg, noverlap)
    win = _window(window, nperseg)
    starts = np.arange(n_segments) * (nperseg - noverlap)
    segments = x[..., starts[:, None] + np.arange(nperseg)]
    segments = _detrend(segments, detrend) * jnp.asarray(win, dtype=x.dtype)
    spectrum = jnp.fft.rfft(segments, axis=-1)
    power = jnp.real(spectrum) ** 2 + jnp.imag(spectrum) ** 2
    if segment_weights is None:
        psd = jnp.mean(power, axis=-2)
    else:
        w = jnp.asarray(segment_weights).astype(x.dtype)
        if w.ndim == 0 or w.shape[-1] != n_segments:
            raise ValueError(
                f"segment_weights must end with an axis of {n_segments} segments (record of "
                f"{x.shape[-1]} samples, nperseg={nperseg}, noverlap={noverlap}), got shape "
                f"{w.shape}"
            )
        total = jnp.sum(w, axis=-1, keepdims=True)
        total = eqx.error_if(
            total,
            total <= 0,
            "segment_weights sum to zero for some record: no segment lies inside its window; "
            "(a) the window is shorter than nperseg, (b) t_start/t_stop lie outside the record",
        )
        psd = jnp.sum(w[..., None] * power, axis=-2) / total
    # density scaling, and the one-sided doubling of all bins but DC (and Nyquist, when present)
    scale = np.full(nperseg // 2 + 1, 2.0 / (fs * np.sum(win * win)))
    scale[0] /= 2.0
    if nperseg % 2 == 0:
        scale[-1] /= 2.0
    psd = psd * jnp.asarray(scale, dtype=x.dtype)
    freqs = jnp.asarray(np.fft.rfftfreq(nperseg, 1.0 / fs), dtype=x.dtype)
    return freqs, jnp.moveaxis(psd, -1, axis)


def segment_weights(
    n_time: int,
    fs: float,
    t_start: float | Float[Array, "*batch"],
    t_stop: float | Float[Array, "*batch"],
    nperseg: int = 512,
    noverlap: int | None = None,
    *,
    t0: float = 0.0,
) -> Float[Array, "*batch segment"]:
    """0/1 weights of the Welch segments that lie entirely inside ``[t_start, t_stop]``.

    Segment ``k`` covers samples ``k (nperseg - noverlap)`` to ``k (nperseg - noverlap) +
    nperseg - 1``, sample ``i`` being at time ``t0 + i / fs``; it gets weight 1 when its
    first sample is at or after ``t_start`` and its last sample at or before ``t_stop``
    (times within 1e-6 sample periods of a sample count as on it). ``t_start`` and ``t_stop``
    may be traced and batched (one window per run); the segment count is static. Pass the
    result as ``welch_psd(..., segment_weights=...)`` to get the PSD of the motion window.

    Parameters
    ----------
    n_time
        Samples per record.
    fs
        Sampling rate in Hz.
    t_start, t_stop
        The window, in the time of the record's samples (seconds).
    nperseg, noverlap
        As in :func:`welch_psd`.
    t0
        The time of the first sample.

    Returns
    -------
    weights
        1 for a segment inside the window, else 0, in the floating dtype of the times.

    Raises
    ------
    ValueError
        For a record shorter than ``nperseg`` or ``noverlap`` outside ``[0, nperseg)``.
    """
    noverlap, n_segments = _segment_layout(n_time, nperseg, noverlap)
    t_start, t_stop = jnp.broadcast_arrays(jnp.asarray(t_start), jnp.asarray(t_stop))
    if not jnp.issubdtype(t_start.dtype, jnp.floating):
        t_start, t_stop = (t.astype(jnp.result_type(float)) for t in (t_start, t_stop))
    fs = float(fs)
    first = jnp.ceil((t_start - t0) * fs - _TIME_TOLERANCE)[..., None]
    last = jnp.floor((t_stop - t0) * fs + _TIME_TOLERANCE)[..., None]
    starts = jnp.asarray(np.arange(n_segments) * (nperseg - noverlap), dtype=t_start.dtype)
    inside = (starts >= first) & (starts + (nperseg - 1) <= last)
    return inside.astype(t_start.dtype)
