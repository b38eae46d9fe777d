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
# # 3. Training, calibration and a damage report
#
# The paper trains a CNN on simulated runs only and applies it to measured ones. bayesdoor
# keeps that idea and makes the training data honest about what the fit does not know: the
# simulated runs take their parameters from the posterior of notebook 2 instead of Gaussian
# scatter around one optimum. This notebook
#
# 1. simulates labelled training runs (healthy, D1, D2) with parameters drawn from the
#    posterior;
# 2. trains an ensemble of small CNNs, calibrates it with one temperature on held-out
#    simulations and checks the calibration with a reliability diagram;
# 3. classifies the rig's test runs (never used for anything else) with probabilities,
#    uncertainty and an out-of-distribution flag;
# 4. writes the HTML damage report.
#
# It starts from the fit saved by `02_model_updating.py`: run that first, with the same
# `BAYESDOOR_EXAMPLE_SIZE` (`tiny`, `quick` (default) or `full`) and `BAYESDOOR_EXAMPLE_OUT`.

# %%
import json
import os
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

from bayesdoor.classify import (
    TrainConfig,
    classification_metrics,
    fit_classifier,
    predict,
    reliability_bins,
    save_ensemble,
)
from bayesdoor.datagen import (
    GenerationConfig,
    PosteriorDraws,
    campaign_features,
    fit_adequacy,
    generate,
    load_training_data,
    measurement_variance,
    with_measured_discrepancy,
)
from bayesdoor.door import ElevatorDoor
from bayesdoor.door.datasets import load_demo_campaign
from bayesdoor.features import CNNInputSpec
from bayesdoor.inference import FitResult, calibration_runs
from bayesdoor.pipeline import PredictiveBands, classify_stage, report_stage

SIZE = os.environ.get("BAYESDOOR_EXAMPLE_SIZE", "quick")
SIZES = {
    # demo campaign size, simulated runs per state, ensemble training
    "tiny": {
        "campaign": (3, 2),
        "runs_per_state": 30,
        "train": TrainConfig(members=3, epochs=10, batch_size=32),
    },
    "quick": {"campaign": (10, 100), "runs_per_state": 100, "train": TrainConfig()},
    "full": {"campaign": (10, 100), "runs_per_state": 600, "train": TrainConfig()},
}
if SIZE not in SIZES:
    raise ValueError(f"BAYESDOOR_EXAMPLE_SIZE={SIZE!r}: use one of {', '.join(SIZES)}")
size = SIZES[SIZE]
ROOT = Path(os.environ.get("BAYESDOOR_EXAMPLE_OUT", "out/examples"))
OUT = ROOT / "03"
OUT.mkdir(parents=True, exist_ok=True)

# %% [markdown]
# ## The posterior and the campaign
#
# `FitResult.load` reads the fit notebook 2 saved (its posterior is an ArviZ NetCDF file).

# %%
fit_folder = ROOT / "02" / "fit"
if not (fit_folder / "fit.json").is_file():
    raise FileNotFoundError(
        f"no fit in {fit_folder}: run examples/02_model_updating.py first with the same "
        "BAYESDOOR_EXAMPLE_SIZE and BAYESDOOR_EXAMPLE_OUT"
    )
fit = FitResult.load(fit_folder)
door = ElevatorDoor()
n_calibration, n_test = size["campaign"]
campaign = load_demo_campaign(calibration_runs=n_calibration, test_runs_per_state=n_test)
test = campaign.isel(run=np.flatnonzero(campaign.split.values == "test"))
print(
    f"fit: {fit.method}, law {fit.held['I']:g}, J {fit.j:.3f}; "
    f"gates passed: {fit.diagnostics.passed}"
)
states, counts = np.unique(test.state.values, return_counts=True)
print(f"{test.sizes['run']} test runs:", dict(zip(states.tolist(), counts.tolist(), strict=True)))

# %% [markdown]
# ## Training data from the posterior, carrying the model's error
#
# Each simulated run takes one posterior sample for all continuous parameters together (so
# their correlations survive), the contact law the posterior was conditioned on, a damage
# severity drawn from its state's range and a speed from the campaign's. Its features are the
# classifier's input, as the door declares it (`door.features`): log10 Welch PSD in 4 Hz bins
# from 0 to 96 Hz, per channel, over the motion window (4 x 25 numbers). The generation is
# chunked and resumable: running this cell again loads the finished chunks instead of
# simulating them.
#
# Then every simulated run gets the discrepancy one healthy calibration run measures at its
# speed (`with_measured_discrepancy`): what the model misses on this machine, as measured.
# This is the main job's default source (`posterior+model_error`, docs/transfer.md).

# %%
fixed = {name: value for name, value in fit.point.items() if name not in fit.names}
source = PosteriorDraws.from_inference_data(fit.idata, fit.names, fixed=fixed)
spec = CNNInputSpec(fmax=door.features.classifier_fmax, nperseg=door.features.classifier_nperseg)
config = GenerationConfig(
    speeds=tuple(float(v) for v in np.unique(campaign.v_max.values)),
    runs_per_state=size["runs_per_state"],
    chunk_size=min(100, size["runs_per_state"]),
    spec=spec,
)
data = generate(door, source, config, OUT / "training", key=jax.random.key(0))
calibration = campaign.isel(run=calibration_runs(campaign))
cal_features = campaign_features(calibration, spec=spec)
cal_speeds = calibration.v_max.values
data = with_measured_discrepancy(data, cal_features, cal_speeds, seed=0)
train, validation = data.subset("train"), data.subset("validation")
print(f"{len(train.labels)} training and {len(validation.labels)} validation runs of {data.states}")

# %% [markdown]
# Do these simulations reproduce the measured healthy runs? The adequacy check holds each
# calibration run against the simulations with the *other* runs' discrepancy (leave one run
# out), per channel and band; the model alone is checked too.

# %%
raw = load_training_data(OUT / "training")
variance = measurement_variance(raw)
alone = fit_adequacy(raw, cal_features, cal_speeds, variance)
held_out = fit_adequacy(raw, cal_features, cal_speeds, variance, discrepancy=True)
print("the model alone:", alone.summary())
print("with the measured discrepancy:", held_out.summary())

# %%
fig, axes = plt.subplots(1, len(data.channels), figsize=(12, 3.2), sharey=True)
for label, state in enumerate(data.states):
    mean = train.features[train.labels == label].mean(axis=0)
    for c, ax in enumerate(axes):
        ax.plot(data.frequencies, mean[c], label=state)
for ax, channel in zip(axes, data.channels, strict=True):
    ax.set_title(channel)
    ax.set_xlabel("frequency (Hz)")
axes[0].set_ylabel("mean log10 PSD")
axes[0].legend()
fig.suptitle("the simulated training runs, mean per state")
fig.savefig(OUT / "training_means.png", dpi=120)

# %% [markdown]
# ## The ensemble and its temperature
#
# `fit_classifier` trains an ensemble of the paper's small 1-D CNN (one convolution along the
# frequency axis, max-pooling, a dense layer: 233 weights) with different initialisations and
# data orders, then fits on the validation runs, which the weights never saw,
#
# - one temperature `T` for the log of the members' mean probabilities (the predicted class
#   cannot change, only the confidence), and
# - the threshold of a Mahalanobis out-of-distribution score (the 99th percentile on
#   validation).

# %%
training = fit_classifier(
    jnp.asarray(train.features),
    jnp.asarray(train.labels),
    jnp.asarray(validation.features),
    jnp.asarray(validation.labels),
    data.states,
    key=jax.random.key(1),
    config=size["train"],
)
ensemble = training.ensemble
print(f"temperature T = {float(ensemble.temperature):.3f}")
print(f"OOD threshold = {float(ensemble.ood.threshold):.2f}")

# %% [markdown]
# A reliability diagram shows whether a confidence of 0.8 is right 80 % of the time. On the
# validation runs the expected calibration error (ECE, 15 equal-width bins) before and after
# the temperature:

# %%
uncalibrated = eqx.tree_at(lambda e: e.temperature, ensemble, jnp.ones_like(ensemble.temperature))
p_raw = np.asarray(predict(uncalibrated, jnp.asarray(validation.features)).probabilities)
p_cal = np.asarray(predict(ensemble, jnp.asarray(validation.features)).probabilities)
fig, ax = plt.subplots(figsize=(5, 5))
for name, p in (("uncalibrated (T = 1)", p_raw), ("calibrated", p_cal)):
    metrics = classification_metrics(p, validation.labels)
    bins = reliability_bins(p, validation.labels)
    filled = bins.counts > 0
    ax.plot(
        bins.confidence[filled],
        bins.accuracy[filled],
        "o-",
        label=f"{name}, ECE {metrics['ece']:.3f}",
    )
    print(f"{name}: accuracy {metrics['accuracy']:.3f}, ECE {metrics['ece']:.3f}")
ax.plot([0, 1], [0, 1], "k--", lw=0.8)
ax.set_xlabel("confidence")
ax.set_ylabel("accuracy")
ax.legend(fontsize=8)
ax.set_title("simulated validation runs")
fig.savefig(OUT / "reliability.png", dpi=120)

# %% [markdown]
# ## The rig's test runs
#
# Now the measured-like runs: features over each run's motion window, the same function as for
# the simulations. For each run the ensemble gives calibrated class probabilities, the total
# uncertainty (entropy), the members' disagreement (mutual information) and the OOD flag.

# %%
x_test = campaign_features(test, spec=spec)
labels = np.array([data.states.index(s) for s in test.state.values])
prediction = predict(ensemble, jnp.asarray(x_test))
metrics = classification_metrics(np.asarray(prediction.probabilities), labels)
print(f"accuracy {metrics['accuracy']:.1%}, ECE {metrics['ece']:.3f}, NLL {metrics['nll']:.3f}")
print("confusion (rows: true, columns: predicted", data.states, ")")
print(np.asarray(metrics["confusion"]))
print(f"flagged out of distribution: {int(np.sum(prediction.ood))} of {len(labels)}")

# %%
fig, ax = plt.subplots(figsize=(6, 4))
for label, state in enumerate(data.states):
    mine = labels == label
    ax.scatter(
        np.asarray(prediction.entropy)[mine],
        np.asarray(prediction.mutual_information)[mine],
        s=10,
        label=state,
    )
ax.set_xlabel("predictive entropy (nats)")
ax.set_ylabel("mutual information (nats)")
ax.legend()
ax.set_title("uncertainty of each test run")
fig.savefig(OUT / "uncertainty.png", dpi=120)

# %% [markdown]
# The OOD score compares a measured run with the *simulated* training distribution. Where the
# reduced model misses something the rig has (its panel bending mode shows on A1X), measured
# runs sit outside that distribution even when the classifier is right, and the flag says so:
# the answer is an extrapolation. `results/classification.md` discusses this on the full demo
# campaign; notebook 4 asks what the model misses.
#
# ## The damage report
#
# The pipeline's stage functions write the same report as `bayesdoor run`: save the ensemble
# with the posterior-predictive bands of the features, classify the campaign, render the HTML.

# %%
model = OUT / "model"
model.mkdir(exist_ok=True)
save_ensemble(model / "ensemble.eqx", ensemble, overwrite=True)
PredictiveBands.from_training_data(data).save(model / "bands.npz")
classify_stage(model, test, OUT / "classify")
report_stage(OUT / "classify", model, OUT / "report", title="Demo campaign (notebook 3)")
summary = json.loads((OUT / "classify" / "classification.json").read_text())
print("runs classified:", summary["n_runs"], " OOD:", summary["n_ood"])
print("open", (OUT / "report" / "index.html").resolve())
