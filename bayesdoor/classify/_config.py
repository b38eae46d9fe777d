"""Training settings of the ensemble."""

from __future__ import annotations

import dataclasses
from typing import Any


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """How the ensemble is trained (the paper's settings by default).

    Parameters
    ----------
    members
        Ensemble size; each member has its own initialisation and its own data shuffling.
    epochs
        Passes over the training data (no early stopping).
    batch_size
        Inputs per Adam step; the last batch of an epoch is smaller when the data do not divide
        evenly (every input is used once per epoch).
    learning_rate
        Adam step size.
    dtype
        Floating type of the weights and of the computation (``"float32"`` or ``"float64"``).

    Raises
    ------
    ValueError
        For a non-positive size or rate, or another dtype.
    """

    members: int = 10
    epochs: int = 80
    batch_size: int = 100
    learning_rate: float = 1e-3
    dtype: str = "float32"

    def __post_init__(self):
        for name in ("members", "epochs", "batch_size"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if not self.learning_rate > 0:
            raise ValueError(f"learning_rate must be positive, got {self.learning_rate!r}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"dtype must be 'float32' or 'float64', got {self.dtype!r}")

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dictionary, inverse of ``TrainConfig(**d)``."""
        return dataclasses.asdict(self)
