"""Model extensions of the bearing: the catalogue of discrepancy causes as code.

Each extension is a frozen module whose fields are static configuration (how many shaft
harmonics, which supply frequency); its fitted quantities are
:class:`~bayesdoor.systems.ParameterSpec` s named ``"<catalogue name>.<quantity>"``. Every
extension is inert at its nominal values (amplitudes and gains of zero), so an extended
bearing at its nominal parameters is the base bearing. The prior of every parameter is
uniform on its bounds (the generic fit's).

Two kinds, as the door's:

- ``shaft_harmonics`` needs the run's shaft speed, so it acts inside
  :meth:`BearingSystem.simulate_values` (``needs_resolve``); its amplitudes act linearly;
- ``structural_mode`` and ``line_frequency`` act on the simulated signal only (output
  extensions): they are refitted on the base signals simulated once.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._types import Array, Float
from ..systems import (
    AbstractExtension,
    ParameterSpec,
    UnsynchronisedLines,
    build_extension,
)
from ._model import resonance_response

#: the default bearing's sampling rate, Hz: the supply's harmonics lie below its Nyquist
_FS = 12000.0
#: the supply frequencies an electrical line may have, Hz
SUPPLY_FREQUENCIES_HZ = (50.0, 60.0)
#: the band a structural mode the model lacks may lie in, Hz: above the shaft-rate lines
#: (10 x 1X is 300-320 Hz at 1800-1900 rpm) and under the recorder's anti-alias cut
MODE_BAND_HZ = (500.0, 5400.0)
#: the most shaft harmonics an extension carries
MAX_SHAFT_HARMONICS = 10


def _spec(
    owner: str, quantity: str, unit: str, nominal: float, lower: float, upper: float, text: str
) -> ParameterSpec:
    return ParameterSpec(f"{owner}.{quantity}", unit, nominal, lower, upper, text)


class AbstractBearingExtension(AbstractExtension):
    """One model extension of the bearing (:class:`bayesdoor.systems.AbstractExtension`).

    Output extensions act on a run's signals (channel, time) in ``stage`` order: structure,
    then the measurement chain.
    """


class ShaftHarmonics(AbstractBearingExtension):
    """Shaft-synchronous lines the model lacks (``shaft_harmonics``): unbalance, misalignment.

    Adds ``a_k cos(2 pi k f_r t + phi_k)`` for k = 1..``harmonics`` to the run, f_r the run's
    shaft frequency (``shaft_speed / 60``). For k up to the base model's own shaft lines
    (1x-3x) phi_k is that line's phase, so ``a_k`` adds to its amplitude (a negative one
    takes from it); above, phi_k is drawn from the run's key like the base phases. Unbalance
    shows at 1x, misalignment at 2x and 3x (and 1x), mechanical looseness as a series of
    harmonics up to about 10x (Randall, "Vibration-based condition monitoring", Wiley 2011,
    ch. 2): ``harmonics`` is at most :data:`MAX_SHAFT_HARMONICS`.

    Parameters: ``shaft_harmonics.amplitude_<k>`` (m/s^2, -2 to 2, the bound of the base
    model's ``shaft_amplitude``; 0 is off).
    """

    name: ClassVar[str] = "shaft_harmonics"
    needs_resolve: ClassVar[bool] = True

    harmonics: int = eqx.field(static=True, default=3)

    def __check_init__(self):
        if not 1 <= self.harmonics <= MAX_SHAFT_HARMONICS:
            raise ValueError(
                f"ShaftHarmonics.harmonics={self.harmonics!r} must lie in 1..{MAX_SHAFT_HARMONICS}"
            )

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        return tuple(
            _spec(
                self.name,
                f"amplitude_{k}",
                "m/s^2",
                0.0,
                -2.0,
                2.0,
                f"amplitude added to the {k}x shaft line",
            )
            for k in range(1, self.harmonics + 1)
        )

    def amplitudes(self, values: Mapping[str, Array]) -> Float[Array, " harmonic"]:
        """The amplitudes 1x..Kx as one array."""
        v = self.local(values)
        return jnp.stack([jnp.asarray(v[f"amplitude_{k}"]) for k in range(1, self.harmonics + 1)])


class StructuralMode(AbstractBearingExtension):
    """A structural resonance the model lacks (``structural_mode``), an output extension.

    The signal x(t) (the base model's: its broadband background and measurement noise are
    the excitation, as the stand's broadband excitation is a real mode's) is filtered by the
    mode's ring-down e^(-zeta w t) sin(w_d t), normalised to unit gain and zero phase at the
    natural frequency, and added ``gain`` times: x + g (h * x), computed on the record's DFT
    grid as the base model's resonances are (a circular convolution). At the mode's frequency
    the spectrum rises by (1 + g)^2; away from it the signal is unchanged (the filtered part
    is in quadrature there, so it only adds); half-power width about 2 zeta f.

    Parameters: ``structural_mode.frequency_hz`` (Hz, :data:`MODE_BAND_HZ`),
    ``structural_mode.damping_ratio`` (0.001-0.1) and ``structural_mode.gain`` (0-300, the
    peak amplification minus one; 0 is off).
    """

    name: ClassVar[str] = "structural_mode"
    needs_resolve: ClassVar[bool] = False
    stage: ClassVar[int] = 1

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        return (
            _spec(
                self.name,
                "frequency_hz",
                "Hz",
                1000.0,
                *MODE_BAND_HZ,
                "natural frequency of the missing mode",
            ),
            _spec(self.name, "damping_ratio", "-", 0.01, 0.001, 0.1, "its damping ratio"),
            _spec(self.name, "gain", "-", 0.0, 0.0, 300.0, "its peak amplification minus one"),
        )

    def apply(self, signal, time, values):
        v = self.local(values)
        n = signal.shape[-1]
        dtype = signal.dtype
        # the record's own rate, from its time axis (the system's sampling rate)
        fs = 1.0 / (time[1] - time[0]).astype(dtype)
        f = jnp.arange(n // 2 + 1, dtype=dtype) * (fs / n)
        fn = jnp.asarray(v["frequency_hz"], dtype)
        zeta = jnp.asarray(v["damping_ratio"], dtype)
        response = resonance_response(f, fs, fn, zeta)
        # unit gain and zero phase at the natural frequency: the mode adds to the signal there
        at_mode = resonance_response(fn[None], fs, fn, zeta)[0]
        filtered = jnp.fft.irfft(jnp.fft.rfft(signal) * (response / at_mode), n=n)
        return signal + jnp.asarray(v["gain"], dtype) * filtered


class LineFrequency(UnsynchronisedLines, AbstractBearingExtension):
    """An electrical line at the supply frequency and its harmonics (``line_frequency``).

    Adds ``sum_m a_m cos(2 pi m f0 t)`` for m = 1..``harmonics``, f0 = ``frequency_hz`` (50
    or 60 Hz): electrical interference in the measurement chain, or the motor's
    electromagnetic forces (the stator field's pull pulsates at 2 f0: an induction motor's
    classic electrical vibration), whatever the shaft speed. The supply is not synchronised
    with the shaft, so a record meets the bearing's own content at a line's frequency (a
    shaft harmonic near 60 Hz) at a phase of chance: each line carries the expectation over
    it, its power added to the signal's (:func:`~bayesdoor.systems.unsynchronised_line`).

    Parameters: ``line_frequency.amplitude_<m>`` (m/s^2, 0-2; 0 is off).
    """

    name: ClassVar[str] = "line_frequency"
    needs_resolve: ClassVar[bool] = False
    stage: ClassVar[int] = 2
    supply_frequencies_hz: ClassVar[tuple[float, ...]] = SUPPLY_FREQUENCIES_HZ
    sampling_rate_hz: ClassVar[float] = _FS

    frequency_hz: float = eqx.field(static=True, default=60.0)
    harmonics: int = eqx.field(static=True, default=6)

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        return tuple(
            _spec(
                self.name,
                f"amplitude_{m}",
                "m/s^2",
                0.0,
                0.0,
                2.0,
                f"amplitude of the line at {m} x {self.frequency_hz:g} Hz",
            )
            for m in range(1, self.harmonics + 1)
        )

    def weigh(self, units, values, dtype):
        """The sum of every harmonic's unit line at its own amplitude."""
        line = jnp.zeros_like(units[0])
        for m in range(1, self.harmonics + 1):
            line = line + jnp.asarray(values[f"amplitude_{m}"], dtype) * units[m - 1]
        return line


#: the extension class of every catalogue name (``none`` is the base model: no class)
EXTENSIONS: dict[str, type[AbstractBearingExtension]] = {
    cls.name: cls for cls in (ShaftHarmonics, StructuralMode, LineFrequency)
}


def extension(name_or_module: str | AbstractBearingExtension, **config) -> AbstractBearingExtension:
    """The extension of a catalogue name (default configuration, or ``config``), or the module.

    Raises
    ------
    ValueError
        For a name outside the catalogue, or ``"none"``.
    """
    return build_extension(name_or_module, EXTENSIONS, "the bearing", **config)
