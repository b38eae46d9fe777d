"""A rig for the oscillator: measured-like runs made by another simulator than the model's.

Each run is the base-excited mass-spring-damper driven by Gaussian white base velocity (not
the model's multisine) at the ISO 8608 level of its speed, integrated in the time domain by
``scipy.signal.lsim`` at four times the sampling rate and decimated through an anti-alias
filter, with sensor noise; its parameters scatter 2 % around a truth away from the
oscillator's nominal values; and its structure has a second mode at 150 Hz (14 dB at its
peak) that the oscillator lacks, above the band the fit compares (5-100 Hz) and inside the
diagnosis's (5-200 Hz). Faulty runs apply the stated faults to the truth: the stiffness loss
to k, the loose mount's damping to the damping ratio. So fitting the oscillator to these runs
is no inverse crime: the model lacks the rig's excitation, its scatter and its second mode.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import scipy.signal
import xarray as xr

from ..io import make_campaign
from ._model import base_velocity_psd
from ._system import FS, RECORD_S, Oscillator

#: integrated from rest for this long before the record: the transient decays by
#: exp(-zeta w_n t) = exp(-13) at the truth's damping
LEAD_S = 2.0
#: the truth: 8 % stiffer, 20 % less damped and on a rougher road than the nominal oscillator
TRUTH = {"natural_frequency_hz": 27.0, "damping_ratio": 0.04, "roughness": 100.0}
#: the run-to-run scatter of the truth's parameters (relative standard deviation)
SCATTER = 0.02
#: the mode the oscillator lacks: Hz, damping ratio, peak amplification minus one
SECOND_MODE = (150.0, 0.02, 4.0)
#: the accelerometer's noise, m/s^2 rms (the response is about 45 m/s^2 rms)
SENSOR_NOISE = 0.05
#: the speeds the runs cycle through, m/s
SPEEDS = (10.0, 15.0, 20.0)


def record_run(
    rng: np.random.Generator,
    speed: float,
    values: dict[str, float],
    *,
    stiffness_loss: float = 0.0,
    added_damping: float = 0.0,
) -> np.ndarray:
    """One record of the rig's structure, m/s^2: lsim of the transfer function from base
    velocity to the mass's acceleration, ``s (c s + k) / (s^2 + c s + k)``, times the second
    mode's ``1 + g B(s)``, ``B = 2 zeta w_2 s / (s^2 + 2 zeta w_2 s + w_2^2)``."""
    wn = 2 * np.pi * values["natural_frequency_hz"]
    k = wn**2 * (1 - stiffness_loss)
    c = 2 * (values["damping_ratio"] + added_damping) * wn
    f2, zeta2, gain = SECOND_MODE
    w2 = 2 * np.pi * f2
    numerator = np.polymul([c, k, 0.0], [1.0, 2 * zeta2 * w2 * (1 + gain), w2**2])
    denominator = np.polymul([1.0, c, k], [1.0, 2 * zeta2 * w2, w2**2])
    fs = 4 * FS
    t = np.arange(round((LEAD_S + RECORD_S) * fs)) / fs
    psd = float(
        base_velocity_psd(
            jnp.asarray(np.float64(values["roughness"])), jnp.asarray(np.float64(speed))
        )
    )
    velocity = np.sqrt(psd * fs / 2) * rng.standard_normal(t.size)
    _, acceleration, _ = scipy.signal.lsim((numerator, denominator), velocity, t)
    record = scipy.signal.decimate(acceleration, 4)[round(LEAD_S * FS) :]
    return record + SENSOR_NOISE * rng.standard_normal(record.size)


def record_campaign(
    seed: int = 0, *, calibration_runs: int = 8, test_runs_per_state: int = 6
) -> xr.Dataset:
    """Healthy calibration runs, then test runs of every state, at :data:`SPEEDS` in turn;
    each fault's severity drawn from the oscillator's prior, every draw from ``seed``.

    Raises
    ------
    ValueError
        For fewer than one calibration run or test run per state.
    """
    if calibration_runs < 1 or test_runs_per_state < 1:
        raise ValueError(
            f"need calibration_runs >= 1 and test_runs_per_state >= 1, got "
            f"{calibration_runs} and {test_runs_per_state}"
        )
    oscillator = Oscillator()
    rng = np.random.default_rng(seed)
    states = [oscillator.healthy] * calibration_runs + [
        s for s in oscillator.states for _ in range(test_runs_per_state)
    ]
    speeds = np.resize(np.asarray(SPEEDS), len(states))
    signals = []
    for state, speed in zip(states, speeds, strict=True):
        values = {k: v * (1 + SCATTER * rng.standard_normal()) for k, v in TRUTH.items()}
        fault = {
            k: rng.uniform(lo, hi) for k, (lo, hi) in oscillator.states[state].severity.items()
        }
        signals.append(record_run(rng, speed, values, **fault)[None])
    t_start, t_stop = oscillator.motion_window(speeds)
    n_test = len(states) - calibration_runs
    return make_campaign(
        np.stack(signals),
        channels=list(oscillator.channels),
        fs=FS,
        state=states,
        system=oscillator.name,
        split=["calibration"] * calibration_runs + ["test"] * n_test,
        t_start=t_start,
        t_stop=t_stop,
        speed=speeds,
    )
