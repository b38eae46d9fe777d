"""The speed figures of README.md and docs/validation.md are those of results/performance.json,
which ``python benchmarks/bench_job.py --warm-up --results results/performance.md`` writes."""

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
RESULT = json.loads((ROOT / "results" / "performance.json").read_text())


def _figures() -> dict[str, str]:
    job, stick = RESULT["job"], RESULT["yardstick"]
    return {
        "job": f"{job['wall_s']:.0f} s ({job['scipy_runs']:.0f} scipy runs",
        "simulate": (
            f"{stick['simulate_x_scipy']:.0f}x faster ({stick['batch_float64_ms_per_run']:.1f} "
            "ms a run"
        ),
    }


@pytest.mark.parametrize("page", ["README.md", "docs/validation.md"])
def test_the_pages_quote_the_benchmarks_figures(page):
    text = (ROOT / page).read_text()
    for name, figure in _figures().items():
        assert figure in text, f"{page} does not quote the benchmark's {name}: {figure!r}"
    if page.startswith("docs/"):
        assert f"commit {RESULT['commit']}" in text


def test_the_result_names_its_command_date_and_commit():
    assert RESULT["command"].startswith("python benchmarks/bench_job.py")
    assert RESULT["date"] and RESULT["commit"] not in ("", "unknown")
    assert not RESULT["commit"].endswith("+changes"), "measured on code that was not committed"
    assert RESULT["warm_up"] is True
