"""Coherence between channels in measured and simulated runs: coherent content the model lacks."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import scipy.stats
from jaxtyping import Complex

from .._types import Bool, Float
from ..features import welch_csd, welch_dof, welch_psd, welch_segment_count
from ._stats import benjamini_hochberg


@dataclasses.dataclass(frozen=True)
class PairCoherence:
    """Measured against simulated coherence of one pair of channels.

    Attributes
    ----------
    pair
        The two channel names ``(a, b)``.
    measured, simulated
        Magnitude-squared coherence per run and bin.
    z
        The combined (over runs) one-sided statistic for measured coherence above simulated.
    significant
        Bins rejected in the Benjamini-Hochberg family of all pairs.
    fraction_significant
        Share of the analysed bins that are significant.
    source, receiver
        The direction of the leak that fits best: ``receiver`` carries a fraction of
        ``source``'s signal.
    transfer
        Median over runs of the change of the transfer function ``receiver / source``
        (measured minus simulated) per bin.
    leak
        The real leak fraction: the median of ``transfer`` over the significant bins (NaN
        when none is).
    leak_spread
        Median absolute deviation of ``transfer`` about ``leak`` over the significant bins,
        relative to ``|leak|``: small for a frequency-independent leak.
    leak_sd
        Standard error of ``leak``: that of the median of ``n`` normal values,
        ``1.2533 sigma / sqrt(n)``, with ``sigma = 1.4826`` times the median absolute
        deviation over the ``n`` significant bins (optimistic where neighbouring bins are
        correlated; NaN without significant bins).
    """

    pair: tuple[str, str]
    measured: Float[np.ndarray, "run freq"]
    simulated: Float[np.ndarray, "run freq"]
    z: Float[np.ndarray, " freq"]
    significant: Bool[np.ndarray, " freq"]
    fraction_significant: float
    source: str
    receiver: str
    transfer: Complex[np.ndarray, " freq"]
    leak: float
    leak_spread: float
    leak_sd: float = float("nan")

    def significant_near(self, frequency_hz: float, freqs: np.ndarray, tol_hz: float) -> bool:
        near = np.abs(freqs - frequency_hz) <= tol_hz
        return bool(np.any(self.significant & near))


@dataclasses.dataclass(frozen=True)
class CoherenceMap:
    """Coherence excess of every requested pair.

    Attributes
    ----------
    freqs
        The analysed bins, Hz.
    pairs
        One :class:`PairCoherence` per pair, in the order requested.
    q, p_threshold
        The false discovery rate and the largest p-value rejected.
    """

    freqs: Float[np.ndarray, " freq"]
    pairs: tuple[PairCoherence, ...]
    q: float
    p_threshold: float

    def for_channel(self, channel: str) -> tuple[PairCoherence, ...]:
        return tuple(p for p in self.pairs if channel in p.pair)


def _spectra(x: np.ndarray, y: np.ndarray, fs: float, nperseg: int):
    _, pxx = welch_psd(x, fs, nperseg=nperseg)
    _, pyy = welch_psd(y, fs, nperseg=nperseg)
    freqs, pxy = welch_csd(x, y, fs, nperseg=nperseg)
    return freqs, pxx, pyy, pxy


def _pair_statistics(runs, a: int, b: int, fs: float, nperseg: int):
    """Per run: coherence, the two transfer functions b/a and a/b, and the segment count."""
    coh, h_ba, h_ab, counts = [], [], [], []
    for x in runs:
        freqs, paa, pbb, pab = _spectra(x[a], x[b], fs, nperseg)
        coh.append(np.abs(pab) ** 2 / (paa * pbb))
        h_ba.append(pab / paa)
        h_ab.append(np.conj(pab) / pbb)
        counts.append(welch_segment_count(x.shape[-1], nperseg))
    return freqs, np.array(coh), np.array(h_ba), np.array(h_ab), np.array(counts)


def _check_runs(name: str, runs, n_channels: int | None, nperseg: int) -> list[np.ndarray]:
    out = [np.asarray(x, dtype=float) for x in runs]
    for i, x in enumerate(out):
        if x.ndim != 2 or (n_channels is not None and x.shape[0] != n_channels):
            raise ValueError(
                f"{name}[{i}] must have dims (channel, time) with {n_channels} channels, got "
                f"shape {x.shape}"
            )
        if x.shape[-1] < nperseg:
            raise ValueError(
                f"{name}[{i}] has {x.shape[-1]} samples, fewer than nperseg={nperseg}: pass a "
                "smaller nperseg"
            )
    return out


def coherence_map(
    measured: Sequence[Float[np.ndarray, "channel time"]],
    simulated: Sequence[Float[np.ndarray, "channel time"]],
    fs: float,
    *,
    channels: Sequence[str],
    pairs: Sequence[tuple[str, str]],
    nperseg: int,
    band: tuple[float, float] | None = None,
    q: float = 0.01,
) -> CoherenceMap:
    """Where measured channels are more coherent than the model says they should be.

    Per run and pair, the magnitude-squared coherence ``C`` (the Welch estimate of
    :func:`bayesdoor.features.welch_csd` and :func:`bayesdoor.features.welch_psd`, Hann, 50 %
    overlap) is Fisher-transformed: ``atanh(sqrt(C))`` is close to normal
    with variance ``1 / (2 (n - 1))`` for ``n`` independent segments (here ``n = nu / 2`` from
    the Welch degrees of freedom); its small-sample bias is the same for measured and simulated
    runs of equal length and cancels in the difference. The differences are combined over runs
    (Stouffer), tested one-sided (more coherence than simulated) in one Benjamini-Hochberg
    family over pairs and bins.

    For a pair ``(a, b)`` where ``b`` receives a fraction ``e`` of ``a`` (``b = b0 + e a``),
    the transfer function ``P_ab / P_aa`` rises by exactly ``e`` at every frequency, while
    the reverse one changes by a frequency-dependent amount; the direction whose change is the
    flatter over the significant bins is reported, with the median change as the leak.

    Parameters
    ----------
    measured, simulated
        Per run, the signals over the analysed window (for example the motion); a simulated
        run per measured run, of the same length.
    fs
        Sampling rate, Hz.
    channels
        Channel names of the rows.
    pairs
        Pairs of channel names to examine.
    nperseg
        Samples per segment; coarser than a residual map (for example ``fs / 4``) so that
        each run has enough segments for a stable coherence.
    band
        Analysed frequency range, Hz; ``None`` drops only 0 Hz and Nyquist.
    q
        False discovery rate.

    Returns
    -------
    CoherenceMap

    Raises
    ------
    ValueError
        For unknown channel names, mismatched runs or runs shorter than ``nperseg``.

    References
    ----------
    J. S. Bendat and A. G. Piersol (2010), *Random Data*, 4th ed., section 9.2.3 (the
    variance of the transformed coherence estimate).
    """
    names = list(channels)
    meas, sim = _check_inputs(measured, simulated, names, pairs, nperseg)
    freqs, stats = _pair_changes(meas, sim, names, pairs, fs, nperseg)
    lo, hi = (freqs[1], freqs[-2]) if band is None else band
    keep = (freqs >= lo) & (freqs <= hi)
    z_all = _excess_z(stats, keep, nperseg)
    rejected, threshold = benjamini_hochberg(scipy.stats.norm.sf(z_all), q)
    out = [
        _pair_coherence(pair, stat, z, sig, keep)
        for pair, stat, z, sig in zip(pairs, stats, z_all, rejected, strict=True)
    ]
    return CoherenceMap(freqs=freqs[keep], pairs=tuple(out), q=float(q), p_threshold=threshold)


def _check_inputs(
    measured: Sequence[np.ndarray],
    simulated: Sequence[np.ndarray],
    names: list[str],
    pairs: Sequence[tuple[str, str]],
    nperseg: int,
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The measured and simulated runs as arrays, once the pairs' names and the shapes check."""
    if not pairs:
        raise ValueError("pairs is empty: name at least one pair of channels to examine")
    for pair in pairs:
        for name in pair:
            if name not in names:
                raise ValueError(f"pair {pair!r} names channel {name!r}; the channels are {names}")
    meas = _check_runs("measured", measured, len(names), nperseg)
    sim = _check_runs("simulated", simulated, len(names), nperseg)
    if len(meas) != len(sim) or any(m.shape != s.shape for m, s in zip(meas, sim, strict=True)):
        raise ValueError(
            "simulated must hold one run of the same shape per measured run; got "
            f"{[m.shape for m in meas]} measured and {[s.shape for s in sim]} simulated"
        )
    return meas, sim


class _PairChange(NamedTuple):
    """One pair's coherence per run and bin, measured and simulated, the change (measured
    minus simulated) of its transfer functions b/a and a/b, and each run's segment count."""

    measured: np.ndarray
    simulated: np.ndarray
    change_ba: np.ndarray
    change_ab: np.ndarray
    counts: np.ndarray


def _pair_changes(
    meas: list[np.ndarray],
    sim: list[np.ndarray],
    names: list[str],
    pairs: Sequence[tuple[str, str]],
    fs: float,
    nperseg: int,
) -> tuple[np.ndarray, list[_PairChange]]:
    """The bins and, per pair, its coherences and transfer changes over all bins."""
    stats = []
    for a_name, b_name in pairs:
        a, b = names.index(a_name), names.index(b_name)
        freqs, c_m, hba_m, hab_m, counts = _pair_statistics(meas, a, b, fs, nperseg)
        _, c_s, hba_s, hab_s, _ = _pair_statistics(sim, a, b, fs, nperseg)
        stats.append(_PairChange(c_m, c_s, hba_m - hba_s, hab_m - hab_s, counts))
    return freqs, stats


def _excess_z(stats: list[_PairChange], keep: np.ndarray, nperseg: int) -> np.ndarray:
    """Per pair and kept bin, the Fisher-transformed coherence excess combined over runs."""
    z_rows = []
    for c_m, c_s, _, _, counts in stats:
        n_eff = np.array([welch_dof(int(k), nperseg) / 2.0 for k in counts])
        var = 1.0 / (2.0 * np.maximum(n_eff - 1.0, 0.5))
        fisher = np.arctanh(np.sqrt(np.clip(c_m, 0, 1 - 1e-12))) - np.arctanh(
            np.sqrt(np.clip(c_s, 0, 1 - 1e-12))
        )
        d = fisher[:, keep] / np.sqrt(2.0 * var)[:, None]
        z_rows.append(d.sum(axis=0) / np.sqrt(d.shape[0]))
    return np.array(z_rows)


def _pair_coherence(
    pair: tuple[str, str], stat: _PairChange, z: np.ndarray, sig: np.ndarray, keep: np.ndarray
) -> PairCoherence:
    """The pair's record over the kept bins, its leak in the direction of the flatter change."""
    a_name, b_name = pair
    c_m, c_s, dba, dab, _ = stat
    t_ba = np.median(dba[:, keep].real, axis=0) + 1j * np.median(dba[:, keep].imag, axis=0)
    t_ab = np.median(dab[:, keep].real, axis=0) + 1j * np.median(dab[:, keep].imag, axis=0)
    leak_ba, spread_ba, sd_ba = _leak(t_ba, sig)
    leak_ab, spread_ab, sd_ab = _leak(t_ab, sig)
    forward = not spread_ab < spread_ba
    return PairCoherence(
        pair=(a_name, b_name),
        measured=c_m[:, keep],
        simulated=c_s[:, keep],
        z=z,
        significant=sig,
        fraction_significant=float(sig.mean()),
        source=a_name if forward else b_name,
        receiver=b_name if forward else a_name,
        transfer=t_ba if forward else t_ab,
        leak=leak_ba if forward else leak_ab,
        leak_spread=spread_ba if forward else spread_ab,
        leak_sd=sd_ba if forward else sd_ab,
    )


def _leak(transfer: np.ndarray, significant: np.ndarray) -> tuple[float, float, float]:
    """Median of the real transfer change over the significant bins, its relative spread and
    its standard error."""
    if not significant.any():
        return float("nan"), float("inf"), float("nan")
    values = transfer[significant]
    leak = float(np.median(values.real))
    mad = float(np.median(np.abs(values - leak)))
    sd = 1.2533 * 1.4826 * mad / np.sqrt(values.size)
    return leak, mad / abs(leak) if leak != 0 else float("inf"), float(sd)
