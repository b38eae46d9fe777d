"""Posterior-predictive bands of the classifier's features, per state and operating speed."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..io import atomic_write

#: the quantiles kept: a 90 % band and the median
QUANTILES = (0.05, 0.5, 0.95)


@dataclasses.dataclass(frozen=True)
class PredictiveBands:
    """Quantiles of the simulated training features of every state at every speed.

    Attributes
    ----------
    states
        The simulated states.
    speeds
        The operating points the training runs were drawn at: ``(speed,)`` for one operating
        condition, ``(speed, condition)`` (one row per point) for several.
    values
        Quantiles :data:`QUANTILES` of the features, ``(state, speed, quantile, channel,
        freq)``; NaN where a state has no run at a speed.
    channels
        Channel names.
    frequencies
        Frequency of each feature bin (Hz).
    """

    states: tuple[str, ...]
    speeds: np.ndarray
    values: np.ndarray
    channels: tuple[str, ...]
    frequencies: np.ndarray

    @classmethod
    def from_training_data(cls, data) -> PredictiveBands:
        """The bands of a :class:`bayesdoor.datagen.TrainingData` (all its runs)."""
        speeds = np.unique(data.speeds, axis=0)
        shape = (len(data.states), len(speeds), len(QUANTILES), *data.features.shape[1:])
        values = np.full(shape, np.nan)
        for i in range(len(data.states)):
            for j, v in enumerate(speeds):
                same = data.speeds == v
                # a point of several operating conditions is a row: every condition matches
                at = same if same.ndim == 1 else np.all(same, axis=-1)
                rows = data.features[(data.labels == i) & at]
                if len(rows):
                    values[i, j] = np.quantile(rows, QUANTILES, axis=0)
        return cls(
            tuple(data.states),
            speeds,
            values,
            tuple(data.channels),
            np.asarray(data.frequencies, dtype=float),
        )

    def nearest(self, speed) -> int:
        """Index of the band speed closest to ``speed`` (a number, or a row of the operating
        conditions: the smallest sum of absolute differences)."""
        if self.speeds.ndim == 1:
            return int(np.argmin(np.abs(self.speeds - float(speed))))
        distance = np.abs(self.speeds - np.asarray(speed, dtype=float)).sum(axis=-1)
        return int(np.argmin(distance))

    def save(self, path: Path) -> None:
        """Write the bands to one ``.npz`` file, atomically."""

        def write(tmp: Path) -> None:
            with open(tmp, "wb") as f:
                np.savez(
                    f,
                    states=np.asarray(self.states),
                    speeds=self.speeds,
                    values=self.values,
                    channels=np.asarray(self.channels),
                    frequencies=self.frequencies,
                )

        atomic_write(path, write, overwrite=True)

    @classmethod
    def load(cls, path: Path) -> PredictiveBands:
        """Read what :meth:`save` wrote."""
        with np.load(path, allow_pickle=False) as f:
            return cls(
                tuple(str(s) for s in f["states"]),
                f["speeds"],
                f["values"],
                tuple(str(c) for c in f["channels"]),
                f["frequencies"],
            )
