"""The diagnosed runs of a campaign and the base model's simulation of them."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import jax.numpy as jnp
import numpy as np
import xarray as xr

from ..features import motion_window as detect_motion_window
from ..inference import FitResult, calibration_runs
from ..io import operating as campaign_operating
from ._features import Features
from ._gain import feature_bins
from ._rank import Catalogue
from ._refit import RefitSetup, Spectra, tile_runs

if TYPE_CHECKING:
    from ..systems import AbstractSystem


@dataclasses.dataclass(frozen=True)
class Measured:
    """The diagnosed runs of a campaign: signals, operating points, motion windows."""

    runs: np.ndarray
    signals: np.ndarray
    operating: np.ndarray
    t_start: np.ndarray
    t_stop: np.ndarray
    fs: float
    channels: tuple[str, ...]

    @classmethod
    def of(cls, system: AbstractSystem, campaign: xr.Dataset, runs: np.ndarray) -> Measured:
        fs = float(campaign.attrs.get("sampling_rate_hz", np.nan))
        if fs != system.sampling_rate_hz:
            raise ValueError(
                f"the campaign's sampling_rate_hz={fs} differs from {system.name}'s "
                f"{system.sampling_rate_hz} Hz: resample the measurements to the model's rate"
            )
        chosen = campaign.isel(run=np.asarray(runs))
        channels = tuple(system.channels)
        x = np.asarray(chosen["acceleration"].sel(channel=list(channels)).values, dtype=float)
        if "t_start" in chosen.variables and "t_stop" in chosen.variables:
            t0 = np.asarray(chosen["t_start"].values, dtype=float)
            t1 = np.asarray(chosen["t_stop"].values, dtype=float)
        else:
            t = np.arange(x.shape[-1]) / fs
            w = np.array([detect_motion_window(t, s) for s in x])
            t0, t1 = w[:, 0], w[:, 1]
        operating = campaign_operating(chosen, system)
        return cls(np.asarray(runs), x, operating, t0, t1, fs, channels)

    @property
    def duration(self) -> float:
        return self.signals.shape[-1] / self.fs

    def setup(
        self,
        system: AbstractSystem,
        point: Mapping[str, float],
        base_signals: np.ndarray,
        sample_times: np.ndarray,
        band: tuple[float, float],
        features: Features | None,
        speeds: np.ndarray | None = None,
    ) -> RefitSetup:
        spectra = Spectra.of_measured(
            self.signals, self.fs, self.t_start, self.t_stop, band, nperseg=int(self.fs)
        )
        if features is not None:
            local = feature_bins(features.residuals, spectra.freqs)
            spectra = dataclasses.replace(spectra, local=local)
        return RefitSetup(
            system=system,
            point=dict(point),
            operating=self.operating,
            duration=self.duration,
            time=sample_times,
            base_signals=base_signals,
            spectra=spectra,
            speeds=speeds,
            measured_signals=self.signals,
        )


def measure(system: AbstractSystem, campaign: xr.Dataset) -> Measured:
    """The diagnosed runs of a campaign: its healthy calibration runs."""
    return Measured.of(system, campaign, calibration_runs(campaign, system.healthy))


def _simulate_rows(
    system: AbstractSystem, measured: Measured, rows: Sequence[Mapping[str, float]]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signals (row, run, channel, time) of every run for each parameter row, success per row."""
    n_runs, n_time = len(measured.runs), measured.signals.shape[-1]
    values = {
        name: jnp.asarray(np.repeat([row[name] for row in rows], n_runs))
        for name in system.parameter_names()
    }
    result = system.simulate_values(
        values,
        jnp.asarray(tile_runs(measured.operating, len(rows))),
        state=system.healthy,
        duration=measured.duration,
    )
    ok = np.all(np.asarray(result.status).reshape(len(rows), n_runs) == 0, axis=1)
    signals = np.asarray(result.signals)[..., :n_time]
    return (
        signals.reshape(len(rows), n_runs, *signals.shape[1:]),
        ok,
        np.asarray(result.time)[:n_time],
    )


def base_setup(
    system: AbstractSystem,
    measured: Measured,
    fit: FitResult,
    band: tuple[float, float],
    features: Features | None = None,
    speeds: np.ndarray | None = None,
) -> RefitSetup:
    """The refit setup of the measured runs, the base model simulated at the fit's point
    (:meth:`Measured.setup`).

    Raises
    ------
    RuntimeError
        When the base model fails to simulate a run at the fit's point.
    """
    sims, ok, sample_times = _simulate_rows(system, measured, [dict(fit.point)])
    if not ok[0]:
        raise RuntimeError("the base model failed to simulate the runs at the fit's point")
    return measured.setup(system, fit.point, sims[0], sample_times, band, features, speeds)


def _band(fit: FitResult, catalogue: Catalogue | None = None) -> tuple[float, float]:
    """The analysed band: the catalogue's ``band`` when it names one, else the fit's feature
    band (where the base model was fitted)."""
    if catalogue is not None and catalogue.band is not None:
        return float(catalogue.band[0]), float(catalogue.band[1])
    return float(fit.feature_spec.f_low), float(fit.feature_spec.f_high)


def _fold_order(catalogue: Catalogue, operating: np.ndarray) -> np.ndarray:
    """What :func:`held_out_folds` sorts the runs by: the catalogue's speed of each run, else
    the operating point (several conditions: their columns in order)."""
    speeds = catalogue.speeds(operating)
    return np.asarray(operating if speeds is None else speeds, dtype=float)
