"""Simulation-based calibration (Talts et al. 2018): rank statistics of prior draws among
posterior draws, and a test of their uniformity.

If ``theta ~ p(theta)``, ``y ~ p(y | theta)`` and the posterior draws are exact, independent
draws of ``p(theta | y)``, the rank of ``theta`` among ``L`` posterior draws is uniform on
``0..L``. A sampler, likelihood or parameterisation that gets the posterior wrong shows up as
non-uniform ranks: a U shape for a posterior that is too narrow, a hump for one too wide, a
slope for a biased one.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import arviz as az
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float, Int
from numpyro import handlers
from scipy import stats

from ..io import atomic_write
from ._diagnostics import diagnose_sampling
from ._samplers import _standard_promotion

#: a posterior fit of one simulated data set: the model's keyword arguments in, draws out
SBCFit = Callable[..., az.InferenceData]


def thin_evenly(draws: Float[np.ndarray, "chain draw *shape"], n: int) -> np.ndarray:
    """``n`` draws spread evenly over every chain (``n // chain`` or one more from each).

    Talts et al. (2018) rank against draws that are close to independent: spacing them
    evenly over the chains, rather than taking consecutive draws, keeps their
    autocorrelation low when ``n`` is below the effective sample size.

    Raises
    ------
    ValueError
        If ``n`` exceeds the number of draws or is not positive.
    """
    draws = np.asarray(draws)
    chains, length = draws.shape[:2]
    if not 0 < n <= chains * length:
        raise ValueError(
            f"n={n} draws cannot be taken from {chains} chains x {length} draws: "
            f"pass 1 <= n <= {chains * length}"
        )
    counts = [n // chains + (c < n % chains) for c in range(chains)]
    picked = [
        draws[c, np.floor((np.arange(k) + 0.5) * length / k).astype(int)]
        for c, k in enumerate(counts)
        if k
    ]
    return np.concatenate(picked, axis=0)


def sbc_ranks(
    truth: Float[np.ndarray, "dataset param"],
    draws: Float[np.ndarray, "dataset sample param"],
) -> Int[np.ndarray, "dataset param"]:
    """The rank of each true value among its data set's posterior draws (number of draws below).

    Parameters
    ----------
    truth
        The prior draw each data set was simulated from.
    draws
        ``L`` posterior draws per data set (evenly spaced over the fit's draws).

    Returns
    -------
    ranks
        Integers in ``0..L``; continuous parameters make ties a null event.

    Raises
    ------
    ValueError
        If the shapes do not match.
    """
    truth = np.asarray(truth)
    draws = np.asarray(draws)
    if truth.ndim != 2 or draws.ndim != 3 or draws.shape[::2] != truth.shape:
        raise ValueError(
            f"truth must be (dataset, param) and draws (dataset, sample, param) with the same "
            f"dataset and param sizes; got {truth.shape} and {draws.shape}"
        )
    return np.sum(draws < truth[:, None, :], axis=1)


@dataclasses.dataclass(frozen=True)
class SBCUniformity:
    """Outcome of :func:`sbc_uniformity`, one entry per parameter.

    Attributes
    ----------
    names
        The parameters.
    n_datasets, n_rank_draws, bins
        Data sets, posterior draws per rank (ranks run over ``0..n_rank_draws``), and the
        number of rank bins of the chi-square test.
    counts
        Data sets per rank bin, per parameter.
    chi2_pvalue, ks_pvalue
        p-values of the chi-square test on the binned ranks and of the Kolmogorov-Smirnov test
        on the ranks scaled to (0, 1).
    mean_rank
        Mean rank scaled to (0, 1): 0.5 for a calibrated posterior; above it, the truth lies
        mostly above the draws (the posterior is biased low).
    spread
        Variance of the scaled ranks over that of a uniform (1/12): above 1 a U shape (the
        posterior is too narrow), below 1 a hump (too wide).
    alpha
        The family-wise level over every parameter and both tests (Bonferroni).
    passed
        No p-value below ``alpha / (2 * len(names))``.
    messages
        One line per parameter that failed: which test, the p-values and the likely cause.
    """

    names: tuple[str, ...]
    n_datasets: int
    n_rank_draws: int
    bins: int
    counts: tuple[tuple[int, ...], ...]
    chi2_pvalue: tuple[float, ...]
    ks_pvalue: tuple[float, ...]
    mean_rank: tuple[float, ...]
    spread: tuple[float, ...]
    alpha: float
    passed: bool
    messages: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        """Plain JSON values."""
        return dataclasses.asdict(self)

    def __str__(self) -> str:
        head = "SBC ranks consistent with uniform" if self.passed else "SBC RANKS NOT UNIFORM"
        lines = [
            f"{head} ({self.n_datasets} data sets, {self.n_rank_draws} draws per rank, "
            f"family-wise level {self.alpha})",
            f"  {'parameter':<16} {'chi2 p':>8} {'KS p':>8} {'mean':>6} {'spread':>7}",
        ]
        for i, name in enumerate(self.names):
            lines.append(
                f"  {name:<16} {self.chi2_pvalue[i]:8.3f} {self.ks_pvalue[i]:8.3f} "
                f"{self.mean_rank[i]:6.3f} {self.spread[i]:7.2f}"
            )
        lines += [f"  ! {m}" for m in self.messages]
        return "\n".join(lines)


def _bin_edges(n_rank_draws: int, bins: int) -> np.ndarray:
    """Edges splitting the ranks ``0..L`` into ``bins`` runs of (nearly) equal length."""
    return np.floor(np.arange(bins + 1) * (n_rank_draws + 1) / bins).astype(int)


def sbc_uniformity(
    ranks: Int[np.ndarray, "dataset param"],
    n_rank_draws: int,
    *,
    names: Sequence[str] | None = None,
    bins: int | None = None,
    alpha: float = 0.01,
) -> SBCUniformity:
    """Test SBC ranks for uniformity, per parameter, at a family-wise level.

    Two tests per parameter: Pearson's chi-square on the ranks in ``bins`` bins (expected
    counts from the exact share of ranks in each bin) and the Kolmogorov-Smirnov test of the
    scaled ranks ``(r + 1/2) / (L + 1)`` against the uniform on (0, 1) (the mid-points of a
    discrete uniform make it slightly conservative). The family-wise level ``alpha`` is
    split evenly over all tests (Bonferroni), so a calibrated posterior fails with
    probability at most ``alpha``.

    Parameters
    ----------
    ranks
        Ranks of the truth among the posterior draws (``SBCResult.ranks``), in
        ``0..n_rank_draws``.
    n_rank_draws
        The number ``L`` of posterior draws each rank was taken among.
    names
        Parameter names (default ``p0, p1, ...``).
    bins
        Bins of the chi-square test; default ``min(10, n_datasets // 5)`` (at least 2), so
        that every bin expects about 5 data sets or more.
    alpha
        Family-wise significance level.

    Returns
    -------
    result
        p-values, shape summaries, ``passed`` and messages.

    Raises
    ------
    ValueError
        For ranks outside ``0..n_rank_draws``, fewer than 2 bins or more bins than ranks,
        fewer than 10 data sets, or a level outside (0, 1).

    References
    ----------
    S. Talts, M. Betancourt, D. Simpson, A. Vehtari and A. Gelman, "Validating Bayesian
    inference algorithms with simulation-based calibration", arXiv:1804.06788 (2018).
    """
    ranks = np.asarray(ranks)
    bins = _checked_bins(ranks, n_rank_draws, bins, alpha)
    n, p = ranks.shape
    names = _parameter_names(names, p)
    edges = _bin_edges(n_rank_draws, bins)
    expected = n * np.diff(edges) / (n_rank_draws + 1)
    level = alpha / (2 * p)
    scaled = (ranks + 0.5) / (n_rank_draws + 1)
    tests = [_rank_test(ranks[:, i], scaled[:, i], edges, expected) for i in range(p)]
    columns = list(zip(*tests, strict=True)) or [()] * 5
    counts, chi2_p, ks_p, means, spreads = (tuple(column) for column in columns)
    messages = [
        f"{name}: chi2 p={chi:.2g}, KS p={ks:.2g} < {level:.2g} (level {alpha} over "
        f"{2 * p} tests); " + "; ".join(_rank_causes(mean, spread, n))
        for name, (_, chi, ks, mean, spread) in zip(names, tests, strict=True)
        if min(chi, ks) < level
    ]
    return SBCUniformity(
        names=names,
        n_datasets=n,
        n_rank_draws=int(n_rank_draws),
        bins=bins,
        counts=counts,
        chi2_pvalue=chi2_p,
        ks_pvalue=ks_p,
        mean_rank=means,
        spread=spreads,
        alpha=alpha,
        passed=not messages,
        messages=tuple(messages),
    )


def _checked_bins(ranks: np.ndarray, n_rank_draws: int, bins: int | None, alpha: float) -> int:
    """The chi-square test's bins (default ``min(10, n_datasets // 5)``, at least 2), with the
    ranks and the level checked.

    Raises
    ------
    ValueError
        For ranks that are not (dataset, param) with 10 data sets or more or lie outside
        ``0..n_rank_draws``, bins outside ``2..n_rank_draws + 1``, or a level outside (0, 1).
    """
    if ranks.ndim != 2 or ranks.shape[0] < 10:
        raise ValueError(
            f"ranks must be (dataset, param) with at least 10 data sets; got {ranks.shape}: "
            "simulate more data sets"
        )
    if ranks.min() < 0 or ranks.max() > n_rank_draws:
        raise ValueError(
            f"ranks run from {ranks.min()} to {ranks.max()}, outside 0..n_rank_draws="
            f"{n_rank_draws}: pass the number of draws the ranks were taken among"
        )
    bins = max(2, min(10, ranks.shape[0] // 5)) if bins is None else int(bins)
    if not 2 <= bins <= n_rank_draws + 1:
        raise ValueError(f"bins={bins} must lie in 2..{n_rank_draws + 1} (the number of ranks)")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha={alpha} must lie in (0, 1), e.g. 0.01")
    return bins


def _parameter_names(names: Sequence[str] | None, p: int) -> tuple[str, ...]:
    """``names`` checked to name ``p`` parameters; ``None``: ``p0, p1, ...``."""
    names = tuple(f"p{i}" for i in range(p)) if names is None else tuple(names)
    if len(names) != p:
        raise ValueError(f"names has {len(names)} entries for {p} parameters: {names}")
    return names


def _rank_test(
    ranks: np.ndarray, scaled: np.ndarray, edges: np.ndarray, expected: np.ndarray
) -> tuple[tuple[int, ...], float, float, float, float]:
    """One parameter's counts per bin, chi-square and KS p-values, mean scaled rank and 12 x
    the variance of the scaled ranks (1 for uniform ranks)."""
    c = np.histogram(ranks, bins=edges - 0.5)[0]
    # the last edge sits at L + 1 - 0.5, so rank L falls in the last bin
    chi = float(stats.chisquare(c, expected).pvalue)
    ks = float(stats.kstest(scaled, "uniform").pvalue)
    return tuple(int(x) for x in c), chi, ks, float(scaled.mean()), float(scaled.var() * 12.0)


def _rank_causes(mean: float, spread: float, n: int) -> list[str]:
    """The likely causes of non-uniform ranks from their scaled mean and 12 x variance over
    ``n`` data sets: a shift, a U shape, a hump, else lumpiness."""
    causes = []
    # standard errors of the mean and of 12 x the variance of n uniform draws
    mean_sd, spread_sd = np.sqrt(1.0 / (12.0 * n)), np.sqrt(0.8 / n)
    if abs(mean - 0.5) > 2.0 * mean_sd:
        side = "below" if mean > 0.5 else "above"
        causes.append(
            f"mean rank {mean:.2f} (0.5 +- {mean_sd:.2f}): the posterior sits {side} the "
            "truth (a biased likelihood, forward model or prior)"
        )
    if spread > 1.0 + 2.0 * spread_sd:
        causes.append(
            f"spread {spread:.2f} (1 +- {spread_sd:.2f}), a U shape: the posterior is too "
            "narrow (noise or model error underestimated, or chains that do not mix)"
        )
    elif spread < 1.0 - 2.0 * spread_sd:
        causes.append(
            f"spread {spread:.2f} (1 +- {spread_sd:.2f}), a hump: the posterior is too "
            "wide (noise or model error overestimated)"
        )
    if not causes:
        causes.append(
            "neither a shift nor a width: lumpy ranks (too few independent draws per "
            "rank, or a posterior of the wrong shape)"
        )
    return causes


@dataclasses.dataclass(frozen=True)
class SBCResult:
    """Ranks of a simulation-based calibration, one row per simulated data set.

    Attributes
    ----------
    names
        The ranked scalars (``name`` or ``name[i]`` for an element of a vector site).
    datasets
        The index of each data set (its prior draw and fit derive from the key and this).
    truth
        The prior draw of each data set.
    ranks
        The rank of the truth among ``n_rank_draws`` thinned posterior draws.
    n_rank_draws
        Posterior draws per rank.
    ess_bulk
        Smallest bulk effective sample size over the ranked scalars, per data set; where it is
        below ``n_rank_draws`` the draws are not independent enough and the ranks are suspect.
    gates_passed
        Whether each data set's posterior passed :func:`diagnose_sampling`'s gates.
    seconds
        Wall time of each data set's fit.
    """

    names: tuple[str, ...]
    datasets: Int[np.ndarray, " dataset"]
    truth: Float[np.ndarray, "dataset param"]
    ranks: Int[np.ndarray, "dataset param"]
    n_rank_draws: int
    ess_bulk: Float[np.ndarray, " dataset"]
    gates_passed: np.ndarray
    seconds: Float[np.ndarray, " dataset"]

    def uniformity(self, *, bins: int | None = None, alpha: float = 0.01) -> SBCUniformity:
        """:func:`sbc_uniformity` of the ranks."""
        return sbc_uniformity(
            self.ranks, self.n_rank_draws, names=self.names, bins=bins, alpha=alpha
        )

    def to_json(self) -> dict[str, Any]:
        """Plain JSON values (:meth:`from_json` reads them back)."""
        return {
            "names": list(self.names),
            "datasets": self.datasets.tolist(),
            "truth": self.truth.tolist(),
            "ranks": self.ranks.tolist(),
            "n_rank_draws": self.n_rank_draws,
            "ess_bulk": self.ess_bulk.tolist(),
            "gates_passed": self.gates_passed.tolist(),
            "seconds": self.seconds.tolist(),
        }

    @classmethod
    def from_json(cls, record: Mapping[str, Any]) -> SBCResult:
        """The result of :meth:`to_json`."""
        return cls(
            names=tuple(record["names"]),
            datasets=np.asarray(record["datasets"], dtype=int),
            truth=np.asarray(record["truth"], dtype=float).reshape(-1, len(record["names"])),
            ranks=np.asarray(record["ranks"], dtype=int).reshape(-1, len(record["names"])),
            n_rank_draws=int(record["n_rank_draws"]),
            ess_bulk=np.asarray(record["ess_bulk"], dtype=float),
            gates_passed=np.asarray(record["gates_passed"], dtype=bool),
            seconds=np.asarray(record["seconds"], dtype=float),
        )

    @classmethod
    def concatenate(cls, parts: Sequence[SBCResult]) -> SBCResult:
        """Join results over disjoint data sets (e.g. from parallel workers), sorted by index.

        Raises
        ------
        ValueError
            If the parts rank different scalars or numbers of draws, or share a data set.
        """
        if not parts:
            raise ValueError("parts is empty: pass at least one SBCResult")
        first = parts[0]
        for part in parts[1:]:
            if part.names != first.names or part.n_rank_draws != first.n_rank_draws:
                raise ValueError(
                    f"parts rank different scalars or draws: {first.names}/{first.n_rank_draws}"
                    f" against {part.names}/{part.n_rank_draws}"
                )
        datasets = np.concatenate([p.datasets for p in parts])
        if np.unique(datasets).size != datasets.size:
            raise ValueError("parts share data sets: each data set index must appear once")
        order = np.argsort(datasets)

        def join(field: str) -> np.ndarray:
            return np.concatenate([getattr(p, field) for p in parts])[order]

        return cls(
            names=first.names,
            datasets=datasets[order],
            truth=join("truth"),
            ranks=join("ranks"),
            n_rank_draws=first.n_rank_draws,
            ess_bulk=join("ess_bulk"),
            gates_passed=join("gates_passed"),
            seconds=join("seconds"),
        )


def _scalars(values: Mapping[str, Any], var_names: Sequence[str], lead: int) -> tuple:
    """Flatten sites to scalar columns: names (``x`` or ``x[i, j]``) and a (..., scalar) array."""
    names, columns = [], []
    for name in var_names:
        v = np.asarray(values[name])
        shape = v.shape[lead:]
        for index in np.ndindex(*shape):
            names.append(f"{name}[{', '.join(map(str, index))}]" if index else name)
            columns.append(v[(..., *index)])
    return tuple(names), np.stack(columns, axis=-1)


@_standard_promotion
def _prior_predictive(
    model: Callable[..., Any],
    model_kwargs: Mapping[str, Any],
    observed: Sequence[str],
    keys: jax.Array,
) -> dict[str, np.ndarray]:
    """One joint draw of every site (latent, deterministic and observed) per key, vmapped."""

    def draw(k):
        kwargs = {**model_kwargs, **{name: None for name in observed}}
        trace = handlers.trace(handlers.seed(model, k)).get_trace(**kwargs)
        return {
            name: site["value"]
            for name, site in trace.items()
            if site["type"] in ("sample", "deterministic")
        }

    return jax.tree_util.tree_map(np.asarray, jax.jit(jax.vmap(draw))(keys))


@dataclasses.dataclass(frozen=True)
class SBCDesign:
    """How many data sets a simulation-based calibration draws, which of them one call
    simulates and fits, and how many posterior draws each rank is taken among.

    Attributes
    ----------
    n_datasets
        Number of data sets (Talts et al. use hundreds; 20 is the least for a coarse test).
    n_rank_draws
        Posterior draws per rank (``L``); keep it below the fits' effective sample size.
    datasets
        Indices of the data sets this call simulates and fits (default all).
    """

    n_datasets: int
    n_rank_draws: int = 99
    datasets: Sequence[int] | None = None

    def indices(self) -> np.ndarray:
        """The indices of the data sets of this call, checked.

        Raises
        ------
        ValueError
            For an index outside ``0..n_datasets - 1``, or none.
        """
        n = self.n_datasets
        indices = np.arange(n) if self.datasets is None else np.asarray(self.datasets, dtype=int)
        if indices.size == 0 or indices.min() < 0 or indices.max() >= n:
            raise ValueError(f"datasets {indices.tolist()} must be non-empty indices in 0..{n - 1}")
        return indices


def run_sbc(
    model: Callable[..., Any],
    *,
    key: jax.Array,
    design: SBCDesign,
    fit: SBCFit,
    var_names: Sequence[str],
    observed: Sequence[str] = ("y",),
    model_kwargs: Mapping[str, Any] | None = None,
    on_dataset: Callable[[SBCResult], None] | None = None,
) -> SBCResult:
    """Simulation-based calibration of a numpyro model and a posterior fit.

    For data set ``i``: draw every site of ``model`` jointly from the prior predictive with
    the key ``fold_in(k_prior, i)`` (the observed sites set to ``None``), fit the posterior
    to the drawn observations with ``fit(model_kwargs, key=fold_in(k_fit, i))``, thin the
    posterior of ``var_names`` to ``n_rank_draws`` draws spread over the chains, and rank the
    drawn truth among them. Data set ``i`` is the same whichever ``datasets`` a call covers,
    so parallel workers can each take a share and :meth:`SBCResult.concatenate` joins them.

    Parameters
    ----------
    model
        A numpyro model whose observed sites take their values from keyword arguments named
        as the sites (``model(y=None)`` draws ``y``), as :func:`make_model` builds.
    key
        PRNG key of the whole calibration.
    design
        The data sets, those of this call, and the draws per rank (:class:`SBCDesign`).
    fit
        ``fit(model_kwargs, *, key) -> InferenceData``: the posterior of ``model`` given the
        keyword arguments (the observations included), e.g. a wrapper of :func:`sample_nuts`.
    var_names
        Sites to rank (latent or deterministic; vector sites are ranked per element).
    observed
        The observed sites (keyword arguments of ``model``).
    model_kwargs
        Other keyword arguments of ``model``.
    on_dataset
        Called with the one-data-set result after each fit (to save it as it comes).

    Returns
    -------
    result
        Truths, ranks, effective sample sizes, gate outcomes and timings.

    Raises
    ------
    ValueError
        For a data set index outside ``0..n_datasets - 1``, a site in ``var_names`` or
        ``observed`` that the model lacks, or a fit without enough draws.

    References
    ----------
    S. Talts, M. Betancourt, D. Simpson, A. Vehtari and A. Gelman, "Validating Bayesian
    inference algorithms with simulation-based calibration", arXiv:1804.06788 (2018).
    """
    model_kwargs = dict(model_kwargs or {})
    indices = design.indices()
    key_prior, key_fit = jax.random.split(key)
    keys = jax.vmap(functools.partial(jax.random.fold_in, key_prior))(jnp.asarray(indices))
    prior = _prior_predictive(model, model_kwargs, tuple(observed), keys)
    _check_sites(prior, var_names, observed)
    names, truth = _scalars(prior, var_names, 1)
    parts = []
    for row, index in enumerate(indices):
        kwargs = {**model_kwargs, **{o: jnp.asarray(prior[o][row]) for o in observed}}
        start = time.perf_counter()
        idata = fit(kwargs, key=jax.random.fold_in(key_fit, int(index)))
        seconds = time.perf_counter() - start
        truth_row = (names, truth[row : row + 1])
        part = _ranked(idata, var_names, truth_row, int(index), design.n_rank_draws, seconds)
        if on_dataset is not None:
            on_dataset(part)
        parts.append(part)
    return SBCResult.concatenate(parts)


def _check_sites(
    prior: Mapping[str, Any], var_names: Sequence[str], observed: Sequence[str]
) -> None:
    """Raise naming the sites of ``var_names`` and ``observed`` the prior draws lack."""
    missing = sorted(set(var_names).union(observed) - set(prior))
    if missing:
        raise ValueError(
            f"the model has no sites {missing}; its sites are {sorted(prior)}: check var_names "
            "and observed"
        )


def _ranked(
    idata: az.InferenceData,
    var_names: Sequence[str],
    truth: tuple[tuple[str, ...], np.ndarray],
    index: int,
    n_rank_draws: int,
    seconds: float,
) -> SBCResult:
    """The one-data-set result of data set ``index``: its ``truth`` (the scalars' names and
    values) ranked among ``n_rank_draws`` thinned draws of the fit ``idata``, the smallest
    bulk ESS, whether the sampling gates passed, and the fit's time."""
    names, values = truth
    post = idata["posterior"]
    _, draws = _scalars({v: post[v].values for v in var_names}, var_names, 2)
    thinned = thin_evenly(draws, n_rank_draws)
    with np.errstate(invalid="ignore", divide="ignore"):
        ess = az.ess(post[list(var_names)], method="bulk")
    ess_min = float(np.nanmin([np.min(ess[v].values) for v in var_names]))
    gates = diagnose_sampling(idata, var_names=var_names, warn=False).passed
    return SBCResult(
        names=names,
        datasets=np.array([index]),
        truth=values,
        ranks=sbc_ranks(values, thinned[None]),
        n_rank_draws=n_rank_draws,
        ess_bulk=np.array([ess_min]),
        gates_passed=np.array([gates]),
        seconds=np.array([seconds]),
    )


def plot_sbc_ranks(
    result: SBCResult, path: str | Path, *, bins: int | None = None, title: str = "SBC ranks"
) -> Path:
    """Rank histograms per scalar with the band a uniform rank distribution fills 99 % of the time.

    Parameters
    ----------
    result
        A :func:`run_sbc` result.
    path
        The PNG file to write (its folder is created).
    bins
        Histogram bins (default as :func:`sbc_uniformity`).
    title
        Figure title.

    Returns
    -------
    path
        The file written.
    """
    from matplotlib.figure import Figure  # no pyplot: the caller's backend stays as it is

    test = result.uniformity(bins=bins)
    edges = _bin_edges(result.n_rank_draws, test.bins)
    share = np.diff(edges) / (result.n_rank_draws + 1)
    n = test.n_datasets
    lo = stats.binom.ppf(0.005, n, share)
    hi = stats.binom.ppf(0.995, n, share)
    cols = min(4, len(result.names))
    rows = -(-len(result.names) // cols)
    fig = Figure(figsize=(3.2 * cols, 2.6 * rows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, cols)).reshape(-1)
    left, width = edges[:-1] - 0.5, np.diff(edges)
    for i, name in enumerate(result.names):
        ax = axes[i]
        for b in range(test.bins):
            ax.fill_between(
                [left[b], left[b] + width[b]], lo[b], hi[b], color="grey", alpha=0.3, linewidth=0
            )
        ax.bar(left, test.counts[i], width=0.9 * width, align="edge", color="C0")
        ax.axhline(n / test.bins, color="k", linewidth=0.8)
        ax.set_title(
            f"{name}: chi2 p={test.chi2_pvalue[i]:.2f}, KS p={test.ks_pvalue[i]:.2f}", fontsize=8
        )
        ax.set_xlabel("rank")
    for ax in axes[len(result.names) :]:
        ax.set_visible(False)
    fig.suptitle(f"{title} ({n} data sets, ranks among {result.n_rank_draws} draws)")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def save_sbc(result: SBCResult, path: str | Path, *, overwrite: bool = False) -> Path:
    """Write :meth:`SBCResult.to_json` to ``path`` whole or not at all (``io.atomic_write``).

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is false.
    """
    text = json.dumps(result.to_json())
    return atomic_write(Path(path), lambda tmp: tmp.write_text(text), overwrite=overwrite)


def load_sbc(path: str | Path) -> SBCResult:
    """Read a result written by :func:`save_sbc`."""
    return SBCResult.from_json(json.loads(Path(path).read_text()))
