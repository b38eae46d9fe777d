"""fit_campaign: which runs it fits, CMA-ES on rig data against the truth's J, the result files;
slow: posterior recovery of the rig's true values and predictive coverage on held-out runs."""

import json
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _toy_system import DURATION, FS, REST, ToySystem

from bayesdoor.door import ElevatorDoor
from bayesdoor.door.datasets import load_demo_campaign, load_demo_truth
from bayesdoor.door.rig import VirtualRig
from bayesdoor.features import objective_j
from bayesdoor.inference import (
    CalibrationData,
    FitProblem,
    FitResult,
    FitSettings,
    calibration_runs,
    campaign_data,
    fit_campaign,
    posterior_predictive,
    run_features,
)
from bayesdoor.inference._calibration import j_standard_error, welch_j_standard_error
from bayesdoor.io import make_campaign
from bayesdoor.systems import ParameterSpec

CHANNELS = ("A1X", "A1Z", "A2X", "A2Z")


def _campaign(states, split=None):
    signals = np.random.default_rng(0).standard_normal((len(states), 4, 4096))
    return make_campaign(
        signals,
        channels=CHANNELS,
        fs=2048.0,
        state=states,
        system="elevator_door",
        v_max=[0.4] * len(states),
        split=split,
    )


def test_calibration_runs_follow_the_split_then_the_state():
    with_split = _campaign(
        ["healthy", "healthy", "D1", "healthy"], ["calibration", "test", "calibration", "test"]
    )
    np.testing.assert_array_equal(calibration_runs(with_split), [0])
    without = _campaign(["D2", "healthy", "healthy"])
    np.testing.assert_array_equal(calibration_runs(without), [1, 2])
    # a split without calibration runs: every healthy run
    tests_only = _campaign(["healthy", "D1"], ["test", "test"])
    np.testing.assert_array_equal(calibration_runs(tests_only), [0])


def test_a_campaign_without_healthy_runs_is_refused_before_any_simulation():
    faulty = _campaign(["D1", "D2", "D1"])
    with pytest.raises(ValueError, match=r"no healthy run .* 2 D1, 1 D2"):
        fit_campaign(ElevatorDoor(), faulty, method="cmaes", quick=True, progress=False)
    faulty_calibration = _campaign(["D1", "healthy"], ["calibration", "test"])
    with pytest.raises(ValueError, match=r"calibration runs: 1 D1"):
        calibration_runs(faulty_calibration)
    with pytest.raises(ValueError, match="method='lbfgs'"):
        fit_campaign(ElevatorDoor(), faulty, method="lbfgs")  # type: ignore[arg-type]
    # the held values are checked before the runs: each against its ParameterSpec
    with pytest.raises(ValueError, match=r"parameter I=12.0 is outside its allowed range \[1, 9\]"):
        fit_campaign(ElevatorDoor(), faulty, problem=FitProblem(fixed={"I": 12}))
    with pytest.raises(ValueError, match=r"parameter I=2.5 must be an integer"):
        fit_campaign(ElevatorDoor(), faulty, problem=FitProblem(fixed={"I": 2.5}))
    with pytest.raises(ValueError, match=r"fixed names \['law', 'Q'\], which are not parameters"):
        fit_campaign(ElevatorDoor(), faulty, problem=FitProblem(fixed={"law": 3, "Q": 1.0, "I": 3}))
    with pytest.raises(ValueError, match=r"fixed\['K'\]='1e6' must be a number"):
        fit_campaign(ElevatorDoor(), faulty, problem=FitProblem(fixed={"K": "1e6"}))
    everything = dict(ElevatorDoor().nominal())
    with pytest.raises(ValueError, match="fixed holds every parameter of elevator_door"):
        fit_campaign(ElevatorDoor(), faulty, problem=FitProblem(fixed=everything))
    del everything["I"]
    with pytest.raises(ValueError, match="method='nuts' samples the continuous parameters"):
        fit_campaign(ElevatorDoor(), faulty, method="nuts", problem=FitProblem(fixed=everything))


def _features(operating, y):
    n_op = len(np.unique(operating))
    return CalibrationData(
        y=jnp.asarray(y),
        welch_variance=jnp.ones(len(y)),
        operating=jnp.arange(float(n_op)),
        run_operating=jnp.asarray(operating),
        band_centres=jnp.arange(float(y.shape[-1])),
    )


def test_j_standard_error_matches_the_scatter_of_a_perfect_models_j():
    """Runs = a true spectrum per operating point plus independent scatter: the spread of the
    perfect model's mean J over many such campaigns is what j_standard_error estimates from
    one campaign's replicates."""
    rng = np.random.default_rng(3)
    operating = np.repeat([0, 1, 2], [3, 4, 3])
    truth = rng.normal(size=(3, 4, 24))
    estimates, perfect = [], []
    for _ in range(200):
        y = truth[operating] + 0.1 * rng.standard_normal((10, 4, 24))
        estimates.append(j_standard_error(_features(operating, y)))
        perfect.append(float(np.mean(objective_j(y, truth[operating]))))
    # 200 campaigns: the sd of the perfect model's J is known to 5 % (1/sqrt(2 x 200)), the
    # mean estimate (9 degrees of freedom each) to about 2 %; 12 % is three combined sds
    np.testing.assert_allclose(np.mean(estimates), np.std(perfect, ddof=1), rtol=0.12)
    # without two replicated runs there is no run-to-run scatter to measure
    single = np.array([0, 1, 2])
    assert j_standard_error(_features(single, truth[single])) is None


def test_welch_j_standard_error_is_the_scatter_of_a_perfect_models_j_under_welch_noise():
    """Runs that scatter only by their stated Welch variance: the Welch-only standard error
    is the spread of the perfect model's mean J over many campaigns, as the replicates'
    estimate is; it scales with the Welch sd and repeats for a seed."""
    rng = np.random.default_rng(4)
    operating = np.arange(12)  # no replicates: j_standard_error has nothing to go on
    truth = rng.normal(size=(12, 3, 40))
    sd = np.linspace(0.05, 0.15, 12)  # each run its own Welch scatter

    def data(y, scale=1.0):
        return CalibrationData(
            y=jnp.asarray(y),
            welch_variance=jnp.asarray((scale * sd) ** 2),
            operating=jnp.arange(12.0),
            run_operating=jnp.asarray(operating),
            band_centres=jnp.arange(40.0),
        )

    perfect = []
    for _ in range(400):
        y = truth + sd[:, None, None] * rng.standard_normal(truth.shape)
        perfect.append(float(np.mean(objective_j(y, truth))))
    se = welch_j_standard_error(data(truth))
    assert j_standard_error(data(truth)) is None
    # 400 campaigns: their sd is known to 3.5 % (1/sqrt(2 x 400)), the estimate (512 draws of
    # 12 runs) to about 1 %; 11 % is three combined sds
    np.testing.assert_allclose(se, np.std(perfect, ddof=1), rtol=0.11)
    assert welch_j_standard_error(data(truth)) == se  # the same seed, the same draws
    # J is homogeneous of degree 1 in the residual: twice the sd, twice the error, exactly
    np.testing.assert_allclose(welch_j_standard_error(data(truth, 2.0)), 2 * se, rtol=1e-12)
    with pytest.raises(ValueError, match="draws=1 must be an integer >= 2"):
        welch_j_standard_error(data(truth), draws=1)


def test_the_solve_stops_after_the_last_segment_and_j_is_unchanged():
    """fit_campaign simulates only up to the last Welch segment inside the windows (here 1152
    of 1229 samples: 0.5 s of motion after 0.1 s of rest); its J equals J from full records."""
    toy, campaign = _toy_campaign([0.3, 0.5, 0.3, 0.5])
    settings = FitSettings(max_motion_s=0.5, cmaes_max_evals=40, cmaes_restarts=0)
    fit = fit_campaign(toy, campaign, method="cmaes", settings=settings, progress=False)
    data, duration = campaign_data(toy, campaign, [0, 1, 2, 3], max_motion_s=0.5)
    assert round(duration * FS) == 1229
    full = toy.simulate_values(
        {k: np.full(2, v) for k, v in fit.point.items()}, data.operating, duration=duration
    )
    t_start, t_stop = toy.motion_window(data.operating, duration=duration)
    assert np.all(t_start == REST)
    features, _ = run_features(full.signals, FS, t_start, t_stop)
    sim = np.asarray(features)[np.asarray(data.run_operating)]
    # the same segments of the same samples: equal to round-off of the sums
    np.testing.assert_allclose(fit.j, float(np.mean(objective_j(sim, data.y))), rtol=1e-12)


def _toy_campaign(speeds, seed=0, k=None):
    """Healthy toy runs at ``speeds``, their stiffness ``k`` (default: 0.5 scattered by 0.02
    with ``seed``): the system and the campaign."""
    toy = ToySystem()
    n = len(speeds)
    if k is None:
        k = 0.5 + 0.02 * np.random.default_rng(seed).standard_normal(n)
    values = {"k": np.asarray(k, dtype=float), "m": np.ones(n), "law": np.full(n, 2.0)}
    signals = np.asarray(toy.simulate_values(values, np.asarray(speeds)).signals)
    return toy, make_campaign(
        signals,
        channels=["X", "Z"],
        fs=FS,
        state=["healthy"] * n,
        v_max=speeds,
        t_start=np.full(n, REST),
        t_stop=np.full(n, DURATION),
        system="toy",
    )


def _stops_at_a_tenth_and_near_the_budgets_j(toy, campaign, se: float):
    """CMA-ES with the default rule stops by pycma's tolfun or tolfunhist at 0.1 x ``se``,
    before a run to the budget (pycma's own tolerances), its J within ``se`` of that run's.
    Returns the ruled fit."""
    kw = dict(cmaes_max_evals=3000, cmaes_restarts=0)
    ruled = fit_campaign(toy, campaign, method="cmaes", progress=False, settings=FitSettings(**kw))
    stop = dict(part.split("=") for part in ruled.cmaes.stop[0].split(", "))
    assert set(stop) & {"tolfun", "tolfunhist"}, ruled.cmaes.stop
    np.testing.assert_allclose(float(stop.get("tolfunhist", stop.get("tolfun"))), 0.1 * se)
    free = fit_campaign(
        toy,
        campaign,
        method="cmaes",
        progress=False,
        settings=FitSettings(cmaes_tolerance=None, **kw),
    )
    print(
        f"J {ruled.j:.5f} after {ruled.cmaes.evaluations}, {free.j:.5f} after "
        f"{free.cmaes.evaluations} evaluations; se {se:.4f}"
    )
    assert ruled.cmaes.evaluations < free.cmaes.evaluations
    assert ruled.j - free.j <= se
    return ruled


def test_cmaes_stops_at_a_tenth_of_js_standard_error():
    """The default rule: pycma's tolfun and tolfunhist at 0.1 x j_standard_error; the J it
    stops at is within one standard error of a run to the budget (pycma's own tolerances)."""
    toy, campaign = _toy_campaign([0.3, 0.5] * 3)
    data, _ = campaign_data(toy, campaign, calibration_runs(campaign))
    se = j_standard_error(data)
    assert se is not None and se > 0
    _stops_at_a_tenth_and_near_the_budgets_j(toy, campaign, se)


class TwoIndexToy(ToySystem):
    """The toy system with a second integer parameter, which its signals ignore."""

    @property
    def parameters(self):
        extra = ParameterSpec("mode", "-", 1, 0, 2, "a second index", integer=True)
        return (*super().parameters, extra)


def test_every_integer_parameter_is_searched_then_held_and_a_continuous_one_may_be_held():
    """Two integer parameters: CMA-ES searches both as integer variables after the continuous
    ones and holds them at the optimum; ``fixed`` takes a continuous parameter out of the
    search and the sampled names, and an integer one out of the search."""
    _, campaign = _toy_campaign([0.3, 0.5] * 2)
    toy = TwoIndexToy()
    settings = FitSettings(max_motion_s=0.5, cmaes_max_evals=60, cmaes_restarts=0)
    fit = fit_campaign(toy, campaign, method="cmaes", settings=settings, progress=False)
    assert fit.names == ("k", "m") and list(fit.held) == ["law", "mode"]
    # the search vector: k, m, then law and mode, integral as pycma keeps them
    x = fit.cmaes.x_best
    assert x.shape == (4,) and x[2] == fit.held["law"] and x[3] == fit.held["mode"]
    assert all(v == round(v) for v in fit.held.values())
    assert fit.point == {"k": x[0], "m": x[1], **fit.held}
    assert fit.to_json()["held"] == fit.held
    held = fit_campaign(
        toy,
        campaign,
        method="cmaes",
        problem=FitProblem(fixed={"mode": 2, "m": 1.0}),
        settings=settings,
        progress=False,
    )
    assert held.names == ("k",) and held.cmaes.x_best.shape == (2,)
    # the system's order, the searched integer at its optimum
    assert held.held == {"m": 1.0, "law": held.cmaes.x_best[1], "mode": 2.0}
    assert held.point == {"k": held.cmaes.x_best[0], **held.held}
    # the toy's tone follows k (20 + 40 k Hz): the runs' k of 0.5 is found with m held
    assert abs(held.point["k"] - 0.5) < 0.05


def test_cmaes_without_replicates_stops_at_a_tenth_of_the_welch_standard_error():
    """No speed measured twice: the stop falls back on the Welch scatter's standard error,
    says so in the notes, and still ends before a run to the budget, within one such
    standard error of its J."""
    toy, campaign = _toy_campaign([0.3, 0.4, 0.5, 0.6])
    data, _ = campaign_data(toy, campaign, calibration_runs(campaign))
    assert j_standard_error(data) is None
    ruled = _stops_at_a_tenth_and_near_the_budgets_j(toy, campaign, welch_j_standard_error(data))
    assert any("Welch scatter alone" in note for note in ruled.notes), ruled.notes


def test_settings_refuse_bad_workers_tolerance_and_chain_method():
    with pytest.raises(ValueError, match="workers=0 must be an integer >= 1"):
        FitSettings(workers=0)
    with pytest.raises(ValueError, match="chain_method='parallel'"):
        FitSettings(chain_method="parallel")
    with pytest.raises(ValueError, match=r"cmaes_tolerance=-0.1 must be positive"):
        FitSettings(cmaes_tolerance=-0.1)


# ---------------------------------------------------------------------------------------------
# the virtual rig: 3 healthy calibration runs at 0.5 m/s and a faulty test run to be ignored


@pytest.fixture(scope="module")
def rig():
    t0 = time.perf_counter()
    recording = VirtualRig().run(
        ["healthy"] * 3 + ["D1"],
        [0.5] * 4,
        key=jax.random.key(11),
        split=["calibration"] * 3 + ["test"],
    )
    print(f"rig: 4 runs recorded in {time.perf_counter() - t0:.1f} s")
    return recording.campaign, recording.truth["parameters"]


def _j_of(door, campaign, runs, points, settings):
    """J at each of ``points``, apart from fit_campaign's machinery: the system's batch
    simulation, run_features in the system's motion window, objective_j per run, mean."""
    data, duration = campaign_data(door, campaign, runs, max_motion_s=settings.max_motion_s)
    ops = np.asarray(data.operating)
    values = {p.name: np.repeat([pt[p.name] for pt in points], ops.size) for p in door.parameters}
    speeds = np.tile(ops, len(points))
    result = jax.jit(lambda v: door.simulate_values(v, speeds, duration=duration, check=False))(
        values
    )
    assert np.all(np.asarray(result.status) == 0)
    t_start, t_stop = door.motion_window(speeds, duration=duration)
    features, _ = run_features(result.signals, door.sampling_rate_hz, t_start, t_stop)
    features = np.asarray(features).reshape(len(points), ops.size, *features.shape[1:])
    sim = features[:, np.asarray(data.run_operating)]
    return [float(np.mean(objective_j(s, data.y))) for s in sim]


@pytest.fixture(scope="module")
def cmaes_fit(rig):
    campaign, _ = rig
    t0 = time.perf_counter()
    result = fit_campaign(ElevatorDoor(), campaign, method="cmaes", quick=True, progress=False)
    print(f"quick CMA-ES fit in {time.perf_counter() - t0:.1f} s: {result.timings}")
    return result


# the two tests of the quick CMA-ES fit on rig data share its recording and fit (40-103 s with
# an empty JAX cache on a 2-core machine, 48 s idle; computed twice when pytest -n 2 gave the
# two tests to both processes): in the long tier, which CI runs after the default suite. The
# fit's refusals and settings stay above; FitResult's save and load are also checked in
# tests/test_diagnosis_gain.py
@pytest.mark.long
def test_cmaes_reaches_the_truths_j_on_rig_data(rig, cmaes_fit):
    campaign, truth = rig
    door = ElevatorDoor()
    runs = calibration_runs(campaign)
    np.testing.assert_array_equal(runs, [0, 1, 2])
    j_truth, j_point = _j_of(door, campaign, runs, [truth, cmaes_fit.point], cmaes_fit.settings)
    # the reported J is the objective at the reported point (independent recomputation)
    np.testing.assert_allclose(cmaes_fit.j, j_point, rtol=1e-8)
    print(f"J: CMA-ES {cmaes_fit.j:.4f}, the rig's truth with the reduced model {j_truth:.4f}")
    # the rig is not the reduced model (bending mode, textbook contact, scatter, noise), so
    # its truth is not J's minimum; a working optimiser must get at least as close. Margin:
    # 10 % of J, what 120 evaluations leave of the gap between a quick and a long search
    assert cmaes_fit.j <= 1.10 * j_truth
    # the budget holds, overshot by at most the last population (pycma stops after the
    # iteration that reaches it; 132 = 11 x 12 measured for a budget of 120)
    history = cmaes_fit.cmaes.history
    assert cmaes_fit.cmaes.evaluations <= cmaes_fit.settings.cmaes_max_evals + history.popsize[-1]
    # the contact-law index, the door's one integer parameter, searched and then held
    assert list(cmaes_fit.held) == ["I"] and cmaes_fit.held["I"] in range(1, 10)
    assert cmaes_fit.point["I"] == cmaes_fit.held["I"] and "I" not in cmaes_fit.names


@pytest.mark.long
def test_a_fit_saves_loads_and_refuses_to_overwrite(cmaes_fit, tmp_path):
    folder = cmaes_fit.save(tmp_path / "fit")
    again = FitResult.load(folder)
    assert again.point == cmaes_fit.point
    assert again.j == cmaes_fit.j
    np.testing.assert_array_equal(again.cmaes.history.best_f, cmaes_fit.cmaes.history.best_f)
    assert again.settings == cmaes_fit.settings
    before = (folder / "fit.json").read_text()
    with pytest.raises(FileExistsError, match="force=True"):
        cmaes_fit.save(folder)
    assert (folder / "fit.json").read_text() == before
    draws = again.posterior_draws()
    assert set(draws) == set(again.names) and all(v.shape == (1,) for v in draws.values())
    assert again.model_error_draws().shape == (1, 4)
    record = json.loads(before)
    assert record["method"] == "cmaes"
    assert record["held"] == cmaes_fit.held == again.held and "law" not in record
    # a fit written before "held" recorded the integer parameter's value as "law": it is the
    # parameter of the point that the sampled names lack
    old = {k: v for k, v in record.items() if k != "held"}
    old["law"] = int(cmaes_fit.held["I"])
    (folder / "fit.json").write_text(json.dumps(old))
    assert FitResult.load(folder).held == cmaes_fit.held
    # one that cannot tell which parameter the law was is refused, not guessed
    old["names"] = [n for n in old["names"] if n != "K"]
    (folder / "fit.json").write_text(json.dumps(old))
    with pytest.raises(ValueError, match=r"old fit record \(law=\d, no 'held'\).*\['I', 'K'\]"):
        FitResult.load(folder)


# ---------------------------------------------------------------------------------------------
# slow: the posterior on rig data


#: what the rig's calibration runs identify, measured on the demo campaign (full fit, law 3,
#: shared discrepancy; `demo_fit` prints them): posterior sd over the uniform prior's sd 0.03-0.1
#: for c_r, K and MF, 0.2-0.45 for C and n; mu_d and mu_s keep most of the prior's spread
#: (0.86 and 0.96), the features barely move them. The 90 % intervals must cover these:
COVERED = ("n", "c_r", "C")
#: and these must stay close to their prior (the data say little about them)
PRIOR_LIKE = ("mu_s", "mu_d")
#: identified (sd ratio < 0.1) but off the rig's value by 2.4 posterior sds in the last full
#: fit (K +3.7 %, MF +1.5 %): effective values of the reduced model, whose smoothed contact,
#: small rotations and rigid panel differ from the rig's; see the xfail test below
EFFECTIVE = ("K", "MF")
#: a posterior "close to the prior": more than half the prior's sd (the last full fit: mu_d
#: 0.86, mu_s 0.96; the weakest covered parameter, n, 0.43). A uniform prior cut to half its
#: range gives exactly 0.5
PRIOR_RATIO = 0.5


@pytest.fixture(scope="module")
def demo_fit():
    """The full fit on the demo campaign (10 calibration runs at three speeds), the law fixed
    at the rig's."""
    campaign = load_demo_campaign()
    truth = load_demo_truth()["parameters"]
    door = ElevatorDoor()
    t0 = time.perf_counter()
    result = fit_campaign(
        door, campaign, method="nuts", problem=FitProblem(fixed={"I": truth["I"]}), progress=False
    )
    print(f"NUTS fit in {time.perf_counter() - t0:.0f} s: {result.timings}")
    print(result.diagnostics)
    print("notes:", result.notes)
    print("model error (decades) per operating point and channel:")
    print(np.round(result.discrepancy_draws().mean(axis=0), 3))
    print("run scatter (Welch sds):", np.round(result.run_scatter_draws().mean(axis=0), 3))
    draws = result.posterior_draws()
    specs = {p.name: p for p in door.parameters}
    rows = {}
    for name in result.names:
        q5, q95 = np.quantile(draws[name], [0.05, 0.95])
        prior_sd = (specs[name].upper - specs[name].lower) / np.sqrt(12.0)
        rows[name] = (q5, q95, draws[name].std() / prior_sd)
        print(
            f"{name}: truth {truth[name]:.4g}, mean {draws[name].mean():.4g}, 90 % "
            f"[{q5:.4g}, {q95:.4g}], sd / prior sd {rows[name][2]:.3f}"
        )
    return campaign, truth, door, result, rows


@pytest.mark.slow
def test_posterior_covers_the_rigs_truth_and_predicts_held_out_runs(demo_fit):
    """Coverage of the rig's values, prior-like posteriors where the data say little, and the
    100 held-out healthy test runs against the posterior predictive."""
    campaign, truth, door, result, rows = demo_fit
    assert result.diagnostics.passed
    assert set(COVERED) | set(PRIOR_LIKE) | set(EFFECTIVE) == set(result.names)
    for name in COVERED:
        q5, q95, _ = rows[name]
        assert q5 <= truth[name] <= q95, name
    for name in PRIOR_LIKE:
        assert rows[name][2] > PRIOR_RATIO, name
    held_out = np.flatnonzero(
        (campaign["split"].values == "test") & (campaign["state"].values == "healthy")
    )
    replicates, data, ok = posterior_predictive(
        result, door, campaign, held_out, key=jax.random.key(5), n_draws=100
    )
    assert ok.all()
    lo, hi = np.quantile(replicates, [0.05, 0.95], axis=0)
    inside = (data.y >= lo) & (data.y <= hi)
    per_op = [float(inside[np.asarray(data.run_operating) == o].mean()) for o in range(3)]
    print(
        f"held-out 90 % predictive coverage: {100 * inside.mean():.1f} % of {data.y.size} "
        f"features; per speed {np.round(100 * np.array(per_op), 1)} %"
    )
    assert 0.80 <= float(inside.mean()) <= 0.97


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="K and MF come out as the reduced model's effective values, 2.4 posterior sds "
    "above the rig's; CMA-ES on all 110 healthy rig runs stays at K +5.4 %, MF +4.1 % "
    "(scripts/pseudo_true.py, results/inference.md): a model-form gap no likelihood closes",
)
def test_posterior_covers_the_rigs_stiffness_and_mass_factor(demo_fit):
    _, truth, _, _, rows = demo_fit
    for name in EFFECTIVE:
        q5, q95, _ = rows[name]
        assert q5 <= truth[name] <= q95, name


def _toy_data():
    toy, campaign = _toy_campaign([0.3, 0.5, 0.3, 0.5], k=np.full(4, 0.5))
    signals = campaign["acceleration"].values
    data, duration = campaign_data(toy, campaign, [0, 1, 2, 3], max_motion_s=0.5)
    return toy, data, duration, signals


def test_the_fits_population_program_holds_no_host_callback_so_it_can_be_cached():
    """The population's simulation and features are traced without equinox's run-time
    checks (a callback keeps JAX from caching the program: compiled again in every process),
    also when the same checks of the same shapes were traced eagerly before, on measured
    records; a failed check gives NaN features, which ``ok`` reports."""
    from bayesdoor.inference._features import FeatureSpec
    from bayesdoor.inference._population import _Population, _simulate_chunk

    toy, data, duration, signals = _toy_data()
    spec = FeatureSpec()
    # the measured records' features first, eagerly, as campaign_data computes them
    run_features(jnp.asarray(signals), FS, jnp.full(4, REST), jnp.full(4, DURATION), spec)
    population = _Population.build(toy, data, duration, spec)
    x = jnp.asarray([[0.5, 1.0, 2.0], [0.52, 1.0, 2.0]])
    text = _simulate_chunk.lower(population, x).as_text()
    assert "callback" not in text
    features, ok = _simulate_chunk(population, x)
    assert np.all(np.asarray(ok)) and np.all(np.isfinite(np.asarray(features)))


def test_a_simulated_window_without_a_whole_welch_segment_is_refused_up_front():
    from bayesdoor.inference._features import FeatureSpec
    from bayesdoor.inference._population import _Population

    toy, data, duration, _ = _toy_data()
    with pytest.raises(ValueError, match="no segment of nperseg=1024 lies inside"):
        _Population.build(toy, data, duration, FeatureSpec(nperseg=1024))
