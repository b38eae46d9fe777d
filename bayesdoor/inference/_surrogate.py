"""A quadratic emulator of the feature vectors, trained on batched simulations in a box.

NUTS straight through the simulator costs a solve and its adjoint per leapfrog step. The
surrogate replaces the solve by a ridge-regularised quadratic polynomial in the scaled
parameters, one per operating point, fitted to a Latin-hypercube design of simulations; its
error on held-out simulations (per feature) enters the likelihood as an extra variance.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import qmc

from .._cacheable import errors_as_nan
from .._exported import persistent_jit
from .._types import Array, Float
from ._likelihood import AbstractForward, ForwardOutput


def _basis(x: Float[Array, "*batch param"]) -> Float[Array, "*batch term"]:
    """1, x_i and x_i x_j (i <= j): the full quadratic in ``x``."""
    d = x.shape[-1]
    i, j = np.triu_indices(d)
    ones = jnp.ones((*x.shape[:-1], 1), dtype=x.dtype)
    return jnp.concatenate([ones, x, x[..., i] * x[..., j]], axis=-1)


class QuadraticSurrogate(AbstractForward):
    """A quadratic polynomial per operating point, in parameters scaled to [-1, 1] on its box.

    Build it with :func:`fit_surrogate`. It is a forward model (see
    :class:`~bayesdoor.inference.SimulatorForward`): jittable, differentiable, and its
    ``variance`` output is the held-out squared error of each feature. Outside its box it
    extrapolates: sample inside the box (``SamplingTransform.box(names, lower, upper)``).

    Parameters
    ----------
    names
        The parameters, in the order of ``theta``.
    operating
        The operating points (one polynomial each).
    lower, upper
        The training box.
    coef
        Polynomial coefficients per operating point, term and feature.
    error_variance
        Mean squared error of each feature on held-out simulations, decades^2.
    ridge
        The ridge penalty chosen (by leave-one-out error) for each operating point.
    n_train
        Simulations the polynomials were fitted to.
    """

    names: tuple[str, ...] = eqx.field(static=True)
    operating: Float[Array, " op"]
    lower: Float[Array, " param"]
    upper: Float[Array, " param"]
    coef: Float[Array, "op term feature"]
    error_variance: Float[Array, "op channel band"]
    ridge: Float[Array, " op"]
    n_train: int = eqx.field(static=True)

    def scaled(self, theta: Float[Array, "*batch param"]) -> Float[Array, "*batch param"]:
        """Parameters scaled to [-1, 1] on the training box."""
        return 2.0 * (theta - self.lower) / (self.upper - self.lower) - 1.0

    def __call__(self, theta: Float[Array, " param"]) -> ForwardOutput:
        phi = _basis(self.scaled(theta))
        flat = jnp.einsum("t,otf->of", phi, self.coef)
        features = flat.reshape(self.error_variance.shape)
        return ForwardOutput(features, self.error_variance, jnp.asarray(True))

    @property
    def heldout_rms(self) -> Float[Array, "op channel band"]:
        """Root-mean-square error of each feature on the held-out simulations, decades."""
        return jnp.sqrt(self.error_variance)

    def edge_fraction(
        self, theta: Float[Array, "sample param"], bounds: tuple[np.ndarray, np.ndarray]
    ) -> np.ndarray:
        """Fraction of samples within 2 % of a box face that is not also a hard bound.

        A posterior that piles up there is cut off by the box, not by the data: refit the
        surrogate on a larger box around the posterior. ``bounds`` are the parameters' own
        (lower, upper) bounds, whose faces count as genuine.
        """
        draws = np.asarray(theta)
        lo, hi = np.asarray(self.lower), np.asarray(self.upper)
        width = hi - lo
        near_lo = (draws - lo < 0.02 * width) & (lo > np.asarray(bounds[0]) + 1e-12 * width)
        near_hi = (hi - draws < 0.02 * width) & (hi < np.asarray(bounds[1]) - 1e-12 * width)
        return np.mean(near_lo | near_hi, axis=0)


def box_around(
    centre: Float[Array, " param"],
    lower: Float[Array, " param"],
    upper: Float[Array, " param"],
    fraction: float | Float[Array, " param"],
) -> tuple[np.ndarray, np.ndarray]:
    """A box of half-width ``fraction`` of each parameter's range around ``centre``, clipped.

    Raises
    ------
    ValueError
        For a fraction outside (0, 1] or a centre outside the bounds.
    """
    lo, hi, c = (np.asarray(a, dtype=float) for a in (lower, upper, centre))
    f = np.broadcast_to(np.asarray(fraction, dtype=float), c.shape)
    if np.any(f <= 0) or np.any(f > 1):
        raise ValueError(f"fraction must lie in (0, 1], got {f.tolist()}")
    if np.any(c < lo) or np.any(c > hi):
        raise ValueError(
            f"centre {c.tolist()} lies outside the bounds [{lo.tolist()}, {hi.tolist()}]"
        )
    half = f * (hi - lo)
    return np.maximum(lo, c - half), np.minimum(hi, c + half)


@persistent_jit
def _batched(forward: AbstractForward, thetas: Float[Array, "design param"]) -> ForwardOutput:
    # without host callbacks, so that the program enters the persistent cache (a failed check
    # gives NaN outputs, which the design treats as a failed simulation)
    with errors_as_nan():
        return jax.vmap(forward)(thetas)


def box_from_samples(
    theta: Float[Array, "sample param"],
    lower: Float[Array, " param"],
    upper: Float[Array, " param"],
    *,
    n_sd: float = 5.0,
) -> tuple[np.ndarray, np.ndarray]:
    """A box of ``n_sd`` posterior standard deviations around the posterior mean, clipped.

    The second stage of a two-stage fit: a surrogate on a wide box gives a first posterior;
    a surrogate refitted on this smaller box is accurate where the posterior lives (a quadratic
    that must span a resonance moving through a band is not).
    """
    draws = np.asarray(theta, dtype=float)
    mean, sd = draws.mean(axis=0), draws.std(axis=0)
    lo, hi = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    return np.maximum(lo, mean - n_sd * sd), np.minimum(hi, mean + n_sd * sd)


def simulate_design(
    forward: AbstractForward,
    thetas: Float[Array, "design param"],
    *,
    chunk: int = 32,
    workers: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Run a forward model on many parameter vectors, ``chunk`` at a time (one compilation).

    The first chunk runs alone (it compiles the vmapped solve); the others run on ``workers``
    threads at once. XLA releases the GIL while it solves, so two threads keep both cores of
    a 2-core machine busy. The results do not depend on ``workers``.

    Returns
    -------
    features
        (design, op, channel, band).
    ok
        Whether each simulation succeeded.
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers={workers!r} must be an integer >= 1 (threads at once)")

    def batch(padded: np.ndarray) -> tuple[Array, Array]:
        out = _batched(forward, jnp.asarray(padded))
        return out.features, out.ok

    features, ok = map_padded_chunks(batch, thetas, chunk, workers, first_alone=True)
    return features, ok


def map_padded_chunks(
    batch: Callable[[np.ndarray], tuple[Array | np.ndarray, ...]],
    x: Float[np.ndarray, "point param"] | Float[Array, "point param"],
    chunk: int,
    workers: int,
    *,
    first_alone: bool,
) -> tuple[np.ndarray, ...]:
    """The outputs of ``batch`` (for example features and success) over the rows of ``x``,
    ``chunk`` rows at a time, each output's rows in the order of ``x``.

    Each chunk is padded to ``chunk`` rows by repeating its last row (one compilation per
    chunk size) and the padding is cut from the results. ``workers`` threads run chunks at
    once; with ``first_alone`` the first chunk runs before the others start, so that threads
    do not each compile.
    """
    points = np.atleast_2d(np.asarray(x, dtype=float))

    def one(start: int) -> tuple[np.ndarray, ...]:
        block = points[start : start + chunk]
        padded = np.concatenate([block, np.repeat(block[-1:], chunk - len(block), axis=0)])
        return tuple(np.asarray(out)[: len(block)] for out in batch(padded))

    starts = list(range(0, len(points), chunk))
    results = [one(starts[0])] if first_alone else []
    rest = starts[1:] if first_alone else starts
    if workers > 1 and len(rest) > 1:
        with ThreadPoolExecutor(min(workers, len(rest))) as pool:
            results += list(pool.map(one, rest))
    else:
        results += [one(start) for start in rest]
    return tuple(np.concatenate(parts) for parts in zip(*results, strict=True))


def _ridge_fit(
    phi: np.ndarray, y: np.ndarray, ridges: np.ndarray
) -> tuple[np.ndarray, float, float]:
    """Ridge regression with an unpenalised intercept; the penalty by leave-one-out error.

    ``phi`` (sample, term) starts with the constant column. Returns the coefficients (term,
    feature), the chosen penalty and its leave-one-out mean squared error.
    """
    x = phi[:, 1:]
    x_mean, y_mean = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - x_mean, y - y_mean
    u, s, vt = np.linalg.svd(xc, full_matrices=False)
    uty = u.T @ yc
    best = (np.inf, 0.0, np.zeros((x.shape[1], y.shape[1])))
    for lam in ridges:
        shrink = s**2 / (s**2 + lam)
        hat_diag = np.sum(u**2 * shrink, axis=1) + 1.0 / len(y)
        resid = yc - u @ (shrink[:, None] * uty)
        loo = np.mean((resid / (1.0 - hat_diag)[:, None]) ** 2)
        if loo < best[0]:
            beta = vt.T @ ((s / (s**2 + lam))[:, None] * uty)
            best = (loo, float(lam), beta)
    loo, lam, beta = best
    coef = np.concatenate([(y_mean - x_mean @ beta)[None], beta])
    return coef, lam, float(loo)


def fit_surrogate(
    forward: AbstractForward,
    box: tuple[Float[Array, " param"], Float[Array, " param"]],
    *,
    key: jax.Array,
    n_train: int = 256,
    n_test: int = 64,
    ridges: Float[Array, " ridge"] | None = None,
    chunk: int = 32,
    workers: int = 1,
) -> QuadraticSurrogate:
    """Fit a :class:`QuadraticSurrogate` of ``forward`` on the box ``[lower, upper]``.

    The training design is a Latin hypercube of ``n_train`` points; the held-out set is
    ``n_test`` further points drawn uniformly and independently; both are simulated by
    ``forward`` (failed simulations are dropped). For each operating point the polynomial's
    ridge penalty is the one of ``ridges`` with the smallest leave-one-out error; the held-out
    squared error of each feature becomes the surrogate's error variance.

    Parameters
    ----------
    forward
        The exact forward model (usually :class:`~bayesdoor.inference.SimulatorForward`).
    box
        The training box ``(lower, upper)`` (see :func:`box_around`).
    key
        Seeds the designs.
    n_train, n_test
        Simulations for fitting and for the held-out error.
    ridges
        Candidate penalties (on parameters scaled to [-1, 1]); default ``logspace(-8, 2, 21)``.
    chunk
        Simulations per vmapped batch.
    workers
        Threads simulating batches at once (:func:`simulate_design`).

    Returns
    -------
    surrogate
        The fitted surrogate; ``surrogate.heldout_rms`` is the held-out RMS error per feature.

    Raises
    ------
    ValueError
        For too few training points for a quadratic, an empty box, or when more than 10 % of
        the simulations fail (the box reaches where the simulator breaks down).
    """
    lo = np.asarray(box[0], dtype=float)
    hi = np.asarray(box[1], dtype=float)
    _check_design(forward, lo, hi, n_train, n_test)
    penalties = np.logspace(-8, 2, 21) if ridges is None else np.asarray(ridges, dtype=float)
    seed_train, seed_test = _design_seeds(key)
    unit_train = qmc.LatinHypercube(lo.size, rng=np.random.default_rng(seed_train)).random(n_train)
    unit_test = np.random.default_rng(seed_test).uniform(size=(n_test, lo.size))
    design = lo + (hi - lo) * np.concatenate([unit_train, unit_test])
    features, ok = simulate_design(forward, design, chunk=chunk, workers=workers)
    if np.mean(~ok) > 0.1:
        raise ValueError(
            f"{int(np.sum(~ok))} of {len(ok)} simulations failed in the box [{lo.tolist()}, "
            f"{hi.tolist()}]: shrink the box or move it away from where the simulator fails"
        )
    scaled = 2.0 * (design - lo) / (hi - lo) - 1.0
    phi = np.asarray(_basis(jnp.asarray(scaled)))
    train = np.arange(len(design)) < n_train
    n_op = features.shape[1]
    flat = features.reshape(len(design), n_op, -1)
    coefs, lams, errors = _ridge_per_operating(phi, flat, train & ok, ~train & ok, penalties)
    return QuadraticSurrogate(
        names=tuple(forward.names),
        operating=jnp.asarray(forward.operating),
        lower=jnp.asarray(lo),
        upper=jnp.asarray(hi),
        coef=jnp.asarray(np.stack(coefs)),
        error_variance=jnp.asarray(np.stack(errors).reshape(features.shape[1:])),
        ridge=jnp.asarray(lams),
        n_train=int(np.sum(train & ok)),
    )


def _check_design(
    forward: AbstractForward, lo: np.ndarray, hi: np.ndarray, n_train: int, n_test: int
) -> None:
    """Raise for a box that is not one interval per parameter of ``forward`` with upper above
    lower, or too few simulations for a quadratic's terms and its held-out error."""
    d = lo.size
    n_terms = 1 + d + d * (d + 1) // 2
    if lo.shape != (len(forward.names),) or hi.shape != lo.shape or np.any(hi <= lo):
        raise ValueError(
            f"lower and upper must be ({len(forward.names)},) with upper > lower for "
            f"{forward.names}; got {lo.tolist()} and {hi.tolist()}"
        )
    if n_train < 2 * n_terms or n_test < 8:
        raise ValueError(
            f"a quadratic in {d} parameters has {n_terms} terms: pass n_train >= {2 * n_terms} "
            f"(got {n_train}) and n_test >= 8 (got {n_test})"
        )


def _design_seeds(key: jax.Array) -> tuple[int, int]:
    """The seeds of the NumPy generators of the training design and of the held-out points,
    one from each half of ``key``."""
    train_key, test_key = jax.random.split(key)
    seed_train, seed_test = (
        int(jax.random.randint(k, (), 0, 2**31 - 1)) for k in (train_key, test_key)
    )
    return seed_train, seed_test


def _ridge_per_operating(
    phi: np.ndarray,
    flat: np.ndarray,
    fit: np.ndarray,
    held_out: np.ndarray,
    penalties: np.ndarray,
) -> tuple[list[np.ndarray], list[float], list[np.ndarray]]:
    """Per operating point, the ridge fit of the polynomial on the ``fit`` rows
    (:func:`_ridge_fit`): its coefficients, its penalty and the mean squared error of each
    feature on the ``held_out`` rows."""
    coefs, lams, errors = [], [], []
    for o in range(flat.shape[1]):
        coef, lam, _ = _ridge_fit(phi[fit], flat[fit, o], penalties)
        pred = phi[held_out] @ coef
        errors.append(np.mean((pred - flat[held_out, o]) ** 2, axis=0))
        coefs.append(coef)
        lams.append(lam)
    return coefs, lams, errors
