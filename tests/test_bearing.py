"""The CWRU drive-end bearing model: geometry, the interface, fault signatures, jit/vmap/grad."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bayesdoor.bearing import (
    CWRU_DRIVE_END,
    CWRU_FAN_END,
    BearingGeometry,
    BearingSystem,
    envelope_spectrum,
)
from bayesdoor.bearing._envelope import line_strength
from bayesdoor.systems import AbstractSystem, get_system

RPM = 1797.0
OPERATING = [RPM, 0.0]


@pytest.fixture(scope="module")
def system():
    return BearingSystem()


@pytest.fixture(scope="module")
def signals(system):
    """One run of each state at 1797 rpm and 0 hp, nominal parameters, 0.007 in faults."""
    out = {}
    for state in ("healthy", "outer_race", "inner_race", "ball"):
        severity = None if state == "healthy" else {"fault_size_in": 0.007}
        result = system.simulate_values(system.nominal(), OPERATING, state=state, severity=severity)
        assert result.signals.shape == (1, 1, 12000)
        assert int(result.status[0]) == 0
        out[state] = np.asarray(result.signals[0, 0])
    return out


def test_fault_orders_match_the_cwru_table():
    orders = CWRU_DRIVE_END.orders()
    expected = {"bpfi": 5.4152, "bpfo": 3.5848, "ftf": 0.39828, "bsf": 2.357}
    for name, value in expected.items():
        assert abs(orders[name] - value) < 1e-3, (name, orders[name])
    assert CWRU_DRIVE_END.impulse_order("ball") == pytest.approx(2 * orders["bsf"])
    hz = CWRU_DRIVE_END.fault_frequencies(RPM / 60)
    assert hz["bpfo"] == pytest.approx(3.5848 * RPM / 60, rel=1e-4)
    # rolling without slip: the surface speed is the cage speed at the outer contact
    d, big_d = 0.3126 * 0.0254, 1.537 * 0.0254
    expected_speed = np.pi * (big_d**2 - d**2) / (2 * big_d)
    assert CWRU_DRIVE_END.surface_speed_per_hz() == pytest.approx(expected_speed)


def test_geometry_rejects_impossible_bearings():
    with pytest.raises(ValueError, match="smaller than the pitch diameter"):
        BearingGeometry(ball_diameter_in=2.0, pitch_diameter_in=1.5)


def test_the_registry_returns_the_bearing(system):
    found = get_system("bearing")
    assert isinstance(found, AbstractSystem)
    assert found == system


def test_interface(system):
    assert system.name == "bearing"
    assert system.channels == ("DE",)
    assert system.sampling_rate_hz == 12000.0
    assert 6 <= len(system.parameters) <= 10
    for p in system.parameters:
        p.check(p.nominal)
        assert p.unit and p.description
    assert set(system.states) == {"healthy", "inner_race", "outer_race", "ball"}
    for name, spec in system.states.items():
        if name == "healthy":
            assert dict(spec.severity) == {}
        else:
            assert spec.severity["fault_size_in"] == (0.005, 0.025)
            # what acts on fault runs only is the fault's own, drawn per run, not fitted
            assert set(spec.severity) == {
                "fault_size_in",
                "impulse_amplitude",
                "slip",
                "unbalance_ratio",
            }
            assert not set(spec.severity) & set(system.parameter_names())
    assert system.condition_names() == ("shaft_speed", "load_hp")
    assert system.conditions[1].positive is False
    op = np.array([[1797.0, 0.0], [1772.0, 1.0], [1750.0, 2.0]])
    system.check_operating(op)
    assert system.record_duration(op) == 1.0
    start, stop = system.motion_window(op)
    np.testing.assert_array_equal(start, 0.0)
    np.testing.assert_allclose(stop, 11999 / 12000)
    assert system.motion_window(op, duration=0.5)[1][0] == pytest.approx(5999 / 12000)
    json.dumps(system.describe())


def test_features_cover_the_resonance_region(system):
    from bayesdoor.features import CNNInputSpec
    from bayesdoor.inference import FeatureSpec

    spec = FeatureSpec.of(system)
    fs = system.sampling_rate_hz
    # 100 Hz bands of four 25 Hz bins, 1.5-5.4 kHz: above the healthy record's lines near
    # 1 kHz, below the anti-alias roll-off, over both resonances' ranges where they overlap it
    assert spec.bins_per_band(fs) == 4
    edges = spec.band_edges(fs)
    assert len(edges) - 1 == 39
    assert edges[0] == pytest.approx(1487.5) and edges[-1] == pytest.approx(5387.5)
    ranges = {p.name: (p.lower, p.upper) for p in system.parameters}
    assert edges[0] < ranges["resonance_1_hz"][0] and edges[-1] > ranges["resonance_2_hz"][0]
    classifier = CNNInputSpec(
        fmax=system.features.classifier_fmax,
        nperseg=system.features.classifier_nperseg,
        envelope_band=system.features.classifier_envelope_band,
    )
    freqs = classifier.frequencies(fs)
    assert len(freqs) == 205 and freqs[-1] <= 600.0
    # the third harmonic of the fastest fault line at the fastest training speed is kept
    assert 3 * system.fault_frequencies(1800.0)["bpfi"] < freqs[-1]
    # the bins resolve the fault lines: BPFO, 2 BSF and BPFI lie more than a bin apart
    hz = system.fault_frequencies(RPM)
    lines = sorted([hz["bpfo"], 2 * hz["bsf"], hz["bpfi"]])
    assert np.min(np.diff(lines)) > freqs[1] - freqs[0]


def test_bad_inputs_raise(system):
    values = system.nominal()
    with pytest.raises(ValueError, match="unknown state"):
        system.simulate_values(values, OPERATING, state="cage")
    with pytest.raises(ValueError, match="missing"):
        system.simulate_values({k: v for k, v in values.items() if k != "damping_1"}, OPERATING)
    with pytest.raises(ValueError, match="damping_1"):
        system.simulate_values({**values, "damping_1": 0.5}, OPERATING)
    with pytest.raises(ValueError, match="slip"):
        system.simulate_values(values, OPERATING, state="inner_race", severity={"slip": 0.5})
    with pytest.raises(ValueError, match="shape"):
        system.simulate_values(values, [1797.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="shaft_speed"):
        system.simulate_values(values, [[3000.0, 0.0]])
    with pytest.raises(ValueError, match="fault_size_in"):
        system.simulate_values(values, OPERATING, state="ball", severity={"fault_size_in": 0.1})
    with pytest.raises(ValueError, match="unknown severity"):
        system.simulate_values(values, OPERATING, severity={"fault_size_in": 0.01})


def _strength(x, target):
    f, a = envelope_spectrum(x, 12000.0)
    return line_strength(f, a, target, tolerance=0.02)


def test_envelope_spectrum_peaks_at_the_fault_frequency(system, signals):
    hz = system.fault_frequencies(RPM)
    targets = {"outer_race": hz["bpfo"], "inner_race": hz["bpfi"]}
    for state, target in targets.items():
        f, a = envelope_spectrum(signals[state], 12000.0)
        band = (f > 50) & (f < 400)
        peak = f[band][np.argmax(a[band])]
        assert abs(peak - target) <= 2.0, (state, peak, target)
        assert _strength(signals[state], target)[1] > 10, state
    # a ball's strikes on the two races: twice the spin frequency
    assert _strength(signals["ball"], 2 * hz["bsf"])[1] > 5
    for target in (hz["bpfo"], hz["bpfi"], 2 * hz["bsf"]):
        assert _strength(signals["healthy"], target)[1] < 4, target


def test_a_rotating_load_modulates_the_outer_race_strikes_at_the_shaft_speed(system):
    """A stationary outer-race defect is struck at BPFO; an unbalance turning with the shaft
    modulates the strikes at 1x: lines at 1x and BPFO +- 1x that the static load lacks."""
    hz = system.fault_frequencies(RPM)
    shaft = RPM / 60.0
    strength = {}
    for ratio in (0.0, 0.5):
        x = system.simulate_values(
            system.nominal(),
            OPERATING,
            state="outer_race",
            severity={"fault_size_in": 0.014, "unbalance_ratio": ratio},
        ).signals[0, 0]
        strength[ratio] = [
            _strength(np.asarray(x), f)[1] for f in (shaft, hz["bpfo"] - shaft, hz["bpfo"] + shaft)
        ]
        assert _strength(np.asarray(x), hz["bpfo"])[1] > 10, ratio
    assert max(strength[0.0]) < 4, strength
    assert min(strength[0.5]) > 4, strength


def test_signal_levels(signals):
    rms = {k: float(np.std(v)) for k, v in signals.items()}
    assert 0.05 < rms["healthy"] < 1.0
    for state in ("outer_race", "inner_race", "ball"):
        assert rms[state] > 2 * rms["healthy"], rms


def test_the_same_inputs_give_the_same_signal_and_size_raises_the_amplitude(system, signals):
    again = system.simulate_values(
        system.nominal(), OPERATING, state="outer_race", severity={"fault_size_in": 0.007}
    )
    np.testing.assert_array_equal(np.asarray(again.signals[0, 0]), signals["outer_race"])
    big = system.simulate_values(
        system.nominal(), OPERATING, state="outer_race", severity={"fault_size_in": 0.021}
    )
    assert np.std(np.asarray(big.signals)) > 2 * np.std(signals["outer_race"])


def test_batches_vmap_jit_and_grad(system):
    values = system.nominal()
    amplitudes = jnp.array([10.0, 20.0, 40.0])
    op = jnp.array([[1797.0, 0.0], [1772.0, 1.0], [1750.0, 2.0]])

    @jax.jit
    def rms(amplitude, f1):
        vals = {**values, "resonance_1_hz": f1}
        result = system.simulate_values(
            vals,
            op,
            state="outer_race",
            severity={"fault_size_in": 0.014, "impulse_amplitude": amplitude},
            duration=0.25,
            check=False,
        )
        return jnp.sqrt(jnp.mean(result.signals**2, axis=(1, 2))), result.status

    levels, status = rms(amplitudes, jnp.full(3, 3200.0))
    assert levels.shape == (3,) and np.all(np.asarray(status) == 0)
    assert levels[0] < levels[1] < levels[2]
    grad = jax.grad(lambda a, f: rms(a, f)[0].sum(), argnums=(0, 1))(
        amplitudes, jnp.full(3, 3200.0)
    )
    for g in grad:
        assert np.all(np.isfinite(np.asarray(g)))
    assert np.all(np.asarray(grad[0]) > 0)


def _ringing_train(rate_hz, rng, *, fs=12000.0, n=12000, amplitude=3.0):
    """White noise plus, for ``rate_hz``, impulses at that rate ringing a 3 kHz mode."""
    x = rng.standard_normal(n)
    if rate_hz is None:
        return x
    t = np.arange(200) / fs
    ring = np.exp(-300 * t) * np.sin(2 * np.pi * 3000 * t)
    train = np.zeros(n)
    times = np.cumsum(
        np.full(int(n / fs * rate_hz) + 2, 1 / rate_hz)
        * (1 + 0.01 * rng.standard_normal(int(n / fs * rate_hz) + 2))
    )
    train[(times[times < n / fs] * fs).astype(int)] = amplitude
    return x + np.convolve(train, ring)[:n] * 5


def test_envelope_rule_names_the_family_and_keeps_its_false_alarm_rate():
    from bayesdoor.bearing import EnvelopeRule

    rng = np.random.default_rng(0)
    rpm = 1797.0
    hz = CWRU_DRIVE_END.fault_frequencies(rpm / 60)
    healthy = np.stack([_ringing_train(None, rng) for _ in range(30)])
    rule = EnvelopeRule.from_healthy(healthy, 12000.0, np.full(30, rpm), false_alarm_rate=0.05)
    # the t prediction bound of 30 segments at 1 - 0.05 / 3, one-sided
    assert rule.z_threshold == pytest.approx(2.2343 * np.sqrt(1 + 1 / 30), abs=1e-3)
    calls = [rule.classify(_ringing_train(None, rng), 12000.0, rpm) for _ in range(100)]
    # 5 false alarms expected of 100; more than 12 has a binomial probability of 0.15 %
    assert 100 - calls.count("healthy") <= 12
    for state, line in (("outer_race", "bpfo"), ("inner_race", "bpfi"), ("ball", "bsf")):
        rate = hz[line] * (2 if state == "ball" else 1)  # a ball strikes at 2 BSF
        assert rule.classify(_ringing_train(rate, rng), 12000.0, rpm) == state
    with pytest.raises(ValueError, match="false_alarm_rate"):
        EnvelopeRule.from_healthy(healthy, 12000.0, rpm, false_alarm_rate=1.5)


def test_signature_check_agrees_with_the_family_shown_and_round_trips(system):
    from bayesdoor.bearing import EnvelopeRule

    rng = np.random.default_rng(1)
    rpm = 1797.0
    hz = CWRU_DRIVE_END.fault_frequencies(rpm / 60)
    healthy = np.stack([_ringing_train(None, rng) for _ in range(30)])
    reference = system.signature_reference(healthy[:, None, :], np.full((30, 2), [rpm, 0.0]))
    rule = EnvelopeRule.from_json(json.loads(json.dumps(reference)))
    assert rule == EnvelopeRule.from_healthy(
        healthy, 12000.0, np.full(30, rpm), false_alarm_rate=0.01
    )
    # one family's prediction bound lies below the three families' Bonferroni bound
    assert rule.family_threshold < rule.z_threshold
    inner = _ringing_train(hz["bpfi"], rng)
    quiet = _ringing_train(None, rng)
    signals = np.stack([inner, quiet])[:, None, :]
    rows = system.signatures(reference, signals, np.array([[rpm, 0.0], [rpm, 0.0]]))
    assert rows[0]["inner_race"] and not rows[0]["healthy"]
    assert rows[1]["healthy"] and not any(rows[1][k] for k in ("inner_race", "outer_race", "ball"))
    # a segment without a family's lines shows it with about the stated rate: at most 5 of 100
    # (1 expected; more than 5 has a binomial probability of 0.06 %)
    shown = [
        system.signatures(reference, _ringing_train(None, rng)[None, None, :], [[rpm, 0.0]])[0]
        for _ in range(100)
    ]
    assert sum(r["outer_race"] for r in shown) <= 5
    assert sum(not r["healthy"] for r in shown) <= 5
    with pytest.raises(ValueError, match="unknown keys"):
        EnvelopeRule.from_json(reference | {"threshold": 1.0})
    # two healthy runs are too few for a prediction bound: no check, rather than a failed job
    assert system.signature_reference(healthy[:2, None, :], np.full((2, 2), [rpm, 0.0])) is None


def test_training_points_span_the_speeds_and_loads_and_keep_the_campaigns(system):
    measured = np.array([[1796.0, 0.0], [1772.0, 1.0]])
    points = system.training_points(measured)
    assert {tuple(p) for p in measured} <= {tuple(p) for p in points}
    assert points[:, 0].min() == 1700.0 and points[:, 0].max() == 1800.0
    assert points[:, 1].min() == 0.0 and points[:, 1].max() == 3.0
    assert len(points) == len({tuple(p) for p in points}) == 2 + 3 * 2
    system.check_operating(points)


def test_another_geometry_and_rate_travel_with_a_campaign():
    from bayesdoor.bearing._system import FEATURES
    from bayesdoor.io import make_campaign, system_of

    # the CWRU fan-end bearing at 48 kHz, its orders those of the Data Center's table
    geometry = CWRU_FAN_END
    orders = geometry.orders()
    np.testing.assert_allclose(
        [orders["bpfi"], orders["bpfo"], orders["ftf"], 2 * orders["bsf"]],
        [4.9469, 3.0530, 0.3817, 3.9874],
        atol=3e-4,  # the table's figures lie within 3 units of their last digit of the formula
    )
    system = BearingSystem(geometry=geometry, sampling_rate_hz=48000.0)
    assert BearingSystem().with_settings(json.loads(json.dumps(system.settings()))) == system
    ds = make_campaign(
        np.zeros((1, 1, 48000)),
        channels=["DE"],
        fs=48000.0,
        state=["healthy"],
        system="bearing",
        shaft_speed=[1797.0],
        load_hp=[0.0],
    )
    assert system_of(ds) == BearingSystem()
    ds.attrs["system_settings"] = json.dumps(system.settings())
    assert system_of(ds) == system
    # the same bin widths at four times the rate: Welch segments of the same duration
    assert system.features.nperseg == 4 * FEATURES.nperseg
    assert system.features.classifier_nperseg == 4 * FEATURES.classifier_nperseg
    assert system.describe()["sampling_rate_hz"] == 48000.0
    with pytest.raises(ValueError, match=r"sampling_rate_hz=8000.0: .* must exceed 11600 Hz"):
        BearingSystem(sampling_rate_hz=8000.0)
    with pytest.raises(ValueError, match=r"unknown settings \['speed'\] of bearing"):
        system.with_settings({"speed": 1.0})


def test_the_envelope_rule_reads_the_lines_of_its_bearing():
    from bayesdoor.bearing import EnvelopeRule

    geometry = CWRU_FAN_END
    system = BearingSystem(geometry=geometry)
    healthy = system.simulate_values(system.nominal(), np.tile(OPERATING, (4, 1))).signals
    faulty = system.simulate_values(
        system.nominal(),
        np.tile(OPERATING, (3, 1)),
        state="outer_race",
        severity={"fault_size_in": 0.014, "impulse_amplitude": 60.0},
    ).signals
    reference = system.signature_reference(healthy, np.tile(OPERATING, (4, 1)))
    assert EnvelopeRule.from_json(json.loads(json.dumps(reference))).geometry == geometry
    calls = system.signatures(reference, faulty, np.tile(OPERATING, (3, 1)))
    assert [c["outer_race"] for c in calls] == [True] * 3
    # the same runs read at the CWRU drive end's frequencies show no outer-race lines
    cwru = BearingSystem().signatures(
        BearingSystem().signature_reference(healthy, np.tile(OPERATING, (4, 1))),
        faulty,
        np.tile(OPERATING, (3, 1)),
    )
    assert [c["outer_race"] for c in cwru] == [False] * 3
