"""Training-data generation: sources, featurizer, chunks, resumption, Dask, the door end to end.

Most tests use a small analytic system (tones whose frequencies and amplitudes follow the
parameters, damage and speed) so that they exercise the generic layer in seconds; the door is
used where the real simulator matters (the featurizer on door runs, a small and a
realistic-size generation).
"""

from __future__ import annotations

import json
import time
import warnings

import arviz as az
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal
from _toy_system import CENTER, FS, ToySystem

from bayesdoor.datagen import (
    Execution,
    GaussianScatter,
    GenerationConfig,
    ModelErrorDraws,
    PosteriorDraws,
    calibration_residuals,
    campaign_features,
    featurize,
    generate,
    load_training_data,
    measured_features,
    measurement_variance,
    model_error_draws,
)
from bayesdoor.door import ElevatorDoor
from bayesdoor.features import MotionDetection, segment_weights
from bayesdoor.inference import FeatureSpec, welch_log10_variance
from bayesdoor.io import make_campaign

TOY = ToySystem()


def toy_source(relative_sd=0.1):
    return GaussianScatter.around(TOY, CENTER, relative_sd)


def toy_config(**kw):
    settings = dict(runs_per_state=5, chunk_size=2, validation_fraction=0.4)
    settings.update(kw)
    return GenerationConfig([0.3, 0.5], **settings)


def assert_same_data(a, b):
    for name in ("features", "labels", "validation", "speeds", "run_ids", "model_error"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    for group in ("parameters", "severities"):
        x, y = getattr(a, group), getattr(b, group)
        assert set(x) == set(y)
        for k in x:
            np.testing.assert_array_equal(x[k], y[k], err_msg=f"{group}/{k}")
    np.testing.assert_array_equal(a.dropped_run_ids, b.dropped_run_ids)


# ---------------------------------------------------------------------------------- sources


def test_gaussian_scatter_statistics(key):
    # wide bounds so that clipping does not bias the moments
    src = GaussianScatter(
        {"a": 10.0, "b": -2.0, "c": 3.0},
        {"a": 0.01, "b": 0.10, "c": 0.0},
        {"a": (0.0, 20.0), "b": (-4.0, 0.0), "c": (1.0, 5.0)},
    )
    n = 20_000
    draws = src.sample(n, key=key)
    for name, center, rel in (("a", 10.0, 0.01), ("b", -2.0, 0.10)):
        x = np.asarray(draws[name])
        sd = rel * abs(center)
        # 4 standard errors: sd / sqrt(n) for the mean, sd / sqrt(2 n) for the sd (Gaussian)
        assert abs(x.mean() - center) < 4 * sd / np.sqrt(n)
        assert abs(x.std(ddof=1) / abs(center) - rel) < 4 * rel / np.sqrt(2 * n)
    np.testing.assert_array_equal(draws["c"], 3.0)
    # independent streams: the correlation of a and b is within sampling error of zero
    assert abs(np.corrcoef(draws["a"], draws["b"])[0, 1]) < 4 / np.sqrt(n)


def test_gaussian_scatter_clips_to_bounds_and_holds_integers(key):
    door = ElevatorDoor()
    optimum = {p.name: p.reference_value for p in door.parameters}
    draws = GaussianScatter.around(door, optimum, 0.10).sample(5000, key=key)
    for p in door.parameters:
        x = np.asarray(draws[p.name])
        assert x.min() >= p.lower and x.max() <= p.upper, p.name
    np.testing.assert_array_equal(draws["I"], 6.0)
    # n = 1.93 lies 2.8 sd below its upper bound 2.2: some draws are clipped onto it
    assert np.any(np.asarray(draws["n"]) == 2.2)
    with pytest.raises(ValueError, match="missing"):
        GaussianScatter.around(door, {"K": 1863.0})
    with pytest.raises(ValueError, match="relative_sd"):
        GaussianScatter({"a": 1.0}, {"a": 1.5}, {"a": (0.0, 2.0)})


def _posterior(key, chains=2, draws=50):
    k1, k2 = jax.random.split(key)
    k = np.asarray(jax.random.uniform(k1, (chains, draws)))
    m = 0.5 + np.asarray(jax.random.uniform(k2, (chains, draws)))
    sigma = 0.1 + 0.05 * k[..., None] * np.ones(2)
    return az.from_dict(posterior={"k": k, "m": m, "sigma_model": sigma})


def test_posterior_draws_only_posterior_values(key):
    idata = _posterior(key)
    src = PosteriorDraws.from_inference_data(idata, ["k", "m"], fixed={"law": 3})
    assert src.n_samples == 100 and set(src.names) == {"k", "m", "law"}
    draws = src.sample(1000, key=jax.random.fold_in(key, 1))
    pairs = set(
        zip(idata.posterior["k"].values.ravel(), idata.posterior["m"].values.ravel(), strict=True)
    )
    drawn = set(zip(np.asarray(draws["k"]), np.asarray(draws["m"]), strict=True))
    # every draw is one posterior sample, jointly (k with its own m), not a recombination
    assert drawn <= pairs
    # with replacement, 1000 draws from 100 samples hit nearly all of them
    assert len(drawn) > 90
    np.testing.assert_array_equal(draws["law"], 3.0)
    with pytest.raises(ValueError, match="no variable 'q'"):
        PosteriorDraws.from_inference_data(idata, ["q"])
    with pytest.raises(ValueError, match="not a scalar"):
        PosteriorDraws.from_inference_data(idata, ["sigma_model"])
    with pytest.raises(ValueError, match="both sampled and fixed"):
        PosteriorDraws({"k": [0.1]}, fixed={"k": 0.2})


def test_model_error_draws(key):
    sigma = np.array([[0.1, 0.3]])  # one posterior sample, one scale per channel
    err = ModelErrorDraws(jnp.asarray(sigma))
    n = 20_000
    offsets = np.asarray(err.sample(n, 2, 5, key=key))
    assert offsets.shape == (n, 2, 5)
    # one offset per channel, shared by its frequency bins
    np.testing.assert_array_equal(offsets, offsets[..., :1].repeat(5, axis=-1))
    # sd of a Gaussian sample: standard error sd / sqrt(2 n), 4 of them
    np.testing.assert_allclose(
        offsets[:, :, 0].std(axis=0), [0.1, 0.3], atol=4 * 0.3 / np.sqrt(2 * n)
    )
    per_bin = ModelErrorDraws(jnp.asarray(sigma), per_bin=True).sample(4, 2, 5, key=key)
    assert np.all(np.std(np.asarray(per_bin), axis=-1) > 0)
    from_idata = ModelErrorDraws.from_inference_data(_posterior(key))
    assert from_idata.sigma.shape == (100, 2)
    with pytest.raises(ValueError, match="does not fit"):
        err.sample(3, 4, 5, key=key)


# ------------------------------------------------------------------------------- featurizer


def test_featurize_matches_scipy_welch_over_the_window():
    # independent reference: scipy.signal.welch on the samples of the window only
    rng = np.random.default_rng(0)
    x = rng.standard_normal((2, 3, 4096))
    t_start = np.array([0.25, 0.5])
    t_stop = np.array([1.5, 1.99])
    got = np.asarray(featurize(x, FS, t_start, t_stop))
    assert got.shape == (2, 3, 25)
    for i in range(2):
        first = int(np.ceil(t_start[i] * FS))
        last = int(np.floor(t_stop[i] * FS))
        # the featurizer keeps whole 512-sample segments on the 256-sample grid of the record
        a = -(-first // 256) * 256
        n_seg = (last + 1 - a - 256) // 256
        seg = x[i, :, a : a + 256 * (n_seg + 1)]
        _, psd = scipy.signal.welch(seg, FS, nperseg=512)
        # float64 FFT round-off only
        np.testing.assert_allclose(got[i], np.log10(psd[:, :25]), rtol=1e-10)


def test_measured_features_use_given_or_detected_window():
    speeds = np.array([0.3, 0.5])
    signals = np.asarray(TOY.simulate_values(TOY.nominal(), speeds, state="D1").signals)
    t = np.arange(signals.shape[-1]) / FS
    start, stop = TOY.motion_window(speeds)
    given = measured_features(t, signals, FS, start, stop)
    np.testing.assert_array_equal(given, featurize(signals, FS, start, stop))
    # the toy's motion starts abruptly at REST = 0.1 s and lasts to the end: the envelope
    # finds it within one 20 ms RMS window, before the first whole segment at 0.125 s
    detected = measured_features(t, signals, FS, detection=MotionDetection(rest_duration=0.08))
    np.testing.assert_array_equal(detected, given)
    half = measured_features(
        t,
        signals,
        FS,
        t_start=np.array([np.nan, 0.25]),
        detection=MotionDetection(rest_duration=0.08),
    )
    np.testing.assert_array_equal(half[0], given[0])
    assert not np.array_equal(half[1], given[1])
    campaign = make_campaign(
        signals,
        channels=TOY.channels,
        fs=FS,
        state=["D1", "D1"],
        v_max=speeds,
        t_start=[np.nan, 0.25],
        t_stop=stop,
        system="toy",
    )
    np.testing.assert_array_equal(
        campaign_features(campaign, detection=MotionDetection(rest_duration=0.08)), half
    )
    with pytest.raises(ValueError, match="sampling_rate_hz"):
        campaign_features(campaign.drop_attrs())


# ------------------------------------------------------------------------------- generation


def test_reproducible_and_seed_dependent(tmp_path, key):
    a = generate(TOY, toy_source(), toy_config(), tmp_path / "a", key=key, progress=False)
    # one chunk after the other, or three at a time finishing in any order: the same data
    for threads in (1, 3):
        b = generate(
            TOY,
            toy_source(),
            toy_config(),
            tmp_path / f"b{threads}",
            key=key,
            progress=False,
            execution=Execution(threads=threads),
        )
        assert_same_data(a, b)
        summary = json.loads((tmp_path / f"b{threads}" / "summary.json").read_text())
        assert summary["threads"] == threads
    with pytest.raises(ValueError, match="threads must be at least 1"):
        generate(
            TOY, toy_source(), toy_config(), tmp_path / "t", key=key, execution=Execution(threads=0)
        )
    c = generate(
        TOY, toy_source(), toy_config(), tmp_path / "c", key=jax.random.key(7), progress=False
    )
    assert not np.array_equal(a.features, c.features)
    assert not np.array_equal(a.parameters["k"], c.parameters["k"])
    assert a.features.shape == (15, 2, 25) and np.all(np.isfinite(a.features))
    manifest = json.loads((tmp_path / "a" / "manifest.json").read_text())
    assert manifest["source"]["kind"] == "GaussianScatter"
    assert {"jax", "diffrax", "numpy"} <= set(manifest["versions"])
    assert manifest["key"]["data"] == np.asarray(jax.random.key_data(key)).tolist()


def test_resume_equals_uninterrupted(tmp_path, key):
    whole = generate(TOY, toy_source(), toy_config(), tmp_path / "whole", key=key, progress=False)
    done = []

    def interrupt(index):
        done.append(index)
        if len(done) == 3:
            raise KeyboardInterrupt

    # two threads: the chunk still running when the interrupt comes is not saved
    with pytest.raises(KeyboardInterrupt):
        generate(
            TOY,
            toy_source(),
            toy_config(),
            tmp_path / "r",
            key=key,
            progress=False,
            execution=Execution(threads=2, on_chunk=interrupt),
        )
    assert len(list((tmp_path / "r" / "chunks").glob("*.npz"))) == 3
    with pytest.raises(ValueError, match="interrupted"):
        load_training_data(tmp_path / "r")
    resumed = generate(TOY, toy_source(), toy_config(), tmp_path / "r", key=key, progress=False)
    assert_same_data(resumed, whole)
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["chunks_computed"] == 9 - 3
    # a finished folder is only reloaded, even with a Dask scheduler named
    again = generate(
        TOY,
        toy_source(),
        toy_config(),
        tmp_path / "r",
        key=key,
        progress=False,
        execution=Execution(scheduler="local"),
    )
    assert_same_data(again, whole)
    assert json.loads((tmp_path / "r" / "summary.json").read_text())["chunks_computed"] == 0


def test_config_change_refused_on_resume(tmp_path, key):
    def stop(index):
        raise KeyboardInterrupt

    out = tmp_path / "g"
    with pytest.raises(KeyboardInterrupt):
        generate(
            TOY,
            toy_source(),
            toy_config(),
            out,
            key=key,
            progress=False,
            execution=Execution(on_chunk=stop),
        )
    before = sorted(p.name for p in (out / "chunks").iterdir())
    for source, config, k in (
        (toy_source(0.05), toy_config(), key),
        (toy_source(), toy_config(runs_per_state=6), key),
        (toy_source(), toy_config(), jax.random.key(1)),
    ):
        with pytest.raises(ValueError, match="different configuration"):
            generate(TOY, source, config, out, key=k, progress=False)
    assert sorted(p.name for p in (out / "chunks").iterdir()) == before


def test_class_balance_split_and_severity_priors(tmp_path, key):
    config = toy_config(runs_per_state=10, chunk_size=4, validation_fraction=0.3)
    data = generate(TOY, toy_source(), config, tmp_path, key=key, progress=False)
    assert data.states == ("healthy", "D1", "D2")
    assert data.counts() == {s: {"train": 7, "validation": 3} for s in data.states}
    np.testing.assert_array_equal(data.run_ids, np.arange(30))
    train, val = data.subset("train"), data.subset("validation")
    assert train.labels.size == 21 and val.labels.size == 9
    assert set(data.speeds) <= {0.3, 0.5}
    for i, state in enumerate(data.states):
        runs = data.labels == i
        for name, values in data.severities.items():
            prior = TOY.states[state].severity.get(name)
            if prior is None:
                assert np.all(np.isnan(values[runs])), (state, name)
            else:
                assert np.all((values[runs] >= prior[0]) & (values[runs] <= prior[1]))
    # the severities enter the simulation: D1's 48 Hz bin (index 12) stands above healthy's
    assert (
        data.features[data.labels == 1, 0, 12].min() > data.features[data.labels == 0, 0, 12].max()
    )


def test_failed_solves_are_redrawn_or_dropped(tmp_path, key):
    # k ~ N(0.5, 0.1 * 0.5): 16 % of draws exceed 0.55 and fail, so 40 runs hold some
    failing = ToySystem(fail_above=0.55)
    config = toy_config(runs_per_state=40, chunk_size=40, states=("healthy",))
    data = generate(failing, toy_source(), config, tmp_path / "redraw", key=key, progress=False)
    assert data.labels.size == 40 and data.dropped_run_ids.size == 0
    assert data.redraws.max() > 0 and data.parameters["k"].max() <= 0.55
    with pytest.warns(UserWarning, match="dropped after failed solves"):
        dropped = generate(
            failing,
            toy_source(),
            toy_config(runs_per_state=40, chunk_size=40, states=("healthy",), on_failure="drop"),
            tmp_path / "drop",
            key=key,
            progress=False,
        )
    assert dropped.dropped_run_ids.size > 0
    assert dropped.labels.size + dropped.dropped_run_ids.size == 40
    assert dropped.parameters["k"].max() <= 0.55
    summary = json.loads((tmp_path / "drop" / "summary.json").read_text())
    assert summary["dropped_run_ids"] == dropped.dropped_run_ids.tolist()


def test_bad_inputs_name_the_problem(tmp_path, key):
    with pytest.raises(ValueError, match="missing \\['m'\\]"):
        generate(
            TOY,
            GaussianScatter(
                {"k": 0.5, "law": 2}, {"k": 0.1, "law": 0}, {"k": (0, 1), "law": (1, 3)}
            ),
            toy_config(),
            tmp_path / "x",
            key=key,
        )
    with pytest.raises(ValueError, match="unknown state 'D9'"):
        generate(TOY, toy_source(), toy_config(states=("D9",)), tmp_path / "y", key=key)
    outside = PosteriorDraws({"k": [1.5, 1.5], "m": [1.0, 1.0]}, fixed={"law": 2})
    with pytest.raises(ValueError, match=r"drew k=1\.5"):
        generate(TOY, outside, toy_config(), tmp_path / "z", key=key, progress=False)
    (tmp_path / "w").mkdir()
    (tmp_path / "w" / "other.txt").write_text("not ours")
    with pytest.raises(ValueError, match="no manifest"):
        generate(TOY, toy_source(), toy_config(), tmp_path / "w", key=key)


def test_model_error_offsets_are_added(tmp_path, key):
    err = ModelErrorDraws(jnp.asarray([[0.2, 0.4]]))
    plain = generate(TOY, toy_source(), toy_config(), tmp_path / "p", key=key, progress=False)
    # this one also runs the progress bar (the other tests switch it off)
    noisy = generate(
        TOY, toy_source(), toy_config(), tmp_path / "n", key=key, model_error=err, progress=True
    )
    # (features + offset) - offset rounds in the last bit of a value of order 10
    np.testing.assert_allclose(noisy.features - noisy.model_error, plain.features, atol=1e-13)
    # one offset per channel and run (per_bin=False): constant along frequency up to round-off
    assert noisy.model_error.std(axis=-1).max() < 1e-15 and noisy.model_error.std() > 0.1


# 16 s (a local Dask cluster starts): in the long tier, to keep the default suite within
# its 10 minutes
@pytest.mark.long
def test_dask_local_cluster_equals_local(tmp_path, key, monkeypatch):
    # the worker processes inherit the environment: let them share the tests' JAX cache
    cache = jax.config.jax_compilation_cache_dir
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", cache)
    monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
    local = generate(TOY, toy_source(), toy_config(), tmp_path / "l", key=key, progress=False)
    dask = generate(
        TOY,
        toy_source(),
        toy_config(),
        tmp_path / "d",
        key=key,
        progress=False,
        execution=Execution(scheduler="local"),
    )
    assert_same_data(dask, local)
    assert dask.features.dtype == np.float64


@pytest.mark.slow
def test_dask_scheduler_address_equals_local(tmp_path, key, monkeypatch):
    from distributed import LocalCluster

    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", jax.config.jax_compilation_cache_dir)
    local = generate(TOY, toy_source(), toy_config(), tmp_path / "l", key=key, progress=False)
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster:
        remote = generate(
            TOY,
            toy_source(),
            toy_config(),
            tmp_path / "d",
            key=key,
            progress=False,
            execution=Execution(scheduler=cluster.scheduler_address),
        )
    assert cluster.scheduler_address.startswith("tcp://")
    assert_same_data(remote, local)


# --------------------------------------------------------------------------------- the door


# ------------------------------------------------------- model error for the OOD detector


@pytest.fixture(scope="module")
def toy_data(tmp_path_factory):
    config = toy_config(runs_per_state=12, chunk_size=12, validation_fraction=0.25)
    out = tmp_path_factory.mktemp("toy_data")
    return generate(TOY, toy_source(), config, out, key=jax.random.key(11), progress=False)


def test_calibration_residuals_subtract_the_simulated_mean_at_the_speed(toy_data):
    measured = toy_data.features[:3] + 0.5  # three runs, offset by half a decade
    speeds = [0.5, 0.3, 0.5]
    got = calibration_residuals(toy_data, measured, speeds, state="D1")
    for i, v in enumerate(speeds):
        same = [
            j
            for j in range(toy_data.labels.size)
            if toy_data.labels[j] == 1 and toy_data.speeds[j] == v and not toy_data.validation[j]
        ]
        expected = measured[i] - np.mean([toy_data.features[j] for j in same], axis=0)
        np.testing.assert_allclose(got[i], expected, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match=r"speed 0\.4 but the training split holds no D1 run"):
        calibration_residuals(toy_data, measured, [0.5, 0.4, 0.5], state="D1")
    with pytest.raises(ValueError, match="state='D9'"):
        calibration_residuals(toy_data, measured, speeds, state="D9")
    with pytest.raises(ValueError, match=r"features must be \(run, 2, 25\)"):
        calibration_residuals(toy_data, measured[:, :1], speeds, state="D1")


def test_measurement_variance_is_the_welch_scatter_plus_the_model_error(toy_data):
    welch = measurement_variance(toy_data)
    # the segments inside the toy's window (0.1 to 0.75 s), counted by the featurizer's own
    # weights: 4 whole segments of 512 samples at 256-sample steps
    n_time = round(0.75 * FS)
    segments = float(np.sum(segment_weights(n_time, FS, 0.1, 0.75, 512)))
    assert segments == 4.0
    bin_hz = FS / 512
    one_bin = FeatureSpec(f_low=bin_hz, f_high=bin_hz, band_width=bin_hz)
    np.testing.assert_allclose(welch, float(welch_log10_variance(segments, FS, one_bin)))
    # an independent check of that value: the scatter of the log10 PSD of white noise over
    # the same window, 4000 records, bins away from 0 Hz (whose periodogram has half the
    # degrees of freedom); 4000 x 23 correlated bins estimate the variance to a few percent,
    # and the chi-square approximation of overlapped Hann segments is good to about 10 %
    noise = np.random.default_rng(0).standard_normal((4000, 1, n_time))
    features = np.asarray(featurize(noise, FS, 0.1, 0.75))
    scatter = np.var(features[:, 0, 1:24], axis=0).mean()
    assert scatter == pytest.approx(welch[0, 0], rel=0.15)
    # the model error adds its posterior mean of sigma^2, per channel
    sigma = np.array([[0.1, 0.3], [0.3, 0.1]])
    np.testing.assert_allclose(
        measurement_variance(toy_data, sigma) - welch, np.full((2, 25), 0.05), rtol=1e-12
    )
    np.testing.assert_allclose(measurement_variance(toy_data, np.array([0.2, 0.2])) - welch, 0.04)
    with pytest.raises(ValueError, match="does not fit features of shape"):
        measurement_variance(toy_data, np.ones((5, 3)))


def test_model_error_draws_have_the_residuals_plus_the_scatter(key):
    rng = np.random.default_rng(1)
    residuals = rng.normal(0.3, 0.2, (5, 2, 3))
    variance = np.array([[0.01, 0.04, 0.09], [0.0, 0.01, 0.25]])
    draws = model_error_draws(40_000, key=key, residuals=residuals, variance=variance)
    # a uniform mixture of the residuals plus independent Gaussian scatter: its mean is the
    # residuals' mean and its variance theirs (ddof 0) plus the scatter's; 40 000 draws give
    # standard errors below 0.005
    np.testing.assert_allclose(draws.mean(axis=0), residuals.mean(axis=0), atol=0.01)
    np.testing.assert_allclose(draws.var(axis=0), residuals.var(axis=0) + variance, atol=0.01)
    only = model_error_draws(50, key=key, residuals=residuals)
    assert all(any(np.array_equal(d, r) for r in residuals) for d in only)
    again = model_error_draws(40_000, key=key, residuals=residuals, variance=variance)
    np.testing.assert_array_equal(draws, again)
    with pytest.raises(ValueError, match="give residuals, variance or both"):
        model_error_draws(3, key=key)
    with pytest.raises(ValueError, match="describe other features"):
        model_error_draws(3, key=key, residuals=residuals, variance=np.ones((2, 4)))
    with pytest.raises(ValueError, match="non-negative"):
        model_error_draws(3, key=key, variance=-variance)


def test_simulated_duration_ends_just_after_the_latest_motion_stop():
    door = ElevatorDoor()

    def simulated(speeds, duration=None):
        return GenerationConfig(speeds, duration=duration).simulated_duration(door)

    fs = door.sampling_rate_hz
    _, (stop,) = door.motion_window([0.3])
    samples = round(simulated([0.3, 0.5]) * fs)
    # the last sample a Welch segment inside the window can use, plus one spare
    assert samples == int(np.floor(stop * fs)) + 2
    assert samples < round(GenerationConfig([0.3, 0.5]).record_duration(door) * fs)
    # the latest stop of the speeds counts, not the first or the fastest one
    assert simulated([0.5, 0.3]) == simulated([0.3, 0.5]) > simulated([0.5])
    # a record that ends before the motion stops is simulated whole
    assert simulated([0.3], duration=1.0) == 1.0
    assert GenerationConfig([0.3], duration=1.0).record_duration(door) == 1.0


# the door's training data end to end, 16-48 s with an empty JAX cache on a 2-core machine (the
# higher figures with other work beside it; most of it compiling the batched solves of its
# chunks): in the long tier, which CI runs after the default suite; the generator itself is
# tested on the toy system above
@pytest.mark.long
def test_door_generation_small(tmp_path, key):
    door = ElevatorDoor()
    optimum = {p.name: p.reference_value for p in door.parameters}
    # 2.7 s records: the stroke at 0.5 m/s stops at 2.575 s, so the solve is cut there
    config = GenerationConfig([0.5], runs_per_state=2, chunk_size=2, duration=2.7)
    data = generate(
        door, GaussianScatter.around(door, optimum), config, tmp_path, key=key, progress=False
    )
    np.testing.assert_allclose(data.t_stop, door.motion_window([0.5])[1][0])
    assert data.features.shape == (6, 4, 25) and np.all(np.isfinite(data.features))
    assert data.channels == door.channels
    np.testing.assert_allclose(data.frequencies, np.arange(25) * 4.0)
    for i, state in enumerate(data.states):
        for name, (lo, hi) in door.states[state].severity.items():
            values = data.severities[name][data.labels == i]
            assert np.all((values >= lo) & (values <= hi)), (state, name)
    # the features are those of the stored draws: simulate the two D2 runs again from them
    d2 = data.labels == 2
    assert np.all(np.isnan(data.severities["d1_height"][d2]))
    values = {k: v[d2] for k, v in data.parameters.items()}
    severity = {k: data.severities[k][d2] for k in ("d2_depth", "d2_angle")}
    res = door.simulate_values(values, data.speeds[d2], state="D2", severity=severity, duration=2.7)
    again = featurize(res.signals, FS, data.t_start[d2], data.t_stop[d2])
    # the whole 2.7 s record against the cut one. The adaptive steps are the same up to the
    # cut, but the two record lengths are two compiled programs, and round-off can move the
    # steps: 1e-6 to 1e-5 decades measured between batch sizes. A cut that lost samples of
    # the last Welch segment would change the features by the scatter of that segment's
    # periodogram (0.1 decades and more).
    np.testing.assert_allclose(again, data.features[d2], rtol=0, atol=1e-4)


@pytest.mark.slow
def test_door_dask_equals_local(tmp_path, key):
    # the adaptive door solve in worker processes: any round-off difference would change steps
    door = ElevatorDoor()
    optimum = {p.name: p.reference_value for p in door.parameters}
    config = GenerationConfig([0.3, 0.5], runs_per_state=2, chunk_size=2, duration=1.0)
    runs = [
        generate(
            door,
            GaussianScatter.around(door, optimum),
            config,
            tmp_path / str(scheduler),
            key=key,
            progress=False,
            execution=Execution(scheduler=scheduler),
        )
        for scheduler in (None, "local")
    ]
    assert_same_data(*runs)


@pytest.mark.slow
def test_door_generation_realistic_size(tmp_path, key):
    door = ElevatorDoor()
    optimum = {p.name: p.reference_value for p in door.parameters}
    config = GenerationConfig([0.25, 0.3, 0.35, 0.4, 0.45, 0.5], runs_per_state=100)
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        data = generate(
            door, GaussianScatter.around(door, optimum), config, tmp_path, key=key, progress=False
        )
    seconds = time.perf_counter() - start
    chunks = json.loads((tmp_path / "summary.json").read_text())["chunk_seconds"]
    steady = sum(chunks[1:]) / (300 - config.chunk_size)
    print(
        f"\n300 door runs: {seconds:.1f} s in all ({seconds / 300 * 1e3:.0f} ms per run); "
        f"after the first chunk (compilation) {steady * 1e3:.0f} ms per run"
    )
    assert data.counts() == {s: {"train": 70, "validation": 30} for s in data.states}
    assert np.all(np.isfinite(data.features))
