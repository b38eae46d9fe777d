"""The contact-law ablation script: its warm start per law, and (slow) one quick run end to end."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bayesdoor.door.contact import get_law

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "scripts" / "contact_law_ablation.py"


def _script():
    spec = importlib.util.spec_from_file_location("contact_law_ablation", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


ablation = _script()

#: closed-form inverses c_r(xi) of three laws, an independent reference for the root finder
INVERSES = {
    1: lambda xi: 1.0 / (1.0 + xi),  # xi = (1 - c) / c
    3: lambda xi: 8.0 / (8.0 + 5.0 * xi),  # xi = 8 (1 - c) / (5 c)
    4: lambda xi: 1.0 - 4.0 * xi / 3.0,  # xi = 3 (1 - c) / 4
    5: lambda xi: 1.0 - 2.0 * xi / 3.0,  # xi = 3 (1 - c) / 2
}


@pytest.mark.parametrize("law", sorted(INVERSES))
@pytest.mark.parametrize("xi", [0.1, 0.2, 0.25])
def test_matched_c_r_inverts_the_hysteresis_factor(law, xi):
    # brentq's xtol is 1e-12 on a smooth monotone function: 1e-9 leaves room for rounding
    assert ablation.matched_c_r(law, xi, 0.6, 0.95) == pytest.approx(INVERSES[law](xi), abs=1e-9)


@pytest.mark.parametrize("law", range(1, 10))
def test_every_law_delivers_the_reference_xi_where_it_can(law):
    reference = {"K": 2000.0, "n": 1.8, "c_r": 0.84, "mu_s": 0.75, "mu_d": 0.7, "C": 0.01}
    reference |= {"MF": 1.2, "I": 3.0}
    xi = float(get_law(3).hysteresis_factor(np.asarray(0.84)))
    start = ablation.warm_start(reference, 3, law, (0.6, 0.95))
    assert "I" not in start
    assert {k: v for k, v in start.items() if k != "c_r"} == {
        k: v for k, v in reference.items() if k not in ("c_r", "I")
    }
    reach = np.asarray(get_law(law).hysteresis_factor(np.array([0.95, 0.6])))
    delivered = float(get_law(law).hysteresis_factor(np.asarray(start["c_r"])))
    if reach[0] <= xi <= reach[1]:
        assert delivered == pytest.approx(xi, rel=1e-9)
    else:
        # Lee and Wang (law 4) tops out at xi = 0.30 < Flores' 0.305 at c_r = 0.84
        assert law == 4
        assert start["c_r"] == 0.6


def test_matched_c_r_clips_to_the_nearer_bound():
    assert ablation.matched_c_r(4, 0.5, 0.6, 0.95) == 0.6
    assert ablation.matched_c_r(4, 0.01, 0.6, 0.95) == 0.95
    with pytest.raises(ValueError, match=r"lower=0\.9"):
        ablation.matched_c_r(4, 0.1, 0.9, 0.6)


def test_per_law_settings_are_a_warm_start_of_the_reference_settings():
    reference = ablation.settings_for("reference", quick=False)
    warm = ablation.settings_for("law", quick=False)
    assert warm.cmaes_sigma0 < reference.cmaes_sigma0
    assert warm.cmaes_max_evals < reference.cmaes_max_evals
    assert warm.cmaes_restarts == 0
    assert warm.num_chains * warm.num_samples >= 4000
    # everything that shapes the posterior other than the search is the campaign fit's
    assert (warm.max_motion_s, warm.train_per_term, warm.box_fraction) == (
        reference.max_motion_s,
        reference.train_per_term,
        reference.box_fraction,
    )


@pytest.mark.slow
def test_quick_ablation_of_two_laws_writes_and_resumes(tmp_path):
    out = tmp_path / "ablation.md"
    command = [
        sys.executable,
        str(SCRIPT),
        "--quick",
        "--laws",
        "3",
        "4",
        "--workers",
        "2",
        "--work",
        str(tmp_path / "work"),
        "--out",
        str(out),
    ]
    subprocess.run(command, check=True, cwd=ROOT, timeout=3600)
    record = json.loads(out.with_suffix(".json").read_text())
    assert [row["law"] for row in record["laws"]] == [3, 4]
    assert all(row["parameter"] == "I" and row["value"] == row["law"] for row in record["laws"])
    assert record["partial"] == [1, 2, 5, 6, 7, 8, 9]
    assert "PARTIAL" in out.read_text()
    first = out.with_suffix(".json").read_text()
    # a second run reads every fit back from --work: same numbers, no fit redone
    done = subprocess.run(command, check=True, cwd=ROOT, timeout=600, capture_output=True)
    assert b"law 3:" not in done.stderr and b"shared search" not in done.stderr
    assert json.loads(out.with_suffix(".json").read_text())["laws"] == json.loads(first)["laws"]
