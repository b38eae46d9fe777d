"""A small analytic system for the tests of the generic layers (datagen, pipeline).

Two channels of tones during the 'motion' after ``REST`` s: a tone at 20 + 40 k Hz of
amplitude m v, plus 48 Hz (D1) or 80 Hz (D2); solves of runs with k above ``fail_above``
fail. Its runs cost microseconds, so the data generation, the training and the job can be
tested in seconds.

The Dask tests ship this module to their workers by value (the workers cannot import
``tests``): :mod:`cloudpickle` is told so here, once for every test module that imports it.
"""

from __future__ import annotations

import sys

import cloudpickle
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from bayesdoor.systems import AbstractSystem, ConditionSpec, DamageSpec, ParameterSpec

FS = 2048.0
REST = 0.1
DURATION = 0.75
CENTER = {"k": 0.5, "m": 1.0, "law": 2.0}

cloudpickle.register_pickle_by_value(sys.modules[__name__])


class ToySystem(AbstractSystem):
    """Tones whose frequency and amplitude follow the parameters, one extra tone per damage.

    Parameters
    ----------
    label
        The system's name.
    d2_amplitude
        The prior range of the D2 tone's amplitude.
    d2_phase
        Whether the D2 tone has a phase severity (uniform over a turn).
    background
        Tones present in every record, moving or not: ``(channel, "sin" | "cos", Hz,
        amplitude)``.
    fail_above
        Runs with ``k`` above it fail (non-zero status, zero signals).
    """

    label: str = eqx.field(static=True, default="toy")
    d2_amplitude: tuple[float, float] = eqx.field(static=True, default=(0.2, 0.4))
    d2_phase: bool = eqx.field(static=True, default=True)
    background: tuple[tuple[int, str, float, float], ...] = eqx.field(
        static=True, default=((1, "cos", 30.0, 0.01),)
    )
    fail_above: float = eqx.field(static=True, default=2.0)

    @property
    def name(self):
        return self.label

    @property
    def parameters(self):
        return (
            ParameterSpec("k", "-", 0.5, 0.0, 1.0, "tone frequency"),
            ParameterSpec("m", "-", 1.0, 0.5, 2.0, "amplitude"),
            ParameterSpec("law", "-", 2, 1, 3, "an integer index", integer=True),
        )

    @property
    def states(self):
        d2 = {"a2": self.d2_amplitude, **({"phase": (0.0, 6.28)} if self.d2_phase else {})}
        return {
            "healthy": DamageSpec("healthy", "none"),
            "D1": DamageSpec("D1", "a 48 Hz tone", {"a1": (0.5, 1.0)}),
            "D2": DamageSpec("D2", "an 80 Hz tone", d2),
        }

    @property
    def channels(self):
        return ("X", "Z")

    @property
    def sampling_rate_hz(self):
        return FS

    @property
    def conditions(self):
        return (ConditionSpec("v_max", "m/s", 0.05, 2.0, "speed"),)

    def record_duration(self, operating):
        return DURATION

    def motion_window(self, operating, *, duration=None):
        v = np.atleast_1d(np.asarray(operating, dtype=float))
        stop = DURATION if duration is None else min(DURATION, duration)
        return np.full(v.shape, REST), np.full(v.shape, stop)

    def simulate(self, theta, damage, operating, *, duration=None):
        return self.simulate_values(theta, operating, state=damage, duration=duration)

    def simulate_values(
        self, values, operating, *, state="healthy", severity=None, duration=None, check=True
    ):
        spec = self.check_state(state)
        severity = dict(severity or {})
        sev = {k: severity.get(k, 0.5 * (lo + hi)) for k, (lo, hi) in spec.severity.items()}
        v = jnp.atleast_1d(jnp.asarray(operating, dtype=float))
        k, m = (jnp.broadcast_to(jnp.asarray(values[n], dtype=float), v.shape) for n in "km")
        sev = {n: jnp.broadcast_to(jnp.asarray(x, dtype=float), v.shape) for n, x in sev.items()}
        n_time = round((duration or DURATION) * FS)
        return _toy_signals(k, m, v, sev, n_time, self.background, self.fail_above)


@eqx.filter_jit
def _toy_signals(k, m, v, sev, n_time: int, background, fail_above: float):
    t = jnp.arange(n_time, dtype=float) / FS
    on = (t >= REST).astype(float)
    x = m[:, None] * v[:, None] * jnp.sin(2 * jnp.pi * (20.0 + 40.0 * k[:, None]) * t)
    if "a1" in sev:
        x = x + sev["a1"][:, None] * jnp.sin(2 * jnp.pi * 48 * t)
    if "a2" in sev:
        phase = sev["phase"][:, None] if "phase" in sev else 0.0
        x = x + sev["a2"][:, None] * jnp.sin(2 * jnp.pi * 80 * t + phase)
    channels = [x * on, 0.5 * x * on]
    for channel, kind, hz, amplitude in background:
        wave = jnp.sin if kind == "sin" else jnp.cos
        channels[channel] = channels[channel] + amplitude * wave(2 * jnp.pi * hz * t)
    signals = jnp.stack(channels, axis=1)
    status = jnp.where(k > fail_above, 1, 0)
    signals = jnp.where(status[:, None, None] == 0, signals, 0.0)
    return _Result(signals, status)


class _Result(eqx.Module):
    signals: jax.Array
    status: jax.Array
