"""Fit adequacy: do the simulations that train the classifier reproduce the measured known runs?

After updating, the training data are posterior-predictive simulations (with the model-error
offsets where the source carries them). Before they train a classifier, the measured runs of
a known state (the healthy calibration runs) are held against them, per channel and
frequency band:

1. For a measured run at speed ``v``, the predictive distribution of its features is the
   simulated runs of that state at ``v`` plus the Welch scatter of a measured record
   (:func:`measurement_variance`).
2. Each feature is standardised by the predictive mean and standard deviation, and the
   standardised values are averaged over the bins of each band: one score per channel and
   band. The predictive distribution of that score is the mixture, over the simulated runs,
   of the band-averaged scatter about each run's score; its CDF at the measured score is the
   run's predictive p-value (PIT) ``u``, with no Gaussian assumption on the simulations.
3. Over the ``n`` measured runs, ``S = sum(Phi^-1(u)) / sqrt(n (1 + (n - 1) / m))`` is
   about standard normal when the runs are draws of the predictive distribution (the
   runs share the ``m`` simulated runs of their speed, which correlates their p-values by
   about ``1 / m``). A cell with ``|S|`` above the
   two-sided Bonferroni bound at family-wise error rate ``alpha`` (over all cells) does not
   reproduce the measurements; the verdict is ``"reproduces"`` when no cell does.

How much: the mean difference of the measured and predicted log10 PSD in the cell, in dB
(10 x decades), and its ratio to the predictive standard deviation.

The check conditions on the fit: the same runs informed the posterior (and the model-error
scale), so it is an in-sample posterior-predictive check, not a leave-one-run-out one.
It says nothing about states that were not measured. Its power grows with the simulated
runs per speed ``m``: a measured score beyond every simulated one gets the p-value
``1 / (2 (m + 1))``, no smaller, since ``m`` runs say nothing finer about the tails (with the
quick job's ~33 runs per speed and 10 calibration runs, ``|S|`` reaches about 6).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import stats

from .._types import Float
from ._generate import TrainingData
from ._model_error import with_measured_discrepancy
from ._points import at_point, point_key
from ._points import measured_points as _measured_points
from ._points import show_point as _show

#: family-wise false-alarm rate of the adequacy verdict (all channels and bands together)
ALPHA = 0.01
#: frequency bands of the check (equal groups of the features' bins)
BANDS = 6


@dataclasses.dataclass(frozen=True)
class Adequacy:
    """The result of :func:`fit_adequacy`.

    Attributes
    ----------
    verdict
        ``"reproduces"`` or ``"does not reproduce"``.
    state
        The state of the measured runs.
    runs
        How many measured runs were checked.
    alpha
        Family-wise false-alarm rate of the verdict.
    threshold
        The bound on ``|statistic|`` (two-sided Bonferroni over the cells).
    channels
        Channel names.
    bands_hz
        ``(low, high)`` edges of each band (Hz).
    statistic
        ``(channel, band)``: ``S``, standard normal when the model reproduces the runs.
    offset_db
        ``(channel, band)``: mean measured minus predicted PSD (dB).
    offset_sd
        ``(channel, band)``: the same difference in predictive standard deviations.
    """

    verdict: str
    state: str
    runs: int
    alpha: float
    threshold: float
    channels: tuple[str, ...]
    bands_hz: tuple[tuple[float, float], ...]
    statistic: np.ndarray
    offset_db: np.ndarray
    offset_sd: np.ndarray

    @property
    def reproduces(self) -> bool:
        return self.verdict == "reproduces"

    def failing(self) -> list[dict[str, Any]]:
        """The cells that do not reproduce, worst first (by ``|S|``, then by the offset)."""
        cells = []
        for c, channel in enumerate(self.channels):
            for b, band in enumerate(self.bands_hz):
                s = float(self.statistic[c, b])
                if abs(s) > self.threshold:
                    cells.append(
                        {
                            "channel": channel,
                            "band_hz": [float(band[0]), float(band[1])],
                            "statistic": s,
                            "offset_db": float(self.offset_db[c, b]),
                            "offset_sd": float(self.offset_sd[c, b]),
                        }
                    )
        # |S| has a ceiling (the p-values' resolution, see above): among cells at it, the
        # larger offset in predictive standard deviations comes first
        return sorted(
            cells, key=lambda cell: (-round(abs(cell["statistic"]), 1), -abs(cell["offset_sd"]))
        )

    def summary(self) -> str:
        """One line: the verdict, and where and by how much the worst cell is off."""
        verb = "reproduce" if self.reproduces else "do not reproduce"
        head = f"the simulations {verb} the {self.runs} measured {self.state} runs"
        bad = self.failing()
        if not bad:
            worst = float(np.max(np.abs(self.statistic)))
            return f"{head} (largest |S| {worst:.1f}, bound {self.threshold:.1f})"
        w = bad[0]
        return (
            f"{head}: {len(bad)} of {self.statistic.size} channel-bands off, worst "
            f"{w['channel']} {w['band_hz'][0]:.0f}-{w['band_hz'][1]:.0f} Hz by "
            f"{w['offset_db']:+.1f} dB ({w['offset_sd']:+.1f} SD; S {w['statistic']:+.1f}, "
            f"bound {self.threshold:.1f})"
        )

    def to_json(self) -> dict[str, Any]:
        bad = self.failing()
        return {
            "verdict": self.verdict,
            "state": self.state,
            "runs": self.runs,
            "alpha": self.alpha,
            "threshold": self.threshold,
            "channels": list(self.channels),
            "bands_hz": [list(b) for b in self.bands_hz],
            "statistic": np.round(self.statistic, 4).tolist(),
            "offset_db": np.round(self.offset_db, 4).tolist(),
            "offset_sd": np.round(self.offset_sd, 4).tolist(),
            "failing": bad,
            "worst": bad[0] if bad else None,
            "summary": self.summary(),
        }


@dataclasses.dataclass(frozen=True)
class AdequacyCheck:
    """The statistics of :func:`fit_adequacy` and :func:`healthy_outliers`.

    Parameters
    ----------
    alpha
        Family-wise false-alarm rate of the verdict (per run for :func:`healthy_outliers`).
    bands
        Number of frequency bands (equal groups of the features' bins).
    """

    alpha: float = ALPHA
    bands: int = BANDS


def band_edges(n_bins: int, bands: int = BANDS) -> list[np.ndarray]:
    """Bin indices of ``bands`` contiguous, nearly equal groups of ``n_bins`` bins."""
    if not 1 <= bands <= n_bins:
        raise ValueError(f"bands={bands} must be between 1 and the {n_bins} frequency bins")
    return [idx for idx in np.array_split(np.arange(n_bins), bands)]


def fit_adequacy(
    data: TrainingData,
    features: Float[np.ndarray, "run channel freq"],
    speeds: Float[np.ndarray, " run"] | Sequence[float],
    variance: Float[np.ndarray, "channel freq"],
    *,
    state: str | None = None,
    seed: int = 0,
    discrepancy: bool = False,
    check: AdequacyCheck = AdequacyCheck(),
) -> Adequacy:
    """Hold measured runs of a known state against the simulated runs of that state.

    Parameters
    ----------
    data
        The simulated training data (train and validation runs are both used).
    features
        Classifier features of the measured runs (:func:`campaign_features`).
    speeds
        Each measured run's operating speed (a speed the data were simulated at).
    variance
        Per-feature variance a measured record adds to a simulation (decades^2), e.g.
        :func:`measurement_variance` without the model error (the Welch scatter).
    state
        The measured runs' state; ``None``: the training data's healthy state
        (:attr:`TrainingData.healthy`).
    seed
        Seed of the scatter draws.
    discrepancy
        The training data carry the measured discrepancy of these runs
        (:func:`with_measured_discrepancy` is applied here, to ``data`` without it): each
        run is then held against simulations that carry the discrepancies of the *other*
        runs only (leave one run out), so the check is not in-sample.
    check
        The false-alarm rate of the verdict and the number of frequency bands.

    Returns
    -------
    Adequacy

    Raises
    ------
    ValueError
        For an unknown state, mismatched shapes, no measured run, or a speed at which fewer
        than 5 simulated runs of the state exist.
    """
    state = data.healthy if state is None else state
    x, v, var, groups = _inputs(data, features, speeds, variance, state, check)
    if not discrepancy:
        scores = _scores(data, x, v, var, state, groups)
    else:
        scores = _left_out_scores(data, x, v, var, state, groups, seed)
    # the runs share their predictive sample: the p-values of two runs at one speed correlate
    # by about 1/m (m simulated runs there), so the sum's variance is n (1 + (n - 1) / m)
    m = float(np.min(scores["simulations"]))
    n = len(x)
    statistic = scores["gauss"].sum(axis=0) / np.sqrt(n * (1.0 + (n - 1) / m))
    threshold = float(stats.norm.isf(check.alpha / (2 * statistic.size)))
    verdict = "reproduces" if np.all(np.abs(statistic) <= threshold) else "does not reproduce"
    return Adequacy(
        verdict=verdict,
        state=state,
        runs=len(x),
        alpha=check.alpha,
        threshold=threshold,
        channels=tuple(data.channels),
        bands_hz=_bands_hz(data.frequencies, groups),
        statistic=statistic,
        offset_db=10.0 * scores["diff"].mean(axis=0),
        offset_sd=scores["ratio"].mean(axis=0),
    )


def _left_out_scores(data, x, v, var, state, groups, seed: int) -> dict[str, np.ndarray]:
    """:func:`_scores` of each run against the simulations that carry the measured
    discrepancies of the other runs (:func:`with_measured_discrepancy`, seed ``seed + 1 + i``
    for run ``i``)."""
    if len(x) < 2:
        raise ValueError("a leave-one-run-out check of the discrepancy needs two runs or more")
    parts = []
    for i in range(len(x)):
        others = np.delete(np.arange(len(x)), i)
        shifted = with_measured_discrepancy(
            data, x[others], v[others], seed=seed + 1 + i, state=state
        )
        parts.append(_scores(shifted, x[i : i + 1], v[i : i + 1], var, state, groups))
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _bands_hz(frequencies, groups: list[np.ndarray]) -> tuple[tuple[float, float], ...]:
    """``(low, high)`` edges (Hz) of each band: half a bin beyond its outer bins' centres
    (the first band starts at its first bin's centre when that is the lowest bin)."""
    freqs = np.asarray(frequencies, dtype=float)
    step = float(freqs[1] - freqs[0]) if len(freqs) > 1 else 1.0
    return tuple(
        (float(freqs[g[0]] - step / 2 if g[0] else freqs[g[0]]), float(freqs[g[-1]] + step / 2))
        for g in groups
    )


def healthy_outliers(
    data: TrainingData,
    features: Float[np.ndarray, "run channel freq"],
    speeds: Float[np.ndarray, " run"] | Sequence[float],
    variance: Float[np.ndarray, "channel freq"],
    *,
    state: str | None = None,
    seed: int = 0,
    replicates: int = 20,
    check: AdequacyCheck = AdequacyCheck(),
) -> tuple[np.ndarray, np.ndarray]:
    """Per run: is it unlike the simulated runs of ``state`` (``None``: the training data's
    healthy state) at its speed?

    The run's score is ``T = sum(Phi^-1(u)^2)`` over the channel-band cells of
    :func:`fit_adequacy` (``u`` its predictive p-values); its threshold is the ``1 - alpha``
    quantile (``check.alpha``) of the same score over ``replicates`` predictive draws per
    simulated run at that speed, so a run of the state is flagged with probability ``alpha``
    when the simulations describe it.

    Returns
    -------
    scores, thresholds
        One of each per run.

    Raises
    ------
    ValueError
        As :func:`fit_adequacy`.
    """
    state = data.healthy if state is None else state
    x, v, var, groups = _inputs(data, features, speeds, variance, state, check)
    null = (np.random.default_rng(seed), replicates, check.alpha)
    out = _scores(data, x, v, var, state, groups, null=null)
    return (out["gauss"] ** 2).sum(axis=(1, 2)), out["threshold"]


def _inputs(data, features, speeds, variance, state, check: AdequacyCheck):
    """The checked inputs of :func:`fit_adequacy` and :func:`healthy_outliers`: the features
    and speeds as arrays, the variance broadcast to a feature's shape, the bands' bins."""
    if state not in data.states:
        raise ValueError(f"state={state!r} is not one of the training data's {data.states}")
    if not 0.0 < check.alpha < 1.0:
        raise ValueError(f"alpha={check.alpha!r} must be in (0, 1)")
    x = np.asarray(features, dtype=float)
    v = _measured_points(speeds, data.speeds)
    shape = data.features.shape[1:]
    if x.ndim != 3 or x.shape[1:] != shape or len(v) != len(x) or len(x) == 0:
        raise ValueError(
            f"features must be (run, {', '.join(map(str, shape))}) with one speed per run and "
            f"at least one run; got features {x.shape}, speeds {v.shape}"
        )
    var = np.broadcast_to(np.asarray(variance, dtype=float), shape)
    return x, v, var, band_edges(shape[1], check.bands)


def _scores(data, x, v, var, state, groups, null=None):
    """Per measured run: Phi^-1 of its predictive p-values per cell and its offsets; with
    ``null = (rng, replicates, alpha)`` also the ``1 - alpha`` quantile of the summed squared
    scores of ``replicates`` predictive draws per simulated run (``threshold``, NaN without).

    The predictive distribution of a band score is the mixture, over the ``m`` simulated
    runs at the run's speed, of Gaussians of the band-averaged measurement scatter about
    each simulated run's score; its CDF at the measured score is the p-value.
    """
    shape = data.features.shape[1:]
    own = data.labels == data.states.index(state)
    n = len(x)
    gauss = np.empty((n, shape[0], len(groups)))
    diff = np.empty_like(gauss)
    ratio = np.empty_like(gauss)
    threshold = np.empty(n)
    sims_at = np.empty(n)
    cache: dict[float | tuple[float, ...], tuple] = {}
    for i, speed in enumerate(v):
        key = point_key(speed)
        if key not in cache:
            at = own & at_point(data.speeds, speed)
            if at.sum() < 5:
                raise ValueError(
                    f"run {i} has speed {_show(speed)} but the data hold {int(at.sum())} "
                    f"simulated {state} runs there (need 5): generate at the campaign's speeds"
                )
            sims = data.features[at]
            mean = sims.mean(axis=0)
            sd = np.sqrt(sims.var(axis=0) + var) + 1e-12
            centres = _band_scores((sims - mean) / sd, groups)  # (m, channel, band)
            # the standard deviation of a band's mean standardised scatter
            spread = np.sqrt(
                np.stack([(var / sd**2)[..., g].sum(-1) / len(g) ** 2 for g in groups], -1)
            )
            spread = np.maximum(spread, 1e-6)
            bound = np.nan if null is None else _null_bound(centres, spread, *null)
            cache[key] = (mean, sd, centres, spread, bound)
        mean, sd, centres, spread, bound = cache[key]
        score = _band_scores(((x[i] - mean) / sd)[None], groups)[0]
        gauss[i] = stats.norm.ppf(_mixture_cdf(score[None], centres, spread)[0])
        diff[i] = _band_scores((x[i] - mean)[None], groups)[0]
        ratio[i] = score
        threshold[i] = bound
        sims_at[i] = len(centres)
    return {
        "gauss": gauss,
        "diff": diff,
        "ratio": ratio,
        "threshold": threshold,
        "simulations": sims_at,
    }


def _null_bound(centres, spread, rng, replicates: int, alpha: float) -> float:
    """The ``1 - alpha`` quantile of the summed squared scores of the predictive draws: each
    simulated run plus ``replicates`` scatter draws, held against the others (leave one out)."""
    t_null = []
    for j in range(len(centres)):
        others = np.delete(centres, j, axis=0)
        noise = spread * rng.standard_normal((replicates, *spread.shape))
        u = _mixture_cdf(centres[j] + noise, others, spread)
        t_null.append((stats.norm.ppf(u) ** 2).sum(axis=(1, 2)))
    return float(np.quantile(np.concatenate(t_null), 1.0 - alpha))


def _mixture_cdf(z: np.ndarray, centres: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """CDF at ``z`` (k, channel, band) of the mixture of N(centre, spread^2) over the centres
    (m, channel, band); kept off 0 and 1 by half a simulated run's weight."""
    m = centres.shape[0]
    cdf = stats.norm.cdf((z[:, None] - centres[None]) / spread).mean(axis=1)
    return np.clip(cdf, 0.5 / (m + 1), 1.0 - 0.5 / (m + 1))


def _band_scores(z: np.ndarray, groups: list[np.ndarray]) -> np.ndarray:
    """Mean over each band's bins: (n, channel, freq) -> (n, channel, band)."""
    return np.stack([z[..., g].mean(axis=-1) for g in groups], axis=-1)
