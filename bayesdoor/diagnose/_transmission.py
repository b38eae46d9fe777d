"""How a family of machines passes a cause to its sensors, against the model."""

from __future__ import annotations

import dataclasses

#: the smallest share of a machine's change that the model's change of the same cause must
#: explain, on every machine of a family, for the model to count as transmitting the cause
#: (below it the machine's change has another shape than the model's, and no scaling of a
#: model limit says what that machine would show)
RELIABLE_SHARE = 0.5


@dataclasses.dataclass(frozen=True)
class Transmission:
    """How a family of machines varied in ways the model lacks passes a cause to the sensors,
    against the model: per machine, the ratio of the model size whose change of the spectra
    best reproduces the machine's change to the size the machine carries
    (:func:`~bayesdoor.diagnose.read_transmission`), and the share of the machine's change
    that this model change explains.

    A machine with ratio ``r`` shows a cause of size ``s`` as the model shows ``r s``: a
    model limit ``L`` is ``L / r`` on it, and ``L / low`` on every machine of the family
    (the family limit).

    Attributes
    ----------
    low, high
        The smallest and largest ratio over the machines.
    explained
        The smallest share explained over the machines.
    machines
        How many machines were read.
    source
        Where the figures were measured (a result file and its command).
    """

    low: float
    high: float
    explained: float
    machines: int
    source: str = ""

    def __post_init__(self) -> None:
        if not (0.0 <= self.low <= self.high) or self.machines < 1:
            raise ValueError(
                f"Transmission: need 0 <= low <= high and at least one machine, got "
                f"low={self.low!r}, high={self.high!r}, machines={self.machines!r}"
            )

    @property
    def reliable(self) -> bool:
        """Whether every machine's change is the model's, scaled: a positive ratio and at
        least :data:`RELIABLE_SHARE` of its change explained on each."""
        return self.low > 0.0 and self.explained >= RELIABLE_SHARE

    @property
    def ratio(self) -> float | None:
        """The ratio a limit or a plan holds on every machine with: the smallest, where the
        transmission is reliable (``None``: no scaling of the model's says what a machine
        shows)."""
        return self.low if self.reliable else None

    def describe(self) -> str:
        """The family's transmission in words."""
        if not self.reliable:
            return (
                f"the model does not transmit it as the {self.machines} machines of its "
                f"family do (at worst {100 * self.explained:.0f} % of a machine's change "
                f"explained, ratio {self.low:.2g}-{self.high:.2g})"
            )
        return (
            f"the {self.machines} machines of its family show it as the model shows "
            f"{self.low:.2g}-{self.high:.2g} times the size"
        )
