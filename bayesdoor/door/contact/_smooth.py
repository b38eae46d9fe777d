"""Smoothed contact primitives: finite values and gradients everywhere.

Works on any array namespace with numpy's names (``numpy`` or ``jax.numpy``), so the same
equations drive diffrax and the scipy reference integrator.
"""

from __future__ import annotations

from types import ModuleType

import jax.numpy as jnp

#: width of the penetration smoothing (m); far below the 0.3-0.4 mm static indentation
PENETRATION_SMOOTHING = 1e-6
#: floor of the latched approach velocity (m/s) for persistent (rolling) contact
LATCH_FLOOR = 0.05


def softplus(x, width, xp: ModuleType = jnp):
    """width * log(1 + exp(x / width)): a smooth ReLU with finite gradient everywhere."""
    z = x / width
    return width * (xp.logaddexp(0.0, z))


def sigmoid(x, width, xp: ModuleType = jnp):
    """Logistic step of the given width; the derivative of :func:`softplus`."""
    return 0.5 * (1.0 + xp.tanh(0.5 * x / width))


def smooth_power(d, n, width=PENETRATION_SMOOTHING, xp: ModuleType = jnp):
    """(softplus d)^n computed as exp(n log(.)); finite with finite gradient for any d."""
    # the tiny offset keeps log() finite in float32 as well; its force is below 1e-30 N
    dp = softplus(d, width, xp) + width * 1e-12
    return xp.exp(n * xp.log(dp))


def smooth_contact_force(
    d,
    d_dot,
    d_dot_minus,
    K,
    n,
    xi,
    width=PENETRATION_SMOOTHING,
    floor=LATCH_FLOOR,
    xp: ModuleType = jnp,
):
    """Contact force F = K d^n (1 + xi d_dot / d_dot_minus), smoothed and never tensile.

    ``d_dot_minus`` is the latched approach velocity, floored smoothly at ``floor``; the damping
    term may not pull the bodies together, so the bracket is clipped smoothly at zero
    (the standard treatment, e.g. Flores et al. 2011).
    """
    ddm = floor + softplus(d_dot_minus - floor, 0.05 * floor, xp)
    bracket = 1.0 + xi * d_dot / ddm
    bracket = softplus(bracket, 1e-3, xp)
    return K * smooth_power(d, n, width, xp) * bracket


def latch_rate(d, d_dot, latch, tau=2e-3, width=PENETRATION_SMOOTHING, xp: ModuleType = jnp):
    """Time derivative of the approach-velocity latch.

    The latch tracks d_dot with time constant ``tau`` while the bodies are apart and freezes
    while they are in contact, so at first contact it holds the impact velocity.
    """
    apart = 1.0 - sigmoid(d, width, xp)
    return apart * (d_dot - latch) / tau


def stribeck_friction(speed2, normal, mu_s, mu_d, v_s=0.01, eps=1e-3, xp: ModuleType = jnp):
    """Smoothed Coulomb-Stribeck friction, as the factor that multiplies the sliding velocity.

    For a sliding velocity vector v with squared norm ``speed2`` the friction force is
    ``stribeck_friction(|v|^2, ...) * v``: magnitude mu(|v|) N with
    mu(v) = mu_d + (mu_s - mu_d) exp(-(v / v_s)^2), direction -v / sqrt(|v|^2 + eps^2), so the
    force is continuous through zero velocity (regularised Coulomb friction). ``eps`` = 1 mm/s
    is ten times below v_s, so the Stribeck peak survives; a smaller ``eps`` makes sticking a
    stiff viscous damper that forces an explicit solver into tiny steps.
    """
    mu = mu_d + (mu_s - mu_d) * xp.exp(-speed2 / (v_s * v_s))
    return -mu * normal / xp.sqrt(speed2 + eps * eps)
