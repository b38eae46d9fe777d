"""The nine hysteresis-damping contact laws: the eight of the paper's Table 1 plus Hu and Guo.

All share F = K d^n + chi d^n d_dot with chi = xi(c_r) K / d_dot_minus; they differ only in the
hysteresis factor xi(c_r). References are given per class; `docs/model.md` tabulates them.
"""

from __future__ import annotations

import abc
import numbers
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..._types import Array, Float, Int


class AbstractContactLaw(eqx.Module):
    """A continuous contact law of the Hunt-Crossley family, identified by its hysteresis factor.

    Concrete laws are final and carry their paper index (1-9), a snake-case name and a reference.
    """

    index: ClassVar[int]
    name: ClassVar[str]
    reference: ClassVar[str]
    formula: ClassVar[str]

    @staticmethod
    @abc.abstractmethod
    def hysteresis_factor(c_r: Float[Array, "*batch"]) -> Float[Array, "*batch"]:
        """The dimensionless factor xi(c_r) in chi = xi K / d_dot_minus."""

    def force(
        self,
        d: Float[Array, "*batch"],
        d_dot: Float[Array, "*batch"],
        d_dot_minus: Float[Array, "*batch"],
        K: Float[Array, "*batch"],
        n: Float[Array, "*batch"],
        c_r: Float[Array, "*batch"],
    ) -> Float[Array, "*batch"]:
        """Contact force for indentation ``d`` (>= 0) and rate ``d_dot`` (raw, unsmoothed).

        This is the textbook law, used for hand checks; the door model uses
        :func:`smooth_contact_force`, which agrees with it away from first contact.
        """
        xi = self.hysteresis_factor(c_r)
        d = jnp.maximum(d, 0.0)
        dn = jnp.where(d > 0, jnp.exp(n * jnp.log(jnp.where(d > 0, d, 1.0))), 0.0)
        return K * dn + xi * K / d_dot_minus * dn * d_dot


class GharibHurmuzlu(AbstractContactLaw):
    """Gharib and Hurmuzlu (2012), J. Appl. Mech. 79(6) 064506: xi = (1 - c_r)/c_r."""

    index: ClassVar[int] = 1
    name: ClassVar[str] = "gharib_hurmuzlu"
    reference: ClassVar[str] = "Gharib & Hurmuzlu (2012), J. Appl. Mech. 79, 064506"
    formula: ClassVar[str] = "(1 - c_r) / c_r"

    @staticmethod
    def hysteresis_factor(c_r):
        return (1.0 - c_r) / c_r


class HerbertMcWhannell(AbstractContactLaw):
    """Herbert and McWhannell (1977), J. Eng. Ind. 99(3) 513-518."""

    index: ClassVar[int] = 2
    name: ClassVar[str] = "herbert_mcwhannell"
    reference: ClassVar[str] = "Herbert & McWhannell (1977), J. Eng. Ind. 99, 513-518"
    formula: ClassVar[str] = "6 (1 - c_r) / ((2 c_r - 1)^2 + 3)"

    @staticmethod
    def hysteresis_factor(c_r):
        return 6.0 * (1.0 - c_r) / ((2.0 * c_r - 1.0) ** 2 + 3.0)


class FloresEtAl(AbstractContactLaw):
    """Flores, Machado, Silva and Martins (2011), Multibody Syst. Dyn. 25, 357-375."""

    index: ClassVar[int] = 3
    name: ClassVar[str] = "flores"
    reference: ClassVar[str] = "Flores et al. (2011), Multibody Syst. Dyn. 25, 357-375"
    formula: ClassVar[str] = "8 (1 - c_r) / (5 c_r)"

    @staticmethod
    def hysteresis_factor(c_r):
        return 8.0 * (1.0 - c_r) / (5.0 * c_r)


class LeeWang(AbstractContactLaw):
    """Lee and Wang (1983), J. Mech. Transm. Autom. Des. 105(3) 534-540."""

    index: ClassVar[int] = 4
    name: ClassVar[str] = "lee_wang"
    reference: ClassVar[str] = "Lee & Wang (1983), J. Mech. Transm. Autom. Des. 105, 534-540"
    formula: ClassVar[str] = "3 (1 - c_r) / 4"

    @staticmethod
    def hysteresis_factor(c_r):
        return 0.75 * (1.0 - c_r)


class HuntCrossley(AbstractContactLaw):
    """Hunt and Crossley (1975), J. Appl. Mech. 42(2) 440-445."""

    index: ClassVar[int] = 5
    name: ClassVar[str] = "hunt_crossley"
    reference: ClassVar[str] = "Hunt & Crossley (1975), J. Appl. Mech. 42, 440-445"
    formula: ClassVar[str] = "3 (1 - c_r) / 2"

    @staticmethod
    def hysteresis_factor(c_r):
        return 1.5 * (1.0 - c_r)


class LankaraniNikravesh(AbstractContactLaw):
    """Lankarani and Nikravesh (1990), J. Mech. Des. 112(3) 369-376."""

    index: ClassVar[int] = 6
    name: ClassVar[str] = "lankarani_nikravesh"
    reference: ClassVar[str] = "Lankarani & Nikravesh (1990), J. Mech. Des. 112, 369-376"
    formula: ClassVar[str] = "3 (1 - c_r^2) / 4"

    @staticmethod
    def hysteresis_factor(c_r):
        return 0.75 * (1.0 - c_r**2)


class ZhiyingQishao(AbstractContactLaw):
    """Qin Zhiying and Lu Qishao (2006), J. Dyn. Control 4(4) 294-298 (in Chinese).

    Cited in the contact literature by the authors' given names, "Zhiying and Qishao".
    """

    index: ClassVar[int] = 7
    name: ClassVar[str] = "zhiying_qishao"
    reference: ClassVar[str] = "Zhiying & Qishao (2006), J. Dyn. Control 4(4), 294-298"
    formula: ClassVar[str] = "3 (1 - c_r^2) exp(2 (1 - c_r)) / 4"

    @staticmethod
    def hysteresis_factor(c_r):
        return 0.75 * (1.0 - c_r**2) * jnp.exp(2.0 * (1.0 - c_r))


class GonthierEtAl(AbstractContactLaw):
    """Gonthier, McPhee, Lange and Piedboeuf (2004), Multibody Syst. Dyn. 11, 209-233."""

    index: ClassVar[int] = 8
    name: ClassVar[str] = "gonthier"
    reference: ClassVar[str] = "Gonthier et al. (2004), Multibody Syst. Dyn. 11, 209-233"
    formula: ClassVar[str] = "(1 - c_r^2) / c_r"

    @staticmethod
    def hysteresis_factor(c_r):
        return (1.0 - c_r**2) / c_r


class HuGuo(AbstractContactLaw):
    """Hu and Guo (2015), Multibody Syst. Dyn. 35(2) 131-151."""

    index: ClassVar[int] = 9
    name: ClassVar[str] = "hu_guo"
    reference: ClassVar[str] = "Hu & Guo (2015), Multibody Syst. Dyn. 35, 131-151"
    formula: ClassVar[str] = "3 (1 - c_r) / (2 c_r)"

    @staticmethod
    def hysteresis_factor(c_r):
        return 1.5 * (1.0 - c_r) / c_r


CONTACT_LAWS: tuple[type[AbstractContactLaw], ...] = (
    GharibHurmuzlu,
    HerbertMcWhannell,
    FloresEtAl,
    LeeWang,
    HuntCrossley,
    LankaraniNikravesh,
    ZhiyingQishao,
    GonthierEtAl,
    HuGuo,
)
LAW_NAMES: tuple[str, ...] = tuple(law.name for law in CONTACT_LAWS)


def get_law(law: int | str | AbstractContactLaw | type[AbstractContactLaw]) -> AbstractContactLaw:
    """Return the contact law for a paper index (1-9), a name, a law class or a law instance.

    Raises
    ------
    ValueError
        For an index outside 1-9 or an unknown name; the message lists the allowed values.
    """
    if isinstance(law, AbstractContactLaw):
        return law
    if isinstance(law, type) and law in CONTACT_LAWS:
        return law()
    if isinstance(law, bool | np.bool_):
        raise ValueError(f"contact law must be an index 1-9 or a name, got {law!r}")
    # numbers.Integral also admits numpy integers, e.g. an index read from an array
    if isinstance(law, numbers.Integral):
        if not 1 <= law <= len(CONTACT_LAWS):
            raise ValueError(
                f"contact law index {law} is out of range: allowed 1-{len(CONTACT_LAWS)} "
                f"({', '.join(f'{i}={n}' for i, n in enumerate(LAW_NAMES, 1))})"
            )
        return CONTACT_LAWS[int(law) - 1]()
    if isinstance(law, str):
        key = law.strip().lower().replace("-", "_").replace(" ", "_")
        if key.isdigit():
            return get_law(int(key))
        for cls in CONTACT_LAWS:
            if key == cls.name:
                return cls()
        raise ValueError(
            f"unknown contact law {law!r}: allowed names are {', '.join(LAW_NAMES)} "
            f"(or an index 1-{len(CONTACT_LAWS)})"
        )
    raise ValueError(f"contact law must be an index 1-9 or a name, got {type(law).__name__}")


def hysteresis_factor(
    law_index: Int[Array, "*batch"] | int, c_r: Float[Array, "*batch"]
) -> Float[Array, "*batch"]:
    """xi(c_r) for a (possibly traced, batched) law index 1-9.

    All nine factors are evaluated and one is selected, so the index can be a traced integer:
    this is what lets CMA-ES evaluate a population of mixed laws as one vmapped batch.
    ``law_index`` and ``c_r`` broadcast against each other. A traced index cannot raise, so one
    outside 1-9 is clipped to the nearest law; check concrete indices with :func:`get_law`.
    """
    c_r = jnp.asarray(c_r)
    idx = jnp.clip(jnp.asarray(law_index) - 1, 0, len(CONTACT_LAWS) - 1).astype(jnp.int32)
    shape = jnp.broadcast_shapes(idx.shape, c_r.shape)
    c_r = jnp.broadcast_to(c_r, shape)
    all_xi = jnp.stack([law.hysteresis_factor(c_r) for law in CONTACT_LAWS], axis=0)
    return jnp.take_along_axis(all_xi, jnp.broadcast_to(idx, shape)[None], axis=0)[0]
