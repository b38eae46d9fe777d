"""The damage report leads with the answer: how many runs were called each state and the runs
to look at first, above the details; an unlabeled campaign's charts by the state called."""

import re
from html.parser import HTMLParser

import numpy as np

from bayesdoor.report import ReportContext, write_damage_report

CLASSES = ["healthy", "D1", "D2"]


class _Text(HTMLParser):
    """The page's headings in order and its visible text."""

    def __init__(self):
        super().__init__()
        self.headings, self.text, self._tag = [], [], None

    def handle_starttag(self, tag, attrs):
        self._tag = tag

    def handle_data(self, data):
        if self._tag == "h2":
            self.headings.append(data)
        if self._tag not in ("style", "script"):
            self.text.append(data)


def _run(i, p, state="unknown", ood=False, uncertain=False):
    probabilities = dict(zip(CLASSES, p, strict=True))
    return {
        "run": i,
        "state": state,
        "predicted": max(probabilities, key=probabilities.get),
        "probabilities": probabilities,
        "entropy": 0.1,
        "mutual_information": 0.01,
        "ood": ood,
        "ood_score": 5.0 if ood else 1.0,
        "uncertain": uncertain,
        "corroborated": None,
        "problem": None,
        "operating": 0.3,
    }


def _report(tmp_path, runs):
    classification = {
        "classes": CLASSES,
        "runs": runs,
        "metrics": None,
        "ood_threshold": 3.0,
        "temperature": 1.2,
    }
    features = np.zeros((len(runs), 2, 8))
    index = write_damage_report(
        tmp_path,
        classification,
        features=features,
        frequencies=np.arange(8.0),
        channels=["X", "Z"],
        context=ReportContext(
            trust={"verdict": "limited", "reasons": ["one run flagged"], "flagged_runs": [3]}
        ),
    )
    parser = _Text()
    parser.feed(index.read_text())
    return parser, index.read_text()


def unlabeled_runs() -> list[dict]:
    """Six runs of unknown state: four called healthy (one OOD, one uncertain), one D1, one D2."""
    return [
        _run(0, [0.96, 0.02, 0.02]),
        _run(1, [0.10, 0.85, 0.05]),
        _run(2, [0.01, 0.01, 0.98]),
        _run(3, [0.90, 0.05, 0.05], ood=True),
        _run(4, [0.55, 0.40, 0.05], uncertain=True),
        _run(5, [0.97, 0.02, 0.01]),
    ]


def test_an_unlabeled_campaign_opens_with_the_counts_and_the_runs_to_look_at(tmp_path):
    parser, page = _report(tmp_path, unlabeled_runs())
    assert parser.headings[0] == "What the runs were called"
    assert parser.headings[1] == "Can these results be trusted?"
    text = " ".join(parser.text)
    opening = text[: text.index("Can these results be trusted?")]
    for label, count in (("called healthy", 4), ("called D1", 1), ("called D2", 1)):
        assert re.search(rf"\b{count}\s*{label}", opening), (label, opening)  # value, label
    # the runs to look at: called a fault (most probably faulty first), then those not vouched for
    order = [int(n) for n in re.findall(r'href="runs/run-(\d{4})\.html"', page.split("<h2>")[1])]
    assert order == [2, 1, 4, 3]
    assert "unlike every simulated state (OOD)" in opening and "uncertain" in opening
    assert "grouped by the state it was called" in text


def test_a_campaign_called_healthy_throughout_says_so(tmp_path):
    parser, _ = _report(tmp_path, [_run(i, [0.97, 0.02, 0.01], state="healthy") for i in range(3)])
    text = " ".join(parser.text)
    assert "No run was called a fault, and the classifier vouches for every one." in text
    assert "grouped by true state" in text
