"""Spectral features: log PSD, band means, the CNN input and the objective J of the paper."""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._cacheable import error_if
from .._types import Array, Float
from ._welch import welch_psd

#: default floor of :func:`log_psd`, far below any physical PSD in (m/s^2)^2/Hz
LOG_FLOOR = 1e-30


def log_psd(
    psd: Float[Array, "*batch freq"], floor: float = LOG_FLOOR
) -> Float[Array, "*batch freq"]:
    """log10 of a PSD, floored so that an exactly zero bin gives a finite value and gradient.

    Parameters
    ----------
    psd
        Power spectral density (any shape).
    floor
        Values below ``floor`` are raised to it before the logarithm.

    Returns
    -------
    log_psd
        ``log10(max(psd, floor))``.
    """
    return jnp.log10(jnp.maximum(psd, floor))


def band_features(
    freqs: Float[Array, " freq"],
    psd: Float[Array, "*batch freq"],
    edges: Sequence[float] | Float[Array, " edge"],
    *,
    log: bool = True,
) -> Float[Array, "*batch band"]:
    """Mean PSD in frequency bands, by default as log10.

    Band ``b`` holds the bins with ``edges[b] <= f < edges[b + 1]``; the last band also holds
    a bin at exactly ``edges[-1]``.

    Parameters
    ----------
    freqs
        The frequency of each PSD bin (the first output of :func:`welch_psd`).
    psd
        Power spectral density with frequency last.
    edges
        Increasing band edges in Hz (static): ``len(edges) - 1`` bands.
    log
        Return ``log10`` of the band means (through :func:`log_psd`) rather than the means.

    Returns
    -------
    features
        One value per band.

    Raises
    ------
    ValueError
        For fewer than two edges or edges that do not increase; at run time
        (``eqx.error_if``) for a band that holds no frequency bin.
    """
    e = np.asarray(edges, dtype=float)
    if e.ndim != 1 or e.size < 2 or np.any(np.diff(e) <= 0):
        raise ValueError(f"edges must be at least two increasing frequencies, got {e.tolist()}")
    lower = jnp.asarray(e[:-1], dtype=psd.dtype)
    upper = jnp.asarray(e[1:], dtype=psd.dtype)
    last = np.arange(e.size - 1) == e.size - 2
    f = jnp.asarray(freqs, dtype=psd.dtype)[:, None]
    member = (f >= lower) & ((f < upper) | (last & (f == upper)))
    member = member.astype(psd.dtype)
    counts = error_if(
        jnp.sum(member, axis=0),
        jnp.sum(member, axis=0) == 0,
        "a frequency band holds no PSD bin: widen the bands or use a finer resolution (nperseg)",
    )
    means = (psd @ member) / counts
    return log_psd(means) if log else means


def _band_or_none(band) -> tuple[float, float] | None:
    return None if band is None else tuple(float(f) for f in band)  # type: ignore[return-value]


class CNNInputSpec(eqx.Module):
    """How the classifier's input is made from the sensor signals (the paper's 4 x 25 image).

    Welch PSD of each channel (Hann window, ``nperseg`` samples, half overlap), the bins from
    0 Hz up to ``fmax`` inclusive, as log10 by default. With 2048 Hz sampling and the
    defaults, the bins are 0, 4, ..., 96 Hz: 25 per channel.

    With ``envelope_band`` the Welch PSD is that of each channel's *envelope* in the band
    (:func:`band_envelope`): the classic input of rolling-element bearing diagnostics, where a
    localised fault shows as lines at its impact rate and harmonics, whatever the transfer
    path that shapes the resonance band (Randall and Antoni, "Rolling element bearing
    diagnostics - A tutorial", MSSP 25, 2011, 485-520).

    Parameters
    ----------
    fmax
        The highest frequency kept, Hz.
    nperseg
        Samples per Welch segment; the bin spacing is ``fs / nperseg``.
    log
        Return log10 PSD (through :func:`log_psd`) rather than the PSD.
    envelope_band
        ``(low, high)`` Hz: the input is the spectrum of the envelope of this band rather than
        the spectrum of the signal; ``None`` (the default) for the signal's own spectrum.
    """

    fmax: float = eqx.field(static=True, default=96.0)
    nperseg: int = eqx.field(static=True, default=512)
    log: bool = eqx.field(static=True, default=True)
    envelope_band: tuple[float, float] | None = eqx.field(
        static=True, default=None, converter=_band_or_none
    )

    def __check_init__(self):
        if not self.fmax > 0:
            raise ValueError(f"fmax must be positive (Hz), got {self.fmax!r}")
        if isinstance(self.nperseg, bool) or not isinstance(self.nperseg, int) or self.nperseg < 2:
            raise ValueError(f"nperseg must be an integer >= 2, got {self.nperseg!r}")
        if self.envelope_band is not None:
            lo, hi = self.envelope_band
            if not 0 <= lo < hi:
                raise ValueError(
                    f"envelope_band must be (low, high) Hz with 0 <= low < high, got "
                    f"{self.envelope_band!r}"
                )

    def frequencies(self, fs: float) -> np.ndarray:
        """The bin frequencies (Hz) of the input at sampling rate ``fs``.

        Raises
        ------
        ValueError
            When ``fmax`` or the envelope band lies above the Nyquist frequency ``fs / 2``.
        """
        if self.fmax > fs / 2:
            raise ValueError(
                f"fmax={self.fmax} Hz lies above the Nyquist frequency {fs / 2} Hz of "
                f"fs={fs} Hz: lower fmax or sample faster"
            )
        if self.envelope_band is not None and self.envelope_band[1] > fs / 2:
            raise ValueError(
                f"envelope_band={self.envelope_band} Hz reaches above the Nyquist frequency "
                f"{fs / 2} Hz of fs={fs} Hz"
            )
        # the tiny slack keeps fmax itself when it falls on a bin (96 Hz = 24 x 4 Hz)
        n_bins = int(np.floor(self.fmax * self.nperseg / fs + 1e-9)) + 1
        return np.arange(n_bins) * (fs / self.nperseg)

    def to_dict(self) -> dict:
        """JSON-able settings; ``envelope_band`` only where it is set, so that the settings
        (and the hashes made from them) of a plain spectrum read as they always did."""
        out: dict = {"fmax": self.fmax, "nperseg": self.nperseg, "log": self.log}
        if self.envelope_band is not None:
            out["envelope_band"] = list(self.envelope_band)
        return out


def band_envelope(
    signals: Float[Array, "*batch time"], fs: float, band: tuple[float, float]
) -> Float[Array, "*batch time"]:
    """The envelope of each signal in a frequency band: the modulus of its analytic signal.

    The band-pass and the Hilbert transform are one step on the DFT of the whole record:
    the bins inside ``[low, high]`` Hz on the positive side, doubled, the others zero; the
    modulus of the inverse DFT is the envelope (an ideal band-pass, circular over the record).

    Parameters
    ----------
    signals
        Signals, time last.
    fs
        Sampling rate, Hz.
    band
        ``(low, high)`` Hz.

    Returns
    -------
    envelope
        Same shape as ``signals``, in their units.
    """
    n = signals.shape[-1]
    f = np.fft.fftfreq(n, 1.0 / fs)
    spectrum = jnp.fft.fft(signals, axis=-1)
    keep = jnp.asarray(np.where((f >= band[0]) & (f <= band[1]), 2.0, 0.0), spectrum.dtype)
    return jnp.abs(jnp.fft.ifft(spectrum * keep, axis=-1))


def cnn_input(
    signals: Float[Array, "*batch channel time"],
    fs: float,
    spec: CNNInputSpec | None = None,
    *,
    segment_weights: Float[Array, "*#batch segment"] | None = None,
) -> Float[Array, "*batch channel freq"]:
    """The classifier's input: low-frequency (log) PSD of every channel, or of its envelope
    in a band (``spec.envelope_band``).

    Parameters
    ----------
    signals
        Sensor signals, time last.
    fs
        Sampling rate in Hz.
    spec
        Resolution, band and scale of the input; ``None`` means ``CNNInputSpec()``, the
        paper's 4 x 25 input (0-96 Hz at 4 Hz for 2048 Hz sampling, log10).
    segment_weights
        Optional Welch segment weights (see :func:`welch_psd`), for example to use only the
        motion window.

    Returns
    -------
    features
        One row of ``len(spec.frequencies(fs))`` values per channel.

    References
    ----------
    The CNN input of "Real-time condition monitoring of mechanical systems using CNNs trained
    by multibody simulations", X ECCOMAS Thematic Conference on Smart Structures and Materials
    (SMART 2023), 2023: PSDs of the four acceleration channels below 100 Hz;
    ``docs/features.md``.
    """
    spec = CNNInputSpec() if spec is None else spec
    n_bins = spec.frequencies(fs).size
    if spec.envelope_band is not None:
        signals = band_envelope(signals, fs, spec.envelope_band)
    _, psd = welch_psd(signals, fs, nperseg=spec.nperseg, segment_weights=segment_weights)
    psd = psd[..., :n_bins]
    return log_psd(psd) if spec.log else psd


def objective_j(
    psd_sim: Float[Array, "*#batch channel freq"],
    psd_meas: Float[Array, "*#batch channel freq"],
) -> Float[Array, "*batch"]:
    """The paper's objective J: the sum over channels of the RMS spectral misfit.

    ``J = sum_i sqrt(mean_j (yhat_ij - y_ij)^2)`` with ``i`` the channel and ``j`` the
    frequency. The spectra are used as given: pass log10 PSDs for the paper's log misfit.
    The square root has gradient 0 (its subgradient) where a channel fits exactly, so
    ``jax.grad`` stays finite at a perfect fit.

    Parameters
    ----------
    psd_sim
        Simulated spectra ``yhat``.
    psd_meas
        Measured spectra ``y``; leading dimensions broadcast against ``psd_sim``.

    Returns
    -------
    j
        One value per leading index.

    Raises
    ------
    ValueError
        When the (channel, freq) shapes differ or the leading dimensions do not broadcast.

    References
    ----------
    Eq. (2) of "Real-time condition monitoring of mechanical systems using CNNs trained by
    multibody simulations", X ECCOMAS Thematic Conference on Smart Structures and Materials
    (SMART 2023), 2023; ``docs/features.md``.
    """
    psd_sim, psd_meas = jnp.asarray(psd_sim), jnp.asarray(psd_meas)
    if psd_sim.ndim < 2 or psd_sim.shape[-2:] != psd_meas.shape[-2:]:
        raise ValueError(
            "psd_sim and psd_meas must end with the same (channel, freq) axes, got shapes "
            f"{psd_sim.shape} and {psd_meas.shape}"
        )
    try:
        np.broadcast_shapes(psd_sim.shape, psd_meas.shape)
    except ValueError:
        raise ValueError(
            f"the leading dimensions of psd_sim {psd_sim.shape} and psd_meas {psd_meas.shape} "
            "do not broadcast"
        ) from None
    mean_square = jnp.mean((psd_sim - psd_meas) ** 2, axis=-1)
    positive = mean_square > 0
    rms = jnp.where(positive, jnp.sqrt(jnp.where(positive, mean_square, 1.0)), 0.0)
    return jnp.sum(rms, axis=-1)
