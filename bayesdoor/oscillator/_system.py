"""A single-degree-of-freedom oscillator as a :class:`~bayesdoor.systems.AbstractSystem`.

A mass on a spring and a damper (an instrument package on its mount in a vehicle) whose base
follows a rough road at the run's ``speed``; one accelerometer ``A`` on the mass. The
response is computed in closed form on the record's DFT grid (:mod:`._model`): the base
velocity is a multisine, white in :data:`~._model.BASE_BAND_HZ` with the PSD of an ISO 8608
road, its phases fixed by the system's ``seed``, so a run is a deterministic function of its
parameters, state and speed.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..systems import (
    ConditionSpec,
    DamageSpec,
    ExtensionHost,
    ParameterSpec,
    SimulationResult,
    SpectralFeatures,
)
from ._extensions import EXTENSIONS, AbstractOscillatorExtension
from ._model import base_velocity_psd, mass_acceleration, multisine_phases

#: the updatable parameters: the mount's natural frequency and damping, the road's roughness
PARAMETERS = (
    ParameterSpec(
        "natural_frequency_hz", "Hz", 25.0, 10.0, 50.0, "natural frequency of the mass on its mount"
    ),
    ParameterSpec("damping_ratio", "-", 0.05, 0.01, 0.3, "damping ratio of the mount"),
    ParameterSpec(
        "roughness", "1e-6 m^3", 64.0, 4.0, 1024.0, "the road's ISO 8608 roughness G(n0)"
    ),
)

#: the healthy state and two faults, each with its severity's uniform prior range
STATES = {
    "healthy": DamageSpec("healthy", "no fault"),
    "stiffness_loss": DamageSpec(
        "stiffness_loss",
        "a cracked or softened spring: k lowered by the fraction stiffness_loss, so the "
        "natural frequency by the factor sqrt(1 - stiffness_loss)",
        {"stiffness_loss": (0.2, 0.5)},
    ),
    "loose_mount": DamageSpec(
        "loose_mount",
        "a loosened bolted joint whose friction adds added_damping to the damping ratio",
        {"added_damping": (0.05, 0.15)},
    ),
}

CONDITIONS = (ConditionSpec("speed", "m/s", 2.0, 40.0, "travel speed over the road"),)

#: the accelerometer's sampling rate, Hz, and the record's length, s
FS = 512.0
RECORD_S = 4.0

#: what the fit and the classifier compare: 1 Hz Welch bins (512 samples); the fit's 24
#: bands of 4 Hz from 5 to 100 Hz (both ends included) hold the first mode of every state and
#: the flat response above it, where the one-mode model is complete; the classifier's bins
#: from 0 to 100 Hz the same. A second mode the model lacks shows above, in the diagnosis's
#: wider band (``OSCILLATOR_CATALOGUE.band``)
FEATURES = SpectralFeatures(
    f_low=5.0,
    f_high=100.0,
    band_width=4.0,
    nperseg=512,
    classifier_fmax=100.0,
    classifier_nperseg=512,
)


class Oscillator(ExtensionHost):
    """A base-excited mass-spring-damper seen by one accelerometer ``A`` (m/s^2).

    Operating condition: ``speed`` (m/s), one value per run. A stiffness loss lowers k and
    leaves c: the natural frequency falls by ``sqrt(1 - stiffness_loss)``; a loose mount adds
    ``added_damping`` to the damping ratio.

    Parameters
    ----------
    seed
        Fixes the phases of the base's multisine (the same in every run).
    extensions
        Model extensions of the catalogue (``SecondMode()``); default none, the base model.
        Their parameters follow the base ones in :attr:`parameters`.

    Examples
    --------
    >>> oscillator = Oscillator()
    >>> run = oscillator.simulate_values(oscillator.nominal(), [10.0, 20.0])
    >>> run.signals.shape
    (2, 1, 2048)
    """

    seed: int = eqx.field(static=True, default=0)
    extensions: tuple[AbstractOscillatorExtension, ...] = eqx.field(
        static=True, default=(), converter=tuple
    )

    extension_base: ClassVar[type] = AbstractOscillatorExtension
    extension_classes: ClassVar[Mapping[str, type[AbstractOscillatorExtension]]] = EXTENSIONS
    extension_owner: ClassVar[str] = "the oscillator"

    @property
    def name(self) -> str:
        return "oscillator"

    @property
    def base_parameters(self) -> tuple[ParameterSpec, ...]:
        return PARAMETERS

    @property
    def states(self) -> dict[str, DamageSpec]:
        return dict(STATES)

    @property
    def channels(self) -> tuple[str, ...]:
        return ("A",)

    @property
    def sampling_rate_hz(self) -> float:
        return FS

    @property
    def conditions(self) -> tuple[ConditionSpec, ...]:
        return CONDITIONS

    @property
    def features(self) -> SpectralFeatures:
        return FEATURES

    @property
    def catalogue(self):
        """The oscillator's catalogue of discrepancy causes: ``second_mode`` and ``none``."""
        from ._catalogue import OSCILLATOR_CATALOGUE

        return OSCILLATOR_CATALOGUE

    def describe(self) -> dict:
        return {
            "name": self.name,
            "seed": self.seed,
            "extensions": [
                {"name": e.name, "parameters": [p.name for p in e.parameters]}
                for e in self.extensions
            ],
        }

    def record_duration(self, operating) -> float:
        return RECORD_S

    def simulate_values(
        self,
        values,
        operating,
        *,
        state="healthy",
        severity=None,
        duration=None,
        check=True,
    ) -> SimulationResult:
        """A batch of runs, one per speed in ``operating`` (values broadcast to it).

        Returns signals (run, 1, time) in m/s^2; a run's status is 1 where its signal is not
        finite (its signal then zero), else 0.

        Raises
        ------
        ValueError
            For an unknown state, severity or parameter name, a missing parameter, and, with
            ``check``, a value or a speed outside its range.
        """
        spec = self.check_state(state)
        severity = dict(severity or {})
        unknown = sorted(set(severity) - set(spec.severity))
        if unknown:
            raise ValueError(
                f"unknown severity {unknown} for state {state!r} of {self.name}: it takes "
                f"{', '.join(spec.severity) or 'none'}"
            )
        names = self.parameter_names()
        missing = [k for k in names if k not in values]
        extra = [k for k in values if k not in names]
        if missing or extra:
            raise ValueError(
                f"values must name every parameter of {self.name} ({', '.join(names)}); "
                f"missing {missing or 'none'}, unknown {extra or 'none'}"
            )
        sev = {k: severity.get(k, 0.5 * (lo + hi)) for k, (lo, hi) in spec.severity.items()}
        if check:
            self._check_host(values, operating, state, sev)
        dtype = jnp.result_type(float)
        speed = jnp.atleast_1d(jnp.asarray(operating, dtype=dtype))
        shape = jnp.broadcast_shapes(
            speed.shape, *(jnp.shape(values[k]) for k in names), *map(jnp.shape, sev.values())
        )
        p = {k: jnp.broadcast_to(jnp.asarray(values[k], dtype=dtype), shape) for k in names}
        s = {k: jnp.broadcast_to(jnp.asarray(v, dtype=dtype), shape) for k, v in sev.items()}
        n_time = round((RECORD_S if duration is None else float(duration)) * FS)
        signals, status = _simulate(self, p, jnp.broadcast_to(speed, shape), s, n_time)
        return SimulationResult(signals, status, jnp.arange(n_time, dtype=dtype) / FS)

    def _check_host(self, values, operating, state, severity) -> None:
        """Every value, speed and severity inside its range, else a ``ValueError`` naming it."""
        self.check_operating(operating)
        for param in self.parameters:
            v = np.asarray(values[param.name], dtype=float)
            param.check(float(v.min()) if np.isfinite(v).all() else float("nan"))
            param.check(float(v.max()))
        for k, (lo, hi) in self.states[state].severity.items():
            v = np.asarray(severity[k], dtype=float)
            if not (np.isfinite(v).all() and lo <= v.min() and v.max() <= hi):
                raise ValueError(
                    f"{k}={v.ravel().tolist()} is outside its range [{lo}, {hi}] "
                    f"(the severity of {state} of {self.name})"
                )


@eqx.filter_jit
def _simulate(system: Oscillator, p, speed, severity, n_time: int):
    w_n = 2.0 * np.pi * p["natural_frequency_hz"]
    stiffness = w_n**2 * (1.0 - severity.get("stiffness_loss", 0.0))
    damping = 2.0 * (p["damping_ratio"] + severity.get("added_damping", 0.0)) * w_n
    psd = base_velocity_psd(p["roughness"], speed)
    phases = multisine_phases(system.seed, n_time)
    x = mass_acceleration(stiffness, damping, psd, phases, FS, n_time)[:, None, :]
    time = jnp.arange(n_time, dtype=x.dtype) / FS
    x = system.apply_output_extensions(x, time, p)
    ok = jnp.all(jnp.isfinite(x), axis=(-2, -1))
    return jnp.where(ok[:, None, None], x, 0.0), jnp.where(ok, 0, 1).astype(jnp.int32)
