"""The bearing's catalogue of discrepancy causes: its extensions, and the generic diagnosis on
bearing simulations with one cause hidden (or none).

A hidden-cause campaign: 8 healthy runs of 1 s at 1600-1900 rpm (18.75 % apart, so a tone
that follows the shaft can be told from one that does not), simulated by the bearing with
another seed than the model's (other draws of the background and noise, as a measurement
has) and with the cause's extension switched on at a stated size. The diagnosis runs under a
point "fit" at the simulating parameters, so the hidden cause is the only discrepancy.
"""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bayesdoor.bearing import (
    BEARING_CATALOGUE,
    BearingSystem,
    LineFrequency,
    ShaftHarmonics,
    StructuralMode,
)
from bayesdoor.diagnose import DiagnosisSettings, ListedFrequency, diagnose_campaign
from bayesdoor.diagnose._held_out import held_out_folds
from bayesdoor.diagnose._refit import tile_runs
from bayesdoor.io import make_campaign

FS = 12000.0
RUNS = 8
RPM = np.linspace(1600.0, 1900.0, RUNS)
OPERATING = np.stack([RPM, np.zeros(RUNS)], axis=1)
SETTINGS = DiagnosisSettings(predictive_draws=4, max_candidates=3, refit_evals=96, limits=False)

#: the hidden causes and their sizes: the 1x line raised by 0.3 m/s^2 (the base model's is
#: 0.05) and a 4x line of 0.1 m/s^2; 60 Hz and 120 Hz lines of 0.03 m/s^2 (the real healthy
#: record's 1x line is 0.028 m/s^2); a mode at 800 Hz, damping ratio 0.002 (half-power width
#: 3.2 Hz, under the residual map's 31-bin smooth discrepancy) and gain 30 (+30 dB)
HIDDEN = {
    "shaft_harmonics": (
        ShaftHarmonics(harmonics=4),
        {"shaft_harmonics.amplitude_1": 0.3, "shaft_harmonics.amplitude_4": 0.1},
    ),
    "line_frequency": (
        LineFrequency(frequency_hz=60.0),
        {"line_frequency.amplitude_1": 0.03, "line_frequency.amplitude_2": 0.03},
    ),
    "structural_mode": (
        StructuralMode(),
        {
            "structural_mode.frequency_hz": 800.0,
            "structural_mode.damping_ratio": 0.002,
            "structural_mode.gain": 30.0,
        },
    ),
}


def _psd(x):
    return np.abs(np.fft.rfft(np.asarray(x), axis=-1)) ** 2


def _bin(hz, n=12000):
    return round(hz * n / FS)


def test_extensions_are_inert_at_nominal_and_carry_their_parameters():
    base = BearingSystem()
    extended = base.with_extensions("shaft_harmonics", "structural_mode", "line_frequency")
    assert extended.extension_names == ("shaft_harmonics", "structural_mode", "line_frequency")
    assert extended.catalogue is BEARING_CATALOGUE
    specs = {p.name: p for p in extended.parameters}
    assert specs["structural_mode.frequency_hz"].unit == "Hz"
    amplitude = specs["line_frequency.amplitude_2"]
    assert (amplitude.lower, amplitude.upper) == (0.0, 2.0)
    assert specs["shaft_harmonics.amplitude_1"].unit == "m/s^2"
    x0 = base.simulate_values(base.nominal(), OPERATING[:2]).signals
    x1 = extended.simulate_values(extended.nominal(), OPERATING[:2]).signals
    np.testing.assert_array_equal(np.asarray(x0), np.asarray(x1))
    assert [e["name"] for e in extended.describe()["extensions"]] == list(extended.extension_names)
    with pytest.raises(ValueError, match="at most one"):
        extended.with_extensions("shaft_harmonics")
    with pytest.raises(ValueError, match="'none' is the base model"):
        base.with_extensions("none")


def test_a_shaft_line_follows_the_speed_and_a_supply_line_does_not():
    base = BearingSystem()
    shaft = base.with_extensions(ShaftHarmonics(harmonics=5))
    supply = base.with_extensions(LineFrequency(frequency_hz=50.0, harmonics=2))
    op = OPERATING[[0, -1]]
    x0 = _psd(base.simulate_values(base.nominal(), op).signals[:, 0])
    v = {**shaft.nominal(), "shaft_harmonics.amplitude_5": 0.2}
    xs = _psd(shaft.simulate_values(v, op).signals[:, 0])
    w = {**supply.nominal(), "line_frequency.amplitude_2": 0.2}
    xl = _psd(supply.simulate_values(w, op).signals[:, 0])
    for r, rpm in enumerate(RPM[[0, -1]]):
        k5 = _bin(5 * rpm / 60.0)
        assert np.argmax(xs[r] - x0[r]) in (k5 - 1, k5, k5 + 1)
        assert np.argmax(xl[r] - x0[r]) == _bin(100.0)


def test_a_mode_raises_the_spectrum_by_one_plus_its_gain_squared_at_its_frequency():
    base = BearingSystem()
    mode = base.with_extensions("structural_mode")
    v = {
        **mode.nominal(),
        "structural_mode.frequency_hz": 1200.0,
        "structural_mode.damping_ratio": 0.01,
        "structural_mode.gain": 3.0,
    }
    x0 = _psd(base.simulate_values(base.nominal(), OPERATING[:1]).signals[0, 0])
    x1 = _psd(mode.simulate_values(v, OPERATING[:1]).signals[0, 0])
    ratio = x1 / x0
    assert ratio[_bin(1200.0)] == pytest.approx(16.0, rel=1e-6)
    # far from the mode (30 half-power widths) the signal is nearly unchanged
    assert np.all(np.abs(10 * np.log10(ratio[_bin(2000.0) : _bin(3000.0)])) < 0.5)


def test_the_extensions_are_differentiable_in_their_parameters():
    system = BearingSystem().with_extensions(
        ShaftHarmonics(harmonics=4), "structural_mode", "line_frequency"
    )
    values = {
        **system.nominal(),
        "shaft_harmonics.amplitude_4": 0.1,
        "structural_mode.gain": 2.0,
        "line_frequency.amplitude_1": 0.05,
    }
    names = [
        "shaft_harmonics.amplitude_4",
        "structural_mode.frequency_hz",
        "structural_mode.damping_ratio",
        "structural_mode.gain",
        "line_frequency.amplitude_1",
    ]

    def power(x):
        v = {**values, **dict(zip(names, x, strict=True))}
        s = system.simulate_values(v, OPERATING[:1], check=False).signals
        return jnp.mean(s**2)

    grad = jax.grad(power)(jnp.array([values[n] for n in names]))
    assert np.all(np.isfinite(np.asarray(grad)))
    assert np.all(np.asarray(grad)[[0, 3, 4]] > 0)


def test_the_catalogue_declares_its_causes_band_and_speed():
    assert BEARING_CATALOGUE.names == (
        "shaft_harmonics",
        "structural_mode",
        "line_frequency",
        "none",
    )
    assert BEARING_CATALOGUE.band[0] < 30.0 and BEARING_CATALOGUE.band[1] <= 5400.0
    np.testing.assert_allclose(BEARING_CATALOGUE.speeds(OPERATING), RPM / 60.0)
    line = next(c for c in BEARING_CATALOGUE.candidates if c.name == "line_frequency")
    assert isinstance(line.signature, ListedFrequency)
    shaft = next(c for c in BEARING_CATALOGUE.candidates if c.name == "shaft_harmonics")
    proposals = shaft.refit.propose({"labels_found": (1, 4)}, band=(10.0, 5375.0))
    assert proposals[0].extension == ShaftHarmonics(harmonics=4)
    assert proposals[0].free == ("shaft_harmonics.amplitude_1", "shaft_harmonics.amplitude_4")
    # lines in deficit and in excess: each kind alone, and both
    mixed = shaft.refit.propose(
        {"labels_found": (1, 2, 5), "deficits": (1, 2)}, band=(10.0, 5375.0)
    )
    assert [p.free for p in mixed] == [
        ("shaft_harmonics.amplitude_1", "shaft_harmonics.amplitude_2"),
        ("shaft_harmonics.amplitude_5",),
        tuple(f"shaft_harmonics.amplitude_{k}" for k in (1, 2, 5)),
    ]
    assert mixed[0].start["shaft_harmonics.amplitude_1"] < 0
    # every cause declares its size, for its detection limit
    for candidate in BEARING_CATALOGUE.candidates:
        if candidate.refit is not None:
            assert candidate.refit.size(band=BEARING_CATALOGUE.band).probes


def test_folds_and_batches_take_several_operating_conditions():
    op = np.array([[1800.0, 0.0], [1700.0, 3.0], [1750.0, 1.0], [1700.0, 0.0]])
    folds = held_out_folds(op, 2)
    # sorted by speed, then load: 1700/0, 1700/3, 1750/1, 1800/0 dealt alternately
    assert [list(test) for _, test in folds] == [[2, 3], [0, 1]]
    assert tile_runs(op, 3).shape == (12, 2)
    np.testing.assert_array_equal(tile_runs(op, 2)[4:], op)
    assert tile_runs(RPM, 2).shape == (2 * RUNS,)


def _campaign(cause: str | None, seed: int):
    truth = BearingSystem(seed=seed)
    values = truth.nominal()
    if cause is not None:
        ext, hidden = HIDDEN[cause]
        truth = truth.with_extensions(ext)
        values = {**truth.nominal(), **hidden}
    x = np.asarray(truth.simulate_values(values, OPERATING).signals)
    n = x.shape[-1]
    return make_campaign(
        x,
        channels=["DE"],
        fs=FS,
        state=["healthy"] * RUNS,
        system="bearing",
        split=["calibration"] * RUNS,
        t_start=np.zeros(RUNS),
        t_stop=np.full(RUNS, (n - 1) / FS),
        shaft_speed=RPM,
        load_hp=np.zeros(RUNS),
    )


def _point_fit(system: BearingSystem):
    """The base model at the simulating parameters, as a CMA-ES point (one draw)."""
    point = system.nominal()
    return SimpleNamespace(
        point=point,
        names=tuple(point),
        bounds=(
            np.array([p.lower for p in system.parameters]),
            np.array([p.upper for p in system.parameters]),
        ),
        posterior_draws=lambda: {k: np.array([v]) for k, v in point.items()},
    )


def _diagnose(cause: str | None, seed: int):
    system = BearingSystem()
    return diagnose_campaign(
        system, _campaign(cause, seed), fit=_point_fit(system), progress=False, settings=SETTINGS
    )


def test_nothing_hidden_answers_none():
    diagnosis = _diagnose(None, seed=7)
    assert diagnosis.verdict == "none"
    assert not diagnosis.confirmed


@pytest.mark.long
@pytest.mark.parametrize("seed", [11, 12])
def test_nothing_hidden_answers_none_at_other_seeds(seed):
    assert _diagnose(None, seed=seed).verdict == "none"


@pytest.mark.long
@pytest.mark.parametrize("cause", ["line_frequency", "shaft_harmonics"])
def test_a_hidden_cause_is_named(cause):
    diagnosis = _diagnose(cause, seed=7)
    assert diagnosis.verdict == cause, [(c.name, c.evidence) for c in diagnosis.causes]
    named = diagnosis.cause(cause)
    assert named.gain is not None and named.gain.decisive
    if cause == "line_frequency":
        assert named.parameters["frequency_hz"] == 60.0
    else:
        assert named.parameters["labels_found"] == (1, 4)


@pytest.mark.long
def test_a_hidden_mode_is_located_but_not_confirmed():
    """The mode's feature is found and its refit lands on its frequency, but the held-out
    gain stays under the rule (2.7 SE at gain 30, 3.2 at gain 10: docs/bearing.md): the
    verdict is ``none``, a known limit, not a false alarm."""
    diagnosis = _diagnose("structural_mode", seed=7)
    top = diagnosis.ranking.causes[0]
    assert top.name == "structural_mode" and top.score == 1.0
    mode = diagnosis.cause("structural_mode")
    assert mode.gain is not None
    assert mode.parameters["structural_mode.frequency_hz"]["mean"] == pytest.approx(800.0, abs=2.0)
    assert diagnosis.verdict in ("none", "structural_mode")
