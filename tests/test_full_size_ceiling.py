"""The ceiling of ``scripts/full_size_case.py --ceiling``: the base model plus the rig's own effect,
judged as a refit is, on a small door setup."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from test_diagnose_extend import _door_setup

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
from full_size_case import ceiling_gain

from bayesdoor.diagnose._held_out import held_out_folds


@pytest.mark.long
def test_the_ceiling_of_a_leak_is_the_measurement_and_of_nothing_is_zero():
    # A2Z reads 8 % of A2X in the "measurement"; the clean record is the base model's own
    # signals, so the ceiling's model is the measured spectra themselves
    speeds = np.array([0.3, 0.35, 0.45, 0.5])
    setup = _door_setup(speeds, leak=0.08)
    folds = held_out_folds(speeds, 2)
    gain, runs = ceiling_gain(setup, folds, False, setup.base_signals)
    assert sorted(runs) == [0, 1, 2, 3] and len(gain.per_run) == 4
    assert all(d > 0 for d in gain.per_run) and gain.j_after < gain.j_before
    # without the leak the effect's change is nothing: the same model, no gain in any run
    clean = _door_setup(speeds)
    none, _ = ceiling_gain(clean, folds, False, clean.base_signals)
    np.testing.assert_allclose(none.per_run, 0.0, atol=1e-9)
    assert not none.decisive
