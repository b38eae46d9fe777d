"""The hand-over from a diagnosis to its extension uses the proposal the refit chose."""

from __future__ import annotations

import dataclasses

import pytest
from test_diagnosis_gain import stand_in

from bayesdoor.diagnose import ExtensionProposal, verdict_extension
from bayesdoor.systems import ElevatorDoor
from bayesdoor.systems.door import SensorCrossAxis


def test_a_cause_carries_the_proposal_its_refit_chose():
    # the stored proposal's configuration is one the recipe would not propose from the
    # signature (the recipe is not asked again), so only the stored one can give this answer
    proposal = ExtensionProposal(
        extension=SensorCrossAxis(sensor="A1", into="X"),
        start={"sensor_cross_axis.fraction": 0.05},
        free=("sensor_cross_axis.fraction",),
        label="made up for the test",
    )
    diagnosis = stand_in(
        "sensor_cross_axis", 1, label=proposal.label, values={"sensor_cross_axis.fraction": 0.07}
    )
    verdict = diagnosis.cause(diagnosis.verdict)
    causes = tuple(
        dataclasses.replace(c, proposal=proposal) if c is verdict else c for c in diagnosis.causes
    )
    found = verdict_extension(ElevatorDoor(), dataclasses.replace(diagnosis, causes=causes))
    assert found is not None
    assert found.proposal is proposal
    assert found.values == {"sensor_cross_axis.fraction": 0.07}
    # without the stored proposal the recipe is asked again, and it never proposes this label
    with pytest.raises(ValueError, match="made up for the test"):
        verdict_extension(ElevatorDoor(), diagnosis)
