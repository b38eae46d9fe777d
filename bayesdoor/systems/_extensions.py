"""The model-extension interface a system's catalogue of discrepancy causes builds on.

An extension adds one physical effect the base model lacks (a structural mode, a line, a
sensor's cross-axis leak, ...) with parameters whose nominal values switch it off. It acts
either inside the simulation (``needs_resolve = True``: refitting it needs new solves) or on
the simulated sensor signals only (an *output* extension, :meth:`AbstractExtension.apply`):
those can be refitted on signals simulated once (:func:`apply_output_extensions`).
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, ClassVar, TypeVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._exported import persistent_jit
from .._types import Array, Float
from ._base import ParameterSpec

E = TypeVar("E", bound="AbstractExtension")


class AbstractExtension(eqx.Module):
    """One model extension: a catalogue name, static configuration and fitted parameters.

    Its parameters are named ``"<name>.<quantity>"``; at their nominal values the extension
    has no effect. An output extension (``needs_resolve = False``) implements :meth:`apply`;
    output extensions act in the order of their ``stage`` (structure before sensor before
    the measurement chain), whatever the order they were switched on in.
    """

    name: ClassVar[str]
    needs_resolve: ClassVar[bool]
    #: the order in which output extensions act
    stage: ClassVar[int] = 0

    @property
    @abc.abstractmethod
    def parameters(self) -> tuple[ParameterSpec, ...]:
        """The fitted parameters, names prefixed with ``"<name>."``; nominal values are inert."""

    def local(self, values: Mapping[str, Array | float]) -> dict[str, Array | float]:
        """This extension's values from a mapping of full names, keyed by the unprefixed names.

        Raises
        ------
        ValueError
            When a parameter of this extension is missing from ``values``.
        """
        names = [p.name for p in self.parameters]
        missing = [n for n in names if n not in values]
        if missing:
            raise ValueError(
                f"values lack the {self.name} parameters {missing}: pass every parameter of "
                f"the extension (its nominal values switch it off)"
            )
        prefix = len(self.name) + 1
        return {n[prefix:]: values[n] for n in names}

    def full(self, values: Mapping[str, Array | float]) -> dict[str, Array | float]:
        """This extension's values from a mapping of full names, keyed by the full names."""
        return {f"{self.name}.{k}": v for k, v in self.local(values).items()}

    def nominal(self) -> dict[str, float]:
        """Nominal value of every parameter by full name (the extension switched off)."""
        return {p.name: p.nominal for p in self.parameters}

    def apply(
        self,
        signals: Float[Array, "channel time"],
        time: Float[Array, " time"],
        values: Mapping[str, Array],
    ) -> Float[Array, "channel time"]:
        """The sensor signals of one run with this extension's effect (output extensions)."""
        return signals


def build_extension(
    name_or_module: str | E, catalogue: Mapping[str, type[E]], owner: str, **config
) -> E:
    """The extension of a catalogue name (default configuration, or ``config``), or the module.

    Parameters
    ----------
    name_or_module
        A name of ``catalogue`` or a built extension.
    catalogue
        The system's extension class of every catalogue name.
    owner
        The system, in words, for the messages (``"the door"``).

    Raises
    ------
    ValueError
        For a name outside the catalogue, ``"none"`` (the base model has no extension), or
        configuration given with a built extension.
    """
    if isinstance(name_or_module, AbstractExtension):
        if config:
            raise ValueError(
                f"configuration {sorted(config)} was given with a built extension "
                f"{name_or_module!r}: pass the catalogue name instead"
            )
        return name_or_module
    if name_or_module not in catalogue:
        hint = " ('none' is the base model: pass no extension)" if name_or_module == "none" else ""
        raise ValueError(
            f"unknown model extension {name_or_module!r}{hint}: {owner}'s catalogue has "
            f"{', '.join(catalogue)}"
        )
    return catalogue[name_or_module](**config)


@persistent_jit
def _apply_in_stage_order(extensions, signals, time, values):
    def one(run, vals):
        for e in sorted(extensions, key=lambda e: e.stage):
            run = e.apply(run, time, vals)
        return run

    return jax.vmap(one)(signals, values)


def apply_output_extensions(
    extensions: Sequence[AbstractExtension],
    signals: Float[Array, "*batch channel time"],
    time: Float[Array, " time"],
    values: Mapping[str, Float[Array, "*batch"] | float],
) -> Float[Array, "*batch channel time"]:
    """Signals with the output extensions among ``extensions`` applied, in ``stage`` order.

    ``values`` names at least their parameters (others are ignored), scalars or arrays that
    broadcast to the batch shape of ``signals``. Without output extensions the signals are
    returned unchanged.
    """
    outputs = tuple(e for e in extensions if not e.needs_resolve)
    if not outputs:
        return signals
    signals = jnp.asarray(signals)
    batch = signals.shape[:-2]
    flat = signals.reshape((-1, *signals.shape[-2:]))
    vals = {
        k: jnp.broadcast_to(jnp.asarray(v, dtype=signals.dtype), batch).reshape(-1)
        for e in outputs
        for k, v in e.full(values).items()
    }
    out = _apply_in_stage_order(outputs, flat, jnp.asarray(time, dtype=signals.dtype), vals)
    return out.reshape(signals.shape)


def unsynchronised_line(
    signals: Float[Array, "*channel time"], phase: Float[Array, " time"]
) -> Float[Array, "*channel time"]:
    """A unit line ``cos(phase + phi)`` per channel whose power adds to the signal's.

    A line from a source not synchronised with the system (the mains, an electrical supply)
    meets the system's own content at its frequency at a phase of chance: one record shows a
    cancellation, another a doubling. Its expectation over that phase is the sum of the two
    powers. The line returned carries that expectation: its phase ``phi`` puts it in
    quadrature with the channel's signal over the record (their inner product is zero):
    with ``A = sum s cos(phase)``, ``B = sum s sin(phase)``, the line is ``(B cos(phase) -
    A sin(phase)) / hypot(A, B)``; ``cos(phase)`` where the signal holds nothing at the
    line's frequency.
    """
    cos, sin = jnp.cos(phase), jnp.sin(phase)
    a = signals @ cos
    b = signals @ sin
    norm2 = a * a + b * b
    some = norm2 > 0.0
    scale = jnp.sqrt(jnp.where(some, norm2, 1.0))
    a_unit = jnp.where(some, a / scale, 0.0)
    b_unit = jnp.where(some, b / scale, 1.0)
    return b_unit[..., None] * cos - a_unit[..., None] * sin


class UnsynchronisedLines(AbstractExtension):
    """Lines at a supply frequency and its harmonics, each of chance phase (an output
    extension).

    An electrical supply (the mains, a motor's feed) is not synchronised with the machine:
    its lines at ``frequency_hz`` and its first ``harmonics`` multiples meet the machine's own
    content at a phase of chance, and each line carries the expectation over that phase, its
    power added to the signal's (:func:`unsynchronised_line`). A system's line extension
    states its parameters and how they weigh the unit lines (:meth:`weigh`: per channel, per
    harmonic); the lines, their phases and the checks of the configuration are these.

    Raises
    ------
    ValueError
        For a frequency outside :attr:`supply_frequencies_hz`, or harmonics outside 1 to
        the last one below the Nyquist frequency of :attr:`sampling_rate_hz`.
    """

    needs_resolve: ClassVar[bool] = False
    #: the frequencies the supply may have, Hz, and its name in messages
    supply_frequencies_hz: ClassVar[tuple[float, ...]] = (50.0, 60.0)
    supply: ClassVar[str] = "the supply"
    #: the sampling rate the lines are recorded at, Hz: the harmonics lie below its Nyquist
    sampling_rate_hz: ClassVar[float]

    if TYPE_CHECKING:  # fields of the subclass, in its own place among its fields
        frequency_hz: float
        harmonics: int

    def __check_init__(self):
        kind = type(self).__name__
        if self.frequency_hz not in self.supply_frequencies_hz:
            allowed = " or ".join(f"{f}" for f in self.supply_frequencies_hz)
            raise ValueError(
                f"{kind}.frequency_hz={self.frequency_hz!r}: {self.supply} is {allowed} Hz"
            )
        nyquist = self.sampling_rate_hz / 2.0
        top = int(nyquist // self.frequency_hz)
        if not 1 <= self.harmonics <= top:
            raise ValueError(
                f"{kind}.harmonics={self.harmonics!r} must be between 1 and {top} (the "
                f"harmonics below the Nyquist frequency {nyquist} Hz)"
            )

    @abc.abstractmethod
    def weigh(
        self,
        units: Sequence[Float[Array, "channel time"]],
        values: Mapping[str, Array],
        dtype,
    ) -> Float[Array, "channel time"]:
        """The lines added to a run's signals, from the unit line of each harmonic 1..H
        (``units[m - 1]``) and this extension's values by unprefixed name."""

    def apply(self, signals, time, values):
        phase = 2.0 * np.pi * self.frequency_hz * time.astype(signals.dtype)
        units = [unsynchronised_line(signals, phase)]
        units += [unsynchronised_line(signals, m * phase) for m in range(2, self.harmonics + 1)]
        return signals + self.weigh(units, self.local(values), signals.dtype)
