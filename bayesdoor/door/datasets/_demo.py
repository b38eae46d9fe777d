"""The embedded demo campaign: recorded by the virtual rig on first use, then cached.

10 healthy calibration runs and 300 test runs (100 healthy, 100 D1, 100 D2) at commanded
speeds 0.3, 0.4 and 0.5 m/s, D1 and D2 severities drawn from their priors, all from fixed seeds.
The file name carries a hash of the generator (the rig's and this module's source, the sizes,
the seed and the JAX version), so a changed generator never serves a stale file.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import uuid
from pathlib import Path

import jax
import numpy as np
import xarray as xr

from ...io import load_campaign, save_campaign
from ..rig import RigConfig, VirtualRig

#: bump when the campaign's plan changes in a way the source hash would not show
DEMO_VERSION = 1
DEMO_SEED = 20_240_611
SPEEDS = (0.3, 0.4, 0.5)
#: record length (s): 0.25 s rest, the slowest stroke (3.14 s at 0.3 m/s, 3.19 s at 3 sigma of
#: the rig's speed scatter) and at least 0.26 s of rest; fixed, so one compilation serves any size
DURATION_S = 3.7
_SOURCES = (
    # the rig's code, less the other-door family, which the demo does not use
    *sorted(
        p for p in (Path(__file__).parent.parent / "rig").glob("*.py") if p.name != "_family.py"
    ),
    Path(__file__),
)


def cache_dir() -> Path:
    """Where the demo campaign is cached: ``$BAYESDOOR_DATA`` or ``~/.cache/bayesdoor``."""
    env = os.environ.get("BAYESDOOR_DATA")
    return Path(env) if env else Path.home() / ".cache" / "bayesdoor"


def _plan(calibration_runs: int, test_runs_per_state: int):
    """States, commanded speeds and splits of every run, from the fixed seed."""
    if calibration_runs < 1 or test_runs_per_state < 1:
        raise ValueError(
            f"need calibration_runs >= 1 and test_runs_per_state >= 1, got "
            f"{calibration_runs} and {test_runs_per_state}"
        )
    rng = np.random.default_rng(DEMO_SEED)
    test_states = np.repeat(["healthy", "D1", "D2"], test_runs_per_state)
    test_states = test_states[rng.permutation(test_states.size)]
    states = ["healthy"] * calibration_runs + [str(s) for s in test_states]
    # speeds cycle through the three values within each group, in a shuffled order
    speeds = np.resize(np.asarray(SPEEDS), len(states))
    speeds = speeds[rng.permutation(speeds.size)]
    split = ["calibration"] * calibration_runs + ["test"] * test_states.size
    return states, speeds, split


def _digest(calibration_runs: int, test_runs_per_state: int) -> str:
    h = hashlib.sha256()
    for path in _SOURCES:
        h.update(path.read_bytes())
    h.update(
        json.dumps(
            [DEMO_VERSION, DEMO_SEED, calibration_runs, test_runs_per_state, jax.__version__]
        ).encode()
    )
    return h.hexdigest()[:12]


def demo_paths(calibration_runs: int = 10, test_runs_per_state: int = 100) -> tuple[Path, Path]:
    """The cache files (campaign, truth) of a demo campaign of this size."""
    stem = f"demo-campaign-v{DEMO_VERSION}-{_digest(calibration_runs, test_runs_per_state)}"
    if (calibration_runs, test_runs_per_state) != (10, 100):
        stem += f"-c{calibration_runs}-t{test_runs_per_state}"
    return cache_dir() / f"{stem}.nc", cache_dir() / f"{stem}.truth.json"


def _generate(calibration_runs: int, test_runs_per_state: int, show_progress: bool) -> None:
    """Record the campaign with the rig and write both files atomically."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    nc_path, truth_path = demo_paths(calibration_runs, test_runs_per_state)
    states, speeds, split = _plan(calibration_runs, test_runs_per_state)
    with Progress(
        TextColumn("recording the demo campaign with the virtual rig"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total} runs"),
        TimeElapsedColumn(),
        disable=not show_progress,
        transient=True,
    ) as bar:
        task = bar.add_task("demo", total=len(states))
        # four chunks: two rounds of the rig's two worker threads
        config = RigConfig(chunk_size=math.ceil(len(states) / 4))
        recording = VirtualRig(config=config).run(
            states,
            speeds,
            key=jax.random.key(DEMO_SEED),
            split=split,
            duration=DURATION_S,
            progress=lambda done: bar.update(task, completed=done),
        )
    truth_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = truth_path.with_name(f".{truth_path.name}.{uuid.uuid4().hex}.tmp")
    try:
        tmp.write_text(json.dumps(recording.truth, indent=1))
        os.replace(tmp, truth_path)
    finally:
        tmp.unlink(missing_ok=True)
    save_campaign(recording.campaign, nc_path, overwrite=True)


def _ensure(calibration_runs: int, test_runs_per_state: int, show_progress: bool):
    nc_path, truth_path = demo_paths(calibration_runs, test_runs_per_state)
    if not (nc_path.is_file() and truth_path.is_file()):
        _generate(calibration_runs, test_runs_per_state, show_progress)
    return nc_path, truth_path


def load_demo_campaign(
    split: str | None = None,
    *,
    calibration_runs: int = 10,
    test_runs_per_state: int = 100,
    show_progress: bool = True,
) -> xr.Dataset:
    """The demo campaign recorded by the virtual rig (generated on first use, then cached).

    The first call records it (a few minutes on a 2-core CPU, with a progress bar) and caches
    it in :func:`cache_dir`; later calls read the file.

    Parameters
    ----------
    split
        ``"calibration"`` or ``"test"`` for those runs only; ``None`` for all.
    calibration_runs, test_runs_per_state
        Campaign size (defaults: 10 healthy calibration runs; 100 test runs per state).
        Other sizes, for tests, are separate cache files.
    show_progress
        Show a progress bar while recording.

    Returns
    -------
    campaign
        The campaign (``docs/data.md``) with ``split``, ``t_start`` and ``t_stop``.
        The rig's true parameters are not in it: see :func:`load_demo_truth`.

    Raises
    ------
    ValueError
        For an unknown ``split`` or a non-positive size.

    Examples
    --------
    >>> test = load_demo_campaign("test")  # doctest: +SKIP
    >>> test.sizes["run"]  # doctest: +SKIP
    300
    """
    if split not in (None, "calibration", "test"):
        raise ValueError(f"split={split!r}: use 'calibration', 'test' or None for all runs")
    nc_path, _ = _ensure(calibration_runs, test_runs_per_state, show_progress)
    campaign = load_campaign(nc_path)
    if split is not None:
        campaign = campaign.isel(run=np.flatnonzero(campaign["split"].values == split))
    return campaign


def load_demo_truth(
    *, calibration_runs: int = 10, test_runs_per_state: int = 100, show_progress: bool = True
) -> dict:
    """What the rig really did for the demo campaign: for tests and reports, never for fitting.

    Returns
    -------
    truth
        ``parameters`` (the rig's true Table 2 values, its contact law and bending mode),
        ``effects``, ``config`` and ``runs`` (per run, in the campaign's order: the scattered
        parameters, the actual speed ``v_actual`` and the damage severities).
    """
    _, truth_path = _ensure(calibration_runs, test_runs_per_state, show_progress)
    return json.loads(truth_path.read_text())


class _DoorDemo:
    """The door's demo campaign for ``bayesdoor demo`` (a
    :class:`bayesdoor.systems.DemoCampaign`)."""

    def cached_path(self) -> Path:
        return demo_paths()[0]

    def load(self, *, show_progress: bool) -> xr.Dataset:
        return load_demo_campaign(show_progress=show_progress)


#: the demo campaign that the ``bayesdoor.demos`` entry point names
DEMO = _DoorDemo()
