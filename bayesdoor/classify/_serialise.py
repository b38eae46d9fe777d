"""Ensemble files: one JSON header line, then the array leaves (``eqx.tree_serialise_leaves``).

No pickle: the header is plain JSON and the leaves are numpy arrays in equinox's format, so a
file cannot run code when it is loaded.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import __version__
from ..io import atomic_write
from ._config import TrainConfig
from ._ensemble import Ensemble
from ._network import NetworkConfig, stacked_members
from ._ood import MahalanobisOOD

#: the ``format`` field of the header
FORMAT = "bayesdoor-ensemble"
#: the version of the layout written by :func:`save_ensemble`; files of another version are refused
FORMAT_VERSION = 1


def _header(ensemble: Ensemble) -> dict[str, Any]:
    ood = ensemble.ood
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "library_version": __version__,
        "architecture": ensemble.network.to_json(),
        "members": ensemble.n_members,
        "dtype": ensemble.dtype.name,
        "class_names": list(ensemble.class_names),
        "normalisation": {
            "mean": np.asarray(ensemble.mean, dtype=np.float64).tolist(),
            "scale": np.asarray(ensemble.scale, dtype=np.float64).tolist(),
        },
        "temperature": float(ensemble.temperature),
        "ood": None
        if ood is None
        else {
            "score": "mahalanobis",
            "threshold": float(ood.threshold),
            "quantile": ood.quantile,
            "features": int(ood.whitening.shape[0]),
            "model_error_draws": ood.model_error_draws,
        },
        "training": None if ensemble.train_config is None else ensemble.train_config.to_json(),
    }


def _leaves(ensemble: Ensemble) -> tuple[Any, ...]:
    ood = ensemble.ood
    return (ensemble.members,) if ood is None else (ensemble.members, ood.means, ood.whitening)


def save_ensemble(path: str | Path, ensemble: Ensemble, *, overwrite: bool = False) -> Path:
    """Write ``ensemble`` to one file, atomically.

    The first line is a JSON header (format and library versions, architecture, class names,
    input normalisation, temperature, OOD threshold, training settings); the rest are the
    member weights and the OOD detector's arrays in ``eqx.tree_serialise_leaves`` format.

    Parameters
    ----------
    path
        The file to write (conventionally ``*.eqx``).
    ensemble
        A trained ensemble.
    overwrite
        Replace an existing file.

    Returns
    -------
    path

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is false; nothing is written then.
    """
    header = json.dumps(_header(ensemble))

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            f.write((header + "\n").encode())
            eqx.tree_serialise_leaves(f, _leaves(ensemble))

    return atomic_write(Path(path), write, overwrite=overwrite)


def read_header(path: str | Path) -> dict[str, Any]:
    """The JSON header of an ensemble file, checked for format and version.

    Raises
    ------
    ValueError
        When the file is not an ensemble file, or was written in another format version.
    """
    path = Path(path)
    with open(path, "rb") as f:
        return _check_header(path, f.readline())


def _check_header(path: Path, line: bytes) -> dict[str, Any]:
    try:
        header = json.loads(line)
    except (UnicodeDecodeError, json.JSONDecodeError):
        header = None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise ValueError(
            f"{path} is not a bayesdoor ensemble file (its first line is not a JSON header with "
            f"format={FORMAT!r}): pass the file written by save_ensemble"
        )
    version = header.get("format_version")
    if version != FORMAT_VERSION:
        raise ValueError(
            f"{path} has ensemble format version {version!r} (written by bayesdoor "
            f"{header.get('library_version', '?')}), this bayesdoor {__version__} reads version "
            f"{FORMAT_VERSION}: retrain and save the ensemble with this version, or load it with "
            f"the bayesdoor version that wrote it"
        )
    return header


def load_ensemble(path: str | Path) -> Ensemble:
    """Read an ensemble written by :func:`save_ensemble`.

    Raises
    ------
    ValueError
        When the file is not an ensemble file, was written in another format version, or its
        weights are truncated or corrupted.
    """
    path = Path(path)
    with open(path, "rb") as f:
        header = _check_header(path, f.readline())
        dtype = jnp.dtype(header["dtype"])
        network = NetworkConfig.from_json(header["architecture"])
        # shapes and types only: the values come from the file
        members = eqx.filter_eval_shape(
            stacked_members, network, header["members"], dtype, jax.random.key(0)
        )
        ood = header["ood"]
        if ood is None:
            like: tuple[Any, ...] = (members,)
        else:
            d = ood["features"]
            like = (
                members,
                jax.ShapeDtypeStruct((network.n_classes, d), dtype),
                jax.ShapeDtypeStruct((d, d), dtype),
            )
        try:
            leaves = eqx.tree_deserialise_leaves(f, like)
        except Exception as err:  # equinox raises its own error type for a bad leaf
            raise ValueError(
                f"{path}: the weights after the header cannot be read ({err}): the file is "
                f"truncated or corrupted; save the ensemble again"
            ) from err
    norm = header["normalisation"]
    return Ensemble(
        members=leaves[0],
        mean=jnp.asarray(norm["mean"], dtype=dtype),
        scale=jnp.asarray(norm["scale"], dtype=dtype),
        temperature=jnp.asarray(header["temperature"], dtype=dtype),
        class_names=tuple(header["class_names"]),
        ood=None
        if ood is None
        else MahalanobisOOD(
            means=leaves[1],
            whitening=leaves[2],
            threshold=jnp.asarray(ood["threshold"], dtype=dtype),
            quantile=float(ood["quantile"]),
            model_error_draws=int(ood.get("model_error_draws", 0)),
        ),
        train_config=None if header["training"] is None else TrainConfig(**header["training"]),
    )
