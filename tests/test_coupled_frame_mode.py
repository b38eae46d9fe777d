"""A frame mode that carries the rail (``CoupledFrameMode``): inert when off, its own equation
exact when uncoupled, a conservative coupling through the wheel contact, and a refit that
profiles its participations exactly."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bayesdoor.diagnose import ExtensionProposal
from bayesdoor.diagnose._refit import RefitSetup, Spectra, refit_extension
from bayesdoor.door import (
    CHANNELS,
    STATE_SIZE,
    CoupledFrameMode,
    DoorDamage,
    DoorParameters,
    ElevatorDoor,
    SolverConfig,
    contact_kinematics,
    initial_state,
    make_args,
    rhs,
    solve,
    state_size,
)

OPT = {k: float(v) for k, v in DoorParameters.paper_optimum().to_dict().items()}
SPEEDS = (0.3, 0.5)
P = "frame_mode."
MODAL_MASS = 20.0


def _mode_values(door, **changes):
    return {**door.nominal(), **{P + k: v for k, v in changes.items()}}


def _args(**changes):
    door = ElevatorDoor(extensions=(CoupledFrameMode(),))
    values = _mode_values(door, **changes)
    ext = {k: v for k, v in values.items() if k.startswith(P)}
    return make_args(
        DoorParameters.paper_optimum(),
        DoorDamage.healthy(),
        0.4,
        extensions=door.extensions,
        extension_values=ext,
    )


def test_the_state_grows_by_the_mode_and_its_velocity():
    args = _args()
    assert state_size(args) == STATE_SIZE + 2
    assert initial_state(args).shape == (STATE_SIZE + 2,)
    with pytest.raises(ValueError, match="coupling"):
        CoupledFrameMode(coupling="channels")
    assert ElevatorDoor().with_extensions(CoupledFrameMode()).describe()["extensions"][0][
        "config"
    ] == {"coupling": "wheel_contact"}


def test_without_lift_the_mode_rings_as_a_damped_oscillator():
    """Displaced by 0.1 mm with no lift, the mode is a free damped oscillator:
    p(t) = p0 exp(-zeta w t) (cos w_d t + zeta / sqrt(1 - zeta^2) sin w_d t). The door rests
    (its motion starts at 0.25 s); the state is integrated with rtol 1e-8, so 1e-6 of p0."""
    f0, zeta, p0 = 60.0, 0.02, 1e-4
    args = _args(frequency_hz=f0, damping_ratio=zeta)
    y0 = initial_state(args).at[STATE_SIZE].set(p0)
    ts = jnp.arange(400.0) / 2048.0
    states, status = solve(args, ts, SolverConfig(rtol=1e-8, atol=1e-12), "states", y0=y0)
    assert int(status) == 0
    w = 2 * np.pi * f0
    wd = w * np.sqrt(1 - zeta**2)
    t = np.asarray(ts)
    exact = (
        p0 * np.exp(-zeta * w * t) * (np.cos(wd * t) + zeta / np.sqrt(1 - zeta**2) * np.sin(wd * t))
    )
    np.testing.assert_allclose(np.asarray(states)[STATE_SIZE], exact, rtol=0, atol=1e-6 * p0)


@pytest.mark.long
def test_the_coupling_through_the_wheels_is_conservative_and_as_calculated():
    """At rest the stiffness between the panel's height y and the mode p is one symmetric
    coupling (a potential exists: the contact's spring energy of the gap lambda p - y):
    K = -M d(acceleration)/d(position) has K_yp = K_py = -lambda (k_L + k_R), with each
    wheel's linearised contact stiffness k = n K d^(n-1) at its static indentation d (read
    from the gaps, as a hand calculation would). 1e-6: the Jacobian is exact (forward mode);
    the hand value uses the smoothed gaps, which equal the true indentation to 1e-8 m."""
    lift = 0.15
    args = _args(frequency_hz=45.0, rail_lift=lift)
    y = initial_state(args)
    jac = np.asarray(jax.jacfwd(lambda s: rhs(0.0, s, args))(y))
    n_dof = 7
    iy, ip = 1, STATE_SIZE  # the panel's height and the mode among the positions
    acc_y, acc_p = n_dof + iy, STATE_SIZE + 1  # rows of their accelerations
    mass = float(args.mass)
    k_yp = -mass * jac[acc_y, ip]
    k_py = -MODAL_MASS * jac[acc_p, iy]
    gaps = np.asarray(contact_kinematics(y[:n_dof], args)[0])[:2]
    n, k_si = float(args.n), float(args.k_contact)
    k_wheels = n * k_si * gaps ** (n - 1.0)
    assert k_yp == pytest.approx(k_py, rel=1e-6)
    assert k_yp == pytest.approx(-lift * k_wheels.sum(), rel=1e-4)


@pytest.fixture(scope="module")
def refit_case():
    """Two runs of the door with a rail-carrying mode (45 Hz, lift 0.15, participations
    0.3, 0, 0.6, -0.2) and the same two runs with the mode at its nominal values (off), in
    one solve; the base door's runs."""
    door = ElevatorDoor()
    extended = door.with_extensions(CoupledFrameMode())
    truth = {
        "frequency_hz": 45.0,
        "damping_ratio": 0.02,
        "rail_lift": 0.15,
        **{f"participation_{c}": s for c, s in zip(CHANNELS, (0.3, 0.0, 0.6, -0.2), strict=True)},
    }
    on, off = _mode_values(extended, **truth), extended.nominal()
    rows = [{**on, **OPT}, {**off, **OPT}]
    values = {k: np.repeat([r[k] for r in rows], len(SPEEDS)) for k in rows[0]}
    made = extended.simulate_values(values, np.tile(SPEEDS, 2), duration=2.0)
    assert np.all(np.asarray(made.status) == 0)
    base = door.simulate_values(OPT, np.array(SPEEDS), duration=2.0)
    signals = np.asarray(made.signals).reshape(2, len(SPEEDS), 4, -1)
    return signals, base, truth


def test_at_nominal_values_it_is_the_base_door(refit_case):
    """Zero lift and participations leave the mode undriven and unseen; the larger state is
    another compiled program whose adaptive steps differ (rtol 1e-5), so the signals agree
    to the solver's tolerance, not bit for bit (measured: 4e-5 of the range at 0.4 m/s;
    the tolerance is 1e-4, as for the surface extensions)."""
    signals, base, _ = refit_case
    b = np.asarray(base.signals)
    np.testing.assert_allclose(signals[1], b, rtol=0, atol=1e-4 * np.abs(b).max())
    assert np.abs(signals[0] - b).max() > 0.1 * np.abs(b).max()


def _setup(refit_case):
    signals, base, truth = refit_case
    door = ElevatorDoor()
    fs = door.sampling_rate_hz
    window = (np.array([0.25, 0.25]), np.array([1.9, 1.9]))
    spectra = Spectra.of_measured(signals[0], fs, *window, (4.0, 96.0), nperseg=int(fs))
    setup = RefitSetup(
        system=door,
        point=OPT,
        operating=np.array(SPEEDS),
        duration=2.0,
        time=np.asarray(base.time),
        base_signals=np.asarray(base.signals),
        spectra=spectra,
    )
    return setup, truth


def _participations_proposal():
    """The frequency searched in 42-48 Hz, damping and lift held, the four participations
    profiled as gains; returns (participation name -> channel, the proposal)."""
    parts = {P + f"participation_{c}": c for c in CHANNELS}
    proposal = ExtensionProposal(
        extension=CoupledFrameMode(),
        start={P + "frequency_hz": 44.0, P + "damping_ratio": 0.02, P + "rail_lift": 0.15},
        free=(P + "frequency_hz", *parts),
        bounds={P + "frequency_hz": (42.0, 48.0)},
        gains=parts,
    )
    return parts, proposal


# 22-33 s with an empty JAX cache: in the long tier, to keep the default suite
# within its 10 minutes
@pytest.mark.long
def test_a_refits_solves_split_over_threads_are_those_of_one_batch(refit_case):
    """The final refit solves its population in two threads, each a block of rows (the last
    block padded): the signals and gain signals are those of one batch to the adaptive
    solver's round-off, every row in its place, and the solves counted once."""
    from bayesdoor.diagnose._refit import _boxes, _Model

    setup, _ = _setup(refit_case)
    parts, proposal = _participations_proposal()
    extended, free, _, _, fixed = _boxes(setup.system, proposal)
    x = np.zeros((3, len(free)))
    x[:, 0] = [43.0, 45.0, 47.0]  # three rows: blocks of two, the second padded
    runs = np.array([1])
    out = {}
    for workers in (1, 2):
        model = _Model(setup, proposal, extended, fixed, {}, workers)
        signals, slope = model.solve_gains(model.values(x, len(runs)), runs, list(parts))
        out[workers] = signals, slope, model.solves
    (s1, g1, n1), (s2, g2, n2) = out[1], out[2]
    assert s1.shape == s2.shape == (3, 1, len(CHANNELS), s1.shape[-1]) and n1 == n2 == 3
    for one, split in ((s1, s2), (g1, g2)):
        scale = np.abs(one).max(axis=-1, keepdims=True)
        np.testing.assert_allclose(split, one, rtol=0, atol=1e-6 * scale.max())
    # the rows differ (their modes are at different frequencies), so a shuffled row would show
    assert np.abs(g1[0] - g1[2]).max() > 1e-3 * np.abs(g1).max()


# 22-33 s with an empty JAX cache: in the long tier, to keep the default suite
# within its 10 minutes
@pytest.mark.long
def test_the_refit_profiles_the_participations_exactly(refit_case):
    """Frequency searched (42-48 Hz), damping and lift held, the four participations
    profiled from the three Welch spectra: the made values come back to the search's
    resolution (Brent's 6e-4 Hz; the profile's 2e-4 of its box) from one training run (a
    check of the code, on data the extension itself made, not of the diagnosis)."""
    setup, truth = _setup(refit_case)
    parts, proposal = _participations_proposal()
    result = refit_extension(setup, proposal, np.array([1]), seed=0, max_evals=40)
    assert result.values[P + "frequency_hz"] == pytest.approx(truth["frequency_hz"], abs=0.02)
    for name, channel in parts.items():
        assert result.values[name] == pytest.approx(truth[f"participation_{channel}"], abs=2e-3), (
            name
        )
    np.testing.assert_allclose(result.spectra, setup.spectra.measured, rtol=0, atol=1e-3)
    assert result.solves > 0


# the refit's solves as the test above: in the long tier
@pytest.mark.long
def test_the_refit_simulates_only_the_candidates_its_constraint_admits(refit_case):
    """A constraint that refuses the made mode's frequency (45 Hz): the refit ends among the
    admitted candidates, though the search proposed refused ones too."""
    setup, _ = _setup(refit_case)
    _, proposal = _participations_proposal()
    asked = []

    def below(system, values):
        asked.append(values[P + "frequency_hz"])
        return values[P + "frequency_hz"] <= 44.0

    result = refit_extension(
        setup, dataclasses.replace(proposal, admissible=below), np.array([1]), seed=0, max_evals=40
    )
    assert result.values[P + "frequency_hz"] <= 44.0
    assert asked and max(asked) > 44.0  # the search proposed refused candidates too


def test_a_refit_whose_constraint_admits_nothing_fails(refit_case):
    setup, _ = _setup(refit_case)
    _, proposal = _participations_proposal()
    refused = dataclasses.replace(proposal, admissible=lambda system, values: False)
    with pytest.raises(ValueError, match="constraint"):
        refit_extension(setup, refused, np.array([1]), seed=0, max_evals=8)


def test_gains_must_name_free_parameters_and_channels(refit_case):
    setup, _ = _setup(refit_case)
    proposal = ExtensionProposal(
        extension=CoupledFrameMode(),
        start={},
        free=(P + "frequency_hz", P + "participation_A1X"),
        gains={P + "participation_A1X": "A3X"},
    )
    with pytest.raises(ValueError, match="A3X"):
        refit_extension(setup, proposal, np.array([0, 1]), seed=0, max_evals=8)


# 115 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): three
# solves of the extended door; in the long tier, which CI runs after the default suite
@pytest.mark.long
def test_one_solve_gives_each_gains_signal_as_two_solves_do():
    """The door returns the participations' signals from one solve (the sensors' derivative
    along them); the generic way solves twice, at 0 and at 1. The dynamics do not depend on
    the participations, so both solve the same trajectory: they agree to round-off
    (1e-9 of the signals' range), and the signals at zero gains are the door's own."""
    door = ElevatorDoor(extensions=(CoupledFrameMode(),))
    values = _mode_values(door, frequency_hz=45.0, rail_lift=0.15)
    values = {**values, **OPT}
    gains = tuple(P + f"participation_{c}" for c in CHANNELS)
    result, slope = door.simulate_gains(values, np.array([0.4]), gains, duration=1.0)
    generic, slope2 = super(ElevatorDoor, door).simulate_gains(
        values, np.array([0.4]), gains, duration=1.0
    )
    scale = np.abs(np.asarray(slope2)).max()
    assert scale > 0
    np.testing.assert_allclose(np.asarray(slope), np.asarray(slope2), rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(
        np.asarray(result.signals), np.asarray(generic.signals), rtol=0, atol=1e-12
    )


# 43 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16): the
# extended door's and the virtual rig's linearisations at rest; in the long tier, which CI runs
# after the default suite
@pytest.mark.long
def test_the_installed_frequency_is_the_extended_doors_mode_at_rest_nearest_the_bare_one():
    from bayesdoor.door._catalogue import FrameModeRefit
    from bayesdoor.door.rig import Effects, VirtualRig
    from bayesdoor.door.rig import FrameMode as RigFrameMode

    recipe = FrameModeRefit()
    coupled, output = recipe.propose(
        {"frequency_hz": 60.0, "channels": ("A1X",), "resolution_hz": 1.0}, band=(4, 96)
    )
    door = ElevatorDoor().with_extensions(coupled.extension)
    values = {p.name: p.nominal for p in door.parameters}
    values.update(DoorParameters.paper_optimum().to_dict())
    # without lift the mode is not coupled: its own (damped) frequency
    bare = {**values, "frame_mode.frequency_hz": 40.0, "frame_mode.rail_lift": 0.0}
    got = recipe.derived(coupled, door, bare)["frame_mode.installed_frequency_hz"]
    zeta = values["frame_mode.damping_ratio"]
    assert got == pytest.approx(40.0 * np.sqrt(1.0 - zeta**2), abs=1e-4)
    # the rig's strongly lifted mode of seed 3 (bare 26.4 Hz, lift 0.17): the rig's own
    # linearisation puts it at 23.9 Hz; the reduced door with the same mode within 1 Hz
    truth = RigFrameMode.from_seed(3)
    lifted = {
        **values,
        "frame_mode.frequency_hz": truth.frequency_hz,
        "frame_mode.damping_ratio": truth.damping_ratio,
        "frame_mode.rail_lift": truth.rail_lift,
    }
    got = recipe.derived(coupled, door, lifted)["frame_mode.installed_frequency_hz"]
    rig = VirtualRig(effects=Effects(frame_mode=truth)).rest_state().frequencies_hz
    expected = rig[np.argmin(np.abs(rig - truth.frequency_hz))]
    assert abs(got - truth.frequency_hz) > 1.5  # the lift moves it
    assert got == pytest.approx(expected, abs=1.0)
    # an output mode's peak is its frequency: nothing derived
    assert recipe.derived(output, ElevatorDoor().with_extensions(output.extension), {}) == {}


def test_no_mode_is_proposed_for_a_line_present_at_rest():
    # a resonance decays at rest: a feature with a line at its frequency before the motion
    # (mains hum) gets no frame-mode refit, a feature without one gets both forms
    from bayesdoor.door._catalogue import FrameModeRefit

    parameters = {
        "frequency_hz": 59.8,
        "channels": ("A2X",),
        "resolution_hz": 1.0,
        "line_at_rest": True,
    }
    assert FrameModeRefit().propose(parameters, band=(4.0, 96.0)) == ()
    parameters["line_at_rest"] = False
    assert len(FrameModeRefit().propose(parameters, band=(4.0, 96.0))) == 2


class _RestModes:
    """A stand-in system whose mode at rest lies ``shift`` Hz from the bare frequency."""

    def __init__(self, shift):
        self.shift = shift

    def rest_modes(self, values):
        f = values[P + "frequency_hz"]
        return np.array([5.0, f + self.shift, 200.0]), np.full(3, 0.02)


def test_the_refit_searches_only_modes_that_peak_on_the_feature():
    # a one-bin feature at 74 Hz in 1 Hz bins: a mode makes it when it peaks within the Hann
    # main lobe's two bins either side, 72-76 Hz
    from bayesdoor.door._catalogue import FrameModeRefit

    parameters = {"frequency_hz": 74.0, "channels": ("A1Z",), "band_hz": (74.0, 74.0)}
    parameters["resolution_hz"] = 1.0
    coupled, output = FrameModeRefit().propose(parameters, band=(4.0, 96.0))
    # an output mode peaks at its frequency: its box is the feature's
    assert output.bounds[P + "frequency_hz"] == (72.0, 76.0) and output.admissible is None
    # a rail-carrying mode peaks at its installed frequency, which its lift moves from the bare
    # one its box holds: the search admits only modes installed in the feature
    lo, hi = coupled.bounds[P + "frequency_hz"]
    assert lo <= 70.0 and hi >= 78.0
    bare = {P + "frequency_hz": 70.0}
    assert coupled.admissible(_RestModes(3.4), bare)  # installed at 73.4 Hz
    # installed at 70.95 Hz (a fold of a false alarm on the rig with nothing hidden)
    assert not coupled.admissible(_RestModes(0.95), bare)
    assert not coupled.admissible(_RestModes(6.5), bare)  # 76.5 Hz
    # the refit keeps to it: every candidate it simulates is admitted (see the refit tests)


def test_a_refitted_mode_must_take_away_some_of_its_features_excess():
    from bayesdoor.door._catalogue import FrameModeRefit

    freqs = np.arange(0.0, 101.0)
    parameters = {
        "frequency_hz": 74.0,
        "damping_ratio": 0.0068,
        "channels": ("A1Z",),
        "band_hz": (74.0, 74.0),
        "resolution_hz": 1.0,
    }
    measured = np.zeros((4, 4, freqs.size))
    measured[:, 1, 74] = 1.0
    base = np.zeros_like(measured)
    args = (parameters, freqs, measured, base)
    recipe = FrameModeRefit()
    ok, words, share = recipe.explains(*args, measured * 0.5, tuple(CHANNELS))
    assert ok and "went from 0.333 to 0.0833" in words
    assert share == pytest.approx(0.75)  # the residual halved: its mean square quartered
    worse = recipe.explains(*args, measured * 2.0, tuple(CHANNELS))
    assert not worse.explained and worse.share == pytest.approx(0.0)  # 2x off: as far as base


def test_the_frequency_box_reaches_the_whole_residual_feature():
    # a broad residual feature (significant from 18 to 34 Hz, peak picked at 22 Hz): both
    # forms of the refit may place the mode anywhere in it, not only near 22 Hz
    from bayesdoor.door._catalogue import FRAME_MODE_BAND, FrameModeRefit

    parameters = {
        "frequency_hz": 22.0,
        "channels": ("A2Z",),
        "band_hz": (18.0, 34.0),
        "resolution_hz": 1.0,
    }
    coupled, output = FrameModeRefit().propose(parameters, band=(4.0, 96.0))
    assert output.bounds["frame_mode.frequency_hz"] == (16.0, 36.0)  # and the main lobe
    lo, hi = coupled.bounds["frame_mode.frequency_hz"]  # bare; installed: in 16-36 Hz
    assert lo <= 18.0 and hi >= 34.0
    # no box leaves the catalogue's band
    narrow = {
        "frequency_hz": 11.0,
        "channels": ("A1X",),
        "band_hz": (10.5, 11.5),
        "resolution_hz": 1.0,
    }
    coupled, output = FrameModeRefit().propose(narrow, band=(4.0, 96.0))
    assert output.bounds["frame_mode.frequency_hz"] == (FRAME_MODE_BAND[0], 13.5)
    lo, hi = coupled.bounds["frame_mode.frequency_hz"]
    assert lo == FRAME_MODE_BAND[0] and 14.0 <= hi <= 15.0
