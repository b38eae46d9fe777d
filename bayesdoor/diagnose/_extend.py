"""From a diagnosis to the extended system: the verdict's extension, as the refit configured it.

:func:`verdict_extension` recovers the model extension the diagnosis confirmed (its static
configuration, as the catalogue's recipe proposed it and the refit chose it) and the values
it fitted; :func:`extend_system` switches it on. The extension's parameters are either
left free (every layer then fits them from their bounds, like the system's own) or held at
the values the diagnosis fitted (:class:`HeldExtension`: the system's own parameters stay
free), which is what a downstream fit that starts from the middle of the bounds needs when
an extension adds a narrow resonance it would not find by itself.

The layer is generic: it knows the system by ``with_extensions``, ``parameters`` and the
calls of :class:`~bayesdoor.systems.AbstractSystem`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import TYPE_CHECKING

import equinox as eqx
import numpy as np

from .._types import Array, Float
from ..systems import AbstractSystem, SimulationResult
from ._rank import NONE
from ._refit import ExtensionProposal

if TYPE_CHECKING:
    from ._job import Diagnosis


@dataclasses.dataclass(frozen=True)
class VerdictExtension:
    """The extension a diagnosis confirmed, with the values its refit found.

    Attributes
    ----------
    name
        The verdict (a catalogue name).
    proposal
        The catalogue recipe's proposal the refit chose (its ``extension`` is what
        ``system.with_extensions`` accepts).
    values
        Every parameter of the extension by full name: the refitted mean of the free and
        held ones, the proposal's start (else the nominal value) of the others.
    """

    name: str
    proposal: ExtensionProposal
    values: dict[str, float]


def _band(diagnosis: Diagnosis) -> tuple[float, float]:
    """The analysed band, as the residual map's 1 Hz bins span it.

    The catalogue's recipes use the band only to count whole multiples of a frequency inside
    it (the mains harmonics), which the integer bins inside the band count alike.
    """
    freqs = np.asarray(diagnosis.features.residuals.freqs, dtype=float)
    return float(freqs.min()), float(freqs.max())


def verdict_extension(system: AbstractSystem, diagnosis: Diagnosis) -> VerdictExtension | None:
    """The model extension of a diagnosis's verdict, configured as its refit chose.

    The proposal the refit chose is the verdict cause's ``proposal``; for a cause without one
    (a diagnosis made before causes kept it) the catalogue's recipe is asked again for its
    proposals from the signature's estimate and the one whose configuration, in words, is the
    verdict's is taken.

    Parameters
    ----------
    system
        The base system the diagnosis was made on.
    diagnosis
        The outcome of :func:`~bayesdoor.diagnose.diagnose_campaign`.

    Returns
    -------
    VerdictExtension or None
        ``None`` for the verdict ``none``.

    Raises
    ------
    ValueError
        When the verdict has no refit recipe in the diagnosis's catalogue, or none of the
        recipe's proposals has the verdict's configuration (a diagnosis made with another
        catalogue, or edited by hand).
    """
    if diagnosis.verdict == NONE:
        return None
    cause = diagnosis.cause(diagnosis.verdict)
    candidate = {c.name: c for c in diagnosis.catalogue.candidates}.get(cause.name)
    if candidate is None or candidate.refit is None:
        raise ValueError(
            f"the verdict {cause.name!r} has no refit recipe in the diagnosis's catalogue "
            f"({', '.join(diagnosis.catalogue.names)}): diagnose with the catalogue whose "
            "recipes made the verdict"
        )
    if cause.proposal is not None:
        proposal = cause.proposal
    else:
        score = {s.name: s for s in diagnosis.ranking.causes}[cause.name]
        proposals = candidate.refit.propose(score.parameters, band=_band(diagnosis))
        chosen = [p for p in proposals if p.label == cause.label]
        if not chosen:
            raise ValueError(
                f"the verdict {cause.name!r} was refitted as {cause.label!r}, but its recipe "
                f"now proposes {[p.label for p in proposals]}: the diagnosis was made with "
                "another catalogue; diagnose the campaign again"
            )
        proposal = chosen[0]
    extended = system.with_extensions(proposal.extension)
    base = set(system.parameter_names())
    values = {}
    for spec in extended.parameters:
        if spec.name in base:
            continue
        fitted = cause.parameters.get(spec.name)
        if isinstance(fitted, Mapping):
            values[spec.name] = float(fitted["mean"])
        else:
            values[spec.name] = float(proposal.start.get(spec.name, spec.nominal))
    extended.check_parameters(values)
    return VerdictExtension(name=cause.name, proposal=proposal, values=values)


class HeldExtension(AbstractSystem):
    """A system whose model extension is held at fixed values; its own parameters stay free.

    :attr:`parameters` are those of ``system`` less the held ones, so fitting, data
    generation and classification see the base system's parameter space and simulate the
    extended model with the held values added to every call.

    Parameters
    ----------
    system
        The extended system (``base.with_extensions(...)``).
    held
        ``(name, value)`` of every held parameter (parameters of the extension, within their
        bounds).
    """

    system: AbstractSystem
    held: tuple[tuple[str, float], ...] = eqx.field(static=True, converter=tuple)

    def __check_init__(self):
        names = [n for n, _ in self.held]
        unknown = [n for n in names if n not in self.system.parameter_names()]
        if unknown:
            raise ValueError(
                f"HeldExtension.held names {unknown}, which are not parameters of "
                f"{self.system.name} (it has {', '.join(self.system.parameter_names())})"
            )
        self.system.check_parameters(dict(self.held))

    @property
    def held_values(self) -> dict[str, float]:
        return dict(self.held)

    @property
    def name(self) -> str:
        return self.system.name

    @property
    def parameters(self):
        held = self.held_values
        return tuple(p for p in self.system.parameters if p.name not in held)

    @property
    def states(self):
        return self.system.states

    @property
    def healthy(self) -> str:
        return self.system.healthy

    @property
    def channels(self) -> tuple[str, ...]:
        return self.system.channels

    @property
    def sampling_rate_hz(self) -> float:
        return self.system.sampling_rate_hz

    @property
    def conditions(self):
        return self.system.conditions

    @property
    def extension_names(self) -> tuple[str, ...]:
        return self.system.extension_names

    def simulate(self, theta, damage, operating, *, duration: float | None = None):
        """One run of the wrapped system with the held values as its ``extension_values``."""
        return self.system.simulate(  # type: ignore[call-arg]
            theta, damage, operating, duration=duration, extension_values=self.held_values
        )

    def record_duration(self, operating) -> float:
        return self.system.record_duration(operating)

    # what the wrapped system says of itself beyond the core: its features, the points its
    # training data are simulated at, its signature check and its catalogue (the base
    # class's defaults would silently replace them)

    @property
    def features(self):
        return self.system.features

    def training_points(self, points: np.ndarray) -> np.ndarray:
        return self.system.training_points(points)

    def signature_reference(self, signals, operating) -> dict | None:
        return self.system.signature_reference(signals, operating)

    def signatures(self, reference, signals, operating):
        return self.system.signatures(reference, signals, operating)

    @property
    def catalogue(self):
        return self.system.catalogue

    def simulate_gains(self, values, operating, gains, *, duration=None, check=True):
        """The wrapped system's :meth:`simulate_gains` with the held values added."""
        return self.system.simulate_gains(
            {**dict(values), **self.held_values},
            operating,
            gains,
            duration=duration,
            check=check,
        )

    def motion_window(self, operating, *, duration: float | None = None):
        return self.system.motion_window(operating, duration=duration)

    def simulate_values(
        self,
        values: Mapping[str, Float[Array, "*batch"] | float],
        operating: Float[Array, " batch"] | float,
        *,
        state: str | None = None,
        severity: Mapping[str, Float[Array, "*batch"] | float] | None = None,
        duration: float | None = None,
        check: bool = True,
    ) -> SimulationResult:
        """The wrapped system's runs with the held values added to ``values`` (``state``
        ``None``: its healthy state)."""
        clash = [n for n in values if n in self.held_values]
        if clash:
            raise ValueError(
                f"values name the held parameters {clash}: they are held at "
                f"{[self.held_values[n] for n in clash]}; pass the free parameters only"
            )
        return self.system.simulate_values(
            {**dict(values), **self.held_values},
            operating,
            state=self.healthy if state is None else state,
            severity=severity,
            duration=duration,
            check=check,
        )

    def with_extensions(self, *extensions) -> HeldExtension:
        """The wrapped system with more extensions (free), the held values still held."""
        return HeldExtension(self.system.with_extensions(*extensions), self.held)

    def without_output_extensions(self) -> HeldExtension:
        """The wrapped system's :meth:`without_output_extensions`, holding what remains held."""
        inner = self.system.without_output_extensions()
        kept = tuple((n, v) for n, v in self.held if n in inner.parameter_names())
        return HeldExtension(inner, kept)

    def apply_output_extensions(self, signals, time, values):
        """The wrapped system's output extensions, the held values added to ``values``."""
        return self.system.apply_output_extensions(
            signals, time, {**dict(values), **self.held_values}
        )

    def describe(self) -> dict:
        """The wrapped system's description with the held values."""
        return {**self.system.describe(), "held": self.held_values}


def extend_system(
    system: AbstractSystem, diagnosis: Diagnosis, *, hold: bool = True
) -> AbstractSystem:
    """The system with the diagnosis's verdict switched on as its refit configured it.

    Parameters
    ----------
    system
        The base system the diagnosis was made on.
    diagnosis
        The outcome of :func:`~bayesdoor.diagnose.diagnose_campaign`.
    hold
        Hold the extension's parameters at the values the diagnosis fitted
        (:class:`HeldExtension`); ``False``: leave them free, from their bounds, for the
        next fit.

    Returns
    -------
    AbstractSystem
        ``system`` itself for the verdict ``none``.

    Raises
    ------
    ValueError
        See :func:`verdict_extension`.

    Examples
    --------
    >>> extended = extend_system(ElevatorDoor(), diagnosis)  # doctest: +SKIP
    >>> run_job(extended, campaign, "out/extended")  # doctest: +SKIP
    """
    found = verdict_extension(system, diagnosis)
    if found is None:
        return system
    extended = system.with_extensions(found.proposal.extension)
    if not hold:
        return extended
    return HeldExtension(extended, tuple(sorted(found.values.items())))
