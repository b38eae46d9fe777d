"""One chunk of simulated training runs: draws, solve, redraws of failed runs, features.

A chunk is a pure function of the job (system, sources, configuration, key) and its index:
its key is ``fold_in(chunk_key, index)``, so chunks can be computed in any order, on any
worker, and restarted, always giving the same arrays.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import numpy as np

from .._types import Array
from ..systems import AbstractSystem
from ._config import GenerationConfig
from ._features import featurize
from ._sources import AbstractParameterSource, ModelErrorDraws


class Job(eqx.Module):
    """Everything a chunk depends on; shipped as one object to Dask workers."""

    system: AbstractSystem
    source: AbstractParameterSource
    model_error: ModelErrorDraws | None
    config: GenerationConfig = eqx.field(static=True)
    key: Array
    x64: bool = eqx.field(static=True)

    @property
    def states(self) -> tuple[str, ...]:
        return self.config.states if self.config.states is not None else tuple(self.system.states)

    @property
    def n_chunks(self) -> int:
        return len(self.states) * self.config.chunks_per_state

    @property
    def duration(self) -> float:
        return self.config.record_duration(self.system)

    @property
    def simulated_duration(self) -> float:
        return self.config.simulated_duration(self.system)

    def chunk_runs(self, index: int) -> tuple[int, np.ndarray]:
        """The state index and the global run ids of chunk ``index``."""
        state, part = divmod(index, self.config.chunks_per_state)
        first = part * self.config.chunk_size
        last = min(first + self.config.chunk_size, self.config.runs_per_state)
        return state, state * self.config.runs_per_state + np.arange(first, last)


def validation_mask(job: Job, state: int) -> np.ndarray:
    """Which of a state's runs (by position within the state) are held out for validation.

    Exactly ``config.validation_per_state`` of them, chosen by a permutation from the job's
    split key, so the split is stratified and independent of the chunking.
    """
    split_key = jax.random.fold_in(jax.random.split(job.key)[1], state)
    order = np.asarray(jax.random.permutation(split_key, job.config.runs_per_state))
    mask = np.zeros(job.config.runs_per_state, dtype=bool)
    mask[order[: job.config.validation_per_state]] = True
    return mask


def _draw(job: Job, state: str, key: Array) -> dict[str, Any]:
    """Parameters, severities and operating points (``speed``: numbers, or rows for several
    conditions) for one full chunk (``chunk_size`` runs)."""
    n = job.config.chunk_size
    k_param, k_sev, k_speed = jax.random.split(key, 3)
    params = {k: np.asarray(v, dtype=float) for k, v in job.source.sample(n, key=k_param).items()}
    prior = job.system.states[state].severity
    u = np.asarray(jax.random.uniform(k_sev, (len(prior), n)))
    severity = {k: lo + (hi - lo) * u[i] for i, (k, (lo, hi)) in enumerate(prior.items())}
    speeds = np.asarray(job.config.speeds)[
        np.asarray(jax.random.randint(k_speed, (n,), 0, len(job.config.speeds)))
    ]
    return {"parameters": params, "severity": severity, "speed": speeds}


def check_draws(job: Job, parameters: dict[str, np.ndarray]) -> None:
    """Raise ``ValueError`` when a source's draws leave the system's parameter bounds."""
    for spec in job.system.parameters:
        v = parameters[spec.name]
        bad = ~((v >= spec.lower) & (v <= spec.upper))
        if spec.integer:
            bad |= v != np.round(v)
        if bad.any():
            raise ValueError(
                f"the parameter source drew {spec.name}={float(v[bad][0])!r} ({int(bad.sum())} of "
                f"{v.size} draws) outside [{spec.lower}, {spec.upper}]"
                f"{' or not an integer' if spec.integer else ''}: (a) the posterior samples lie "
                "outside the system's bounds (a different parameterisation?), (b) a fixed value "
                "is wrong; clip or fix the source"
            )


def _simulate(job: Job, state: str, draws: dict[str, Any]):
    check_draws(job, draws["parameters"])
    result = job.system.simulate_values(
        draws["parameters"],
        draws["speed"],
        state=state,
        severity=draws["severity"],
        duration=job.simulated_duration,
    )
    return np.asarray(result.signals), np.asarray(result.status)


def _select(mask: np.ndarray, new: dict[str, Any], old: dict[str, Any]) -> dict[str, Any]:
    """``new`` where ``mask`` (one flag per run, the first axis), else ``old``; an operating
    point of several conditions is a row and is taken whole."""

    def pick(a, b):
        return np.where(mask.reshape(mask.shape + (1,) * (np.ndim(a) - 1)), a, b)

    return jax.tree_util.tree_map(pick, new, old)


def compute_chunk(job: Job, index: int) -> dict[str, np.ndarray]:
    """The arrays of chunk ``index`` (see :func:`generate` for the names).

    Failed solves are redrawn from ``fold_in(redraw_key, round)`` (a full chunk of fresh
    draws per round, so the solve keeps its compiled shape) and dropped after
    ``config.max_redraws`` rounds, or at once with ``on_failure="drop"``.
    """
    config = job.config
    state_index, run_ids = job.chunk_runs(index)
    state = job.states[state_index]
    n = run_ids.size
    chunk_key = jax.random.fold_in(jax.random.split(job.key)[0], index)
    k_draw, k_error, k_redraw = jax.random.split(chunk_key, 3)

    draws = _draw(job, state, k_draw)
    signals, status = _simulate(job, state, draws)
    redraws = np.zeros(config.chunk_size, dtype=np.int64)
    rounds = config.max_redraws if config.on_failure == "redraw" else 0
    for attempt in range(1, rounds + 1):
        failed = status[:n] != 0
        if not failed.any():
            break
        failed = np.concatenate([failed, np.zeros(config.chunk_size - n, dtype=bool)])
        fresh = _draw(job, state, jax.random.fold_in(k_redraw, attempt))
        fresh_signals, fresh_status = _simulate(job, state, fresh)
        draws = _select(failed, fresh, draws)
        signals = np.where(failed[:, None, None], fresh_signals, signals)
        status = np.where(failed, fresh_status, status)
        redraws = np.where(failed, attempt, redraws)

    fs = job.system.sampling_rate_hz
    t_start, t_stop = job.system.motion_window(draws["speed"], duration=job.duration)
    features = np.asarray(featurize(signals, fs, t_start, t_stop, spec=config.spec))
    if job.model_error is None:
        offsets = np.zeros_like(features)
    else:
        offsets = np.asarray(
            job.model_error.sample(config.chunk_size, *features.shape[1:], key=k_error)
        )
    kept = status[:n] == 0
    validation = validation_mask(job, state_index)[run_ids - state_index * config.runs_per_state]
    arrays = {
        "run_id": run_ids[kept],
        "label": np.full(int(kept.sum()), state_index, dtype=np.int64),
        "validation": validation[kept],
        "speed": draws["speed"][:n][kept],
        "t_start": np.asarray(t_start)[:n][kept],
        "t_stop": np.asarray(t_stop)[:n][kept],
        "features": (features + offsets)[:n][kept],
        "model_error": offsets[:n][kept],
        "redraws": redraws[:n][kept],
        "dropped_run_id": run_ids[~kept],
        "dropped_status": status[:n][~kept],
    }
    for name in job.system.parameter_names():
        arrays[f"parameter/{name}"] = draws["parameters"][name][:n][kept]
    for spec in job.system.states.values():
        for name in spec.severity:
            values = draws["severity"].get(name, np.full(config.chunk_size, np.nan))
            arrays.setdefault(f"severity/{name}", values[:n][kept])
    return arrays


def run_chunk(job: Job, index: int) -> tuple[int, dict[str, np.ndarray]]:
    """:func:`compute_chunk` under the job's float64 setting (the Dask workers' entry point)."""
    with jax.enable_x64(job.x64):
        return index, compute_chunk(job, index)
