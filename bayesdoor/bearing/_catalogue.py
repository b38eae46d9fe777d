"""The bearing's catalogue of discrepancy causes (docs/bearing.md, "Diagnosis"), as data.

Each candidate has a signature (how it shows in the residual features, the generic ones of
:mod:`bayesdoor.diagnose`) and a refit recipe (which model extension of
``_extensions.py`` to fit, started from the signature's estimate). The diagnosis sees each
run's speed as its shaft frequency in revolutions per second (:func:`shaft_rev_per_s`),
so a shaft-synchronous line at k x 1X has the period 1 / k revolution.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import equinox as eqx
import numpy as np

from ..diagnose import (
    AbstractRefit,
    Candidate,
    Catalogue,
    CauseSize,
    Check,
    ExtensionProposal,
    Features,
    FixedFrequency,
    ListedFrequency,
    Match,
    NoResidual,
    Region,
    SizeProbe,
    SpeedTracking,
)
from ._extensions import (
    MAX_SHAFT_HARMONICS,
    MODE_BAND_HZ,
    SUPPLY_FREQUENCIES_HZ,
    LineFrequency,
    ShaftHarmonics,
    StructuralMode,
)

#: shaft harmonics k = 1..10 attributed to the shaft (unbalance 1x, misalignment 2x-3x,
#: looseness a series to about 10x); above, the lines of a 1600-1900 rpm shaft reach the
#: bearing's own fault orders' harmonics (BPFO 3.58x, BPFI 5.42x) beyond their third
SHAFT_HARMONICS = tuple(range(1, MAX_SHAFT_HARMONICS + 1))
#: periods of the shaft lines in revolutions (speed in rev/s over frequency in Hz)
SHAFT_PERIODS = tuple(1.0 / k for k in SHAFT_HARMONICS)
#: a line within this many Hz of k x 1X is that harmonic: two 1 Hz bins (1 s records; a
#: line's peak refined between bins lies within one of its frequency, and the record's
#: stated rpm within 1 rpm, 0.17 Hz at 10x, of the shaft's)
SHAFT_TOLERANCE_HZ = 2.0
#: supply harmonics m = 1..6 attributed to the supply: the line and the stator field's pull
#: at 2 f0, and the force harmonics of a three-phase supply's 3rd and 5th voltage
#: harmonics up to 6 f0
SUPPLY_HARMONICS = 6
#: a line within one 1 Hz bin (1 s records) of m f0 is at the supply frequency (grids hold f0
#: within 0.1 Hz)
SUPPLY_TOLERANCE_HZ = 1.0
#: the diagnosis's analysed band, Hz: from the lowest shaft line (1x at 1600 rpm is 26.7 Hz)
#: to the top of the fit's band (the recorder's anti-alias filter above)
DIAGNOSIS_BAND_HZ = (10.0, 5375.0)
#: search box of a mode's frequency around the signature's, Hz (a few 1 Hz bins either side,
#: widened to the feature's own significant bins)
_MODE_BOX_HZ = 5.0


def shaft_rev_per_s(operating: np.ndarray) -> np.ndarray:
    """Each run's shaft frequency (rev/s) from its operating point (rpm, hp)."""
    op = np.atleast_2d(np.asarray(operating, dtype=float))
    return op[:, 0] / 60.0


def _peaks(region: Region, speeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The peak frequency (Hz) and the shaft frequency (rev/s) of each affected run (of
    every searched run when none is affected)."""
    f = region.runs.frequency_hz
    use = region.runs.affected if region.runs.affected.any() else np.isfinite(f)
    return f[use], speeds[use]


class ShaftLines(SpeedTracking):
    """Shaft-synchronous lines: residual regions at k x the runs' shaft frequency, k in
    ``labels``, in excess or in deficit.

    The generic :class:`~bayesdoor.diagnose.SpeedTracking` examines excess only; the base
    model has shaft lines of its own (1x-3x at fixed ratios, their amplitude a parameter that
    the fit's 1.5-5.4 kHz band does not see), which the measurement can show weaker: a
    deficit at a shaft harmonic is the same cause, its extension's amplitude negative. Each
    region of either sign, in either map, is matched by its peak in the affected runs: the
    nearest harmonic k of each run's shaft frequency, within ``tolerance_hz`` in every run.
    Checks: at a shaft harmonic; the frequency follows the speed (as SpeedTracking's check:
    it fails where the speeds cannot decide, so a fixed line at the same frequency ties);
    in most runs. Parameters: ``label`` (k), ``labels_found`` (every k with a matching
    region, either sign), ``deficits`` (the k found in deficit only), ``period``
    (1 / k revolution).
    """

    tolerance_hz: float = eqx.field(static=True, default=SHAFT_TOLERANCE_HZ)

    def _harmonic(self, region: Region, speeds: np.ndarray) -> tuple[int, float]:
        """The nearest listed harmonic of the region's peaks and the largest distance (Hz)
        of a run's peak from it; ``(0, inf)`` without peaks."""
        f, v = _peaks(region, speeds)
        if not f.size or not np.all(np.isfinite(f)):
            return 0, float("inf")
        ks = np.asarray(self.labels, dtype=int)
        k = int(ks[np.argmin(np.abs(np.median(f / v) - ks))])
        return k, float(np.max(np.abs(f - k * v)))

    def match(self, features: Features) -> Match | None:
        res = features.residuals
        if res.speeds is None:
            return None
        speeds = np.asarray(res.speeds, dtype=float)
        matched = [(r, *self._harmonic(r, speeds)) for r in res.regions]
        at = [(r, k) for r, k, off in matched if k and off <= self.tolerance_hz]
        found = sorted({k for _, k in at})
        excess = {k for r, k in at if r.sign > 0}
        deficits = tuple(k for k in found if k not in excess)
        out = []
        for region, k, off in matched:
            checks = (
                Check(
                    "at a shaft harmonic",
                    bool(k) and off <= self.tolerance_hz,
                    f"{k} x 1X, {off:.2f} Hz off in the worst run" if k else "no peak",
                ),
                Check(
                    "frequency follows the speed",
                    region.speed.preferred == "tracking",
                    f"across runs: {region.speed.preferred}",
                ),
                Check(
                    "in most runs",
                    2 * region.runs_present >= features.n_runs,
                    f"{region.runs_present} of {features.n_runs}",
                ),
            )
            out.append(
                Match(
                    feature=region.describe(),
                    checks=checks,
                    parameters={
                        "label": k,
                        "labels_found": tuple(found),
                        "deficits": deficits,
                        "period": 1.0 / k if k else float("nan"),
                    },
                    strength=abs(region.z),
                )
            )
        return max(out, key=lambda m: (m.score, m.strength), default=None)


class ShaftRefit(AbstractRefit):
    """Lines at the shaft harmonics the residual shows: each found harmonic's amplitude free.

    The amplitudes act linearly on the signal (``linear``): one simulation per harmonic. A
    harmonic in deficit takes from the base model's own line (started negative); one in
    excess adds a line (above the base model's 3x its sign is its phase, which the spectra
    do not see: searched from 0). When the residual shows both, the lines in deficit alone,
    those in excess alone and all together are proposed, and the refit keeps the one that
    fits the training runs best: each harmonic is a free parameter, and a search over many at
    once within the refit's budget is poorer than over the few of one kind. Nothing is
    proposed when no line lies at a shaft harmonic.
    """

    def _proposal(self, harmonics: list[int], deficits: set[int]) -> ExtensionProposal:
        start = {
            f"shaft_harmonics.amplitude_{k}": -0.05 if k in deficits else 0.05 for k in harmonics
        }
        bounds = {f"shaft_harmonics.amplitude_{k}": (0.0, 2.0) for k in harmonics if k > 3}
        kind = (
            "in deficit"
            if set(harmonics) <= deficits
            else "in excess"
            if not set(harmonics) & deficits
            else "all"
        )
        return ExtensionProposal(
            extension=ShaftHarmonics(harmonics=max(harmonics)),
            start=start,
            free=tuple(start),
            bounds=bounds,
            key=tuple(start),
            linear=tuple(start),
            label=f"shaft lines at {', '.join(f'{k}x' for k in harmonics)} ({kind})",
        )

    def propose(
        self, parameters: Mapping[str, Any], *, band: tuple[float, float]
    ) -> tuple[ExtensionProposal, ...]:
        found = sorted({int(k) for k in parameters.get("labels_found", ())} - {0})
        label = int(parameters.get("label", 0))
        if label >= 1 and label not in found:
            found = sorted([*found, label])
        if not found:
            return ()
        deficits = {int(k) for k in parameters.get("deficits", ())} & set(found)
        excess = [k for k in found if k not in deficits]
        groups = [sorted(deficits), excess, found] if deficits and excess else [found]
        return tuple(self._proposal(g, deficits) for g in groups)

    def size(self, *, band: tuple[float, float]) -> CauseSize:
        """A line's amplitude added to the base model's: typically at 1x (unbalance), also at
        2x (misalignment) and at 4x (a line the base model does not have)."""
        probes = tuple(
            SizeProbe(
                label=label,
                proposal=ExtensionProposal(
                    extension=ShaftHarmonics(harmonics=k),
                    start={},
                    free=(f"shaft_harmonics.amplitude_{k}",),
                ),
                scales={f"shaft_harmonics.amplitude_{k}": 1.0},
                reference=0.05,
            )
            for label, k in (("typical: 1x", 1), ("2x", 2), ("4x", 4))
        )
        return CauseSize(
            "shaft line amplitude", "m/s^2", 1e-4, 2.0, probes, display=("mm/s^2", 1e3)
        )


class ModeRefit(AbstractRefit):
    """A mode at the residual's frequency: frequency (within the feature), damping, gain.

    An output extension (:class:`StructuralMode`), refitted on the base signals.
    """

    def propose(
        self, parameters: Mapping[str, Any], *, band: tuple[float, float]
    ) -> tuple[ExtensionProposal, ...]:
        f = float(parameters["frequency_hz"])
        zeta = float(np.clip(parameters.get("damping_ratio", 0.01), 0.001, 0.1))
        lo, hi = f - _MODE_BOX_HZ, f + _MODE_BOX_HZ
        feature = parameters.get("band_hz")
        if feature is not None and len(feature) == 2 and np.all(np.isfinite(feature)):
            lo, hi = min(lo, float(feature[0])), max(hi, float(feature[1]))
        lo, hi = max(lo, MODE_BAND_HZ[0]), min(hi, MODE_BAND_HZ[1])
        if not lo < hi:
            return ()
        # the feature's excess gives the amplification, (1 + g)^2 = 10^(excess / 10); the
        # search reaches 4 times it: the refit's profiled discrepancy absorbs a level offset
        # near the feature, so a gain far above what the feature shows is not ruled out by
        # the training runs alone (a mode hidden at g = 10 was refitted at g = 213 unbounded)
        excess = float(parameters.get("excess_db", 10.0))
        implied = 10.0 ** (max(excess, 1.0) / 20.0)
        gain = float(np.clip(implied - 1.0, 0.1, 100.0))
        top = float(min(4.0 * implied, 300.0))
        start = {
            "structural_mode.frequency_hz": float(np.clip(f, lo, hi)),
            "structural_mode.damping_ratio": zeta,
            "structural_mode.gain": gain,
        }
        return (
            ExtensionProposal(
                extension=StructuralMode(),
                start=start,
                free=tuple(start),
                bounds={
                    "structural_mode.frequency_hz": (lo, hi),
                    "structural_mode.gain": (0.0, top),
                },
                key=("structural_mode.frequency_hz", "structural_mode.damping_ratio"),
                label=f"a mode near {f:.0f} Hz",
            ),
        )

    def size(self, *, band: tuple[float, float]) -> CauseSize:
        """The mode's gain (its peak amplification minus one), damping ratio 0.005:
        typically at 1 kHz, also at 3 kHz (the model's housing mode's region)."""
        probes = tuple(
            SizeProbe(
                label=label,
                proposal=ExtensionProposal(
                    extension=StructuralMode(),
                    start={
                        "structural_mode.frequency_hz": f,
                        "structural_mode.damping_ratio": 0.005,
                    },
                    free=("structural_mode.gain",),
                ),
                scales={"structural_mode.gain": 1.0},
                reference=3.0,
            )
            for label, f in (("typical: 1 kHz", 1000.0), ("3 kHz", 3000.0))
        )
        return CauseSize("structural mode gain", "-", 0.01, 300.0, probes)


class LineRefit(AbstractRefit):
    """Lines at the matched supply frequency's harmonics the residual shows, each free."""

    def propose(
        self, parameters: Mapping[str, Any], *, band: tuple[float, float]
    ) -> tuple[ExtensionProposal, ...]:
        f0 = float(parameters["frequency_hz"])
        found = {int(m) for m in parameters.get("harmonics_found", ())}
        found.add(int(parameters.get("harmonic", 1)))
        found = {m for m in found if band[0] <= m * f0 <= band[1]}
        if not found:
            return ()
        start = {f"line_frequency.amplitude_{m}": 0.05 for m in sorted(found)}
        return (
            ExtensionProposal(
                extension=LineFrequency(frequency_hz=f0, harmonics=max(SUPPLY_HARMONICS, *found)),
                start=start,
                free=tuple(start),
                key=tuple(start),
                label=f"{f0:g} Hz supply, harmonics {sorted(found)}",
            ),
        )

    def size(self, *, band: tuple[float, float]) -> CauseSize:
        """One line's amplitude: typically 60 Hz (the stand's supply), also 2 x 60 Hz (an
        induction motor's electrical vibration) and 50 Hz."""
        probes = tuple(
            SizeProbe(
                label=label,
                proposal=ExtensionProposal(
                    extension=LineFrequency(frequency_hz=f0, harmonics=m),
                    start={},
                    free=(f"line_frequency.amplitude_{m}",),
                ),
                scales={f"line_frequency.amplitude_{m}": 1.0},
                reference=0.01,
            )
            for label, f0, m in (
                ("typical: 60 Hz", 60.0, 1),
                ("120 Hz", 60.0, 2),
                ("50 Hz", 50.0, 1),
            )
        )
        return CauseSize(
            "supply line amplitude", "m/s^2", 1e-4, 2.0, probes, display=("mm/s^2", 1e3)
        )


BEARING_CATALOGUE = Catalogue(
    speed=shaft_rev_per_s,
    band=DIAGNOSIS_BAND_HZ,
    # the background and the noise are drawn per run: one simulation is one realisation
    random_realisations=True,
    candidates=(
        Candidate(
            name="shaft_harmonics",
            description="shaft-synchronous lines the model lacks (unbalance, misalignment, "
            "looseness): tones at k x the shaft frequency",
            signature=ShaftLines(periods=SHAFT_PERIODS, labels=SHAFT_HARMONICS, unit="rev"),
            refit=ShaftRefit(),
        ),
        Candidate(
            name="structural_mode",
            description="a structural resonance the model lacks",
            signature=FixedFrequency(band=MODE_BAND_HZ),
            refit=ModeRefit(),
        ),
        Candidate(
            name="line_frequency",
            description="an electrical line at the supply frequency or its harmonics, "
            "whatever the shaft speed",
            signature=ListedFrequency(
                fundamentals=SUPPLY_FREQUENCIES_HZ,
                harmonics=SUPPLY_HARMONICS,
                tolerance_hz=SUPPLY_TOLERANCE_HZ,
                excluded=SHAFT_PERIODS,
            ),
            refit=LineRefit(),
        ),
        Candidate(
            name="none",
            description="the model explains the data within its uncertainty",
            signature=NoResidual(),
        ),
    ),
)
