"""The outcome of a fit (:class:`FitResult`), written to and read from a folder."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import arviz as az
import numpy as np

from ..io import atomic_write
from ..systems import AbstractSystem
from ._cmaes import CMAESHistory, CMAESResult
from ._diagnostics import SamplingDiagnostics
from ._features import FeatureSpec
from ._likelihood import ModelError
from ._posterior import load_posterior, save_posterior
from ._settings import FitSettings


@dataclasses.dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit_campaign`.

    Attributes
    ----------
    method
        ``cmaes``, ``nuts`` or ``emcee``.
    held
        Every parameter held fixed, by name: those the fit was given (``fixed``) and the
        integer ones (the door's contact-law index ``I``) at the CMA-ES optimum's value;
        empty when every parameter was sampled or optimised.
    point
        Every parameter by name: the CMA-ES optimum (``cmaes``) or the posterior mean, with
        the held parameters at ``held``.
    j
        The paper's objective J at ``point`` (exact simulator), averaged over the runs.
    idata
        The posterior (``nuts``/``emcee``), with ``posterior_predictive``; ``None`` for
        ``cmaes``.
    diagnostics
        The sampling gates (``None`` for ``cmaes``).
    cmaes
        The CMA-ES run (optimum, history).
    feature_spec
        The features used.
    settings
        The stage sizes.
    names
        The sampled (continuous, not held) parameters, in order.
    sigma_point
        Model-error (discrepancy) scale at the CMA-ES optimum (decades), per operating point
        (in the order of the calibration runs' distinct operating points) and channel, or per
        channel (``ModelError(per_operating=False)``); a moment estimate from the residuals
        there.
    scatter_point
        Run scatter per channel at the CMA-ES optimum (Welch standard deviations; 1 for the
        independent model error), likewise.
    model_error
        The model-error prior and structure of the likelihood.
    bounds
        Lower and upper bounds of ``names``.
    surrogate_box
        The surrogate's training box (``None`` for ``cmaes``).
    surrogate_rms
        The surrogate's held-out RMS error over all features (decades), or ``None``.
    runs
        Indices (in the campaign) of the runs fitted.
    duration
        Simulated record length (s).
    notes
        Warnings raised during the fit (failed gates, a posterior cut by the surrogate box).
    timings
        Seconds spent per stage.
    seed
        The seed.
    system
        The fitted system's :meth:`~bayesdoor.systems.AbstractSystem.describe` (its
        extensions and their configuration); ``None`` for fits written before it was recorded.
    """

    method: str
    held: dict[str, float]
    point: dict[str, float]
    j: float
    idata: az.InferenceData | None
    diagnostics: SamplingDiagnostics | None
    cmaes: CMAESResult
    feature_spec: FeatureSpec
    settings: FitSettings
    names: tuple[str, ...]
    sigma_point: np.ndarray
    scatter_point: np.ndarray
    model_error: ModelError
    bounds: tuple[np.ndarray, np.ndarray]
    surrogate_box: tuple[np.ndarray, np.ndarray] | None
    surrogate_rms: float | None
    runs: np.ndarray
    duration: float
    notes: tuple[str, ...]
    timings: dict[str, float]
    seed: int
    system: dict[str, Any] | None = None

    def check_system(self, system: AbstractSystem, *, source: str = "the fit") -> None:
        """Refuse a fit of another system configuration (an extended system for a base one).

        Fits recorded without a description are compared by their parameter names.

        Raises
        ------
        ValueError
            In one line, naming both descriptions' extensions and the fix.
        """
        if self.system is None:
            if set(self.point) == set(system.parameter_names()):
                return
            recorded: Any = sorted(self.point)
            expected: Any = list(system.parameter_names())
        else:
            recorded, expected = _described(self.system), _described(system.describe())
            if recorded == expected:
                return
        raise ValueError(
            f"{source} was made for {system.name} {_extensions_text(recorded)}, not "
            f"{_extensions_text(expected)} as given: refit with this system, or use the fit "
            "only with the system it was made for"
        )

    def posterior_draws(self) -> dict[str, np.ndarray]:
        """Draws of every continuous parameter, chains flattened (``cmaes``: the point once)."""
        if self.idata is None:
            return {n: np.asarray([self.point[n]]) for n in self.names}
        post = self.idata["posterior"]
        return {n: np.asarray(post[n].values).reshape(-1) for n in self.names}

    def model_error_draws(self) -> np.ndarray | None:
        """Model-error scales per channel, (draw, channel), decades (``cmaes``: the point once).

        With scales per operating point, their root mean square over the operating points;
        with a part common to every operating point, that and the common scale in quadrature.
        """
        sigma = self.discrepancy_draws()
        sigma = np.sqrt(np.mean(sigma**2, axis=1)) if sigma.ndim == 3 else sigma
        tau = self.common_draws()
        return sigma if tau is None else np.sqrt(sigma**2 + tau**2)

    def common_draws(self) -> np.ndarray | None:
        """Scales of the discrepancy common to every operating point, (draw, channel), decades;
        ``None`` without one (``ModelError(common=False)``, or a CMA-ES point)."""
        if self.idata is None or "sigma_common" not in self.idata["posterior"]:
            return None
        tau = np.asarray(self.idata["posterior"]["sigma_common"].values)
        return tau.reshape(-1, tau.shape[-1])

    def discrepancy_draws(self) -> np.ndarray:
        """Discrepancy scales as fitted: (draw, op, channel) per operating point, else
        (draw, channel); decades (``cmaes``: the point once)."""
        if self.idata is None:
            return np.asarray(self.sigma_point)[None]
        post = self.idata["posterior"]
        name = "sigma_operating" if "sigma_operating" in post else "sigma_model"
        sigma = np.asarray(post[name].values)
        return sigma.reshape(-1, *sigma.shape[2:])

    def run_scatter_draws(self) -> np.ndarray:
        """Run scatter in Welch sds, (draw, channel) (``cmaes`` or independent: one row)."""
        if self.idata is None or "run_scatter" not in self.idata["posterior"]:
            return np.asarray(self.scatter_point)[None]
        rho = np.asarray(self.idata["posterior"]["run_scatter"].values)
        return rho.reshape(-1, rho.shape[-1])

    def to_json(self) -> dict[str, Any]:
        """Per parameter: point (or mean), sd and 90 % interval; diagnostics; J."""
        draws = self.posterior_draws()
        parameters: dict[str, Any] = {}
        for name, value in self.point.items():
            if name in draws and self.idata is not None:
                d = draws[name]
                q5, q95 = np.quantile(d, [0.05, 0.95])
                parameters[name] = {
                    "mean": float(np.mean(d)),
                    "sd": float(np.std(d)),
                    "q5": float(q5),
                    "q95": float(q95),
                }
            else:
                parameters[name] = {"point": float(value), "sd": None, "q5": None, "q95": None}
        sigma = self.model_error_draws()
        return {
            "method": self.method,
            "held": self.held,
            "j": self.j,
            "parameters": parameters,
            "model_error": None if sigma is None else np.mean(sigma, axis=0).tolist(),
            "run_scatter": np.mean(self.run_scatter_draws(), axis=0).tolist(),
            "diagnostics": None if self.diagnostics is None else self.diagnostics.to_json(),
            "cmaes": {
                "f_best": self.cmaes.f_best,
                "evaluations": self.cmaes.evaluations,
                "restarts": self.cmaes.restarts,
                "stop": list(self.cmaes.stop),
            },
            "surrogate_rms": self.surrogate_rms,
            "runs": self.runs.tolist(),
            "notes": list(self.notes),
            "timings": self.timings,
        }

    def save(self, folder: str | Path, *, force: bool = False) -> Path:
        """Write ``fit.json`` (everything but the posterior) and ``posterior.nc`` to a folder.

        Raises
        ------
        FileExistsError
            When the folder already holds a fit and ``force`` is false (nothing is written).
        """
        folder = Path(folder)
        target = folder / "fit.json"
        nc = folder / "posterior.nc"
        if not force and (target.exists() or nc.exists()):
            raise FileExistsError(
                f"{folder} already holds a fit ({target.name} or {nc.name}); pass force=True "
                "to overwrite it"
            )
        folder.mkdir(parents=True, exist_ok=True)
        if self.idata is not None:
            save_posterior(self.idata, nc, overwrite=True)
        h = self.cmaes.history
        record = {
            "method": self.method,
            "held": self.held,
            "point": self.point,
            "j": self.j,
            "feature_spec": {
                f: getattr(self.feature_spec, f)
                for f in ("f_low", "f_high", "band_width", "nperseg", "noverlap", "window")
            },
            "settings": dataclasses.asdict(self.settings),
            "names": list(self.names),
            "sigma_point": np.asarray(self.sigma_point).tolist(),
            "scatter_point": np.asarray(self.scatter_point).tolist(),
            "model_error": {
                f: getattr(self.model_error, f)
                for f in (
                    "scale",
                    "slope",
                    "slope_scale",
                    "shared",
                    "per_operating",
                    "scatter_scale",
                    "correlation",
                    "infer_correlation",
                    "correlation_scale",
                    "common",
                )
            },
            "bounds": [np.asarray(b).tolist() for b in self.bounds],
            "surrogate_box": None
            if self.surrogate_box is None
            else [np.asarray(b).tolist() for b in self.surrogate_box],
            "surrogate_rms": self.surrogate_rms,
            "runs": self.runs.tolist(),
            "duration": self.duration,
            "notes": list(self.notes),
            "timings": self.timings,
            "seed": self.seed,
            "system": self.system,
            "diagnostics": None if self.diagnostics is None else self.diagnostics.to_json(),
            "cmaes": {
                "x_best": self.cmaes.x_best.tolist(),
                "f_best": self.cmaes.f_best,
                "evaluations": self.cmaes.evaluations,
                "restarts": self.cmaes.restarts,
                "failed": self.cmaes.failed,
                "stop": list(self.cmaes.stop),
                "seed": self.cmaes.seed,
                "history": {
                    f.name: np.asarray(getattr(h, f.name)).tolist() for f in dataclasses.fields(h)
                },
            },
        }
        text = json.dumps(record, indent=1, default=_json_default) + "\n"
        atomic_write(target, lambda tmp: tmp.write_text(text), overwrite=True)
        return folder

    @classmethod
    def load(cls, folder: str | Path) -> FitResult:
        """Read a fit written by :meth:`save`.

        Fits written before ``held`` recorded the one integer parameter's value as ``law``;
        that parameter is the one of ``point`` that ``names`` (the sampled ones) lacks.

        Raises
        ------
        FileNotFoundError
            When the folder holds no ``fit.json`` (or a sampled fit lacks ``posterior.nc``).
        ValueError
            For an old record whose ``law`` cannot be told to which parameter it belongs.
        """
        folder = Path(folder)
        target = folder / "fit.json"
        if not target.is_file():
            raise FileNotFoundError(f"{target} not found: pass a folder written by fit.save")
        r = json.loads(target.read_text())
        c = r["cmaes"]
        history = CMAESHistory(
            **{
                k: np.asarray(v, dtype=float if k in ("best_f", "median_f", "sigma") else int)
                for k, v in c["history"].items()
            }
        )
        cmaes = CMAESResult(
            x_best=np.asarray(c["x_best"], dtype=float),
            f_best=_float(c["f_best"]),
            evaluations=c["evaluations"],
            restarts=c["restarts"],
            failed=c["failed"],
            stop=tuple(c["stop"]),
            history=history,
            seed=c["seed"],
        )
        diagnostics = None
        if r["diagnostics"] is not None:
            d = dict(r["diagnostics"])
            for k in ("rhat_max", "ess_bulk_min", "ess_tail_min"):
                d[k] = _float(d[k])
            d["ebfmi"] = None if d["ebfmi"] is None else tuple(_float(e) for e in d["ebfmi"])
            d["messages"] = tuple(d["messages"])
            diagnostics = SamplingDiagnostics(**d)
        return cls(
            method=r["method"],
            held=_held_of(r, target),
            point={k: float(v) for k, v in r["point"].items()},
            j=_float(r["j"]),
            idata=None if r["method"] == "cmaes" else load_posterior(folder / "posterior.nc"),
            diagnostics=diagnostics,
            cmaes=cmaes,
            feature_spec=FeatureSpec(**r["feature_spec"]),
            settings=FitSettings(**r["settings"]),
            names=tuple(r["names"]),
            sigma_point=np.asarray(r["sigma_point"], dtype=float),
            scatter_point=np.asarray(
                r.get("scatter_point", np.ones(len(r["sigma_point"]))), dtype=float
            ),
            # fits written before the shared discrepancy existed had the independent form
            model_error=ModelError(**r.get("model_error", {"shared": False})),
            bounds=tuple(np.asarray(b, dtype=float) for b in r["bounds"]),  # type: ignore[arg-type]
            surrogate_box=None
            if r["surrogate_box"] is None
            else tuple(np.asarray(b, dtype=float) for b in r["surrogate_box"]),  # type: ignore[arg-type]
            surrogate_rms=r["surrogate_rms"],
            runs=np.asarray(r["runs"], dtype=int),
            duration=float(r["duration"]),
            notes=tuple(r["notes"]),
            timings=dict(r["timings"]),
            seed=int(r["seed"]),
            system=r.get("system"),
        )


def _held_of(record: dict[str, Any], target: Path) -> dict[str, float]:
    """The held parameters of a ``fit.json`` record; of an old one (``law`` instead of
    ``held``), the parameter of ``point`` that ``names`` lacks at the value ``law``."""
    if "held" in record:
        return {str(k): float(v) for k, v in record["held"].items()}
    law = record.get("law")
    held = {str(k): float(v) for k, v in record["point"].items() if k not in record["names"]}
    if law is None and not held:
        return {}
    if law is not None and len(held) == 1 and next(iter(held.values())) == float(law):
        return held
    raise ValueError(
        f"{target} is an old fit record (law={law!r}, no 'held') whose held parameter cannot be "
        f"told from its point and names (parameters not sampled: {sorted(held) or 'none'}): "
        "refit it"
    )


def _described(description: dict[str, Any]) -> Any:
    """A description as plain JSON values (tuples as lists), for comparison."""
    return json.loads(json.dumps(description, sort_keys=True, default=_json_default))


def _extensions_text(described: Any) -> str:
    """The extensions (and held values) of a description, or its parameter names, in words."""
    if not isinstance(described, dict):
        return f"with the parameters {described}"
    parts = [
        f"{e['name']}({', '.join(f'{k}={v!r}' for k, v in e.get('config', {}).items())})"
        for e in described.get("extensions", [])
    ]
    text = f"with extensions [{', '.join(parts)}]" if parts else "without extensions"
    held = described.get("held")
    return f"{text} held at {held}" if held else text


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot write {type(value).__name__} as JSON")


def _float(value: float | None) -> float:
    return float("nan") if value is None else float(value)
