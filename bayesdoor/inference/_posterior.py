"""Posterior samples as an ArviZ ``InferenceData``: pointwise log-likelihood, provenance, files."""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import platform
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import arviz as az
import jax
import numpy as np
import numpyro
import numpyro.distributions as dist
from numpyro.infer import init_to_sample

from ..io import atomic_write

#: groups every posterior written by bayesdoor holds (docs/inference.md, "Files")
POSTERIOR_GROUPS = ("posterior", "sample_stats", "log_likelihood", "observed_data")

#: arrays up to this size are recorded by value in the provenance attributes
_LISTED_SIZE = 64

_LIBRARIES = ("bayesdoor", "jax", "numpyro", "arviz", "emcee", "cma", "numpy", "xarray")


def _library_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for name in _LIBRARIES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def _digest(value: Any) -> Any:
    """A JSON-able stand-in for a setting or model argument.

    Small arrays (e.g. start values) are listed; larger ones (data) are represented by shape,
    dtype and content hash.
    """
    if isinstance(value, Mapping):
        return {str(k): _digest(v) for k, v in sorted(value.items(), key=lambda kv: str(kv[0]))}
    if isinstance(value, list | tuple):
        return [_digest(v) for v in value]
    if isinstance(value, str | bool | int | float) or value is None:
        return value
    if hasattr(value, "shape") and hasattr(value, "dtype"):
        array = np.ascontiguousarray(np.asarray(value))
        if array.size <= _LISTED_SIZE:
            return array.tolist()
        return {
            "shape": list(array.shape),
            "dtype": str(array.dtype),
            "sha256": hashlib.sha256(array.tobytes()).hexdigest(),
        }
    return repr(value)


def configuration_hash(
    model: Callable[..., Any],
    sampler: str,
    settings: Mapping[str, Any],
    model_kwargs: Mapping,
    observed: Mapping[str, Any] | None = None,
) -> str:
    """SHA-256 of what determines a posterior apart from the seed.

    The model is identified by its qualified name, the data by a content hash of every array
    argument and of every observed value (so data captured in a closure counts too), the
    sampler by its name and settings. Other constants a closure captures are covered only
    through the model's name. Two runs with the same hash and the same seed (stored next to
    it) give the same samples on the same library versions.

    Parameters
    ----------
    model
        The numpyro model function.
    sampler
        Sampler name, e.g. ``"nuts"``.
    settings
        The sampler's settings (JSON-able values).
    model_kwargs
        The model's keyword arguments (data and static configuration).
    observed
        The values of the model's observed sites.

    Returns
    -------
    hash
        64 hexadecimal characters.
    """
    config = {
        "model": f"{getattr(model, '__module__', '?')}.{getattr(model, '__qualname__', model)}",
        "sampler": sampler,
        "settings": _digest(dict(settings)),
        "model_kwargs": _digest(dict(model_kwargs)),
        "observed": _digest(dict(observed or {})),
    }
    return hashlib.sha256(json.dumps(config, sort_keys=True).encode()).hexdigest()


def model_sites(model: Callable[..., Any], model_kwargs: Mapping) -> dict[str, Any]:
    """One trace of the model (latent sites drawn anyhow): its sample sites by name."""
    traced = numpyro.handlers.substitute(
        numpyro.handlers.seed(model, jax.random.key(0)), substitute_fn=init_to_sample
    )
    trace = numpyro.handlers.trace(traced).get_trace(**model_kwargs)
    return {name: site for name, site in trace.items() if site["type"] == "sample"}


def _observed(model: Callable[..., Any], model_kwargs: Mapping) -> dict[str, np.ndarray]:
    """The observed data by site; ``numpyro.factor`` terms (``Unit`` sites) are not data."""
    return {
        name: np.asarray(s["value"])
        for name, s in model_sites(model, model_kwargs).items()
        if s["is_observed"] and not isinstance(s["fn"], dist.Unit)
    }


def _key_data(key: jax.Array) -> np.ndarray:
    """The integers behind a typed key (``jax.random.key``) or a raw one (``PRNGKey``)."""
    if jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key):
        return np.asarray(jax.random.key_data(key))
    return np.asarray(key)


def to_inference_data(
    model: Callable[..., Any],
    *,
    samples: Mapping[str, Any],
    sample_stats: Mapping[str, Any],
    model_kwargs: Mapping,
    sampler: str,
    settings: Mapping[str, Any],
    key: jax.Array,
    per_chain_stats: Mapping[str, Any] | None = None,
) -> az.InferenceData:
    """Assemble posterior draws of a numpyro model into an ArviZ ``InferenceData``.

    Both samplers go through here, so their outputs have the same layout: ``posterior``
    (constrained values, including deterministic sites), ``sample_stats``,
    ``log_likelihood`` (pointwise, from :func:`numpyro.infer.log_likelihood`, so PSIS-LOO
    works), ``observed_data`` and provenance attributes on every group.

    Parameters
    ----------
    model
        The numpyro model.
    samples
        Constrained draws by site, each with leading ``(chain, draw)`` dimensions.
    sample_stats
        Per-draw statistics, each ``(chain, draw)``.
    model_kwargs
        The model's keyword arguments used for sampling.
    sampler, settings
        Sampler name and settings, recorded as attributes and in the configuration hash.
    key
        The PRNG key the sampler was given (its data is recorded as the seed).
    per_chain_stats
        Statistics with one value per chain (e.g. emcee's acceptance fraction per walker),
        stored in ``sample_stats`` with the ``chain`` dimension only.

    Returns
    -------
    idata
        The assembled ``InferenceData``.
    """
    samples = {name: np.asarray(v) for name, v in samples.items()}
    chains, draws = next(iter(samples.values())).shape[:2]
    flat = {name: v.reshape((chains * draws, *v.shape[2:])) for name, v in samples.items()}
    observed = _observed(model, model_kwargs)
    pointwise = numpyro.infer.log_likelihood(model, flat, **model_kwargs)
    log_likelihood = {
        name: np.asarray(v).reshape((chains, draws, *v.shape[1:]))
        for name, v in pointwise.items()
        if name in observed
    }
    attrs = {
        "sampler": sampler,
        "settings": json.dumps(_digest(dict(settings)), sort_keys=True),
        "seed": json.dumps(_key_data(key).tolist()),
        "configuration_hash": configuration_hash(model, sampler, settings, model_kwargs, observed),
        "model": f"{getattr(model, '__module__', '?')}.{getattr(model, '__qualname__', model)}",
        "library_versions": json.dumps(_library_versions(), sort_keys=True),
        "inference_library": "numpyro" if sampler == "nuts" else sampler,
    }
    idata = az.from_dict(
        posterior=samples,
        sample_stats={name: np.asarray(v) for name, v in sample_stats.items()},
        log_likelihood=log_likelihood,
        observed_data=observed,
    )
    for name, value in (per_chain_stats or {}).items():
        idata.sample_stats[name] = ("chain", np.asarray(value))
    for group in idata.groups():
        idata[group].attrs.update(attrs)
    return idata


#: the provenance attribute holding the fitted system's description (JSON)
SYSTEM_ATTR = "system"


def record_system(idata: az.InferenceData, description: Mapping[str, Any]) -> None:
    """Record the fitted system's ``describe()`` on every group (attribute :data:`SYSTEM_ATTR`).

    An extended system (a model extension switched on, or held at values) has another
    description than the base one, so its posterior is never taken for the base model's.
    """
    text = json.dumps(dict(description), sort_keys=True)
    for group in idata.groups():
        idata[group].attrs[SYSTEM_ATTR] = text


def posterior_system(idata: az.InferenceData) -> dict[str, Any] | None:
    """The system description :func:`record_system` recorded (``None``: not recorded)."""
    text = idata["posterior"].attrs.get(SYSTEM_ATTR)
    return None if text is None else json.loads(text)


def save_posterior(idata: az.InferenceData, path: str | Path, *, overwrite: bool = False) -> Path:
    """Write a posterior to NetCDF atomically (a temporary file in the folder, then a rename).

    Parameters
    ----------
    idata
        The posterior, holding at least the groups ``posterior``, ``sample_stats``,
        ``log_likelihood`` and ``observed_data``.
    path
        Target file (``.nc``); its folder is created.
    overwrite
        Replace an existing file; otherwise an existing file is left untouched.

    Returns
    -------
    path
        The file written.

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is false (nothing is written).
    ValueError
        If a required group is missing from ``idata``.
    """
    path = Path(path)
    missing = [g for g in POSTERIOR_GROUPS if g not in idata.groups()]
    if missing:
        raise ValueError(
            f"the posterior lacks the group(s) {missing}; build it with sample_nuts or "
            "sample_emcee, which add every required group"
        )
    return atomic_write(path, lambda tmp: idata.to_netcdf(str(tmp)), overwrite=overwrite)


def load_posterior(path: str | Path) -> az.InferenceData:
    """Read a posterior written by :func:`save_posterior` into memory and check its groups.

    Parameters
    ----------
    path
        A NetCDF file.

    Returns
    -------
    idata
        The posterior, fully loaded (the file is closed afterwards).

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If one of the groups ``posterior``, ``sample_stats``, ``log_likelihood`` and
        ``observed_data`` is missing (not a bayesdoor posterior, or truncated).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no posterior file at {path}")
    with az.rc_context({"data.load": "eager"}):
        idata = az.from_netcdf(str(path))
    missing = [g for g in POSTERIOR_GROUPS if g not in idata.groups()]
    if missing:
        raise ValueError(
            f"{path} lacks the group(s) {missing} of a bayesdoor posterior (it has "
            f"{list(idata.groups())}); was it written by save_posterior?"
        )
    return idata
