"""What the later stages need of a model-updating result, saved without the full posterior."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..io import atomic_write
from ._stages import Finished, StageRecord, stage_in


def _finite_or_none(value: Any) -> float | None:
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


@dataclasses.dataclass(frozen=True)
class FitSummary:
    """The point, the posterior draws and the model error of a fit, as plain arrays.

    Attributes
    ----------
    method
        How the fit was made (``"cmaes"``, ``"nuts"``, ``"emcee"``).
    point
        One value per system parameter (the posterior mean of a sampled fit, the CMA-ES
        optimum of a point fit; the held parameters, such as the door's contact-law index,
        included).
    optimum
        The CMA-ES optimum, one value per system parameter (the centre of the paper's
        Gaussian baseline).
    j
        The objective at ``point`` (``None`` when the fit does not report it).
    draws
        Posterior draws of the sampled parameters (empty for a point fit).
    sigma_model
        Posterior draws of the model-error scale, ``(sample, channel)`` in log10 decades, or
        ``None`` when the fit has no model-error posterior.
    diagnostics
        The sampling diagnostics as JSON (max R-hat, min bulk ESS, divergences, ...), ``None``
        for a point fit.
    """

    method: str
    point: dict[str, float]
    optimum: dict[str, float]
    j: float | None
    draws: dict[str, np.ndarray]
    sigma_model: np.ndarray | None
    diagnostics: dict[str, Any] | None = None

    @classmethod
    def from_result(cls, result: Any, method: str) -> FitSummary:
        """Take the summary from a :class:`bayesdoor.inference.FitResult`.

        Uses its ``point``, ``j``, ``names`` with ``cmaes.x_best`` (the optimum of the
        continuous parameters, in that order), ``posterior_draws()`` and
        ``model_error_draws()``. A fit with a single draw (a CMA-ES point) keeps no draws and
        no model error: they are estimates at a point, not posteriors.
        """
        point = {str(k): float(v) for k, v in result.point.items()}
        best = np.asarray(result.cmaes.x_best, dtype=float)
        optimum = {**point, **{n: float(best[i]) for i, n in enumerate(result.names)}}
        draws = {
            str(k): np.asarray(v, dtype=float).reshape(-1)
            for k, v in result.posterior_draws().items()
        }
        sigma = result.model_error_draws()
        if sigma is not None:
            sigma = np.asarray(sigma, dtype=float)
            sigma = sigma.reshape(sigma.shape[0], -1)
        if any(v.size < 2 for v in draws.values()):
            draws, sigma = {}, None
        if sigma is not None and sigma.shape[0] < 2:
            sigma = None
        diagnostics = getattr(result, "diagnostics", None)
        return cls(
            method=method,
            point=point,
            optimum=optimum,
            j=_finite_or_none(result.j),
            draws=draws,
            sigma_model=sigma,
            diagnostics=None if diagnostics is None else diagnostics.to_json(),
        )

    def save(self, folder: Path) -> None:
        """Write ``summary.json`` and ``draws.npz`` into ``folder``."""
        header = {
            "method": self.method,
            "point": self.point,
            "optimum": self.optimum,
            "j": self.j,
            "diagnostics": self.diagnostics,
        }
        text = json.dumps(header, indent=1) + "\n"
        atomic_write(folder / "summary.json", lambda tmp: tmp.write_text(text), overwrite=True)
        arrays: dict[str, Any] = {f"draw/{k}": v for k, v in self.draws.items()}
        if self.sigma_model is not None:
            arrays["sigma_model"] = self.sigma_model

        def write(tmp: Path) -> None:
            with open(tmp, "wb") as f:
                np.savez(f, **arrays)

        atomic_write(folder / "draws.npz", write, overwrite=True)

    @classmethod
    def load(cls, folder: Path) -> FitSummary:
        """Read what :meth:`save` wrote."""
        header = json.loads((folder / "summary.json").read_text())
        with np.load(folder / "draws.npz", allow_pickle=False) as f:
            arrays = {k: f[k] for k in f.files}
        return cls(
            method=header["method"],
            point={k: float(v) for k, v in header["point"].items()},
            optimum={k: float(v) for k, v in header["optimum"].items()},
            j=header["j"],
            draws={k.split("/", 1)[1]: v for k, v in arrays.items() if k.startswith("draw/")},
            sigma_model=arrays.get("sigma_model"),
            diagnostics=header.get("diagnostics"),
        )

    def table(self) -> list[dict[str, Any]]:
        """Per parameter: the CMA-ES optimum, and the posterior mean, sd and 90 % interval."""
        rows = []
        for name, value in self.optimum.items():
            row: dict[str, Any] = {"parameter": name, "point": value}
            if name in self.draws:
                d = self.draws[name]
                lo, hi = np.quantile(d, [0.05, 0.95])
                row.update(mean=float(d.mean()), sd=float(d.std()), q05=float(lo), q95=float(hi))
            rows.append(row)
        return rows

    def to_json(self) -> dict[str, Any]:
        """The ``fit`` of ``bayesdoor run --json`` (``docs/cli.md``), keyed as ``fit --json`` does.

        Per parameter the CMA-ES optimum (``point``) and, when it was sampled, the posterior
        ``mean``, ``sd`` and 90 % interval (``q5``, ``q95``; ``None`` otherwise); the sampling
        ``diagnostics``; ``j``.
        """
        parameters = {
            row["parameter"]: {
                "point": row["point"],
                "mean": row.get("mean"),
                "sd": row.get("sd"),
                "q5": row.get("q05"),
                "q95": row.get("q95"),
            }
            for row in self.table()
        }
        return {
            "method": self.method,
            "j": self.j,
            "parameters": parameters,
            "diagnostics": self.diagnostics,
        }


@dataclasses.dataclass(frozen=True)
class Fitted(Finished):
    """The product of the ``fit`` stage: the summary the later stages read and, beside it,
    the full result (``result/``, read by the diagnosis).

    Attributes
    ----------
    summary
        The fit's point, draws and model error.
    result
        The full fit (a :class:`bayesdoor.inference.FitResult`); ``None`` when loaded (it
        stays on disk, in :attr:`result_folder`).
    stage
        The record of the stage that made it (``None`` before it is saved by one).
    """

    summary: FitSummary
    result: Any = None
    stage: StageRecord | None = None

    def save(self, folder: Path) -> None:
        """Write the result into ``folder/result`` and the summary into ``folder``."""
        if self.result is not None:
            self.result.save(folder / "result")
        self.summary.save(folder)

    @classmethod
    def load(cls, folder: Path) -> Fitted:
        """The summary :meth:`save` wrote (the result stays on disk)."""
        return cls(FitSummary.load(folder), stage=stage_in(folder))

    @property
    def result_folder(self) -> Path:
        """Where the full result is saved."""
        return self.folder / "result"
