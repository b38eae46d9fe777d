"""Posterior sampling of one numpyro model with NUTS (numpyro) or the affine-invariant ensemble
sampler (emcee), both returning the same ArviZ layout."""

from __future__ import annotations

import dataclasses
import functools
import json
import sys
import warnings
from collections.abc import Callable, Mapping
from typing import Any, Protocol, TypeVar, cast

import arviz as az
import emcee
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from numpyro.infer import MCMC, NUTS, init_to_median, init_to_value
from numpyro.infer.util import initialize_model

from ._posterior import model_sites, to_inference_data

_F = TypeVar("_F", bound=Callable[..., Any])

_NUTS_FIELDS = (
    "diverging",
    "energy",
    "num_steps",
    "adapt_state.step_size",
    "potential_energy",
    "accept_prob",
)


def _standard_promotion(sampler: _F) -> _F:
    """Run a sampler under JAX's standard dtype promotion.

    numpyro's kernels mix integer and float arrays (e.g. the mean acceptance over a tree's
    proposals), which the strict promotion the tests enable refuses; the setting is confined
    to the sampler's own calls.
    """

    @functools.wraps(sampler)
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        with jax.numpy_dtype_promotion("standard"):
            return sampler(*args, **kwargs)

    return cast(_F, wrapped)


def _show_progress(progress: bool) -> bool:
    """Whether to draw a progress bar: asked for, and standard error is a terminal or this is
    a Jupyter kernel (whose standard error is no terminal but draws the bars in place).

    numpyro's and emcee's bars are tqdm bars on standard error, redrawn in place with carriage
    returns; written to a file or a pipe (CI, ``bayesdoor demo > log 2>&1``) every redraw
    stays, thousands of lines per run.
    """
    isatty = getattr(sys.stderr, "isatty", None)
    terminal = callable(isatty) and bool(isatty())
    return progress and (terminal or "ipykernel" in sys.modules)


def _init_strategy(
    model: Callable[..., Any], model_kwargs: Mapping[str, Any], init_values: Mapping | None
):
    """``init_to_value`` for the given sites (checked against the model), else the median."""
    if init_values is None:
        return init_to_median()
    latent = [n for n, s in model_sites(model, model_kwargs).items() if not s["is_observed"]]
    unknown = sorted(set(init_values) - set(latent))
    if unknown:
        # numpyro would silently start such sites elsewhere
        raise ValueError(
            f"init_values names {unknown}, which are not latent sample sites of the model; "
            f"its latent sites are {latent}"
        )
    return init_to_value(values={name: jnp.asarray(v) for name, v in init_values.items()})


def _positive(name: str, value: int, minimum: int = 1) -> None:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ValueError(f"{name}={value!r} must be an integer >= {minimum}")


class _IndependentEnsembles(emcee.moves.StretchMove):
    """The stretch move on ``n_ensembles`` independent ensembles that step in lockstep.

    Walkers ``k W .. (k + 1) W - 1`` form ensemble ``k``. As in emcee's red-blue move, each
    ensemble is split at random into two halves, and a walker's stretch partner is drawn from
    the other half of its own ensemble only, so the ensembles never interact: each is an
    exact emcee ensemble, while one call of the vectorised log density serves the moving
    halves of all of them.
    """

    def __init__(self, n_ensembles: int, a: float = 2.0):
        super().__init__(a=a)
        self.n_ensembles = n_ensembles

    def propose(self, model, state):
        n_walkers = state.coords.shape[0]
        per = n_walkers // self.n_ensembles
        ensemble = np.arange(n_walkers) // per
        half = np.concatenate([model.random.permutation(per) % 2 for _ in range(self.n_ensembles)])
        accepted = np.zeros(n_walkers, dtype=bool)
        for split in (0, 1):
            moving = half == split
            proposals, factors = zip(
                *(
                    self.get_proposal(
                        state.coords[moving & (ensemble == k)],
                        [state.coords[~moving & (ensemble == k)]],
                        model.random,
                    )
                    for k in range(self.n_ensembles)
                ),
                strict=True,
            )
            q = np.concatenate(proposals)  # walker order: ensembles are contiguous blocks
            log_prob, blobs = model.compute_log_prob_fn(q)
            log_ratio = np.concatenate(factors) + log_prob - state.log_prob[moving]
            accepted[moving] = log_ratio > np.log(model.random.rand(q.shape[0]))
            state = self.update(
                state, emcee.State(q, log_prob=log_prob, blobs=blobs), accepted, moving
            )
        return state, accepted


# ---------------------------------------------------------------------------------------------
# one interface: a sampler is its settings, and one call samples a model's posterior


class _Sampler(Protocol):
    """A posterior sampler of a numpyro model: its settings fixed, one call returns the draws
    of the model's sites and the sampler's statistics as :class:`arviz.InferenceData`
    (``posterior``, ``sample_stats``, ``log_likelihood``, ``observed_data``)."""

    def sample(
        self,
        model: Callable[..., Any],
        *,
        key: jax.Array,
        init_values: Mapping[str, Any] | None,
        progress: bool,
        model_kwargs: Mapping[str, Any] | None = None,
    ) -> az.InferenceData: ...


# ---------------------------------------------------------------------------------------------
# NUTS (numpyro)


@dataclasses.dataclass(frozen=True)
class NUTSSettings:
    """The settings of :func:`sample_nuts`, checked; ``sample`` runs NUTS with them.

    Attributes
    ----------
    num_warmup, num_samples
        Warm-up (adaptation) and kept iterations per chain.
    num_chains
        Number of chains.
    dense_mass
        Adapt a dense mass matrix (for strongly correlated parameters) instead of a diagonal.
    target_accept
        Target acceptance probability of the step-size adaptation; raise it (e.g. 0.95) when
        there are divergences.
    max_tree_depth
        Maximum tree depth (at most ``2**max_tree_depth - 1`` leapfrog steps per draw).
    chain_method
        ``"vectorized"`` (chains vmapped in one program) or ``"sequential"``.
    jit_model_args
        Pass ``model_kwargs`` to the compiled sampler as arguments rather than constants
        (numpyro's ``jit_model_args``), so fits of many data sets of one shape compile once
        and share the persistent compilation cache (simulation-based calibration); every
        keyword argument must then be an array.

    Raises
    ------
    ValueError
        If a count, ``target_accept`` or ``chain_method`` is invalid.
    """

    num_warmup: int = 1000
    num_samples: int = 1000
    num_chains: int = 4
    dense_mass: bool = False
    target_accept: float = 0.8
    max_tree_depth: int = 10
    chain_method: str = "vectorized"
    jit_model_args: bool = False

    def __post_init__(self) -> None:
        for name, value in (("num_samples", self.num_samples), ("num_chains", self.num_chains)):
            _positive(name, value)
        _positive("num_warmup", self.num_warmup, 0)
        _positive("max_tree_depth", self.max_tree_depth)
        if not 0.0 < self.target_accept < 1.0:
            raise ValueError(
                f"target_accept={self.target_accept} must lie in (0, 1), e.g. 0.8 or 0.95"
            )
        if self.chain_method not in ("vectorized", "sequential"):
            raise ValueError(
                f"chain_method={self.chain_method!r}: use 'vectorized' or 'sequential' "
                "(one CPU device)"
            )

    @_standard_promotion
    def sample(
        self,
        model: Callable[..., Any],
        *,
        key: jax.Array,
        init_values: Mapping[str, Any] | None,
        progress: bool,
        model_kwargs: Mapping[str, Any] | None = None,
    ) -> az.InferenceData:
        """Run numpyro's :class:`~numpyro.infer.MCMC` with NUTS, see :func:`sample_nuts`."""
        model_kwargs = dict(model_kwargs or {})
        kernel = NUTS(
            model,
            init_strategy=_init_strategy(model, model_kwargs, init_values),
            dense_mass=self.dense_mass,
            target_accept_prob=self.target_accept,
            max_tree_depth=self.max_tree_depth,
        )
        mcmc = MCMC(
            kernel,
            num_warmup=self.num_warmup,
            num_samples=self.num_samples,
            num_chains=self.num_chains,
            chain_method=self.chain_method,
            progress_bar=_show_progress(progress),
            jit_model_args=self.jit_model_args,
        )
        mcmc.run(key, extra_fields=_NUTS_FIELDS, **model_kwargs)
        settings = {
            **dataclasses.asdict(self),
            "init_values": dict(init_values) if init_values is not None else None,
        }
        return to_inference_data(
            model,
            samples=mcmc.get_samples(group_by_chain=True),
            sample_stats=_nuts_stats(mcmc.get_extra_fields(group_by_chain=True)),
            model_kwargs=model_kwargs,
            sampler="nuts",
            settings=settings,
            key=key,
        )


def _nuts_stats(fields: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """ArviZ's ``sample_stats`` of NUTS from numpyro's extra fields (:data:`_NUTS_FIELDS`)."""
    fields = {k: np.asarray(v) for k, v in fields.items()}
    return {
        "diverging": fields["diverging"].astype(bool),
        "energy": fields["energy"],
        # a full tree of depth d takes 2**d - 1 leapfrog steps
        "tree_depth": np.floor(np.log2(np.maximum(fields["num_steps"], 1))).astype(int) + 1,
        "n_steps": fields["num_steps"],
        "step_size": fields["adapt_state.step_size"],
        "lp": -fields["potential_energy"],
        "acceptance_rate": fields["accept_prob"],
    }


def sample_nuts(
    model: Callable[..., Any],
    *,
    key: jax.Array,
    model_kwargs: Mapping[str, Any] | None = None,
    init_values: Mapping[str, Any] | None = None,
    settings: NUTSSettings = NUTSSettings(),
    progress: bool = True,
) -> az.InferenceData:
    """Sample a numpyro model's posterior with NUTS.

    Parameters
    ----------
    model
        A numpyro model (priors and an observed likelihood), called as
        ``model(**model_kwargs)``.
    key
        PRNG key (``jax.random.key(seed)``).
    model_kwargs
        Keyword arguments of the model (data, static configuration).
    init_values
        Constrained start values by site, e.g. a CMA-ES optimum (``init_to_value``; every
        chain starts there and warm-up separates them). ``None``: the prior median.
    settings
        Warm-up, samples, chains, mass matrix, step-size target, tree depth and how the
        chains run (:class:`NUTSSettings`).
    progress
        Show numpyro's progress bar, when standard error is a terminal.

    Returns
    -------
    idata
        ``posterior``, ``sample_stats`` (``diverging``, ``energy``, ``tree_depth``,
        ``step_size``, ``lp``, ``n_steps``, ``acceptance_rate``), ``log_likelihood``,
        ``observed_data`` and provenance attributes.

    References
    ----------
    M. D. Hoffman and A. Gelman, "The No-U-Turn Sampler", JMLR 15 (2014).
    """
    return settings.sample(
        model, key=key, init_values=init_values, progress=progress, model_kwargs=model_kwargs
    )


# ---------------------------------------------------------------------------------------------
# emcee: independent ensembles on the unconstrained space

#: draws mapped back to constrained values per compiled call: the jitted ``postprocess_fn``
#: is compiled once for this batch size, so memory stays bounded whatever the run length
_CONVERT_CHUNK = 4096


#: the stopping checks of an adaptive emcee run estimate tau on at most about this many
#: steps (emcee's estimate on 192 walkers x 16000 steps x 23 dimensions takes about 10 s)
_CHECK_ROWS = 2000


def _constrained_draws(
    postprocess: Callable[[jax.Array], Mapping[str, jax.Array]],
    flat: np.ndarray,
    chunk: int = _CONVERT_CHUNK,
) -> dict[str, np.ndarray]:
    """``vmap(postprocess)(flat)`` jitted, in batches of ``chunk`` draws, as NumPy arrays.

    An un-jitted ``vmap`` of numpyro's ``postprocess_fn`` materialises every intermediate of
    the model (the likelihood's included) for all draws at once, tens of kB per draw; jitted,
    XLA drops what the constrained values do not need, and the batches bound what is left.
    The last batch is padded with copies of its last draw, so one program serves every batch.
    """
    total = flat.shape[0]
    size = min(chunk, total)
    convert = jax.jit(jax.vmap(postprocess))
    pieces: list[dict[str, np.ndarray]] = []
    for begin in range(0, total, size):
        block = flat[begin : begin + size]
        filled = block.shape[0]
        if filled < size:
            block = np.concatenate([block, np.repeat(block[-1:], size - filled, axis=0)])
        out = convert(jnp.asarray(block))
        pieces.append({name: np.asarray(v)[:filled] for name, v in out.items()})
    return {name: np.concatenate([p[name] for p in pieces]) for name in pieces[0]}


def _run_length_reached(
    tau: np.ndarray, previous: np.ndarray | None, kept: int, lengths: float, tolerance: float
) -> bool:
    """emcee's stopping rule: kept steps >= ``lengths`` x every tau, and tau settled."""
    if previous is None or not np.all(np.isfinite(tau)) or not np.all(tau > 0):
        return False
    settled = np.all(np.abs(previous - tau) / tau < tolerance)
    return bool(kept >= lengths * np.max(tau) and settled)


@dataclasses.dataclass(frozen=True)
class _Unconstrained:
    """A numpyro model on its unconstrained space, as one flat vector: the start point, the
    log density of a batch of walkers and the map of one point back to the constrained sites
    (deterministic sites included)."""

    z0: jax.Array
    log_density: Callable[[np.ndarray], np.ndarray]
    constrain: Callable[[jax.Array], Mapping[str, jax.Array]]

    @classmethod
    def of(
        cls,
        model: Callable[..., Any],
        model_kwargs: Mapping[str, Any],
        init_values: Mapping[str, Any] | None,
        key: jax.Array,
    ) -> _Unconstrained:
        """numpyro's ``potential_fn`` and ``postprocess_fn`` of ``model``, started at
        ``init_values`` (else the prior median). The log density is ``-potential_fn`` (priors,
        likelihood and the Jacobians of the transforms), jitted and vmapped over walkers, in
        float64; a NaN (a failed simulation) is ``-inf``, so emcee rejects the proposal."""
        info = initialize_model(
            key,
            model,
            init_strategy=_init_strategy(model, model_kwargs, init_values),
            model_kwargs=model_kwargs,
        )
        z0, unravel = ravel_pytree(info.param_info.z)
        batched = jax.jit(jax.vmap(lambda z: -info.potential_fn(unravel(z))))

        def log_density(walkers: np.ndarray) -> np.ndarray:
            lp = np.asarray(batched(jnp.asarray(walkers, dtype=z0.dtype)), dtype=np.float64)
            return np.where(np.isnan(lp), -np.inf, lp)

        return cls(z0, log_density, lambda z: info.postprocess_fn(unravel(z)))

    @property
    def ndim(self) -> int:
        """The number of unconstrained dimensions."""
        return int(self.z0.size)


def _walkers_per_ensemble(n_walkers: int | None, ndim: int) -> int:
    """``n_walkers``, checked against the fewest the stretch move needs in ``ndim``
    dimensions (``2 * ndim + 2``); ``None``: that fewest."""
    fewest = 2 * ndim + 2
    if n_walkers is None:
        return fewest
    if isinstance(n_walkers, bool) or not isinstance(n_walkers, int | np.integer):
        raise ValueError(f"n_walkers={n_walkers!r} must be an integer >= {fewest}, or None")
    if n_walkers < fewest:
        raise ValueError(
            f"n_walkers={n_walkers} is too few for {ndim} unconstrained dimensions: the stretch "
            f"move needs at least 2 * ndim + 2 = {fewest} walkers per ensemble (each half must "
            f"span every direction); pass n_walkers >= {fewest}, or None for {fewest}"
        )
    return n_walkers


def _initial_walkers(
    space: _Unconstrained,
    total: int,
    init_scale: float,
    key_start: jax.Array,
    key_numpy: jax.Array,
) -> emcee.State:
    """emcee's start state: ``total`` walkers drawn (``key_start``) from a Gaussian ball of
    standard deviation ``init_scale`` around the start point, their log densities, and the
    state of NumPy's generator that emcee's moves draw from, seeded by ``key_numpy``.

    Raises
    ------
    ValueError
        If a walker starts at a non-finite log density.
    """
    z0 = space.z0
    start = jax.random.normal(key_start, (total, space.ndim), z0.dtype)
    walkers = np.asarray(z0 + init_scale * start)
    lp0 = space.log_density(walkers)
    if not np.all(np.isfinite(lp0)):
        raise ValueError(
            f"{int(np.sum(~np.isfinite(lp0)))} of {total} walkers start with a non-finite "
            f"log density (init_scale={init_scale}): (a) start closer to the posterior mode "
            "(e.g. a CMA-ES optimum), (b) shrink init_scale, (c) check the model at init_values"
        )
    seed = int(jax.random.randint(key_numpy, (), 0, np.iinfo(np.int32).max))
    return emcee.State(walkers, log_prob=lp0, random_state=np.random.RandomState(seed).get_state())


def _autocorr_time(sampler: emcee.EnsembleSampler, burn: int) -> np.ndarray:
    """emcee's integrated autocorrelation time of every unconstrained coordinate on the
    steps after ``burn``, in steps; NaN for a run too short to estimate it."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return sampler.get_autocorr_time(discard=burn, tol=0)


def _thinning(thin: int | None, tau: np.ndarray) -> int:
    """The thinning interval: ``thin``, or for ``None`` emcee's recipe ``max(1, min(tau) //
    2)`` (1 when tau could not be estimated)."""
    if thin is not None:
        return thin
    if np.all(np.isfinite(tau)):
        return max(1, int(np.min(tau)) // 2)
    return 1


@dataclasses.dataclass(frozen=True)
class _EmceeRun:
    """A finished emcee run: the sampler with its chain, the space it ran on, the walkers per
    ensemble, the autocorrelation time per coordinate and why it stopped."""

    sampler: emcee.EnsembleSampler
    space: _Unconstrained
    n_walkers: int
    tau: np.ndarray
    stopped: str


@dataclasses.dataclass(frozen=True)
class EmceeSettings:
    """The settings of :func:`sample_emcee`, checked; ``sample`` runs the ensembles with them.

    The run length is adaptive by default (``n_steps=None``), as emcee's documentation
    recommends: the ensembles advance in blocks of ``check_every`` steps (emcee's own
    ``sample``, continuing from the last state); after each block emcee's integrated
    autocorrelation time ``tau`` of every unconstrained coordinate is estimated on the
    steps after ``burn``, and the run stops once those steps number at least
    ``min_autocorr_lengths`` times the largest ``tau`` and no ``tau`` moved by
    ``tau_tolerance`` (relative) since the previous block (the checks thin long chains
    to about 2000 steps for speed; a stop is confirmed on the full chain), or at
    ``max_steps``. A run that
    the cap stops short of that length warns, and fails the length gate of
    :func:`diagnose_sampling`. The blocks do not change the draws: a run that stops after
    ``N`` steps equals a run of ``n_steps=N`` with the same key.

    Attributes
    ----------
    n_walkers
        Walkers per ensemble, at least ``2 * ndim + 2`` for ``ndim`` unconstrained
        dimensions: a walker's stretch partner comes from the other half of its ensemble,
        whose ``n_walkers / 2`` walkers must span all ``ndim`` directions (an affine hull of
        dimension ``n_walkers / 2 - 1``). ``None``: exactly that. In the output each walker is
        a ``chain``, as in ``arviz.from_emcee``, ensemble by ensemble.
    n_ensembles
        Independent ensembles (at least 2 for the nested R-hat of :func:`diagnose_sampling`;
        1 is a single emcee ensemble, whose R-hat is taken over walkers).
    n_steps
        Ensemble steps, including the burn-in, for a run of fixed length; ``None``: the
        adaptive length described above.
    max_steps
        Adaptive runs: the most ensemble steps, including the burn-in.
    check_every
        Adaptive runs: steps between two estimates of the autocorrelation time.
    min_autocorr_lengths
        Adaptive runs: steps after the burn-in, in autocorrelation times, at which the run
        may stop (emcee's documentation recommends 50; :func:`diagnose_sampling`'s gate).
    tau_tolerance
        Adaptive runs: the largest relative change of every ``tau`` between two checks at
        which the run may stop (emcee's documentation uses 1 %).
    burn
        Steps discarded at the start.
    thin
        Keep every ``thin``-th step after the burn-in; ``None``: every ``max(1, min(tau) //
        2)``-th, emcee's documented choice, which keeps nearly all the effective samples
        of the fastest coordinate in a fraction of the draws (the pointwise log-likelihood
        is stored for every draw: 960 features x 8 bytes each on the door's demo fit). The
        autocorrelation time is estimated on every step.
    init_scale
        Standard deviation of the start ball in unconstrained coordinates.

    Raises
    ------
    ValueError
        If a count is invalid.
    """

    n_walkers: int | None = None
    n_ensembles: int = 4
    n_steps: int | None = None
    max_steps: int = 40000
    check_every: int = 500
    min_autocorr_lengths: float = 50.0
    tau_tolerance: float = 0.01
    burn: int = 1000
    thin: int | None = 1
    init_scale: float = 1e-2

    def __post_init__(self) -> None:
        _positive(self._length_name, self._length)
        _positive("n_ensembles", self.n_ensembles)
        _positive("check_every", self.check_every)
        _positive("burn", self.burn, 0)
        if self.thin is not None:
            _positive("thin", self.thin)
        if self.burn >= self._length:
            raise ValueError(
                f"burn={self.burn} must be smaller than {self._length_name}={self._length}"
            )
        if not self.init_scale > 0:
            raise ValueError(f"init_scale={self.init_scale} must be positive, e.g. 1e-2")
        if not self.min_autocorr_lengths > 0 or not 0 < self.tau_tolerance < 1:
            raise ValueError(
                f"min_autocorr_lengths={self.min_autocorr_lengths} must be positive and "
                f"tau_tolerance={self.tau_tolerance} in (0, 1): emcee's documentation uses "
                "50 and 0.01"
            )

    @property
    def _length(self) -> int:
        """The most steps: ``n_steps`` for a fixed run, else ``max_steps``."""
        return self.max_steps if self.n_steps is None else self.n_steps

    @property
    def _length_name(self) -> str:
        """The name of the argument that sets :attr:`_length`."""
        return "max_steps" if self.n_steps is None else "n_steps"

    @_standard_promotion
    def sample(
        self,
        model: Callable[..., Any],
        *,
        key: jax.Array,
        init_values: Mapping[str, Any] | None,
        progress: bool,
        model_kwargs: Mapping[str, Any] | None = None,
    ) -> az.InferenceData:
        """Run the ensembles, see :func:`sample_emcee`: the start ball, the run to its
        length, the autocorrelation time and the thinning, the draws mapped back to the
        constrained sites."""
        model_kwargs = dict(model_kwargs or {})
        key_init, key_start, key_numpy = jax.random.split(key, 3)
        space = _Unconstrained.of(model, model_kwargs, init_values, key_init)
        n_walkers = _walkers_per_ensemble(self.n_walkers, space.ndim)
        total = self.n_ensembles * n_walkers
        state = _initial_walkers(space, total, self.init_scale, key_start, key_numpy)
        sampler = emcee.EnsembleSampler(
            total,
            space.ndim,
            space.log_density,
            moves=_IndependentEnsembles(self.n_ensembles),
            vectorize=True,
        )
        stopped = self._run(sampler, state, _show_progress(progress))
        tau = _autocorr_time(sampler, self.burn)
        if stopped == "max_steps":
            self._warn_short(sampler.iteration, tau)
        run = _EmceeRun(sampler, space, n_walkers, tau, stopped)
        return self._inference_data(model, model_kwargs, init_values, key, run)

    def _run(self, sampler: emcee.EnsembleSampler, state: emcee.State, progress: bool) -> str:
        """Advance the ensembles from ``state``: a fixed run in one go to ``n_steps``; an
        adaptive one in blocks of ``check_every`` steps, checked after each
        (:meth:`_long_enough`), up to ``max_steps``. Returns why it stopped: ``"n_steps"``,
        ``"converged"`` or ``"max_steps"``. The blocks do not change the draws."""
        length = self._length
        previous: np.ndarray | None = None
        while sampler.iteration < length:
            block = length - sampler.iteration if self.n_steps is not None else self.check_every
            state = sampler.run_mcmc(
                state, min(block, length - sampler.iteration), progress=progress
            )
            if self.n_steps is None and sampler.iteration > self.burn:
                done, previous = self._long_enough(sampler, previous)
                if done:
                    return "converged"
        return "n_steps" if self.n_steps is not None else "max_steps"

    def _long_enough(
        self, sampler: emcee.EnsembleSampler, previous: np.ndarray | None
    ) -> tuple[bool, np.ndarray]:
        """The stopping check of an adaptive run after a block: whether the kept steps reach
        ``min_autocorr_lengths`` x every tau with tau settled to ``tau_tolerance`` since the
        ``previous`` check (:func:`_run_length_reached`), and the tau this check estimated.

        The check thins long chains to about :data:`_CHECK_ROWS` steps (its cost grows with
        the steps, the estimate of a tau of many thinning intervals barely moves), and a stop
        is confirmed on the full chain, the estimate the length gate of
        :func:`diagnose_sampling` reads. ``tol=0``: emcee's own length check is this rule, not
        a logged warning.
        """
        kept = sampler.iteration - self.burn
        step = max(1, kept // _CHECK_ROWS)
        tau = sampler.get_autocorr_time(discard=self.burn, thin=step, tol=0)
        lengths = self.min_autocorr_lengths
        if _run_length_reached(tau, previous, kept, lengths, self.tau_tolerance):
            full = tau if step == 1 else sampler.get_autocorr_time(discard=self.burn, tol=0)
            return bool(kept >= lengths * np.max(full)), tau
        return False, tau

    def _warn_short(self, steps: int, tau: np.ndarray) -> None:
        """Warn that ``max_steps`` stopped an adaptive run before its length, with the
        ``max_steps`` that would reach it (the caller of :func:`sample_emcee` is named)."""
        burn, lengths = self.burn, self.min_autocorr_lengths
        warnings.warn(
            f"emcee stopped at max_steps={self.max_steps} before its adaptive length: "
            f"{steps - burn} kept steps = {(steps - burn) / np.max(tau):.1f} autocorrelation "
            f"times (largest tau {np.max(tau):.0f} steps; {lengths:g} asked, tau settled to "
            f"{self.tau_tolerance:g}): raise max_steps to about "
            f"{burn + int(np.ceil(lengths * np.max(tau) * 1.2))}, or use NUTS",
            UserWarning,
            # this method, sample, its dtype-promotion wrapper, sample_emcee, its caller
            stacklevel=5,
        )

    def _inference_data(
        self,
        model: Callable[..., Any],
        model_kwargs: Mapping[str, Any],
        init_values: Mapping[str, Any] | None,
        key: jax.Array,
        run: _EmceeRun,
    ) -> az.InferenceData:
        """The run as ArviZ data: the kept steps, thinned (:func:`_thinning`) and mapped back
        (:func:`_emcee_draws`), the settings with the walker count used, each walker's
        acceptance fraction and ensemble, and the run's length, stop and ``tau`` as
        attributes of ``sample_stats``."""
        sampler, n_walkers, tau = run.sampler, run.n_walkers, run.tau
        every = _thinning(self.thin, tau)
        settings = {
            **dataclasses.asdict(self),
            "n_walkers": n_walkers,
            "init_values": dict(init_values) if init_values is not None else None,
        }
        idata = to_inference_data(
            model,
            **_emcee_draws(sampler, run.space, self.burn, every),
            model_kwargs=model_kwargs,
            sampler="emcee",
            settings=settings,
            key=key,
            per_chain_stats={
                "acceptance_fraction": sampler.acceptance_fraction,
                "ensemble": np.repeat(np.arange(self.n_ensembles), n_walkers),
            },
        )
        # emcee's own convergence measure (Goodman and Weare 2010; emcee's docs ask for runs
        # of at least 50 autocorrelation times), per unconstrained coordinate, in steps
        stats = idata["sample_stats"].attrs
        stats["autocorr_time"] = json.dumps(np.asarray(tau).tolist())
        stats["kept_steps"] = sampler.iteration - self.burn
        stats["total_steps"] = sampler.iteration
        stats["stopped"] = run.stopped
        stats["thin"] = every
        return idata


def _emcee_draws(
    sampler: emcee.EnsembleSampler, space: _Unconstrained, burn: int, every: int
) -> dict[str, dict[str, np.ndarray]]:
    """The kept steps (after ``burn``, every ``every``-th) as :func:`to_inference_data`'s
    ``samples`` (constrained sites by walker and draw, :func:`_constrained_draws`) and
    ``sample_stats`` (``lp``)."""
    chain = sampler.get_chain(discard=burn, thin=every)  # (draw, walker, ndim)
    draws, walkers = chain.shape[:2]
    flat = np.swapaxes(chain, 0, 1).reshape(walkers * draws, space.ndim).astype(space.z0.dtype)
    constrained = _constrained_draws(space.constrain, flat)
    return {
        "samples": {
            name: v.reshape((walkers, draws, *v.shape[1:])) for name, v in constrained.items()
        },
        "sample_stats": {"lp": sampler.get_log_prob(discard=burn, thin=every).T},
    }


def sample_emcee(
    model: Callable[..., Any],
    *,
    key: jax.Array,
    model_kwargs: Mapping[str, Any] | None = None,
    init_values: Mapping[str, Any] | None = None,
    settings: EmceeSettings = EmceeSettings(),
    progress: bool = True,
) -> az.InferenceData:
    """Sample a numpyro model's posterior with independent emcee ensembles, walkers vmapped.

    The sampler runs on the model's unconstrained space: the log density is numpyro's
    ``-potential_fn`` (priors, likelihood and the Jacobians of the transforms), jitted and
    vmapped over walkers (emcee's ``vectorize=True``); the draws are mapped back to
    constrained values (with deterministic sites) by numpyro's ``postprocess_fn``, jitted
    and in batches. A log density that is NaN (a failed simulation) is treated as ``-inf``, a
    rejected proposal.

    ``n_ensembles`` independent ensembles of ``n_walkers`` walkers each run side by side
    (the stretch move of Goodman and Weare within each ensemble, one vectorised log density
    call for all). Walkers of one ensemble are not independent chains, and each one's
    autocorrelation time is tens to hundreds of steps, so the split R-hat over walkers stays
    near ``1 + tau / N`` for ``N`` kept steps and reaches 1.01 only after about 100 to 150
    autocorrelation times; independent ensembles are what :func:`diagnose_sampling` compares
    instead (a nested R-hat, Margossian et al. 2024). All ensembles start in the same ball.
    The run length is adaptive by default (:class:`EmceeSettings`).

    Parameters
    ----------
    model
        A numpyro model, called as ``model(**model_kwargs)``.
    key
        PRNG key (``jax.random.key(seed)``); it seeds the start ball and emcee's generator.
    model_kwargs
        Keyword arguments of the model.
    init_values
        Constrained values around which the walkers start, e.g. a CMA-ES optimum;
        ``None``: the prior median.
    settings
        Walkers, ensembles, run length, burn-in, thinning and start ball
        (:class:`EmceeSettings`).
    progress
        Show emcee's progress bar (one per block of an adaptive run), when standard
        error is a terminal.

    Returns
    -------
    idata
        ``posterior`` (walkers as chains), ``sample_stats`` (``lp`` per draw,
        ``acceptance_fraction`` and ``ensemble`` per walker, and the attributes
        ``autocorr_time``, emcee's integrated autocorrelation time per unconstrained
        coordinate as JSON, ``kept_steps``, ``total_steps``, ``thin`` (the thinning used)
        and ``stopped``: ``"n_steps"``, ``"converged"`` or ``"max_steps"``),
        ``log_likelihood``, ``observed_data`` and provenance attributes.

    Raises
    ------
    ValueError
        If there are fewer than ``2 * ndim + 2`` walkers, or a walker of the start ball has
        a non-finite log density (start closer to the posterior, or shrink ``init_scale``).

    Warns
    -----
    UserWarning
        When ``max_steps`` stops an adaptive run before it reaches its length.

    References
    ----------
    D. Foreman-Mackey, D. W. Hogg, D. Lang and J. Goodman, "emcee: The MCMC Hammer",
    PASP 125 (2013); J. Goodman and J. Weare, "Ensemble samplers with affine invariance",
    CAMCoS 5 (2010); emcee's documentation, "Autocorrelation analysis & convergence" and
    "Saving & monitoring progress".
    """
    return settings.sample(
        model, key=key, init_values=init_values, progress=progress, model_kwargs=model_kwargs
    )
