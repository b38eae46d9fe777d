"""The optional base of a system that hosts model extensions from a catalogue.

A system whose discrepancy catalogue names model extensions (a structural mode, a line, a
sensor's cross-axis leak) switches them on with :meth:`ExtensionHost.with_extensions`: the
extensions' parameters follow the model's own, output extensions act on signals simulated once
(:meth:`ExtensionHost.apply_output_extensions`), and the configuration hashes describe them
alike. A system without extensions derives from :class:`~bayesdoor.systems.AbstractSystem`
directly.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Mapping
from typing import TYPE_CHECKING, ClassVar

from .._types import Array, Float
from ._base import AbstractSystem, ParameterSpec
from ._extensions import AbstractExtension, apply_output_extensions, build_extension


class ExtensionHost(AbstractSystem):
    """A system with a catalogue of model extensions, at most one of each switched on.

    A subclass declares the field ``extensions`` (a tuple of its extension modules, default
    none: the base model), :attr:`base_parameters`, and the class variables
    :attr:`extension_base` (the class its extensions derive from), :attr:`extension_classes`
    (the extension class of every catalogue name) and :attr:`extension_owner` (the system in
    words, for messages).

    Raises
    ------
    ValueError
        When built with an extension that is not an :attr:`extension_base`, or with one
        extension twice.
    """

    if TYPE_CHECKING:  # a field of the subclass, in its own place among its fields
        extensions: tuple[AbstractExtension, ...]
    #: the class the system's extensions derive from
    extension_base: ClassVar[type]
    #: the extension class of every catalogue name (``none``, the base model, has none)
    extension_classes: ClassVar[Mapping[str, type[AbstractExtension]]]
    #: the system in words, for messages (``"the door"``)
    extension_owner: ClassVar[str]

    def __check_init__(self):
        kind = type(self).__name__
        for e in self.extensions:
            if not isinstance(e, self.extension_base):
                raise ValueError(
                    f"{kind}.extensions holds {e!r}, not a model extension of "
                    f"{self.extension_owner} ({', '.join(self.extension_classes)}): pass "
                    f"catalogue names to {kind}().with_extensions(...)"
                )
        names = [e.name for e in self.extensions]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(
                f"{kind}.extensions holds {twice} more than once: at most one of each "
                "catalogue extension"
            )

    @property
    @abc.abstractmethod
    def base_parameters(self) -> tuple[ParameterSpec, ...]:
        """The model's own parameters, without any extension's."""

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        """:attr:`base_parameters`, then each extension's (``"<extension>.<quantity>"``)."""
        return self.base_parameters + tuple(p for e in self.extensions for p in e.parameters)

    @property
    def extension_names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.extensions)

    @property
    def output_extensions(self) -> tuple[AbstractExtension, ...]:
        """The extensions that act on the sensor signals only (no new solve to refit them)."""
        return tuple(e for e in self.extensions if not e.needs_resolve)

    def extension(self, name_or_module: str | AbstractExtension, **config) -> AbstractExtension:
        """The extension of a catalogue name (default configuration, or ``config``), or the
        module (:func:`~bayesdoor.systems.build_extension`)."""
        return build_extension(
            name_or_module, self.extension_classes, self.extension_owner, **config
        )

    def with_extensions(self, *extensions: str | AbstractExtension):
        """This system with more extensions switched on: catalogue names or built modules."""
        added = tuple(self.extension(e) for e in extensions)
        return dataclasses.replace(self, extensions=self.extensions + added)

    def without_output_extensions(self):
        """This system with only the extensions that act inside the simulation (its "base
        signals")."""
        kept = tuple(e for e in self.extensions if e.needs_resolve)
        return dataclasses.replace(self, extensions=kept)

    def apply_output_extensions(
        self,
        signals: Float[Array, "*batch channel time"],
        time: Float[Array, " time"],
        values: Mapping[str, Float[Array, "*batch"] | float],
    ) -> Float[Array, "*batch channel time"]:
        """Signals of :meth:`without_output_extensions` with the output extensions applied,
        in their ``stage`` order whatever the order they were switched on in; ``values``
        names at least their parameters (others are ignored), scalars or arrays that
        broadcast to the batch shape of ``signals``. Bounds are not checked (use
        :meth:`check_parameters`)."""
        return apply_output_extensions(self.extensions, signals, time, values)

    def extension_records(self) -> list[dict]:
        """Every extension switched on: its name, configuration and parameters (JSON-able),
        for :meth:`describe`."""
        return [
            {
                "name": e.name,
                "config": {f.name: getattr(e, f.name) for f in dataclasses.fields(e)},
                "parameters": [p.name for p in e.parameters],
            }
            for e in self.extensions
        ]
