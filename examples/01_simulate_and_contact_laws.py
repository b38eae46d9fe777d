# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#       jupytext_version: 1.19.6
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # 1. Simulating the door and comparing contact laws
#
# The reduced-order door of the paper is a differentiable JAX model: one panel hanging from two
# wheels on a top rail, a guide shoe in the sill groove, a belt drive and a flexible frame. Two
# accelerometers, A1 on the panel and A2 on the header, measure along X (out of the door plane)
# and Z (the sliding direction), at 2048 Hz. This notebook
#
# 1. simulates one opening stroke in each of the three states (healthy, D1 debris in the
#    groove, D2 a flat on the top right wheel) and looks at the signals and their spectra;
# 2. compares the nine contact laws of the paper's Table 1: their hysteresis factors, the
#    restitution each actually delivers in one impact, and what the choice does to a run.
#
# Sizes are set by one variable, read from the environment: `BAYESDOOR_EXAMPLE_SIZE=tiny` (the
# test suite) computes fewer restitution values; `quick` (the default) and `full` are the same
# here, a minute or two on a laptop CPU, most of it compiling the solver.

# %%
import os
from pathlib import Path

import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np
from scipy.optimize import brentq

from bayesdoor.diagnose import log10_psd_variance, welch_dof
from bayesdoor.door import CHANNELS, DoorDamage, DoorParameters, ElevatorDoor
from bayesdoor.door.contact import LAW_NAMES, hysteresis_factor, single_impact
from bayesdoor.features import log_psd, segment_weights, welch_psd

SIZE = os.environ.get("BAYESDOOR_EXAMPLE_SIZE", "quick")
SIZES = {
    # restitution values for the single-impact comparison, door speed (m/s)
    "tiny": {"c_r": [0.6, 0.9], "v_max": 0.5},
    "quick": {"c_r": list(np.linspace(0.55, 0.95, 9)), "v_max": 0.4},
}
SIZES["full"] = SIZES["quick"]
if SIZE not in SIZES:
    raise ValueError(f"BAYESDOOR_EXAMPLE_SIZE={SIZE!r}: use one of {', '.join(SIZES)}")
size = SIZES[SIZE]
OUT = Path(os.environ.get("BAYESDOOR_EXAMPLE_OUT", "out/examples")) / "01"
OUT.mkdir(parents=True, exist_ok=True)

# %% [markdown]
# ## One stroke in each state
#
# `ElevatorDoor()` integrates the equations with diffrax (adaptive Tsit5, float64). The
# parameters are the paper's Table 2 optimum; the damage severities are the middle of their
# ranges (D1: a 1.05 mm bump; D2: a 0.175 mm deep flat). The first call compiles the solver
# (seconds); later calls reuse it.

# %%
door = ElevatorDoor()
theta = DoorParameters.paper_optimum()
v_max = size["v_max"]
runs = {state: door.simulate(theta, DoorDamage.for_state(state), v_max) for state in door.states}
t = np.asarray(runs["healthy"].time)
print({name: float(value) for name, value in theta.to_dict().items()})
print(f"{len(t)} samples, {t[-1]:.2f} s at {door.sampling_rate_hz:.0f} Hz")

# %%
fig, axes = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
for ax, channel in zip(axes, ("A1X", "A1Z"), strict=True):
    c = CHANNELS.index(channel)
    for state, run in runs.items():
        ax.plot(t, np.asarray(run.signals[c]), lw=0.6, label=state)
    ax.set_ylabel(f"{channel} (m/s$^2$)")
axes[0].legend(ncol=3)
axes[-1].set_xlabel("time (s)")
fig.suptitle(f"one opening stroke at v_max = {v_max} m/s")
fig.savefig(OUT / "signals.png", dpi=120)

# %% [markdown]
# D1 shows two bursts where the shoe rides over the bumps (at 0.25 m and 0.55 m of travel);
# D2 shows a dip of the wheel load once per wheel revolution (every 0.1885 m of travel). The
# classifier does not see the signals but their spectra: the log10 Welch PSD (Hann, 512
# samples, half overlap) over the segments that lie entirely inside the stroke.

# %%
t_start, t_stop = door.motion_window(v_max)
weights = segment_weights(len(t), door.sampling_rate_hz, t_start[0], t_stop[0])
fig, axes = plt.subplots(1, len(CHANNELS), figsize=(12, 3.2), sharey=True)
for state, run in runs.items():
    freqs, psd = welch_psd(run.signals, door.sampling_rate_hz, segment_weights=weights)
    for c, ax in enumerate(axes):
        ax.plot(np.asarray(freqs), np.asarray(log_psd(psd[c])), lw=0.8, label=state)
for ax, channel in zip(axes, CHANNELS, strict=True):
    ax.set_xlim(0, 200)
    ax.set_title(channel)
    ax.set_xlabel("frequency (Hz)")
axes[0].set_ylabel("log10 PSD ((m/s$^2$)$^2$/Hz)")
axes[0].legend()
fig.savefig(OUT / "psd_by_state.png", dpi=120)

# %% [markdown]
# ## The nine contact laws
#
# All nine laws share the paper's force `F = K d^n (1 + xi(c_r) d_dot / d_dot_minus)`; they
# differ only in the hysteresis factor `xi(c_r)`. `hysteresis_factor(I, c_r)` evaluates law
# `I` (the paper's index, 1-9) and works on traced, batched indices.

# %%
c_r_grid = jnp.linspace(0.5, 0.99, 100)
fig, ax = plt.subplots(figsize=(7, 4))
for index, name in enumerate(LAW_NAMES, start=1):
    ax.plot(np.asarray(c_r_grid), np.asarray(hysteresis_factor(index, c_r_grid)), label=name)
ax.set_xlabel("nominal coefficient of restitution c_r")
ax.set_ylabel("hysteresis factor xi")
ax.legend(fontsize=7)
fig.savefig(OUT / "hysteresis_factors.png", dpi=120)

# %% [markdown]
# What a law really does is the restitution it *delivers*. `single_impact` integrates one impact
# of a point mass on a flat through the law (scipy DOP853, tight tolerances) and returns
# `v_out / v_in`. It depends on `xi` alone, not on the stiffness, the exponent, the mass or the
# speed (the closed form is in [the model page](../docs/model.md)). Hu-Guo delivers within a
# few per cent of the nominal value over the whole range and Herbert-McWhannell from about
# `c_r = 0.7` up; Hunt-Crossley and Lankarani-Nikravesh only as `c_r -> 1`; Lee-Wang and
# Gharib-Hurmuzlu dissipate less than their nominal `c_r` says, Flores, Zhiying-Qishao and
# Gonthier more (`results/contact_laws.md` tabulates it).

# %%
c_r_values = size["c_r"]
delivered = np.array(
    [
        [single_impact(index, c_r, 0.1, 2e8, 1.5, 1.0) for c_r in c_r_values]
        for index in range(1, len(LAW_NAMES) + 1)
    ]
)
fig, ax = plt.subplots(figsize=(7, 4))
for name, row in zip(LAW_NAMES, delivered, strict=True):
    ax.plot(c_r_values, row, "o-", ms=3, label=name)
ax.plot([0.5, 1.0], [0.5, 1.0], "k--", lw=0.8, label="delivered = nominal")
ax.set_xlabel("nominal c_r")
ax.set_ylabel("delivered restitution")
ax.legend(fontsize=7)
fig.savefig(OUT / "delivered_restitution.png", dpi=120)
for name, row in zip(LAW_NAMES, delivered, strict=True):
    print(f"{name:>20}: " + "  ".join(f"{e:.3f}" for e in row))

# %% [markdown]
# ## Does the law matter for a run of the door?
#
# The law index is a traced parameter, so the nine variants of one healthy run are one
# vmapped solve (`simulate_batch`): everything else stays at the paper's optimum. The spread
# between laws is compared with the scatter of the Welch estimate itself: a bin of the log PSD
# of a noisy measurement averaged over `K` Hann segments is a scaled chi-square with `nu`
# degrees of freedom (`welch_dof`), so its log10 scatters by `sqrt(log10_psd_variance(nu))`
# decades. No fit can resolve less than that from one run.

# %%
laws = jnp.arange(1, len(LAW_NAMES) + 1)
batch_theta = DoorParameters(**{**theta.to_dict(), "I": laws})
batch = door.simulate_batch(batch_theta, DoorDamage.healthy(), v_max)
assert bool(jnp.all(batch.ok)), "a law's solve failed"
freqs, psd = welch_psd(batch.signals, door.sampling_rate_hz, segment_weights=weights)
logs = np.asarray(log_psd(psd))  # (law, channel, freq)
band = (np.asarray(freqs) >= 4) & (np.asarray(freqs) <= 96)
spread = logs[..., band].max(axis=0) - logs[..., band].min(axis=0)
segments = int(np.asarray(weights).sum())
welch_sd = float(np.sqrt(log10_psd_variance(welch_dof(segments, 512))))
for channel, row in zip(CHANNELS, spread, strict=True):
    print(f"{channel}: largest spread between laws over 4-96 Hz {row.max():.3f} decades")
print(f"Welch scatter of one measured run ({segments} segments): about {welch_sd:.3f} decades")

# %%
fig, axes = plt.subplots(1, len(CHANNELS), figsize=(12, 3.2), sharey=True)
for c, ax in enumerate(axes):
    ax.plot(np.asarray(freqs)[band], spread[c], lw=1)
    ax.axhline(welch_sd, color="k", ls="--", lw=0.8)
    ax.set_title(CHANNELS[c])
    ax.set_xlabel("frequency (Hz)")
axes[0].set_ylabel("max - min over the laws (decades)")
fig.savefig(OUT / "law_spread.png", dpi=120)

# %% [markdown]
# At the paper's nominal `c_r = 0.69` the laws move the spectrum by several times the Welch
# scatter: the law matters. But not as a separate property. The force depends on the law and
# `c_r` only through `xi(c_r)`, so two laws at restitutions with the same `xi` are the same
# force. Every law reaches `xi` between 0.10 and 0.30 inside the Table 2 bounds of `c_r`
# (0.60-0.95); below, each law gets the `c_r` that gives it Lankarani-Nikravesh's `xi` at
# `c_r = 0.85`, and the nine runs are simulated again.

# %%
xi_target = float(hysteresis_factor(6, 0.85))
matched_c_r = jnp.asarray(
    [
        brentq(lambda c, index=index: float(hysteresis_factor(index, c)) - xi_target, 0.6, 0.95)
        for index in range(1, len(LAW_NAMES) + 1)
    ]
)
for name, c in zip(LAW_NAMES, np.asarray(matched_c_r), strict=True):
    print(f"{name:>20}: c_r = {c:.4f}")
matched_theta = DoorParameters(**{**theta.to_dict(), "I": laws, "c_r": matched_c_r})
matched = door.simulate_batch(matched_theta, DoorDamage.healthy(), v_max)
_, matched_psd = welch_psd(matched.signals, door.sampling_rate_hz, segment_weights=weights)
matched_logs = np.asarray(log_psd(matched_psd))[..., band]
matched_spread = matched_logs.max(axis=0) - matched_logs.min(axis=0)
print(f"largest spread between laws at matched xi: {matched_spread.max():.2e} decades")

# %% [markdown]
# With matched `xi` the nine runs agree to round-off: over the overlap of their ranges, the law
# index and `c_r` are one parameter, and healthy runs cannot tell the laws apart. That is what
# the contact-law ablation (`results/contact_law_ablation.md`, a posterior per law) finds too.
# The index stays a parameter of the fit (CMA-ES treats it as an integer), but its value says
# little on its own; read it together with `c_r`. When this notebook runs as a script, its
# figures are in `out/examples/01/`.
