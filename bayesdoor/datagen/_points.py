"""Operating points of runs: one value per run for one condition, a row per run for several.

A system with one operating condition (the door's ``v_max``) takes ``operating`` of shape
``(run,)``; one with several (the bearing's shaft speed and load) ``(run, condition)``. The
helpers here group and match runs by their whole point (a row), never by one column, and
leave the one-condition arrays as they were.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np


def as_points(values) -> np.ndarray:
    """Operating points as floats: ``(run,)`` for one condition, ``(run, condition)`` for
    several (a single row ``(condition,)`` of several conditions is not told apart from runs
    of one condition, so pass rows as a 2-D array)."""
    points = np.asarray(values, dtype=float)
    if points.ndim == 0:
        return points.reshape(1)
    if points.ndim > 2:
        raise ValueError(
            f"operating points must be (run,) or (run, condition), got shape {points.shape}"
        )
    return points


def at_point(points: np.ndarray, point) -> np.ndarray:
    """Which of ``points`` (``(run,)`` or ``(run, condition)``) equal ``point`` (relative
    tolerance 1e-9 on every condition)."""
    points = np.asarray(points, dtype=float)
    same = np.isclose(points, np.asarray(point, dtype=float), rtol=1e-9, atol=0.0)
    return same if points.ndim == 1 else np.all(same, axis=-1)


def unique_points(points: np.ndarray) -> np.ndarray:
    """The distinct points, sorted (rows for several conditions)."""
    points = np.asarray(points, dtype=float)
    return np.unique(points) if points.ndim == 1 else np.unique(points, axis=0)


def point_key(point) -> float | tuple[float, ...]:
    """A hashable point: the number for one condition, the tuple of its values for several,
    rounded to 9 decimals so that a value read back from JSON meets the array's."""
    value = np.asarray(point, dtype=float)
    if value.ndim == 0:
        return round(float(value), 9)
    return tuple(round(float(v), 9) for v in value.ravel())


def point_list(points: Iterable) -> list:
    """The points as JSON-able values, sorted: numbers or lists of numbers."""
    return [list(p) if isinstance(p, tuple) else p for p in sorted({point_key(p) for p in points})]


def measured_points(values, like: np.ndarray) -> np.ndarray:
    """Measured runs' points shaped like the simulated ``like``: ``(run,)`` for one condition
    (any shape flattened), ``(run, condition)`` with ``like``'s columns for several."""
    if np.ndim(like) == 1:
        return np.asarray(values, dtype=float).reshape(-1)
    return as_points(values).reshape(-1, np.shape(like)[1])


def show_point(point) -> float | list[float]:
    """A point for a message: the number, or the list of its conditions."""
    value = np.asarray(point, dtype=float)
    return float(value) if value.ndim == 0 else value.tolist()
