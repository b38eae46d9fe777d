"""The bearing's catalogue of discrepancy causes (docs/bearing.md, "Diagnosis"), as data.

Each candidate has a signature (how it shows in the residual features, the generic ones of
:mod:`bayesdoor.diagnose`) and a refit recipe (which model extension of
``_extensions.py`` to fit, started from the signature's estimate). The diagnosis sees each
run's speed as its shaft frequency in revolutions per second (:func:`shaft_rev_per_s`),
so a shaft-synchronous line at k x 1X has the "wavelength" 1 / k revolution.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ..diagnose import (
    AbstractRefit,
    Candidate,
    Catalogue,
    ExtensionProposal,
    FixedFrequency,
    ListedFrequency,
    NoResidual,
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
#: "wavelengths" of the shaft lines in revolutions (speed in rev/s over frequency in Hz)
SHAFT_PERIODS = tuple(1.0 / k for k in SHAFT_HARMONICS)
#: a tone within this relative distance of k x 1X is that harmonic: less than half the
#: 1 / (2 K) = 5 % between the 10th and 11th, and more than a 1 Hz bin at 1X (30 Hz)
SHAFT_MATCH = 0.04
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


class ShaftRefit(AbstractRefit):
    """Lines at the shaft harmonics the residual shows: each found harmonic's amplitude free.

    The amplitudes act linearly on the signal (``linear``): one simulation per harmonic.
    Nothing is proposed when no tone lies at a shaft harmonic.
    """

    def propose(
        self, parameters: Mapping[str, Any], *, band: tuple[float, float]
    ) -> tuple[ExtensionProposal, ...]:
        found = [int(k) for k in parameters.get("labels_found", ())]
        if "label" in parameters and int(parameters["label"]) not in found:
            found.append(int(parameters["label"]))
        if not found:
            return ()
        start = {f"shaft_harmonics.amplitude_{k}": 0.05 for k in sorted(found)}
        return (
            ExtensionProposal(
                extension=ShaftHarmonics(harmonics=max(found)),
                start=start,
                free=tuple(start),
                key=tuple(start),
                linear=tuple(start),
                label=f"shaft lines at {', '.join(f'{k}x' for k in sorted(found))}",
            ),
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
            signature=SpeedTracking(
                wavelengths=SHAFT_PERIODS, labels=SHAFT_HARMONICS, rel_tol=SHAFT_MATCH
            ),
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
