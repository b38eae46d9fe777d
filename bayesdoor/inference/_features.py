"""Features for fitting: log10 Welch band PSDs in the motion window, and their Welch scatter.

The same function serves measured and simulated runs, so a misfit between them is a misfit of
the physics, not of the processing.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._types import Array, Float
from ..features import (
    WelchOptions,
    band_features,
    log10_psd_variance,
    segment_weights,
    welch_dof,
    welch_psd,
)

#: how far (in bin spacings) a band edge may sit from a multiple of the bin spacing
_GRID_TOLERANCE = 1e-9


class FeatureSpec(eqx.Module):
    """How a run becomes its feature vector: log10 Welch PSD, averaged in bands, all channels.

    The Welch PSD (``window``, ``nperseg`` samples, ``noverlap`` shared by consecutive
    segments) is taken over the segments inside the run's motion window; the bins from
    ``f_low`` to ``f_high`` (both included) are averaged in consecutive groups of
    ``band_width / (fs / nperseg)`` bins, and each group mean becomes log10. The defaults give
    the paper's analysis band: 4 to 96 Hz at 4 Hz resolution (24 bands of one bin each at
    2048 Hz sampling).

    Parameters
    ----------
    f_low, f_high
        The first and the last bin frequency of the analysis band, Hz.
    band_width
        Width of a band, Hz: a whole multiple of the bin spacing ``fs / nperseg``.
    nperseg
        Samples per Welch segment.
    noverlap
        Samples shared by consecutive segments; ``None`` means ``nperseg // 2``.
    window
        A ``scipy.signal.get_window`` name.
    """

    f_low: float = eqx.field(static=True, default=4.0)
    f_high: float = eqx.field(static=True, default=96.0)
    band_width: float = eqx.field(static=True, default=4.0)
    nperseg: int = eqx.field(static=True, default=512)
    noverlap: int | None = eqx.field(static=True, default=None)
    window: str = eqx.field(static=True, default="hann")

    def __check_init__(self):
        if not 0.0 < self.f_low <= self.f_high:
            raise ValueError(
                f"need 0 < f_low <= f_high, got f_low={self.f_low!r}, f_high={self.f_high!r} Hz "
                "(the DC bin carries the mean, not the vibration)"
            )
        if not self.band_width > 0.0:
            raise ValueError(f"band_width must be positive (Hz), got {self.band_width!r}")
        if isinstance(self.nperseg, bool) or not isinstance(self.nperseg, int) or self.nperseg < 4:
            raise ValueError(f"nperseg must be an integer >= 4, got {self.nperseg!r}")
        if self.noverlap is not None and not 0 <= self.noverlap < self.nperseg:
            raise ValueError(
                f"noverlap must lie in [0, nperseg) = [0, {self.nperseg}), got {self.noverlap!r}"
            )

    @classmethod
    def of(cls, system) -> FeatureSpec:
        """The fit's features as ``system`` declares them (:attr:`~bayesdoor.systems.
        AbstractSystem.features`)."""
        f = system.features
        return cls(f_low=f.f_low, f_high=f.f_high, band_width=f.band_width, nperseg=f.nperseg)

    @property
    def step(self) -> int:
        """Samples between the starts of consecutive segments."""
        return self.nperseg - (self.nperseg // 2 if self.noverlap is None else self.noverlap)

    def bins_per_band(self, fs: float) -> int:
        """PSD bins averaged in one band at sampling rate ``fs``.

        Raises
        ------
        ValueError
            When the band width is not a whole multiple of the bin spacing, the analysis band
            does not hold a whole number of bands, a band edge is off the bin grid, or
            ``f_high`` lies above the Nyquist frequency.
        """
        df = float(fs) / self.nperseg
        ratio = self.band_width / df
        bins = round(ratio)
        if bins < 1 or abs(ratio - bins) > _GRID_TOLERANCE * max(1.0, ratio):
            raise ValueError(
                f"band_width={self.band_width} Hz must be a whole multiple of the bin spacing "
                f"fs / nperseg = {df:g} Hz; pass band_width={max(1, round(ratio)) * df:g}"
            )
        if abs(self.f_low / df - round(self.f_low / df)) > _GRID_TOLERANCE * self.f_low / df:
            raise ValueError(
                f"f_low={self.f_low} Hz must lie on the bin grid (multiples of {df:g} Hz)"
            )
        n_bins = (self.f_high - self.f_low) / df + 1.0
        if abs(n_bins / bins - round(n_bins / bins)) > _GRID_TOLERANCE * n_bins:
            raise ValueError(
                f"the analysis band {self.f_low}-{self.f_high} Hz holds {n_bins:g} bins of "
                f"{df:g} Hz, not a whole number of bands of {bins} bins; pass f_high="
                f"{self.f_low + (np.ceil(n_bins / bins) * bins - 1) * df:g}"
            )
        if self.f_high > fs / 2:
            raise ValueError(
                f"f_high={self.f_high} Hz lies above the Nyquist frequency {fs / 2} Hz"
            )
        return bins

    def band_edges(self, fs: float) -> np.ndarray:
        """Band edges (Hz), half a bin outside the first and last bin of each band."""
        bins = self.bins_per_band(fs)
        df = float(fs) / self.nperseg
        n_bands = round(((self.f_high - self.f_low) / df + 1.0) / bins)
        return self.f_low - 0.5 * df + np.arange(n_bands + 1) * bins * df

    def band_centres(self, fs: float) -> np.ndarray:
        """The mean bin frequency of each band (Hz)."""
        edges = self.band_edges(fs)
        return 0.5 * (edges[:-1] + edges[1:])

    def n_segments(self, n_time: int) -> int:
        """Welch segments in a record of ``n_time`` samples (the static segment count)."""
        return max(0, (n_time - self.nperseg) // self.step + 1)


def run_features(
    signals: Float[Array, "*batch channel time"],
    fs: float,
    t_start: Float[Array, "*#batch"] | float,
    t_stop: Float[Array, "*#batch"] | float,
    spec: FeatureSpec | None = None,
) -> tuple[Float[Array, "*batch channel band"], Float[Array, "*batch"]]:
    """The feature vector of each run and the number of Welch segments it averages.

    Parameters
    ----------
    signals
        Sensor signals of one or more runs, time last, the first sample at t = 0.
    fs
        Sampling rate, Hz.
    t_start, t_stop
        The motion window of each run (s); only Welch segments entirely inside it count.
    spec
        The feature definition; ``None`` means ``FeatureSpec()``.

    Returns
    -------
    features
        log10 of the band-mean Welch PSD ((units of signals)^2 / Hz), per channel and band.
    n_segments
        The number of segments averaged for each run (it sets the Welch scatter, see
        :func:`welch_log10_variance`).

    Raises
    ------
    ValueError
        For an inconsistent ``spec`` (see :meth:`FeatureSpec.bins_per_band`) or a record shorter
        than one segment; at run time, for a window that holds no whole segment.
    """
    spec = FeatureSpec() if spec is None else spec
    signals = jnp.asarray(signals)
    edges = spec.band_edges(fs)
    weights = segment_weights(
        signals.shape[-1], fs, t_start, t_stop, spec.nperseg, spec.noverlap
    ).astype(signals.dtype)
    weights = jnp.broadcast_to(
        weights, (*jnp.broadcast_shapes(weights.shape[:-1], signals.shape[:-2]), weights.shape[-1])
    )
    freqs, psd = welch_psd(
        signals,
        fs,
        nperseg=spec.nperseg,
        noverlap=spec.noverlap,
        segment_weights=weights[..., None, :],
        options=WelchOptions(window=spec.window),
    )
    return band_features(freqs, psd, edges.tolist()), jnp.sum(weights, axis=-1)


def welch_degrees_of_freedom(
    n_segments: Float[Array, "*batch"] | float, fs: float, spec: FeatureSpec | None = None
) -> Float[Array, "*batch"]:
    """Equivalent chi-square degrees of freedom of a band-mean Welch PSD.

    :func:`bayesdoor.features.welch_dof` for the segmentation and the bins per band of
    ``spec`` at sampling rate ``fs``: a band mean of ``B`` bins, each averaged over ``K``
    overlapping windowed segments, is distributed approximately as ``P chi2_nu / nu``. With
    one bin and no overlap ``nu = 2 K``; the Hann window at 50 % overlap correlates
    neighbouring segments (``rho^2 = 1/36``) and neighbouring bins (``rho^2 = 4/9``), so
    ``nu`` is smaller than ``2 K B``.

    Parameters
    ----------
    n_segments
        Segments averaged in each run (the second output of :func:`run_features`); traced.
    fs
        Sampling rate, Hz.
    spec
        The feature definition; ``None`` means ``FeatureSpec()``.

    Returns
    -------
    nu
        The degrees of freedom of each run's band means.
    """
    spec = FeatureSpec() if spec is None else spec
    return welch_dof(
        jnp.asarray(n_segments),
        spec.nperseg,
        spec.noverlap,
        spec.window,
        bins=spec.bins_per_band(fs),
    )


def welch_log10_variance(
    n_segments: Float[Array, "*batch"] | float, fs: float, spec: FeatureSpec | None = None
) -> Float[Array, "*batch"]:
    """Variance of a log10 band-mean Welch PSD about log10 of its expectation.

    :func:`bayesdoor.features.log10_psd_variance` of :func:`welch_degrees_of_freedom`:
    ``trigamma(nu / 2) / ln(10)^2``. (Its mean is also shifted, by ``(digamma(nu / 2) -
    ln(nu / 2)) / ln 10``, about ``-0.01`` decades for the door's 20-odd segments; the
    likelihood leaves that to the model error.)

    Parameters
    ----------
    n_segments
        Segments averaged in each run.
    fs
        Sampling rate, Hz.
    spec
        The feature definition; ``None`` means ``FeatureSpec()``.

    Returns
    -------
    variance
        Variance in decades^2, one per run.
    """
    return log10_psd_variance(welch_degrees_of_freedom(n_segments, fs, spec))
