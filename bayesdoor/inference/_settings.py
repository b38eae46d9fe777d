"""The sizes of every stage of a fit (:class:`FitSettings`) and the fit's methods."""

from __future__ import annotations

import dataclasses
from typing import Literal

Method = Literal["cmaes", "nuts", "emcee"]
METHODS: tuple[str, ...] = ("cmaes", "nuts", "emcee")
"""The values of :func:`fit_campaign`'s ``method``: the CMA-ES optimum alone, or a posterior
sampled with NUTS or emcee."""


@dataclasses.dataclass(frozen=True)
class FitSettings:
    """Sizes of every stage of :func:`fit_campaign`.

    Attributes
    ----------
    max_motion_s
        Longest stretch of motion (s) that enters the features; ``None``: the whole motion.
    cmaes_max_evals, cmaes_restarts, cmaes_popsize, cmaes_sigma0
        CMA-ES budget, IPOP restarts, first population (``None``: pycma's default) and
        initial step (fraction of each range). A restart starts only while the budget left
        is at least what the previous run used (one cut off by the budget before it
        converges only costs time).
    cmaes_tolerance
        CMA-ES stops when its best J of the last iterations spans less than this fraction of
        J's standard error from the run-to-run scatter (pycma's
        ``tolfun`` and ``tolfunhist``): a finer optimum of J is below what the data resolve.
        A campaign without replicate runs takes the standard error from the Welch scatter
        alone (a lower bound, so a tighter stop), and says
        so in the fit's notes. ``None``: pycma's default tolerances (1e-11 and 1e-12), so
        the budget stops it.
    workers
        Threads that simulate at once: each CMA-ES population (and every later batch of
        the exact simulator) is split into this many vmapped chunks. XLA runs a vmapped
        solve on one core, so 2 uses both cores of a 2-core machine. The batch size moves
        the adaptive solver's round-off, so features change with it at the solver's
        tolerance (5e-5 decades between one batch of 12 and two of 6 on the demo).
    box_fraction
        Half-width of the surrogate's box around the optimum, as a fraction of each range.
    box_moves
        How often the box may move to the posterior mean and widen (surrogate refitted,
        posterior resampled) when a face of the box that is not a bound lies within 4
        posterior sds of a parameter's mean, or more than 5 % of its draws lie at such a
        face.
    insensitive
        A parameter whose move from its lower to its upper bound changes no feature by more
        than this many Welch standard deviations spans its whole range in the surrogate's box
        (the data cannot constrain it, so its posterior must be free to be its prior).
    train_per_term, n_test
        Surrogate training simulations per polynomial term, and held-out simulations.
    num_warmup, num_samples, num_chains, target_accept
        NUTS settings.
    chain_method
        How NUTS runs its chains (:func:`sample_nuts`): ``"vectorized"`` (one vmapped
        program, the fastest on a CPU) or ``"sequential"`` (one chain after another; a
        likelihood with a Cholesky per step, ``ModelError(correlation=...)``, deadlocked
        inside XLA with vectorised chains on the demo fit).
    emcee_walkers, emcee_steps, emcee_max_steps, emcee_burn, emcee_thin
        emcee settings (:func:`sample_emcee`): walkers per ensemble (``None``: twice the
        sampled dimension plus two, the fewest the stretch move needs; fewer is an error),
        steps of a fixed-length run (``None``: run until the kept steps reach 50
        autocorrelation times and the estimate has settled to 1 %, at most
        ``emcee_max_steps``), burn-in and thinning (``None``: half the smallest
        autocorrelation time, emcee's documented choice).
    predictive_draws
        Posterior draws kept in the ``posterior_predictive`` group.
    """

    max_motion_s: float | None = None
    cmaes_max_evals: int = 1500
    cmaes_restarts: int = 2
    cmaes_popsize: int | None = None
    cmaes_sigma0: float = 0.25
    cmaes_tolerance: float | None = 0.1
    workers: int = 2
    box_fraction: float = 0.25
    box_moves: int = 2
    insensitive: float = 0.5
    train_per_term: int = 7
    n_test: int = 64
    num_warmup: int = 500
    num_samples: int = 500
    num_chains: int = 4
    target_accept: float = 0.9
    chain_method: str = "vectorized"
    emcee_walkers: int | None = None
    emcee_steps: int | None = None
    emcee_max_steps: int = 40000
    emcee_burn: int = 1000
    emcee_thin: int | None = None
    predictive_draws: int = 400

    def __post_init__(self) -> None:
        if self.chain_method not in ("vectorized", "sequential"):
            raise ValueError(
                f"chain_method={self.chain_method!r}: use 'vectorized' or 'sequential'"
            )
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 1:
            raise ValueError(
                f"workers={self.workers!r} must be an integer >= 1 (threads simulating at once; "
                "2 for a 2-core machine)"
            )
        if self.cmaes_tolerance is not None and not self.cmaes_tolerance > 0:
            raise ValueError(
                f"cmaes_tolerance={self.cmaes_tolerance!r} must be positive (a fraction of J's "
                "standard error, e.g. 0.1) or None for pycma's default tolerances"
            )

    @classmethod
    def quick(cls) -> FitSettings:
        """Small sizes for tests and demos (minutes on a loaded 2-core CPU, not converged).

        1 s of motion per run; CMA-ES 120 evaluations, no restart; a surrogate on twice as
        many simulations as terms and 16 held-out ones; NUTS 2 chains x (300 + 1200), the
        fewest draws that passed the sampling gates on the demo campaign's fit (seeds 0-2;
        2 x (150 + 150) failed them on every seed), for a few seconds more on the surrogate;
        emcee 600 steps (200 burn-in, a fixed length) with the fewest walkers; 100 predictive
        draws.
        """
        return cls(
            max_motion_s=1.0,
            cmaes_max_evals=120,
            cmaes_restarts=0,
            train_per_term=2,
            n_test=16,
            num_warmup=300,
            num_samples=1200,
            num_chains=2,
            emcee_steps=600,
            emcee_burn=200,
            emcee_thin=1,
            predictive_draws=100,
        )
