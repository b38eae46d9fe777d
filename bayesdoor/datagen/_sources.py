"""Where the parameters of simulated training runs come from: a posterior or Gaussian scatter.

Every source is a frozen module with explicit keys: ``source.sample(n, key=key)`` returns one
array of ``n`` values per parameter name, and ``source.describe()`` a JSON-able description
(kind, names, settings and a digest of any sample arrays) that goes into the provenance of the
generated data and into its configuration hash.
"""

from __future__ import annotations

import abc
import hashlib
from collections.abc import Mapping, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._types import Array, Float
from ..systems import AbstractSystem


def _digest(arrays: Mapping[str, Any]) -> str:
    """SHA-256 of the names, shapes, dtypes and bytes of some arrays (for provenance)."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(np.asarray(arrays[name]))
        h.update(f"{name}|{a.shape}|{a.dtype.str}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _group_dataset(data: Any, group: str):
    """The xarray Dataset of one group of an ArviZ ``InferenceData`` or an xarray ``DataTree``."""
    try:
        node = data[group]
    except (KeyError, TypeError):
        raise ValueError(
            f"the inference data has no group {group!r}; pass an arviz.InferenceData or "
            "xarray.DataTree with that group, or a dict of sample arrays"
        ) from None
    return node.to_dataset() if hasattr(node, "to_dataset") else node


def _flat_draws(dataset, name: str) -> np.ndarray:
    """All (chain, draw) samples of one variable, flattened; extra dimensions are kept last."""
    if name not in dataset.data_vars:
        raise ValueError(
            f"the posterior has no variable {name!r}; it holds "
            f"{sorted(map(str, dataset.data_vars))}"
        )
    da = dataset[name]
    sample_dims = [d for d in ("chain", "draw") if d in da.dims]
    if not sample_dims:
        raise ValueError(f"posterior variable {name!r} has no chain/draw dimension: {da.dims}")
    other = [d for d in da.dims if d not in sample_dims]
    values = np.asarray(da.transpose(*sample_dims, *other).values, dtype=float)
    return values.reshape(-1, *values.shape[len(sample_dims) :])


class AbstractParameterSource(eqx.Module):
    """Draws of the system parameters for simulated training runs."""

    @property
    @abc.abstractmethod
    def names(self) -> tuple[str, ...]:
        """The parameter names of every draw."""

    @abc.abstractmethod
    def sample(self, n: int, *, key: Array) -> dict[str, Float[Array, " n"]]:
        """``n`` draws: one array of ``n`` values per name in :attr:`names`."""

    @abc.abstractmethod
    def describe(self) -> dict[str, Any]:
        """A JSON-able description for provenance (kind, settings, digest of its arrays)."""


class PosteriorDraws(AbstractParameterSource):
    """Joint draws, with replacement, from posterior samples of the parameters.

    A draw picks one posterior sample (one index into all parameter arrays at once), so the
    correlations of the posterior (K with n, for example) are kept. Parameters that the
    posterior holds fixed, such as a contact-law index chosen before sampling, are passed
    through unchanged in every draw.

    Parameters
    ----------
    samples
        One 1-D array of posterior samples per parameter name, all of the same length.
    fixed
        Values of the parameters that are not sampled.

    Examples
    --------
    >>> import jax, numpy as np
    >>> src = PosteriorDraws({"a": np.array([1.0, 2.0, 3.0])}, fixed={"b": 6.0})
    >>> draws = src.sample(4, key=jax.random.key(0))
    >>> sorted(draws), draws["b"].tolist()
    (['a', 'b'], [6.0, 6.0, 6.0, 6.0])
    """

    samples: dict[str, Float[Array, " sample"]]
    fixed: tuple[tuple[str, float], ...] = eqx.field(static=True)

    def __init__(
        self,
        samples: Mapping[str, Float[Array, " sample"] | np.ndarray],
        *,
        fixed: Mapping[str, float] | None = None,
    ):
        arrays = {str(k): np.asarray(v, dtype=float) for k, v in samples.items()}
        fixed = {} if fixed is None else {str(k): float(v) for k, v in fixed.items()}
        if not arrays:
            raise ValueError("samples is empty: pass at least one parameter's posterior samples")
        lengths = {k: v.shape for k, v in arrays.items()}
        if any(len(s) != 1 for s in lengths.values()) or len(set(lengths.values())) != 1:
            raise ValueError(
                f"samples must be 1-D arrays of one common length, got shapes {lengths}; "
                "flatten (chain, draw) first or use PosteriorDraws.from_inference_data"
            )
        if next(iter(arrays.values())).size == 0:
            raise ValueError("samples hold no draws: the posterior arrays are empty")
        bad = [k for k, v in arrays.items() if not np.all(np.isfinite(v))]
        if bad:
            raise ValueError(f"samples of {bad} contain non-finite values; drop those draws first")
        both = sorted(set(arrays) & set(fixed))
        if both:
            raise ValueError(f"{both} are both sampled and fixed: give each parameter once")
        self.samples = {k: jnp.asarray(v) for k, v in arrays.items()}
        self.fixed = tuple(sorted(fixed.items()))

    @classmethod
    def from_inference_data(
        cls,
        data: Any,
        names: Sequence[str],
        *,
        fixed: Mapping[str, float] | None = None,
        group: str = "posterior",
    ) -> PosteriorDraws:
        """Take the samples of ``names`` from an ArviZ ``InferenceData`` (or ``DataTree``).

        Parameters
        ----------
        data
            The inference data; its ``group`` holds variables with ``chain`` and ``draw``
            dimensions.
        names
            The sampled parameters to take (other variables such as model-error scales are
            ignored).
        fixed
            Values of the parameters that were not sampled (for example the contact-law index).
        group
            The group holding the samples.

        Raises
        ------
        ValueError
            For a missing group or variable, or a variable with dimensions beyond
            ``(chain, draw)``.
        """
        dataset = _group_dataset(data, group)
        samples = {}
        for name in names:
            values = _flat_draws(dataset, name)
            if values.ndim != 1:
                raise ValueError(
                    f"posterior variable {name!r} is not a scalar parameter (per-draw shape "
                    f"{values.shape[1:]}); pass scalar parameters only"
                )
            samples[name] = values
        return cls(samples, fixed=fixed)

    @property
    def names(self) -> tuple[str, ...]:
        return (*self.samples, *(k for k, _ in self.fixed))

    @property
    def n_samples(self) -> int:
        return int(next(iter(self.samples.values())).size)

    def sample(self, n: int, *, key: Array) -> dict[str, Float[Array, " n"]]:
        """``n`` joint draws with replacement (uniform over the posterior samples)."""
        index = jax.random.randint(key, (n,), 0, self.n_samples)
        draws = {k: v[index] for k, v in self.samples.items()}
        for k, value in self.fixed:
            draws[k] = jnp.full((n,), value)
        return draws

    def describe(self) -> dict[str, Any]:
        return {
            "kind": "PosteriorDraws",
            "sampled": list(self.samples),
            "fixed": dict(self.fixed),
            "n_samples": self.n_samples,
            "sha256": _digest({k: np.asarray(v) for k, v in self.samples.items()}),
        }


class GaussianScatter(AbstractParameterSource):
    """The paper's baseline: independent Gaussian scatter around a point, clipped to the bounds.

    Each parameter ``p`` is drawn as ``center[p] * (1 + relative_sd[p] * z)`` with ``z``
    standard normal, then clipped to ``[lower, upper]``; parameters with a relative sd of 0
    (integers such as the contact-law index) are passed through. Clipping piles a little
    probability on a bound when the centre lies near it; the draws are what the paper's
    "variation of 1-10 % around the optimal values" produces with the bounds enforced.

    Parameters
    ----------
    center
        The point (for example the CMA-ES optimum), one value per parameter.
    relative_sd
        Standard deviation as a fraction of ``|center|``, per parameter; 0 holds one fixed.
    bounds
        ``(lower, upper)`` per parameter; draws are clipped to them.

    References
    ----------
    "Real-time condition monitoring of mechanical systems using CNNs trained by multibody
    simulations", X ECCOMAS Thematic Conference on Smart Structures and Materials (SMART 2023),
    2023, section 4: "a variation of 1-10 % was added to the optimal parameter values, creating
    the Gaussian sampling pool"; ``docs/datagen.md``.
    """

    center: tuple[tuple[str, float], ...] = eqx.field(static=True)
    relative_sd: tuple[tuple[str, float], ...] = eqx.field(static=True)
    bounds: tuple[tuple[str, float, float], ...] = eqx.field(static=True)

    def __init__(
        self,
        center: Mapping[str, float],
        relative_sd: Mapping[str, float],
        bounds: Mapping[str, tuple[float, float]],
    ):
        names = list(center)
        for what, mapping in (("relative_sd", relative_sd), ("bounds", bounds)):
            if set(mapping) != set(names):
                raise ValueError(
                    f"{what} must name exactly the parameters of center {names}; missing "
                    f"{sorted(set(names) - set(mapping))}, unknown "
                    f"{sorted(set(mapping) - set(names))}"
                )
        for k in names:
            lo, hi = (float(b) for b in bounds[k])
            c, sd = float(center[k]), float(relative_sd[k])
            if not lo <= c <= hi:
                raise ValueError(f"center {k}={c!r} lies outside its bounds [{lo}, {hi}]")
            if not 0.0 <= sd < 1.0:
                raise ValueError(
                    f"relative_sd {k}={sd!r} must lie in [0, 1) (the paper uses 0.01-0.10)"
                )
        self.center = tuple((k, float(center[k])) for k in names)
        self.relative_sd = tuple((k, float(relative_sd[k])) for k in names)
        self.bounds = tuple((k, float(bounds[k][0]), float(bounds[k][1])) for k in names)

    @classmethod
    def around(
        cls,
        system: AbstractSystem,
        center: Mapping[str, float],
        relative_sd: float | Mapping[str, float] = 0.05,
    ) -> GaussianScatter:
        """Scatter around ``center`` within the system's parameter bounds.

        ``relative_sd`` is one fraction for every continuous parameter (default 5 %, the middle
        of the paper's 1-10 %) or one per parameter; integer parameters are held at their
        centre unless a mapping gives them a value.

        Raises
        ------
        ValueError
            When ``center`` does not name exactly the system's parameters.
        """
        specs = {p.name: p for p in system.parameters}
        if set(center) != set(specs):
            raise ValueError(
                f"center must give every parameter of {system.name}: missing "
                f"{sorted(set(specs) - set(center))}, unknown {sorted(set(center) - set(specs))}"
            )
        if isinstance(relative_sd, Mapping):
            sd = {k: float(relative_sd.get(k, 0.0)) for k in specs}
        else:
            sd = {k: 0.0 if p.integer else float(relative_sd) for k, p in specs.items()}
        return cls(
            {k: float(center[k]) for k in specs},
            sd,
            {k: (p.lower, p.upper) for k, p in specs.items()},
        )

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(k for k, _ in self.center)

    def sample(self, n: int, *, key: Array) -> dict[str, Float[Array, " n"]]:
        """``n`` independent draws (one standard-normal stream per parameter)."""
        z = jax.random.normal(key, (len(self.center), n))
        draws = {}
        for i, ((k, c), (_, sd), (_, lo, hi)) in enumerate(
            zip(self.center, self.relative_sd, self.bounds, strict=True)
        ):
            draws[k] = jnp.clip(c * (1.0 + sd * z[i]), lo, hi) if sd > 0 else jnp.full((n,), c)
        return draws

    def describe(self) -> dict[str, Any]:
        return {
            "kind": "GaussianScatter",
            "center": dict(self.center),
            "relative_sd": dict(self.relative_sd),
            "bounds": {k: [lo, hi] for k, lo, hi in self.bounds},
        }


class ModelErrorDraws(eqx.Module):
    """Offsets of the log-PSD features drawn from the posterior of the model-error scale.

    For each run one posterior sample of ``sigma`` is picked (with replacement) and an offset
    ``sigma * z`` (``z`` standard normal) is added to its features: one offset per channel,
    shared by all frequency bins (``per_bin=False``, a level error of the channel), or one per
    bin (``per_bin=True``).

    Parameters
    ----------
    sigma
        Posterior samples of the model-error scale, in log10 units of the features after
        multiplying by ``scale``: shape ``(sample,)`` (one scale), ``(sample, channel)`` or
        ``(sample, channel, freq)`` (then the frequency count must match the features).
    scale
        Factor taking ``sigma`` to log10 units (``1 / ln 10`` when the posterior's model error
        is in natural-log units).
    per_bin
        Independent offsets per frequency bin instead of one per channel.
    """

    sigma: Float[Array, "sample ..."]
    scale: float = eqx.field(static=True, default=1.0)
    per_bin: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        s = np.asarray(self.sigma)
        if s.ndim not in (1, 2, 3) or s.shape[0] == 0:
            raise ValueError(
                f"sigma must have shape (sample,), (sample, channel) or (sample, channel, freq), "
                f"got {s.shape}"
            )
        if not np.all(np.isfinite(s)) or np.any(s < 0):
            raise ValueError("sigma must hold finite, non-negative model-error scales")
        if not self.scale > 0:
            raise ValueError(f"scale must be positive, got {self.scale!r}")

    @classmethod
    def from_inference_data(
        cls,
        data: Any,
        name: str = "sigma_model",
        *,
        group: str = "posterior",
        scale: float = 1.0,
        per_bin: bool = False,
    ) -> ModelErrorDraws:
        """Take the samples of the model-error scale ``name`` from ArviZ inference data."""
        return cls(
            jnp.asarray(_flat_draws(_group_dataset(data, group), name)),
            scale=scale,
            per_bin=per_bin,
        )

    def sample(
        self, n: int, channels: int, freqs: int, *, key: Array
    ) -> Float[Array, "n channel freq"]:
        """Offsets for ``n`` runs with features of shape ``(channels, freqs)``.

        Raises
        ------
        ValueError
            When the shape of ``sigma`` does not fit the features.
        """
        s = self.sigma
        shape = s.shape[1:]
        if shape not in ((), (channels,), (channels, freqs)):
            raise ValueError(
                f"model-error sigma of per-sample shape {shape} does not fit features of shape "
                f"({channels}, {freqs}): give one scale, one per channel or one per bin"
            )
        k_index, k_z = jax.random.split(key)
        index = jax.random.randint(k_index, (n,), 0, s.shape[0])
        picked = s[index].reshape((n, *shape, *(1,) * (2 - len(shape))))
        if self.per_bin:
            z = jax.random.normal(k_z, (n, channels, freqs))
        else:
            z = jnp.broadcast_to(jax.random.normal(k_z, (n, channels, 1)), (n, channels, freqs))
        return self.scale * picked * z

    def describe(self) -> dict[str, Any]:
        return {
            "kind": "ModelErrorDraws",
            "shape": list(np.shape(self.sigma)),
            "scale": self.scale,
            "per_bin": self.per_bin,
            "sha256": _digest({"sigma": np.asarray(self.sigma)}),
        }
