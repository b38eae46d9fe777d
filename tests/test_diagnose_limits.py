"""Detection limits and measurement plans (bayesdoor.diagnose.detection_limits, plan_campaign).

The formulas of the expected held-out difference are checked against simulated Gaussian
spectra; the rule's probability of naming against its false-alarm rate; and the whole
computation on the toy fan of ``test_system_plugin.py`` (analytic runs, seconds): a 50 Hz
hum hidden at 1.5 times the stated limit must be named by the full diagnosis in at least 70 %
of seeds, at 0.5 times in at most 30 % (a reduced-size version of the door's check in
``scripts/diagnosis_limits.py``; results/diagnosis_limits.md).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.stats
from test_system_plugin import (
    CATALOGUE,
    CHANNELS,
    FS,
    TRUE,
    ToyFan,
    _HumRecipe,
    fan_campaign,
)

from bayesdoor.diagnose import (
    LIMIT_POWER,
    Candidate,
    Catalogue,
    CauseLimit,
    CauseSize,
    ExtensionProposal,
    PlanSettings,
    PowerCurve,
    SizeProbe,
    Transmission,
    diagnose_campaign,
    plan_campaign,
)
from bayesdoor.diagnose._design import CampaignPlan, estimation_cost, fold_labels
from bayesdoor.diagnose._gain import DECISIVE_SE, changed_bins
from bayesdoor.diagnose._limits import (
    bin_variance_factor,
    expected_differences,
    naming_probability,
    size_spectra,
)
from bayesdoor.diagnose._refit import RefitSetup, Spectra, exact_signals
from bayesdoor.inference import fit_campaign


def test_the_expected_difference_matches_simulated_spectra():
    # the truth is the extended model; the base model's scatter in the changed bins is
    # v + mean(delta^2) per channel, the extended model's v: the mean and variance of the
    # per-run log-density difference over many draws of the measured spectra
    rng = np.random.default_rng(3)
    runs, channels, bins = 6, 2, 40
    base = np.zeros((runs, channels, bins))
    delta = np.zeros_like(base)
    delta[:, :, 10:16] = rng.uniform(0.2, 0.8, (runs, channels, 6))
    welch = np.full(runs, 0.04)
    variance = np.full(base.shape, 0.05)
    mean, var = expected_differences(
        base, base + delta, variance, welch, parameters=0, smooth_bins=None
    )
    changed = changed_bins(base, base + delta, welch)
    d2 = np.where(changed, delta**2, 0.0)
    vb = variance + d2.sum(axis=(0, 2), keepdims=True) / changed.sum(axis=(0, 2), keepdims=True)
    draws = 20000
    y = base + delta + np.sqrt(variance) * rng.standard_normal((draws, *base.shape))

    def lpd(model, v):
        return -0.5 * np.sum(
            np.where(changed, np.log(2 * np.pi * v) + (y - model) ** 2 / v, 0.0), axis=(-2, -1)
        )

    d = lpd(base + delta, variance) - lpd(base, vb)
    assert np.allclose(mean, d.mean(axis=0), rtol=0.03), (mean, d.mean(axis=0))
    assert np.allclose(var, d.var(axis=0), rtol=0.1), (var, d.var(axis=0))


def test_a_broad_change_is_taken_by_the_smooth_discrepancy_and_a_narrow_one_is_not():
    base = np.zeros((6, 1, 200))
    welch, variance = np.full(6, 0.01), np.full(base.shape, 0.02)
    broad = base + 0.5  # a level change of the whole band: both models' smooth part takes it
    mean, _ = expected_differences(base, broad, variance, welch, parameters=0)
    assert np.allclose(mean, 0.0, atol=1e-9)
    narrow = base.copy()
    narrow[..., 100:103] = 0.5
    mean, _ = expected_differences(base, narrow, variance, welch, parameters=0)
    whole, _ = expected_differences(base, narrow, variance, welch, parameters=0, smooth_bins=None)
    assert np.allclose(mean, whole) and np.all(mean > 1.0)


def test_the_parameters_cost_their_estimation_error():
    base = np.zeros((8, 1, 10))
    mean0, _ = expected_differences(base, base, np.ones(base.shape), np.ones(8), parameters=0)
    mean4, _ = expected_differences(base, base, np.ones(base.shape), np.ones(8), parameters=4)
    assert np.allclose(mean0, 0.0) and np.allclose(mean4, -4 / 8)


def test_the_probability_of_naming_is_the_rules_false_alarm_rate_under_no_change():
    runs, draws = 12, 200_000
    normals = np.random.default_rng(5).standard_normal((draws, runs))
    p = float(naming_probability(np.zeros(runs), np.ones(runs), normals))
    expected = scipy.stats.t.sf(DECISIVE_SE, runs - 1)
    assert abs(p - expected) < 4 * np.sqrt(expected / draws), (p, expected)
    strong = naming_probability(np.full((2, runs), [[1.0], [20.0]]), np.ones((2, runs)), normals)
    assert strong[0] < 0.5 < 0.999 < strong[1]


def test_neighbouring_hann_bins_double_a_sums_variance():
    # the DFT coefficients of a Hann window one and two bins apart correlate 2/3 and 1/6
    assert bin_variance_factor(1024) == pytest.approx(1 + 2 * ((2 / 3) ** 2 + (1 / 6) ** 2))


class _SizedHum(_HumRecipe):
    """The fan's hum recipe with its size: the line's amplitude on both channels."""

    def size(self, *, band):
        scales = {f"hum.amplitude_{c}": 1.0 for c in CHANNELS}
        probe = SizeProbe(
            label="both channels",
            proposal=ExtensionProposal(extension="hum", start={}, free=tuple(scales)),
            scales=scales,
            reference=0.02,
        )
        return CauseSize("hum amplitude", "m/s^2", 1e-4, 0.2, (probe,))


SIZED = Catalogue(
    candidates=tuple(
        Candidate(c.name, c.description, c.signature, _SizedHum()) if c.name == "hum" else c
        for c in CATALOGUE.candidates
    )
)
#: seeds of the fan's campaigns at each factor of the limit (not those of the other tests)
SEEDS = range(300, 310)


def test_the_spectra_at_any_size_are_the_welch_estimates_of_the_simulated_signals():
    # a Welch PSD is quadratic in the signal: three estimates give every size exactly
    fan = ToyFan()
    campaign = fan_campaign(test=False, seed=298)
    speeds = np.asarray(campaign["speed"].values, dtype=float)
    t0, t1 = (np.asarray(campaign[k].values, dtype=float) for k in ("t_start", "t_stop"))
    result = fan.simulate_values(TRUE, speeds)
    signals = np.asarray(result.signals)
    spectra = Spectra.of_measured(
        np.asarray(campaign["acceleration"].values), FS, t0, t1, (5.0, 200.0), nperseg=256
    )
    setup = RefitSetup(
        system=fan,
        point=TRUE,
        operating=speeds,
        duration=signals.shape[-1] / FS,
        time=np.asarray(result.time),
        base_signals=signals,
        spectra=spectra,
    )
    probe = _SizedHum().size(band=(5.0, 200.0)).probes[0]
    at = size_spectra(setup, probe)
    runs = np.arange(len(speeds))
    for size in (0.0, 0.003, 0.07):
        direct = spectra.model(
            exact_signals(setup, probe.proposal, probe.values(size, len(runs)), runs), runs
        )
        assert np.allclose(at(size), direct, atol=1e-8), size


@pytest.fixture(scope="module")
def fan_fit():
    campaign = fan_campaign(test=False, seed=299)
    return campaign, fit_campaign(ToyFan(), campaign, seed=0, quick=True, progress=False)


#: 21 diagnoses of the fan: 184 s measured on the shared 2-CPU machine (about 8 processes)
@pytest.mark.long
def test_a_hum_at_its_limit_is_named_as_often_as_stated(fan_fit):
    campaign, fit = fan_fit
    fan = ToyFan()
    nothing = diagnose_campaign(fan, campaign, fit=fit, quick=True, progress=False, catalogue=SIZED)
    assert nothing.verdict == "none"
    limit = nothing.limits["hum"]
    assert limit.size is not None and limit.power == LIMIT_POWER
    payload = nothing.to_json()["limits"]["hum"]
    assert payload["unit"] == "m/s^2" and payload["size"] == limit.size
    named = {}
    for factor in (0.5, 1.5):
        verdicts = [
            diagnose_campaign(
                fan,
                fan_campaign(test=False, hum=factor * limit.size, seed=seed),
                fit=fit,
                seed=seed,
                quick=True,
                progress=False,
                catalogue=SIZED,
            ).verdict
            for seed in SEEDS
        ]
        named[factor] = sum(v == "hum" for v in verdicts) / len(verdicts)
    assert named[1.5] >= 0.7 and named[0.5] <= 0.3, (limit.size, named)


#: the fan's fit (39 s measured on the shared machine, shared with the other long tests)
#: and four plans (2 s each)
@pytest.mark.long
def test_a_plan_for_the_family_is_the_plan_for_what_its_least_machine_shows(fan_fit):
    campaign, fit = fan_fit
    fan = ToyFan()

    def declaring(transmission):
        class Recipe(_SizedHum):
            def size(self, *, band):
                return dataclasses.replace(super().size(band=band), transmission=transmission)

        return Catalogue(
            candidates=tuple(
                Candidate(c.name, c.description, c.signature, Recipe()) if c.name == "hum" else c
                for c in CATALOGUE.candidates
            )
        )

    family = declaring(Transmission(low=0.5, high=1.2, explained=0.9, machines=4))
    size = 0.01
    held = plan_campaign(fan, campaign, "hum", size, fit=fit, catalogue=family)
    weaker = plan_campaign(fan, campaign, "hum", 0.5 * size, fit=fit, catalogue=SIZED)
    assert held.ratio == 0.5 and held.size == size and weaker.ratio is None
    assert held.runs == weaker.runs and held.probability == pytest.approx(weaker.probability)
    model = plan_campaign(
        fan,
        campaign,
        "hum",
        size,
        fit=fit,
        catalogue=family,
        settings=PlanSettings(machines="model"),
    )
    assert model.ratio is None and (model.runs or 0) <= (held.runs or 10**6)
    shape = declaring(Transmission(low=0.5, high=1.2, explained=0.2, machines=4))
    with pytest.raises(ValueError, match="machines='model'"):
        plan_campaign(fan, campaign, "hum", size, fit=fit, catalogue=shape)
    with pytest.raises(ValueError, match="machines="):
        PlanSettings(machines="rig")


#: the fan's fit (39 s measured on the shared machine) and a plan (2 s)
@pytest.mark.long
def test_the_plan_names_the_hum_it_plans_for(fan_fit):
    campaign, fit = fan_fit
    fan = ToyFan()
    limit = diagnose_campaign(
        fan, campaign, fit=fit, quick=True, progress=False, catalogue=SIZED
    ).limits["hum"]
    small = 0.6 * limit.size
    plan = plan_campaign(fan, campaign, "hum", small, fit=fit, catalogue=SIZED)
    assert plan.runs is not None and plan.runs > 8 and plan.probability >= LIMIT_POWER
    assert plan.current < LIMIT_POWER
    assert set(plan.conditions) <= {13.0, 21.0}
    with pytest.raises(ValueError, match="declares no size"):
        plan_campaign(fan, campaign, "resonance", 0.1, fit=fit, catalogue=SIZED)


def test_the_report_shows_the_limits_and_their_power_curves():
    from bayesdoor.report import diagnosis_page

    curve = {
        "label": "typical",
        "size": 2e-6,
        "sizes": [1e-6, 2e-6, 4e-6],
        "probability": [0.1, 0.8, 1.0],
        "evidence_se": [1.0, 4.5, 9.0],
    }
    limit = {
        "quantity": "rail waviness amplitude",
        "unit": "m",
        "power": 0.8,
        "size": 2e-6,
        "worst": None,
        "runs": 12,
        "configurations": [curve, {**curve, "label": "long", "size": None}],
        "words": "rail_waviness: a rail waviness amplitude under 2 um would not be named",
    }
    bare = diagnosis_page({"verdict": "none", "causes": []})
    page = diagnosis_page({"verdict": "none", "causes": [], "limits": {"rail_waviness": limit}})
    assert "Limits" not in bare and "Limits" in page
    assert "above the range" in page and "a rail waviness amplitude under 2 um" in page
    assert page.count("data:image/png") == bare.count("data:image/png") + 1
    # the family's limit beside the model's, or why there is none
    assert "limit (family)" in page and "not measured" in page
    family = {"low": 0.25, "high": 0.5, "explained": 0.9, "machines": 4, "reliable": True}
    with_family = {**limit, "family_size": 8e-6, "transmission": family}
    page = diagnosis_page({"verdict": "none", "causes": [], "limits": {"r": with_family}})
    assert "8e-06" in page and "not measured" not in page
    shape = {**with_family, "family_size": None, "transmission": {**family, "reliable": False}}
    page = diagnosis_page({"verdict": "none", "causes": [], "limits": {"r": shape}})
    assert "not transmitted as the model does" in page


PLAN = CampaignPlan(
    cause="rail_waviness",
    size=1e-6,
    unit="m",
    configuration="typical",
    power=0.8,
    conditions=(0.3, 0.4),
    runs_per_condition=9,
    probability=0.82,
    record_s=2.0,
    current=0.3,
    display=("um", 1e6),
)


def test_after_a_none_the_report_and_the_summary_plan_a_campaign_per_cause():
    from bayesdoor.cli._diagnose import summary_lines
    from bayesdoor.report import diagnosis_page, diagnosis_section

    limit = {
        "quantity": "rail waviness amplitude",
        "unit": "m",
        "power": 0.8,
        "size": 2e-6,
        "worst": 2e-6,
        "runs": 12,
        "configurations": [],
        "words": "rail_waviness: a rail waviness amplitude under 2 um would not be named",
        "plan": PLAN.to_json(),
    }
    words = "9 runs at each of 2 conditions (0.3, 0.4) (18 runs of 2 s in all) name rail_waviness"
    assert words in PLAN.describe()
    assert "if the machine transmits it as the model does" in PLAN.describe()
    family = dataclasses.replace(PLAN, ratio=0.25).describe()
    assert "on every machine of its family (the least of which shows it as the model" in family
    assert "0.25 times the size" in family and PLAN.to_json()["ratio"] is None
    one = dataclasses.replace(PLAN, conditions=(0.3,))
    assert "9 runs at 0.3 (9 runs of 2 s in all)" in one.describe()
    for verdict, shown in (("none", True), ("frame_mode", False)):
        payload = {"verdict": verdict, "causes": [], "limits": {"rail_waviness": limit}}
        page = diagnosis_page(payload)
        section = diagnosis_section(payload, None)
        lines = summary_lines({**payload, "report": "diagnosis.html"})
        assert ("Campaigns that would see smaller causes" in page) is shown
        assert (words in page) is shown and (words in section) is shown
        assert any(words in line for line in lines) is shown
        assert any("under 2 um" in line for line in lines)


def test_the_refits_estimation_costs_kappa_p_over_2_per_fold():
    # a fold's runs share one chi2_p draw: with the folds equally informative they lose
    # kappa p / 2 together in expectation, each run in proportion to its information
    rng = np.random.default_rng(0)
    runs, p, kappa = 8, 3, 1.9
    information = np.tile(rng.uniform(0.5, 2.0, runs // 2), 2)  # the folds alike
    folds = np.repeat([0, 1], runs // 2)
    chi2 = rng.chisquare(p, (100_000, 2))
    cost = estimation_cost(information, folds, chi2, kappa)
    for f in (0, 1):
        mine = folds == f
        lost = cost[:, mine].sum(axis=1) / 2.0
        assert lost.mean() == pytest.approx(kappa * p / 2.0, rel=0.02)
        share = information[mine] / information[mine].sum()
        assert np.allclose(cost[:, mine] / 2.0, lost[:, None] * share)


def test_the_folds_are_the_judgements():
    from bayesdoor.diagnose._held_out import held_out_folds

    order = np.array([0.4, 0.25, 0.3, 0.3, 0.5, 0.45, 0.35])
    labels = fold_labels(order)
    for f, (_, test) in enumerate(held_out_folds(order, 2)):
        assert np.array_equal(np.flatnonzero(labels == f), test)


def test_the_estimation_lowers_the_probability_of_naming():
    runs = 12
    rng = np.random.default_rng(1)
    normals = rng.standard_normal((4000, runs))
    mean, variance = np.full(runs, 3.0), np.full(runs, 4.0)
    truth = float(naming_probability(mean, variance, normals))
    costs = [
        float(
            naming_probability(
                mean,
                variance,
                normals,
                estimation_cost(
                    np.ones(runs), np.arange(runs) % 2, rng.chisquare(p, (4000, 2)), 1.9
                ),
                1.9,
            )
        )
        for p in (1, 6)
    ]
    assert truth > costs[0] > costs[1]


def _limit(size, transmission):
    sizes = np.geomspace(1e-4, 1e-1, 5)
    curve = PowerCurve("typical", sizes, np.linspace(0, 1, 5), np.zeros(5), size)
    return CauseLimit(
        "hum",
        "hum amplitude",
        "m/s^2",
        ("mm/s^2", 1e3),
        0.8,
        12,
        (curve,),
        transmission=transmission,
    )


def test_the_family_limit_is_the_model_limit_over_the_smallest_ratio():
    family = Transmission(low=0.25, high=0.9, explained=0.8, machines=4, source="here")
    limit = _limit(0.002, family)
    assert limit.family == pytest.approx(0.008)
    words = limit.describe()
    assert "under 2 mm/s^2" in words and "across the family of machines, under 8 mm/s^2" in words
    assert "0.25-0.9 times" in words
    payload = limit.to_json()
    assert payload["family_size"] == pytest.approx(0.008)
    assert payload["transmission"]["low"] == 0.25 and payload["transmission"]["reliable"]
    # a family whose change the model's does not make: no family limit, said with its figure
    shape = Transmission(low=0.2, high=0.9, explained=0.3, machines=4)
    assert not shape.reliable and _limit(0.002, shape).family is None
    assert "at worst 30 % of a machine's change explained" in _limit(0.002, shape).describe()
    # a family limit beyond the sizes scanned is still the size the least-transmitting
    # machine shows as the model shows its limit: the refit reaches it
    weak = Transmission(low=0.01, high=0.9, explained=0.8, machines=4)
    assert _limit(0.002, weak).family == pytest.approx(0.2)
    # no transmission measured, or no model limit: none
    assert _limit(0.002, None).family is None and _limit(None, family).family is None
    assert "family" not in _limit(0.002, None).describe()
    with pytest.raises(ValueError, match="low <= high"):
        Transmission(low=0.5, high=0.2, explained=1.0, machines=2)
