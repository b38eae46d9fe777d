"""The oscillator's demo campaign for ``bayesdoor demo --system oscillator``.

10 healthy calibration runs and 30 test runs of each state, recorded by the oscillator's rig
(:mod:`bayesdoor.oscillator._rig`: another simulator than the model's, with a second mode the
model lacks) from a fixed seed in a few seconds, then cached. The file name carries a hash of
the rig's source and the plan, so a changed rig never serves a stale file.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import xarray as xr

from ..io import load_campaign, save_campaign
from . import _rig

#: the demo's seed and sizes
DEMO_SEED = 7
CALIBRATION_RUNS = 10
TEST_RUNS_PER_STATE = 30


def demo_path() -> Path:
    """Where the demo campaign is cached: under ``$BAYESDOOR_DATA`` or ``~/.cache/bayesdoor``,
    named by a hash of the rig's source and the plan."""
    env = os.environ.get("BAYESDOOR_DATA")
    folder = Path(env) if env else Path.home() / ".cache" / "bayesdoor"
    plan = f"{DEMO_SEED} {CALIBRATION_RUNS} {TEST_RUNS_PER_STATE}".encode()
    digest = hashlib.sha256(Path(_rig.__file__).read_bytes() + plan).hexdigest()[:12]
    return folder / f"oscillator-demo-{digest}.nc"


def load_demo_campaign(*, show_progress: bool = True) -> xr.Dataset:
    """The demo campaign, recorded first when it is not cached."""
    path = demo_path()
    if not path.exists():
        if show_progress:
            print(f"recording the oscillator's demo campaign to {path} (a few seconds)")
        campaign = _rig.record_campaign(
            DEMO_SEED,
            calibration_runs=CALIBRATION_RUNS,
            test_runs_per_state=TEST_RUNS_PER_STATE,
        )
        path.parent.mkdir(parents=True, exist_ok=True)
        save_campaign(campaign, path)  # atomic: a concurrent reader sees no partial file
    return load_campaign(path)


class _OscillatorDemo:
    """The oscillator's demo campaign (a :class:`bayesdoor.systems.DemoCampaign`)."""

    def cached_path(self) -> Path:
        return demo_path()

    def load(self, *, show_progress: bool) -> xr.Dataset:
        return load_demo_campaign(show_progress=show_progress)


#: the demo campaign that the ``bayesdoor.demos`` entry point names
DEMO = _OscillatorDemo()
