"""Held-out evidence for a model extension: J and log predictive density, base against extended.

Both models are judged on the same spectra (log10 Welch PSD per run, channel and bin) of runs
they were not fitted on. Each model's predictive distribution of a run's spectrum is

    y_rcf ~ Normal(m_rcf + delta_cf, s_r^2 + sigma_c^2)

with ``m`` the model's simulated spectrum, ``s_r^2`` the Welch variance of the run's estimate,
and the model's discrepancy estimated on the training runs: ``delta_c(f)`` its smooth part (the
running median over frequency of the training runs' mean residual, :func:`smooth_discrepancy`)
and ``sigma_c^2`` the remaining scatter per channel. The base model thus competes with an
anonymous smooth discrepancy (Kennedy and O'Hagan 2001); a named extension wins only where it
predicts what a smooth correction cannot: a resonance, a tone, a line, a leak's spectral shape.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .._types import Float
from ._residual import smooth_discrepancy

#: the ELPD difference must exceed this many of its standard errors to be decisive
DECISIVE_SE = 4.0
#: smallest discrepancy scale per channel, decades (keeps a perfect fit's density finite)
SIGMA_FLOOR = 0.01
#: the decision rule, in words (reported with every diagnosis)
RULE = (
    f"an extension is confirmed when, on held-out runs, its log predictive density exceeds the "
    f"base model's by more than {DECISIVE_SE:g} standard errors (the standard error of the sum "
    "of the per-run differences) and its J is lower; the verdict is the confirmed extension "
    "with the largest gain, else none"
)


@dataclasses.dataclass(frozen=True)
class Discrepancy:
    """A model's discrepancy estimated on training runs: smooth part and remaining scatter.

    Attributes
    ----------
    smooth
        ``delta_c(f)``, decades, added to the model's spectrum.
    variance
        ``sigma_c^2`` per channel, decades^2.
    """

    smooth: Float[np.ndarray, "channel freq"]
    variance: Float[np.ndarray, " channel"]


def estimate_discrepancy(
    model: Float[np.ndarray, "run channel freq"],
    measured: Float[np.ndarray, "run channel freq"],
    log_variance: Float[np.ndarray, " run"],
    half_width: int,
) -> Discrepancy:
    """The smooth discrepancy and the remaining scatter of a model on its training runs.

    Parameters
    ----------
    model, measured
        log10 spectra of the simulated and the measured runs.
    log_variance
        Welch variance of each measured run's log10 estimate.
    half_width
        Half-width (bins) of the running median.

    Returns
    -------
    Discrepancy
        ``smooth`` the running median of the run-mean residual; ``variance`` the mean squared
        remaining residual less the mean Welch variance, floored at ``SIGMA_FLOOR^2``.
    """
    resid = np.asarray(measured, dtype=float) - np.asarray(model, dtype=float)
    smooth = smooth_discrepancy(resid.mean(axis=0), half_width)
    excess = np.mean((resid - smooth) ** 2, axis=(0, 2)) - np.mean(log_variance)
    return Discrepancy(smooth=smooth, variance=np.maximum(excess, SIGMA_FLOOR**2))


def log_predictive(
    model: Float[np.ndarray, "*pop run channel freq"],
    measured: Float[np.ndarray, "run channel freq"],
    log_variance: Float[np.ndarray, " run"],
    discrepancy: Discrepancy,
) -> Float[np.ndarray, "*pop run"]:
    """Log predictive density of each run's spectrum (summed over channels and bins)."""
    var = np.asarray(log_variance)[:, None, None] + discrepancy.variance[None, :, None]
    r = np.asarray(measured) - np.asarray(model) - discrepancy.smooth
    return -0.5 * np.sum(np.log(2.0 * np.pi * var) + r**2 / var, axis=(-2, -1))


def objective_per_run(
    model: Float[np.ndarray, "*pop run channel freq"],
    measured: Float[np.ndarray, "run channel freq"],
) -> Float[np.ndarray, "*pop run"]:
    """The paper's J of each run: the sum over channels of the RMS log-spectral misfit."""
    return np.sum(np.sqrt(np.mean((np.asarray(model) - measured) ** 2, axis=-1)), axis=-1)


@dataclasses.dataclass(frozen=True)
class Gain:
    """Held-out J and log predictive density of the base and the extended model.

    Attributes
    ----------
    j_before, j_after
        Mean J over the held-out runs: the paper's objective on the diagnosis spectra, of
        each model's prediction with its smooth discrepancy (estimated on the training runs;
        without it, J of a model whose spectrum lies broadly above the measured one rises when
        a correct resonance adds power there).
    elpd_before, elpd_after
        Sum over the held-out runs of the log predictive density.
    elpd_difference, elpd_se
        ``elpd_after - elpd_before`` and its standard error, ``sqrt(n var(d_r))`` over the
        per-run differences ``d_r`` (runs are the independent units).
    n_runs
        Held-out runs.
    decisive
        Whether the rule (:data:`RULE`) is met.
    """

    j_before: float
    j_after: float
    elpd_before: float
    elpd_after: float
    elpd_difference: float
    elpd_se: float
    n_runs: int
    decisive: bool

    def to_json(self) -> dict[str, Any]:
        return {
            "j_before": self.j_before,
            "j_after": self.j_after,
            "delta_j": self.j_after - self.j_before,
            "elpd_before": self.elpd_before,
            "elpd_after": self.elpd_after,
            "delta_elpd": self.elpd_difference,
            "elpd_se": self.elpd_se,
            "held_out_runs": self.n_runs,
            "decisive": self.decisive,
        }

    def describe(self) -> str:
        return (
            f"held-out ELPD {self.elpd_before:.1f} -> {self.elpd_after:.1f} "
            f"({self.elpd_difference:+.1f} +- {self.elpd_se:.1f}), J {self.j_before:.4f} -> "
            f"{self.j_after:.4f} over {self.n_runs} runs: "
            + ("decisive" if self.decisive else "not decisive")
        )


def compare_held_out(
    lpd_before: Float[np.ndarray, " run"],
    lpd_after: Float[np.ndarray, " run"],
    j_before: Float[np.ndarray, " run"],
    j_after: Float[np.ndarray, " run"],
) -> Gain:
    """Apply the decision rule to per-run held-out densities and J of two models.

    Raises
    ------
    ValueError
        For fewer than two held-out runs or arrays of different lengths.
    """
    a, b = np.asarray(lpd_before, dtype=float), np.asarray(lpd_after, dtype=float)
    ja, jb = np.asarray(j_before, dtype=float), np.asarray(j_after, dtype=float)
    if not a.shape == b.shape == ja.shape == jb.shape or a.ndim != 1 or a.size < 2:
        raise ValueError(
            f"need one value per held-out run (at least 2) in every array; got shapes "
            f"{a.shape}, {b.shape}, {ja.shape}, {jb.shape}"
        )
    d = b - a
    diff = float(d.sum())
    se = float(np.sqrt(d.size * d.var(ddof=1)))
    j0, j1 = float(ja.mean()), float(jb.mean())
    decisive = bool(np.isfinite(diff) and diff > DECISIVE_SE * se and j1 < j0)
    return Gain(
        j_before=j0,
        j_after=j1,
        elpd_before=float(a.sum()),
        elpd_after=float(b.sum()),
        elpd_difference=diff,
        elpd_se=se,
        n_runs=int(d.size),
        decisive=decisive,
    )
