"""Signatures: how each candidate cause shows in the residual features, and how well it fits.

A signature is data (a frozen module with the system's numbers); :meth:`match` examines the
features, picks the feature that fits the signature best and returns the checks it passes
and the parameter estimate it implies. The score of a signature is the share of its checks
that the best feature passes (checks that the data cannot decide, for example the rest when no
rest segment was recorded, are left out of the share).
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Mapping

import equinox as eqx
import numpy as np

from ._coherence import PairCoherence
from ._comb import harmonic_comb
from ._features import Features
from ._order import order_peak
from ._residual import FIXED, FREQUENCY, TRACKING, UNDETERMINED, WAVENUMBER, Region

#: a fixed-frequency line at rest has this tolerance in motion bins, on top of the rest bin
LINE_TOLERANCE_BINS = 2.0
#: a line's power at rest and in motion may differ by this much (dB) and count as constant
CONSTANT_AMPLITUDE_DB = 6.0


@dataclasses.dataclass(frozen=True)
class Check:
    """One test of a signature on a feature: ``passed`` is ``None`` when the data cannot tell."""

    name: str
    passed: bool | None
    detail: str = ""


@dataclasses.dataclass(frozen=True)
class Match:
    """The best feature for a signature: its checks, the parameters it implies, its strength."""

    feature: str
    checks: tuple[Check, ...]
    parameters: Mapping[str, float | str | tuple]
    strength: float

    @property
    def score(self) -> float:
        known = [c.passed for c in self.checks if c.passed is not None]
        return float(np.mean(known)) if known else 0.0

    def evidence(self) -> str:
        parts = []
        for c in self.checks:
            mark = "n/a" if c.passed is None else ("yes" if c.passed else "no")
            parts.append(f"{c.name}: {mark}" + (f" ({c.detail})" if c.detail else ""))
        return f"{self.feature}; " + "; ".join(parts)


def _best(matches: list[Match]) -> Match | None:
    return max(matches, key=lambda m: (m.score, m.strength), default=None)


def _in_most_runs(region: Region, n_runs: int) -> Check:
    n = region.runs_present
    return Check("in most runs", 2 * n >= n_runs, f"{n} of {n_runs}")


def _speed_check(features: Features, region: Region, wanted: str) -> Check:
    """Across runs when the speeds decide, else within the runs when the profiles decide."""
    name = "frequency independent of speed" if wanted == FIXED else "frequency follows the speed"
    across = region.speed.preferred
    within = features.within(region)
    inside = "" if within is None else f"; within runs: {within.preferred} (z = {within.z:.1f})"
    if across == UNDETERMINED and within is not None and within.preferred != UNDETERMINED:
        return Check(name, within.preferred == wanted, f"across runs: {across}{inside}")
    return Check(name, across == wanted, f"across runs: {across}{inside}")


def _rest_tolerance(features: Features) -> float:
    rest = features.rest_before
    res = features.residuals.resolution_hz
    return LINE_TOLERANCE_BINS * res + (rest.resolution_hz if rest is not None else 0.0)


def _absent_before_motion(features: Features, frequencies: np.ndarray) -> Check:
    rest = features.rest_before
    if rest is None:
        return Check("absent at rest before the motion", None, "no rest recorded")
    tol = _rest_tolerance(features)
    found = [line for f in frequencies if np.isfinite(f) for line in rest.near(float(f), tol)]
    detail = f"line at {found[0].frequency_hz:.2f} Hz" if found else ""
    return Check("absent at rest before the motion", not found, detail)


def _unshared_fraction(
    regions: tuple[Region, ...], freqs: np.ndarray, pair: PairCoherence
) -> float:
    """Share of a pair's bins with a coherence excess that no shared feature explains.

    A resonance or tone that both channels of the pair show (overlapping positive
    frequency-domain regions) makes them coherent over its band; a leak makes them coherent
    wherever the source has signal, with an excess in the receiver's spectrum only. Bins within
    one coherence bin of the overlap of two such regions are left out of both the count and the
    total.
    """
    step = float(freqs[1] - freqs[0])
    a_regions, b_regions = (
        [r for r in regions if r.channel == ch and r.sign > 0 and r.domain == FREQUENCY]
        for ch in pair.pair
    )
    shared = np.zeros(freqs.shape, dtype=bool)
    for a in a_regions:
        for b in b_regions:
            lo, hi = max(a.low, b.low), min(a.high, b.high)
            if lo <= hi:
                shared |= (freqs >= lo - step) & (freqs <= hi + step)
    rest = ~shared
    return float(np.sum(pair.significant & rest) / max(int(rest.sum()), 1))


class AbstractSignature(eqx.Module):
    """How a cause shows in the residual features."""

    @abc.abstractmethod
    def match(self, features: Features) -> Match | None:
        """The best-matching feature, or ``None`` when no feature is of this kind at all."""


class FixedFrequency(AbstractSignature):
    """A resonance the model lacks: excess at a speed-independent frequency within ``band``.

    Checks on each excess region of the fixed-frequency map with its peak in ``band``: its
    peak frequency does not move with speed (the speed fit across runs prefers ``f = const``,
    or, when it cannot tell, the within-run test does); it is in most runs; no line at that
    frequency at rest before the motion (a resonance needs excitation and decays at rest);
    its channel has no broadband coherence excess beyond shared features (a line carried
    over from another channel is a leak, not a mode). Parameters: ``frequency_hz`` (the
    centroid of the half-power band of the run-averaged excess power; over the channels that
    show the mode, the strongest region of each, weighted by its statistic),
    ``damping_ratio`` (half-power width over twice the frequency; an upper bound near the
    resolution, since the width includes the window's main lobe), ``excess_db``,
    ``channels``, ``band_hz`` (the lowest and highest significant bin of those regions, Hz),
    ``resolution_hz`` (the residual map's bin spacing, Hz) and ``line_at_rest`` (whether a
    line lies at the frequency at rest before the motion).
    """

    band: tuple[float, float] = eqx.field(static=True)
    max_coherent_fraction: float = eqx.field(static=True, default=0.1)

    def __check_init__(self):
        lo, hi = self.band
        if not 0 <= lo < hi:
            raise ValueError(f"band must be (low, high) Hz with 0 <= low < high, got {self.band}")

    def match(self, features: Features) -> Match | None:
        res = features.residuals
        regions = [
            r
            for r in res.regions
            if r.domain == FREQUENCY and r.sign > 0 and self.band[0] <= r.peak <= self.band[1]
        ]
        matches = []
        for region in regions:
            f = region.frequency_hz
            near = [
                r
                for r in regions
                if abs(r.centroid_hz - region.centroid_hz)
                <= max(LINE_TOLERANCE_BINS * res.resolution_hz, region.half_power_width_hz)
            ]
            # the strongest region of each channel that shows the mode, weighted by strength
            same = [
                max((r for r in near if r.channel == ch), key=lambda r: abs(r.z))
                for ch in {r.channel for r in near}
            ] or [region]
            weights = np.array([abs(r.z) for r in same])
            leak = None
            if features.coherence is not None:
                pairs = features.coherence.for_channel(region.channel)
                fractions = [
                    _unshared_fraction(res.regions, features.coherence.freqs, p) for p in pairs
                ]
                leak = max(fractions, default=0.0) >= self.max_coherent_fraction
            at_rest = _absent_before_motion(features, np.array([f]))
            checks = (
                _speed_check(features, region, FIXED),
                _in_most_runs(region, features.n_runs),
                at_rest,
                Check("no broadband coherence excess", None if leak is None else not leak),
            )
            matches.append(
                Match(
                    feature=region.describe(),
                    checks=checks,
                    parameters={
                        "frequency_hz": float(
                            np.average([r.centroid_hz for r in same], weights=weights)
                        ),
                        "damping_ratio": float(
                            np.average(
                                [r.half_power_width_hz / (2 * r.centroid_hz) for r in same],
                                weights=weights,
                            )
                        ),
                        "excess_db": region.excess_db,
                        "channels": tuple(sorted({r.channel for r in same})),
                        "band_hz": (
                            float(min(r.low for r in same)),
                            float(max(r.high for r in same)),
                        ),
                        "resolution_hz": float(res.resolution_hz),
                        "line_at_rest": at_rest.passed is False,
                    },
                    strength=abs(region.z),
                )
            )
        return _best(matches)


def _period_sd(region: Region) -> float:
    """Standard error of the tracking fit's period: the period times that of the mean of
    ``ln(f / v)`` over the affected runs (NaN with fewer than three)."""
    fit = region.speed
    if fit.n_runs < 3 or not np.isfinite(fit.rss_tracking):
        return float("nan")
    return float(fit.period * np.sqrt(fit.rss_tracking / (fit.n_runs - 1) / fit.n_runs))


#: the order-domain peak is searched within this relative distance of the speed fit's
#: wavenumber (a wheel's neighbouring harmonics lie 1 / k apart, 17 % at k = 6)
ORDER_WINDOW = 0.1
#: the measured order spectrum's own peak within this relative distance of the excess's is
#: taken as the tone's wavenumber (0: the excess's peak)
MEASURED_PEAK_WINDOW = 0.04


def _order_period(features: Features, region: Region) -> tuple[float, float, bool]:
    """A tracking region's period: from the order spectra (the channels' mean excess)
    when they were computed and show a peak near the speed fit's wavenumber (sharp whatever
    the speed profile), else the speed fit's; its standard error; whether order tracking
    gave it."""
    lam = region.speed.period
    excess = features.order_excess()
    if excess is None or features.orders is None or not np.isfinite(lam):
        return lam, _period_sd(region), False
    # every channel sees the same spatial period: their mean excess locates it more surely
    # than the region's own channel (on the rig, one channel's peak was 2.6 % off, the mean's
    # 1.6 %)
    kappa, sd = order_peak(
        excess.mean(axis=1), features.orders.wavenumbers, 1.0 / lam, ORDER_WINDOW
    )
    if not np.isfinite(kappa) or kappa <= 0:
        return lam, _period_sd(region), False
    if MEASURED_PEAK_WINDOW:
        # the excess is a ratio to the base model: a trough of the base spectrum next to the
        # tone pulls its peak off the tone; the measured spectrum's own peak is the tone's
        measured, measured_sd = order_peak(
            features.orders.log_psd.mean(axis=1),
            features.orders.wavenumbers,
            kappa,
            MEASURED_PEAK_WINDOW,
        )
        if np.isfinite(measured) and measured > 0:
            kappa, sd = measured, measured_sd
    return 1.0 / kappa, sd / kappa**2, True


def _closest(period: float, table: tuple[float, ...]) -> tuple[int, float] | None:
    """Index of the table's period nearest ``period`` and its relative distance
    ``|table[i] / period - 1|``; ``None`` for an empty table or a period not finite."""
    if not table or not np.isfinite(period):
        return None
    errors = np.abs(np.asarray(table) / period - 1.0)
    i = int(np.argmin(errors))
    return i, float(errors[i])


def _excluded_detail(period: float, excluded: tuple[float, ...], unit: str) -> str:
    """The period and the nearest excluded one, with how far apart they are: a tone at
    an excluded period (a wheel harmonic, for the rail) is the same excitation as the cause
    it belongs to, and the report should say how close it came."""
    closest = _closest(period, excluded)
    if closest is None:
        return f"{period:.4g} {unit}"
    nearest = excluded[closest[0]]
    return (
        f"{period:.4g} {unit}; the nearest excluded is {nearest:.4g} {unit}, "
        f"{100 * abs(period / nearest - 1.0):.1f} % away"
    )


class SpeedTracking(AbstractSignature):
    """A tone whose frequency is proportional to an operating condition: ``f = v / period``,
    ``v`` the condition the catalogue tracks (a door's speed in m/s, whose tones have a
    spatial period in metres; a shaft's speed in rev/s, whose orders ``k`` have the period
    ``1 / k`` revolution), ``period`` in its ``unit`` per cycle.

    ``periods`` lists the periods this cause produces (with ``labels``, for example the
    harmonic numbers); ``excluded`` lists periods this cause cannot have (they belong to
    another cause); a relative tolerance ``rel_tol`` decides a match. Checks on each excess
    region of the wavenumber map, or of the frequency map unless it is known to stay put
    (with one speed for all runs and no within-run test, a tone's period is ``v / f`` and
    the speed check fails, as the fixed signature's does: the two tie): the frequency
    follows the speed; it is in most runs; its
    period is one of ``periods`` (when given) and none of ``excluded`` (when given);
    no line at rest before the motion at its frequencies. Parameters: ``period`` (from
    the order spectra's peak within ``ORDER_WINDOW`` of the speed fit's wavenumber when the
    features hold order spectra, else the speed fit's) and ``period_sd`` (its standard
    error over the runs' peaks), ``period_source``, and with
    ``periods`` the matched ``label``, its ``listed_period`` and every label found among the
    tracking regions
    (``labels_found``).
    """

    periods: tuple[float, ...] = eqx.field(static=True, default=())
    excluded: tuple[float, ...] = eqx.field(static=True, default=())
    labels: tuple[int | str, ...] = eqx.field(static=True, default=())
    rel_tol: float = eqx.field(static=True, default=0.04)
    unit: str = eqx.field(static=True, default="m")

    def __check_init__(self):
        if any(w <= 0 for w in self.periods + self.excluded):
            raise ValueError("periods and excluded must be positive")
        if self.labels and len(self.labels) != len(self.periods):
            raise ValueError(
                f"labels names {len(self.labels)} periods, there are {len(self.periods)}"
            )
        if not 0 < self.rel_tol < 0.5:
            raise ValueError(f"rel_tol must lie in (0, 0.5), got {self.rel_tol}")

    def _nearest(self, period: float, table: tuple[float, ...]) -> int | None:
        closest = _closest(period, table)
        return closest[0] if closest is not None and closest[1] <= self.rel_tol else None

    def match(self, features: Features) -> Match | None:
        res = features.residuals
        regions = [
            r
            for r in res.regions
            if r.sign > 0
            and (r.domain == WAVENUMBER or not _speed_check(features, r, FIXED).passed)
            and np.isfinite(r.speed.period)
        ]
        labels = self.labels or tuple(range(1, len(self.periods) + 1))
        found = sorted(
            {
                labels[i]
                for r in regions
                if _speed_check(features, r, TRACKING).passed
                and (i := self._nearest(r.speed.period, self.periods)) is not None
            },
            key=str,
        )
        matches = []
        for region in regions:
            lam, lam_sd, tracked = _order_period(features, region)
            checks = [
                _speed_check(features, region, TRACKING),
                _in_most_runs(region, features.n_runs),
            ]
            params: dict[str, float | str | tuple] = {
                "period": lam,
                "period_sd": lam_sd,
                "period_source": "order tracking" if tracked else "speed fit",
            }
            if self.periods:
                i = self._nearest(lam, self.periods)
                checks.append(
                    Check("period among the listed ones", i is not None, f"{lam:.4g} {self.unit}")
                )
                if i is not None:
                    params["label"] = labels[i]
                    params["listed_period"] = self.periods[i]
                params["labels_found"] = tuple(found)
            if self.excluded:
                j = self._nearest(lam, self.excluded)
                checks.append(
                    Check(
                        "period not an excluded one",
                        j is None,
                        _excluded_detail(lam, self.excluded, self.unit),
                    )
                )
            checks.append(_absent_before_motion(features, region.runs.frequency_hz))
            matches.append(
                Match(
                    feature=region.describe(),
                    checks=tuple(checks),
                    parameters=params,
                    strength=abs(region.z),
                )
            )
        return _best(matches)


class HarmonicComb(AbstractSignature):
    """Lines at every harmonic ``k / period_m`` of a revolution in the order spectra.

    The matched test for a source on a part that turns once per ``period_m`` metres of travel
    (an out-of-round wheel: ``2 pi R``): :func:`harmonic_comb` over ``harmonics`` at the
    family-wise level ``alpha``, at least ``min_harmonics`` harmonics present (one line alone
    may be a rail tone that lies near a harmonic). One check, the comb; no match without order
    spectra. Parameters: ``labels_found`` (the present harmonics), ``label`` (the strongest),
    ``period`` (``period_m / label``) and ``comb_z`` (each harmonic's ``z``).
    """

    period_m: float = eqx.field(static=True)
    harmonics: tuple[int, ...] = eqx.field(static=True)
    alpha: float = eqx.field(static=True, default=0.01)
    min_harmonics: int = eqx.field(static=True, default=2)

    def __check_init__(self):
        if not self.period_m > 0 or not self.harmonics or min(self.harmonics) < 1:
            raise ValueError(
                f"period_m={self.period_m!r} must be positive and harmonics="
                f"{self.harmonics!r} non-empty integers >= 1"
            )
        if not 1 <= self.min_harmonics <= len(self.harmonics):
            raise ValueError(
                f"min_harmonics={self.min_harmonics!r} must lie in 1..{len(self.harmonics)}"
            )

    def match(self, features: Features) -> Match | None:
        if features.orders is None or not features.orders_predictive:
            return None
        comb = harmonic_comb(
            features.orders,
            features.orders_predictive,
            self.period_m,
            self.harmonics,
            alpha=self.alpha,
            min_harmonics=self.min_harmonics,
        )
        ranked = np.where(comb.present, comb.z, -np.inf)
        best = int(np.argmax(ranked)) if comb.present.any() else int(np.argmax(comb.z))
        label = comb.harmonics[best]
        return Match(
            feature=f"harmonic comb of {self.period_m:.4g} m in the order spectra",
            checks=(Check("harmonic comb", comb.significant, comb.describe()),),
            parameters={
                "labels_found": comb.found,
                "label": label,
                "period": self.period_m / label,
                "period_source": "harmonic comb",
                "comb_z": tuple(float(z) for z in comb.z),
            },
            strength=float(np.max(comb.z)),
        )


class FirstOf(AbstractSignature):
    """The first of ``signatures`` that can examine the features (returns a match).

    For a cause with a matched test that needs more than the residual maps, and a fallback:
    the door's wheel is judged by its harmonic comb when order spectra were computed, by a
    tracking tone at a harmonic otherwise (a single tone within 4 % of a harmonic is as
    likely a rail period: on the rig, a 26.0 mm rail tone passed as harmonic 7).
    """

    signatures: tuple[AbstractSignature, ...]

    def match(self, features: Features) -> Match | None:
        for signature in self.signatures:
            found = signature.match(features)
            if found is not None:
                return found
        return None


class CrossAxisCoherence(AbstractSignature):
    """One channel carries a fraction of another's signal: coherence the model lacks.

    Checks on each listed pair with a significant coherence excess: the excess covers at
    least ``min_fraction`` of the analysed bins that no feature shared by both channels
    explains (overlapping excess regions on both channels are left out: broadband, unlike a
    resonance both channels feel); the change of
    the transfer function in the best direction is flat (relative spread at most
    ``max_spread``). Parameters: ``fraction`` (the leak, signed, measured from the data's
    transfer function), ``fraction_sd`` (its standard error), ``receiver`` and ``source``.
    """

    pairs: tuple[tuple[str, str], ...] = eqx.field(static=True)
    min_fraction: float = eqx.field(static=True, default=0.1)
    max_spread: float = eqx.field(static=True, default=0.5)

    def match(self, features: Features) -> Match | None:
        coherence = features.coherence
        if coherence is None:
            return None
        wanted = {frozenset(p) for p in self.pairs}
        matches = []
        for pair in coherence.pairs:
            if frozenset(pair.pair) not in wanted or not pair.significant.any():
                continue
            fraction = _unshared_fraction(features.residuals.regions, coherence.freqs, pair)
            checks = (
                Check(
                    "broadband coherence excess",
                    fraction >= self.min_fraction,
                    f"{100 * fraction:.0f} % of the bins no shared feature explains",
                ),
                Check(
                    "frequency-independent leak",
                    pair.leak_spread <= self.max_spread,
                    f"relative spread {pair.leak_spread:.2f}",
                ),
            )
            matches.append(
                Match(
                    feature=f"coherence {pair.pair[0]}-{pair.pair[1]}, max Z = {pair.z.max():.1f}",
                    checks=checks,
                    parameters={
                        "fraction": pair.leak,
                        "fraction_sd": pair.leak_sd,
                        "receiver": pair.receiver,
                        "source": pair.source,
                    },
                    strength=float(pair.z.max()),
                )
            )
        return _best(matches)


class RestLine(AbstractSignature):
    """Interference at fixed frequencies: a line present while the system is at rest.

    Checks on each line at rest before the motion that the simulated rest lacks: it lies
    within ``tolerance_hz`` of a listed fundamental or one of its first ``harmonics``
    multiples; it is also at rest after the motion (not decidable where a line the simulated
    ring-down also has lies there, or where the PSD after the motion is within
    ``CONSTANT_AMPLITUDE_DB`` of the line's without a line standing out); where the motion
    spectra show an excess region at the same frequency, its power there and at rest agree within
    ``CONSTANT_AMPLITUDE_DB`` (constant amplitude; not decidable when the line is hidden under
    the motion's vibration). Parameters: ``frequency_hz`` (the
    matched fundamental), ``harmonic``, ``line_frequency_hz`` (measured, from the finer motion
    spectrum where available).
    """

    fundamentals: tuple[float, ...] = eqx.field(static=True)
    harmonics: int = eqx.field(static=True, default=3)
    tolerance_hz: float = eqx.field(static=True, default=1.0)

    def __check_init__(self):
        if not self.fundamentals or any(f <= 0 for f in self.fundamentals):
            raise ValueError(f"fundamentals must be positive frequencies, got {self.fundamentals}")
        if self.harmonics < 1:
            raise ValueError(f"harmonics must be at least 1, got {self.harmonics}")

    def match(self, features: Features) -> Match | None:
        rest = features.rest_before or features.rest_after
        if rest is None:
            return None
        res = features.residuals
        tol = _rest_tolerance(features)
        matches = []
        for line in rest.unexplained():
            f = line.frequency_hz
            options = [
                (abs(f - m * f0), f0, m)
                for f0 in self.fundamentals
                for m in range(1, self.harmonics + 1)
            ]
            error, f0, m = min(options)
            after = None
            if features.rest_after is not None and features.rest_before is not None:
                after = bool(features.rest_after.near(f, tol))
                line_psd, _ = features.rest_before.at(line.channel, f)
                psd_after, _ = features.rest_after.at(line.channel, f)
                masked = features.rest_after.near(f, tol, explained=True) or (
                    psd_after * 10.0 ** (CONSTANT_AMPLITUDE_DB / 10.0) >= line_psd
                )
                if not after and masked:
                    after = None
            motion = [
                r
                for r in res.regions
                if r.domain == FREQUENCY
                and r.sign > 0
                and r.speed.preferred != TRACKING
                and r.channel == line.channel
                and abs(r.frequency_hz - f) <= tol
            ]
            constant = None
            line_f = f
            if motion:
                region = max(motion, key=lambda r: r.z)
                line_f = region.frequency_hz
                affected = region.runs.affected
                power = float(np.mean(region.runs.power[affected])) if affected.any() else 0.0
                if power > 0 and line.power > 0:
                    ratio_db = 10.0 * np.log10(line.power / power)
                    constant = bool(abs(ratio_db) <= CONSTANT_AMPLITUDE_DB)
            checks = (
                Check(
                    "at a listed frequency or harmonic",
                    error <= self.tolerance_hz,
                    f"{f:.2f} Hz vs {m} x {f0:g} Hz",
                ),
                Check("also at rest after the motion", after),
                Check(
                    "same power at rest and in motion",
                    constant,
                    "" if motion else "not visible above the motion's vibration",
                ),
            )
            matches.append(
                Match(
                    feature=f"line at rest {line.channel} {f:.2f} Hz, {line.level_db:.1f} dB",
                    checks=checks,
                    parameters={
                        "frequency_hz": float(f0),
                        "harmonic": int(m),
                        "line_frequency_hz": float(line_f),
                    },
                    strength=line.z,
                )
            )
        return _best(matches)


class ListedFrequency(AbstractSignature):
    """A line at a listed fixed frequency, seen while the system runs (no rest needed).

    For a machine that never stops during a record (a motor's supply lines): each excess
    region of the frequency map is matched to the nearest harmonic ``m f0`` of the
    ``fundamentals`` (m = 1..``harmonics``). Checks: its peak lies within ``tolerance_hz`` of
    one; the frequency does not move with the speed (as :class:`FixedFrequency`'s check:
    it fails where the speeds cannot decide, so the two tie); it is in most runs; and, with
    ``excluded`` periods (spatial periods of another cause, in the units of the runs'
    speeds over Hz), no affected run's speed puts one of them within ``tolerance_hz`` of
    the peak (n/a without the runs' speeds): a line that lies on another cause's tone at
    every run's speed cannot be told from it. Parameters: ``frequency_hz`` (the matched
    fundamental), ``harmonic``, ``line_frequency_hz`` (the region's peak) and ``harmonics_found``
    (every harmonic of that fundamental with a matching region).
    """

    fundamentals: tuple[float, ...] = eqx.field(static=True)
    harmonics: int = eqx.field(static=True, default=3)
    tolerance_hz: float = eqx.field(static=True, default=1.0)
    excluded: tuple[float, ...] = eqx.field(static=True, default=())

    def __check_init__(self):
        if not self.fundamentals or any(f <= 0 for f in self.fundamentals):
            raise ValueError(f"fundamentals must be positive frequencies, got {self.fundamentals}")
        if self.harmonics < 1:
            raise ValueError(f"harmonics must be at least 1, got {self.harmonics}")
        if not self.tolerance_hz > 0 or any(w <= 0 for w in self.excluded):
            raise ValueError("tolerance_hz and the excluded periods must be positive")

    def _nearest(self, f: float) -> tuple[float, float, int]:
        return min(
            (abs(f - m * f0), f0, m)
            for f0 in self.fundamentals
            for m in range(1, self.harmonics + 1)
        )

    def match(self, features: Features) -> Match | None:
        res = features.residuals
        regions = [r for r in res.regions if r.domain == FREQUENCY and r.sign > 0]
        tol = max(self.tolerance_hz, res.resolution_hz)
        matches = []
        for region in regions:
            f = float(region.frequency_hz)
            error, f0, m = self._nearest(f)
            found = sorted(
                {
                    mm
                    for r in regions
                    for err, ff, mm in [self._nearest(float(r.frequency_hz))]
                    if err <= tol and ff == f0
                }
            )
            checks = [
                Check("at a listed frequency", error <= tol, f"{f:.2f} Hz vs {m} x {f0:g} Hz"),
                _speed_check(features, region, FIXED),
                _in_most_runs(region, features.n_runs),
            ]
            if self.excluded:
                speeds = res.speeds
                if speeds is None:
                    checks.append(Check("not another cause's tone", None, "no speeds"))
                else:
                    runs = region.runs.affected if region.runs.affected.any() else slice(None)
                    tones = np.asarray(speeds)[runs][:, None] / np.asarray(self.excluded)[None]
                    close = float(np.min(np.abs(tones - f)))
                    checks.append(
                        Check(
                            "not another cause's tone",
                            close > tol,
                            f"nearest excluded tone {close:.2f} Hz away",
                        )
                    )
            matches.append(
                Match(
                    feature=region.describe(),
                    checks=tuple(checks),
                    parameters={
                        "frequency_hz": float(f0),
                        "harmonic": int(m),
                        "line_frequency_hz": f,
                        "harmonics_found": tuple(found),
                    },
                    strength=abs(region.z),
                )
            )
        return _best(matches)


class NoResidual(AbstractSignature):
    """The model explains the data: no significant region, coherence excess or rest line."""

    def match(self, features: Features) -> Match | None:
        summary = features.summary()
        return Match(
            feature="no significant residual" if not summary else f"{len(summary)} features",
            checks=(Check("no significant residual", not summary, "; ".join(summary[:3])),),
            parameters={},
            strength=0.0,
        )
