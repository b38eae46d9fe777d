"""The oscillator's catalogue of discrepancy causes, as data: one cause and ``none``.

The diagnosis looks over :data:`DIAGNOSIS_BAND_HZ`, wider than the fit's band.

``second_mode``: excess power at a frequency that does not move with the speed
(:class:`~bayesdoor.diagnose.FixedFrequency` in :data:`MODE_BAND_HZ`), confirmed by
refitting :class:`SecondMode` started from the excess's frequency, width and height.
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
    NoResidual,
)
from ._extensions import MODE_BAND_HZ

#: the diagnosis's band, Hz: the fit's (5-100 Hz, where the one-mode model is complete) and
#: above it up to the top of the band a second mode may lie in
DIAGNOSIS_BAND_HZ = (5.0, MODE_BAND_HZ[1])
#: the refit searches the mode's frequency this far either side of the excess's, Hz
MODE_BOX_HZ = 5.0


class SecondModeRefit(AbstractRefit):
    """A second mode at the excess: its frequency (within the feature), damping and gain."""

    def propose(
        self, parameters: Mapping[str, Any], *, band: tuple[float, float]
    ) -> tuple[ExtensionProposal, ...]:
        f = float(parameters["frequency_hz"])
        lo, hi = f - MODE_BOX_HZ, f + MODE_BOX_HZ
        feature = parameters.get("band_hz")
        if feature is not None and np.all(np.isfinite(feature)):
            lo, hi = min(lo, float(feature[0])), max(hi, float(feature[1]))
        lo, hi = max(lo, MODE_BAND_HZ[0], band[0]), min(hi, MODE_BAND_HZ[1], band[1])
        if not lo < hi:
            return ()
        # the excess's height gives the amplification: (1 + g)^2 = 10^(excess / 10)
        implied = 10.0 ** (max(float(parameters.get("excess_db", 10.0)), 1.0) / 20.0)
        start = {
            "second_mode.frequency_hz": float(np.clip(f, lo, hi)),
            "second_mode.damping_ratio": float(
                np.clip(parameters.get("damping_ratio", 0.02), 0.005, 0.1)
            ),
            "second_mode.gain": float(np.clip(implied - 1.0, 0.1, 50.0)),
        }
        return (
            ExtensionProposal(
                extension="second_mode",
                start=start,
                free=tuple(start),
                bounds={
                    "second_mode.frequency_hz": (lo, hi),
                    "second_mode.gain": (0.0, min(4.0 * implied, 100.0)),
                },
                key=("second_mode.frequency_hz", "second_mode.damping_ratio"),
                label=f"a second mode near {f:.0f} Hz",
            ),
        )


OSCILLATOR_CATALOGUE = Catalogue(
    band=DIAGNOSIS_BAND_HZ,
    candidates=(
        Candidate(
            name="second_mode",
            description="a second mode of the structure that the one-mode model lacks",
            signature=FixedFrequency(band=MODE_BAND_HZ),
            refit=SecondModeRefit(),
        ),
        Candidate(
            name="none",
            description="the model explains the data within its uncertainty",
            signature=NoResidual(),
        ),
    ),
)
