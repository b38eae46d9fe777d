"""The likelihood of measured log-PSD features: model discrepancy, run scatter, surrogate error.

For run ``r`` at operating point ``o(r)``, channel ``c`` and band ``b``,

    y_rcb = m_o(r)cb(theta) + delta_o(r)cb + eps_rcb,
    delta_ocb ~ Normal(0, sigma_oc(f_b)^2 + e_ocb^2),   eps_rcb ~ Normal(0, rho_c^2 s_r^2)

with ``m`` the simulated feature vector (:func:`~bayesdoor.inference.run_features` of a
simulated run, or a surrogate of it), ``delta`` the model's discrepancy, shared by every run at
one operating point (Kennedy and O'Hagan 2001: the model misses the system the same way in
each repetition, so replicate runs average the scatter away, never the discrepancy), with
``sigma_oc(f) = sigma_oc exp(beta_c x(f))`` per operating point and channel (``x`` the band
centre scaled to [-1/2, 1/2], ``beta = 0`` unless the slope is on; with
``ModelError(per_operating=False)`` one ``sigma_c`` for every operating point) and ``e^2`` the
surrogate's held-out error variance
(zero for the exact simulator; also shared, it is an error of ``m``), and ``eps`` the scatter
of one run, ``s_r^2`` the Welch variance of its features (from its number of segments) scaled
by the inferred ``rho_c^2`` per channel (1 for a Gaussian random response, below 1 for a mostly
deterministic one). The discrepancy is marginalised in closed form (:class:`DiscrepancyNormal`).

With ``ModelError(correlation=l)`` the discrepancy is also correlated over the bands of a
channel: ``delta_oc ~ Normal(0, S_oc R S_oc + diag(e_oc^2))``, ``S_oc = diag(sigma_oc(f_b))``,
``R_bb' = exp(-(b - b')^2 / (2 l^2))`` over the band index (Kennedy and O'Hagan's Gaussian
process discrepancy on the band grid; :class:`CorrelatedDiscrepancyNormal`). A model-form error
(a resonance the model places slightly off) moves neighbouring bands together; independent
bands count each of them as separate evidence about the parameters that move them.

With ``ModelError(common=True)`` the discrepancy has a part common to every operating point:
``delta_ocb = gamma_cb + delta'_ocb``, ``gamma_cb ~ Normal(0, tau_c^2)``. A model-form error
(a resonance the reduced model places a few per cent off) misses every speed the same way at
the same frequency; per operating point alone, the three speeds would count as three
independent looks at the parameters that move it.

``ModelError(shared=False)`` is the earlier, independent form ``y_rcb ~ Normal(m, s_r^2 +
sigma_c(f_b)^2 + e_ocb^2)`` (``rho = 1``): every run adds its own model error, so ten runs of
one speed shrink the parameters' posterior as if the model's error were noise.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Mapping, Sequence
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist
from numpyro.distributions import constraints

from .._types import Array, Bool, Float, Int
from ..features import segment_weights
from ..systems import AbstractSystem
from ._features import FeatureSpec, run_features, welch_log10_variance
from ._parameterisation import SamplingTransform


class ForwardOutput(eqx.Module):
    """What a forward model returns for one parameter vector.

    ``features`` and ``variance`` have one row per operating point; ``variance`` is the forward
    model's own error variance (decades^2; zero for the exact simulator); ``ok`` is false when
    the simulation failed, in which case ``features`` are not meaningful.
    """

    features: Float[Array, "*batch op channel band"]
    variance: Float[Array, "*batch op channel band"]
    ok: Bool[Array, "*batch"]


class AbstractForward(eqx.Module):
    """Parameter vector -> simulated feature vectors at a fixed set of operating points."""

    names: eqx.AbstractVar[tuple[str, ...]]
    operating: eqx.AbstractVar[Float[Array, " op"]]

    @abc.abstractmethod
    def __call__(self, theta: Float[Array, " param"]) -> ForwardOutput:
        """Features at every operating point for the parameter values ``theta``."""


class SimulatorForward(AbstractForward):
    """The exact forward model: simulate the system, then take the features of each run.

    Differentiable (through the system's solver) and jittable; a failed solve gives
    ``ok = False``, never an exception. Build it with :meth:`build`.
    """

    system: AbstractSystem
    names: tuple[str, ...] = eqx.field(static=True)
    fixed: tuple[tuple[str, float], ...] = eqx.field(static=True)
    operating: Float[Array, " op"]
    t_start: Float[Array, " op"]
    t_stop: Float[Array, " op"]
    duration: float = eqx.field(static=True)
    spec: FeatureSpec

    @classmethod
    def build(
        cls,
        system: AbstractSystem,
        names: Sequence[str],
        fixed: Mapping[str, float],
        operating: Sequence[float] | Float[Array, " op"],
        *,
        spec: FeatureSpec | None = None,
        duration: float | None = None,
    ) -> SimulatorForward:
        """The simulator as a function of the parameters ``names``, the others ``fixed``.

        Parameters
        ----------
        system
            The simulated system.
        names
            The free (continuous) parameters, in the order of ``theta``.
        fixed
            Values of every other parameter, integer ones (a contact-law index) included.
        operating
            The distinct operating points (for example speeds) of the runs.
        spec
            The feature definition; ``None`` means ``FeatureSpec()``.
        duration
            Record length (s); default: the system's record length for these operating points.
            The motion window is the system's, clipped to the record.

        Raises
        ------
        ValueError
            For unknown or missing parameter names, a free integer parameter, or a fixed value
            out of bounds.
        """
        specs = {p.name: p for p in system.parameters}
        names = tuple(names)
        unknown = [n for n in (*names, *fixed) if n not in specs]
        missing = [n for n in specs if n not in names and n not in fixed]
        both = [n for n in names if n in fixed]
        if unknown or missing or both:
            raise ValueError(
                f"every parameter of {system.name} ({', '.join(specs)}) must be either free "
                f"(names) or fixed, exactly once; unknown {unknown or 'none'}, missing "
                f"{missing or 'none'}, both {both or 'none'}"
            )
        integer = [n for n in names if specs[n].integer]
        if integer:
            raise ValueError(
                f"integer parameters {integer} cannot be free: fix them (one fit per value)"
            )
        system.check_parameters(dict(fixed))
        op = np.atleast_1d(np.asarray(operating, dtype=float))
        duration = system.record_duration(op) if duration is None else float(duration)
        t_start, t_stop = system.motion_window(op, duration=duration)
        return cls(
            system=system,
            names=names,
            fixed=tuple((k, float(v)) for k, v in fixed.items()),
            operating=jnp.asarray(op),
            t_start=jnp.asarray(t_start),
            t_stop=jnp.asarray(t_stop),
            duration=duration,
            spec=FeatureSpec() if spec is None else spec,
        )

    def __call__(self, theta: Float[Array, " param"]) -> ForwardOutput:
        values: dict[str, Array | float] = {n: theta[i] for i, n in enumerate(self.names)}
        values.update(dict(self.fixed))
        result = self.system.simulate_values(
            values, self.operating, state=self.system.healthy, duration=self.duration, check=False
        )
        features, _ = run_features(
            result.signals, self.system.sampling_rate_hz, self.t_start, self.t_stop, self.spec
        )
        return ForwardOutput(features, jnp.zeros_like(features), jnp.all(result.status == 0))


class CalibrationData(eqx.Module):
    """Measured feature vectors of the calibration runs and what the likelihood needs of them.

    Build it with :meth:`from_signals`.

    Parameters
    ----------
    y
        The measured features (log10 band PSD) of each run.
    welch_variance
        The Welch scatter of each run's features, decades^2.
    operating
        The distinct operating points (rows for several operating conditions); the forward
        model must be built on the same ones.
    run_operating
        The index into ``operating`` of each run.
    band_centres
        The centre frequency of each band, Hz.
    """

    y: Float[Array, "run channel band"]
    welch_variance: Float[Array, " run"]
    operating: Float[Array, " op"]
    run_operating: Int[Array, " run"]
    band_centres: Float[Array, " band"]

    @classmethod
    def from_signals(
        cls,
        signals: Float[Array, "run channel time"],
        fs: float,
        operating: Sequence[float] | Float[Array, " run"],
        t_start: Sequence[float] | Float[Array, " run"],
        t_stop: Sequence[float] | Float[Array, " run"],
        spec: FeatureSpec | None = None,
    ) -> CalibrationData:
        """Features, Welch scatter and operating points of measured runs.

        Parameters
        ----------
        signals
            The measured signals, the first sample at t = 0.
        fs
            Sampling rate, Hz.
        operating
            The operating point of each run (runs at equal values share a simulation):
            ``(run,)`` for one operating condition, ``(run, condition)`` for several.
        t_start, t_stop
            The motion window of each run, s.
        spec
            The feature definition (the same as the forward model's).

        Raises
        ------
        ValueError
            When the numbers of runs disagree or a window holds no whole Welch segment.
        """
        spec = FeatureSpec() if spec is None else spec
        signals = jnp.asarray(signals)
        op = np.asarray(operating, dtype=float)
        starts = np.asarray(t_start, dtype=float)
        stops = np.asarray(t_stop, dtype=float)
        if (
            signals.ndim != 3
            or op.ndim not in (1, 2)
            or not op.shape[:1] == starts.shape == stops.shape == signals.shape[:1]
        ):
            raise ValueError(
                f"signals must be (run, channel, time) with one operating point and window per "
                f"run; got signals {signals.shape}, operating {op.shape}, t_start "
                f"{starts.shape}, t_stop {stops.shape}"
            )
        inside = segment_weights(
            signals.shape[-1],
            fs,
            jnp.asarray(starts),
            jnp.asarray(stops),
            spec.nperseg,
            spec.noverlap,
        ).sum(axis=-1)
        short = np.flatnonzero(np.asarray(inside) < 1)
        if short.size:
            raise ValueError(
                f"runs {short.tolist()} hold no whole Welch segment of {spec.nperseg} samples in "
                f"their motion window (t_start {starts[short].tolist()} s, t_stop "
                f"{stops[short].tolist()} s): (a) t_start/t_stop are wrong, (b) nperseg is too "
                "large for the window"
            )
        features, n_segments = run_features(
            signals, fs, jnp.asarray(starts), jnp.asarray(stops), spec
        )
        # a point of several operating conditions is a row
        unique, index = (
            np.unique(op, return_inverse=True)
            if op.ndim == 1
            else np.unique(op, axis=0, return_inverse=True)
        )
        return cls(
            y=features,
            welch_variance=welch_log10_variance(n_segments, fs, spec),
            operating=jnp.asarray(unique),
            run_operating=jnp.asarray(index.reshape(-1), dtype=jnp.int32),
            band_centres=jnp.asarray(spec.band_centres(fs)),
        )


class ModelError(eqx.Module):
    """Priors of the model discrepancy sigma_c(f) and the run scatter rho_c of each channel.

    ``sigma_c ~ HalfNormal(scale)`` (log10 decades): with the default 0.5, a model whose log
    PSD is off by a factor 10 (one decade) in a channel is still plausible a priori (2 sd), off
    by a factor 100 is not. With ``slope`` on, ``sigma_c(f) = sigma_c exp(beta_c x(f))``,
    ``beta_c ~ Normal(0, slope_scale)``, ``x`` the band centre scaled to [-1/2, 1/2] over the
    analysis band.

    With ``shared`` (the default) the discrepancy is one draw per operating point, channel and
    band, common to every run there, with a scale ``sigma_oc`` per operating point and channel
    (``per_operating``, the default; each ``~ HalfNormal(scale)``; the site ``sigma_model`` is
    then their root mean square over the operating points): a reduced model can match a
    system closely at one speed and poorly at another, and one scale per channel would let the
    worst speed set the tolerance of every other. Each run scatters about the discrepancy by
    ``rho_c`` Welch standard deviations, ``rho_c ~ LogNormal(0, scatter_scale)``: the Welch
    variance is the scatter of a
    Gaussian random response (``rho = 1``), a response mostly set by a deterministic excitation
    (a rail's fixed profile) scatters less, one whose parameters vary from run to run more.
    Replicate runs at an operating point identify ``rho_c``; with one run per operating point
    its prior keeps it near the Welch value. ``shared=False`` is the independent form (each
    run its own model error, ``rho = 1``; see the module docstring).

    ``correlation`` (bands; needs ``shared``) correlates the shared discrepancy over the bands
    of a channel with a squared-exponential correlation of that length over the band index
    (:class:`CorrelatedDiscrepancyNormal`); 0, the default, keeps the bands independent. With
    ``infer_correlation`` the length is a parameter, ``discrepancy_length ~
    LogNormal(ln correlation, correlation_scale)``, one for every channel and operating point:
    with the default scale 1 a length of a third or three times the prior median is still
    plausible (1.1 sd).

    With ``common`` (needs ``shared``, not with ``correlation``) the discrepancy of every
    operating point also holds a part common to all of them, one draw per channel and band,
    ``gamma_cb ~ Normal(0, tau_c^2)`` with ``tau_c ~ HalfNormal(scale)`` (the site
    ``sigma_common``), marginalised in closed form with the rest (:class:`DiscrepancyNormal`).
    """

    scale: float = eqx.field(static=True, default=0.5)
    slope: bool = eqx.field(static=True, default=False)
    slope_scale: float = eqx.field(static=True, default=1.0)
    shared: bool = eqx.field(static=True, default=True)
    per_operating: bool = eqx.field(static=True, default=True)
    scatter_scale: float = eqx.field(static=True, default=1.0)
    correlation: float = eqx.field(static=True, default=0.0)
    infer_correlation: bool = eqx.field(static=True, default=False)
    correlation_scale: float = eqx.field(static=True, default=1.0)
    common: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        if not (self.scale > 0 and self.slope_scale > 0 and self.scatter_scale > 0):
            raise ValueError(
                f"scale, slope_scale and scatter_scale must be positive, got {self.scale!r}, "
                f"{self.slope_scale!r}, {self.scatter_scale!r}"
            )
        if not (self.correlation >= 0 and self.correlation_scale > 0):
            raise ValueError(
                f"correlation={self.correlation!r} must be >= 0 (a length in bands, 0 for "
                f"independent bands) and correlation_scale={self.correlation_scale!r} positive"
            )
        if self.infer_correlation and self.correlation == 0:
            raise ValueError(
                "infer_correlation=True needs correlation > 0, the prior median of the length "
                "in bands (e.g. correlation=2.0)"
            )
        if self.correlation > 0 and not self.shared:
            raise ValueError(
                f"correlation={self.correlation!r} needs shared=True: the correlated "
                "discrepancy is the one shared by the runs of an operating point"
            )
        if self.common and (not self.shared or self.correlation > 0):
            raise ValueError(
                f"common=True needs shared=True and correlation=0 (got shared={self.shared!r}, "
                f"correlation={self.correlation!r}): the common part is added to the "
                "discrepancy shared by the runs of an operating point, independent over bands"
            )

    def correlation_length(self) -> float | None:
        """The fixed correlation length in bands, ``None`` for independent bands."""
        return self.correlation if self.correlation > 0 else None


class DiscrepancyNormal(dist.Distribution):
    """Gaussian features of runs that share a discrepancy per operating point.

    ``y_r = loc_r + gamma + delta_o(r) + eps_r`` elementwise, ``delta_o ~ Normal(0,
    shared_variance_o)`` common to the runs at operating point ``o``, ``gamma ~ Normal(0,
    common_variance)`` common to every run (absent unless given), ``eps_r ~ Normal(0,
    run_variance_r)`` independent. The runs of one operating point are jointly Gaussian with
    covariance ``diag(run_variance) + shared_variance 11^T`` per element, handled in closed form
    (Sherman-Morrison), and ``gamma`` adds ``common_variance 11^T`` over every run (Sherman-
    Morrison again, on each operating point's precision-weighted mean), so the cost is linear in
    the runs.

    ``log_prob`` returns, per element, the leave-one-out conditional ``log p(y_i | y_-i)`` given
    the other runs of its operating point (with ``gamma``: given every other run): the pointwise
    terms PSIS-LOO needs for a model whose likelihood does not factorise over runs (Buerkner,
    Gabry and Vehtari 2021). They do not sum to the joint density: :meth:`joint_log_prob` is
    that, and a model observing this distribution adds ``joint_log_prob - sum(log_prob)`` as a
    factor (as :func:`make_model` does). With ``shared_variance = 0`` and no ``gamma`` both are
    the independent Gaussian. ``sample`` draws from the joint (a fresh discrepancy per operating
    point).

    Parameters
    ----------
    loc
        The mean of each run's features.
    run_variance
        The variance of each run's own scatter (positive).
    shared_variance
        The variance of the discrepancy at each operating point (non-negative).
    run_operating
        The operating point (index into the first axis of ``shared_variance``) of each run.
    common_variance
        The variance of the discrepancy common to every operating point, per channel and band
        (non-negative); ``None``: no common part.

    References
    ----------
    P.-C. Buerkner, J. Gabry and A. Vehtari, "Efficient leave-one-out cross-validation for
    Bayesian non-factorized normal and Student-t models", Computational Statistics 36, 2021.
    M. C. Kennedy and A. O'Hagan, "Bayesian calibration of computer models", JRSS B 63, 2001.
    """

    arg_constraints: ClassVar[dict[str, constraints.Constraint]] = {
        "loc": constraints.real,
        "run_variance": constraints.positive,
        "shared_variance": constraints.nonnegative,
    }
    support = constraints.real
    reparametrized_params: ClassVar[list[str]] = ["loc", "run_variance", "shared_variance"]

    def __init__(
        self,
        loc: Float[Array, "run channel band"],
        run_variance: Float[Array, "#run #channel #band"],
        shared_variance: Float[Array, "op channel band"],
        run_operating: Int[Array, " run"],
        *,
        common_variance: Float[Array, "#channel #band"] | None = None,
        validate_args: bool | None = None,
    ):
        self.loc = loc
        self.run_variance = jnp.broadcast_to(run_variance, loc.shape)
        self.shared_variance = jnp.broadcast_to(
            shared_variance, (shared_variance.shape[0], *loc.shape[1:])
        )
        self.run_operating = run_operating
        self.common_variance = (
            None if common_variance is None else jnp.broadcast_to(common_variance, loc.shape[1:])
        )
        super().__init__(batch_shape=loc.shape, validate_args=validate_args)

    def _sums(self, value):
        """Per operating point: sum of 1/v, of r/v, of r^2/v and of ln v over its runs."""
        r = value - self.loc
        w = 1.0 / self.run_variance
        n_op = self.shared_variance.shape[0]

        def total(x):
            return jax.ops.segment_sum(x, self.run_operating, num_segments=n_op)

        return r, w, total(w), total(r * w), total(r * r * w), total(jnp.log(self.run_variance))

    def _level(self, p, a):
        """``k = 1 / (1 + s p)`` per operating point, and the sums over operating points of
        ``p k`` and ``a k``: the precision and precision-weighted residual each operating
        point's mean offers the common part (its variance ``s + 1 / p``)."""
        k = 1.0 / (1.0 + self.shared_variance * p)
        return k, jnp.sum(p * k, axis=0), jnp.sum(a * k, axis=0)

    def _common(self, p, a):
        """``1 / (1 + s p)`` per operating point, and the common part's posterior mean and
        variance given every run (zero without a common part)."""
        k, big_p, big_a = self._level(p, a)
        if self.common_variance is None:
            zero = jnp.zeros(p.shape[1:])
            return k, zero, zero
        t = self.common_variance
        return k, t * big_a / (1.0 + t * big_p), t / (1.0 + t * big_p)

    def joint_log_prob(self, value: Float[Array, "run channel band"]) -> Float[Array, ""]:
        """log p(y) of every run together (the discrepancy marginalised)."""
        _, _, p, a, q, log_v = self._sums(value)
        s = self.shared_variance
        counts = jax.ops.segment_sum(
            jnp.ones_like(self.loc), self.run_operating, num_segments=s.shape[0]
        )
        group = (
            counts * jnp.log(2.0 * jnp.pi) + log_v + jnp.log1p(s * p) + q - s * a**2 / (1.0 + s * p)
        )
        total = jnp.sum(group)
        if self.common_variance is not None:
            _, big_p, big_a = self._level(p, a)
            t = self.common_variance
            total = total + jnp.sum(jnp.log1p(t * big_p) - t * big_a**2 / (1.0 + t * big_p))
        return -0.5 * total

    def log_prob(self, value: Float[Array, "run channel band"]) -> Float[Array, "run channel band"]:
        """Per element, ``log p(y_i | y_-i)`` given the other runs of its operating point (with
        a common part: given every other run)."""
        if self.common_variance is not None:
            return self._conditional(value, *self.discrepancy_posterior(value))
        r, w, p, a, _, _ = self._sums(value)
        s = self.shared_variance[self.run_operating]
        p_others = p[self.run_operating] - w
        a_others = a[self.run_operating] - r * w
        mean = s * a_others / (1.0 + s * p_others)
        variance = self.run_variance + s / (1.0 + s * p_others)
        return jax.scipy.stats.norm.logpdf(r, mean, jnp.sqrt(variance))

    def _conditional(
        self,
        value: Float[Array, "run channel band"],
        mean: Float[Array, "op channel band"],
        variance: Float[Array, "op channel band"],
    ) -> Float[Array, "run channel band"]:
        """``log p(y_i | y_-i)`` from the discrepancy's posterior mean and marginal variance
        given every element (Woodbury): with ``g = C^-1 r`` and ``G = diag(C^-1)`` of the joint
        covariance ``C``, ``g = W (r - delta_hat)`` and ``G = W - W^2 K`` (``W`` the run's
        precision), and the conditional is ``Normal(r - g / G, 1 / G)``."""
        r = value - self.loc
        w = 1.0 / self.run_variance
        g = w * (r - mean[self.run_operating])
        precision = w - w * w * variance[self.run_operating]
        return jax.scipy.stats.norm.logpdf(r, r - g / precision, jnp.sqrt(1.0 / precision))

    def discrepancy_posterior(
        self, value: Float[Array, "run channel band"]
    ) -> tuple[Float[Array, "op channel band"], Float[Array, "op channel band"]]:
        """Mean and variance of each operating point's whole discrepancy (its own part and the
        common part) given the runs ``value``."""
        _, _, p, a, _, _ = self._sums(value)
        s = self.shared_variance
        k, common_mean, common_variance = self._common(p, a)
        return k * (common_mean + s * a), k**2 * common_variance + s * k

    def common_posterior(
        self, value: Float[Array, "run channel band"]
    ) -> tuple[Float[Array, "channel band"], Float[Array, "channel band"]]:
        """Mean and variance of the common part given the runs ``value`` (zero without one):
        the discrepancy at an operating point no run measured is this plus its own prior."""
        _, _, p, a, _, _ = self._sums(value)
        _, mean, variance = self._common(p, a)
        return mean, variance

    def sample(self, key, sample_shape=()):
        k_shared, k_run = jax.random.split(key)
        shared = jnp.sqrt(self.shared_variance) * jax.random.normal(
            k_shared, sample_shape + self.shared_variance.shape
        )
        own = jnp.sqrt(self.run_variance) * jax.random.normal(k_run, sample_shape + self.shape())
        out = self.loc + shared[..., self.run_operating, :, :] + own
        if self.common_variance is not None:
            common = jnp.sqrt(self.common_variance) * jax.random.normal(
                jax.random.fold_in(key, 2), sample_shape + self.common_variance.shape
            )
            out = out + common[..., None, :, :]
        return out

    @property
    def mean(self):
        return self.loc

    @property
    def variance(self):
        own = self.run_variance + self.shared_variance[self.run_operating]
        return own if self.common_variance is None else own + self.common_variance


def band_correlation(n_band: int, length: Float[Array, ""] | float) -> Float[Array, "band band"]:
    """The squared-exponential correlation ``exp(-(b - b')^2 / (2 length^2))`` over band index.

    Parameters
    ----------
    n_band
        Bands.
    length
        Correlation length in bands (positive).
    """
    index = jnp.arange(n_band, dtype=jnp.result_type(float))
    distance = (index[:, None] - index[None, :]) / length
    return jnp.exp(-0.5 * distance**2)


class CorrelatedDiscrepancyNormal(DiscrepancyNormal):
    """Gaussian features of runs that share a discrepancy correlated over the bands.

    As :class:`DiscrepancyNormal`, with ``delta_oc ~ Normal(0, shared_covariance_oc)`` over the
    bands of channel ``c`` at operating point ``o`` (channels and operating points independent),
    the run scatter still independent over bands. Marginalised in closed form per operating
    point and channel: with ``P`` the diagonal sum of the runs' precisions, ``a`` the sum of
    their precision-weighted residuals, ``b = P^{-1/2} a`` and ``B = I + P^{1/2} Sigma
    P^{1/2}`` (never singular, Sigma need not be invertible), the joint density is the
    independent runs' with ``-1/2 ln det B`` and ``+1/2 (b'b - b' B^-1 b)`` added; one
    Cholesky factor of ``B`` per operating point and channel. ``shared_variance`` is the
    diagonal of ``shared_covariance``, so :attr:`variance` is the marginal of each element.

    ``log_prob`` returns, per element, ``log p(y_i | y_-i)`` given every other element of its
    operating point and channel (the other bands of its run included), from the diagonal of
    the inverse joint covariance (Buerkner, Gabry and Vehtari 2021); :meth:`joint_log_prob` is
    the joint density.

    Parameters
    ----------
    loc
        The mean of each run's features.
    run_variance
        The variance of each run's own scatter (positive).
    shared_covariance
        The covariance over the bands of each operating point's discrepancy, per channel
        (positive semi-definite).
    run_operating
        The operating point of each run.
    """

    def __init__(
        self,
        loc: Float[Array, "run channel band"],
        run_variance: Float[Array, "#run #channel #band"],
        shared_covariance: Float[Array, "op channel band band"],
        run_operating: Int[Array, " run"],
        *,
        validate_args: bool | None = None,
    ):
        self.shared_covariance = shared_covariance
        super().__init__(
            loc,
            run_variance,
            jnp.diagonal(shared_covariance, axis1=-2, axis2=-1),
            run_operating,
            validate_args=validate_args,
        )

    def _factor(self, p: Float[Array, "op channel band"]):
        """``sqrt(P)`` and the Cholesky factor of ``B = I + sqrt(P) Sigma sqrt(P)``."""
        root = jnp.sqrt(p)
        n_band = p.shape[-1]
        b_matrix = (
            jnp.eye(n_band) + root[..., :, None] * self.shared_covariance * root[..., None, :]
        )
        return root, jnp.linalg.cholesky(b_matrix)

    def _whitened(self, a, root, cholesky):
        """``b = a / sqrt(P)`` (0 where no run weighs in) and ``L^-1 b``."""
        safe = jnp.where(root > 0, root, 1.0)
        b = jnp.where(root > 0, a / safe, 0.0)
        return b, jax.scipy.linalg.solve_triangular(cholesky, b[..., None], lower=True)[..., 0]

    def joint_log_prob(self, value: Float[Array, "run channel band"]) -> Float[Array, ""]:
        """log p(y) of every run together (the discrepancy marginalised)."""
        _, _, p, a, q, log_v = self._sums(value)
        root, cholesky = self._factor(p)
        b, c = self._whitened(a, root, cholesky)
        counts = jax.ops.segment_sum(
            jnp.ones_like(self.loc), self.run_operating, num_segments=p.shape[0]
        )
        log_det = 2.0 * jnp.sum(jnp.log(jnp.diagonal(cholesky, axis1=-2, axis2=-1)))
        quadratic = jnp.sum(q) - jnp.sum(b * b) + jnp.sum(c * c)
        return -0.5 * (jnp.sum(counts * jnp.log(2.0 * jnp.pi) + log_v) + log_det + quadratic)

    def discrepancy_posterior_covariance(
        self, value: Float[Array, "run channel band"]
    ) -> tuple[Float[Array, "op channel band"], Float[Array, "op channel band band"]]:
        """Mean and covariance over the bands of each operating point's discrepancy given the
        runs ``value``: ``Sigma sqrt(P) B^-1 b`` and ``Sigma - Sigma sqrt(P) B^-1 sqrt(P)
        Sigma``."""
        _, _, p, a, _, _ = self._sums(value)
        root, cholesky = self._factor(p)
        _, c = self._whitened(a, root, cholesky)
        sigma = self.shared_covariance
        v = jax.scipy.linalg.solve_triangular(cholesky, root[..., :, None] * sigma, lower=True)
        u = jax.scipy.linalg.solve_triangular(cholesky, c[..., None], lower=True, trans=1)
        mean = jnp.einsum("...ij,...j->...i", sigma, root * u[..., 0])
        return mean, sigma - jnp.einsum("...ki,...kj->...ij", v, v)

    def discrepancy_posterior(
        self, value: Float[Array, "run channel band"]
    ) -> tuple[Float[Array, "op channel band"], Float[Array, "op channel band"]]:
        """Mean and marginal variance of each operating point's discrepancy given ``value``."""
        mean, covariance = self.discrepancy_posterior_covariance(value)
        return mean, jnp.diagonal(covariance, axis1=-2, axis2=-1)

    def log_prob(self, value: Float[Array, "run channel band"]) -> Float[Array, "run channel band"]:
        """Per element, ``log p(y_i | y_-i)`` given the rest of its operating point and channel.

        With ``g = C^-1 r`` and ``G = diag(C^-1)`` of the joint covariance ``C``: by Woodbury,
        ``g = W (r - delta_hat)`` and ``G = W - W^2 K`` (``W`` the run's precision, ``delta_hat``
        and ``K`` the discrepancy's posterior mean and variance given all runs), and the
        conditional is ``Normal(r - g / G, 1 / G)``.
        """
        return self._conditional(value, *self.discrepancy_posterior(value))

    def sample(self, key, sample_shape=()):
        k_shared, k_run = jax.random.split(key)
        eigenvalues, vectors = jnp.linalg.eigh(self.shared_covariance)
        root = vectors * jnp.sqrt(jnp.clip(eigenvalues, 0.0))[..., None, :]
        z = jax.random.normal(k_shared, sample_shape + self.shared_variance.shape)
        shared = jnp.einsum("...ij,...j->...i", root, z)
        own = jnp.sqrt(self.run_variance) * jax.random.normal(k_run, sample_shape + self.shape())
        return self.loc + shared[..., self.run_operating, :, :] + own


def _frequency_position(band_centres: Float[Array, " band"]) -> Float[Array, " band"]:
    lo, hi = band_centres[0], band_centres[-1]
    return jnp.where(hi > lo, (band_centres - 0.5 * (lo + hi)) / jnp.maximum(hi - lo, 1e-30), 0.0)


class Discrepancy(eqx.Module):
    """The model error at one draw: the discrepancy's scales, their slope over the band, the
    run scatter, the correlation length over the bands and the common part's scales.

    Attributes
    ----------
    sigma_model
        The discrepancy scale of each channel (decades), one for every operating point or one
        per operating point (a leading axis in the order of ``data.operating``).
    slope
        The discrepancy's slope over the band per channel; ``None``: flat.
    run_scatter
        ``rho_c``, each channel's run scatter in Welch standard deviations; ``None``: 1.
    correlation_length
        The shared discrepancy's correlation length over the bands (in bands, positive;
        :func:`band_correlation`); the forward model's own error stays independent over the
        bands. ``None``: independent bands.
    common
        ``tau_c``, the scale (decades) of each channel's discrepancy common to every operating
        point (needs ``shared``, not with ``correlation_length``); ``None``: none.
    shared
        The discrepancy is shared by the runs of an operating point (see the module
        docstring); ``False``: each run's is independent.

    Raises
    ------
    ValueError
        For a correlation length or a common part without ``shared``, or both together.
    """

    sigma_model: Float[Array, "*op channel"]
    slope: Float[Array, " channel"] | None = None
    run_scatter: Float[Array, " channel"] | None = None
    correlation_length: Float[Array, ""] | float | None = None
    common: Float[Array, " channel"] | None = None
    shared: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        if self.correlation_length is not None and self.common is None and not self.shared:
            raise ValueError(
                f"correlation_length={self.correlation_length!r} needs shared=True: only the "
                "discrepancy shared by the runs of an operating point is correlated over bands"
            )
        if self.common is not None and (not self.shared or self.correlation_length is not None):
            raise ValueError(
                "common= needs shared=True and no correlation_length: the common part is added "
                "to the discrepancy shared by the runs of an operating point, independent over "
                "the bands"
            )


def feature_distribution(
    theta: Float[Array, " param"],
    discrepancy: Discrepancy,
    data: CalibrationData,
    forward: AbstractForward,
) -> tuple[DiscrepancyNormal, Bool[Array, ""]]:
    """The distribution of the measured features at ``theta``, and whether the model ran.

    Where the forward model failed, the mean is replaced by the data (so nothing downstream
    sees a NaN); the caller adds ``-inf`` to the log density (see :func:`log_likelihood`).

    Parameters
    ----------
    theta
        The parameters, in the forward model's order.
    discrepancy
        The model error's values.
    data
        The measured runs.
    forward
        The simulator or a surrogate of it.

    Returns
    -------
    distribution
        A :class:`DiscrepancyNormal` over ``data.y`` (a :class:`CorrelatedDiscrepancyNormal`
        with a correlation length).
    ok
        False when the forward model failed.
    """
    out = forward(theta)
    loc = out.features[data.run_operating]
    x = _frequency_position(data.band_centres)
    n_channel = data.y.shape[1]
    d = discrepancy
    slope = jnp.zeros(n_channel) if d.slope is None else d.slope
    rho = jnp.ones(n_channel) if d.run_scatter is None else d.run_scatter
    variance = (d.sigma_model[..., None] * jnp.exp(slope[:, None] * x[None, :])) ** 2
    run_variance = data.welch_variance[:, None, None] * rho[None, :, None] ** 2
    ok = out.ok & jnp.all(jnp.isfinite(loc))
    loc = jnp.where(ok, loc, data.y)
    if d.correlation_length is not None and d.common is None:
        scale = jnp.sqrt(jnp.broadcast_to(variance, out.features.shape))
        correlation = band_correlation(data.y.shape[-1], d.correlation_length)
        covariance = scale[..., :, None] * correlation * scale[..., None, :]
        covariance = covariance + jax.vmap(jax.vmap(jnp.diag))(out.variance)
        return CorrelatedDiscrepancyNormal(loc, run_variance, covariance, data.run_operating), ok
    shared_variance = jnp.broadcast_to(variance + out.variance, out.features.shape)
    if d.common is not None:
        common_variance = jnp.broadcast_to(d.common[:, None] ** 2, data.y.shape[1:])
        return DiscrepancyNormal(
            loc,
            run_variance,
            shared_variance,
            data.run_operating,
            common_variance=common_variance,
        ), ok
    if not d.shared:
        run_variance = run_variance + shared_variance[data.run_operating]
        shared_variance = jnp.zeros_like(shared_variance)
    return DiscrepancyNormal(loc, run_variance, shared_variance, data.run_operating), ok


def predictive_normal(
    theta: Float[Array, " param"],
    discrepancy: Discrepancy,
    data: CalibrationData,
    forward: AbstractForward,
) -> tuple[Float[Array, "run channel band"], Float[Array, "run channel band"], Bool[Array, ""]]:
    """Mean and marginal standard deviation of each measured feature, and whether the model ran.

    The marginal of one feature (discrepancy and run scatter together); the runs of an
    operating point are correlated through the discrepancy (see :func:`feature_distribution`
    for the joint and the parameters).

    Returns
    -------
    loc, scale
        The Gaussian of each run, channel and band.
    ok
        False when the forward model failed.
    """
    d, ok = feature_distribution(theta, discrepancy, data, forward)
    return d.mean, jnp.sqrt(d.variance), ok


def log_likelihood(
    theta: Float[Array, " param"],
    discrepancy: Discrepancy,
    data: CalibrationData,
    forward: AbstractForward,
) -> Float[Array, ""]:
    """The log likelihood of all runs; ``-inf`` (with finite gradients) where the model failed.

    See :func:`feature_distribution` for the parameters.
    """
    d, ok = feature_distribution(theta, discrepancy, data, forward)
    return jnp.where(ok, d.joint_log_prob(data.y), -jnp.inf)


def make_model(
    data: CalibrationData,
    forward: AbstractForward,
    transform: SamplingTransform,
    error: ModelError | None = None,
) -> Callable[..., None]:
    """The numpyro model of the calibration runs.

    Sites: ``z`` (the sampling coordinates of :class:`SamplingTransform`, uniform box prior),
    one deterministic site per parameter name, ``sigma_operating`` (per operating point and
    channel, with ``per_operating``), ``sigma_model`` (per channel: sampled, or the root mean
    square of ``sigma_operating`` over the operating points), ``sigma_slope``
    (when the slope is on), ``run_scatter`` (per channel, with a shared discrepancy),
    ``discrepancy_length`` (with ``infer_correlation``), ``sigma_common`` (per channel, with
    ``common``),
    ``solver_failed`` (a ``-inf`` factor when the forward model failed), ``shared_discrepancy``
    (a factor: the joint density less the sum of the pointwise terms, zero for the independent
    form) and the observed ``y`` with one log-likelihood term per run, channel and band, the
    leave-one-out conditional of :class:`DiscrepancyNormal` (so ArviZ's PSIS-LOO can use
    them). Call the model with ``y=None`` for posterior-predictive replicates.

    Parameters
    ----------
    data
        The measured features.
    forward
        The exact simulator or a surrogate, on the same operating points as ``data``.
    transform
        The sampling parameterisation; its names must be the forward model's.
    error
        The model-error prior; ``None`` means ``ModelError()``.

    Raises
    ------
    ValueError
        When the names or the operating points of ``forward``, ``transform`` and ``data``
        disagree.

    Examples
    --------
    >>> from numpyro.infer import MCMC, NUTS  # doctest: +SKIP
    >>> mcmc = MCMC(NUTS(make_model(data, forward, transform)), num_warmup=500, num_samples=500)
    >>> mcmc.run(jax.random.key(0))  # doctest: +SKIP
    """
    error = ModelError() if error is None else error
    _check_alignment(data, forward, transform)
    n_run, n_channel, n_band = data.y.shape
    n_op = data.operating.shape[0]

    def model(y: Float[Array, "run channel band"] | None = data.y) -> None:
        z = numpyro.sample("z", transform.prior())
        theta = transform.from_sampling(z)
        for i, name in enumerate(transform.names):
            numpyro.deterministic(name, theta[i])
        discrepancy = _discrepancy_sites(error, n_channel, n_op)
        features, ok = feature_distribution(theta, discrepancy, data, forward)
        numpyro.factor("solver_failed", jnp.where(ok, 0.0, -jnp.inf))
        if y is not None and error.shared:
            numpyro.factor(
                "shared_discrepancy", features.joint_log_prob(y) - jnp.sum(features.log_prob(y))
            )
        with (
            numpyro.plate("run", n_run, dim=-3),
            numpyro.plate("feature_channel", n_channel, dim=-2),
            numpyro.plate("band", n_band, dim=-1),
        ):
            numpyro.sample("y", features, obs=y)

    return model


def _check_alignment(
    data: CalibrationData, forward: AbstractForward, transform: SamplingTransform
) -> None:
    """Raise when the names of ``transform`` and ``forward`` or the operating points of
    ``forward`` and ``data`` disagree."""
    if tuple(transform.names) != tuple(forward.names):
        raise ValueError(
            f"the transform's parameters {transform.names} differ from the forward model's "
            f"{forward.names}: build both on the same names, in the same order"
        )
    if forward.operating.shape != data.operating.shape or not np.allclose(
        np.asarray(forward.operating), np.asarray(data.operating)
    ):
        raise ValueError(
            f"the forward model's operating points {np.asarray(forward.operating).tolist()} "
            f"differ from the data's {np.asarray(data.operating).tolist()}: build the forward "
            "model on data.operating"
        )


def _discrepancy_sites(error: ModelError, n_channel: int, n_op: int) -> Discrepancy:
    """The model error's sample sites of :func:`make_model`, in its order: the correlation
    length, then per channel the discrepancy scales (per operating point with
    ``per_operating``), their slope, the run scatter and the common part's scales."""
    length = (
        numpyro.sample(
            "discrepancy_length",
            dist.LogNormal(jnp.log(error.correlation), error.correlation_scale),
        )
        if error.infer_correlation
        else error.correlation_length()
    )
    with numpyro.plate("channel", n_channel):
        if error.shared and error.per_operating:
            with numpyro.plate("operating", n_op, dim=-2):
                sigma = numpyro.sample("sigma_operating", dist.HalfNormal(error.scale))
            numpyro.deterministic("sigma_model", jnp.sqrt(jnp.mean(sigma**2, axis=0)))
        else:
            sigma = numpyro.sample("sigma_model", dist.HalfNormal(error.scale))
        slope = (
            numpyro.sample("sigma_slope", dist.Normal(0.0, error.slope_scale))
            if error.slope
            else None
        )
        rho = (
            numpyro.sample("run_scatter", dist.LogNormal(0.0, error.scatter_scale))
            if error.shared
            else None
        )
        tau = numpyro.sample("sigma_common", dist.HalfNormal(error.scale)) if error.common else None
    return Discrepancy(sigma, slope, rho, length, tau, shared=error.shared)
