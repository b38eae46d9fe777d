"""The oscillator's model extension: the cause of its catalogue as code.

One extension, :class:`SecondMode`: a second mode of the structure that the
single-degree-of-freedom model lacks (a bracket's bending, a panel). It acts on the simulated
acceleration only (an output extension), so the diagnosis refits it on the base model's
signals simulated once. At its nominal gain of zero it is off: an extended oscillator at its
nominal parameters is the base oscillator.
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from ..systems import AbstractExtension, ParameterSpec, build_extension

#: where a second mode may lie, Hz: above the first mode's range and below the base band's top
MODE_BAND_HZ = (55.0, 200.0)


class AbstractOscillatorExtension(AbstractExtension):
    """One model extension of the oscillator (:class:`bayesdoor.systems.AbstractExtension`)."""


class SecondMode(AbstractOscillatorExtension):
    """A second mode the model lacks (``second_mode``), an output extension.

    The acceleration x is filtered by the mode's band-pass ``B(w) = 2i zeta w_2 w / (w_2^2 -
    w^2 + 2i zeta w_2 w)`` (unit gain and zero phase at ``w_2``) and added ``gain`` times,
    ``x + g (B * x)``, on the record's DFT grid: at the mode's frequency the spectrum rises by
    ``(1 + g)^2``, elsewhere it is nearly unchanged; half-power width about ``2 zeta f_2``.

    Parameters: ``second_mode.frequency_hz`` (Hz, :data:`MODE_BAND_HZ`),
    ``second_mode.damping_ratio`` (0.002-0.2) and ``second_mode.gain`` (0-100; 0 is off).
    """

    name: ClassVar[str] = "second_mode"
    needs_resolve: ClassVar[bool] = False
    stage: ClassVar[int] = 1

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        return (
            ParameterSpec(
                "second_mode.frequency_hz",
                "Hz",
                100.0,
                *MODE_BAND_HZ,
                "natural frequency of the missing mode",
            ),
            ParameterSpec("second_mode.damping_ratio", "-", 0.02, 0.002, 0.2, "its damping ratio"),
            ParameterSpec(
                "second_mode.gain", "-", 0.0, 0.0, 100.0, "its peak amplification minus one"
            ),
        )

    def apply(self, signals, time, values):
        v = self.local(values)
        n = signals.shape[-1]
        dtype = signals.dtype
        fs = 1.0 / (time[1] - time[0]).astype(dtype)
        w = 2.0 * np.pi * jnp.fft.rfftfreq(n, 1.0 / fs).astype(dtype)
        w2 = 2.0 * np.pi * jnp.asarray(v["frequency_hz"], dtype)
        bandwidth = 2.0 * jnp.asarray(v["damping_ratio"], dtype) * w2
        zero = jnp.zeros_like(w)
        band_pass = jax.lax.complex(zero, bandwidth * w) / jax.lax.complex(
            w2**2 - w**2, bandwidth * w
        )
        filtered = jnp.fft.irfft(jnp.fft.rfft(signals) * band_pass, n=n)
        return signals + jnp.asarray(v["gain"], dtype) * filtered


#: the extension class of every catalogue name (``none`` is the base model: no class)
EXTENSIONS: dict[str, type[AbstractOscillatorExtension]] = {SecondMode.name: SecondMode}


def extension(
    name_or_module: str | AbstractOscillatorExtension, **config
) -> AbstractOscillatorExtension:
    """The extension of a catalogue name, or the module itself.

    Raises
    ------
    ValueError
        For a name outside the catalogue, or ``"none"``.
    """
    return build_extension(name_or_module, EXTENSIONS, "the oscillator", **config)
