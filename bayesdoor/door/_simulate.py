"""Solving the door's equations with diffrax: one run, vmapped batches, failure as a status."""

from __future__ import annotations

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._cacheable import errors_as_nan
from .._exported import persistent_jit
from .._types import Array, Float, Int
from . import _geometry as g
from ._model import (
    N_DOF,
    N_LATCH,
    STATE_SIZE,
    DoorArgs,
    extension_dofs,
    rhs,
    sensor_signals,
    static_residual,
)

#: status codes of a solve (``SimulationResult.status``)
STATUS_OK = 0
STATUS_MAX_STEPS = 1
STATUS_FAILED = 2
STATUS_MESSAGES = {
    STATUS_OK: "success",
    STATUS_MAX_STEPS: (
        "the solver reached max_steps: (a) parameters far outside the calibrated range make the "
        "contact stiff, (b) max_steps is too small for the record length, (c) the tolerances are "
        "too tight for float32"
    ),
    STATUS_FAILED: (
        "the solve failed (non-finite state or step size collapsed): (a) parameters outside "
        "their bounds, (b) a fixed step coarser than 1/2048 s, (c) float32 with tight tolerances"
    ),
}


class SolverConfig(eqx.Module):
    """How the equations are integrated.

    Adaptive Tsit5 (rtol 1e-5; atol 1e-8 in float64, 1e-7 in float32) by default: the model is
    not stiff, and the implicit solvers are over 30x slower (``docs/model.md``). In float32
    an atol of 1e-8 sits below the round-off of the small states (frame displacements of a few
    micrometres) and the step controller rejects steps forever (57 000 steps instead of 2 000
    for a 3.5 s run); 1e-7 keeps the 4-96 Hz log-PSD of a healthy run within 1.5 % of
    float64 at a similar step count. ``dt`` switches to fixed steps, which is
    what gradients against finite differences need (an adaptive step sequence changes with the
    parameters); steps coarser than 1/2048 s are inaccurate.

    The step controller is diffrax's ``PIDController`` with ``pcoeff`` and ``icoeff``: 0 and 1
    (an integral controller) by default. A proportional-integral one (0.4 and 0.3; G.
    Soderlind, "Digital filters in adaptive time-stepping", ACM TOMS 29(1), 2003) rejects
    fewer than half as many steps and solves about a tenth faster
    (``results/performance.md``, "The simulator"), but it carries round-off into the
    results: with it, the fit's J recomputed at its point in another batch moved by 2e-6 of
    itself (``tests/test_update.py``, which holds 1e-8) and the nine contact laws at matched
    restitution spread 4.5e-5 decades (``tests/test_examples.py``, which holds 1e-6). A
    result that changes with the batch it was solved in cannot be reproduced on a cluster,
    so it is not the default.
    """

    rtol: float = eqx.field(static=True, default=1e-5)
    atol: float | None = eqx.field(static=True, default=None)
    dt: float | None = eqx.field(static=True, default=None)
    max_steps: int = eqx.field(static=True, default=100_000)
    dtype: str = eqx.field(static=True, default="float64")
    pcoeff: float = eqx.field(static=True, default=0.0)
    icoeff: float = eqx.field(static=True, default=1.0)

    def __check_init__(self):
        if not (self.pcoeff >= 0 and self.icoeff > 0):
            raise ValueError(
                f"step controller coefficients pcoeff={self.pcoeff!r}, icoeff={self.icoeff!r}: "
                "pcoeff must be >= 0 and icoeff > 0 (0 and 1: the integral controller)"
            )
        if self.dtype not in ("float64", "float32"):
            raise ValueError(f"dtype must be 'float64' or 'float32', got {self.dtype!r}")
        if self.dt is not None and not 0.0 < self.dt <= 1.0 / g.SAMPLING_RATE_HZ:
            raise ValueError(
                f"fixed step dt={self.dt!r} s must be in (0, {1.0 / g.SAMPLING_RATE_HZ:.6g}] "
                "(coarser steps are wrong or blow up); use dt=None for adaptive steps"
            )
        if not (self.rtol > 0 and (self.atol is None or self.atol > 0)):
            raise ValueError(f"tolerances must be positive, got rtol={self.rtol}, atol={self.atol}")

    @property
    def absolute_tolerance(self) -> float:
        if self.atol is not None:
            return self.atol
        return 1e-7 if self.dtype == "float32" else 1e-8


def static_equilibrium(args: DoorArgs) -> Float[Array, " 7"]:
    """Rest configuration with the drive at the closed position: the static forces' root.

    ``optimistix.Newton`` on the forces in units of half the weight, from the wheels' Hertz
    indentation under it (``(m g / 2 / K)^(1/n)``, everything else at zero). It stops when a
    step moves no coordinate by more than ``1e-12 (1 m + |q|)`` and the scaled forces are
    below 1e-12 (in float32: 1.2e-5, a hundred round-offs). A solve that does not converge
    in 30 steps (parameters where the door has no rest configuration) gives NaN, so the
    simulation that starts from it fails with a status.

    The Jacobian in ``q`` is taken by central differences (:func:`_forces_in_q`), all 2 x 7
    displaced configurations in one vmapped evaluation of the static forces, rather than by
    forward mode: the forward-mode trace of the forces makes a batched solve's compilation a
    third longer (tracing and compiling four runs of 0.3 s: 61 to 67 s against 47 to 53 s
    on a loaded 2-core CPU). The step, the initial indentation times eps^(1/3) (about 2e-9 m
    in float64), balances truncation against round-off to a relative Jacobian error of about
    1e-10, far below the millimetre scales of the contact and the rail. An approximate
    Jacobian only turns Newton's quadratic convergence into a linear one with that factor:
    the root is the same to round-off. The derivative with respect to the parameters is the
    implicit-function one (``optimistix.ImplicitAdjoint``): the exact derivative of the
    forces in the parameters, solved with that Jacobian.
    """
    dtype = args.k_contact.dtype
    load = args.mass * g.GRAVITY / 2.0
    indent = jnp.exp(jnp.log(load / args.k_contact) / args.n)
    q0 = jnp.zeros(N_DOF, dtype=dtype).at[1].set(-indent)
    eps = float(np.finfo(dtype).eps)
    step = indent * eps ** (1.0 / 3.0)
    # 1e-12 in float64; in float32 a hundred round-offs of the scaled forces
    tolerance = max(1e-12, 100.0 * eps)
    solution: optx.Solution = optx.root_find(
        _scaled_static_forces,
        optx.Newton(rtol=tolerance, atol=tolerance),
        q0,
        (args, load, step),
        max_steps=30,
        throw=False,
    )
    return jnp.where(solution.result == optx.RESULTS.successful, solution.value, jnp.nan)


def _scaled_static_forces(q: Float[Array, " 7"], inputs) -> Float[Array, " 7"]:
    """The static forces over half the weight: differentiated in ``q`` by central
    differences, in the parameters exactly (the second term is zero in value)."""
    args, load, step = inputs
    exact = static_residual(jax.lax.stop_gradient(q), args, jnp) / load
    by_differences = _forces_in_q(q, jax.lax.stop_gradient((args, load, step)))
    return by_differences + (exact - jax.lax.stop_gradient(exact))


@jax.custom_jvp
def _forces_in_q(q: Float[Array, " 7"], inputs) -> Float[Array, " 7"]:
    args, load, _ = inputs
    return static_residual(q, args, jnp) / load


@_forces_in_q.defjvp
def _forces_in_q_jvp(primals, tangents):
    """The Jacobian by central differences times the tangent in ``q`` (the inputs' tangent
    is zero: they enter through ``jax.lax.stop_gradient``)."""
    q, inputs = primals
    dq, _ = tangents
    step = inputs[2]
    offsets = step * jnp.concatenate(
        [jnp.eye(N_DOF, dtype=q.dtype), -jnp.eye(N_DOF, dtype=q.dtype)]
    )
    values = jax.vmap(lambda x: _forces_in_q(x, inputs))(jnp.concatenate([q[None], q + offsets]))
    jac = ((values[1 : 1 + N_DOF] - values[1 + N_DOF :]) / (2.0 * step)).T
    return values[0], jac @ dq


def initial_state(args: DoorArgs) -> Float[Array, " state"]:
    """Static equilibrium, at rest, with every approach-velocity latch at its floor.

    18 entries for the base door; extensions with their own coordinates start at rest too
    (those are measured from their static position).
    """
    q = static_equilibrium(args)
    dtype = q.dtype
    rest = jnp.zeros(2 * extension_dofs(args), dtype)
    return jnp.concatenate([q, jnp.zeros(N_DOF, dtype), jnp.full((N_LATCH,), 0.05, dtype), rest])


def central_jacobian(
    flow, x0: Float[Array, " n"], steps: Float[Array, " n"]
) -> Float[Array, "n n"]:
    """Jacobian of ``flow`` at ``x0`` by central differences, a step per coordinate; the
    2 n displaced points in one vmapped evaluation."""
    shifts = jnp.diag(steps)
    f = jax.vmap(flow)(jnp.concatenate([x0 + shifts, x0 - shifts]))
    n = x0.shape[0]
    return (f[:n] - f[n:]).T / (2.0 * steps)


def oscillatory_modes(jac) -> tuple[Float[np.ndarray, " mode"], Float[np.ndarray, " mode"]]:
    """Frequencies (Hz, damped) and damping ratios of a linear flow's oscillatory modes: its
    eigenvalues with a positive imaginary part, sorted by frequency."""
    eig = np.linalg.eigvals(np.asarray(jac))
    eig = eig[eig.imag > 1e-6]
    eig = eig[np.argsort(eig.imag)]
    return eig.imag / (2.0 * np.pi), -eig.real / np.abs(eig)


def rest_modes(args: DoorArgs) -> tuple[Float[np.ndarray, " mode"], Float[np.ndarray, " mode"]]:
    """Frequencies (Hz) and damping ratios of the door's modes at rest, extensions included.

    The flow of (q, q_dot, x, x_dot) is linearised at the static equilibrium (the drive at
    its closed position, the latches at their floor, the extensions' coordinates at their
    static position) by central differences, as the virtual rig's ``rest_state`` does
    (steps of 1 nm and 1 um/s, far inside the contact indentation and the friction's
    regularisation). The modes are the eigenvalues with a positive imaginary part, sorted
    by frequency. The linearisation is one compiled program per structure of ``args``
    (:func:`rest_jacobian`); the eigenvalues are numpy's.
    """
    return oscillatory_modes(rest_jacobian(args))


@persistent_jit
def rest_jacobian(args: DoorArgs) -> Float[Array, "n n"]:
    """The Jacobian of the door's flow at rest that :func:`rest_modes` reads its modes from."""
    state0 = initial_state(args)
    n_ext = extension_dofs(args)
    moving = np.r_[0 : 2 * N_DOF, STATE_SIZE : STATE_SIZE + 2 * n_ext]
    velocity = np.r_[N_DOF : 2 * N_DOF, STATE_SIZE + n_ext : STATE_SIZE + 2 * n_ext]

    def flow(y):
        return rhs(0.0, state0.at[moving].set(y), args)[moving]

    steps = jnp.asarray(np.where(np.isin(moving, velocity), 1e-6, 1e-9), dtype=state0.dtype)
    return central_jacobian(flow, state0[moving], steps)


def sample_times(duration: float, fs: float = g.SAMPLING_RATE_HZ, dtype=jnp.float64):
    """Sample instants 0, 1/fs, ... of a record of ``duration`` seconds."""
    n = round(duration * fs)
    return jnp.asarray(np.arange(n) / fs, dtype=dtype)


def _status(result) -> Int[Array, ""]:
    return jnp.where(
        result == diffrax.RESULTS.successful,
        STATUS_OK,
        jnp.where(result == diffrax.RESULTS.max_steps_reached, STATUS_MAX_STEPS, STATUS_FAILED),
    )


_OUTPUTS = {
    "sensors": lambda t, y, a: sensor_signals(t, y, a, jnp),
    "states": lambda t, y, a: y,
}


def _with_gains(gains: tuple[str, ...]):
    """The sensors and their derivative along every gain at once (eight rows).

    The gains scale signals added to the channels only, so at a fixed state the sensors are
    linear in them and the derivative is each gain's signal on its channel (forward mode).
    """

    def fn(t, y, a):
        def sensors(values):
            return sensor_signals(t, y, eqx.tree_at(lambda x: x.extension_values, a, values), jnp)

        values = a.extension_values
        unknown = [g for g in gains if g not in values]
        if unknown:
            raise ValueError(f"gains {unknown} are not parameters of the solved extensions")
        tangent = {
            k: jnp.ones_like(v) if k in gains else jnp.zeros_like(v) for k, v in values.items()
        }
        out, slope = jax.jvp(sensors, (values,), (tangent,))
        return jnp.concatenate([out, slope])

    return fn


@persistent_jit
def solve(
    args: DoorArgs,
    ts: Float[Array, " time"],
    config: SolverConfig,
    output: str = "sensors",
    y0: Float[Array, " state"] | None = None,
    gains: tuple[str, ...] = (),
) -> tuple[Float[Array, "channel time"], Int[Array, ""]]:
    """Integrate one run from rest and return its signals (channel, time) and status.

    ``output="sensors"`` gives the four accelerometer channels, ``"states"`` the full state
    (for reference comparisons). ``gains`` (full names of solved extensions' parameters that
    only scale what a channel reads, such as a rail-carrying mode's participations) append
    four rows to the sensors: their derivative along every gain at once, each gain's signal
    on its channel. ``y0`` replaces the default start (static equilibrium at rest). A failed
    solve never raises here: its signals are zeroed and its status is non-zero, so batched
    and likelihood code can mask it (and gradients stay finite).
    """
    if output not in _OUTPUTS:
        raise ValueError(f"output must be one of {sorted(_OUTPUTS)}, got {output!r}")
    y0 = initial_state(args) if y0 is None else y0
    term = diffrax.ODETerm(lambda t, y, a: rhs(t, y, a, jnp))
    controller: diffrax.AbstractStepSizeController
    if config.dt is None:
        controller = diffrax.PIDController(
            rtol=config.rtol,
            atol=config.absolute_tolerance,
            pcoeff=config.pcoeff,
            icoeff=config.icoeff,
        )
        dt0 = None
    else:
        controller = diffrax.ConstantStepSize()
        dt0 = config.dt
    # diffrax's checks of the save times as NaN, not host callbacks: the compiled solve can
    # then be cached across processes (bayesdoor._cacheable); ts is increasing and inside
    # [ts[0], ts[-1]] by construction, and a NaN would fail the finite check below
    with errors_as_nan():
        sol = diffrax.diffeqsolve(
            term,
            diffrax.Tsit5(),
            t0=ts[0],
            t1=ts[-1],
            dt0=dt0,
            y0=y0,
            args=args,
            saveat=diffrax.SaveAt(ts=ts),
            stepsize_controller=controller,
            max_steps=config.max_steps,
            throw=False,
        )
    # the outputs of the saved states, all sample times at once (evaluated inside the
    # solver's loop, one save at a time, they took a seventh of a batched solve's time);
    # a failed solve leaves non-finite states, read as zero so that no NaN enters the
    # outputs or their gradients (the status says it failed)
    finite = jnp.isfinite(sol.ys)
    states = jnp.where(finite, sol.ys, 0.0)
    output_fn = _with_gains(gains) if gains else _OUTPUTS[output]
    ys = jax.vmap(output_fn, in_axes=(0, 0, None))(ts, states, args)
    status = _status(sol.result)
    good = (status == STATUS_OK) & jnp.all(finite) & jnp.all(jnp.isfinite(ys))
    status = jnp.where((status == STATUS_OK) & ~good, STATUS_FAILED, status)
    signals = jnp.where(good, ys, 0.0).T
    return signals, status


@persistent_jit
def solve_batch(
    args: DoorArgs, ts: Float[Array, " time"], config: SolverConfig, gains: tuple[str, ...] = ()
) -> tuple[Float[Array, "batch channel time"], Int[Array, " batch"]]:
    """:func:`solve` vmapped over a batch of arguments (leading axis of every leaf)."""
    return jax.vmap(lambda a: solve(a, ts, config, gains=gains))(args)
