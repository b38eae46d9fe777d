"""Welch power and cross spectral densities, whole-record or weighted over a window of the record.

One implementation serves fitting (JAX: traced, batched, differentiated) and diagnosis (numpy):
a JAX array in gives a JAX array out, anything else a numpy array; the segmentation, window,
detrending and scaling are the same code for both.
"""

from __future__ import annotations

import dataclasses
from types import ModuleType
from typing import TypeVar

import jax
import jax.numpy as jnp
import numpy as np
import scipy.signal
from jaxtyping import Complex

from .._cacheable import error_if
from .._types import Array, Float

#: numpy arrays in give numpy arrays out, JAX arrays JAX arrays
_A = TypeVar("_A", np.ndarray, Array)

#: how far (in sample periods) a time may lie from a sample and still count as on it
_TIME_TOLERANCE = 1e-6


@dataclasses.dataclass(frozen=True)
class WelchOptions:
    """How :func:`welch_psd` and :func:`welch_csd` treat each segment (scipy's defaults).

    Parameters
    ----------
    window
        A ``scipy.signal.get_window`` specification or an array of ``nperseg`` values.
    detrend
        ``"constant"`` (remove each segment's mean), ``"linear"`` (remove its least-squares
        line) or ``False``.
    nfft
        FFT length of each segment, at least ``nperseg``: the windowed segment is zero-padded
        to it, which interpolates the spectrum on a finer grid without narrowing the window's
        main lobe; ``None`` means ``nperseg``.
    """

    window: str | tuple | Float[Array, " nperseg"] = "hann"
    detrend: str | bool | None = "constant"
    nfft: int | None = None


def welch_segment_count(n_time: int, nperseg: int, noverlap: int | None = None) -> int:
    """How many whole segments a Welch estimate averages over a record of ``n_time`` samples.

    Segments of ``nperseg`` samples start every ``nperseg - noverlap`` samples and a trailing
    partial segment is dropped, as in :func:`welch_psd`: ``(n_time - noverlap) // (nperseg -
    noverlap)``, 0 for a record shorter than one segment. It is the ``n_segments`` of
    :func:`bayesdoor.features.welch_dof`.

    Raises
    ------
    ValueError
        For ``nperseg`` not a positive integer or ``noverlap`` outside ``[0, nperseg)``.
    """
    if isinstance(nperseg, bool) or not isinstance(nperseg, int | np.integer) or nperseg < 1:
        raise ValueError(f"nperseg must be a positive integer, got {nperseg!r}")
    noverlap = nperseg // 2 if noverlap is None else noverlap
    if not 0 <= noverlap < nperseg:
        raise ValueError(
            f"noverlap must lie in [0, nperseg) = [0, {nperseg}), got {noverlap!r}; "
            "pass None for the default nperseg // 2"
        )
    if n_time < nperseg:
        return 0
    return int((n_time - noverlap) // (nperseg - noverlap))


def _segment_layout(n_time: int, nperseg: int, noverlap: int | None) -> tuple[int, int]:
    """Check the segmentation options; return (noverlap, number of segments)."""
    n_segments = welch_segment_count(n_time, nperseg, noverlap)
    if n_segments == 0:
        raise ValueError(
            f"the record has {n_time} samples, fewer than nperseg={nperseg}: pass a smaller "
            "nperseg or a longer record (scipy would silently shrink nperseg; a static JAX "
            "shape cannot)"
        )
    return int(nperseg // 2 if noverlap is None else noverlap), n_segments


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


def _detrend(segments, detrend, xp):
    if detrend is False or detrend is None:
        return segments
    centred = segments - xp.mean(segments, axis=-1, keepdims=True)
    if detrend == "constant":
        return centred
    if detrend == "linear":
        n = segments.shape[-1]
        ramp = np.arange(n) - 0.5 * (n - 1)
        ramp = xp.asarray(ramp / np.sqrt(np.sum(ramp * ramp)), dtype=segments.dtype)
        return centred - xp.sum(centred * ramp, axis=-1, keepdims=True) * ramp
    raise ValueError(f"detrend must be 'constant', 'linear' or False, got {detrend!r}")


def _namespace(*arrays) -> ModuleType:
    """``jax.numpy`` when any input is a JAX array (or a tracer), else ``numpy``."""
    return jnp if any(isinstance(a, jax.Array) for a in arrays) else np


def _time_last(x, axis, xp):
    x = xp.moveaxis(xp.asarray(x), axis, -1)
    if not xp.issubdtype(x.dtype, xp.floating):
        x = x.astype(xp.result_type(float))
    return x


def _used_segments(n_time, nperseg, noverlap, segment_weights) -> np.ndarray | None:
    """The segments that some numpy weight keeps (``None``: every segment, for JAX weights,
    no weights, or weights that :func:`_average` rejects). A finite segment of weight 0
    everywhere adds exact zeros to the average, so leaving it out changes no bit; in numpy it
    is not computed (and a non-finite sample outside every window no longer reaches the
    average)."""
    if segment_weights is None or isinstance(segment_weights, jax.Array):
        return None
    w = np.asarray(segment_weights)
    _, n_segments = _segment_layout(n_time, nperseg, noverlap)
    if w.ndim == 0 or w.shape[-1] != n_segments:
        return None
    used = np.flatnonzero(np.any(w.reshape(-1, n_segments) != 0, axis=0))
    return used if 0 < used.size < n_segments else None


def _segment_spectra(x, nperseg, noverlap, options: WelchOptions, xp, used=None):
    """The FFT of every detrended, windowed segment of ``x`` (time last), or of the ``used``
    ones: (..., segment, freq); the window, the number of segments and the FFT length."""
    noverlap, n_segments = _segment_layout(x.shape[-1], nperseg, noverlap)
    nfft = nperseg if options.nfft is None else options.nfft
    if isinstance(nfft, bool) or not isinstance(nfft, int | np.integer) or nfft < nperseg:
        raise ValueError(f"nfft must be an integer of at least nperseg={nperseg}, got {nfft!r}")
    win = _window(options.window, nperseg)
    starts = np.arange(n_segments) * (nperseg - noverlap)
    if used is not None:
        starts = starts[used]
    segments = x[..., starts[:, None] + np.arange(nperseg)]
    segments = _detrend(segments, options.detrend, xp) * xp.asarray(win, dtype=x.dtype)
    return xp.fft.rfft(segments, n=int(nfft), axis=-1), win, n_segments, int(nfft)


def _average(power, segment_weights, layout: tuple[int, int, int | None, int], xp, used=None):
    """Mean over the segment axis (-2), or the ``segment_weights`` average (``power`` of the
    ``used`` segments only, when given)."""
    if segment_weights is None:
        return xp.mean(power, axis=-2)
    n_time, nperseg, noverlap, n_segments = layout
    w = xp.asarray(segment_weights).astype(xp.real(power).dtype)
    if w.ndim == 0 or w.shape[-1] != n_segments:
        raise ValueError(
            f"segment_weights must end with an axis of {n_segments} segments (record of "
            f"{n_time} samples, nperseg={nperseg}, noverlap={noverlap}), got shape {w.shape}"
        )
    total = xp.sum(w, axis=-1, keepdims=True)
    message = (
        "segment_weights sum to zero for some record: no segment lies inside its window; "
        "(a) the window is shorter than nperseg, (b) t_start/t_stop lie outside the record"
    )
    if xp is jnp:
        total = error_if(total, total <= 0, message)
    elif np.any(total <= 0):
        raise ValueError(message)
    if used is not None:
        w = w[..., used]
    return xp.sum(w[..., None] * power, axis=-2) / total


def _density(spectrum, win, nfft, fs, dtype, axis, xp):
    """Frequencies, and the averaged periodogram scaled to a one-sided density on ``axis``."""
    fs = float(fs)
    # density scaling, and the one-sided doubling of all bins but DC (and Nyquist, when present)
    scale = np.full(nfft // 2 + 1, 2.0 / (fs * np.sum(win * win)))
    scale[0] /= 2.0
    if nfft % 2 == 0:
        scale[-1] /= 2.0
    spectrum = spectrum * xp.asarray(scale, dtype=dtype)
    freqs = xp.asarray(np.fft.rfftfreq(nfft, 1.0 / fs), dtype=dtype)
    return freqs, xp.moveaxis(spectrum, -1, axis)


def welch_psd(
    x: Float[_A, "*batch time"],
    fs: float,
    nperseg: int = 512,
    noverlap: int | None = None,
    axis: int = -1,
    *,
    segment_weights: Float[_A, "*#batch segment"] | None = None,
    options: WelchOptions = WelchOptions(),
) -> tuple[Float[_A, " freq"], Float[_A, "*batch freq"]]:
    """One-sided Welch power spectral density, as ``scipy.signal.welch`` computes it.

    The record is cut into segments of ``nperseg`` samples that start every
    ``nperseg - noverlap`` samples (a trailing partial segment is dropped), each segment is
    detrended and windowed, and the periodograms (``scaling="density"``, one-sided) are
    averaged. Works under ``jit``, ``grad`` and ``vmap``; the options are static. A JAX
    array in (``x`` or ``segment_weights``) gives JAX arrays out; numpy arrays in give numpy
    arrays out, computed by numpy with the same code (no compilation for each record length).

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
    options
        The window, the detrending and the FFT length (:class:`WelchOptions`).

    Returns
    -------
    freqs
        The frequencies, ``k fs / nfft`` for ``k = 0 .. nfft // 2``.
    psd
        The power spectral density in (units of ``x``)^2 / Hz.

    Raises
    ------
    ValueError
        For a record shorter than ``nperseg``, ``noverlap`` outside ``[0, nperseg)``, an
        unknown ``detrend``, a window of the wrong length, ``nfft`` below ``nperseg`` or weights
        with the wrong number of segments; for weights that sum to zero somewhere (at run
        time, through ``eqx.error_if``, for JAX arrays).

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
    xp = _namespace(x, segment_weights)
    x = _time_last(x, axis, xp)
    used = _used_segments(x.shape[-1], nperseg, noverlap, segment_weights)
    spectrum, win, n_segments, nfft = _segment_spectra(x, nperseg, noverlap, options, xp, used)
    power = xp.real(spectrum) ** 2 + xp.imag(spectrum) ** 2
    layout = (x.shape[-1], nperseg, noverlap, n_segments)
    psd = _average(power, segment_weights, layout, xp, used)
    return _density(psd, win, nfft, fs, x.dtype, axis, xp)


def welch_csd(
    x: Float[_A, "*batch time"],
    y: Float[_A, "*batch time"],
    fs: float,
    nperseg: int = 512,
    noverlap: int | None = None,
    axis: int = -1,
    *,
    segment_weights: Float[_A, "*#batch segment"] | None = None,
    options: WelchOptions = WelchOptions(),
) -> tuple[Float[_A, " freq"], Complex[_A, "*batch freq"]]:
    """One-sided Welch cross spectral density ``P_xy``, as ``scipy.signal.csd`` computes it.

    The segments, window, detrending, weights and scaling are those of :func:`welch_psd`
    (``welch_csd(x, x, ...)`` is ``welch_psd(x, ...)`` as a complex array); each segment
    contributes ``conj(X) Y`` of the two FFTs. With :func:`welch_psd` of both signals it gives
    the magnitude-squared coherence ``|P_xy|^2 / (P_xx P_yy)`` and the transfer function
    ``P_xy / P_xx``.

    Parameters
    ----------
    x, y
        The two signals, of one shape (or shapes that broadcast), time on ``axis``.
    fs, nperseg, noverlap, axis, segment_weights, options
        As in :func:`welch_psd`.

    Returns
    -------
    freqs
        The frequencies, ``k fs / nfft`` for ``k = 0 .. nfft // 2``.
    csd
        The cross spectral density in (units of ``x``)(units of ``y``) / Hz.

    Raises
    ------
    ValueError
        As :func:`welch_psd`.
    """
    xp = _namespace(x, y, segment_weights)
    x, y = xp.broadcast_arrays(_time_last(x, axis, xp), _time_last(y, axis, xp))
    used = _used_segments(x.shape[-1], nperseg, noverlap, segment_weights)
    sx, win, n_segments, nfft = _segment_spectra(x, nperseg, noverlap, options, xp, used)
    sy, _, _, _ = _segment_spectra(y, nperseg, noverlap, options, xp, used)
    layout = (x.shape[-1], nperseg, noverlap, n_segments)
    cross = _average(xp.conj(sx) * sy, segment_weights, layout, xp, used)
    return _density(cross, win, nfft, fs, x.dtype, axis, xp)


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
