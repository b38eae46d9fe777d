"""Fit adequacy: do the simulations that train the classifier reproduce the measured known runs?

After updating, the training data are posterior-predictive simulations (with the model-error
offsets where the source carries them). Before they train a classifier, the measured runs of
a known state (the healthy calibration runs) are held against them, per channel and
frequency band:

1. For a measured run at speed ``v``, the predictive distribution of its features is the
   simulated runs of that state at ``v`` plus the Welch scatter of a measured record
   (:func:`measurement_variance`), drawn ``replicates`` times per simulated run.
2. Each feature is standardised by the predictive mean and standard deviation, and the
   standardised values are averaged over the bins of each band: one score per channel and
   band. The same score of every predictive draw gives its null distribution, so the
   measured score's predictive p-value (PIT) ``u`` needs no Gaussian assumption.
3. Over the ``n`` measured runs, ``S = sum(Phi^-1(u)) / sqrt(n)`` is standard normal when
   the runs are draws of the predictive distribution. A cell with ``|S|`` above the
   two-sided Bonferroni bound at family-wise error rate ``alpha`` (over all cells) does not
   reproduce the measurements; the verdict is ``"reproduces"`` when no cell does.

How much: the mean difference of the measured and predicted log10 PSD in the cell, in dB
(10 x decades), and its ratio to the predictive standard deviation.

The check conditions on the fit: the same runs informed the posterior (and the model-error
scale), so it is an in-sample posterior-predictive check, not a leave-one-run-out one.
It is conservative for a systematic discrepancy (a missing mode, a gain error shared by the
runs) and says nothing about states that were not measured.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import stats

from .._types import Float
from ._generate import TrainingData

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
        """The cells that do not reproduce, worst first."""
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
        return sorted(cells, key=lambda cell: -abs(cell["statistic"]))

    def summary(self) -> str:
        """One line: the verdict, and where and by how much the worst cell is off."""
        head = f"the training simulations {self.verdict} the {self.runs} measured {self.state} runs"
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
    state: str = "healthy",
    seed: int = 0,
    alpha: float = ALPHA,
    bands: int = BANDS,
    replicates: int = 20,
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
        The measured runs' state.
    seed
        Seed of the scatter draws.
    alpha
        Family-wise false-alarm rate of the verdict.
    bands
        Number of frequency bands.
    replicates
        Scatter draws per simulated run.

    Returns
    -------
    Adequacy

    Raises
    ------
    ValueError
        For an unknown state, mismatched shapes, no measured run, or a speed at which fewer
        than 5 simulated runs of the state exist.
    """
    if state not in data.states:
        raise ValueError(f"state={state!r} is not one of the training data's {data.states}")
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha={alpha!r} must be in (0, 1)")
    x = np.asarray(features, dtype=float)
    v = np.asarray(speeds, dtype=float).reshape(-1)
    shape = data.features.shape[1:]
    if x.ndim != 3 or x.shape[1:] != shape or len(v) != len(x) or len(x) == 0:
        raise ValueError(
            f"features must be (run, {', '.join(map(str, shape))}) with one speed per run and "
            f"at least one run; got features {x.shape}, speeds {v.shape}"
        )
    var = np.broadcast_to(np.asarray(variance, dtype=float), shape)
    groups = band_edges(shape[1], bands)
    scores = _scores(data, x, v, var, state, groups, np.random.default_rng(seed), replicates)
    gauss, diff, ratio = scores["gauss"], scores["diff"], scores["ratio"]
    statistic = gauss.sum(axis=0) / np.sqrt(len(x))
    cells = statistic.size
    threshold = float(stats.norm.isf(alpha / (2 * cells)))
    verdict = "reproduces" if np.all(np.abs(statistic) <= threshold) else "does not reproduce"
    freqs = np.asarray(data.frequencies, dtype=float)
    step = float(freqs[1] - freqs[0]) if len(freqs) > 1 else 1.0
    edges = tuple(
        (float(freqs[g[0]] - step / 2 if g[0] else freqs[g[0]]), float(freqs[g[-1]] + step / 2))
        for g in groups
    )
    return Adequacy(
        verdict=verdict,
        state=state,
        runs=len(x),
        alpha=alpha,
        threshold=threshold,
        channels=tuple(data.channels),
        bands_hz=edges,
        statistic=statistic,
        offset_db=10.0 * diff.mean(axis=0),
        offset_sd=ratio.mean(axis=0),
    )


def healthy_outliers(
    data: TrainingData,
    features: Float[np.ndarray, "run channel freq"],
    speeds: Float[np.ndarray, " run"] | Sequence[float],
    variance: Float[np.ndarray, "channel freq"],
    *,
    state: str = "healthy",
    seed: int = 0,
    alpha: float = ALPHA,
    bands: int = BANDS,
    replicates: int = 20,
) -> tuple[np.ndarray, np.ndarray]:
    """Per run: is it unlike the simulated runs of ``state`` at its speed?

    The run's score is ``T = sum(Phi^-1(u)^2)`` over the channel-band cells of
    :func:`fit_adequacy` (``u`` its predictive p-values); its threshold is the ``1 - alpha``
    quantile of the same score over the predictive draws at that speed, so a run of the
    state is flagged with probability ``alpha`` when the simulations describe it.

    Returns
    -------
    scores, thresholds
        One of each per run.
    """
    x = np.asarray(features, dtype=float)
    v = np.asarray(speeds, dtype=float).reshape(-1)
    shape = data.features.shape[1:]
    var = np.broadcast_to(np.asarray(variance, dtype=float), shape)
    groups = band_edges(shape[1], bands)
    rng = np.random.default_rng(seed)
    out = _scores(data, x, v, var, state, groups, rng, replicates, alpha=alpha)
    return (out["gauss"] ** 2).sum(axis=(1, 2)), out["threshold"]


def _scores(data, x, v, var, state, groups, rng, replicates, alpha=ALPHA):
    """Per measured run: Phi^-1 of its predictive p-values per cell, its offsets, and the
    ``1 - alpha`` quantile of the summed squared scores of the predictive draws."""
    shape = data.features.shape[1:]
    own = data.labels == data.states.index(state)
    n = len(x)
    gauss = np.empty((n, shape[0], len(groups)))
    diff = np.empty_like(gauss)
    ratio = np.empty_like(gauss)
    threshold = np.empty(n)
    cache: dict[float, tuple[np.ndarray, np.ndarray, np.ndarray, float]] = {}
    for i, speed in enumerate(v):
        key = float(speed)
        if key not in cache:
            at = own & np.isclose(data.speeds, speed, rtol=1e-9, atol=0.0)
            if at.sum() < 5:
                raise ValueError(
                    f"run {i} has speed {speed} but the data hold {int(at.sum())} simulated "
                    f"{state} runs there (need 5): generate at the campaign's speeds"
                )
            sims = data.features[at]
            draws = sims[:, None] + np.sqrt(var) * rng.standard_normal(
                (len(sims), replicates, *shape)
            )
            draws = draws.reshape(-1, *shape)
            mean, sd = draws.mean(axis=0), draws.std(axis=0) + 1e-12
            scores = _band_scores((draws - mean) / sd, groups)
            m = scores.shape[0]
            # the draws' own p-values are their ranks among all draws
            ranks = np.argsort(np.argsort(scores, axis=0), axis=0)
            t_null = (stats.norm.ppf((ranks + 0.5) / m) ** 2).sum(axis=(1, 2))
            null = np.sort(scores, axis=0)
            cache[key] = (mean, sd, null, float(np.quantile(t_null, 1.0 - alpha)))
        mean, sd, null, t_bound = cache[key]
        score = _band_scores(((x[i] - mean) / sd)[None], groups)[0]
        m = null.shape[0]
        below = np.empty_like(score)
        for c in range(shape[0]):
            for b in range(len(groups)):
                below[c, b] = np.searchsorted(null[:, c, b], score[c, b])
        gauss[i] = stats.norm.ppf((below + 0.5) / (m + 1))
        diff[i] = _band_scores((x[i] - mean)[None], groups)[0]
        ratio[i] = score
        threshold[i] = t_bound
    return {"gauss": gauss, "diff": diff, "ratio": ratio, "threshold": threshold}


def _band_scores(z: np.ndarray, groups: list[np.ndarray]) -> np.ndarray:
    """Mean over each band's bins: (n, channel, freq) -> (n, channel, band)."""
    return np.stack([z[..., g].mean(axis=-1) for g in groups], axis=-1)
