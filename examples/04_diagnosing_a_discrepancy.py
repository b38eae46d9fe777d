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
# # 4. Diagnosing a discrepancy
#
# A fitted model is wrong somewhere; the question is where, and why. `bayesdoor.diagnose`
# compares measured runs with posterior-predictive simulations of the same runs, finds the
# features the model does not explain (a residual map over frequency and over wavenumber, the
# coherence between a sensor's axes, lines at rest), and ranks the causes of the system's
# catalogue by how well their signatures match. This notebook
#
# 1. records a new campaign on the virtual rig with an effect the reduced model lacks, an
#    extra frame resonance (`frame_mode`);
# 2. simulates those runs with the posterior of notebook 2 (fitted on runs without the
#    effect) and finds the residual features;
# 3. ranks the door's catalogue of causes and compares the verdict with what the rig hid;
# 4. runs the same diagnosis on healthy runs without the effect, the reference any verdict
#    has to beat.
#
# It starts from the fit saved by `02_model_updating.py`: run that first, with the same
# `BAYESDOOR_EXAMPLE_SIZE` (`tiny`, `quick` (default) or `full`) and `BAYESDOOR_EXAMPLE_OUT`.

# %%
import os
from pathlib import Path

import jax
import matplotlib.pyplot as plt
import numpy as np
import scipy.signal

from bayesdoor.datasets import load_demo_campaign
from bayesdoor.diagnose import find_features, rank_causes
from bayesdoor.inference import FitResult
from bayesdoor.rig import Effects, FrameMode, VirtualRig
from bayesdoor.systems.door import DOOR_CATALOGUE, ElevatorDoor

SIZE = os.environ.get("BAYESDOOR_EXAMPLE_SIZE", "quick")
SIZES = {
    # rig runs with the effect (their speeds), predictive draws per run, demo campaign size
    "tiny": {"speeds": [0.3, 0.4, 0.5], "draws": 4, "campaign": (3, 2)},
    "quick": {"speeds": [0.25, 0.3, 0.35, 0.4, 0.45, 0.5], "draws": 8, "campaign": (10, 100)},
    "full": {"speeds": list(np.linspace(0.25, 0.5, 12)), "draws": 16, "campaign": (10, 100)},
}
if SIZE not in SIZES:
    raise ValueError(f"BAYESDOOR_EXAMPLE_SIZE={SIZE!r}: use one of {', '.join(SIZES)}")
size = SIZES[SIZE]
ROOT = Path(os.environ.get("BAYESDOOR_EXAMPLE_OUT", "out/examples"))
OUT = ROOT / "04"
OUT.mkdir(parents=True, exist_ok=True)

# %% [markdown]
# ## A campaign with a hidden frame resonance
#
# `FrameMode.from_seed(0)` draws an extra frame mode (frequency, damping, how much it lifts the
# rail, how much each channel sees of it); the rig records healthy runs at several speeds with
# it. The effect's parameters stay in `recording.truth`, apart from the campaign.

# %%
effect = FrameMode.from_seed(0)
rig = VirtualRig(effects=Effects(frame_mode=effect))
speeds = size["speeds"]
recording = rig.run(
    ["healthy"] * len(speeds),
    speeds,
    key=jax.random.key(4),
    split=["calibration"] * len(speeds),
)
campaign = recording.campaign
print(f"{campaign.sizes['run']} runs at v_max {speeds} m/s")
print("hidden:", effect)

# %% [markdown]
# ## Posterior-predictive simulations of the same runs
#
# Each predictive draw takes one posterior sample of notebook 2's fit (the contact law fixed
# at the fit's) and simulates every run at its speed, over the same record length. The rig's
# records carry acquisition noise the model does not simulate; white noise at the level each
# channel shows at rest, before the door moves, is added to the simulations, so that a quiet
# frequency is not mistaken for a discrepancy. The level is the median over frequency of the
# rest spectrum, which a line or a ringing mode at rest cannot raise.

# %%
fit_folder = ROOT / "02" / "fit"
if not (fit_folder / "fit.json").is_file():
    raise FileNotFoundError(
        f"no fit in {fit_folder}: run examples/02_model_updating.py first with the same "
        "BAYESDOOR_EXAMPLE_SIZE and BAYESDOOR_EXAMPLE_OUT"
    )
fit = FitResult.load(fit_folder)
door = ElevatorDoor()
fs = door.sampling_rate_hz


def predictive_runs(runs, n_draws, seed):
    """Measured signals, predictive simulations (draw, run, channel, time) and the windows."""
    measured = np.asarray(runs.acceleration.transpose("run", "channel", "time").values)
    n_run, n_channel, n_time = measured.shape
    v = np.asarray(runs.v_max.values, dtype=float)
    t_start = np.asarray(runs.t_start.values, dtype=float)
    t_stop = np.asarray(runs.t_stop.values, dtype=float)
    draws = fit.posterior_draws()
    pick = np.linspace(0, len(next(iter(draws.values()))) - 1, n_draws).astype(int)
    values = {
        name: np.repeat(draws[name][pick], n_run)
        if name in draws
        else np.full(n_draws * n_run, value)
        for name, value in fit.point.items()
    }
    result = door.simulate_values(values, np.tile(v, n_draws), duration=n_time / fs)
    if not bool(np.all(np.asarray(result.status) == 0)):
        raise RuntimeError("a predictive simulation failed; check the fit's draws")
    simulated = np.asarray(result.signals).reshape(n_draws, n_run, n_channel, -1)[..., :n_time]
    rest = measured[..., : int(t_start.min() * fs)]
    _, rest_psd = scipy.signal.welch(rest, fs, nperseg=min(rest.shape[-1], int(fs) // 4))
    noise_sd = np.sqrt(np.median(rest_psd.mean(axis=0), axis=-1) * fs / 2)[None, None, :, None]
    rng = np.random.default_rng(seed)
    simulated = simulated + noise_sd * rng.standard_normal(simulated.shape)
    return measured, simulated, v, t_start, t_stop


measured, predictive, v, t_start, t_stop = predictive_runs(campaign, size["draws"], seed=0)
print("measured", measured.shape, " predictive", predictive.shape)

# %% [markdown]
# ## What the model does not explain
#
# `find_features` builds the residual map: per run, channel and 1 Hz bin, the measured log PSD
# against the predictive draws, standardised with the Welch scatter and the draws' spread,
# combined over runs at fixed frequency and at fixed wavenumber (a tone from a spatial period
# moves with the speed), then tested with Benjamini-Hochberg at a 1 % false discovery rate. It
# also compares the coherence of each sensor's X and Z and looks for lines at rest.
#
# Two choices keep the reduced model's known limits out of the answer. The band is the fit's
# feature band (4-96 Hz): above it the rig differs from the reduced model everywhere (its panel
# bending mode at 165 Hz, fine rail roughness; `docs/diagnosis.md`). And a smooth misfit of
# the spectrum's shape, which no catalogue cause explains, is taken out first: the running
# median of each run's residual over 31 bins (`smooth_discrepancy_bins=15`, as the library's
# own diagnosis uses), so that only features narrower than that remain (a resonance, a tone, a
# line).

# %%
pairs = (("A1X", "A1Z"), ("A2X", "A2Z"))
band = (fit.feature_spec.f_low, fit.feature_spec.f_high)
features = find_features(
    measured,
    predictive,
    fs,
    channels=door.channels,
    t_start=t_start,
    t_stop=t_stop,
    speeds=v,
    pairs=pairs,
    band=band,
    smooth_discrepancy_bins=15,
)
found = features.summary()
print(f"{len(found)} significant features; the first ten:")
for line in found[:10]:
    print(" ", line)

# %%
residuals = features.residuals
fig, axes = plt.subplots(len(door.channels), 1, figsize=(9, 7), sharex=True)
for c, ax in enumerate(axes):
    ax.plot(residuals.freqs, residuals.combined[c], lw=0.8)
    hits = residuals.significant[c]
    ax.plot(residuals.freqs[hits], residuals.combined[c][hits], "r.", ms=4)
    ax.axvline(effect.frequency_hz, color="k", ls=":", lw=0.8)
    ax.set_ylabel(door.channels[c])
axes[0].set_title("combined residual over runs (red: significant; dotted: the hidden mode)")
axes[-1].set_xlabel("frequency (Hz)")
fig.savefig(OUT / "residual_map.png", dpi=120)

# %% [markdown]
# ## Which cause?
#
# Each candidate of `DOOR_CATALOGUE` has a signature: a frame mode is a peak at a fixed
# frequency in most runs that is absent at rest; an eccentric wheel gives tones at harmonics of
# the wheel's rotation that track the speed; a rail irregularity a tracking tone at another
# wavelength; a cross-axis sensor an excess coherence between its axes; mains hum a line at 50
# or 60 Hz that stays at rest. `rank_causes` scores each signature on the features; the verdict
# is the top candidate when it passes at least 3/4 of its checks and is not tied.

# %%
ranking = rank_causes(features, DOOR_CATALOGUE)
print("verdict:", ranking.verdict)
for cause in ranking.causes:
    print(f"{cause.name:>20}: score {cause.score:.2f}  {cause.feature}")
best = ranking.causes[0]
print("\nevidence:", best.evidence)
print("parameters:", dict(best.parameters))
print(
    f"hidden: frame mode at {effect.frequency_hz:.2f} Hz, damping ratio {effect.damping_ratio:.4f}"
)

# %% [markdown]
# ## The reference: runs without the effect
#
# A verdict only means something if runs without any effect do not produce one. The healthy
# test runs of the demo campaign come from the same rig without effects; the same diagnosis
# with the same fit:

# %%
n_calibration, n_test = size["campaign"]
demo = load_demo_campaign(calibration_runs=n_calibration, test_runs_per_state=n_test)
clean = demo.isel(
    run=np.flatnonzero((demo.split.values == "test") & (demo.state.values == "healthy"))[
        : len(speeds)
    ]
)
measured0, predictive0, v0, t_start0, t_stop0 = predictive_runs(clean, size["draws"], seed=1)
features0 = find_features(
    measured0,
    predictive0,
    fs,
    channels=door.channels,
    t_start=t_start0,
    t_stop=t_stop0,
    speeds=v0,
    pairs=pairs,
    band=band,
    smooth_discrepancy_bins=15,
)
reference = rank_causes(features0, DOOR_CATALOGUE)
print(f"{clean.sizes['run']} runs without the effect at v_max {v0.tolist()}")
print("verdict:", reference.verdict)
if reference.causes[0].score > 0:
    print("its parameters:", dict(reference.causes[0].parameters))
found0 = features0.summary()
print(f"{len(found0)} significant features; the first ten:")
for line in found0[:10]:
    print(" ", line)

# %% [markdown]
# Read the two verdicts together. A feature that also shows without the effect is a
# difference between the rig and the reduced model (the model is not the rig), not the hidden
# cause; only what appears with the effect and not without is evidence for it. The signature
# ranking proposes; confirming a cause takes a refit of the model extended by it and a gain on
# held-out runs (`docs/diagnosis.md`, section 5).
