"""The reduced-order door against independent references, physics signatures and bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
import scipy.signal
from scipy.integrate import solve_ivp

from bayesdoor.door import (
    DoorConstants,
    DoorDamage,
    DoorParameters,
    ElevatorDoor,
    SolverConfig,
    commanded_motion,
    contact_kinematics,
    initial_state,
    make_args,
    rhs,
    sample_times,
    solve,
    static_equilibrium,
)
from bayesdoor.door.contact import get_law

OPT = DoorParameters.paper_optimum()
# the flat meets the rail 60 mm into the stroke, so a short record contains a passage
D2_ANGLE = float(np.mod((0.35 + 0.06) / 0.03, 2 * np.pi))
CASES = {
    "healthy": DoorDamage.healthy(),
    "D1": DoorDamage.for_state("D1", d1_height=1.0e-3),
    "D2": DoorDamage.for_state("D2", d2_depth=0.2e-3, d2_angle=D2_ANGLE),
}


def test_numpy_and_jax_right_hand_sides_agree():
    # the scipy references and benchmarks run the numpy branch of the same equations
    args = make_args(OPT, CASES["D1"], 0.5)
    args_np = jax.tree_util.tree_map(np.asarray, args)
    y0 = np.asarray(initial_state(args))
    rng = np.random.default_rng(0)
    scale = np.r_[1e-2, 1e-5, 1e-5, 1e-5, 1e-6, 1e-6, 1e-6, 0.1 * np.ones(7), 0.01 * np.ones(4)]
    for t in (0.1, 0.8, 1.3):
        y = y0 + rng.normal(size=y0.size) * scale
        f_jax = np.asarray(rhs(t, jnp.asarray(y), args))
        f_np = rhs(t, y, args_np, np)
        # identical formulas; differences are floating-point reassociation only
        np.testing.assert_allclose(f_jax, f_np, rtol=1e-12, atol=1e-12 * np.abs(f_jax).max())


#: in the long tier, which CI runs after the default suite: 7-20 s each with an empty JAX cache
#: on a 2-core machine, the higher figures with other work beside it (most of it outside JAX:
#: scipy's reference solve at rtol 1e-10); the healthy case took 52 s in the default suite
#: (`pytest -n 2`, 2026-11-27, the machine under load 12-16)
@pytest.mark.long
@pytest.mark.parametrize("case", list(CASES))
def test_diffrax_matches_scipy_dop853(case):
    """Same equations, independent integrator: scipy DOP853 at rtol 1e-10 is the reference.

    Error is measured per state relative to that state's excursion over the record. diffrax at
    rtol 1e-8 agreed to <= 1e-6 when this test was written; 1e-5 leaves room for platform
    rounding but would catch any error in the solve set-up (saving, args, initial state). The
    default tolerances (rtol 1e-5) agreed to <= 5e-4; they must stay below 2e-3.
    """
    args = make_args(OPT, CASES[case], 0.5)
    ts = sample_times(1.3)
    y0 = np.asarray(initial_state(args))
    f = jax.jit(lambda t, y: rhs(t, y, args))
    ref = solve_ivp(
        lambda t, y: np.asarray(f(t, y)),
        (0.0, float(ts[-1])),
        y0,
        method="DOP853",
        t_eval=np.asarray(ts),
        rtol=1e-10,
        atol=1e-13,
    )
    assert ref.success
    excursion = np.abs(ref.y[:14] - ref.y[:14, :1]).max(axis=1)
    for config, tol in ((SolverConfig(rtol=1e-8, atol=1e-11), 1e-5), (SolverConfig(), 2e-3)):
        ys, status = solve(args, ts, config, "states")
        assert int(status) == 0
        err = np.abs(np.asarray(ys)[:14] - ref.y[:14]).max(axis=1) / excursion
        assert err.max() < tol, (config, err)


def test_linear_lateral_limit_matches_matrix_exponential():
    """With the frame cross-couplings, gib preload, rolling resistance and waviness switched off,
    the header mode and the panel's sway form a linear 2-DOF system (the panel hangs from the
    moving rail line). Its free response from a displaced header is exp(A t) x0 exactly.
    """
    constants = DoorConstants(
        gib_preload=0.0,
        rolling_resistance=0.0,
        waviness_scale=0.0,
        torsion_lift=0.0,
        racking_tilt=0.0,
        rail_lateral=0.0,
    )
    args = make_args(OPT, DoorDamage.healthy(), 0.5, constants=constants)
    y0 = initial_state(args).at[4].add(1e-4)  # header displaced 0.1 mm, shoe stays clear
    ts = sample_times(0.24)  # before the drive starts
    ys, status = solve(args, ts, SolverConfig(rtol=1e-9, atol=1e-13), "states", y0)
    assert int(status) == 0
    ys = np.asarray(ys)

    # hand-built from the door model of docs/model.md: coordinates (phi, q1)
    m, h, H = 60.0, 2.1, 1.10
    m_f, w1 = 20.0, 2 * np.pi * 32.0
    M = np.array([[m * h**2 / 12 + m * H**2, m * H], [m * H, m_f + m]])
    K = np.diag([m * 9.81 * H, m_f * w1**2])
    C = np.diag([0.0, 2 * 0.018 * m_f * w1])
    A = np.block([[np.zeros((2, 2)), np.eye(2)], [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]])
    x0 = np.array([0.0, 1e-4, 0.0, 0.0])
    ref = np.stack([scipy.linalg.expm(A * t) @ x0 for t in np.asarray(ts)], axis=1)
    sim = ys[[3, 4, 10, 11]] - np.asarray(initial_state(args))[[3, 4, 10, 11], None]
    # tight solver: the difference is integration error, orders below 1e-6 of the amplitude
    np.testing.assert_allclose(sim[1], ref[1], atol=1e-6 * 1e-4)
    np.testing.assert_allclose(sim[0], ref[0], atol=1e-6 * np.abs(ref[0]).max())
    # the hanging panel lowers the bare 32 Hz header mode to about 25 Hz (docs/model.md)
    f_installed = np.sort(np.abs(np.linalg.eigvals(A).imag))[-1] / (2 * np.pi)
    assert 24.0 < f_installed < 26.0


@pytest.mark.parametrize(("params", "expected_mm"), [("optimum", 0.384), ("nominal", 0.341)])
def test_static_deflection_matches_hand_calculation(params, expected_mm):
    """Wheel indentation at rest: (m g / 2 / K)^(1/n) in mm, from K, n and the weight.

    Hand values: optimum K = 1863, n = 1.93 -> (294.3 / 1863)^(1/1.93) = 0.384 mm; nominal
    K = 1475, n = 1.5 -> 0.341 mm. The two wheels share the load only up to the rail waviness
    under them and the belt's pitch moment, so each is within 3 % and their mean within 1 %.
    """
    p = OPT if params == "optimum" else DoorParameters.nominal()
    args = make_args(p, DoorDamage.healthy(), 0.5)
    q = static_equilibrium(args)
    gaps = np.asarray(contact_kinematics(q, args)[0])
    wheels_mm = gaps[:2] * 1e3
    np.testing.assert_allclose(wheels_mm, expected_mm, rtol=0.03)
    np.testing.assert_allclose(wheels_mm.mean(), expected_mm, rtol=0.01)
    assert np.all(gaps[2:] < 0)  # the guide shoe is clear of both groove walls


# 61 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): two
# solves, one at tight tolerances; in the long tier, which CI runs after the default suite
@pytest.mark.long
def test_run_at_rest_stays_at_rest():
    """The record before the drive starts (0.25 s) must be still: equilibrium is solved to
    machine precision, so any acceleration is integration error. With tight tolerances it is
    below 1e-9 m/s^2 (physics); at the default tolerances below 1e-3 m/s^2, a thousandth of a
    moving run's RMS (solver noise at the atol level, amplified by the stiff sticking friction).
    """
    for config, tol in ((SolverConfig(rtol=1e-10, atol=1e-14), 1e-9), (SolverConfig(), 1e-3)):
        res = ElevatorDoor(config).simulate(OPT, DoorDamage.healthy(), 0.4, duration=0.24)
        assert np.abs(np.asarray(res.signals)).max() < tol


def _log_spectrum(signals):
    seg = signals * jnp.hanning(signals.shape[-1])
    return jnp.log(jnp.abs(jnp.fft.rfft(seg, axis=-1))[..., 1:200] ** 2 + 1e-12)


# 40-174 s with an empty JAX cache on a 2-core machine (47 s idle), nearly all of it tracing
# and compiling the gradient of a fixed-step solve that no other test of the default suite
# uses: in the long tier, which CI runs after the default suite
@pytest.mark.long
def test_gradient_of_log_psd_loss_matches_central_differences():
    """Fixed-step solve (dt = 1/4096 s): the step sequence does not move with the parameters, so
    central differences in float64 are meaningful. Relative step 1e-5 balances truncation
    (~h^2) and round-off (~1e-16 / h); they agreed to better than 1e-5 when written, 1e-3 is
    the tolerance."""
    config = SolverConfig(dt=1.0 / 4096)
    ts = sample_times(0.9)
    names = ("K", "n", "c_r", "mu_s", "mu_d", "C", "MF")
    target = _log_spectrum(
        solve(make_args(DoorParameters.nominal(), CASES["D1"], 0.5), ts, config)[0]
    )
    base = OPT.to_dict()

    def loss(x):
        p = DoorParameters(**{**base, **dict(zip(names, x, strict=True))})
        sig, _ = solve(make_args(p, CASES["D1"], 0.5), ts, config)
        return jnp.mean((_log_spectrum(sig) - target) ** 2)

    x0 = jnp.asarray([float(base[k]) for k in names])
    grad = np.asarray(jax.jit(jax.grad(loss))(x0))
    f = jax.jit(loss)
    fd = []
    for i in range(len(names)):
        h = 1e-5 * float(x0[i])
        fd.append((float(f(x0.at[i].add(h))) - float(f(x0.at[i].add(-h)))) / (2 * h))
    fd = np.asarray(fd)
    assert np.all(np.isfinite(grad))
    np.testing.assert_allclose(grad, fd, rtol=1e-3, atol=1e-6 * np.abs(fd).max())


@pytest.fixture(scope="module")
def signatures():
    door = ElevatorDoor()
    v = 0.4
    out = {}
    for name, dmg in (
        ("healthy", DoorDamage.healthy()),
        ("D1", DoorDamage.for_state("D1", d1_height=1.0e-3)),
        ("D2", DoorDamage.for_state("D2", d2_depth=0.15e-3, d2_angle=1.0)),
    ):
        out[name] = np.asarray(door.simulate(OPT, dmg, v).signals)
    ts = np.asarray(sample_times(door.record_duration(v)))
    pos = np.array([float(commanded_motion(t, v)[0]) for t in ts])
    return ts, pos, out


def test_d2_impacts_once_per_wheel_revolution(signatures):
    _ts, pos, sig = signatures
    diff = sig["D2"] - sig["healthy"]
    energy = np.sum(diff**2, axis=0)
    peaks, _ = scipy.signal.find_peaks(energy, height=0.2 * energy.max(), distance=int(0.15 * 2048))
    travel = np.diff(pos[peaks])
    assert len(peaks) >= 3
    # one flat passage every 2 pi R = 0.1885 m of travel (wheel rolls without slip)
    np.testing.assert_allclose(travel, 2 * np.pi * 0.03, rtol=0.03)


def test_d1_impacts_are_transversal_at_the_bumps(signatures):
    ts, pos, sig = signatures
    diff = sig["D1"] - sig["healthy"]
    # the debris pushes the shoe sideways: the X channels carry the fault
    x_gain = np.sum(sig["D1"][[0, 2]] ** 2) / np.sum(sig["healthy"][[0, 2]] ** 2)
    assert x_gain > 5.0
    # impacts are broadband; above 150 Hz the 25 Hz ringing of the header mode is filtered out
    sos = scipy.signal.butter(4, 150, "highpass", fs=2048, output="sos")
    x_energy = np.sum(scipy.signal.sosfiltfilt(sos, diff[[0, 2]], axis=-1) ** 2, axis=0)
    for bump in (0.25, 0.55):
        # the shoe reaches the bump's flank 4 mm before its centre
        arrival = ts[np.argmax(pos >= bump - 4e-3)]
        window = (ts >= arrival - 0.01) & (ts < arrival + 0.05)
        before = (ts >= arrival - 0.2) & (ts < arrival - 0.05)
        assert x_energy[window].max() > 100 * x_energy[before].max()


# 38 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): four
# whole solves with D2, one at tight tolerances; in the long tier, which CI runs after the default
# suite
@pytest.mark.long
def test_contact_law_changes_the_response():
    """Laws with different hysteresis factors at c_r = 0.69 (Lee-Wang 0.23, Lankarani-Nikravesh
    0.39, Gonthier 0.76) damp the wheel impacts differently. The change of the log-PSD must
    stand far above the solver's own noise (default vs tight tolerances, same law)."""
    dmg = DoorDamage.for_state("D2", d2_depth=0.15e-3, d2_angle=1.0)

    def log_psd(law, config=None):
        p = DoorParameters(**{**OPT.to_dict(), "I": jnp.asarray(law, dtype=jnp.int32)})
        sig = np.asarray(ElevatorDoor(config or SolverConfig()).simulate(p, dmg, 0.4).signals)
        return np.log(scipy.signal.welch(sig, fs=2048, nperseg=512)[1][:, 1:100])

    base = log_psd(6)
    noise = np.abs(base - log_psd(6, SolverConfig(rtol=1e-8, atol=1e-11))).mean()
    for law in (4, 8):
        assert np.abs(log_psd(law) - base).mean() > 20 * noise


# 182 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16):
# batched and single solves of the door at the default record length, and a starved batch; in the
# long tier, which CI runs after the default suite
@pytest.mark.long
def test_batch_equals_single_runs_and_reports_failures():
    door = ElevatorDoor()
    params = DoorParameters(**{**OPT.to_dict(), "K": jnp.asarray([1500.0, 2200.0])})
    batch = door.simulate_batch(params, CASES["D2"], 0.45)
    assert np.all(np.asarray(batch.status) == 0)
    for i, k in enumerate((1500.0, 2200.0)):
        single = door.simulate(
            DoorParameters(**{**OPT.to_dict(), "K": jnp.asarray(k)}), CASES["D2"], 0.45
        )
        # vmapped and single solves round differently, and the adaptive step controller carries
        # that to its own tolerance level (rtol 1e-5): agreement to 1e-3 of the peak, not 1e-9
        peak = np.abs(np.asarray(single.signals)).max()
        np.testing.assert_allclose(batch.signals[i], single.signals, rtol=0, atol=1e-3 * peak)

    starved = ElevatorDoor(SolverConfig(max_steps=50))
    failed = starved.simulate_batch(params, CASES["D2"], 0.45)
    assert np.all(np.asarray(failed.status) == 1)
    assert np.all(np.asarray(failed.signals) == 0)
    with pytest.raises(RuntimeError, match="max_steps"):
        starved.simulate(OPT, CASES["D2"], 0.45)


# 101 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): a
# float32 solve that no other default test compiles, against float64; in the long tier, which CI
# runs after the default suite
@pytest.mark.long
def test_float32_on_request_tracks_float64():
    """Healthy rolling is insensitive to round-off: float32 must reproduce the float64 log-PSD
    in the CNN's 4-96 Hz band to 5 % per bin (measured: 1.5 % max, 0.09 % mean). Impact runs (D1)
    are sensitive to any perturbation: there float64 at rtol 1e-7 and 1e-5 already differ by
    ~10 % in single bins, so they are not a round-off test."""
    p = DoorParameters.paper_optimum()
    s64 = np.asarray(ElevatorDoor().simulate(p, CASES["healthy"], 0.5).signals)
    s32 = ElevatorDoor(SolverConfig(dtype="float32")).simulate(p, CASES["healthy"], 0.5).signals
    assert s32.dtype == jnp.float32
    psd64 = scipy.signal.welch(s64, fs=2048, nperseg=512)[1][:, 1:25]
    psd32 = scipy.signal.welch(np.asarray(s32, dtype=float), fs=2048, nperseg=512)[1][:, 1:25]
    dev = np.abs(np.log(psd32 / psd64))
    assert dev.max() < 0.05
    assert dev.mean() < 0.005


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"K": 3000.0}, r"K=3000\.0.*\[1300\.0, 2500\.0\]"),
        ({"n": 1.2}, r"n=1\.2.*\[1\.5, 2\.2\]"),
        ({"MF": 0.5}, r"MF=0\.5.*\[1\.0, 2\.0\]"),
        ({"I": 10}, r"I=10.*\[1, 9\]"),
    ],
)
def test_out_of_bounds_parameters_are_refused(change, message):
    values = {k: float(v) for k, v in OPT.to_dict().items()}
    with pytest.raises(ValueError, match=message):
        DoorParameters.from_dict({**values, **change})


@pytest.mark.parametrize("v_max", [0.0, -0.3, 2.0, float("nan")])
def test_bad_speed_is_refused(v_max):
    with pytest.raises(ValueError, match=r"v_max=.*allowed range \[0\.1, 0\.7"):
        ElevatorDoor().simulate(OPT, DoorDamage.healthy(), v_max)


def test_unknown_state_law_and_severity_are_refused():
    with pytest.raises(ValueError, match=r"unknown state 'D3'.*healthy, D1, D2"):
        DoorDamage.for_state("D3")
    with pytest.raises(ValueError, match=r"d1_height=0\.005.*outside"):
        DoorDamage.for_state("D1", d1_height=5e-3)
    with pytest.raises(ValueError, match="index 12 is out of range"):
        get_law(12)
    with pytest.raises(ValueError, match="unknown contact law 'hertz'"):
        get_law("hertz")


def test_the_batched_solve_holds_no_host_callback_so_it_can_be_cached():
    """JAX writes no program with a host callback to its persistent cache; diffrax's checks of
    the save times were such callbacks (equinox's ``error_if``), so every process compiled the
    solves again (bayesdoor._cacheable)."""
    door = ElevatorDoor()
    nominal = {p.name: p.nominal for p in door.parameters}

    def signals(k):
        values = {**nominal, "K": k}
        return door.simulate_values(
            values, jnp.asarray([0.3, 0.4]), duration=0.5, check=False
        ).signals

    text = jax.jit(signals).lower(jnp.asarray([1500.0, 2000.0])).as_text()
    assert "solve_batch" in text  # the solve is inside what was lowered
    assert "callback" not in text


def test_importing_the_door_leaves_the_diagnosis_and_inference_layers_out():
    """Simulating the door needs neither the diagnosis nor the inference layers (arviz, cma):
    its discrepancy catalogue, which does, is read on first use."""
    import subprocess
    import sys

    code = (
        "import sys, bayesdoor.door as d\n"
        "print(sorted(m for m in ('bayesdoor.diagnose', 'bayesdoor.inference', 'arviz', 'cma')"
        " if m in sys.modules))\n"
        "print(d.ElevatorDoor().catalogue is d.DOOR_CATALOGUE, 'bayesdoor.diagnose' in sys.modules)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    ).stdout.split("\n")
    assert out[0] == "[]"
    assert out[1] == "True True"


def test_a_failed_solve_has_zero_signals_and_a_finite_gradient():
    """A solve stopped by max_steps leaves non-finite states behind its last step; the sensor
    outputs read them as zero, so neither the signals nor their gradient holds a NaN (a
    likelihood masks the failed run and must still differentiate)."""
    config = SolverConfig(dt=1.0 / 4096, max_steps=40)
    ts = sample_times(0.05)

    def energy(k):
        p = DoorParameters(**{**OPT.to_dict(), "K": k})
        signals, status = solve(make_args(p, CASES["D2"], 0.45), ts, config)
        return jnp.sum(signals**2), status

    (value, status), grad = jax.jit(jax.value_and_grad(energy, has_aux=True))(
        jnp.asarray(float(OPT.K))
    )
    assert int(status) == 1
    assert float(value) == 0.0 and np.isfinite(float(grad))
