"""The decision rule's probability of naming a cause, and the cheapest campaign that reaches it.

Both the detection limits (:mod:`~bayesdoor.diagnose._limits`) and the measurement plans
(:mod:`~bayesdoor.diagnose._plan`) start from each run's expected held-out log-density
difference ``m_r`` and its variance ``q_r`` were the cause there at a given size, with the
extension at its true values. The refit does not know them: it fits the ``p`` free
parameters on the other fold's runs. To second order about the truth, the held-out run
``r`` then gains ``delta' s_r - delta' H_r delta / 2`` more, with ``delta`` the estimate's
error, ``H_r`` the run's curvature of its log density in the parameters and ``s_r`` its score
at the truth (mean 0, covariance ``kappa H_r``: the log density treats the Welch bins as
independent, their sums vary ``kappa`` times more, :func:`~bayesdoor.diagnose._limits.
bin_variance_factor`). The estimate from the training runs has covariance
``kappa H_train^-1`` (the sandwich), so with every run's curvature along the parameters in
proportion to its information ``h_r`` (the size's, :func:`information`), the cost

    c_r = delta' H_r delta = kappa h_r chi2_p / h_train            (one chi2_p per fold)

lowers the run's difference by ``c_r / 2`` and adds ``kappa c_r`` to its variance; the folds
are the judgement's (the runs sorted by speed dealt in turn). In expectation the runs of a
fold lose ``kappa p / 2`` in all, ``kappa`` times the textbook ``p / 2`` of an estimate of
``p`` parameters from as many runs as are judged; the draws keep what the expectation loses:
the loss is shared by a fold's runs (it shifts them together, which the rule's t statistic
does not see as spread) and it scatters with ``chi2_p``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .._types import Float, Int
from ._gain import capped_t, rule_thresholds, t_statistic

#: most runs per condition a plan proposes
MAX_RUNS_PER_CONDITION = 40
#: folds of the held-out judgement (``DiagnosisSettings.folds``)
FOLDS = 2


def fold_labels(
    order: Float[np.ndarray, " run"] | Float[np.ndarray, "run k"], k: int = FOLDS
) -> np.ndarray:
    """Each run's fold of the held-out judgement: the runs sorted by ``order`` (the first
    column first, ties by the next) dealt to the ``k`` folds in turn (the dealing of
    :func:`~bayesdoor.diagnose._held_out.held_out_folds`)."""
    key = np.asarray(order, dtype=float)
    ranked = np.argsort(key, kind="stable") if key.ndim == 1 else np.lexsort(key.T[::-1])
    labels = np.empty(len(key), dtype=int)
    labels[ranked] = np.arange(len(key)) % k
    return labels


def estimation_cost(
    information: Float[np.ndarray, "*size run"],
    folds: Int[np.ndarray, " run"],
    chi2: Float[np.ndarray, "draw fold"],
    correlation: float,
) -> Float[np.ndarray, "*size draw run"]:
    """Each run's cost ``c_r = kappa h_r chi2_p / h_train`` of the refit's estimation error
    per draw (the module's formula; ``chi2`` holds one ``chi2_p`` draw per fold, ``p`` the
    free parameters, and ``kappa`` is ``correlation``)."""
    h = np.maximum(np.asarray(information, dtype=float), 0.0)
    folds = np.asarray(folds, dtype=int)
    train = np.stack([h[..., folds != f].sum(axis=-1) for f in range(chi2.shape[-1])], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(train[..., folds] > 0, h / train[..., folds], 0.0)  # (*size, run)
    return correlation * share[..., None, :] * np.asarray(chi2)[:, folds]


def naming_probability(
    mean: Float[np.ndarray, "*size run"],
    variance: Float[np.ndarray, "*size run"],
    normals: Float[np.ndarray, "draw run"],
    cost: Float[np.ndarray, "*size draw run"] | None = None,
    correlation: float = 1.0,
) -> Float[np.ndarray, "*size"]:
    """The share of draws ``d = mean - c / 2 + sqrt(variance + correlation c) z`` that the
    rule's statistics pass (the plain or the capped over its threshold for as many held-out
    runs); ``c`` the refit's estimation cost per draw (:func:`estimation_cost`; ``None``:
    the extension judged at its true values)."""
    mean, variance = np.asarray(mean, dtype=float), np.asarray(variance, dtype=float)
    on_t, on_capped = rule_thresholds(mean.shape[-1])
    c = 0.0 if cost is None else np.asarray(cost, dtype=float)
    spread = np.sqrt(variance[..., None, :] + correlation * c)
    d = mean[..., None, :] - 0.5 * c + spread * normals
    named = (t_statistic(d) > on_t) | (capped_t(d) > on_capped)
    return named.mean(axis=-1)


@dataclasses.dataclass(frozen=True)
class RunGains:
    """Each run's expected held-out difference at a size, its variance and its information
    about the cause's parameters (:func:`~bayesdoor.diagnose._limits.expected_differences`,
    :func:`~bayesdoor.diagnose._limits.information`), with what judging them needs."""

    mean: Float[np.ndarray, " run"]
    variance: Float[np.ndarray, " run"]
    information: Float[np.ndarray, " run"]
    parameters: int
    correlation: float

    def probability(self, draws: int, seed: Any, folds: np.ndarray | None = None) -> float:
        """The probability that the rule names the cause in these runs (``folds``: each
        run's fold; ``None``: alternate runs)."""
        n = self.mean.size
        folds = np.arange(n) % FOLDS if folds is None else folds
        rng = np.random.default_rng(seed)
        normals = rng.standard_normal((draws, n))
        chi2 = rng.chisquare(self.parameters, (draws, FOLDS)) if self.parameters else None
        cost = (
            None
            if chi2 is None
            else estimation_cost(self.information, folds, chi2, self.correlation)
        )
        return float(naming_probability(self.mean, self.variance, normals, cost, self.correlation))


@dataclasses.dataclass(frozen=True)
class CampaignPlan:
    """The campaign that names a cause at a size with the stated probability.

    Attributes
    ----------
    cause, size, unit, configuration
        What is to be named (the cause's typical configuration unless chosen).
    power
        The probability asked for.
    conditions
        The operating conditions to run (the campaign's own values).
    runs_per_condition
        Runs at each; ``None`` when no plan up to :data:`MAX_RUNS_PER_CONDITION` runs per
        condition reaches the power.
    probability
        The probability that the rule names the cause in that campaign (in the largest
        campaign tried when none reaches the power).
    record_s
        The record length of each run, s (the campaign's).
    current
        The probability in the campaign as it is.
    display
        A unit to show the size in and its factor from ``unit`` (``("um", 1e6)``; ``""``:
        ``unit`` itself).
    ratio
        The transmission planned for: the machine shows the cause at ``size`` as the model
        shows ``ratio`` times it (the least of a family's machines,
        :class:`~bayesdoor.diagnose.Transmission`); ``None``: as the model does.
    """

    cause: str
    size: float
    unit: str
    configuration: str
    power: float
    conditions: tuple[float, ...]
    runs_per_condition: int | None
    probability: float
    record_s: float
    current: float
    display: tuple[str, float] = ("", 1.0)
    ratio: float | None = None

    @property
    def machines(self) -> str:
        """Which machines the plan holds for, in words."""
        if self.ratio is None:
            return "if the machine transmits it as the model does"
        return (
            f"on every machine of its family (the least of which shows it as the model "
            f"shows {self.ratio:.2g} times the size)"
        )

    @property
    def runs(self) -> int | None:
        """The cost: runs in all (``None``: no plan reaches the power)."""
        if self.runs_per_condition is None:
            return None
        return self.runs_per_condition * len(self.conditions)

    @property
    def shown_size(self) -> str:
        """The size in its display unit."""
        return f"{self.size * self.display[1]:.3g} {self.display[0] or self.unit}"

    def describe(self) -> str:
        where = ", ".join(f"{c:g}" for c in self.conditions)
        if self.runs_per_condition is None:
            return (
                f"no campaign of up to {MAX_RUNS_PER_CONDITION} runs per condition at these "
                f"conditions names {self.cause} at {self.shown_size} with "
                f"{100 * self.power:.0f} % probability (best {100 * self.probability:.0f} %) "
                f"{self.machines}"
            )
        at = (
            f"at {where}"
            if len(self.conditions) == 1
            else f"at each of {len(self.conditions)} conditions ({where})"
        )
        return (
            f"{self.runs_per_condition} runs {at} ({self.runs} runs of "
            f"{self.record_s:.3g} s in all) name {self.cause} at "
            f"{self.shown_size} ({self.configuration}) with "
            f"{100 * self.probability:.0f} % probability {self.machines} (this campaign: "
            f"{100 * self.current:.0f} %)"
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "size": self.size,
            "unit": self.unit,
            "configuration": self.configuration,
            "power": self.power,
            "conditions": list(self.conditions),
            "runs_per_condition": self.runs_per_condition,
            "runs": self.runs,
            "probability": self.probability,
            "record_s": self.record_s,
            "current_probability": self.current,
            "ratio": self.ratio,
            "words": self.describe(),
        }


@dataclasses.dataclass(frozen=True)
class PlanTarget:
    """What a campaign is planned to name: a cause at a size, in its configuration.

    ``display`` is a unit to show the size in and its factor from ``unit`` (``("um",
    1e6)``; ``""``: ``unit`` itself).
    """

    cause: str
    size: float
    unit: str
    configuration: str
    display: tuple[str, float] = ("", 1.0)


def design_campaign(
    gains: RunGains,
    operating: Float[np.ndarray, " run"],
    order: Float[np.ndarray, " run"] | None = None,
    *,
    target: PlanTarget,
    power: float,
    record_s: float,
    draws: int = 2000,
    seed: int = 0,
) -> CampaignPlan:
    """The cheapest campaign at the runs' operating conditions (fewest runs, then fewest
    conditions) that the rule names with probability ``power``: ``m`` runs at each of the
    ``k`` conditions best by their runs' expected evidence hold each condition's mean
    difference, variance and information ``m`` times, judged as ``m k`` held-out runs in the
    judgement's folds. ``order`` sorts the runs into folds (the speeds; ``None``:
    ``operating``)."""
    operating = np.asarray(operating, dtype=float)
    order = operating if order is None else np.asarray(order, dtype=float)
    conditions = np.unique(operating)
    by = [operating == c for c in conditions]
    m_c = np.array([gains.mean[b].mean() for b in by])
    q_c = np.array([gains.variance[b].mean() for b in by])
    h_c = np.array([gains.information[b].mean() for b in by])
    o_c = np.array([order[b].mean() for b in by])
    rank = np.argsort(-(m_c / np.sqrt(np.maximum(q_c, 1e-300))))

    def judged(g: RunGains, folds: np.ndarray | None) -> float:
        return g.probability(draws, [seed, g.mean.size], folds)

    current = judged(gains, fold_labels(order))
    best: tuple[int, int, float, np.ndarray] | None = None
    largest = (0.0, conditions[rank[:1]])
    for k in range(1, len(conditions) + 1):
        chosen = rank[:k]

        def at(m: int, chosen: np.ndarray = chosen) -> float:
            g = dataclasses.replace(
                gains,
                mean=np.repeat(m_c[chosen], m),
                variance=np.repeat(q_c[chosen], m),
                information=np.repeat(h_c[chosen], m),
            )
            return judged(g, fold_labels(np.repeat(o_c[chosen], m)))

        low, high = max(1, -(-4 // k)), MAX_RUNS_PER_CONDITION
        top = at(high)
        if top > largest[0]:
            largest = (top, conditions[chosen])
        if top < power:
            continue
        while low < high:  # the fewest runs per condition that reach the power
            mid = (low + high) // 2
            if at(mid) >= power:
                high = mid
            else:
                low = mid + 1
        if best is None or low * k < best[0] * best[1]:
            best = (low, k, at(low), conditions[chosen])
    if best is None:
        chosen_conditions, per, prob = largest[1], None, largest[0]
    else:
        per, _, prob, chosen_conditions = best
    return CampaignPlan(
        cause=target.cause,
        size=float(target.size),
        unit=target.unit,
        configuration=target.configuration,
        power=power,
        conditions=tuple(float(c) for c in np.sort(chosen_conditions)),
        runs_per_condition=per,
        probability=prob,
        record_s=float(record_s),
        current=current,
        display=target.display,
    )
