"""The phenomenological signal model of one run, in JAX (jit, vmap and grad).

One accelerometer signal, sampled at ``fs``, is the sum of

* shaft harmonics: ``a_s sum_h r_h cos(2 pi h f_r t + phi_h)`` (h = 1, 2, 3);
* a broadband background: white noise passed through the structural resonances, scaled to an
  rms ``roughness_rms`` (distributed roughness and the stand's random excitation; it makes
  the resonances visible in a healthy record);
* for a localised fault, impulses at the kinematic fault frequency (McFadden and Smith 1984;
  Randall and Antoni 2011): defect passage k starts at
  ``t_k = t_0 + sum_{j<k} T (1 + slip e_j)``, ``e_j ~ N(0, 1)``, ``T = 1 / (order f_r)``,
  with an amplitude ``A (size / 0.014 in) q(theta_k)`` (the load-zone factor ``q``) and a
  duration ``tau = size / v_surface``, and excites the resonances;
* white measurement noise of rms ``noise_rms``.

The resonances: impulse response ``h(t) = e^{-s1 t} sin(w1 t) + g2 e^{-s2 t} sin(w2 t)``
(``s = zeta omega_n``, ``w = omega_n sqrt(1 - zeta^2)``), applied in the frequency domain as
its exact z-transform on the DFT grid (impulse invariance), so the convolution is circular:
the impulses before the record's start ring into it as the last ones ring out. A defect
passage (after Sawalhi and Randall, MSSP 25, 2011, 846-870: a gradual entry and a sharp exit
impact) is a Hann-shaped unloading of length ``tau`` and area ``-entry_ratio`` followed, at
``tau``, by a unit impulse: its spectrum ``e^{-2 pi i f tau} - entry_ratio sinc(f tau) /
(1 - (f tau)^2) e^{-pi i f tau}``. The exit impact excites the resonances whatever the size,
so the ring-down grows with the amplitude; ``tau`` shapes the envelope (the entry-exit
separation). The impulses are placed at their exact times with a 16-tap windowed-sinc
fractional delay, so the signal is differentiable in every parameter.

Load zone (Stribeck's distribution, as in Randall and Antoni 2011):
``q(theta) = |L| max(0, 1 - (1 - cos theta) / (2 eps))^1.5`` of the angle between the defect
and the load ``L``: the inner-race defect turns with the shaft (``2 pi f_r t + phi``), a ball
with the cage (``2 pi FTF t + phi``), an outer-race defect sits at 6 o'clock. The load is the
static radial load (down, magnitude 1) plus a rotating load of ``unbalance_ratio`` times it
turning with the shaft (an unbalance): it swings the load zone and its magnitude at the shaft
frequency, so the strikes on the stationary outer-race defect are modulated at 1x (without it,
``q = 1`` there), and those of the inner race and a ball by their angle to the moving load. A
ball's strikes alternate between the outer race (weight 1) and the inner race (weight
``ball_inner_ratio``).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from ._geometry import INCH

#: the fault size at which ``impulse_amplitude`` is defined, inch
REFERENCE_SIZE_IN = 0.014
#: taps of the windowed-sinc fractional delay that places each impulse
TAPS = 16
#: exponent of the Stribeck load distribution of a ball bearing
LOAD_EXPONENT = 1.5


def resonance_response(f: jax.Array, fs: float, freq_hz: jax.Array, zeta: jax.Array) -> jax.Array:
    """DFT of the sampled ring-down ``e^{-zeta w_n t} sin(w_d t)`` at the frequencies ``f``.

    The z-transform of the sampled impulse response (impulse invariance), evaluated on the unit
    circle: ``r sin(th) z^-1 / (1 - 2 r cos(th) z^-1 + r^2 z^-2)``, ``r = e^{-zeta w_n / fs}``,
    ``th = w_d / fs``. On the frequencies of an N-point DFT it is the DFT of the ring-down
    wrapped onto N samples.
    """
    wn = 2 * jnp.pi * freq_hz
    r = jnp.exp(-zeta * wn / fs)
    th = wn * jnp.sqrt(1 - zeta**2) / fs
    phi = 2 * jnp.pi * f / fs
    zinv = jax.lax.complex(jnp.cos(phi), -jnp.sin(phi))
    c = _complex_dtype(f)
    a, b, rr = (r * jnp.sin(th)).astype(c), (2 * r * jnp.cos(th)).astype(c), (r**2).astype(c)
    return a * zinv / (1 - b * zinv + rr * zinv**2)


def _complex_dtype(x: jax.Array):
    return jnp.complex128 if x.dtype == jnp.float64 else jnp.complex64


def passage_spectrum(f: jax.Array, tau: jax.Array, entry_ratio: float) -> jax.Array:
    """Spectrum of one defect passage of length ``tau`` starting at t = 0.

    A Hann pulse of area ``-entry_ratio`` over ``[0, tau]`` (the entry) and a unit impulse
    at ``tau`` (the exit impact).
    """
    x = f * tau
    near = jnp.abs(1 - x**2) < 1e-6
    safe = jnp.where(near, 0.5, x)
    hann = jnp.where(near, 0.5, jnp.sinc(safe) / (1 - safe**2))
    real = jnp.cos(2 * jnp.pi * x) - entry_ratio * hann * jnp.cos(jnp.pi * x)
    imag = -jnp.sin(2 * jnp.pi * x) + entry_ratio * hann * jnp.sin(jnp.pi * x)
    return jax.lax.complex(real, imag)


def load_zone(theta: jax.Array, epsilon: float) -> jax.Array:
    """Stribeck load factor (1 at the load direction) of a defect at angle ``theta``."""
    return jnp.maximum(0.0, 1 - (1 - jnp.cos(theta)) / (2 * epsilon)) ** LOAD_EXPONENT


def radial_load(ratio: jax.Array, psi: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Magnitude (per static load) and direction (rad from 6 o'clock) of the bearing's load.

    The static radial load points down (6 o'clock); a rotating load of ``ratio`` times it
    (an unbalance turning with the shaft, at angle ``psi``) adds to it as a vector.
    """
    x = 1 + ratio * jnp.cos(psi)
    y = ratio * jnp.sin(psi)
    return jnp.sqrt(x**2 + y**2), jnp.arctan2(y, x)


def place_impulses(times: jax.Array, weights: jax.Array, n_time: int, fs: float) -> jax.Array:
    """A circular sample train with impulse ``k`` of weight ``weights[k]`` at ``times[k]`` s.

    Each impulse is spread over :data:`TAPS` samples by a Hann-windowed sinc, exact for the
    frequencies below about 0.8 of Nyquist and differentiable in ``times``.
    """
    pos = times * fs
    n0 = jnp.floor(pos)
    frac = pos - n0
    j = jnp.arange(-TAPS // 2 + 1, TAPS // 2 + 1, dtype=pos.dtype)
    offset = j[None, :] - frac[:, None]
    window = 0.5 + 0.5 * jnp.cos(jnp.pi * offset / (TAPS / 2))
    taps = jnp.sinc(offset) * window * weights[:, None]
    index = (n0.astype(jnp.int32)[:, None] + j.astype(jnp.int32)[None, :]) % n_time
    return jnp.zeros(n_time, dtype=pos.dtype).at[index.ravel()].add(taps.ravel())


def run_signal(
    p: dict[str, jax.Array],
    shaft_hz: jax.Array,
    size_in: jax.Array,
    key: jax.Array,
    *,
    state: str,
    n_time: int,
    fs: float,
    order: float,
    ftf_order: float,
    surface_speed_per_hz: float,
    n_impulses: int,
    harmonics: tuple[float, ...],
    epsilon: float,
    ball_inner_ratio: float,
    entry_ratio: float,
    extra_harmonics: jax.Array | None = None,
) -> jax.Array:
    """The signal (m/s^2, ``n_time`` samples) of one run; see the module docstring.

    Parameters
    ----------
    p
        The parameters by name (scalars).
    shaft_hz
        Shaft frequency, Hz.
    size_in
        Fault size, inch (unused for ``healthy``).
    key
        The run's random key (jitter, phases, background and noise).
    state
        ``healthy``, ``inner_race``, ``outer_race`` or ``ball``.
    n_time, fs
        Samples and sampling rate, Hz.
    order
        Impulses per shaft revolution (unused for ``healthy``).
    ftf_order
        Cage frequency per shaft frequency.
    surface_speed_per_hz
        Rolling surface speed, m/s per Hz of shaft frequency.
    n_impulses
        Impulses drawn (those past the record's end are dropped).
    harmonics
        Relative amplitudes of the shaft harmonics 1x, 2x, ...
    epsilon
        Load distribution factor of the load zone.
    ball_inner_ratio
        Weight of a ball's strikes on the inner race.
    entry_ratio
        Area of a defect passage's entry (unloading) per unit exit impact.
    extra_harmonics
        Amplitudes added to the shaft lines 1x, 2x, ... (the ``shaft_harmonics`` extension):
        in phase with the base lines where the base has them, at phases drawn from the run's
        key (folded with 1, so the base draws stay as they are) above.
    """
    k_phase, k_rough, k_noise, k_jitter, k_start, k_angle = jax.random.split(key, 6)
    dtype = shaft_hz.dtype
    t = jnp.arange(n_time, dtype=dtype) / fs
    f = jnp.arange(n_time // 2 + 1, dtype=dtype) * (fs / n_time)

    phases = jax.random.uniform(k_phase, (len(harmonics),), dtype=dtype) * 2 * jnp.pi
    h = jnp.arange(1, len(harmonics) + 1, dtype=dtype)
    ratios = jnp.asarray(harmonics, dtype=dtype)
    shaft = p["shaft_amplitude"] * jnp.sum(
        ratios[:, None] * jnp.cos(2 * jnp.pi * h[:, None] * shaft_hz * t + phases[:, None]),
        axis=0,
    )
    if extra_harmonics is not None:
        k_count = extra_harmonics.shape[0]
        more = max(k_count - len(harmonics), 0)
        extra_phases = jax.random.uniform(jax.random.fold_in(k_phase, 1), (more,), dtype=dtype) * (
            2 * jnp.pi
        )
        all_phases = jnp.concatenate([phases, extra_phases])[:k_count]
        k = jnp.arange(1, k_count + 1, dtype=dtype)
        shaft = shaft + jnp.sum(
            extra_harmonics.astype(dtype)[:, None]
            * jnp.cos(2 * jnp.pi * k[:, None] * shaft_hz * t + all_phases[:, None]),
            axis=0,
        )

    second = resonance_response(f, fs, p["resonance_2_hz"], p["damping_2"])
    resonances = (
        resonance_response(f, fs, p["resonance_1_hz"], p["damping_1"])
        + p["resonance_2_gain"].astype(second.dtype) * second
    )
    # background: unit white noise through the resonances, scaled to its expected rms
    weight = jnp.ones_like(f).at[1:].set(2.0)
    if n_time % 2 == 0:
        weight = weight.at[-1].set(1.0)
    gain = jnp.sqrt(jnp.sum(weight * jnp.abs(resonances) ** 2) / n_time)
    white = jax.random.normal(k_rough, (n_time,), dtype=dtype)
    rough = jnp.fft.irfft(jnp.fft.rfft(white) * resonances, n=n_time) / gain
    noise = jax.random.normal(k_noise, (n_time,), dtype=dtype)
    x = shaft + p["roughness_rms"] * rough + p["noise_rms"] * noise
    if state == "healthy":
        return x

    period = 1 / (order * shaft_hz)
    e = jax.random.normal(k_jitter, (n_impulses,), dtype=dtype)
    spacing = period * jnp.maximum(1 + p["slip"] * e, 0.5)
    t0 = jax.random.uniform(k_start, (), dtype=dtype) * period
    tk = t0 + jnp.concatenate([jnp.zeros(1, dtype=dtype), jnp.cumsum(spacing[:-1])])
    inside = tk < n_time / fs
    angle = jax.random.uniform(k_angle, (), dtype=dtype) * 2 * jnp.pi
    k_unbalance = jax.random.fold_in(k_angle, 1)
    unbalance_phase = jax.random.uniform(k_unbalance, (), dtype=dtype) * 2 * jnp.pi
    magnitude, direction = radial_load(
        p["unbalance_ratio"], 2 * jnp.pi * shaft_hz * tk + unbalance_phase
    )
    if state == "inner_race":
        defect = 2 * jnp.pi * shaft_hz * tk + angle
        q = magnitude * load_zone(defect - direction, epsilon)
    elif state == "ball":
        alternate = jnp.where(jnp.arange(n_impulses) % 2 == 0, 1.0, ball_inner_ratio)
        defect = 2 * jnp.pi * ftf_order * shaft_hz * tk + angle
        q = magnitude * load_zone(defect - direction, epsilon) * alternate
    else:
        q = magnitude * load_zone(-direction, epsilon)
    amplitude = p["impulse_amplitude"] * size_in / REFERENCE_SIZE_IN
    weights = jnp.where(inside, amplitude * q, 0.0)
    train = place_impulses(jnp.where(inside, tk, 0.0), weights, n_time, fs)
    tau = size_in * INCH / (surface_speed_per_hz * shaft_hz)
    spectrum = jnp.fft.rfft(train) * resonances * passage_spectrum(f, tau, entry_ratio)
    return x + jnp.fft.irfft(spectrum, n=n_time)


def impulse_capacity(duration: float, order: float, max_shaft_hz: float, max_slip: float) -> int:
    """Impulses to draw so that a record of ``duration`` s is filled at the fastest shaft."""
    shortest = 1 / (order * max_shaft_hz) * max(1 - 4 * max_slip, 0.5)
    return math.ceil(duration / shortest) + 2
