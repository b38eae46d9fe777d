"""Every fenced ```python block of README.md and docs/*.md runs as written.

The blocks of one page run in order in one namespace, as a reader types them, in a fresh
working folder (examples that write files write there), with matplotlib's Agg backend and
``BAYESDOOR_DATA`` pointing at the demo campaign's cache (``$BAYESDOOR_DATA`` or
``~/.cache/bayesdoor``, so that the campaign is recorded once). Blocks written as doctests
(``>>>`` prompts: docs/features.md, docs/data.md) are run, and their printed output compared, by
tests/test_inspect.py; they are left out here. Pages whose examples take more than a few seconds
(a fit, training data, the ensemble, rig runs, a diagnosis) are in the long tier (``make
test-long``), with the reason in ``LONG``; those that take longer (a diagnosis and a job) are
``slow``, in ``SLOW``.

A block whose first line is ``# quoted from PATH`` quotes the project's own file ``PATH``: it
is not run, and its other lines must appear in that file as they stand, so that a guide that
teaches from the source cannot drift from it.
"""

import os
import re
from pathlib import Path

import matplotlib
import pytest

from bayesdoor.door.datasets import cache_dir

ROOT = Path(__file__).resolve().parent.parent
PAGES = ["README.md", *sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "docs").glob("*.md"))]

#: the pages whose examples take more than a few seconds on a 2-core machine, and why
LONG = {
    "README.md": "a quick NUTS fit of the demo campaign",
    "docs/classification.md": "trains the ten-member ensemble for 80 epochs",
    "docs/rig.md": "records three rig runs (about 25 s, most of it compiling the rig's solver)",
}


#: the pages whose examples take longer than the long tier's few minutes (``pytest -m slow``)
SLOW = {
    "docs/datagen.md": "a quick NUTS fit and 180 simulated training runs",
    "docs/diagnosis.md": "a quick diagnosis (CMA-ES fit, refits) and a quick job",
}


def _marks(page: str):
    if page in SLOW:
        return [pytest.mark.slow]
    return [pytest.mark.long] if page in LONG else []


#: the first line of a block that quotes a file of the project
QUOTED = re.compile(r"# quoted from (\S+)\n")


def blocks(page: str) -> list[tuple[int, str]]:
    """The page's ```python blocks that are neither doctests nor quotes, each with its first
    line's number."""
    text = (ROOT / page).read_text(encoding="utf-8")
    found = []
    for match in re.finditer(r"^```python\n(.*?)^```", text, flags=re.S | re.M):
        code = match.group(1)
        if not re.search(r"^\s*>>>", code, flags=re.M) and not QUOTED.match(code):
            found.append((text.count("\n", 0, match.start()) + 2, code))
    return found


def quotes(page: str) -> list[tuple[int, str, str]]:
    """The page's fenced blocks (any language) that quote a file: each block's first line's
    number, the file and the quoted text."""
    text = (ROOT / page).read_text(encoding="utf-8")
    found = []
    for match in re.finditer(r"^```\w*\n(.*?)^```", text, flags=re.S | re.M):
        quote = QUOTED.match(match.group(1))
        if quote:
            line = text.count("\n", 0, match.start()) + 2
            found.append((line, quote.group(1), match.group(1)[quote.end() :]))
    return found


RUNNABLE = [page for page in PAGES if blocks(page)]
QUOTING = [page for page in PAGES if quotes(page)]


def test_every_example_is_collected():
    # the README's example and the guides' examples; a page listed as long still has examples
    assert "README.md" in RUNNABLE and len(RUNNABLE) >= 6, RUNNABLE
    assert set(LONG) | set(SLOW) <= set(RUNNABLE), sorted(set(LONG) | set(SLOW) - set(RUNNABLE))


@pytest.mark.parametrize(
    "page",
    [pytest.param(page, marks=_marks(page)) for page in RUNNABLE],
)
def test_page_examples_run(page, tmp_path, monkeypatch):
    data = Path(os.environ.get("BAYESDOOR_DATA") or cache_dir()).resolve()
    monkeypatch.setenv("BAYESDOOR_DATA", str(data))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    matplotlib.use("Agg")
    monkeypatch.chdir(tmp_path)
    import matplotlib.pyplot as plt

    namespace: dict = {"__name__": "__main__"}
    try:
        for line, code in blocks(page):
            try:
                # padded so that a traceback names the page's own line numbers
                exec(compile("\n" * (line - 1) + code, str(ROOT / page), "exec"), namespace)
            except Exception as error:
                raise AssertionError(f"the block at {page}:{line} fails: {error!r}") from error
    finally:
        plt.close("all")


def test_every_quote_is_collected():
    # the guide to writing a system teaches from the reference system's source
    assert "docs/systems.md" in QUOTING, QUOTING


@pytest.mark.parametrize("page", QUOTING)
def test_quoted_source_stands_in_its_file(page):
    for line, path, quoted in quotes(page):
        source = ROOT / path
        assert source.is_file(), f"{page}:{line} quotes {path}, which does not exist"
        assert quoted in source.read_text(encoding="utf-8"), (
            f"{page}:{line}: the quote of {path} is not in the file as it stands: copy the "
            "lines again from the file"
        )
