"""The main job with ``extend``: the same job on the system extended by the diagnosis's verdict.

The tone system of ``test_pipeline`` gains one model extension (a 60 Hz hum in X), and a
stand-in diagnosis names it with a refitted amplitude, so the hand-over from the verdict to the
extended job is tested in seconds; :func:`bayesdoor.diagnose.extend_system` itself is tested
on the door in ``test_diagnosis_gain``.
"""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
from types import SimpleNamespace

import equinox as eqx
import jax.numpy as jnp
import pytest
from _toy_system import FS, ToySystem
from test_pipeline import (
    SIZES,
    SYSTEM,
    job_arguments,
    stand_in_diagnose,
    stand_in_fit,
    tone_campaign,
)

from bayesdoor.diagnose import ExtensionProposal, HeldExtension
from bayesdoor.pipeline import run_job
from bayesdoor.report import EXTENSION_PROVENANCE, extension_section
from bayesdoor.systems import ParameterSpec

HUM = ParameterSpec("hum.amplitude", "-", 0.0, 0.0, 0.1, "amplitude of a 60 Hz hum in X")


class HumTones(ToySystem):
    """The tone system with one model extension: a 60 Hz hum in X (off by default)."""

    hum: bool = eqx.field(static=True, default=False)

    @property
    def parameters(self):
        return (*super().parameters, *((HUM,) if self.hum else ()))

    @property
    def extension_names(self):
        return ("hum",) if self.hum else ()

    def with_extensions(self, *extensions):
        assert extensions == ("hum",), extensions
        return dataclasses.replace(self, hum=True)

    def describe(self):
        return {"name": self.name, "extensions": list(self.extension_names)}

    def simulate_values(self, values, operating, **options):
        res = super().simulate_values(values, operating, **options)
        if not self.hum:
            return res
        amplitude = jnp.reshape(jnp.asarray(values[HUM.name], dtype=float), (-1, 1))
        t = jnp.arange(res.signals.shape[-1], dtype=float) / FS
        x = res.signals[:, 0] + amplitude * jnp.sin(2 * jnp.pi * 60.0 * t)
        return eqx.tree_at(lambda r: r.signals, res, res.signals.at[:, 0].set(x))


BASE = HumTones(
    label="tones",
    d2_amplitude=SYSTEM.d2_amplitude,
    d2_phase=SYSTEM.d2_phase,
    background=SYSTEM.background,
)
PROPOSAL = ExtensionProposal(
    extension="hum", start={HUM.name: 0.0}, free=(HUM.name,), label="a 60 Hz hum in X"
)
HELD = 0.03


class HumDiagnosis:
    """What the job reads of a diagnosis that names the hum: its JSON, its verdict's cause
    (the refit's proposal and amplitude) and its catalogue's recipe for it."""

    verdict = "hum"

    def __init__(self):
        self.catalogue = SimpleNamespace(
            candidates=(SimpleNamespace(name="hum", refit="a stand-in recipe"),), names=("hum",)
        )
        self._cause = SimpleNamespace(
            name="hum",
            label=PROPOSAL.label,
            proposal=PROPOSAL,
            parameters={HUM.name: {"mean": HELD, "sd": 0.005}},
        )

    def cause(self, name):
        assert name == "hum"
        return self._cause

    def to_json(self):
        return {
            "verdict": "hum",
            "causes": [
                {
                    "name": "hum",
                    "evidence": "a 60 Hz line in X",
                    "parameters": self._cause.parameters,
                    "gain": {},
                }
            ],
        }


CALLS = {"diagnose": 0, "fit": []}


def hum_diagnose(system, campaign, fit_folder, *, seed, quick, progress):
    CALLS["diagnose"] += 1
    return HumDiagnosis()


def recording_fit(system, campaign, **options):
    CALLS["fit"].append(system)
    return stand_in_fit(system, campaign, **options)


def job(out, **kw):
    settings = dict(
        seed=0,
        sizes=SIZES,
        fit=recording_fit,
        diagnose=hum_diagnose,
        progress=False,
        extend=True,
        report=lambda line: None,
    )
    settings.update(kw)
    config, options = job_arguments(**settings)
    return run_job(BASE, tone_campaign(), out, config, **options)


def test_extend_needs_the_diagnosis(tmp_path):
    with pytest.raises(ValueError, match="diagnosis=False skips the diagnosis"):
        job(tmp_path / "job", diagnosis=False)
    assert not (tmp_path / "job").exists()


def test_the_extension_section_compares_or_says_why_not():
    before = {"accuracy": 0.833, "ece": 0.091, "trust": "trusted"}
    after = {"accuracy": 0.867, "ece": 0.077, "trust": "limited", "report": "../x/index.html"}
    page = extension_section(
        {
            "verdict": "frame_mode",
            "configuration": "a mode on the rail",
            "held": {"frame_mode.frequency_hz": 42.5},
            "before": before,
            "after": after,
        }
    )
    for text in ("frame_mode.frequency_hz = 42.5", "0.833", "0.867", "limited", "../x/index.html"):
        assert text in page, text
    assert "never informed the diagnosis" in page
    none = extension_section({"reason": "the verdict is none", "before": before, "after": None})
    assert "Nothing was extended: the verdict is none" in none and "0.833" not in none


# 15 s on the 2-core machine (2026-11-27, `pytest -n 0`): two tone jobs, the base twice more
@pytest.mark.long
def test_the_job_extended_by_the_verdict_runs_beside_it_and_is_reused(tmp_path):
    out = tmp_path / "job"
    CALLS.update(diagnose=0, fit=[])
    result = job(out)
    extended = result.extended
    assert extended is not None and extended.out == out / "extended"
    assert extended.extends == {
        "verdict": "hum",
        "configuration": PROPOSAL.label,
        "held": {HUM.name: HELD},
    }
    # the extended job fitted the hum-extended system, the hum held at the refitted amplitude
    assert CALLS["diagnose"] == 1 and len(CALLS["fit"]) == 2
    fitted = CALLS["fit"][1]
    assert isinstance(fitted, HeldExtension) and fitted.held_values == {HUM.name: HELD}
    assert fitted.system.extension_names == ("hum",)
    stage = json.loads((out / "extended" / "fit" / "stage.json").read_text())
    assert "hum.amplitude" in stage["config"]["system"]["repr"]
    assert [s.name for s in extended.stages] == [
        "fit",
        "generate",
        "adequacy",
        "train",
        "classify",
        "trust",
        "report",
    ]
    payload = result.to_json()["extended"]
    assert payload["held"] == {HUM.name: HELD} and payload["verdict"] == "hum"
    assert payload["metrics"] == extended.classification["metrics"]
    assert payload["trust"]["verdict"] in ("trusted", "limited", "not trusted")
    record = json.loads((out / "job.json").read_text())["extended"]
    assert record["out"] == str(out / "extended") and record["held"] == {HUM.name: HELD}
    index = (out / "report" / "index.html").read_text()
    assert "With the diagnosed extension" in index
    assert EXTENSION_PROVENANCE in index.replace("&#x27;", "'")
    links = re.findall(r'href="(\.\./extended/[^"]*)"', index)
    assert links == ["../extended/report/index.html"]
    assert (out / "report" / links[0]).resolve().is_file()

    # a second call recomputes nothing, in either job
    again = job(out)
    assert all(s.reused for s in again.stages), [(s.name, s.reused) for s in again.stages]
    assert again.extended is not None
    assert all(s.reused for s in again.extended.stages)
    assert CALLS["diagnose"] == 1 and len(CALLS["fit"]) == 2
    assert again.to_json()["extended"]["metrics"] == payload["metrics"]

    # a diagnosis whose verdict is none extends nothing, and the report says so
    shutil.rmtree(out / "diagnose")
    plain = job(out, diagnose=stand_in_diagnose)
    assert plain.extended is None and plain.to_json()["extended"] is None
    assert "verdict is none" in plain.extension["reason"]
    assert {s.name: s.reused for s in plain.stages}["train"]
    assert "Nothing was extended" in (out / "report" / "index.html").read_text()
    assert json.loads((out / "job.json").read_text())["extended"] is None


class _Called(Exception):
    """Raised by the stand-in job with the options the command passed it."""


def test_run_extend_reaches_the_job_and_its_summary(tmp_path, monkeypatch):
    from test_robustness import campaign, invoke

    import bayesdoor.pipeline
    from bayesdoor.cli._run import extension_lines
    from bayesdoor.io import save_campaign

    def called(system, data, out, config, **options):
        raise _Called(config)

    monkeypatch.setattr(bayesdoor.pipeline, "run_job", called)
    path = save_campaign(campaign(), tmp_path / "door.nc")
    for flags, extend in (([], False), (["--extend"], True)):
        result = invoke("run", path, "--out", tmp_path / "job", *flags)
        assert isinstance(result.exception, _Called), result.output
        assert result.exception.args[0].extend is extend
    base = {"metrics": {"accuracy": 0.833, "ece": 0.091}, "trust": {"verdict": "trusted"}}
    extended = {
        "verdict": "frame_mode",
        "configuration": "a mode on the rail",
        "held": {"frame_mode.frequency_hz": 42.5},
        "out": "out/job/extended",
        "metrics": {"accuracy": 0.867, "ece": 0.077},
        "trust": {"verdict": "limited"},
    }
    lines = extension_lines({**base, "extended": extended})
    assert "frame_mode.frequency_hz = 42.5" in lines[0]
    assert lines[1:4] == [
        "  accuracy: 0.833 -> 0.867",
        "  ECE: 0.091 -> 0.077",
        "  trust: trusted -> limited",
    ]
    assert "never informed the diagnosis" in lines[4]
    none = extension_lines({**base, "diagnosis": {"verdict": "none"}, "extended": None})
    assert none == ["with the diagnosed extension: nothing was extended (verdict none)"]


def test_a_kept_diagnosis_extends_the_door_as_the_diagnosis_itself(tmp_path):
    """The stage pickles the diagnosis without its fit; read back, it gives the same system."""
    from test_diagnosis_gain import stand_in

    from bayesdoor.diagnose import extend_system
    from bayesdoor.door import ElevatorDoor
    from bayesdoor.pipeline._diagnose import keep_diagnosis, kept_diagnosis

    diagnosis = stand_in(
        "sensor_cross_axis", 0, label=None, values={"sensor_cross_axis.fraction": 0.07}
    )
    assert diagnosis.verdict == "sensor_cross_axis"
    assert keep_diagnosis(dataclasses.replace(diagnosis, fit="the job's fit"), tmp_path)
    back = kept_diagnosis(tmp_path)
    assert back.fit is None  # the job keeps its fit in OUT/fit
    door = ElevatorDoor()
    expected = extend_system(door, diagnosis).describe()
    assert extend_system(door, back).describe() == expected
    assert expected["held"] == {"sensor_cross_axis.fraction": 0.07}
    (tmp_path / "diagnosis.pkl").write_bytes(b"not a pickle")
    with pytest.raises(ValueError, match="cannot be read back"):
        kept_diagnosis(tmp_path)
