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
# features the model does not explain, ranks the causes of the system's catalogue by how well
# their signatures match, and confirms a cause only when the model extended by it predicts
# held-out runs better. This notebook
#
# 1. records a new campaign on the virtual rig with an effect the reduced model lacks, an
#    extra frame resonance (`frame_mode`);
# 2. diagnoses it against the door model as notebook 2 fitted it (on runs without the effect);
# 3. looks at the residual features, the signature ranking and the refits' held-out gain, and
#    compares the verdict with what the rig hid;
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

from bayesdoor.diagnose import DiagnosisSettings, diagnose_campaign
from bayesdoor.door import DOOR_CATALOGUE, ElevatorDoor
from bayesdoor.door.datasets import load_demo_campaign
from bayesdoor.door.rig import Effects, FrameMode, VirtualRig
from bayesdoor.inference import FitResult

SIZE = os.environ.get("BAYESDOOR_EXAMPLE_SIZE", "quick")
SIZES = {
    # speeds of the rig runs with the effect, demo campaign size, diagnose_campaign's sizes
    "tiny": {
        "speeds": [0.3, 0.4, 0.5, 0.3],
        "campaign": (3, 2),
        "diagnosis": DiagnosisSettings(predictive_draws=2, max_candidates=1, refit_evals=16),
    },
    "quick": {
        "speeds": [0.25, 0.3, 0.35, 0.4, 0.45, 0.5],
        "campaign": (10, 100),
        "diagnosis": DiagnosisSettings.quick(),
    },
    "full": {
        "speeds": list(np.linspace(0.25, 0.5, 12)),
        "campaign": (10, 100),
        "diagnosis": DiagnosisSettings(),
    },
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
# it. The effect's parameters stay with us, apart from the campaign.

# %%
effect = FrameMode.from_seed(0)
rig = VirtualRig(effects=Effects(frame_mode=effect))
speeds = size["speeds"]
campaign = rig.record(
    ["healthy"] * len(speeds),
    speeds,
    key=jax.random.key(4),
    split=["calibration"] * len(speeds),
)
print(f"{campaign.sizes['run']} runs at v_max {speeds} m/s")
print(f"hidden: a frame mode at {effect.frequency_hz:.2f} Hz, damping {effect.damping_ratio:.4f}")

# %% [markdown]
# ## The diagnosis
#
# `diagnose_campaign(door, campaign, fit=...)` works in three steps (`docs/diagnosis.md`):
#
# 1. **Residual features.** Posterior draws of the fit simulate every run at its speed over the
#    same record length, plus white noise at the level the records show at rest (the rig's
#    acquisition noise, which no simulator produces). Per run, channel and 1 Hz bin, the
#    measured log PSD is standardised against the draws and the Welch scatter, combined over
#    runs at fixed frequency and at fixed wavenumber (a tone from a spatial period moves with
#    the speed), and tested with Benjamini-Hochberg at a 1 % false discovery rate; the
#    coherence of each sensor's X and Z and the lines at rest are tested too. The band is the
#    fit's (4-96 Hz), and a smooth misfit of the spectrum's shape, which no catalogue cause
#    explains, is taken out first.
# 2. **Signatures.** Each candidate of the door's catalogue scores the features: a frame mode is
#    a peak at a fixed frequency in most runs, absent at rest before the motion; an eccentric
#    wheel gives tones at harmonics of the wheel rotation that track the speed; a rail
#    irregularity a tracking tone at another wavelength; a cross-axis sensor an excess coherence
#    between its axes; mains hum a line at 50 or 60 Hz that stays at rest.
# 3. **Refits.** Each plausible candidate's recipe extends the door model (here: an extra frame
#    mode), fits the extension's parameters on half the runs starting from the signature's
#    estimate and scores both models on the other half, both ways. A cause is confirmed by a
#    decisive held-out gain.
#
# The fit given is notebook 2's: the same door before the change, so the diagnosis asks what the
# new runs show that the known model does not. Without `fit=` it would fit the base model on
# this campaign first (CMA-ES).

# %%
fit_folder = ROOT / "02" / "fit"
if not (fit_folder / "fit.json").is_file():
    raise FileNotFoundError(
        f"no fit in {fit_folder}: run examples/02_model_updating.py first with the same "
        "BAYESDOOR_EXAMPLE_SIZE and BAYESDOOR_EXAMPLE_OUT"
    )
fit = FitResult.load(fit_folder)
door = ElevatorDoor()
diagnosis = diagnose_campaign(
    door, campaign, fit=fit, catalogue=DOOR_CATALOGUE, settings=size["diagnosis"], seed=0
)
print({stage: round(seconds, 1) for stage, seconds in diagnosis.timings.items()})

# %% [markdown]
# ## What the model does not explain
#
# The residual features, strongest first, and the combined residual over runs at fixed
# frequency (red: significant bins).

# %%
found = diagnosis.features.summary()
print(f"{len(found)} significant features; the first ten:")
for line in found[:10]:
    print(" ", line)

# %%
residuals = diagnosis.features.residuals
fig, axes = plt.subplots(len(residuals.channels), 1, figsize=(9, 7), sharex=True)
for c, ax in enumerate(axes):
    ax.plot(residuals.freqs, residuals.combined[c], lw=0.8)
    hits = residuals.significant[c]
    ax.plot(residuals.freqs[hits], residuals.combined[c][hits], "r.", ms=4)
    ax.axvline(effect.frequency_hz, color="k", ls=":", lw=0.8)
    ax.set_ylabel(residuals.channels[c])
axes[0].set_title("combined residual over runs (red: significant; dotted: the hidden mode)")
axes[-1].set_xlabel("frequency (Hz)")
fig.savefig(OUT / "residual_map.png", dpi=120)

# %% [markdown]
# ## Which cause?
#
# The signature ranking first (the share of each signature's checks its best feature passes),
# then the verdict of the refits.

# %%
print("signature verdict:", diagnosis.ranking.verdict)
for score in diagnosis.ranking.causes:
    print(f"{score.name:>20}: {score.score:.2f}  {score.feature}")
print()
print("verdict:", diagnosis.verdict)
print("rule:", diagnosis.rule)
for cause in diagnosis.causes:
    gain = "not refitted" if cause.gain is None else cause.gain.describe()
    print(f"{cause.name:>20}: confirmed {cause.confirmed}; {gain}")
for note in diagnosis.notes:
    print("note:", note)
top = diagnosis.causes[0]
print(f"\n{top.name}: {top.evidence}")
print("parameters:", dict(top.parameters))
print(f"hidden: {effect.frequency_hz:.2f} Hz, damping ratio {effect.damping_ratio:.4f}")

# %% [markdown]
# ## The reference: runs without the effect
#
# A verdict only means something if runs without any effect do not produce one. The healthy
# test runs of the demo campaign come from the same rig without effects; the same diagnosis,
# with the same fit, on as many of them (relabelled as the runs to diagnose):

# %%
n_calibration, n_test = size["campaign"]
demo = load_demo_campaign(calibration_runs=n_calibration, test_runs_per_state=n_test)
healthy = (demo.split.values == "test") & (demo.state.values == "healthy")
clean = demo.isel(run=np.flatnonzero(healthy)[: len(speeds)])
clean = clean.assign_coords(split=("run", ["calibration"] * clean.sizes["run"]))
reference = diagnose_campaign(
    door, clean, fit=fit, catalogue=DOOR_CATALOGUE, settings=size["diagnosis"], seed=0
)
print(f"{clean.sizes['run']} runs without the effect at v_max {clean.v_max.values.tolist()}")
print(f"{len(reference.features.summary())} significant features")
print("signature verdict:", reference.ranking.verdict, "  verdict:", reference.verdict)
for cause in reference.causes:
    gain = "not refitted" if cause.gain is None else cause.gain.describe()
    print(f"{cause.name:>20}: signature {cause.score:.2f}, confirmed {cause.confirmed}; {gain}")

# %% [markdown]
# Read the two together. A residual feature that also shows without the effect is a difference
# between the rig and the reduced model (the model is not the rig), not the hidden cause: the
# signatures alone may name it, and only the held-out gain of a refit tells a cause the data
# support from one they merely resemble. The rule is strict on purpose: with few runs the standard
# error of the held-out gain is large, and a real cause can show a clear signature and a positive
# gain yet fall short of the rule's thresholds (at 6 runs 4.5 standard errors, or 7.4 with the
# gains above the median capped; at 12 runs 4.2 or 5.2: `bayesdoor.diagnose.rule_thresholds`; at
# the `quick` size, 6 runs, that is what happened when this was written, under the plain 4
# standard errors of the rule then); more runs narrow it. At the `tiny` size (a poor fit, a short
# refit) neither verdict means much. How often the diagnosis names the right cause over many
# hidden effects, and stays at `none` without one, is what its own tests and benchmarks measure
# (`docs/diagnosis.md`, `results/diagnosis.md`).
