"""The damage report as a reader's browser shows it: rendered by Chromium (Qt WebEngine,
tests/_browser.py), the answer read from the laid-out page and its first screen, not from the
HTML's text. The unlabeled campaign of tests/test_damage_report.py."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from test_damage_report import _report, unlabeled_runs

BROWSER = Path(__file__).with_name("_browser.py")


@pytest.mark.long
def test_a_browser_shows_the_counts_and_the_runs_to_look_at_on_the_first_screen(tmp_path):
    # the engine (PyQt6-WebEngine, in the development install) is imported by the renderer's
    # own process only: a missing engine fails there, with its error below
    _report(tmp_path / "report", unlabeled_runs())
    shot = tmp_path / "shot.png"
    done = subprocess.run(
        [sys.executable, str(BROWSER), str(tmp_path / "report" / "index.html"), str(shot)],
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    dom = json.loads(done.stdout.strip().splitlines()[-1])
    assert dom["loaded"], dom
    # the answer first: the counts per state called, on the first screen, above the trust
    headings = [h["text"] for h in dom["headings"]]
    assert headings[:2] == ["What the runs were called", "Can these results be trusted?"]
    labels = {c["label"].lower(): c["value"] for c in dom["cards"]}
    called = {label: value for label, value in labels.items() if label.startswith("called")}
    assert called == {"called healthy": "4", "called d1": "1", "called d2": "1"}
    first_screen = dom["height"]
    trust_top = dom["headings"][1]["top"]
    assert all(c["top"] < min(first_screen, trust_top) for c in dom["cards"][:3]), dom["cards"]
    # then the runs to look at, the most probably faulty first, as the browser lays them out
    assert [int(row[0]) for row in dom["rows"]] == [2, 1, 4, 3]
    assert dom["rows"][2][-1].endswith("uncertain") and "(OOD)" in dom["rows"][3][-1]
    # an unlabeled campaign's charts by the state called; every figure drawn
    assert "grouped by the state it was called" in dom["text"]
    assert dom["images"] and all(i["complete"] and i["width"] > 0 for i in dom["images"])
    assert shot.stat().st_size > 10_000
