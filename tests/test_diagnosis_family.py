"""The door-family diagnosis benchmark's bookkeeping (scripts/diagnosis_family.py): what counts
as a false alarm on a door that carries causes of its own, the symptom veto recounted, and how a
hidden cause's refitted size is read against the size hidden."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))

import diagnosis_family as fam


def _refit(name, *, decisive, confirmed, share=None, label="", **parameters):
    return {
        "name": name,
        "decisive": decisive,
        "confirmed": confirmed,
        "feature_share": share,
        "label": label,
        "parameters": parameters,
    }


def _row(cause, size, refits):
    return {
        "cause": cause,
        "size": size,
        "confirmed": [r["name"] for r in refits if r["confirmed"]],
        "refits": refits,
    }


def test_a_cause_the_door_carries_or_had_hidden_is_no_false_alarm():
    refits = [
        _refit("frame_mode", decisive=True, confirmed=True, share=0.6),
        _refit("sensor_cross_axis", decisive=True, confirmed=True),
        _refit("mains_hum", decisive=True, confirmed=True),
        _refit("rail_waviness", decisive=False, confirmed=False),
    ]
    assert fam.false_alarms(_row(fam.NOTHING, None, refits)) == ["mains_hum"]
    assert fam.false_alarms(_row("mains_hum", 0.01, refits)) == []


def test_without_the_veto_every_decisive_refit_counts():
    vetoed = _refit("frame_mode", decisive=True, confirmed=False, share=-0.1)
    row = _row(fam.NOTHING, None, [vetoed, _refit("mains_hum", decisive=False, confirmed=False)])
    assert fam.confirmed_by(row, "veto") == []
    assert fam.confirmed_by(row, "no veto") == ["frame_mode"]


def test_a_hidden_cause_is_read_in_the_configuration_it_was_hidden_in():
    door = {"gains_db": [0.0, 0.0, 0.0, 0.0], "mounting_deg": [0.0, 0.0]}
    rail = _refit(
        "rail_waviness",
        decisive=True,
        confirmed=True,
        **{
            "rail_waviness.wavelength_m": 25.4e-3,
            "rail_waviness.sin_left_m": 3e-6,
            "rail_waviness.cos_left_m": 4e-6,  # 5 um under the left wheel
            "rail_waviness.sin_right_m": 0.0,
            "rail_waviness.cos_right_m": 3e-6,  # 3 um under the right
        },
    )
    assert fam.transmission(_row("rail_waviness", 8e-6, [rail]), door) == pytest.approx(
        (4e-6, 8e-6)
    )
    # refitted at another wavelength: not the hidden rail
    far = dict(rail, parameters={**rail["parameters"], "rail_waviness.wavelength_m": 12e-3})
    assert fam.transmission(_row("rail_waviness", 8e-6, [far]), door) is None
    # the leak: the mounting's rotation adds sin(angle) of the other axis, in the gain ratio
    tilted = {"gains_db": [20 * np.log10(1.1), 0.0, 0.0, 0.0], "mounting_deg": [2.0, 0.0]}
    leak = _refit(
        "sensor_cross_axis",
        decisive=True,
        confirmed=True,
        label="A1X reads A1Z",
        **{"sensor_cross_axis.fraction": 0.05},
    )
    refit, hidden = fam.transmission(_row("sensor_cross_axis", 0.02, [leak]), tilted)
    assert refit == 0.05 and hidden == pytest.approx((0.02 + np.sin(np.radians(2.0))) * 1.1)
    other = dict(leak, label="A2X reads A2Z")
    assert fam.transmission(_row("sensor_cross_axis", 0.02, [other]), tilted) is None
    # a cause not refitted, or nothing hidden
    assert fam.transmission(_row("mains_hum", 0.01, []), door) is None
    assert fam.transmission(_row(fam.NOTHING, None, [leak]), door) is None


def test_a_cause_is_hidden_at_its_family_limit_only_where_the_family_transmits_it():
    from bayesdoor.door._catalogue import FAMILY_TRANSMISSION

    for cause, t in FAMILY_TRANSMISSION.items():
        scale = fam.family_scale(cause)
        assert (scale is None) == (not t.reliable), cause
        if scale is not None:
            assert scale == pytest.approx(1.0 / t.low)
    assert fam.family_scale("frame_mode") is None
