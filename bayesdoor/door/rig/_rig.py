"""The virtual test rig: measured-like campaigns of the door from a separate, finer simulator."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr

from ... import door
from ..._types import Array
from ...io import make_campaign
from ..contact import get_law
from . import _door as d
from ._daq import anti_alias_decimate, apply_cross_axis, mains_signal, quantise
from ._effects import CHANNELS, MAX_HARMONICS, WHEELS, Effects
from ._integrate import integrate

#: per-run parameters the rig scatters (relative standard deviation in :class:`RigConfig`)
SCATTERED = ("K", "c_r", "mu_s", "mu_d", "C")


class RigConfig(eqx.Module):
    """How the rig integrates and measures (all static).

    Attributes
    ----------
    sampling_rate_hz
        Output rate of the data acquisition (Hz).
    oversampling
        Integration steps per output sample: classical RK4 at ``oversampling`` x the output
        rate (16384 Hz by default).
    filter_order, cutoff
        Butterworth anti-alias low-pass of this order at ``cutoff`` x the output rate.
    noise_rms
        White noise of the acquisition chain after its filter, per channel (m/s^2).
    full_scale, bits
        ADC range +-``full_scale`` (m/s^2; default 8 g: the largest D1 impacts reach 35 m/s^2) and
        resolution.
    scatter
        Relative standard deviation (log-normal) of each run's K, c_r, mu_s, mu_d and C
        around the truth: the door is not quite the same from one run to the next.
    speed_scatter
        Relative standard deviation of the actual peak speed around the commanded one.
    rest_after_s
        Rest recorded after the slowest stroke of a campaign.
    chunk_size
        Runs integrated together (one vmapped solve); the last chunk is padded to this size
        (or to the number of runs, if smaller) so every chunk reuses one compilation.
    workers
        Chunks integrated at the same time (threads; each keeps one CPU core busy).
    """

    sampling_rate_hz: float = eqx.field(static=True, default=2048.0)
    oversampling: int = eqx.field(static=True, default=8)
    filter_order: int = eqx.field(static=True, default=8)
    cutoff: float = eqx.field(static=True, default=0.4)
    noise_rms: float = eqx.field(static=True, default=3e-3)
    full_scale: float = eqx.field(static=True, default=8.0 * 9.81)
    bits: int = eqx.field(static=True, default=16)
    scatter: tuple[float, float, float, float, float] = eqx.field(
        static=True, default=(0.03, 0.02, 0.02, 0.02, 0.05)
    )
    speed_scatter: float = eqx.field(static=True, default=0.005)
    rest_after_s: float = eqx.field(static=True, default=0.25)
    chunk_size: int = eqx.field(static=True, default=64)
    workers: int = eqx.field(static=True, default=2)

    def __check_init__(self):
        if not (isinstance(self.oversampling, int) and self.oversampling >= 2):
            raise ValueError(
                f"oversampling={self.oversampling!r} must be an integer >= 2 (the integration "
                "rate is oversampling x sampling_rate_hz; 8 gives 16384 Hz)"
            )
        if not 0.0 < self.cutoff < 0.5:
            raise ValueError(
                f"cutoff={self.cutoff!r} must be in (0, 0.5) of the output rate (below Nyquist)"
            )
        if len(self.scatter) != len(SCATTERED) or min(self.scatter) < 0:
            raise ValueError(
                f"scatter needs {len(SCATTERED)} non-negative relative deviations "
                f"for {SCATTERED}, got {self.scatter!r}"
            )
        for name in ("noise_rms", "speed_scatter", "rest_after_s"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}={getattr(self, name)!r} must be >= 0")
        if self.full_scale <= 0 or self.bits < 2 or self.chunk_size < 1 or self.workers < 1:
            raise ValueError(
                "need full_scale > 0, bits >= 2, chunk_size >= 1 and workers >= 1; got "
                f"{self.full_scale!r}, {self.bits!r}, {self.chunk_size!r}, {self.workers!r}"
            )

    @property
    def lsb(self) -> float:
        """One step of the ADC (m/s^2)."""
        return 2.0 * self.full_scale / 2**self.bits

    @property
    def dt(self) -> float:
        """The integration step (s)."""
        return 1.0 / (self.sampling_rate_hz * self.oversampling)


@dataclasses.dataclass(frozen=True)
class Recording:
    """A campaign and, kept apart from it, what the rig really did.

    ``truth`` is plain JSON-ready data: the rig's true parameters, the effects, the
    configuration and, per run, the scattered parameters, the actual speed and the damage.
    Fitting and classification code receives only ``campaign``.
    """

    campaign: xr.Dataset
    truth: dict


@dataclasses.dataclass(frozen=True)
class RestState:
    """The rig's door at rest with the drive at the closed position.

    ``indentation_m``: the four contact gaps (left wheel, right wheel, +X and -X groove wall;
    positive = indentation, negative = clearance). ``frequencies_hz`` and ``damping_ratios``:
    the oscillatory modes of the equations linearised there (friction acts as its
    regularised viscous slope at rest), sorted by frequency.
    """

    indentation_m: np.ndarray
    frequencies_hz: np.ndarray
    damping_ratios: np.ndarray


@eqx.filter_jit
def _linearise_at_rest(a: d.RunArgs):
    """Contact gaps at the static equilibrium and the Jacobian of the flow (q, q_dot) there.

    The Jacobian is by central differences (steps of 1 nm and 1 um/s, far inside the contact
    indentation and the friction's 0.5 mm/s regularisation): differentiating the equations,
    which already hold Jacobians and a second derivative, would compile for minutes.
    """
    q0 = d.static_equilibrium(a)
    latch = jnp.full(d.N_CONTACT, d.LATCH_FLOOR)

    def flow(x):
        q, qd = x[: d.N_DOF], x[d.N_DOF :]
        return jnp.concatenate([qd, d.dynamics(0.0, q, qd, latch, a)[0]])

    x0 = jnp.concatenate([q0, jnp.zeros_like(q0)])
    steps = jnp.concatenate([jnp.full(d.N_DOF, 1e-9), jnp.full(d.N_DOF, 1e-6)])
    jac = door.central_jacobian(flow, x0, steps)
    return d.contact_coordinates(q0, a)[: d.N_CONTACT], jac


def _severities(states, severities, keys) -> dict[str, np.ndarray]:
    """Damage of each run: given, or drawn uniformly from its state's prior (DamageSpec)."""
    runs = len(states)
    draws = np.asarray(jax.vmap(lambda k: jax.random.uniform(k, (3,)))(keys))
    out = {name: np.zeros(runs) for name in ("d1_height", "d2_depth", "d2_angle")}
    for i, state in enumerate(states):
        spec = door.STATES[state]
        given = {} if severities is None else dict(severities[i] or {})
        unknown = sorted(set(given) - set(spec.severity))
        if unknown:
            raise ValueError(
                f"run {i} ({state}) takes severities {list(spec.severity) or 'none'}, got {unknown}"
            )
        for j, (name, (lo, hi)) in enumerate(spec.severity.items()):
            value = float(given.get(name, lo + (hi - lo) * draws[i, j]))
            if not lo <= value <= hi:
                raise ValueError(f"run {i}: {state} severity {name}={value!r} outside [{lo}, {hi}]")
            out[name][i] = value
    return out


class VirtualRig(eqx.Module):
    """A virtual test rig of the door: the "real door" the library's model is fitted to.

    A second, higher-fidelity simulator, independent of the reduced model's code: textbook
    (non-smoothed) contact with latched approach velocities, classical RK4 at 16384 Hz,
    exact rotations and convective terms, a panel bending mode near 165 Hz, run-to-run
    parameter scatter, a causal anti-alias filter and decimation to 2048 Hz, sensor noise
    and 16-bit quantisation. It can inject every catalogue effect (:class:`Effects`).
    ``docs/rig.md`` describes it.

    Parameters
    ----------
    truth
        The rig's true parameters (default: :class:`RigTruth`'s values, law 3).
    effects
        Catalogue effects to inject (default: none).
    config
        Integration and measurement settings.

    Examples
    --------
    >>> rig = VirtualRig()
    >>> campaign = rig.record(["healthy", "D2"], [0.4, 0.3], key=jax.random.key(0))
    >>> campaign.acceleration.dims
    ('run', 'channel', 'time')
    """

    truth: d.RigTruth = d.RigTruth()
    effects: Effects = Effects()
    config: RigConfig = RigConfig()

    def record(
        self,
        states: Sequence[str],
        v_max: Sequence[float] | np.ndarray,
        *,
        key: Array,
        split: Sequence[str] | None = None,
        severities: Sequence[Mapping[str, float] | None] | None = None,
        duration: float | None = None,
        progress: Callable[[int], None] | None = None,
    ) -> xr.Dataset:
        """Record a campaign (``docs/data.md``); the truth is in :meth:`run`'s result.

        See :meth:`run` for the parameters.
        """
        return self.run(
            states,
            v_max,
            key=key,
            split=split,
            severities=severities,
            duration=duration,
            progress=progress,
        ).campaign

    def run(
        self,
        states: Sequence[str],
        v_max: Sequence[float] | np.ndarray,
        *,
        key: Array,
        split: Sequence[str] | None = None,
        severities: Sequence[Mapping[str, float] | None] | None = None,
        duration: float | None = None,
        progress: Callable[[int], None] | None = None,
    ) -> Recording:
        """Record one run per entry of ``states`` and return the campaign and the truth.

        Parameters
        ----------
        states
            Per run: ``healthy``, ``D1`` or ``D2``.
        v_max
            Per run: commanded peak speed (m/s).
        key
            PRNG key; run i's data depend only on ``split(key, runs)[i]`` (its scatter,
            damage draw, noise and hum phase), so the same key gives the same data.
        split
            Per run, optional: ``calibration`` or ``test``.
        severities
            Per run, optional: damage severities (e.g. ``{"d1_height": 1e-3}``); missing
            ones are drawn uniformly from the state's prior (``door.STATES``).
        duration
            Record length (s); default 0.25 s rest, the slowest actual stroke and
            ``config.rest_after_s`` of rest, whole samples.
        progress
            Called with the number of runs finished after each chunk (chunks may finish in
            any order).

        Returns
        -------
        recording
            ``campaign`` (variable ``acceleration`` (run, channel, time); per-run ``state``,
            ``v_max``, ``t_start``, ``t_stop`` and ``split`` if given) and ``truth``.

        Raises
        ------
        ValueError
            For an empty or mismatched ``states`` / ``v_max`` / ``split``, an unknown state,
            a speed outside ``door.V_MAX_RANGE``, severities outside their prior, or a
            duration shorter than the runs' strokes.
        """
        states = [str(s) for s in states]
        speeds = np.atleast_1d(np.asarray(v_max, dtype=float))
        runs = len(states)
        if runs == 0 or speeds.shape != (runs,):
            raise ValueError(
                f"need one v_max per state: got {runs} states and v_max of shape {speeds.shape}"
            )
        bad = sorted(set(states) - set(door.STATES))
        if bad:
            raise ValueError(f"unknown states {bad}: the rig records {', '.join(door.STATES)}")
        lo, hi = door.V_MAX_RANGE
        if not np.all(np.isfinite(speeds) & (speeds >= lo) & (speeds <= 0.98 * hi)):
            raise ValueError(
                f"v_max must lie in [{lo}, {0.98 * hi:.3f}] m/s (the S-curve's range, less room "
                f"for the rig's speed scatter); got {speeds[(speeds < lo) | (speeds > 0.98 * hi)]}"
            )
        if split is not None and len(split) != runs:
            raise ValueError(f"split needs one label per run ({runs}), got {len(split)}")
        if severities is not None and len(severities) != runs:
            raise ValueError(f"severities needs one entry per run ({runs}), got {len(severities)}")

        run_keys = jax.random.split(key, runs)
        parts = jax.vmap(lambda k: jax.random.split(k, 4))(run_keys)
        k_scatter, k_damage, k_noise, k_hum = (parts[:, i] for i in range(4))
        cfg = self.config
        z = np.asarray(jax.vmap(lambda k: jax.random.normal(k, (6,)))(k_scatter))
        per_run = {
            name: getattr(self.truth, name) * np.exp(sd * z[:, i])
            for i, (name, sd) in enumerate(zip(SCATTERED, cfg.scatter, strict=True))
        }
        per_run["v_actual"] = speeds * (1.0 + cfg.speed_scatter * z[:, 5])
        damage = _severities(states, severities, k_damage)
        strokes = np.asarray(door.motion_duration(per_run["v_actual"]))
        needed = d.REST_S + float(strokes.max())
        if duration is None:
            duration = needed + cfg.rest_after_s
        elif duration < needed:
            raise ValueError(
                f"duration={duration!r} s is shorter than the rest and the slowest stroke "
                f"({needed:.3f} s); leave it out for the default"
            )
        n_out = math.ceil(round(duration * cfg.sampling_rate_hz, 6))

        acc = np.empty((runs, len(CHANNELS), n_out))
        size = min(cfg.chunk_size, runs)
        chunks = [np.arange(i, min(i + size, runs)) for i in range(0, runs, size)]
        inputs = {**per_run, **damage}

        def chunk_args(idx):
            padded = np.concatenate([idx, np.full(size - idx.size, idx[-1])])
            return self._run_args({k: v[padded] for k, v in inputs.items()})

        solve = integrate.lower(chunk_args(chunks[0]), n_out * cfg.oversampling, cfg.dt).compile()

        def record_chunk(idx):
            fine = np.asarray(solve(chunk_args(idx)))[: idx.size]
            acc[idx] = self._measure(fine, k_noise[idx], k_hum[idx], n_out)
            return idx.size

        # chunks run concurrently in threads (XLA releases the GIL), one core each
        with ThreadPoolExecutor(max_workers=cfg.workers) as pool:
            done = 0
            for finished in as_completed([pool.submit(record_chunk, idx) for idx in chunks]):
                done += finished.result()
                if progress is not None:
                    progress(done)

        campaign = make_campaign(
            acc,
            channels=CHANNELS,
            fs=cfg.sampling_rate_hz,
            state=states,
            system="elevator_door",
            v_max=speeds,
            t_start=np.full(runs, d.REST_S),
            t_stop=d.REST_S + strokes,
            split=None if split is None else list(split),
        )
        campaign.attrs["source"] = "bayesdoor virtual rig"
        campaign.attrs["effects"] = ", ".join(self.effects.names()) or "none"
        truth = {
            "parameters": self.truth.to_dict(),
            "effects": self.effects.to_dict(),
            "config": {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg)},
            "runs": [
                {name: float(v[i]) for name, v in {**per_run, **damage}.items()}
                for i in range(runs)
            ],
        }
        return Recording(campaign=campaign, truth=truth)

    def rest_state(self) -> RestState:
        """Static indentations and the modes of the door at rest (true, unscattered values).

        Examples
        --------
        >>> rest = VirtualRig().rest_state()
        >>> bool(rest.indentation_m[0] > 0)  # the wheels sit in the rail
        True
        """
        names = {*SCATTERED, "v_actual", "d1_height", "d2_depth", "d2_angle"}
        args = self._run_args({k: np.atleast_1d(self._true_value(k)) for k in names})
        one = jax.tree_util.tree_map(lambda x: x[0], args)
        gaps, jac = (np.asarray(x) for x in _linearise_at_rest(one))
        frequencies, damping = door.oscillatory_modes(jac)
        return RestState(indentation_m=gaps, frequencies_hz=frequencies, damping_ratios=damping)

    def _true_value(self, name: str) -> float:
        if name in SCATTERED:
            return float(getattr(self.truth, name))
        return 0.4 if name == "v_actual" else 0.0

    def _run_args(self, per_run: Mapping[str, np.ndarray]) -> d.RunArgs:
        """Equation arguments of a batch of runs (SI units)."""
        t = self.truth
        batch = per_run["K"].shape[0]

        def col(x):
            return jnp.asarray(np.broadcast_to(np.asarray(x, dtype=float), (batch,)))

        def rows(x):
            x = np.asarray(x, dtype=float)
            return jnp.asarray(np.broadcast_to(x, (batch, *x.shape)))

        n = t.n
        omega = 2.0 * np.pi * np.asarray(d.FRAME_HZ)
        w_bend = 2.0 * np.pi * t.bending_hz
        xi = np.asarray(get_law(t.I).hysteresis_factor(jnp.asarray(per_run["c_r"])))
        fm = self.effects.frame_mode
        w_extra = 2.0 * np.pi * (50.0 if fm is None else fm.frequency_hz)
        zeta_extra = 0.01 if fm is None else fm.damping_ratio
        ecc = self.effects.wheel_eccentricity
        ecc_amp = np.zeros((2, MAX_HARMONICS))
        ecc_phase = np.zeros((2, MAX_HARMONICS))
        if ecc is not None:
            side, count = WHEELS.index(ecc.wheel), len(ecc.amplitudes)
            ecc_amp[side, :count] = ecc.amplitudes
            ecc_phase[side, :count] = ecc.phases
        wav = self.effects.rail_waviness
        return d.RunArgs(
            k_contact=col(per_run["K"] * 1000.0**n),
            n=col(n),
            xi=col(xi),
            mu_s=col(per_run["mu_s"]),
            mu_d=col(per_run["mu_d"]),
            mass=col(d.PANEL_MASS * t.MF),
            frame_k=rows(d.FRAME_MODAL_MASS * omega**2),
            frame_c=jnp.asarray(2.0 * d.FRAME_MODAL_MASS * per_run["C"][:, None] * omega),
            bend_k=col(d.BENDING_MODAL_MASS * w_bend**2),
            bend_c=col(2.0 * t.bending_damping * d.BENDING_MODAL_MASS * w_bend),
            v_run=col(per_run["v_actual"]),
            d1_height=col(per_run["d1_height"]),
            d2_depth=col(per_run["d2_depth"]),
            d2_angle=col(per_run["d2_angle"]),
            extra_k=col(d.FRAME_MODAL_MASS * w_extra**2),
            extra_c=col(2.0 * zeta_extra * d.FRAME_MODAL_MASS * w_extra),
            extra_lift=col(0.0 if fm is None else fm.rail_lift),
            extra_shape=rows(np.zeros(4) if fm is None else fm.participation),
            ecc_amplitude=rows(ecc_amp),
            ecc_phase=rows(ecc_phase),
            wav_wavenumber=col(1.0 if wav is None else 2.0 * np.pi / wav.wavelength_m),
            wav_amplitude=col(0.0 if wav is None else wav.amplitude_m),
            wav_phase=col(0.0 if wav is None else wav.phase),
        )

    def _measure(self, fine: np.ndarray, noise_keys, hum_keys, n_out: int) -> np.ndarray:
        """The acquisition chain on fine-rate accelerations (run, channel, step)."""
        cfg = self.config
        x = apply_cross_axis(fine, self.effects.sensor_cross_axis)
        hum = self.effects.mains_hum
        if hum is not None:
            orders = len(hum.harmonic_ratios) + 1
            phases = np.asarray(
                jax.vmap(lambda k: jax.random.uniform(k, (orders,), maxval=2.0 * np.pi))(hum_keys)
            )
            t = np.arange(fine.shape[-1]) * cfg.dt
            x = x + mains_signal(hum, t, phases)
        x = anti_alias_decimate(
            x, cfg.oversampling, cfg.sampling_rate_hz, cfg.cutoff, cfg.filter_order
        )[..., :n_out]
        noise = np.asarray(
            jax.vmap(lambda k: jax.random.normal(k, (len(CHANNELS), n_out)))(noise_keys)
        )
        return quantise(x + cfg.noise_rms * noise, cfg.full_scale, cfg.bits)
