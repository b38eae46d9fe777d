"""Convergence gates on a posterior: R-hat, bulk and tail ESS, divergences, E-BFMI."""

from __future__ import annotations

import dataclasses
import json
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import arviz as az
import numpy as np
import xarray as xr
from jaxtyping import Float, Int
from scipy import stats

if TYPE_CHECKING:
    import pandas as pd


class SamplingGateWarning(UserWarning):
    """Issued when a posterior fails the convergence gates of :func:`diagnose_sampling`."""


@dataclasses.dataclass(frozen=True)
class SamplingDiagnostics:
    """Outcome of :func:`diagnose_sampling`.

    Attributes
    ----------
    rhat_max, rhat_worst
        Largest rank-normalised split R-hat and the variable (with index) where it occurs.
    ess_bulk_min, ess_bulk_worst
        Smallest bulk effective sample size and its variable.
    ess_tail_min, ess_tail_worst
        Smallest tail effective sample size (5 % and 95 % quantiles) and its variable.
    divergences
        Divergent transitions after warm-up (``None`` for samplers without them, e.g. emcee).
    draws
        Total draws over all chains.
    ebfmi
        Energy Bayesian fraction of missing information per chain (``None`` without energy).
    autocorr_lengths
        emcee only: kept steps divided by the largest integrated autocorrelation time
        (``None`` for other samplers).
    passed
        Whether every gate passed.
    messages
        One line per failed gate: what failed, by how much, and what to do.
    thresholds
        The gate thresholds used.
    rhat_method
        ``"split-rank"`` (Vehtari et al. 2021, over chains) or ``"nested"`` (over the
        independent ensembles of :func:`sample_emcee`, see :func:`nested_rhat`).
    """

    rhat_max: float
    rhat_worst: str
    ess_bulk_min: float
    ess_bulk_worst: str
    ess_tail_min: float
    ess_tail_worst: str
    divergences: int | None
    draws: int
    ebfmi: tuple[float, ...] | None
    autocorr_lengths: float | None
    passed: bool
    messages: tuple[str, ...]
    thresholds: dict[str, float]
    rhat_method: str = "split-rank"

    def to_json(self) -> dict[str, Any]:
        """The diagnostics as plain JSON values (non-finite numbers become ``None``)."""

        def clean(value: Any) -> Any:
            if isinstance(value, dict):
                return {k: clean(v) for k, v in value.items()}
            if isinstance(value, list | tuple):
                return [clean(v) for v in value]
            if isinstance(value, float) and not np.isfinite(value):
                return None
            return value

        return clean(dataclasses.asdict(self))

    def __str__(self) -> str:
        head = "sampling gates PASSED" if self.passed else "SAMPLING GATES FAILED"
        lines = [
            head,
            f"  max R-hat      {self.rhat_max:.4f} ({self.rhat_worst}; {self.rhat_method})",
            f"  min bulk ESS   {self.ess_bulk_min:.0f} ({self.ess_bulk_worst})",
            f"  min tail ESS   {self.ess_tail_min:.0f} ({self.ess_tail_worst})",
        ]
        if self.divergences is not None:
            lines.append(f"  divergences    {self.divergences} of {self.draws} draws")
        if self.ebfmi is not None:
            lines.append("  E-BFMI         " + ", ".join(f"{e:.2f}" for e in self.ebfmi))
        if self.autocorr_lengths is not None:
            lines.append(f"  run length     {self.autocorr_lengths:.1f} autocorrelation times")
        lines += [f"  ! {m}" for m in self.messages]
        return "\n".join(lines)


def _extreme(ds: xr.Dataset, *, largest: bool, constant: xr.Dataset) -> tuple[float, str]:
    """The largest (or smallest) value over all variables and elements, and where it is.

    arviz gives NaN for an element that never changes. Where the element is the same in every
    draw of every chain (a deterministic site fixed by the data) there is nothing to check;
    any other NaN (a stuck chain) counts as the worst possible value.
    """
    ignored, worst = (-np.inf, np.inf) if largest else (np.inf, -np.inf)
    best_value, best_name = ignored, ""
    for name, da in ds.data_vars.items():
        values = np.asarray(da.values, dtype=np.float64).reshape(-1)
        fixed = np.asarray(constant[name].values).reshape(-1)
        values = np.where(np.isnan(values), np.where(fixed, ignored, worst), values)
        i = int(np.argmax(values) if largest else np.argmin(values))
        if (values[i] > best_value) if largest else (values[i] < best_value):
            index = np.unravel_index(i, da.shape) if da.ndim else ()
            label = f"{name}[{', '.join(str(j) for j in index)}]" if index else str(name)
            best_value, best_name = float(values[i]), label
    return best_value, best_name


def _normal_scores(x: np.ndarray) -> np.ndarray:
    """Ranks over all values mapped to normal quantiles (Vehtari et al. 2021, eq. 14)."""
    ranks = stats.rankdata(x, axis=None).reshape(x.shape)
    return stats.norm.ppf((ranks - 0.375) / (x.size + 0.25))


def _nested_rhat_raw(x: np.ndarray, superchain: np.ndarray) -> float:
    k = np.unique(superchain)
    chain_means = x.mean(axis=1)
    within = x.var(axis=1, ddof=1)
    super_means, spread = [], []
    for s in k:
        members = superchain == s
        super_means.append(chain_means[members].mean())
        between = chain_means[members].var(ddof=1) if members.sum() > 1 else 0.0
        spread.append(between + within[members].mean())
    w = float(np.mean(spread))
    b = float(np.var(super_means, ddof=1))
    return float(np.sqrt(1.0 + b / w)) if w > 0 else np.nan


def nested_rhat(
    draws: Float[np.ndarray, "chain draw"], superchain: Int[np.ndarray, " chain"]
) -> float:
    """Nested R-hat of one scalar: chains grouped in superchains (Margossian et al. 2024).

    ``sqrt(1 + B / W)`` with ``B`` the variance between superchain means and ``W`` the mean
    over superchains of the variance between their chains' means plus the mean within-chain
    variance. It tends to 1 as the chains per superchain grow, however short and
    autocorrelated each chain is, which fits emcee: ``M`` walkers of one ensemble per
    superchain, and about ``1 + tau / (2 M N)`` for ``N`` steps at stationarity instead of the
    ``1 + tau / N`` of the split R-hat over walkers. As in Vehtari et al. (2021) it is taken on
    rank-normalised draws and on rank-normalised distances from the median (the folded draws,
    for the scale), the larger of the two; and as in the split R-hat each chain's first and
    second halves count as separate superchains, so a drift within the run shows up too.

    Parameters
    ----------
    draws
        Draws of one scalar.
    superchain
        The superchain (for emcee: the independent ensemble) of each chain; at least two.

    Returns
    -------
    rhat
        The nested R-hat; ``nan`` for a constant.

    Raises
    ------
    ValueError
        For fewer than two superchains, a label per chain missing, or fewer than 4 draws.

    References
    ----------
    C. C. Margossian, M. D. Hoffman, P. Sountsov, L. Riou-Durand, A. Vehtari and A. Gelman,
    "Nested R-hat: assessing the convergence of Markov chain Monte Carlo when running many
    short chains", Bayesian Analysis (2024).
    """
    x = np.asarray(draws, dtype=float)
    superchain = np.asarray(superchain)
    if x.ndim != 2 or superchain.shape != x.shape[:1] or x.shape[1] < 4:
        raise ValueError(
            f"draws must be (chain, draw) with at least 4 draws and superchain one label per "
            f"chain; got draws {x.shape} and superchain {superchain.shape}"
        )
    if np.unique(superchain).size < 2:
        raise ValueError(
            "nested R-hat needs at least two superchains (independent ensembles); got "
            f"{np.unique(superchain).tolist()}: run sample_emcee with n_ensembles >= 2"
        )
    if np.all(x == x.flat[0]):
        return np.nan
    half = x.shape[1] // 2
    split = np.concatenate([x[:, :half], x[:, -half:]])
    labels = np.concatenate([2 * superchain, 2 * superchain + 1])
    folded = np.abs(split - np.median(split))
    return max(
        _nested_rhat_raw(_normal_scores(split), labels),
        _nested_rhat_raw(_normal_scores(folded), labels),
    )


def _nested_rhat_dataset(posterior: xr.Dataset, superchain: np.ndarray) -> xr.Dataset:
    """:func:`nested_rhat` of every element of every posterior variable."""

    def one(da: xr.DataArray) -> xr.DataArray:
        values = np.moveaxis(
            np.asarray(da.transpose("chain", "draw", ...).values), (0, 1), (-2, -1)
        )
        out = np.full(values.shape[:-2], np.nan)
        for index in np.ndindex(*out.shape):
            out[index] = nested_rhat(values[index], superchain)
        dims = [d for d in da.transpose("chain", "draw", ...).dims if d not in ("chain", "draw")]
        return xr.DataArray(out, dims=dims)

    return xr.Dataset({name: one(da) for name, da in posterior.data_vars.items()})


@dataclasses.dataclass(frozen=True)
class SamplingGates:
    """The thresholds of :func:`diagnose_sampling`'s convergence gates.

    Attributes
    ----------
    rhat_max
        Largest acceptable rank-normalised split R-hat.
    ess_bulk_min
        Smallest acceptable bulk effective sample size.
    ess_tail_min
        Smallest acceptable tail effective sample size; ``None`` reports it without gating.
    max_divergences
        Largest acceptable number of divergent transitions.
    ebfmi_min
        Smallest acceptable E-BFMI per chain.
    min_autocorr_lengths
        Smallest acceptable emcee run length after burn-in, in autocorrelation times (emcee's
        documentation recommends 50).
    """

    rhat_max: float = 1.01
    ess_bulk_min: float = 400.0
    ess_tail_min: float | None = None
    max_divergences: int = 0
    ebfmi_min: float = 0.3
    min_autocorr_lengths: float = 50.0

    def as_dict(self) -> dict[str, float]:
        """The thresholds by name (an ungated tail ESS as NaN)."""
        return {
            "rhat_max": self.rhat_max,
            "ess_bulk_min": self.ess_bulk_min,
            "ess_tail_min": np.nan if self.ess_tail_min is None else self.ess_tail_min,
            "max_divergences": self.max_divergences,
            "ebfmi_min": self.ebfmi_min,
            "min_autocorr_lengths": self.min_autocorr_lengths,
        }


def diagnose_sampling(
    idata: az.InferenceData,
    *,
    gates: SamplingGates = SamplingGates(),
    var_names: Sequence[str] | None = None,
    warn: bool = True,
) -> SamplingDiagnostics:
    """Check a posterior against convergence gates and explain every failure.

    Gates (Vehtari et al. 2021; Betancourt 2017; :class:`SamplingGates`): max R-hat at most
    ``rhat_max`` (the nested R-hat over independent ensembles, :func:`nested_rhat`, where
    ``sample_stats`` has an ``ensemble`` per chain, as :func:`sample_emcee` writes; else the
    split R-hat), min bulk ESS at least ``ess_bulk_min``, min tail ESS at least
    ``ess_tail_min`` (when given), at most ``max_divergences`` divergent transitions, E-BFMI
    at least ``ebfmi_min`` in every chain, and (emcee) at least ``min_autocorr_lengths``
    integrated autocorrelation times kept. Divergences and E-BFMI are checked only when
    ``sample_stats`` holds ``diverging`` and ``energy`` (NUTS), the run length only when its
    attributes hold emcee's ``autocorr_time``. A failed gate issues a
    :class:`SamplingGateWarning` (unless ``warn`` is false) so that a failing run cannot pass
    silently.

    Parameters
    ----------
    idata
        A posterior with ``posterior`` and ``sample_stats`` groups.
    gates
        The thresholds.
    var_names
        Variables to check (default: every posterior variable).
    warn
        Issue a :class:`SamplingGateWarning` when a gate fails.

    Returns
    -------
    diagnostics
        The figures, ``passed`` and a message per failed gate.

    Raises
    ------
    ValueError
        If ``idata`` has no ``posterior`` group.

    References
    ----------
    A. Vehtari, A. Gelman, D. Simpson, B. Carpenter and P.-C. Bürkner, "Rank-normalization,
    folding, and localization: an improved R-hat for assessing convergence of MCMC",
    Bayesian Analysis 16 (2021). M. Betancourt, "A conceptual introduction to Hamiltonian
    Monte Carlo", arXiv:1701.02434 (2017).
    """
    posterior = _posterior(idata, var_names)
    stats = idata["sample_stats"] if "sample_stats" in idata.groups() else xr.Dataset()
    mixing = _Mixing.of(posterior, stats)
    total = mixing.chains * mixing.draws
    divergences, divergence_messages = _divergences(stats, total, gates.max_divergences)
    ebfmi, ebfmi_messages = _ebfmi(idata, stats, gates.ebfmi_min)
    lengths, length_messages = _run_length(stats, gates.min_autocorr_lengths)
    messages = mixing.messages(gates) + divergence_messages + ebfmi_messages + length_messages
    result = SamplingDiagnostics(
        rhat_max=mixing.rhat,
        rhat_worst=mixing.rhat_at,
        ess_bulk_min=mixing.bulk,
        ess_bulk_worst=mixing.bulk_at,
        ess_tail_min=mixing.tail,
        ess_tail_worst=mixing.tail_at,
        divergences=divergences,
        draws=total,
        ebfmi=ebfmi,
        autocorr_lengths=lengths,
        passed=not messages,
        messages=tuple(messages),
        thresholds=gates.as_dict(),
        rhat_method="nested" if mixing.nested else "split-rank",
    )
    if messages and warn:
        warnings.warn(
            "posterior FAILED the sampling gates:\n" + "\n".join(messages),
            SamplingGateWarning,
            stacklevel=2,
        )
    return result


def _posterior(idata: az.InferenceData, var_names: Sequence[str] | None) -> xr.Dataset:
    """The posterior group, of ``var_names`` only when given.

    Raises
    ------
    ValueError
        If ``idata`` has no ``posterior`` group.
    """
    if "posterior" not in idata.groups():
        raise ValueError(
            f"idata has no posterior group (groups: {list(idata.groups())}); pass the output "
            "of sample_nuts or sample_emcee"
        )
    names = list(var_names) if var_names is not None else None
    return idata["posterior"] if names is None else idata["posterior"][names]


@dataclasses.dataclass(frozen=True)
class _Mixing:
    """The worst R-hat, bulk and tail ESS of a posterior and where each occurs, its chains and
    draws per chain, and whether the R-hat is the nested one over independent ensembles."""

    rhat: float
    rhat_at: str
    bulk: float
    bulk_at: str
    tail: float
    tail_at: str
    chains: int
    draws: int
    nested: bool

    @classmethod
    def of(cls, posterior: xr.Dataset, stats: xr.Dataset) -> _Mixing:
        """The figures of ``posterior``; the nested R-hat when ``stats`` labels two or more
        ensembles (emcee's independent ensembles, one label per walker)."""
        constant = posterior.max(("chain", "draw")) == posterior.min(("chain", "draw"))
        superchain = np.asarray(stats["ensemble"].values) if "ensemble" in stats else None
        nested = superchain is not None and np.unique(superchain).size > 1
        with np.errstate(invalid="ignore", divide="ignore"):  # constant elements give NaN
            if superchain is not None and nested:
                rhat_ds = _nested_rhat_dataset(posterior, superchain)
            else:
                rhat_ds = az.rhat(posterior)
            bulk_ds = az.ess(posterior, method="bulk")
            tail_ds = az.ess(posterior, method="tail")
        rhat, rhat_at = _extreme(rhat_ds, largest=True, constant=constant)
        bulk, bulk_at = _extreme(bulk_ds, largest=False, constant=constant)
        tail, tail_at = _extreme(tail_ds, largest=False, constant=constant)
        chains, draws = posterior.sizes["chain"], posterior.sizes["draw"]
        return cls(rhat, rhat_at, bulk, bulk_at, tail, tail_at, chains, draws, nested)

    def messages(self, gates: SamplingGates) -> list[str]:
        """One message per failed R-hat, bulk ESS or tail ESS gate."""
        messages = []
        rhat, rhat_max = self.rhat, gates.rhat_max
        if not rhat <= rhat_max and self.nested:
            messages.append(
                f"nested R-hat {rhat:.3f} > {rhat_max} for {self.rhat_at}: the independent "
                "ensembles (or the two halves of the run) disagree; run longer (more burn-in "
                "and steps), start closer to the posterior, or use NUTS"
            )
        elif not rhat <= rhat_max:
            messages.append(
                f"R-hat {rhat:.3f} > {rhat_max} for {self.rhat_at}: the chains disagree; run "
                "longer chains (more warm-up and samples), start them from a better point, or "
                "reparameterise"
            )
        if not self.bulk >= gates.ess_bulk_min:
            messages.append(
                f"bulk ESS {self.bulk:.0f} < {gates.ess_bulk_min:.0f} for {self.bulk_at} "
                f"({self.chains} chains x {self.draws} draws): draw more samples or chains, or "
                "reparameterise to reduce autocorrelation"
            )
        if gates.ess_tail_min is not None and not self.tail >= gates.ess_tail_min:
            messages.append(
                f"tail ESS {self.tail:.0f} < {gates.ess_tail_min:.0f} for {self.tail_at}: the "
                "5 %/95 % quantiles are poorly resolved; draw more samples"
            )
        return messages


def _divergences(
    stats: xr.Dataset, total: int, max_divergences: int
) -> tuple[int | None, list[str]]:
    """NUTS's divergent transitions (``None`` without a ``diverging`` statistic) and the
    message when there are more than ``max_divergences`` (a share of the ``total`` draws)."""
    if "diverging" not in stats:
        return None, []
    divergences = int(np.asarray(stats["diverging"]).sum())
    if divergences <= max_divergences:
        return divergences, []
    return divergences, [
        f"{divergences} divergent transitions ({100 * divergences / total:.1f}"
        f" % of draws) > {max_divergences}: the sampler cannot follow the posterior's "
        "curvature; raise target_accept (e.g. 0.95), or reparameterise (a non-centred "
        "form for hierarchical scales, standardised parameters)"
    ]


def _ebfmi(
    idata: az.InferenceData, stats: xr.Dataset, ebfmi_min: float
) -> tuple[tuple[float, ...] | None, list[str]]:
    """E-BFMI per chain (``None`` without an ``energy`` statistic) and the message naming the
    chains below ``ebfmi_min``."""
    if "energy" not in stats:
        return None, []
    ebfmi = tuple(float(e) for e in az.bfmi(idata))
    low = [(c, e) for c, e in enumerate(ebfmi) if not e >= ebfmi_min]
    if not low:
        return ebfmi, []
    listed = ", ".join(f"chain {c}: {e:.2f}" for c, e in low)
    return ebfmi, [
        f"E-BFMI below {ebfmi_min} ({listed}): the momentum resampling explores the "
        "energy levels poorly, typical of heavy tails or funnels; reparameterise"
    ]


def _run_length(stats: xr.Dataset, min_autocorr_lengths: float) -> tuple[float | None, list[str]]:
    """emcee's kept steps in autocorrelation times (``None`` without emcee's ``autocorr_time``
    attribute) and the message when they are fewer than ``min_autocorr_lengths``."""
    if "autocorr_time" not in stats.attrs:
        return None, []
    tau = float(np.max(json.loads(stats.attrs["autocorr_time"])))
    kept = int(stats.attrs["kept_steps"])
    lengths = kept / tau
    if not np.isfinite(tau):
        return lengths, [
            f"emcee's autocorrelation time could not be estimated from {kept} kept steps: "
            f"run at least {min_autocorr_lengths:.0f} times longer than it is likely to be"
        ]
    if not lengths >= min_autocorr_lengths:
        return lengths, [
            f"emcee kept {kept} steps = {lengths:.1f} autocorrelation times "
            f"(largest tau {tau:.0f} steps) < {min_autocorr_lengths:.0f}: run about "
            f"{int(np.ceil(min_autocorr_lengths * tau))} steps after burn-in, or use NUTS"
        ]
    return lengths, []


def summary_table(
    idata: az.InferenceData,
    *,
    var_names: Sequence[str] | None = None,
    hdi_prob: float = 0.9,
) -> pd.DataFrame:
    """Posterior summary per parameter (``arviz.summary``): mean, sd, HDI, MCSE, ESS, R-hat.

    Parameters
    ----------
    idata
        A posterior.
    var_names
        Variables to include (default: all posterior variables).
    hdi_prob
        Probability mass of the highest-density interval columns (0.9: ``hdi_5%``,
        ``hdi_95%``).

    Returns
    -------
    table
        One row per scalar parameter; ``print(table.to_string())`` shows it.
    """
    return az.summary(
        idata, var_names=list(var_names) if var_names is not None else None, hdi_prob=hdi_prob
    )
