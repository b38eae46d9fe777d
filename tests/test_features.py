"""Spectral features against scipy.signal.welch and hand-computed values; jit, vmap, grad."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal

from bayesdoor.features import (
    LOG_FLOOR,
    CNNInputSpec,
    MotionDetection,
    WelchOptions,
    band_envelope,
    band_features,
    cnn_input,
    log_psd,
    motion_window,
    objective_j,
    segment_weights,
    welch_csd,
    welch_psd,
    welch_segment_count,
    windowed_log_psd,
)

FS = 2048.0
# compiled once per configuration: eager mode compiles every primitive anew and is slower
_welch = eqx.filter_jit(welch_psd)
_cnn = eqx.filter_jit(cnn_input)


def _signals(kind, shape, seed=0):
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal(shape)
    if kind == "random":
        return noise
    t = np.arange(shape[-1]) / FS
    # two tones (one between bins) 60 dB above the noise: a PSD with a 1e10 dynamic range
    return np.sin(2 * np.pi * 96.3 * t + 0.4) + 3 * np.sin(2 * np.pi * 25 * t) + 1e-3 * noise


def _assert_matches_scipy(psd, ref):
    # FFT round-off is relative to the largest bin (the total energy), ~1e-16 of it; bins 1e10
    # below the peak therefore carry ~1e-12 relative error, hence the two terms
    psd, ref = np.asarray(psd), np.asarray(ref)
    scale = ref.max(axis=-1, keepdims=True)
    assert np.all(np.abs(psd - ref) <= 1e-12 * ref + 1e-14 * scale)


@pytest.mark.parametrize("kind", ["random", "sinusoid"])
@pytest.mark.parametrize(
    "n, nperseg, noverlap, detrend, window",
    [
        (7168, 512, None, "constant", "hann"),
        (1001, 128, None, "constant", "hann"),
        (999, 127, 30, "linear", "hann"),
        (4097, 1000, 990, False, ("tukey", 0.25)),
        (700, 64, 0, "constant", "hamming"),
        (513, 512, None, "linear", "boxcar"),
    ],
)
def test_welch_matches_scipy(kind, n, nperseg, noverlap, detrend, window):
    x = _signals(kind, (2, 3, n))
    freqs, psd = _welch(
        jnp.asarray(x),
        FS,
        nperseg=nperseg,
        noverlap=noverlap,
        options=WelchOptions(window=window, detrend=detrend),
    )
    f_ref, p_ref = scipy.signal.welch(
        x, FS, nperseg=nperseg, noverlap=noverlap, detrend=detrend, window=window
    )
    assert psd.shape == p_ref.shape == (2, 3, nperseg // 2 + 1)
    np.testing.assert_array_equal(np.asarray(freqs), f_ref)
    _assert_matches_scipy(psd, p_ref)


@pytest.mark.parametrize(
    "n, nperseg, noverlap, nfft, detrend",
    [
        (7168, 512, None, 2048, "constant"),
        (999, 127, 30, 509, "linear"),
        (1001, 128, 0, None, False),
    ],
)
def test_numpy_welch_and_cross_spectrum_match_scipy(n, nperseg, noverlap, nfft, detrend):
    x = _signals("sinusoid", (2, n))
    y = 0.3 * x + _signals("random", (2, n), seed=1)
    kw = dict(nperseg=nperseg, noverlap=noverlap, nfft=nfft, detrend=detrend)
    ours = dict(
        nperseg=nperseg, noverlap=noverlap, options=WelchOptions(nfft=nfft, detrend=detrend)
    )
    freqs, psd = welch_psd(x, FS, **ours)
    f_csd, csd = welch_csd(x, y, FS, **ours)
    # numpy in, numpy out: the same code run by numpy (diagnosis), without compiling
    assert type(psd) is type(csd) is type(freqs) is np.ndarray
    f_ref, p_ref = scipy.signal.welch(x, FS, **kw)
    _, c_ref = scipy.signal.csd(x, y, FS, **kw)
    assert psd.shape == p_ref.shape == ((2, (nfft or nperseg) // 2 + 1))
    np.testing.assert_array_equal(freqs, f_ref)
    np.testing.assert_array_equal(f_csd, f_ref)
    _assert_matches_scipy(psd, p_ref)
    scale = np.abs(c_ref).max(axis=-1, keepdims=True)
    assert np.all(np.abs(csd - c_ref) <= 1e-12 * np.abs(c_ref) + 1e-14 * scale)
    # the JAX path of the same code agrees with the numpy one
    _, psd_jax = welch_psd(jnp.asarray(x), FS, **ours)
    _assert_matches_scipy(psd_jax, psd)
    # the cross spectrum of a signal with itself is its power spectrum
    np.testing.assert_allclose(welch_csd(x, x, FS, **ours)[1].real, psd, rtol=1e-12)


def test_segment_count_is_the_number_of_segments_averaged():
    for n, nperseg, noverlap in [
        (7168, 512, None),
        (999, 127, 30),
        (1001, 128, 0),
        (511, 512, None),
    ]:
        step = nperseg - (nperseg // 2 if noverlap is None else noverlap)
        # the whole segments, one starting every step samples
        assert welch_segment_count(n, nperseg, noverlap) == len(range(0, n - nperseg + 1, step))
    # scipy's segments of the same layout (a spectrogram has one column per segment)
    x = _signals("random", (7168,))
    ref = scipy.signal.spectrogram(x, FS, nperseg=512, noverlap=256)[2]
    assert welch_segment_count(7168, 512) == ref.shape[-1]
    with pytest.raises(ValueError, match="nfft must be an integer of at least nperseg=128"):
        welch_psd(np.zeros(300), FS, nperseg=128, options=WelchOptions(nfft=100))
    with pytest.raises(ValueError, match="segment_weights sum to zero"):
        welch_psd(np.zeros(300), FS, nperseg=128, segment_weights=np.zeros(3))


def test_welch_along_another_axis_and_with_a_window_array():
    x = _signals("random", (3, 900, 2))
    win = scipy.signal.get_window(("kaiser", 6.0), 200)
    _, psd = welch_psd(
        jnp.asarray(x), FS, nperseg=200, axis=1, options=WelchOptions(window=jnp.asarray(win))
    )
    _, p_ref = scipy.signal.welch(x, FS, nperseg=200, window=win, axis=1)
    assert psd.shape == p_ref.shape == (3, 101, 2)
    _assert_matches_scipy(np.moveaxis(psd, 1, -1), np.moveaxis(p_ref, 1, -1))


def test_welch_keeps_float32():
    x = jnp.asarray(_signals("random", (4, 2048)), dtype=jnp.float32)
    freqs, psd = _welch(x, FS, nperseg=256)
    assert freqs.dtype == psd.dtype == jnp.float32
    _, p_ref = scipy.signal.welch(np.asarray(x, dtype=np.float64), FS, nperseg=256)
    # float32 round-off (6e-8) accumulated over a 256-point FFT and 15 averaged segments
    np.testing.assert_allclose(psd, p_ref, rtol=1e-4)


def test_welch_refuses_bad_options():
    x = jnp.zeros((4, 300))
    with pytest.raises(ValueError, match="300 samples, fewer than nperseg=512"):
        welch_psd(x, FS)
    with pytest.raises(ValueError, match=r"noverlap must lie in \[0, nperseg\) = \[0, 128\)"):
        welch_psd(x, FS, nperseg=128, noverlap=128)
    with pytest.raises(ValueError, match="detrend must be 'constant', 'linear' or False"):
        welch_psd(x, FS, nperseg=128, options=WelchOptions(detrend="quadratic"))
    with pytest.raises(ValueError, match=r"window array must have shape \(nperseg,\) = \(128,\)"):
        welch_psd(x, FS, nperseg=128, options=WelchOptions(window=jnp.ones(100)))
    with pytest.raises(ValueError, match="must end with an axis of 3 segments"):
        welch_psd(x, FS, nperseg=128, segment_weights=jnp.ones(4))


def test_weighted_welch_with_equal_weights_is_plain_welch():
    x = jnp.asarray(_signals("sinusoid", (3, 4, 7168)))
    _, plain = _welch(x, FS)
    _, weighted = _welch(x, FS, segment_weights=jnp.ones(27))
    _, doubled = _welch(x, FS, segment_weights=jnp.full((3, 1, 27), 2.0))
    # sum(w P) / sum(w) against mean(P): the same sums, up to XLA's order of summation
    np.testing.assert_allclose(weighted, plain, rtol=1e-14, atol=0)
    np.testing.assert_allclose(doubled, plain, rtol=1e-14, atol=0)


@pytest.mark.parametrize("nperseg, noverlap", [(512, None), (256, 64), (300, 100)])
def test_weighted_welch_on_a_window_is_scipy_on_the_cropped_record(nperseg, noverlap):
    n = 7168
    step = nperseg - (nperseg // 2 if noverlap is None else noverlap)
    x = _signals("sinusoid", (3, 4, n))
    # a different block of whole segments for each run, given as times on the sample grid
    blocks = [(0, 5), (3, 9), (7, 7)]
    t_start = jnp.asarray([k0 * step / FS for k0, _ in blocks])
    t_stop = jnp.asarray([(k1 * step + nperseg - 1) / FS for _, k1 in blocks])
    w = segment_weights(n, FS, t_start, t_stop, nperseg=nperseg, noverlap=noverlap)
    for run, (k0, k1) in enumerate(blocks):
        np.testing.assert_array_equal(np.flatnonzero(w[run]), np.arange(k0, k1 + 1))
    _, psd = _welch(
        jnp.asarray(x), FS, nperseg=nperseg, noverlap=noverlap, segment_weights=w[:, None, :]
    )
    for run, (k0, k1) in enumerate(blocks):
        cropped = x[run, :, k0 * step : k1 * step + nperseg]
        _, p_ref = scipy.signal.welch(cropped, FS, nperseg=nperseg, noverlap=noverlap)
        _assert_matches_scipy(psd[run], p_ref)


def test_numpy_welch_leaves_out_the_segments_no_weight_keeps():
    # numpy computes only the segments some weight keeps, JAX every one: the same average
    n = 7168
    x = _signals("random", (2, 3, n))
    w = np.asarray(segment_weights(n, FS, jnp.asarray([0.5, 0.9]), jnp.asarray([2.0, 2.6])))
    assert w[:, 0].sum() == 0 and w[:, -1].sum() == 0  # some segments in no window
    _, by_numpy = welch_psd(x, FS, segment_weights=w[:, None])
    _, by_jax = welch_psd(jnp.asarray(x), FS, segment_weights=jnp.asarray(w[:, None]))
    np.testing.assert_allclose(by_numpy, by_jax, rtol=1e-12, atol=0)
    # what lies outside every window does not reach the average, even when not finite
    spoiled = x.copy()
    spoiled[..., :100] = np.nan
    np.testing.assert_array_equal(welch_psd(spoiled, FS, segment_weights=w[:, None])[1], by_numpy)
    _, cross = welch_csd(x, x, FS, segment_weights=w[:, None])
    np.testing.assert_allclose(cross.real, by_numpy, rtol=1e-14, atol=0)


def test_windowed_log_psd_of_draws_is_each_draw_alone():
    x = _signals("random", (3, 2, 4, 7168))
    t0, t1 = np.asarray([0.25, 0.5]), np.asarray([3.0, 2.2])
    _, draws, log_var = windowed_log_psd(x, FS, t0, t1, nperseg=2048)
    assert draws.shape == (3, 2, 4, 1025) and log_var.shape == (2,)
    for draw, alone in zip(draws, x, strict=True):
        np.testing.assert_array_equal(draw, windowed_log_psd(alone, FS, t0, t1, nperseg=2048)[1])
    with pytest.raises(ValueError, match=r"dims \(\.\.\., run, channel, time\)"):
        windowed_log_psd(x[0, 0], FS, t0, t1, nperseg=2048)


def test_segment_weights_select_segments_inside_the_window():
    # segments of 512 samples every 256: segment k covers [k/8, k/8 + 511/2048] s
    w = segment_weights(7168, FS, 0.3, 1.5, t0=0.05)
    # inside: start >= 0.25 s after t0 (k >= 2), end <= 1.45 s after t0 (k <= 9)
    np.testing.assert_array_equal(np.flatnonzero(w), np.arange(2, 10))
    assert w.dtype == jnp.float64


def test_weights_that_select_nothing_raise_at_run_time():
    x = jnp.asarray(_signals("random", (4, 7168)))
    w = segment_weights(7168, FS, 1.0, 1.2)  # 0.2 s: shorter than one 0.25 s segment
    assert float(jnp.sum(w)) == 0.0
    for run in (welch_psd, eqx.filter_jit(welch_psd)):
        with pytest.raises(eqx.EquinoxRuntimeError, match="no segment lies inside its window"):
            jax.block_until_ready(run(x, FS, segment_weights=w))


def test_objective_j_hand_computed():
    sim = jnp.asarray([[1.0, 2.0, 3.0, 4.0], [0.0, 0.0, 0.0, 0.0], [5.0, 5.0, 5.0, 5.0]])
    meas = jnp.asarray([[1.0, 2.0, 3.0, 6.0], [1.0, -1.0, 1.0, -1.0], [5.0, 5.0, 5.0, 5.0]])
    # channel 0: sqrt(4 / 4) = 1; channel 1: sqrt(4 / 4) = 1; channel 2: exact fit, 0
    assert float(objective_j(sim, meas)) == 2.0
    other = jnp.asarray([[0.0, 0.0, 3.0, 4.0], [3.0, 3.0, 3.0, 3.0], [5.0, 5.0, 5.0, 9.0]])
    # channel 0: sqrt((1 + 4) / 4); channel 1: sqrt(36 / 4) = 3; channel 2: sqrt(16 / 4) = 2
    expected = np.sqrt(5.0 / 4.0) + 3.0 + 2.0
    batched = objective_j(jnp.stack([sim, sim]), jnp.stack([meas, other]))
    np.testing.assert_allclose(batched, [2.0, expected], rtol=1e-15)  # a few roundings
    np.testing.assert_allclose(objective_j(jnp.stack([meas, other]), sim), [2.0, expected])
    with pytest.raises(ValueError, match=r"same \(channel, freq\) axes, got shapes \(3, 4\)"):
        objective_j(sim, meas[:, :3])
    with pytest.raises(ValueError, match="do not broadcast"):
        objective_j(jnp.zeros((2, 3, 4)), jnp.zeros((3, 3, 4)))


@jax.jit
def _j_of_signals(x, target):
    return objective_j(cnn_input(x, FS), target)


def test_gradient_of_j_through_welch_is_finite_and_matches_finite_differences():
    x = jnp.asarray(_signals("random", (4, 2048), seed=1))
    target = _cnn(jnp.asarray(_signals("random", (4, 2048), seed=2)), FS)
    value, grad = jax.jit(jax.value_and_grad(_j_of_signals))(x, target)
    assert np.isfinite(float(value)) and np.all(np.isfinite(grad))
    v = jnp.asarray(np.random.default_rng(3).standard_normal(x.shape))
    h = 1e-5
    fd = (_j_of_signals(x + h * v, target) - _j_of_signals(x - h * v, target)) / (2 * h)
    # central differences in float64: truncation O(h^2) ~ 1e-10, cancellation ~ 1e-16 / h
    np.testing.assert_allclose(float(jnp.vdot(grad, v)), float(fd), rtol=1e-7)


def test_gradient_at_a_perfect_fit_is_zero_not_nan():
    spectra = cnn_input(jnp.asarray(_signals("random", (4, 2048))), FS)
    grad = jax.grad(objective_j)(spectra, spectra)
    np.testing.assert_array_equal(grad, 0.0)
    x = jnp.asarray(_signals("random", (4, 2048)))
    # the same program computes both sides, so the misfit is exactly zero
    grad = jax.jit(jax.grad(lambda x: _j_of_signals(x, jax.lax.stop_gradient(cnn_input(x, FS)))))(x)
    np.testing.assert_array_equal(grad, 0.0)


def test_cnn_input_is_the_papers_4_by_25_log_psd():
    x = _signals("sinusoid", (4, 7168))
    features = _cnn(jnp.asarray(x), FS)
    assert features.shape == (4, 25)
    np.testing.assert_array_equal(CNNInputSpec().frequencies(FS), np.arange(0.0, 97.0, 4.0))
    _, p_ref = scipy.signal.welch(x, FS, nperseg=512)
    # log10 turns the PSD's relative error (<= 1e-12, see _assert_matches_scipy) into absolute
    np.testing.assert_allclose(features, np.log10(p_ref[:, :25]), rtol=0, atol=1e-12)
    assert int(jnp.argmax(features[1])) == round(25 / 4)  # the 25 Hz tone


def test_cnn_input_spec_options():
    x = jnp.asarray(_signals("random", (2, 4, 4096)))
    spec = CNNInputSpec(fmax=200.0, nperseg=256, log=False)
    features = _cnn(x, FS, spec)
    assert features.shape == (2, 4, 26)  # 0, 8, ..., 200 Hz
    _, psd = _welch(x, FS, nperseg=256)
    np.testing.assert_allclose(features, psd[..., :26], rtol=1e-14)  # separately compiled
    with pytest.raises(ValueError, match=r"fmax=2000\.0 Hz lies above the Nyquist frequency"):
        cnn_input(x, FS, CNNInputSpec(fmax=2000.0))
    with pytest.raises(ValueError, match="nperseg must be an integer >= 2, got 1"):
        CNNInputSpec(nperseg=1)
    with pytest.raises(ValueError, match="fmax must be positive"):
        CNNInputSpec(fmax=0.0)


def test_band_envelope_recovers_an_amplitude_modulation_and_matches_scipy_hilbert():
    fs, n = 12000.0, 12000
    t = np.arange(n) / fs
    rng = np.random.default_rng(3)
    modulation = 1.0 + 0.5 * np.cos(2 * np.pi * 107.0 * t)
    # a 3 kHz carrier, modulated at 107 Hz, beside a strong 500 Hz tone outside the band
    x = modulation * np.sin(2 * np.pi * 3000.0 * t) + 4.0 * np.sin(2 * np.pi * 500.0 * t)
    x = x + 0.01 * rng.standard_normal(n)
    env = np.asarray(band_envelope(jnp.asarray(x), fs, (2000.0, 4500.0)))
    np.testing.assert_allclose(env[500:-500], modulation[500:-500], atol=0.03)
    # the same ideal band-pass, then scipy's Hilbert transform
    spectrum = np.fft.rfft(x)
    f = np.fft.rfftfreq(n, 1 / fs)
    passed = np.fft.irfft(np.where((f >= 2000.0) & (f <= 4500.0), spectrum, 0.0), n)
    np.testing.assert_allclose(env, np.abs(scipy.signal.hilbert(passed)), atol=1e-10)
    spec = CNNInputSpec(fmax=600.0, nperseg=4096, envelope_band=(2000.0, 4500.0))
    features = np.asarray(_cnn(jnp.asarray(x[None]), fs, spec))[0]
    freqs = spec.frequencies(fs)
    assert features.shape == freqs.shape == (205,)
    peak = np.argmax(features[5:]) + 5  # above the window's leakage of the mean
    assert abs(freqs[peak] - 107.0) <= fs / 4096
    # the plain spectrum of the same signal peaks at the out-of-band tone, not at 107 Hz
    plain = np.asarray(_cnn(jnp.asarray(x[None]), fs, CNNInputSpec(fmax=600.0, nperseg=4096)))
    assert abs(freqs[np.argmax(plain[0])] - 500.0) <= fs / 4096


def test_envelope_spec_settings_round_trip_and_bad_bands_raise():
    spec = CNNInputSpec(fmax=600.0, nperseg=4096, envelope_band=[2000, 4500])
    assert spec.envelope_band == (2000.0, 4500.0)
    assert CNNInputSpec(**spec.to_dict()) == spec
    assert "envelope_band" not in CNNInputSpec().to_dict()  # plain specs keep their settings
    with pytest.raises(ValueError, match="envelope_band must be"):
        CNNInputSpec(envelope_band=(4500.0, 2000.0))
    with pytest.raises(ValueError, match="reaches above the Nyquist"):
        CNNInputSpec(fmax=100.0, envelope_band=(2000.0, 4500.0)).frequencies(FS)


def test_jit_and_vmap_agree_with_eager_and_do_not_recompile():
    x = jnp.asarray(_signals("random", (3, 4, 7168)))
    eager = cnn_input(x, FS)
    jitted = jax.jit(lambda x: cnn_input(x, FS))
    np.testing.assert_allclose(jitted(x), eager, rtol=1e-14)  # fusion may reorder sums
    np.testing.assert_allclose(jax.vmap(lambda r: cnn_input(r, FS))(x), eager, rtol=1e-14)
    jitted(x + 1.0)
    assert jitted._cache_size() == 1
    t_start = jnp.asarray([0.25, 0.5, 1.0])
    per_run = jax.jit(
        jax.vmap(lambda r, a: cnn_input(r, FS, segment_weights=segment_weights(7168, FS, a, 3.0)))
    )(x, t_start)
    together = cnn_input(x, FS, segment_weights=segment_weights(7168, FS, t_start, 3.0)[:, None])
    np.testing.assert_allclose(per_run, together, rtol=1e-14)


def test_band_features_hand_computed():
    freqs = jnp.asarray([0.0, 4.0, 8.0, 12.0, 16.0])
    psd = jnp.asarray([[1.0, 3.0, 10.0, 20.0, 30.0], [1.0, 1.0, 1.0, 1.0, 1.0]])
    means = eqx.filter_jit(band_features)(freqs, psd, [0.0, 8.0, 16.0], log=False)
    # [0, 8): bins 0, 4 Hz; [8, 16]: bins 8, 12, 16 Hz (the last band includes its edge)
    np.testing.assert_allclose(means, [[2.0, 20.0], [1.0, 1.0]], rtol=1e-15)
    np.testing.assert_allclose(
        band_features(freqs, psd, [0.0, 8.0, 16.0]), np.log10([[2.0, 20.0], [1.0, 1.0]])
    )
    with pytest.raises(ValueError, match=r"at least two increasing frequencies, got \[8.0, 4.0\]"):
        band_features(freqs, psd, [8.0, 4.0])
    with pytest.raises(eqx.EquinoxRuntimeError, match="holds no PSD bin"):
        band_features(freqs, psd, [0.0, 1.0, 2.0, 16.0])


def test_log_psd_floor_keeps_values_and_gradients_finite():
    psd = jnp.asarray([0.0, 1e-40, 1e-3])
    # XLA's log10 may differ from numpy's in the last bit
    np.testing.assert_allclose(log_psd(psd), [-30.0, -30.0, -3.0], rtol=1e-15)
    assert LOG_FLOOR == 1e-30
    assert np.all(np.isfinite(jax.grad(lambda p: jnp.sum(log_psd(p)))(psd)))


def _run_with_motion(rest_noise, seed=0):
    """Rest until 0.5 s, a burst of 'motion' until 2.0 s, rest until 3.5 s (door-like)."""
    rng = np.random.default_rng(seed)
    t = np.arange(7168) / FS
    moving = (t >= 0.5) & (t < 2.0)
    x = rest_noise * rng.standard_normal((4, t.size)) + 0.02  # sensor offset
    x[1] += moving * (0.3 * np.sin(2 * np.pi * 40 * t) + 0.1 * rng.standard_normal(t.size))
    x[3] += moving * 0.2 * np.sin(2 * np.pi * 58 * t)
    return t, x


@pytest.mark.parametrize("rest_noise", [0.01, 0.0])
def test_motion_window_finds_the_burst(rest_noise):
    t, x = _run_with_motion(rest_noise)
    t_start, t_stop = motion_window(t, x, channels=[1, 3])
    # the rule errs inward by at most one RMS window (0.02 s); a sine's zero crossings and the
    # threshold cost a few more samples
    assert 0.5 <= t_start <= 0.5 + 0.025
    assert 2.0 - 0.025 <= t_stop < 2.0


def test_motion_window_keeps_given_times_and_refuses_a_still_record():
    t, x = _run_with_motion(0.01)
    assert motion_window(t, x, t_start=0.3, t_stop=3.0) == (0.3, 3.0)
    start, stop = motion_window(t, x, t_start=0.3)
    assert start == 0.3 and 1.975 <= stop < 2.0
    still = 0.01 * np.random.default_rng(0).standard_normal((4, t.size))
    for record in (still, np.zeros((4, t.size))):
        with pytest.raises(ValueError, match="no motion detected"):
            motion_window(t, record)
    with pytest.raises(ValueError, match=r"rest_duration=10.0 s gives 7168 rest samples of 7168"):
        motion_window(t, x, detection=MotionDetection(rest_duration=10.0))
    with pytest.raises(ValueError, match=r"got shapes \(7168,\) and \(4, 100\)"):
        motion_window(t, x[:, :100])
