"""The likelihood of measured log-PSD features: Welch scatter, model error, surrogate error.

For run ``r`` at operating point ``o(r)``, channel ``c`` and band ``b``,

    y_rcb ~ Normal(m_o(r)cb(theta), s_r^2 + sigma_c(f_b)^2 + e_o(r)cb^2)

with ``m`` the simulated feature vector (:func:`~bayesdoor.inference.run_features` of a
simulated run, or a surrogate of it), ``s_r^2`` the Welch scatter of run ``r`` (from its number
of segments), ``sigma_c(f) = sigma_c exp(beta_c x(f))`` the model error of channel ``c``
(inferred; ``x`` the band centre scaled to [-1/2, 1/2], ``beta = 0`` unless the slope is on)
and ``e^2`` the surrogate's held-out error variance (zero for the exact simulator). All runs
share the parameters.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist

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
            values, self.operating, duration=self.duration, check=False
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
        The distinct operating points; the forward model must be built on the same ones.
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
            The operating point of each run (runs at equal values share a simulation).
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
        if signals.ndim != 3 or not op.shape == starts.shape == stops.shape == signals.shape[:1]:
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
        unique, index = np.unique(op, return_inverse=True)
        return cls(
            y=features,
            welch_variance=welch_log10_variance(n_segments, fs, spec),
            operating=jnp.asarray(unique),
            run_operating=jnp.asarray(index.reshape(-1), dtype=jnp.int32),
            band_centres=jnp.asarray(spec.band_centres(fs)),
        )


class ModelError(eqx.Module):
    """Prior of the model-error scale sigma_c(f) of each channel (log10 decades).

    ``sigma_c ~ HalfNormal(scale)``: with the default 0.5, a model whose log PSD is off by a
    factor 10 (one decade) in a channel is still plausible a priori (2 sd), off by a factor
    100 is not. With ``slope`` on, ``sigma_c(f) = sigma_c exp(beta_c x(f))``, ``beta_c ~
    Normal(0, slope_scale)``, ``x`` the band centre scaled to [-1/2, 1/2] over the analysis band.
    """

    scale: float = eqx.field(static=True, default=0.5)
    slope: bool = eqx.field(static=True, default=False)
    slope_scale: float = eqx.field(static=True, default=1.0)

    def __check_init__(self):
        if not (self.scale > 0 and self.slope_scale > 0):
            raise ValueError(
                f"scale and slope_scale must be positive, got {self.scale!r}, {self.slope_scale!r}"
            )


def _frequency_position(band_centres: Float[Array, " band"]) -> Float[Array, " band"]:
    lo, hi = band_centres[0], band_centres[-1]
    return jnp.where(hi > lo, (band_centres - 0.5 * (lo + hi)) / jnp.maximum(hi - lo, 1e-30), 0.0)


def predictive_normal(
    theta: Float[Array, " param"],
    sigma_model: Float[Array, " channel"],
    data: CalibrationData,
    forward: AbstractForward,
    slope: Float[Array, " channel"] | None = None,
) -> tuple[Float[Array, "run channel band"], Float[Array, "run channel band"], Bool[Array, ""]]:
    """Mean and standard deviation of each measured feature, and whether the model ran.

    Where the forward model failed, the mean is replaced by the data (so nothing downstream
    sees a NaN); the caller adds ``-inf`` to the log density (see :func:`log_likelihood`).

    Returns
    -------
    loc, scale
        The Gaussian of each run, channel and band.
    ok
        False when the forward model failed.
    """
    out = forward(theta)
    loc = out.features[data.run_operating]
    x = _frequency_position(data.band_centres)
    slope = jnp.zeros_like(sigma_model) if slope is None else slope
    sigma = sigma_model[:, None] * jnp.exp(slope[:, None] * x[None, :])
    variance = (
        data.welch_variance[:, None, None] + sigma[None] ** 2 + out.variance[data.run_operating]
    )
    ok = out.ok & jnp.all(jnp.isfinite(loc))
    return jnp.where(ok, loc, data.y), jnp.sqrt(variance), ok


def log_likelihood(
    theta: Float[Array, " param"],
    sigma_model: Float[Array, " channel"],
    data: CalibrationData,
    forward: AbstractForward,
    slope: Float[Array, " channel"] | None = None,
) -> Float[Array, ""]:
    """The log likelihood of all runs; ``-inf`` (with finite gradients) where the model failed."""
    loc, scale, ok = predictive_normal(theta, sigma_model, data, forward, slope)
    total = jnp.sum(jax.scipy.stats.norm.logpdf(data.y, loc, scale))
    return jnp.where(ok, total, -jnp.inf)


def make_model(
    data: CalibrationData,
    forward: AbstractForward,
    transform: SamplingTransform,
    error: ModelError | None = None,
) -> Callable[..., None]:
    """The numpyro model of the calibration runs.

    Sites: ``z`` (the sampling coordinates of :class:`SamplingTransform`, uniform box prior),
    one deterministic site per parameter name, ``sigma_model`` (per channel), ``sigma_slope``
    (when the slope is on), ``solver_failed`` (a ``-inf`` factor when the forward model
    failed) and the observed ``y`` with one log-likelihood term per run, channel and band (so
    ArviZ's PSIS-LOO can use them). Call the model with ``y=None`` for posterior-predictive
    replicates.

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
    n_run, n_channel, n_band = data.y.shape

    def model(y: Float[Array, "run channel band"] | None = data.y) -> None:
        z = numpyro.sample("z", transform.prior())
        theta = transform.from_sampling(z)
        for i, name in enumerate(transform.names):
            numpyro.deterministic(name, theta[i])
        with numpyro.plate("channel", n_channel):
            sigma = numpyro.sample("sigma_model", dist.HalfNormal(error.scale))
            slope = (
                numpyro.sample("sigma_slope", dist.Normal(0.0, error.slope_scale))
                if error.slope
                else None
            )
        loc, scale, ok = predictive_normal(theta, sigma, data, forward, slope)
        numpyro.factor("solver_failed", jnp.where(ok, 0.0, -jnp.inf))
        with (
            numpyro.plate("run", n_run, dim=-3),
            numpyro.plate("feature_channel", n_channel, dim=-2),
            numpyro.plate("band", n_band, dim=-1),
        ):
            numpyro.sample("y", dist.Normal(loc, scale), obs=y)

    return model
