"""The sampling parameterisation: box-bounded parameters mapped to whitened real coordinates.

Each parameter ``theta_i`` in its box ``[lower_i, upper_i]`` maps to a real coordinate
``u_i = logit((theta_i - lower_i) / (upper_i - lower_i))``; the sampler moves ``z`` with
``u = centre + L z``. With ``L`` the Cholesky factor of a covariance of ``u`` near the
posterior (from CMA-ES or a Laplace approximation), strongly correlated parameters (the door's
contact stiffness and exponent) become nearly independent unit-scale coordinates, and the
sampler's step size and mass matrix start from a well-conditioned problem.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import numpyro.distributions as dist
import optimistix as optx
from jax.scipy.linalg import solve_triangular
from numpyro.distributions import transforms

from .._types import Array, Float
from ..systems import ParameterSpec

#: the Laplace mode's BFGS stops when its last step moved every logit coordinate by less than
#: this plus as much relative, and the negative log density by less than this plus as much
#: relative; BFGS converges superlinearly, so the mode is then far closer than the posterior's
#: scales (sds of 1e-3 or more in the logits) and the Hessian there moves by as little
_MODE_TOLERANCE = 1e-8


class SamplingTransform(eqx.Module):
    """A bijection between a box of parameters and the real coordinates a sampler moves.

    ``theta = lower + (upper - lower) sigmoid(centre + chol @ z)``. The identity whitening
    (``centre = 0``, ``chol = I``) is the plain logit map numpyro applies to a uniform prior;
    :meth:`from_covariance` and :meth:`whitened_at` make the whitened one.

    Parameters
    ----------
    names
        Parameter names, in the order of the vectors.
    lower, upper
        The box: the support of the uniform prior.
    centre
        The origin of ``z`` in logit coordinates.
    chol
        Lower-triangular factor with a positive diagonal.
    """

    names: tuple[str, ...] = eqx.field(static=True)
    lower: Float[Array, " param"]
    upper: Float[Array, " param"]
    centre: Float[Array, " param"]
    chol: Float[Array, "param param"]

    def __check_init__(self):
        d = len(self.names)
        shapes = [self.lower.shape, self.upper.shape, self.centre.shape, self.chol.shape]
        if shapes != [(d,), (d,), (d,), (d, d)]:
            raise ValueError(
                f"for {d} parameters {self.names}, lower, upper and centre must have shape "
                f"({d},) and chol ({d}, {d}); got {shapes}"
            )
        if not isinstance(self.lower, jax.core.Tracer) and not bool(
            jnp.all(self.upper > self.lower)
        ):
            raise ValueError(
                f"every upper bound must exceed its lower bound; got lower={self.lower.tolist()} "
                f"upper={self.upper.tolist()} for {self.names}"
            )

    @classmethod
    def box(
        cls, names: Sequence[str], lower: Sequence[float], upper: Sequence[float]
    ) -> SamplingTransform:
        """Plain logit coordinates of the box (no whitening)."""
        lo = jnp.asarray(lower, dtype=float)
        return cls(
            tuple(names),
            lo,
            jnp.asarray(upper, dtype=float),
            jnp.zeros_like(lo),
            jnp.eye(lo.size, dtype=lo.dtype),
        )

    @classmethod
    def from_specs(
        cls, specs: Sequence[ParameterSpec], names: Sequence[str] | None = None
    ) -> SamplingTransform:
        """Plain logit coordinates of the parameters' own bounds (the Table 2 box).

        Raises
        ------
        ValueError
            For a name that no spec has, or an integer parameter (fix those per model).
        """
        by_name = {p.name: p for p in specs}
        names = [p.name for p in specs if not p.integer] if names is None else list(names)
        for name in names:
            if name not in by_name:
                raise ValueError(f"unknown parameter {name!r}: allowed {', '.join(by_name)}")
            if by_name[name].integer:
                raise ValueError(
                    f"parameter {name!r} is an integer: a sampling transform covers continuous "
                    "parameters only; fix it per model (one fit per value)"
                )
        return cls.box(names, [by_name[n].lower for n in names], [by_name[n].upper for n in names])

    def unconstrained(self, theta: Float[Array, "*batch param"]) -> Float[Array, "*batch param"]:
        """Logit coordinates ``u`` of parameter values inside the box."""
        unit = (theta - self.lower) / (self.upper - self.lower)
        return jnp.log(unit) - jnp.log1p(-unit)

    def constrained(self, u: Float[Array, "*batch param"]) -> Float[Array, "*batch param"]:
        """Parameter values of logit coordinates ``u``."""
        return self.lower + (self.upper - self.lower) * jax.nn.sigmoid(u)

    def from_sampling(self, z: Float[Array, "*batch param"]) -> Float[Array, "*batch param"]:
        """Parameter values of sampling coordinates ``z``."""
        return self.constrained(self.centre + z @ self.chol.T)

    def to_sampling(self, theta: Float[Array, "*batch param"]) -> Float[Array, "*batch param"]:
        """Sampling coordinates ``z`` of parameter values strictly inside the box."""
        du = self.unconstrained(theta) - self.centre
        return solve_triangular(self.chol, du.T, lower=True).T

    def prior(self) -> dist.Distribution:
        """The uniform box prior as a distribution over ``z`` (samples and densities).

        Its density includes the Jacobian of the map, so a sampler that moves ``z`` targets the
        posterior of a uniform prior on the box; drawing from it draws uniform parameters.
        """
        return dist.TransformedDistribution(
            dist.Uniform(self.lower, self.upper).to_event(1),
            [
                transforms.AffineTransform(
                    self.lower, self.upper - self.lower, domain=dist.constraints.unit_interval
                ).inv,
                transforms.SigmoidTransform().inv,
                transforms.LowerCholeskyAffine(self.centre, self.chol).inv,
            ],
        )

    def with_covariance(
        self, centre_theta: Float[Array, " param"], cov_u: Float[Array, "param param"]
    ) -> SamplingTransform:
        """The same box, whitened by a covariance ``cov_u`` of the logit coordinates.

        Raises
        ------
        ValueError
            When ``cov_u`` is not symmetric positive definite.
        """
        cov = np.asarray(cov_u, dtype=float)
        d = len(self.names)
        if cov.shape != (d, d) or not np.allclose(cov, cov.T, rtol=1e-8, atol=0.0):
            raise ValueError(
                f"the covariance must be a symmetric ({d}, {d}) matrix, got shape {cov.shape}"
            )
        eig = np.linalg.eigvalsh(cov)
        if not eig[0] > 0:
            raise ValueError(
                f"the covariance is not positive definite (smallest eigenvalue {eig[0]:.3g}): "
                "(a) a parameter the objective does not depend on, (b) too few CMA-ES "
                "iterations; regularise it or fix that parameter"
            )
        centre = self.unconstrained(jnp.asarray(centre_theta, dtype=self.lower.dtype))
        return SamplingTransform(
            self.names, self.lower, self.upper, centre, jnp.asarray(np.linalg.cholesky(cov))
        )

    def from_covariance(
        self, mean: Float[Array, " param"], cov: Float[Array, "param param"]
    ) -> SamplingTransform:
        """Whitening from a mean and covariance of the parameters (for example CMA-ES's).

        The covariance is carried to logit coordinates through the Jacobian of the logit map at
        the mean (first order); the mean must lie strictly inside the box.
        """
        mean = jnp.asarray(mean, dtype=self.lower.dtype)
        jac = jnp.diag(jax.jacfwd(self.unconstrained)(mean))
        cov_u = jac[:, None] * jnp.asarray(cov, dtype=mean.dtype) * jac[None, :]
        return self.with_covariance(mean, cov_u)

    def log_jacobian(self, u: Float[Array, "*batch param"]) -> Float[Array, "*batch"]:
        """``log |d theta / d u|`` of the logit map (a uniform prior's density in ``u``)."""
        return jnp.sum(
            jnp.log(self.upper - self.lower) + jax.nn.log_sigmoid(u) + jax.nn.log_sigmoid(-u),
            axis=-1,
        )

    def whitened_at(
        self,
        log_density: Callable[[Float[Array, " param"]], Float[Array, ""]],
        theta_start: Float[Array, " param"],
        *,
        floor: float = 1e-2,
        max_iterations: int = 200,
    ) -> SamplingTransform:
        """Laplace whitening: the mode and inverse Hessian of the density in logit coordinates.

        The density of ``u`` is ``log_density(theta(u))`` plus the Jacobian of the logit map
        (the uniform box prior); ``optimistix.BFGS`` finds its mode from ``theta_start`` (for
        example the CMA-ES optimum), and the inverse of the negative Hessian there becomes the
        covariance.
        Eigenvalues of the negative Hessian below ``floor`` (directions the density barely
        constrains) are raised to it, so those directions keep a prior-sized scale.

        Parameters
        ----------
        log_density
            Log likelihood (or log posterior density over a uniform prior) of the parameter
            values, for example :func:`~bayesdoor.inference.log_likelihood` with the
            model-error scales fixed.
        theta_start
            Where the search for the mode starts, strictly inside the box.
        floor
            Smallest eigenvalue kept of the negative Hessian.
        max_iterations
            Most BFGS steps (a search cut off there keeps the point it reached).

        Raises
        ------
        ValueError
            When the density or its Hessian is not finite at the mode found.
        """

        def negative(u, _=None):
            return -(log_density(self.constrained(u)) + self.log_jacobian(u))

        u0 = self.unconstrained(jnp.asarray(theta_start, dtype=self.lower.dtype))
        mode = optx.minimise(
            negative,
            optx.BFGS(rtol=_MODE_TOLERANCE, atol=_MODE_TOLERANCE),
            u0,
            max_steps=max_iterations,
            throw=False,
        ).value
        precision = np.asarray(jax.hessian(negative)(mode))
        if not (np.isfinite(float(negative(mode))) and np.all(np.isfinite(precision))):
            raise ValueError(
                f"the log density or its Hessian is not finite at the mode found "
                f"({self.constrained(mode).tolist()}): (a) theta_start sits on the box "
                "edge, (b) the forward model fails there"
            )
        eig, vec = np.linalg.eigh(0.5 * (precision + precision.T))
        cov = (vec / np.maximum(eig, floor)) @ vec.T
        return self.with_covariance(self.constrained(mode), 0.5 * (cov + cov.T))
