"""The door's catalogue declares the family's transmissions that the family benchmark measured.

``FAMILY_TRANSMISSION`` (bayesdoor/door/_catalogue.py) holds, per cause, the smallest and
largest ratio and the smallest share explained over the development doors, as
``scripts/diagnosis_transmission.py`` wrote them to results/diagnosis_transmission.json; a
results file made again with other figures, or a constant edited by hand, fails here until the
two agree. The figures docs/diagnosis.md quotes are checked the same way.
"""

import json
import re
from pathlib import Path

import pytest

from bayesdoor.diagnose import Transmission
from bayesdoor.door import DOOR_CATALOGUE
from bayesdoor.door._catalogue import FAMILY_TRANSMISSION

ROOT = Path(__file__).resolve().parent.parent
MEASURED = json.loads((ROOT / "results" / "diagnosis_transmission.json").read_text())


@pytest.mark.parametrize("cause", sorted(FAMILY_TRANSMISSION))
def test_each_declared_transmission_is_the_measured_one(cause):
    declared, measured = FAMILY_TRANSMISSION[cause], MEASURED["causes"][cause]
    assert declared.machines == measured["machines"]
    for name in ("low", "high", "explained"):
        assert getattr(declared, name) == pytest.approx(measured[name], rel=5e-3), name
    # and what it decides: a family limit where every development door's change is the
    # model's, scaled; none where a door's change lies in other bins
    rebuilt = Transmission(measured["low"], measured["high"], measured["explained"], 1)
    assert declared.reliable == rebuilt.reliable


def test_the_recipes_carry_the_declared_transmissions():
    sizes = {
        c.name: c.refit.size(band=(4.0, 96.0))
        for c in DOOR_CATALOGUE.candidates
        if c.refit is not None and c.refit.size(band=(4.0, 96.0)) is not None
    }
    for cause, declared in FAMILY_TRANSMISSION.items():
        assert sizes[cause].transmission is declared
    # the frame mode's transmission is not measured (every door of the family carries one)
    assert sizes["frame_mode"].transmission is None


def test_the_results_table_is_the_json_it_was_written_with():
    text = (ROOT / "results" / "diagnosis_transmission.md").read_text()
    for cause, m in MEASURED["causes"].items():
        ratio = f"{m['low']:.2f}-{m['high']:.2f}"
        row = f"| {cause} | {m['machines']} | {ratio} | {m['explained']:.2f} |"
        assert row in text, row


def test_the_guide_quotes_the_measured_factors():
    guide = " ".join((ROOT / "docs" / "diagnosis.md").read_text().split())
    hum = MEASURED["causes"]["mains_hum"]
    leak = MEASURED["causes"]["sensor_cross_axis"]
    assert f"{1 / hum['low']:.1f} times the model limit" in guide
    assert f"ratio {leak['low']:.2f}-{leak['high']:.2f}" in guide
    for cause in ("rail_waviness", "wheel_eccentricity"):
        share = round(100 * MEASURED["causes"][cause]["explained"])
        assert re.search(rf"{cause}[^.]*at worst {share} %", guide), cause


def test_the_summary_learns_on_the_development_doors_and_checks_the_held_out_ones():
    import sys

    sys.path.insert(0, str(ROOT / "scripts"))
    import diagnosis_transmission as script

    def door(seed, ratio, explained):
        return {"door": seed, "causes": {"mains_hum": {"ratio": ratio, "explained": explained}}}

    doors = [door(0, 0.2, 0.9), door(1, 0.5, 0.6), door(12, 0.1, 0.4), door(13, 0.3, 0.8)]
    table = script.summary(doors, [0, 1])["mains_hum"]
    assert (table["low"], table["high"], table["explained"], table["machines"]) == (
        0.2,
        0.5,
        0.6,
        2,
    )
    # the held-out doors: one at or above the development doors' least ratio, one under it
    assert (table["held_out"], table["held_out_covered"], table["held_out_explained"]) == (
        2,
        1,
        0.4,
    )
