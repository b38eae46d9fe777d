"""The population simulator of a fit: features of batches of parameter vectors at every
operating point, in padded vmapped chunks, and J of each."""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._cacheable import errors_as_nan
from .._exported import persistent_jit
from .._types import Array, Bool, Float, Int
from ..features import objective_j, segment_weights
from ..systems import AbstractSystem
from ._features import FeatureSpec, run_features
from ._likelihood import AbstractForward, CalibrationData, ForwardOutput
from ._surrogate import map_padded_chunks

#: candidates per vmapped simulation outside a fit (posterior predictive draws); a fit pads
#: every batch to a multiple of its first CMA-ES population, so one compilation serves it all
_CHUNK = 10

#: samples simulated past the end of the last Welch segment any run uses: the solver's last
#: step is clipped to the end of the record, so it must lie beyond every sample used (a step
#: is about 1 ms; 128 samples are 62.5 ms at 2048 Hz)
_HORIZON_MARGIN = 128


def simulation_horizon(
    system: AbstractSystem, data: CalibrationData, duration: float, spec: FeatureSpec
) -> float:
    """How long a record the features of ``data`` need simulated (s), at most ``duration``.

    The features average only the Welch segments that lie entirely inside a run's window (the
    system's motion window clipped to ``duration``), so the samples after the last such
    segment of any operating point never enter them. The horizon is the end of that segment
    plus :data:`_HORIZON_MARGIN` samples, so that the solver's last step, which is clipped to
    the end of the record, lies past every sample used and those come out as a full record
    gives them. On the demo campaign (0.3-0.5 m/s, 3.64 s records) it is 3.44 s.

    Parameters
    ----------
    system
        The simulated system.
    data
        The calibration features (their operating points).
    duration
        The record length the windows are clipped to (s).
    spec
        The feature definition (segment length and overlap).

    Returns
    -------
    horizon
        Seconds, a whole number of samples.
    """
    t_start, t_stop = system.motion_window(np.asarray(data.operating), duration=duration)
    fs = system.sampling_rate_hz
    n_time = round(duration * fs)
    used = np.asarray(
        segment_weights(
            n_time, fs, jnp.asarray(t_start), jnp.asarray(t_stop), spec.nperseg, spec.noverlap
        )
    ).any(axis=0)
    end = int(np.flatnonzero(used).max()) * spec.step + spec.nperseg if used.any() else n_time
    return min(n_time, end + _HORIZON_MARGIN) / fs


class _Population(eqx.Module):
    """Features of a batch of full parameter vectors at every operating point, simulated up
    to :func:`simulation_horizon`."""

    system: AbstractSystem
    operating: Float[Array, " op"]
    t_start: Float[Array, " op"]
    t_stop: Float[Array, " op"]
    horizon: float = eqx.field(static=True)
    spec: FeatureSpec

    @classmethod
    def build(
        cls, system: AbstractSystem, data: CalibrationData, duration: float, spec: FeatureSpec
    ) -> _Population:
        t_start, t_stop = system.motion_window(np.asarray(data.operating), duration=duration)
        horizon = simulation_horizon(system, data, duration, spec)
        # the simulations' features are traced without run-time checks (_simulate_chunk): a
        # window that holds no Welch segment is refused here, with the check's own words
        fs = system.sampling_rate_hz
        counts = np.asarray(
            segment_weights(
                round(horizon * fs),
                fs,
                jnp.asarray(t_start),
                jnp.asarray(t_stop),
                spec.nperseg,
                spec.noverlap,
            )
        ).sum(axis=-1)
        if np.any(counts < 1):
            bad = int(np.argmin(counts))
            raise ValueError(
                f"segment_weights sum to zero for operating point {bad}: no segment of "
                f"nperseg={spec.nperseg} lies inside its simulated motion window "
                f"[{float(np.ravel(t_start)[bad]):.3f}, {float(np.ravel(t_stop)[bad]):.3f}] s of "
                f"a {horizon:.3f} s record"
            )
        return cls(
            system,
            data.operating,
            jnp.asarray(t_start),
            jnp.asarray(t_stop),
            horizon,
            spec,
        )

    def __call__(
        self, x: Float[Array, "pop param"]
    ) -> tuple[Float[Array, "pop op channel band"], Bool[Array, " pop"]]:
        pop, n_op = x.shape[0], self.operating.shape[0]
        values = {p.name: jnp.repeat(x[:, i], n_op) for i, p in enumerate(self.system.parameters)}
        # every candidate at every operating point (a row for several conditions)
        reps = (pop,) + (1,) * (self.operating.ndim - 1)
        result = self.system.simulate_values(
            values,
            jnp.tile(self.operating, reps),
            state=self.system.healthy,
            duration=self.horizon,
            check=False,
        )
        features, _ = run_features(
            result.signals,
            self.system.sampling_rate_hz,
            jnp.tile(self.t_start, pop),
            jnp.tile(self.t_stop, pop),
            self.spec,
        )
        features = features.reshape(pop, n_op, *features.shape[1:])
        ok = jnp.all((result.status == 0).reshape(pop, n_op), axis=-1)
        return features, ok & jnp.all(jnp.isfinite(features), axis=(1, 2, 3))


@persistent_jit
def _simulate_chunk(
    population: _Population, x: Float[Array, "pop param"]
) -> tuple[Float[Array, "pop op channel band"], Bool[Array, " pop"]]:
    # traced without host callbacks, so that the program enters the persistent cache: a
    # check that fails gives NaN features, which ``ok`` reports as a failed simulation (the
    # windows are checked when the population is built)
    with errors_as_nan():
        return population(x)


def _simulate(
    population: _Population,
    x: Float[np.ndarray, "pop param"],
    chunk: int = _CHUNK,
    workers: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Features and success of any number of full parameter vectors, in padded chunks.

    Each chunk of ``chunk`` candidates is one vmapped simulation (the last padded by
    repeating its last row; one compilation per chunk size); ``workers`` threads run chunks
    at once. XLA runs one vmapped solve on one core and releases the GIL meanwhile, so two
    threads use both cores of a 2-core machine. The first call of a chunk size should run
    with one worker: threads that all miss the compilation cache each compile.
    """
    features, ok = map_padded_chunks(
        lambda padded: _simulate_chunk(population, jnp.asarray(padded)),
        x,
        chunk,
        workers,
        first_alone=False,
    )
    return features, ok


class _PartialForward(AbstractForward):
    """The population simulator as a forward model of some parameters, the rest held.

    The held values (for example the contact-law index) are traced, not static, so a fit per
    held value reuses one compilation of the vmapped simulation.
    """

    population: _Population
    names: tuple[str, ...] = eqx.field(static=True)
    operating: Float[Array, " op"]
    index: Int[Array, " param"]
    base: Float[Array, " full"]

    @classmethod
    def build(
        cls,
        system: AbstractSystem,
        population: _Population,
        names: Sequence[str],
        held: dict[str, float],
    ) -> _PartialForward:
        order = [p.name for p in system.parameters]
        base = _full(system, np.zeros(len(names)), names, held)[0]
        return cls(
            population=population,
            names=tuple(names),
            operating=population.operating,
            index=jnp.asarray([order.index(n) for n in names]),
            base=jnp.asarray(base),
        )

    def __call__(self, theta: Float[Array, " param"]) -> ForwardOutput:
        features, ok = self.population(self.base.at[self.index].set(theta)[None])
        return ForwardOutput(features[0], jnp.zeros_like(features[0]), ok[0])


def _j(features: np.ndarray, ok: np.ndarray, data: CalibrationData) -> np.ndarray:
    """The paper's J of each candidate, averaged over the runs; ``inf`` for a failed one."""
    sim = features[:, np.asarray(data.run_operating)]
    j = np.asarray(objective_j(jnp.asarray(sim), data.y[None])).mean(axis=-1)
    return np.where(ok & np.isfinite(j), j, np.inf)


def _full(
    system: AbstractSystem, x: np.ndarray, names: Sequence[str], fixed: dict[str, float]
) -> np.ndarray:
    """Full parameter vectors (the system's order) from the columns ``names`` and ``fixed``."""
    x = np.atleast_2d(x)
    columns = {n: x[:, i] for i, n in enumerate(names)}
    return np.stack(
        [
            columns[p.name] if p.name in columns else np.full(len(x), fixed[p.name])
            for p in system.parameters
        ],
        axis=-1,
    )
