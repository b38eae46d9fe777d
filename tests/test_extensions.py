"""The door's model extensions: each puts its signature where physics says, at nominal values
each is the base model, gradients are finite and right, bad values are refused by name."""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal

from bayesdoor.datagen import GaussianScatter, GenerationConfig, describe_system, generate
from bayesdoor.door import (
    EXTENSIONS,
    WHEEL_CIRCUMFERENCE,
    DoorDamage,
    DoorParameters,
    ElevatorDoor,
    FrameMode,
    MainsHum,
    RailWaviness,
    SensorCrossAxis,
    SolverConfig,
    WheelEccentricity,
    extension,
    motion_duration,
)
from bayesdoor.inference import FitProblem, FitSettings, fit_campaign
from bayesdoor.io import make_campaign

FS = 2048.0
SPEEDS = (0.3, 0.5)
OPT = {k: float(v) for k, v in DoorParameters.paper_optimum().to_dict().items()}
WAVELENGTH = 0.025


def _values(door, **changes):
    return {**door.nominal(), **OPT, **changes}


def _cruise(t, v_max):
    """Samples of the constant-speed phase of the stroke (S-curve ramps are v/a + a/j long)."""
    ramp = v_max / 0.8 + 0.8 / 8.0
    return (t >= 0.25 + ramp) & (t <= 0.25 + float(motion_duration(v_max)) - ramp)


@pytest.fixture(scope="module")
def base_runs():
    """The base door at the paper's optimum and the two speeds."""
    result = ElevatorDoor().simulate_values({k: np.asarray(v) for k, v in OPT.items()}, SPEEDS)
    assert np.all(np.asarray(result.status) == 0)
    return result


@pytest.fixture(scope="module")
def surface_runs():
    """One compiled solve for both surface extensions: off, eccentric wheel, wavy rail, each at
    the two speeds."""
    door = ElevatorDoor(extensions=(WheelEccentricity(), RailWaviness()))
    cases = (
        {},
        {"wheel_eccentricity.amplitude_1": 20e-6},
        {"rail_waviness.amplitude_m": 10e-6, "rail_waviness.wavelength_m": WAVELENGTH},
    )
    rows = [(_values(door, **c), v) for c in cases for v in SPEEDS]
    values = {k: np.asarray([r[0][k] for r in rows]) for k in door.parameter_names()}
    result = door.simulate_values(values, np.asarray([r[1] for r in rows]))
    assert np.all(np.asarray(result.status) == 0)
    signals = np.asarray(result.signals).reshape(len(cases), len(SPEEDS), 4, -1)
    return dict(zip(("off", "eccentric", "wavy"), signals, strict=True)), np.asarray(result.time)


def _tone(y, t, band):
    """Frequency of the sinusoid (plus a linear trend) that best fits ``y``: the least-squares
    residual scanned over ``band`` in 50 mHz steps, then around its minimum in 1 mHz steps."""

    def best(grid):
        resid = []
        for f in grid:
            arg = 2 * np.pi * f * t
            basis = np.stack([np.ones_like(t), t, np.cos(arg), np.sin(arg)])
            coef, *_ = np.linalg.lstsq(basis.T, y, rcond=None)
            resid.append(np.sum((basis.T @ coef - y) ** 2))
        return grid[int(np.argmin(resid))]

    coarse = best(np.arange(*band, 0.05))
    return best(np.arange(coarse - 0.05, coarse + 0.05, 0.001))


# ---------------------------------------------------------------------------------------------
# switching on, names, provenance, bad input


def test_no_extensions_is_the_base_door():
    door = ElevatorDoor(extensions=())
    assert door == ElevatorDoor()
    assert door.parameter_names() == ("K", "n", "c_r", "I", "mu_s", "mu_d", "C", "MF")
    assert door.extension_names == ()
    signals = jnp.ones((4, 3))
    assert door.apply_output_extensions(signals, jnp.arange(3.0), {}) is signals


def test_parameters_follow_table_2_with_prefixed_names():
    door = ElevatorDoor().with_extensions("frame_mode", "sensor_cross_axis", MainsHum(60.0, 2))
    names = door.parameter_names()
    assert names[:8] == ElevatorDoor().parameter_names()
    assert all(n.split(".")[0] in door.extension_names for n in names[8:])
    assert "mains_hum.ratio_2" in names and "mains_hum.ratio_3" not in names
    for p in door.parameters[8:]:
        assert p.lower <= p.nominal <= p.upper and p.unit and p.description
    assert set(EXTENSIONS) == {
        "frame_mode",
        "wheel_eccentricity",
        "rail_waviness",
        "sensor_cross_axis",
        "mains_hum",
    }
    assert [e.needs_resolve for e in door.extensions] == [False, False, False]
    assert WheelEccentricity.needs_resolve and RailWaviness.needs_resolve
    assert door.without_output_extensions() == ElevatorDoor()


def test_an_extended_door_is_never_described_as_the_base_one():
    base = describe_system(ElevatorDoor())
    for name in EXTENSIONS:
        described = describe_system(ElevatorDoor().with_extensions(name))
        assert described != base
        assert ElevatorDoor().with_extensions(name).describe()["extensions"][0]["name"] == name
    # the static configuration counts too
    left = ElevatorDoor().with_extensions(WheelEccentricity(wheel="left"))
    right = ElevatorDoor().with_extensions(WheelEccentricity(wheel="right"))
    assert describe_system(left) != describe_system(right)
    assert left.describe() != right.describe()


def test_bad_extensions_and_values_are_refused_by_name():
    with pytest.raises(ValueError, match="'none' is the base model"):
        extension("none")
    with pytest.raises(ValueError, match="unknown model extension 'mains'"):
        ElevatorDoor().with_extensions("mains")
    with pytest.raises(ValueError, match="more than once"):
        ElevatorDoor().with_extensions("mains_hum", MainsHum(frequency_hz=60.0))
    with pytest.raises(ValueError, match=re.escape("mains is 50.0 or 60.0")):
        MainsHum(frequency_hz=55.0)
    with pytest.raises(ValueError, match=re.escape("SensorCrossAxis.sensor='A3'")):
        SensorCrossAxis(sensor="A3")
    with pytest.raises(ValueError, match=re.escape("WheelEccentricity.wheel='top'")):
        WheelEccentricity(wheel="top")
    door = ElevatorDoor().with_extensions("frame_mode")
    with pytest.raises(ValueError, match=r"frame_mode\.frequency_hz=500\.0 Hz is outside .*10\.0"):
        door.simulate_values(_values(door, **{"frame_mode.frequency_hz": 500.0}), 0.4)
    incomplete = _values(door)
    del incomplete["frame_mode.damping_ratio"]
    with pytest.raises(ValueError, match=r"frame_mode\.damping_ratio"):
        door.simulate_values(incomplete, 0.4)
    with pytest.raises(ValueError, match=r"frame_mode\.damping_ratio"):
        door.apply_output_extensions(jnp.zeros((4, 8)), jnp.arange(8.0) / FS, incomplete)
    with pytest.raises(ValueError, match=r"rail_waviness\.amplitude_m"):
        door.simulate(
            DoorParameters.paper_optimum(),
            DoorDamage.healthy(),
            0.4,
            extension_values={"rail_waviness.amplitude_m": 1e-6},
        )


# ---------------------------------------------------------------------------------------------
# at nominal values an extension is the base model


def test_output_extensions_at_nominal_values_leave_signals_bit_identical(surface_runs):
    runs, t = surface_runs
    base = runs["off"]
    door = ElevatorDoor().with_extensions("frame_mode", "sensor_cross_axis", "mains_hum")
    out = np.asarray(door.apply_output_extensions(base, t, door.nominal()))
    np.testing.assert_array_equal(out, base)


def test_surface_extensions_at_nominal_values_match_the_base_door(surface_runs, base_runs):
    """A zero amplitude adds exact zeros, but the extended right-hand side is another compiled
    program: the adaptive step sequence can differ, which moves the solution by the solver's
    tolerance (rtol 1e-5) accumulated over the run. Measured: 1e-10 of the signal's range at
    0.3 m/s, 2.3e-5 at 0.5 m/s; the tolerance is 1e-4, far below any physical change."""
    runs, _ = surface_runs
    base = np.asarray(base_runs.signals)
    np.testing.assert_allclose(runs["off"], base, rtol=0, atol=1e-4 * np.abs(base).max())


def test_simulating_an_output_extension_equals_applying_it_to_base_signals(base_runs):
    """The refit path (simulate once, apply many times) is the simulation path."""
    door = ElevatorDoor().with_extensions(SensorCrossAxis(sensor="A2", into="Z"), "mains_hum")
    values = _values(door, **{"sensor_cross_axis.fraction": 0.15, "mains_hum.amplitude_A1Z": 0.02})
    sim = door.simulate_values(values, SPEEDS)
    assert door.without_output_extensions() == ElevatorDoor()
    again = door.apply_output_extensions(base_runs.signals, base_runs.time, values)
    np.testing.assert_array_equal(np.asarray(sim.signals), np.asarray(again))


# ---------------------------------------------------------------------------------------------
# signatures


def test_frame_mode_response_matches_scipy_lsim(key):
    """The same oscillator through scipy's linear simulation (first-order hold, as here): both
    are exact for a drive linear between samples, so they agree to round-off (1e-9 of the
    response's peak allows for the matrix exponentials' error amplified by 8192 steps)."""
    drive = jax.random.normal(key, (8192,))
    f0, zeta = 87.0, 0.01
    ours = np.asarray(FrameMode().response(drive, 1.0 / FS, f0, zeta))
    w = 2 * np.pi * f0
    system = scipy.signal.lti(
        [[0.0, 1.0], [-(w**2), -2 * zeta * w]],
        [[0.0], [-1.0]],
        [[-(w**2), -2 * zeta * w]],
        [[-1.0]],
    )
    _, ref, _ = scipy.signal.lsim(system, np.asarray(drive), np.arange(8192) / FS)
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-9 * np.abs(ref).max())


def test_frame_mode_decays_freely_once_its_drive_stops(key):
    """After a 0.1 s burst the mode rings at its damped frequency with the envelope
    exp(-zeta w t): the energy in whole damped periods 0.2 s apart falls by exp(-2 zeta w 0.2 s)
    (to 1 %: the squared cosine's mean over a period depends on the phase by O(zeta))."""
    f0, zeta = 60.0, 0.02
    drive = jnp.zeros(2048).at[:204].set(jax.random.normal(key, (204,)))
    y = np.asarray(FrameMode().response(drive, 1.0 / FS, f0, zeta))
    w = 2 * np.pi * f0
    period = 2 * np.pi / (w * np.sqrt(1 - zeta**2))
    t = np.arange(2048) / FS

    def energy(t0):
        inside = (t >= t0) & (t < t0 + 5 * period)
        return np.sum(y[inside] ** 2)

    np.testing.assert_allclose(energy(0.5) / energy(0.3), np.exp(-2 * zeta * w * 0.2), rtol=0.01)


def test_frame_mode_is_a_peak_at_its_frequency_with_its_bandwidth(surface_runs):
    """The mode's share of A2X over its drive: Welch spectra (1 Hz bins) peak in the bin of
    f0 and the half-power width (linear interpolation between bins) is 2 zeta f0 = 9 Hz;
    10 % allows for the Hann window's smearing of a 9-bin-wide peak."""
    runs, t = surface_runs
    base = runs["off"][0]
    f0, zeta = 150.0, 0.03
    door = ElevatorDoor().with_extensions("frame_mode")
    values = _values(
        door,
        **{
            "frame_mode.frequency_hz": f0,
            "frame_mode.damping_ratio": zeta,
            "frame_mode.participation_A2X": 0.5,
        },
    )
    out = np.asarray(door.apply_output_extensions(base, t, values))
    np.testing.assert_array_equal(out[[0, 1, 3]], base[[0, 1, 3]])
    f, p_drive = scipy.signal.welch(base.sum(axis=0), FS, nperseg=2048)
    _, p_mode = scipy.signal.welch(out[2] - base[2], FS, nperseg=2048)
    ratio = p_mode / p_drive
    k = int(np.argmax(ratio))
    assert f[k] == f0
    # the peak's height is that of the transfer function, (p / (2 zeta))^2, to 10 %
    np.testing.assert_allclose(ratio[k], (0.5 / (2 * zeta)) ** 2, rtol=0.1)
    half = ratio[k] / 2
    lo = k - np.argmax(ratio[k::-1] < half)
    hi = k + np.argmax(ratio[k:] < half)
    left = np.interp(half, ratio[lo : lo + 2], f[lo : lo + 2])
    right = np.interp(half, ratio[hi - 1 : hi + 1][::-1], f[hi - 1 : hi + 1][::-1])
    np.testing.assert_allclose(right - left, 2 * zeta * f0, rtol=0.1)


def test_sensor_cross_axis_mixes_one_sensor_and_raises_its_coherence(surface_runs):
    runs, t = surface_runs
    base = runs["off"][1]
    door = ElevatorDoor().with_extensions(SensorCrossAxis(sensor="A1", into="X"))
    out = np.asarray(
        door.apply_output_extensions(base, t, _values(door, **{"sensor_cross_axis.fraction": 0.1}))
    )
    # to round-off (a fused multiply-add may round once instead of twice)
    scale = np.abs(base[:2]).max()
    np.testing.assert_allclose(out[0], base[0] + 0.1 * base[1], rtol=0, atol=1e-15 * scale)
    np.testing.assert_array_equal(out[1:], base[1:])

    def coherence(sig, a, b):
        f, c = scipy.signal.coherence(sig[a], sig[b], FS, nperseg=512)
        return np.mean(c[(f >= 5) & (f <= 300)])

    # measured: about 0.3 without, 0.9 with; the other sensor is untouched
    assert coherence(out, 0, 1) > coherence(base, 0, 1) + 0.3
    assert coherence(out, 2, 3) == coherence(base, 2, 3)


@pytest.mark.parametrize("mains_hz", [50.0, 60.0])
def test_mains_hum_is_a_line_at_mains_frequency_present_at_rest(surface_runs, mains_hz):
    """During the first 0.25 s (the door at rest) the spectrum's largest line is the mains
    frequency, with its harmonics; a least-squares fit of the three lines there returns the
    parameters (to 1e-4: the base model's rest signal on A2X is 2e-8 m/s^2, the hum 20 mm/s^2)."""
    runs, t = surface_runs
    base = runs["off"][0]
    door = ElevatorDoor().with_extensions(MainsHum(frequency_hz=mains_hz, harmonics=3))
    values = _values(
        door,
        **{"mains_hum.amplitude_A2X": 0.02, "mains_hum.ratio_2": 0.3, "mains_hum.ratio_3": 0.2},
    )
    out = np.asarray(door.apply_output_extensions(base, t, values))
    rest = t < 0.25
    # 0.25 s of rest in one segment, the spectrum on a 2 Hz grid that holds 50 and 60 Hz
    f, p = scipy.signal.welch(out[2, rest], FS, nperseg=512, nfft=1024)
    assert f[np.argmax(p)] == mains_hz
    for h in (2, 3):
        peak = f[np.argmax(np.where(np.abs(f - h * mains_hz) < 20, p, 0))]
        assert peak == h * mains_hz and p[f == peak] > 100 * np.median(p)
    tt = t[rest]
    arg = 2 * np.pi * mains_hz * tt
    basis = np.stack([fn(h * arg) for h in (1, 2, 3) for fn in (np.cos, np.sin)])
    coef, *_ = np.linalg.lstsq(basis.T, out[2, rest], rcond=None)
    amplitudes = np.hypot(coef[0::2], coef[1::2])
    np.testing.assert_allclose(amplitudes, [0.02, 0.3 * 0.02, 0.2 * 0.02], rtol=1e-4)
    np.testing.assert_array_equal(out[[0, 1, 3]], base[[0, 1, 3]])


def test_mains_hum_adds_its_power_to_a_tone_of_the_signal_at_its_frequency():
    """A signal with its own 50 Hz tone, as the door has at one speed: a hum of a fixed phase
    interferes with it (in phase it doubles the line's amplitude, against it cancels it);
    the extension's line is in quadrature with the signal over the record, so the powers add,
    the expectation over a hum's chance phase. Checked on scipy's Welch spectrum (1 Hz bins):
    at 49-51 Hz the extended power is the tone's plus the hum's alone to 1 %, on both
    channels whose tone phases differ; the hum's amplitude is kept (least squares)."""
    t = np.arange(int(4 * FS)) / FS
    rng = np.random.default_rng(0)
    tone = np.stack([0.02 * np.cos(2 * np.pi * 50.0 * t + p) for p in (0.0, 2.1, -1.0, 3.0)])
    signals = tone + 1e-4 * rng.standard_normal(tone.shape)
    door = ElevatorDoor().with_extensions(MainsHum(frequency_hz=50.0, harmonics=1))
    values = _values(door, **{f"mains_hum.amplitude_{c}": 0.02 for c in ("A1X", "A2X")})
    out = np.asarray(door.apply_output_extensions(jnp.asarray(signals), jnp.asarray(t), values))

    def power(x):
        f, p = scipy.signal.welch(x, FS, nperseg=int(FS))
        return p[..., np.abs(f - 50.0) <= 1.0].sum(axis=-1)

    hum_alone = power(0.02 * np.cos(2 * np.pi * 50.0 * t))
    for channel in (0, 2):
        np.testing.assert_allclose(
            power(out[channel]), power(signals[channel]) + hum_alone, rtol=0.01
        )
        basis = np.stack([np.cos(2 * np.pi * 50.0 * t), np.sin(2 * np.pi * 50.0 * t)])
        coef, *_ = np.linalg.lstsq(basis.T, out[channel] - signals[channel], rcond=None)
        assert np.hypot(*coef) == pytest.approx(0.02, rel=1e-4)
    # a line at phase zero on channel 0 (its tone at phase zero) would have doubled the tone
    assert power(signals[0] + 0.02 * np.cos(2 * np.pi * 50.0 * t)) > 1.9 * power(out[0])
    np.testing.assert_array_equal(out[[1, 3]], signals[[1, 3]])


def test_eccentric_wheel_tone_is_at_the_rotation_frequency_and_tracks_speed(surface_runs):
    """The change the eccentric wheel makes to A1Z during the cruise, low-passed at 10 Hz, is a
    tone at v / (2 pi R): 1.59 Hz at 0.3 m/s, 2.65 Hz at 0.5 m/s. The cruise holds only 3.5
    and 2.3 periods of it, next to the drive's own low-frequency response, so the fitted
    frequency is good to a few percent (measured 0.5 % and 1.9 %); 3 % tells the rotation
    frequency from a tone fixed in time (a 67 % change between the speeds)."""
    runs, t = surface_runs
    sos = scipy.signal.butter(4, 10.0, fs=FS, output="sos")
    found = []
    for i, v in enumerate(SPEEDS):
        change = scipy.signal.sosfiltfilt(sos, runs["eccentric"][i, 1] - runs["off"][i, 1])
        m = _cruise(t, v)
        found.append(_tone(change[m], t[m], (0.5, 8.0)))
        np.testing.assert_allclose(found[-1], v / WHEEL_CIRCUMFERENCE, rtol=0.03)
    np.testing.assert_allclose(found[1] / found[0], SPEEDS[1] / SPEEDS[0], rtol=0.03)


def test_rail_waviness_tone_is_at_speed_over_wavelength(surface_runs):
    """A 25 mm wavelength gives 12 Hz at 0.3 m/s and 20 Hz at 0.5 m/s on A1Z (measured within
    0.4 %); 1 % is a tenth of the spacing to the neighbouring wheel-harmonic tones."""
    runs, t = surface_runs
    for i, v in enumerate(SPEEDS):
        change = runs["wavy"][i, 1] - runs["off"][i, 1]
        m = _cruise(t, v)
        np.testing.assert_allclose(_tone(change[m], t[m], (2.0, 60.0)), v / WAVELENGTH, rtol=0.01)


def test_rail_waviness_with_independent_phases_is_one_sine_per_wheel():
    """Quadrature parts (s, c) = a (cos phi, sin phi) under a wheel give a sin(k zeta + phi)
    there (the rail at phase phi), nothing under the other wheel; the slope is d/dzeta."""
    a, phi, lam = 7e-6, 1.1, 0.023
    zeta = jnp.linspace(-0.3, 1.2, 101)
    free = RailWaviness(independent=True)
    values = {p.name: p.nominal for p in free.parameters}
    values.update(
        {
            "rail_waviness.wavelength_m": lam,
            "rail_waviness.sin_right_m": a * np.cos(phi),
            "rail_waviness.cos_right_m": a * np.sin(phi),
        }
    )
    fixed = RailWaviness(phase=phi)
    one = {"rail_waviness.wavelength_m": lam, "rail_waviness.amplitude_m": a}
    height, slope = free.surface(zeta, 1, values)
    want, want_slope = fixed.surface(zeta, 1, one)
    np.testing.assert_allclose(height, want, atol=1e-15)
    np.testing.assert_allclose(slope, want_slope, rtol=1e-12, atol=1e-15)
    grad = jax.vmap(jax.grad(lambda z: free.surface(z, 1, values)[0]))(zeta)
    np.testing.assert_allclose(slope, grad, rtol=1e-9, atol=1e-15)
    left, left_slope = free.surface(zeta, 0, values)
    assert float(jnp.abs(left).max()) == 0.0 and float(jnp.abs(left_slope).max()) == 0.0
    assert {p.name for p in free.parameters} >= {
        f"rail_waviness.{q}_{w}_m" for q in ("sin", "cos") for w in ("left", "right")
    }


# ---------------------------------------------------------------------------------------------
# gradients


def test_gradients_of_output_extensions_match_central_differences(surface_runs):
    """No solver inside: the output extensions are smooth functions of their parameters, so
    central differences (relative step 1e-6) agree with autodiff to about 1e-7; 1e-5 is the
    tolerance."""
    runs, t = surface_runs
    base = jnp.asarray(runs["off"][0])
    door = ElevatorDoor().with_extensions("frame_mode", "sensor_cross_axis", "mains_hum")
    names = (
        "frame_mode.frequency_hz",
        "frame_mode.damping_ratio",
        "frame_mode.participation_A1Z",
        "sensor_cross_axis.fraction",
        "mains_hum.amplitude_A2Z",
        "mains_hum.ratio_2",
    )
    point = _values(
        door,
        **dict(zip(names, (120.0, 0.02, 0.3, 0.05, 0.01, 0.4), strict=True)),
    )
    tt = jnp.asarray(t)

    def loss(x):
        values = {**point, **dict(zip(names, x, strict=True))}
        out = door.apply_output_extensions(base, tt, values)
        spectrum = jnp.abs(jnp.fft.rfft(out, axis=-1))[:, 1:800] ** 2
        return jnp.mean(jnp.log(spectrum + 1e-12))

    x0 = jnp.asarray([point[n] for n in names])
    grad = np.asarray(jax.jit(jax.grad(loss))(x0))
    f = jax.jit(loss)
    fd = []
    for i in range(len(names)):
        h = 1e-6 * float(x0[i])
        fd.append((float(f(x0.at[i].add(h))) - float(f(x0.at[i].add(-h)))) / (2 * h))
    assert np.all(np.isfinite(grad)) and np.all(grad != 0)
    np.testing.assert_allclose(grad, fd, rtol=1e-5)


@pytest.mark.slow
def test_gradients_through_the_solve_of_surface_extensions_match_central_differences():
    """Fixed steps (1/4096 s) over a short record, as in the base door's gradient test: the
    step sequence does not move with the parameters, so central differences are meaningful."""
    door = ElevatorDoor(
        config=SolverConfig(dt=1.0 / 4096), extensions=(WheelEccentricity(), RailWaviness())
    )
    names = (
        "wheel_eccentricity.amplitude_1",
        "wheel_eccentricity.phase_1",
        "rail_waviness.wavelength_m",
        "rail_waviness.amplitude_m",
    )
    point = _values(door, **dict(zip(names, (15e-6, 1.0, 0.03, 8e-6), strict=True)))

    def loss(x):
        values = {**point, **dict(zip(names, x, strict=True))}
        sim = door.simulate_values(values, 0.5, duration=0.9, check=False)
        spectrum = jnp.abs(jnp.fft.rfft(sim.signals[0, :, 512:], axis=-1))[:, 1:200] ** 2
        return jnp.mean(jnp.log(spectrum + 1e-12))

    x0 = jnp.asarray([point[n] for n in names])
    grad = np.asarray(jax.jit(jax.grad(loss))(x0))
    f = jax.jit(loss)
    fd = []
    for i in range(len(names)):
        h = 1e-5 * float(x0[i])
        fd.append((float(f(x0.at[i].add(h))) - float(f(x0.at[i].add(-h)))) / (2 * h))
    assert np.all(np.isfinite(grad))
    np.testing.assert_allclose(grad, fd, rtol=1e-3, atol=1e-6 * np.abs(fd).max())


# ---------------------------------------------------------------------------------------------
# the generic layers take the extended parameters


# a whole (tiny) CMA-ES fit of the extended door, 12-75 s with an empty JAX cache on a 2-core
# machine (the higher figures with other work beside it), nearly all of it compiling the fit's
# solves of that door: in the long tier, which CI runs after the default suite
@pytest.mark.long
def test_fit_campaign_updates_the_extension_parameters_with_table_2(base_runs):
    """Smoke: a campaign with a 60 Hz hum on every channel, fitted by a tiny CMA-ES with the
    extended door. The generic layer sees only names: the point names every parameter and
    stays within the bounds, and J is finite."""
    door = ElevatorDoor().with_extensions(MainsHum(frequency_hz=60.0, harmonics=2))
    hum = {f"mains_hum.amplitude_{c}": 0.03 for c in door.channels}
    signals = door.apply_output_extensions(base_runs.signals, base_runs.time, _values(door, **hum))
    campaign = make_campaign(
        np.asarray(signals),
        channels=door.channels,
        fs=FS,
        state=["healthy"] * 2,
        system="elevator_door",
        v_max=SPEEDS,
    )
    settings = FitSettings(max_motion_s=0.5, cmaes_max_evals=8, cmaes_restarts=0, cmaes_popsize=4)
    fit = fit_campaign(
        door, campaign, problem=FitProblem(fixed={"I": 6}), settings=settings, progress=False
    )
    assert set(fit.point) == set(door.parameter_names()) and fit.held == {"I": 6.0}
    for p in door.parameters:
        assert p.lower <= fit.point[p.name] <= p.upper
    assert np.isfinite(fit.j)
    assert "mains_hum.amplitude_A2Z" in fit.to_json()["parameters"]


@pytest.mark.slow
def test_training_data_generation_draws_the_extension_parameters(tmp_path, key):
    """Smoke: posterior-predictive data generation with an extended door; its draws name the
    extension parameters and its manifest describes the extended system."""
    door = ElevatorDoor().with_extensions(FrameMode(), "mains_hum")
    center = _values(
        door,
        **{
            "frame_mode.frequency_hz": 140.0,
            "frame_mode.participation_A1X": 0.4,
            "mains_hum.amplitude_A1Z": 0.02,
        },
    )
    config = GenerationConfig([0.3, 0.5], runs_per_state=2, chunk_size=2, duration=1.0)
    data = generate(
        door, GaussianScatter.around(door, center), config, tmp_path, key=key, progress=False
    )
    assert np.all(np.isfinite(data.features))
    assert set(data.parameters) == set(door.parameter_names())
    drawn = data.parameters["frame_mode.frequency_hz"]
    assert np.all((drawn >= 10.0) & (drawn <= 300.0)) and np.std(drawn) > 0
    manifest = (tmp_path / "manifest.json").read_text()
    assert "frame_mode.participation_A1X" in manifest and "MainsHum" in manifest


def test_an_unsynchronised_line_is_orthogonal_to_the_signal_and_of_unit_amplitude():
    from bayesdoor.systems import unsynchronised_line

    t = np.arange(4096) / FS
    phase = jnp.asarray(2 * np.pi * 60.0 * t)
    rng = np.random.default_rng(1)
    signals = jnp.asarray(
        np.stack([0.3 * np.cos(2 * np.pi * 60.0 * t + 0.7), rng.standard_normal(t.size)])
    )
    line = np.asarray(unsynchronised_line(signals, phase))
    assert line.shape == signals.shape
    np.testing.assert_allclose(np.sum(line * np.asarray(signals), axis=-1), 0.0, atol=1e-8)
    np.testing.assert_allclose(np.sqrt(2 * np.mean(line**2, axis=-1)), 1.0, rtol=1e-3)
    # one channel (a bearing's), and a silent one: the plain cosine
    one = np.asarray(unsynchronised_line(signals[0], phase))
    np.testing.assert_allclose(one, line[0], atol=1e-12)
    silent = np.asarray(unsynchronised_line(jnp.zeros(t.size), phase))
    np.testing.assert_allclose(silent, np.cos(np.asarray(phase)), atol=1e-12)
