"""The oscillator's response in closed form: a base-excited mass on a spring and a damper.

The equation of motion of the mass (absolute displacement x) on a base that moves by y::

    x'' + (c/m) (x' - y') + (k/m) (x - y) = 0

gives, for a base velocity of spectrum V(f), the mass's absolute acceleration
``A(f) = i w T(w) V(f)`` with the absolute transmissibility
``T(w) = (k/m + i w c/m) / (k/m - w^2 + i w c/m)``, ``w = 2 pi f`` (Inman, "Engineering
Vibration", 4th ed., 2014, sec. 2.4). For a base motion that repeats with the record's period
(a multisine on the record's DFT grid) this is the exact steady-state response: the signal is
the inverse real FFT of ``A``. No time stepping, no transient, and every step differentiable.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._types import Array, Float

#: spatial frequency of ISO 8608's reference roughness, cycles per metre
REFERENCE_WAVENUMBER = 0.1
#: the band of the base's motion, Hz: the multisine's lines lie between these frequencies
BASE_BAND_HZ = (1.0, 220.0)


def base_velocity_psd(roughness: Float[Array, "*run"], speed: Float[Array, "*run"]):
    """One-sided PSD of the base velocity, (m/s)^2/Hz, on a road of ISO 8608's slope.

    A road whose displacement PSD falls as ``G(n) = G(n0) (n / n0)^-2`` (n in cycles/m),
    driven over at ``speed`` v, moves the base with a time-domain displacement PSD
    ``G(f / v) / v``: its velocity PSD, ``(2 pi f)^2 G(f / v) / v = 4 pi^2 n0^2 G(n0) v``, is
    white and grows with the speed (ISO 8608:2016, "Mechanical vibration - Road surface
    profiles"). ``roughness`` is ``G(n0)`` in 1e-6 m^3 (ISO class A below 32, B 32-128).
    """
    g0 = roughness * 1e-6
    return 4.0 * np.pi**2 * REFERENCE_WAVENUMBER**2 * g0 * speed


def multisine_phases(seed: int, n_time: int) -> Float[Array, " freq"]:
    """The base motion's phases on the record's real-FFT grid: uniform, fixed by ``seed``."""
    return jax.random.uniform(
        jax.random.key(seed), (n_time // 2 + 1,), minval=0.0, maxval=2.0 * np.pi
    )


def transmissibility(
    f: Float[Array, " freq"], stiffness: Float[Array, "*run"], damping: Float[Array, "*run"]
) -> Float[Array, "*run freq"]:
    """Absolute transmissibility ``T`` (complex) from the base's to the mass's motion.

    ``stiffness`` is k/m (rad^2/s^2), ``damping`` c/m (1/s): a healthy oscillator of natural
    frequency f_n and damping ratio zeta has ``(2 pi f_n)^2`` and ``2 zeta 2 pi f_n``.
    """
    w = 2.0 * np.pi * f
    k, c, w = jnp.broadcast_arrays(stiffness[..., None], damping[..., None], w)
    return jax.lax.complex(k, w * c) / jax.lax.complex(k - w**2, w * c)


def mass_acceleration(
    stiffness: Float[Array, " run"],
    damping: Float[Array, " run"],
    velocity_psd: Float[Array, " run"],
    phases: Float[Array, " freq"],
    fs: float,
    n_time: int,
) -> Float[Array, "run time"]:
    """The mass's absolute acceleration (m/s^2) over one period of a multisine base motion.

    The base velocity has a line of PSD ``velocity_psd`` at every frequency of the record's
    DFT grid inside :data:`BASE_BAND_HZ`, phases ``phases``; a line of DFT coefficient
    ``|V|`` carries the power ``2 |V|^2 / n^2``, so ``|V| = sqrt(S n fs / 2)`` gives the PSD
    ``S`` over the line spacing ``fs / n``.
    """
    f = jnp.fft.rfftfreq(n_time, 1.0 / fs)
    lines = ((f >= BASE_BAND_HZ[0]) & (f <= BASE_BAND_HZ[1])).astype(f.dtype)
    amplitude = jnp.sqrt(velocity_psd * n_time * fs / 2.0)[..., None] * lines
    velocity = jax.lax.complex(amplitude * jnp.cos(phases), amplitude * jnp.sin(phases))
    w = 2.0 * np.pi * f
    derivative = jax.lax.complex(jnp.zeros_like(w), w)
    acceleration = derivative * transmissibility(f, stiffness, damping) * velocity
    return jnp.fft.irfft(acceleration, n=n_time)
