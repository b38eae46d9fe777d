"""What a training-data generation makes: sizes, states, speeds, split, chunks, features."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Literal

import equinox as eqx
import numpy as np

from ..features import CNNInputSpec
from ..systems import AbstractSystem


def _points(speeds) -> tuple[float, ...] | tuple[tuple[float, ...], ...]:
    """Operating points as a tuple of numbers, or of rows for several conditions."""
    points = np.asarray(list(speeds), dtype=float)
    if points.ndim == 2:
        return tuple(tuple(float(v) for v in row) for row in points)
    return tuple(float(v) for v in points)


def _state_names(states) -> tuple[str, ...] | None:
    return None if states is None else tuple(str(s) for s in states)


def _optional_float(value) -> float | None:
    return None if value is None else float(value)


def _input_spec(spec: CNNInputSpec | None) -> CNNInputSpec:
    return CNNInputSpec() if spec is None else spec


class GenerationConfig(eqx.Module):
    """Sizes and settings of one training-data generation (the paper's by default).

    Parameters
    ----------
    speeds
        The operating points runs are drawn from (uniformly, with replacement), for example
        the campaign's ``v_max`` values: numbers for a system with one operating condition,
        rows (one value per condition, in the order of the system's ``conditions``) for a
        system with several.
    runs_per_state
        Simulated runs of every state (the paper: 600, so 1800 for three states).
    states
        The states to simulate, keys of the system's ``states``; ``None`` means all of them.
    validation_fraction
        Fraction of every state's runs held out for validation (the paper: 0.3); the split
        is stratified: exactly ``round(validation_fraction * runs_per_state)`` runs of each
        state.
    chunk_size
        Runs simulated (as one vmapped batch) and saved together; a chunk holds runs of one
        state. The last chunk of a state is padded to this size for the solve (one compiled
        shape), and the padding runs are discarded.
    duration
        Record length (s); ``None`` means the system's ``record_duration`` of all ``speeds``.
        The solve itself stops just after the latest motion stop
        (:meth:`simulated_duration`), which gives the same features.
    spec
        The classifier input (:class:`bayesdoor.features.CNNInputSpec`), computed over each
        run's motion window.
    on_failure
        What to do with a run whose solve fails: ``"redraw"`` its parameters, severities and
        speed with a key derived from the chunk's (deterministic, up to ``max_redraws``
        times, then drop it) or ``"drop"`` it at once. Dropped runs are reported, never kept.
    max_redraws
        Redraw rounds per chunk before a still-failing run is dropped.
    """

    # any sequence of operating points in, tuples of floats stored (``_points``)
    speeds: Sequence[float] | Sequence[Sequence[float]] | np.ndarray = eqx.field(
        static=True, converter=_points
    )
    runs_per_state: int = eqx.field(static=True, default=600, converter=int, kw_only=True)
    states: tuple[str, ...] | None = eqx.field(
        static=True, default=None, converter=_state_names, kw_only=True
    )
    validation_fraction: float = eqx.field(static=True, default=0.3, converter=float, kw_only=True)
    chunk_size: int = eqx.field(static=True, default=100, converter=int, kw_only=True)
    duration: float | None = eqx.field(
        static=True, default=None, converter=_optional_float, kw_only=True
    )
    spec: CNNInputSpec = eqx.field(static=True, default=None, converter=_input_spec, kw_only=True)
    on_failure: Literal["redraw", "drop"] = eqx.field(static=True, default="redraw", kw_only=True)
    max_redraws: int = eqx.field(static=True, default=5, converter=int, kw_only=True)

    def __check_init__(self):
        if not self.speeds:
            raise ValueError("speeds is empty: give the operating points to draw runs at")
        if self.runs_per_state < 1:
            raise ValueError(f"runs_per_state must be at least 1, got {self.runs_per_state}")
        if self.states is not None and (
            not self.states or len(set(self.states)) < len(self.states)
        ):
            raise ValueError(f"states must be distinct and not empty, got {self.states}")
        if not 0.0 <= self.validation_fraction < 1.0:
            raise ValueError(
                f"validation_fraction must lie in [0, 1), got {self.validation_fraction}"
            )
        if self.chunk_size < 1:
            raise ValueError(f"chunk_size must be at least 1, got {self.chunk_size}")
        if self.on_failure not in ("redraw", "drop"):
            raise ValueError(f"on_failure must be 'redraw' or 'drop', got {self.on_failure!r}")
        if self.max_redraws < 0:
            raise ValueError(f"max_redraws must be >= 0, got {self.max_redraws}")

    @property
    def chunks_per_state(self) -> int:
        return math.ceil(self.runs_per_state / self.chunk_size)

    @property
    def validation_per_state(self) -> int:
        return round(self.validation_fraction * self.runs_per_state)

    def record_duration(self, system: AbstractSystem) -> float:
        """The record length of every run (s): ``duration``, else the system's for ``speeds``."""
        if self.duration is not None:
            return self.duration
        return float(system.record_duration(np.asarray(self.speeds)))

    def simulated_duration(self, system: AbstractSystem) -> float:
        """The record length actually simulated (s): to just after the latest motion stop.

        The features use only the Welch segments that end at or before a run's ``t_stop``
        (:func:`bayesdoor.features.segment_weights`), and a simulated record is causal (a
        sample does not depend on later ones), so the solve stops two samples after the
        latest ``t_stop`` of ``speeds`` rather than at :meth:`record_duration`: the features
        are those of the whole record (the adaptive steps are the same up to the last one,
        which the end time clips). For the door at 0.3-0.5 m/s that drops the 0.25 s rest
        after the slowest stroke (3.39 of 3.64 s are simulated): 7 % less memory, about the
        same solver time (the rest takes few steps). Never longer than
        :meth:`record_duration`.
        """
        duration = self.record_duration(system)
        _, stop = system.motion_window(np.asarray(self.speeds), duration=duration)
        fs = float(system.sampling_rate_hz)
        # sample floor(t_stop fs) is the last one a segment can use (1e-6: as segment_weights)
        needed = math.floor(float(np.max(stop)) * fs + 1e-6) + 2
        return min(round(duration * fs), needed) / fs

    def to_dict(self) -> dict[str, Any]:
        """The settings as JSON-able values (for the manifest and the configuration hash)."""
        return {
            "speeds": [list(p) if isinstance(p, tuple) else p for p in self.speeds],
            "runs_per_state": self.runs_per_state,
            "states": None if self.states is None else list(self.states),
            "validation_fraction": self.validation_fraction,
            "chunk_size": self.chunk_size,
            "duration": self.duration,
            "spec": self.spec.to_dict(),
            "on_failure": self.on_failure,
            "max_redraws": self.max_redraws,
        }
