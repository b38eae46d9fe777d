"""The ensemble's probabilities weighed against a physical signature check, as one stated model.

A system with a signature check (a bearing's envelope lines at its kinematic fault
frequencies) says, per run and per damage state, whether that state's signature shows in the
signal. The ensemble read the same signal; its calibration was established on simulations,
where a damage's signature shows. This module asks, run by run, whether the ensemble's
probabilities hold, and reports the probabilities that follow:

* **Two hypotheses for a run.** A: the ensemble's probabilities hold. They are the posterior
  of the state given the whole signal, the part the check reads included, so under A the
  check adds nothing to them; it only has to be consistent with them. B: only the ensemble's
  split between the healthy state and damage holds, and it says nothing about which damage
  (the damage states share ``1 - p(healthy)`` equally): what a classifier trained on
  simulations is worth where a machine's damage looks other than simulated. Under B the check
  is the only evidence of which damage.
* **The check.** For a damage state ``k`` the observation is ``s_k`` (its signature shows or
  not). A run of state ``k`` shows it with probability ``d_k`` (how often a real fault shows
  its line: unknown, a simulation cannot say); a run of another damage state with ``l_k`` (a
  fault raises the envelope's lines of other families too: modulation, a noisier envelope;
  unknown); a healthy run with the check's stated false-alarm rate ``alpha`` (from which its
  threshold was derived). The states' checks are independent given the state.
* **The campaign.** A holds for a run with prior probability ``pi``. ``pi``, every ``d_k``
  and every ``l_k`` are shared by the campaign's runs, with uniform priors (``d_k`` and
  ``l_k`` on ``(alpha, 1)``: no state shows a signature less often than a healthy run), and
  are learned from every checked run without labels: Gibbs sampling of each run's hypothesis,
  then of its state, then of the rates from their conjugate Beta posteriors. The state is drawn
  from the ensemble's belief and the check together, as if the two were independent given the
  state (under A; under B from the check alone): an approximation, since the ensemble read the
  signal the check reads, which biases the learned rates up a little (by up to 0.1 on
  campaigns drawn with a known truth, tests/test_evidence.py).

A run's reported probability of a state is ``P(A | s) p_ensemble + P(B | s) p(state | s, B)``,
averaged over the sampled rates (Rao-Blackwellised), where ``P(A | s)`` weighs how probable the
check's outcome is if the state is drawn from the ensemble's probabilities against if it is
drawn from B's. Where the ensemble's calls carry the signatures that the campaign shows
its states to carry, ``P(A | s)`` is near 1 and the probabilities are the ensemble's. Where a
call goes against them (an inner-race call without the inner-race line, on a campaign whose
inner-race runs show it), the run leans to B and its probability moves to the damage states
the signal does not rule out: the number the user reads says that the two disagree. Runs
without a check keep the ensemble's probabilities.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from jaxtyping import ArrayLike, Float
from scipy.stats import beta

#: Gibbs sweeps kept, and discarded before them
SWEEPS = 1500
BURN_IN = 300


class Evidence(NamedTuple):
    """The combined probabilities and what the campaign said about the unknowns.

    Attributes
    ----------
    probabilities
        ``(run, state)``: each run's posterior state probabilities (the ensemble's, unchanged,
        for a run without a check).
    applies
        Per run, the posterior probability that the ensemble's probabilities apply as they
        stand (hypothesis A); NaN for a run without a check.
    pi
        Posterior mean and central 90 % interval of the share of runs the ensemble applies to.
    detection
        Per damage state (by index), the posterior mean and central 90 % interval of the
        detection rate ``d_k`` of its signature.
    leak
        The same of ``l_k``, the rate at which its signature shows on a run of another
        damage state.
    checked
        Runs with a check.
    alpha
        The check's false-alarm rate used.
    """

    probabilities: np.ndarray
    applies: np.ndarray
    pi: tuple[float, float, float]
    detection: dict[int, tuple[float, float, float]]
    leak: dict[int, tuple[float, float, float]]
    checked: int
    alpha: float


def _summary(draws: np.ndarray) -> tuple[float, float, float]:
    low, high = np.quantile(draws, [0.05, 0.95])
    return float(np.mean(draws)), float(low), float(high)


def _truncated_beta(rng: np.random.Generator, a, b, low: float) -> np.ndarray:
    """Draws of Beta(a, b) restricted to (low, 1), by its inverse distribution function."""
    lo = beta.cdf(low, a, b)
    u = lo + (1 - lo) * rng.random(np.shape(a))
    return np.clip(beta.ppf(u, a, b), low, 1 - 1e-12)


def _check(
    p: np.ndarray, s: np.ndarray, healthy: int, false_alarm_rate: float, sweeps: int, burn_in: int
) -> None:
    """Refuse shapes, probabilities, rates or sweep counts that :func:`combine_evidence` cannot
    use."""
    if p.ndim != 2 or s.shape != p.shape:
        raise ValueError(
            f"probabilities and shows must both have shape (run, state), got {p.shape} and "
            f"{s.shape}"
        )
    n_state = p.shape[1]
    if n_state < 2 or not 0 <= healthy < n_state:
        raise ValueError(f"need at least two states and a healthy index among them, got {healthy}")
    if not np.all(np.isfinite(p)) or np.any(np.abs(p.sum(axis=1) - 1) > 1e-6):
        raise ValueError("probabilities must be finite and sum to 1 over the states of each run")
    if not 0 < false_alarm_rate < 1:
        raise ValueError(f"false_alarm_rate must be in (0, 1), got {false_alarm_rate!r}")
    if sweeps < 1 or burn_in < 0:
        raise ValueError(
            f"sweeps must be positive and burn_in not negative, got {sweeps}, {burn_in}"
        )


def _prior_evidence(p: np.ndarray, damage: list[int], alpha: float) -> Evidence:
    """Nothing learned (no run has a check): the ensemble's probabilities, and the priors'
    means and central 90 % intervals."""
    flat = (
        float((1 + alpha) / 2),
        float(alpha + 0.05 * (1 - alpha)),
        float(1 - 0.05 * (1 - alpha)),
    )
    return Evidence(
        p.copy(),
        np.full(len(p), np.nan),
        (0.5, 0.05, 0.95),
        dict.fromkeys(damage, flat),
        dict.fromkeys(damage, flat),
        0,
        alpha,
    )


class _Draws(NamedTuple):
    """What the Gibbs sweeps after the burn-in add up and keep."""

    total: np.ndarray
    total_a: np.ndarray
    pis: list[float]
    ds: list[np.ndarray]
    leaks: list[np.ndarray]


def _gibbs(
    pc: np.ndarray,
    sc: np.ndarray,
    healthy: int,
    alpha: float,
    rng: np.random.Generator,
    sweeps: int,
    burn_in: int,
) -> _Draws:
    """The Gibbs sampler of the checked runs' hypotheses and states and the campaign's rates."""
    n, n_state = len(pc), pc.shape[1]
    # hypothesis B: the ensemble's healthy share kept, the damage states sharing the rest
    b = np.repeat(((1 - pc[:, healthy]) / (n_state - 1))[:, None], n_state, axis=1)
    b[:, healthy] = pc[:, healthy]
    seen = np.isfinite(sc)
    shown = (seen & (sc == 1)).astype(float)
    hidden = (seen & (sc == 0)).astype(float)
    is_damage = np.arange(n_state) != healthy
    pi = 0.5
    d = np.full(n_state, (1 + alpha) / 2)
    leak = np.full(n_state, (1 + alpha) / 2)
    draws = _Draws(np.zeros_like(pc), np.zeros(n), [], [], [])
    for sweep in range(burn_in + sweeps):
        # q[y, k]: the probability that state k's signature shows on a run of state y
        q = np.where(is_damage[:, None], leak[None, :], alpha)
        q[np.diag_indices(n_state)] = np.where(is_damage, d, alpha)
        like = np.exp(shown @ np.log(q).T + hidden @ np.log1p(-q).T)  # (run, y)
        a_term = pc * like  # the ensemble's belief times the check's likelihood
        b_term = b * like
        m_a, m_b = a_term.sum(axis=1), b_term.sum(axis=1)  # P(s | A), P(s | B)
        applies_now = pi * m_a / (pi * m_a + (1 - pi) * m_b)
        given_b = b_term / m_b[:, None]
        if sweep >= burn_in:
            # the predictive: under A the ensemble's probabilities (it read the signal the
            # check reads, so the check adds nothing to them), under B the check's posterior
            draws.total[...] += applies_now[:, None] * pc + (1 - applies_now)[:, None] * given_b
            draws.total_a[...] += applies_now
            draws.pis.append(pi)
            draws.ds.append(d.copy())
            draws.leaks.append(leak.copy())
        # draw each run's hypothesis, then its state from the ensemble's belief and the check
        # together (the check's rates are learned from states that the check informs, as if
        # the two were independent given the state), then pi, d and the leaks from their
        # conjugate posteriors
        is_a = rng.random(n) < applies_now
        weights = np.where(is_a[:, None], a_term / m_a[:, None], given_b)
        cdf = np.cumsum(weights, axis=1)
        state = np.minimum((rng.random(n)[:, None] > cdf).sum(axis=1), n_state - 1)
        pi = float(rng.beta(1 + is_a.sum(), 1 + (~is_a).sum()))
        mine = state[:, None] == np.arange(n_state)[None]
        other = is_damage[state][:, None] & ~mine
        d = _truncated_beta(
            rng, 1.0 + (mine * shown).sum(axis=0), 1.0 + (mine * hidden).sum(axis=0), alpha
        )
        leak = _truncated_beta(
            rng, 1.0 + (other * shown).sum(axis=0), 1.0 + (other * hidden).sum(axis=0), alpha
        )
    return draws


def combine_evidence(
    probabilities: Float[ArrayLike, "run state"],
    shows: Float[ArrayLike, "run state"],
    healthy: int,
    false_alarm_rate: float,
    *,
    seed: int = 0,
    sweeps: int = SWEEPS,
    burn_in: int = BURN_IN,
) -> Evidence:
    """Each run's state probabilities given the ensemble and the signature check.

    Parameters
    ----------
    probabilities
        The ensemble's calibrated probabilities, ``(run, state)``.
    shows
        Per run and damage state, 1 when the state's signature shows, 0 when it does not,
        NaN when the check says nothing of it (the healthy state's column is ignored: its
        agreement is that no damage signature shows). A run whose row is all NaN has no check.
    healthy
        The index of the healthy state.
    false_alarm_rate
        The check's stated false-alarm rate per state (``alpha``), in (0, 1).
    seed
        The Gibbs sampler's seed (the result is a deterministic function of it).
    sweeps, burn_in
        Gibbs sweeps averaged, and discarded before them.

    Returns
    -------
    Evidence

    Raises
    ------
    ValueError
        For shapes that do not match, probabilities that are not finite and normalised, a
        false-alarm rate outside (0, 1), or fewer than two states.
    """
    p = np.asarray(probabilities, dtype=float)
    s = np.array(shows, dtype=float)
    _check(p, s, healthy, false_alarm_rate, sweeps, burn_in)
    n_state = p.shape[1]
    s[:, healthy] = np.nan
    if np.any(np.isfinite(s) & (s != 0) & (s != 1)):
        raise ValueError("shows must hold 1, 0 or NaN")
    alpha = float(false_alarm_rate)
    damage = [k for k in range(n_state) if k != healthy]
    checked = np.isfinite(s).any(axis=1)
    if not checked.any():
        return _prior_evidence(p, damage, alpha)
    rng = np.random.default_rng(seed)
    draws = _gibbs(p[checked], s[checked], healthy, alpha, rng, sweeps, burn_in)
    out = p.copy()
    applies = np.full(len(p), np.nan)
    out[checked] = draws.total / sweeps
    applies[checked] = draws.total_a / sweeps
    ds_arr = np.asarray(draws.ds)
    return Evidence(
        out,
        applies,
        _summary(np.asarray(draws.pis)),
        {k: _summary(ds_arr[:, k]) for k in damage},
        {k: _summary(np.asarray(draws.leaks)[:, k]) for k in damage},
        int(checked.sum()),
        alpha,
    )
