"""Simulation-based calibration: rank statistics and their uniformity test against exact
posteriors (which must pass) and deliberately wrong ones (which must fail), NUTS through
``sample_nuts`` on a conjugate target, and (slow) the reduced door itself."""

import json
import subprocess
import sys
from pathlib import Path

import arviz as az
import jax
import numpy as np
import numpyro
import numpyro.distributions as dist
import pytest

from bayesdoor.inference import (
    NUTSSettings,
    SBCDesign,
    SBCResult,
    load_sbc,
    plot_sbc_ranks,
    run_sbc,
    sample_nuts,
    save_sbc,
    sbc_uniformity,
)
from bayesdoor.inference._sbc import sbc_ranks, thin_evenly

# --- the array core ----------------------------------------------------------------------------


def test_ranks_count_the_draws_below_the_truth():
    truth = np.array([[0.5, 10.0], [-1.0, 0.0]])
    draws = np.array(
        [[[0.1, 11.0], [0.7, 9.0], [0.2, 12.0]], [[-2.0, -1.0], [-3.0, 1.0], [5.0, -0.5]]]
    )
    np.testing.assert_array_equal(sbc_ranks(truth, draws), [[2, 1], [2, 2]])
    with pytest.raises(ValueError, match=r"\(dataset, param\)"):
        sbc_ranks(truth, draws[:, :, :1])


def test_thin_evenly_spreads_over_chains():
    draws = np.arange(2 * 10).reshape(2, 10)
    np.testing.assert_array_equal(thin_evenly(draws, 4), [2, 7, 12, 17])
    # an odd count: the first chain gives the extra draw
    assert thin_evenly(draws, 5).tolist() == [1, 5, 8, 12, 17]
    with pytest.raises(ValueError, match="n=21"):
        thin_evenly(draws, 21)


def test_uniformity_false_alarm_rate_is_at_most_the_level():
    """Uniform ranks: over 400 repetitions the family-wise test fails about alpha of the time.

    With alpha = 0.05 the number of failures is Binomial(400, <= 0.05), mean at most 20, so
    40 or more failures (4.6 sd above 20) would say the test is anti-conservative.
    """
    rng = np.random.default_rng(0)
    failures = sum(
        not sbc_uniformity(rng.integers(0, 100, (50, 3)), 99, alpha=0.05).passed for _ in range(400)
    )
    assert failures < 40


def test_uniformity_names_the_shape_of_each_failure():
    rng = np.random.default_rng(1)
    u = rng.uniform(size=(100, 3))
    ranks = np.stack(
        [
            np.floor(100 * u[:, 0]),  # uniform
            np.floor(100 * u[:, 1] ** 2),  # mostly low: the truth sits below the draws
            np.floor(100 * np.where(u[:, 2] < 0.5, 0.3 * u[:, 2], 1 - 0.3 * u[:, 2])),  # U
        ],
        axis=1,
    ).astype(int)
    result = sbc_uniformity(ranks, 99, names=["ok", "biased", "narrow"])
    assert not result.passed and len(result.messages) == 2
    assert result.messages[0].startswith("biased:") and "sits above the truth" in result.messages[0]
    assert result.messages[1].startswith("narrow:") and "too narrow" in result.messages[1]
    assert "SBC RANKS NOT UNIFORM" in str(result)
    assert sum(result.counts[0]) == 100 and result.bins == 10
    with pytest.raises(ValueError, match=r"outside 0\.\.n_rank_draws=50"):
        sbc_uniformity(ranks, 50)


# --- the driver, with exact posterior draws (no sampler error at all) ---------------------------

N_OBS = 5


def normal_model(y=None):
    mu = numpyro.sample("mu", dist.Normal(0.0, 1.0))
    with numpyro.plate("obs", N_OBS):
        numpyro.sample("y", dist.Normal(mu, 1.0), obs=y)


def exact_fit(sd_factor):
    """The exact conjugate posterior N(sum y / 6, 1/6), its sd scaled by ``sd_factor``."""

    def fit(kwargs, *, key):
        y = np.asarray(kwargs["y"])
        mean, sd = y.sum() / (1 + N_OBS), np.sqrt(1 / (1 + N_OBS))
        draws = mean + sd_factor * sd * np.asarray(jax.random.normal(key, (2, 300)))
        return az.from_dict(posterior={"mu": draws})

    return fit


def test_driver_passes_exact_posteriors_and_fails_an_overconfident_one(tmp_path):
    kw = dict(key=jax.random.key(2), var_names=["mu"])
    design = SBCDesign(n_datasets=100)
    good = run_sbc(normal_model, design=design, fit=exact_fit(1.0), **kw)
    assert good.uniformity().passed, str(good.uniformity())
    assert good.ranks.shape == (100, 1) and good.names == ("mu",)
    # 600 independent draws: the bulk ESS estimate scatters about 600 (seen 380 to 770)
    assert np.all(good.ess_bulk > 250)
    # half the posterior sd: the truth falls outside the draws about 18 % of the time
    narrow = run_sbc(normal_model, design=design, fit=exact_fit(0.5), **kw)
    test = narrow.uniformity()
    assert not test.passed and test.spread[0] > 1.3
    np.testing.assert_array_equal(narrow.truth, good.truth)  # the same prior draws
    # data sets split over workers and joined equal one run over all of them
    parts = [
        run_sbc(normal_model, design=SBCDesign(100, datasets=d), fit=exact_fit(1.0), **kw)
        for d in ([5, 1], [0])
    ]
    joined = SBCResult.concatenate(parts)
    np.testing.assert_array_equal(joined.datasets, [0, 1, 5])
    np.testing.assert_array_equal(joined.ranks, good.ranks[[0, 1, 5]])
    path = save_sbc(joined, tmp_path / "sbc.json")
    assert load_sbc(path).to_json() == joined.to_json()
    with pytest.raises(FileExistsError):
        save_sbc(joined, path)
    assert json.loads(path.read_text())["n_rank_draws"] == 99
    assert plot_sbc_ranks(good, tmp_path / "ranks.png").stat().st_size > 0


def test_driver_names_unknown_sites():
    with pytest.raises(ValueError, match=r"no sites \['nu'\]"):
        run_sbc(
            normal_model,
            key=jax.random.key(0),
            design=SBCDesign(n_datasets=3),
            fit=exact_fit(1.0),
            var_names=["nu"],
        )


# --- NUTS through sample_nuts on a conjugate target ---------------------------------------------
# D independent data sets in one model (a plate): the joint posterior factorises, so each
# component's marginal is the posterior of its own data set, and one NUTS run gives D
# calibration data sets. One draw of the joint prior predictive is D SBC data sets.
D = 120
N_COUNTS = 3


def many_datasets(y=None, c=None, y_scale=1.0):
    """mu_d ~ N(0, 1), y_di ~ N(mu_d, y_scale); lam_d ~ Gamma(2, 1), c_dk ~ Poisson(lam_d)."""
    with numpyro.plate("dataset", D, dim=-2):
        mu = numpyro.sample("mu", dist.Normal(0.0, 1.0))
        lam = numpyro.sample("lam", dist.Gamma(2.0, 1.0))
        with numpyro.plate("obs", N_OBS, dim=-1):
            numpyro.sample("y", dist.Normal(mu, y_scale), obs=y)
        with numpyro.plate("counts", N_COUNTS, dim=-1):
            numpyro.sample("c", dist.Poisson(lam), obs=c)


def nuts_sbc(y_scale):
    """The SBC of ``many_datasets``, the fit's likelihood scale of y set to ``y_scale``."""

    def fit(kwargs, *, key):
        return sample_nuts(
            many_datasets,
            key=key,
            model_kwargs={**kwargs, "y_scale": y_scale},
            settings=NUTSSettings(
                num_warmup=300, num_samples=300, num_chains=2, jit_model_args=True
            ),
            progress=False,
        )

    result = run_sbc(
        many_datasets,
        key=jax.random.key(11),
        design=SBCDesign(n_datasets=1),
        fit=fit,
        var_names=["mu", "lam"],
        observed=("y", "c"),
    )
    ranks = result.ranks.reshape(2, D).T  # mu[0..D-1], then lam[0..D-1]
    return sbc_uniformity(ranks, result.n_rank_draws, names=["mu", "lam"]), result


# 90 s in the default suite (`pytest -n 2`, 2026-11-27, the 2-core machine under load 12-16):
# simulation-based calibration of NUTS, one run per replicate; in the long tier, which CI runs after
# the default suite
@pytest.mark.long
def test_nuts_on_a_conjugate_target_passes_sbc():
    test, result = nuts_sbc(1.0)
    assert test.passed, str(test)
    # thinned ranks need draws close to independent: NUTS on this target has ESS above 99
    assert result.ess_bulk[0] > result.n_rank_draws


@pytest.mark.long
def test_an_overconfident_likelihood_fails_sbc():
    """Fitted with y's sd halved, mu's posterior sd is 0.22 instead of 0.41: a U shape."""
    test, _ = nuts_sbc(0.5)
    assert not test.passed
    assert test.messages[0].startswith("mu:") and "too narrow" in test.messages[0]
    # lam does not involve y: its ranks stay uniform
    assert min(test.chi2_pvalue[1], test.ks_pvalue[1]) > test.alpha / 4


# --- the reduced door (slow) -------------------------------------------------------------------


@pytest.mark.slow
def test_door_sbc_on_twenty_data_sets(tmp_path):
    """``scripts/sbc.py`` with the surrogate forward: 20 data sets from the reduced door model.

    K, C and mu_d free with the Table 2 prior, the library's likelihood (shared discrepancy
    and run scatter per channel), NUTS 2 x (300 + 300); every ranked scalar must pass at the
    family-wise level 0.01. The exact-simulator version is the same command with
    ``--forward exact`` (hours on two cores; see results/sbc.md).
    """
    root = Path(__file__).resolve().parent.parent
    report = tmp_path / "sbc.md"
    run = subprocess.run(
        [
            sys.executable,
            str(root / "scripts" / "sbc.py"),
            "--forward",
            "surrogate",
            "--n-datasets",
            "20",
            "--workers",
            "2",
            "--work",
            str(tmp_path / "work"),
            "--report",
            str(report),
        ],
        capture_output=True,
        text=True,
        check=True,
        cwd=root,
    )
    assert json.loads(run.stdout.strip().splitlines()[-1])["passed"], run.stderr[-3000:]
    assert "ranks consistent with uniform" in report.read_text()
    assert (tmp_path / "sbc_ranks.png").stat().st_size > 0
