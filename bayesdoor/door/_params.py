"""Parameters and damage modes of the reference door (the paper's Table 2; ``docs/model.md``)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .._types import Array, Float, Int
from ..systems import DamageSpec, ParameterSpec

PARAMETERS: tuple[ParameterSpec, ...] = (
    ParameterSpec(
        "K",
        "N/mm^n",
        1475.0,
        1300.0,
        2500.0,
        "wheel-rail contact stiffness",
        reference_value=1863.0,
    ),
    ParameterSpec("n", "-", 1.50, 1.50, 2.20, "contact exponent", reference_value=1.93),
    ParameterSpec("c_r", "-", 0.70, 0.60, 0.95, "coefficient of restitution", reference_value=0.69),
    ParameterSpec(
        "I",
        "-",
        1,
        1,
        9,
        "contact-law index (paper's Table 1 order)",
        integer=True,
        reference_value=6,
    ),
    ParameterSpec(
        "mu_s", "-", 0.80, 0.70, 0.85, "static friction coefficient", reference_value=0.78
    ),
    ParameterSpec(
        "mu_d", "-", 0.76, 0.60, 0.80, "dynamic friction coefficient", reference_value=0.77
    ),
    ParameterSpec("C", "-", 0.010, 0.005, 0.020, "frame damping ratio", reference_value=0.018),
    ParameterSpec("MF", "-", 1.0, 1.0, 2.0, "mass factor of the panel", reference_value=1.0),
)
CONTINUOUS_PARAMETERS = tuple(p.name for p in PARAMETERS if not p.integer)

STATES: dict[str, DamageSpec] = {
    "healthy": DamageSpec("healthy", "no damage"),
    "D1": DamageSpec(
        "D1",
        "debris in the bottom rail: two raised-cosine bumps (8 mm base) on the +X groove wall "
        "at 0.25 m and 0.55 m of travel",
        {"d1_height": (0.6e-3, 1.5e-3)},
    ),
    "D2": DamageSpec(
        "D2",
        "flat on the top right wheel: raised-cosine radius reduction over 20 degrees, "
        "at an arbitrary angular position",
        {"d2_depth": (0.05e-3, 0.3e-3), "d2_angle": (0.0, 6.283185307179586)},
    ),
}


class DoorParameters(eqx.Module):
    """The updatable door parameters (the paper's Table 2); K in N/mm^n as in the paper.

    Fields may be scalars or arrays with a common batch shape (vmapped simulation).
    """

    K: Float[Array, "*batch"]
    n: Float[Array, "*batch"]
    c_r: Float[Array, "*batch"]
    I: Int[Array, "*batch"]
    mu_s: Float[Array, "*batch"]
    mu_d: Float[Array, "*batch"]
    C: Float[Array, "*batch"]
    MF: Float[Array, "*batch"]

    @classmethod
    def nominal(cls) -> DoorParameters:
        return cls.from_dict({p.name: p.nominal for p in PARAMETERS})

    @classmethod
    def paper_optimum(cls) -> DoorParameters:
        """The CMA-ES optimum reported in the paper's Table 2."""
        return cls.from_dict({p.name: p.reference_value for p in PARAMETERS})

    @classmethod
    def from_dict(cls, values, *, check: bool = True) -> DoorParameters:
        """Build from a mapping of all eight Table 2 names; checks bounds unless told not to."""
        missing = [p.name for p in PARAMETERS if p.name not in values]
        unknown = [k for k in values if k not in {p.name for p in PARAMETERS}]
        if missing or unknown:
            raise ValueError(
                f"door parameters need exactly {', '.join(p.name for p in PARAMETERS)}; "
                f"missing {missing or 'none'}, unknown {unknown or 'none'}"
            )
        if check:
            check_parameter_values(values)
        kw = {
            p.name: jnp.asarray(values[p.name], dtype=jnp.int32 if p.integer else float)
            for p in PARAMETERS
        }
        return cls(**kw)

    def to_dict(self) -> dict[str, Array]:
        return {p.name: getattr(self, p.name) for p in PARAMETERS}


def check_parameter_values(values) -> None:
    """Raise ``ValueError`` naming the first out-of-range value (arrays are checked elementwise)."""
    import numpy as np

    specs = {p.name: p for p in PARAMETERS}
    for name, value in values.items():
        arr = np.atleast_1d(np.asarray(value, dtype=float))
        spec = specs[name]
        for v in arr:
            spec.check(v)


class DoorDamage(eqx.Module):
    """Damage severities of one run (zero means absent), all in SI units.

    ``d1_height``: debris bump height (m); ``d2_depth``: wheel flat depth (m); ``d2_angle``:
    angular position of the flat on the wheel (rad) at the closed position.
    """

    d1_height: Float[Array, "*batch"]
    d2_depth: Float[Array, "*batch"]
    d2_angle: Float[Array, "*batch"]

    @classmethod
    def healthy(cls) -> DoorDamage:
        return cls(jnp.asarray(0.0), jnp.asarray(0.0), jnp.asarray(0.0))

    @classmethod
    def for_state(cls, state: str, **severity: float) -> DoorDamage:
        """Damage of a named state with the given severities (defaults: mid-range of the prior).

        Raises
        ------
        ValueError
            For an unknown state, unknown severity names or severities outside their range.
        """
        if state not in STATES:
            raise ValueError(f"unknown state {state!r}: allowed {', '.join(STATES)}")
        spec = STATES[state]
        unknown = [k for k in severity if k not in spec.severity]
        if unknown:
            raise ValueError(
                f"state {state} takes severities {list(spec.severity) or 'none'}, got {unknown}"
            )
        values = {"d1_height": 0.0, "d2_depth": 0.0, "d2_angle": 0.0}
        for k, (lo, hi) in spec.severity.items():
            v = float(severity.get(k, 0.5 * (lo + hi)))
            if not lo <= v <= hi:
                raise ValueError(f"{state} severity {k}={v!r} is outside [{lo}, {hi}]")
            values[k] = v
        return cls(**{k: jnp.asarray(v) for k, v in values.items()})
