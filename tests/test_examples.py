"""The notebooks in ``examples/`` run from top to bottom at their tiny size.

Each notebook is a jupytext percent-format script, executed here with ``runpy`` under
``BAYESDOOR_EXAMPLE_SIZE=tiny`` and matplotlib's non-interactive backend, writing into a
temporary folder (``BAYESDOOR_EXAMPLE_OUT``) with its own demo-campaign cache
(``BAYESDOOR_DATA``). Notebooks 3 and 4 start from the fit notebook 2 saves, so those three run in
one test, in order (a parallel test runner may not split them). Beyond running, the tests check
what the notebooks' text claims of their results.
"""

import json
import runpy
from pathlib import Path

import matplotlib
import numpy as np
import pytest

from bayesdoor.door import DOOR_CATALOGUE

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


@pytest.fixture
def tiny(tmp_path, monkeypatch):
    """The environment of a tiny run: size, output folder, data cache, Agg backend."""
    monkeypatch.setenv("BAYESDOOR_EXAMPLE_SIZE", "tiny")
    monkeypatch.setenv("BAYESDOOR_EXAMPLE_OUT", str(tmp_path))
    monkeypatch.setenv("BAYESDOOR_DATA", str(tmp_path / "data"))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    matplotlib.use("Agg")
    return tmp_path


def _run(name: str) -> dict:
    import matplotlib.pyplot as plt

    try:
        return runpy.run_path(str(EXAMPLES / name), run_name="__main__")
    finally:
        plt.close("all")


def test_every_notebook_is_tested():
    names = sorted(p.name for p in EXAMPLES.glob("[0-9][0-9]_*.py"))
    assert names == [
        "01_simulate_and_contact_laws.py",
        "02_model_updating.py",
        "03_training_calibration_report.py",
        "04_diagnosing_a_discrepancy.py",
        "05_real_bearing.py",
    ]


def test_unknown_size_is_refused(tiny, monkeypatch):
    monkeypatch.setenv("BAYESDOOR_EXAMPLE_SIZE", "huge")
    with pytest.raises(ValueError, match="BAYESDOOR_EXAMPLE_SIZE='huge': use one of tiny"):
        _run("01_simulate_and_contact_laws.py")


#: 22-107 s with an empty JAX cache on a 2-core machine (the higher figures with other work
#: beside it; the nine contact laws' solves compiled): in the long tier, which CI runs after the
#: default suite (tests/test_contact.py checks the laws themselves)
@pytest.mark.long
def test_01_simulate_and_contact_laws(tiny):
    g = _run("01_simulate_and_contact_laws.py")
    # the text's claim: with matched xi the nine laws give the same run. The force depends on
    # (law, c_r) through xi only, so the runs agree to the solver's round-off (adaptive steps
    # at rtol 1e-8 leave ~1e-10 decades); 1e-6 decades is far below any physical difference
    # (the unmatched laws differ by 0.2-0.8 decades) and far above round-off
    assert g["matched_spread"].max() < 1e-6
    # ... while at one nominal c_r they differ by "several times the Welch scatter" (7.6 times
    # at the tiny size's 0.5 m/s when written)
    assert g["spread"].max() > 5 * g["welch_sd"]
    # delivered restitution: a physical fraction, and Lankarani-Nikravesh at c_r = 0.9 within
    # 2 % of nominal (its factor is exact to first order in 1 - c_r; docs/model.md)
    assert np.all((g["delivered"] > 0) & (g["delivered"] < 1))
    assert abs(g["delivered"][5, -1] - 0.9) < 0.02
    assert len(list((tiny / "01").glob("*.png"))) == 5


#: 210-220 s with an empty JAX cache, most of it tracing and compiling: in the
#: long tier, which CI runs after the default suite
@pytest.mark.long
def test_02_03_04_update_train_report_diagnose(tiny):
    g2 = _run("02_model_updating.py")
    assert (tiny / "02" / "fit" / "fit.json").is_file()
    assert g2["fit"].idata is not None and 0.0 <= g2["inside"].mean() <= 1.0
    assert g2["fit"].held["I"] in range(1, 10)

    g3 = _run("03_training_calibration_report.py")
    report = tiny / "03" / "report" / "index.html"
    assert report.is_file() and (tiny / "03" / "report" / "runs").is_dir()
    classification = json.loads((tiny / "03" / "classify" / "classification.json").read_text())
    assert classification["n_runs"] == g3["test"].sizes["run"] == 6
    # the notebook's metrics are those of the report (same ensemble, same runs)
    assert classification["metrics"]["accuracy"] == pytest.approx(g3["metrics"]["accuracy"])

    g4 = _run("04_diagnosing_a_discrepancy.py")
    for diagnosis in (g4["diagnosis"], g4["reference"]):
        assert diagnosis.verdict in DOOR_CATALOGUE.names
    # the four rig runs with the effect were diagnosed, with the fit's band
    assert g4["diagnosis"].runs.tolist() == [0, 1, 2, 3]
    assert g4["residuals"].freqs.min() >= g2["fit"].feature_spec.f_low
    assert (tiny / "04" / "residual_map.png").is_file()


#: the real CWRU records, outside the repository (the notebook's default folder)
CWRU = EXAMPLES.parent.parent / "shared" / "data" / "cwru"


#: 40-100 s on a 2-core machine (reading the records, a quick CMA-ES fit): in the long tier
@pytest.mark.long
@pytest.mark.skipif(not CWRU.is_dir(), reason="the CWRU records are not at ../shared/data/cwru")
def test_05_real_bearing(tiny, monkeypatch):
    monkeypatch.setenv("BAYESDOOR_CWRU", str(CWRU))
    g = _run("05_real_bearing.py")
    # the text's claim: the geometry gives the CWRU documentation's orders (to its digits)
    for name, value in g["cwru"].items():
        assert g["orders"][name] == pytest.approx(value, abs=5e-5)
    # every test segment called, by the rule whose reference is the calibration split only
    assert len(g["calls"]) == len(g["test"]) == g["runs"] - len(g["calibration"])
    assert set(g["state"][g["calibration"]]) == {"healthy"}
    assert len(g["votes"]) == len(set(g["record"]))
    assert g["band_error_db"].shape == g["edges"].shape
    assert (tiny / "05" / "healthy_psd.png").is_file()
    assert (tiny / "05" / "envelope_spectra.png").is_file()
