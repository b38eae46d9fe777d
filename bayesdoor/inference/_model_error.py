"""Moment estimates of the model error at a point, and the start values of its sampled sites."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax.numpy as jnp
import numpy as np
import xarray as xr

from .._types import Array, Float
from ._likelihood import CalibrationData, ModelError

#: smallest model-error scale (decades) used to start the sampler and for a CMA-ES point
_SIGMA_FLOOR = 0.01


def _point_error(
    residual: Float[np.ndarray, "run channel band"],
    data: CalibrationData,
    error: ModelError,
) -> tuple[np.ndarray, np.ndarray]:
    """The discrepancy scales and the run scatter the residuals at a point call for.

    Moment estimates. Shared: the run scatter (in Welch sds, per channel) from the spread of
    the runs about their operating point's mean (1 without replicate runs), the discrepancy
    (per operating point and channel, or per channel) from the operating points' mean
    residuals less the part of their variance the scatter explains. Independent: the excess
    of the mean squared residual over the Welch variance, scatter 1. The discrepancy scale is
    floored at ``_SIGMA_FLOOR``.
    """
    welch = np.asarray(data.welch_variance)
    index = np.asarray(data.run_operating)
    n_op = data.operating.shape[0]
    rho = np.ones(residual.shape[1])
    if not error.shared:
        excess = np.mean(residual**2, axis=(0, 2)) - np.mean(welch)
        return np.sqrt(np.maximum(excess, _SIGMA_FLOOR**2)), rho
    counts = np.bincount(index, minlength=n_op)
    means = _operating_means(residual, data)
    spread = residual - means[index]
    replicated = counts[index] > 1
    if replicated.any():
        dof = np.sum(1.0 - 1.0 / counts[index][replicated])
        ratio = (spread[replicated] ** 2 / welch[replicated, None, None]).sum(axis=(0, 2))
        rho = np.sqrt(np.maximum(ratio / (dof * residual.shape[2]), _SIGMA_FLOOR**2))
    scatter = rho[None, :] ** 2 * np.array([welch[index == o].mean() for o in range(n_op)])[:, None]
    excess = np.mean(means**2, axis=2) - scatter / counts[:, None]
    if not error.per_operating:
        excess = excess.mean(axis=0)
    return np.sqrt(np.maximum(excess, _SIGMA_FLOOR**2)), rho


def _operating_means(
    residual: Float[np.ndarray, "run channel band"], data: CalibrationData
) -> Float[np.ndarray, "op channel band"]:
    """The mean residual of the runs at each operating point."""
    index = np.asarray(data.run_operating)
    return np.stack([residual[index == o].mean(axis=0) for o in range(data.operating.shape[0])])


def _common_point(
    residual: Float[np.ndarray, "run channel band"], data: CalibrationData
) -> np.ndarray:
    """A start for the common discrepancy's scale per channel: the root mean square over the
    bands of the operating points' mean residuals averaged over the operating points (what
    every speed misses alike), floored at ``_SIGMA_FLOOR``."""
    means = _operating_means(residual, data)
    return np.maximum(np.sqrt(np.mean(means.mean(axis=0) ** 2, axis=-1)), _SIGMA_FLOOR)


def _sigma_site(error: ModelError) -> str:
    """The sampled site of the discrepancy scales."""
    return "sigma_operating" if error.shared and error.per_operating else "sigma_model"


@dataclasses.dataclass(frozen=True)
class _ErrorStart:
    """Start values of the model-error sites: the discrepancy scales, the run scatter, the
    correlation length and the common discrepancy's scales (``None`` without one)."""

    sigma: Array
    rho: Array
    length: float | None
    tau: Array | None

    @classmethod
    def at_point(
        cls,
        sigma_point: np.ndarray,
        scatter_point: np.ndarray,
        residual: np.ndarray,
        data: CalibrationData,
        error: ModelError,
    ) -> _ErrorStart:
        """The moment estimates at the CMA-ES optimum."""
        tau = jnp.asarray(_common_point(residual, data)) if error.common else None
        return cls(
            jnp.asarray(sigma_point), jnp.asarray(scatter_point), error.correlation_length(), tau
        )

    def moved(self, posterior: xr.Dataset, error: ModelError) -> _ErrorStart:
        """The posterior means of the sampled model-error sites (the others kept)."""

        def mean(name: str, trailing: int) -> Array:
            draws = np.asarray(posterior[name].values)
            return jnp.asarray(draws.reshape(-1, *draws.shape[2:][-trailing:]).mean(axis=0))

        sigma = np.asarray(posterior[_sigma_site(error)].values)
        return _ErrorStart(
            sigma=jnp.asarray(sigma.reshape(-1, *sigma.shape[2:]).mean(axis=0)),
            rho=mean("run_scatter", 1) if error.shared else self.rho,
            length=(
                float(np.mean(posterior["discrepancy_length"].values))
                if error.infer_correlation
                else self.length
            ),
            tau=mean("sigma_common", 1) if error.common else self.tau,
        )

    def values(self, error: ModelError) -> dict[str, Any]:
        """The start values by sampled site (the sampling coordinate ``z`` aside)."""
        init: dict[str, Any] = {_sigma_site(error): self.sigma}
        if error.shared:
            init["run_scatter"] = self.rho
        if error.infer_correlation:
            init["discrepancy_length"] = jnp.asarray(self.length)
        if self.tau is not None:
            init["sigma_common"] = self.tau
        return init
