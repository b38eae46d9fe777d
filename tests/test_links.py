"""Every relative link of README.md, docs/*.md and results/*.md leads to a file of the
repository, and a link to a heading of a Markdown page (``page.md#heading``) to a heading that
page has (MkDocs' slugs: lower case, punctuation dropped, spaces as hyphens)."""

import re
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [
    ROOT / "README.md",
    *sorted((ROOT / "docs").glob("*.md")),
    *sorted((ROOT / "results").glob("*.md")),
]
#: ``[text](target)`` and ``![alt](target)``, the target up to a space or the closing bracket
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^(```|~~~).*?^\1", flags=re.S | re.M)
CODE = re.compile(r"`[^`\n]*`")


def _prose(text: str) -> str:
    """The page without its fenced blocks and inline code (their brackets are not links)."""
    return CODE.sub("", FENCE.sub("", text))


def _slug(heading: str) -> str:
    """The anchor Python-Markdown's ``toc`` extension gives a heading."""
    text = unicodedata.normalize("NFKD", CODE.sub(lambda m: m.group(0)[1:-1], heading))
    text = re.sub(r"[^\w\s-]", "", text.encode("ascii", "ignore").decode()).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def _anchors(page: Path) -> set[str]:
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    return {_slug(h) for h in re.findall(r"^#{1,6}\s+(.*?)\s*#*$", text, flags=re.M)}


def links(page: Path) -> list[str]:
    return [
        target
        for target in LINK.findall(_prose(page.read_text(encoding="utf-8")))
        if not re.match(r"^[a-z][a-z0-9+.-]*:", target)  # http:, https:, mailto:
    ]


def test_the_pages_hold_relative_links():
    # the check below reads links at all: the README and the docs link to each other
    assert len(links(ROOT / "README.md")) >= 10
    assert len(links(ROOT / "docs" / "index.md")) >= 10


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_resolves(page):
    broken = []
    for target in links(page):
        path, _, anchor = target.partition("#")
        resolved = (page.parent / path).resolve() if path else page
        if not resolved.exists() or ROOT not in (resolved, *resolved.parents):
            broken.append(f"{target}: no such file in the repository")
        elif anchor and resolved.suffix == ".md" and anchor not in _anchors(resolved):
            broken.append(f"{target}: {resolved.name} has no heading with the anchor {anchor!r}")
    assert not broken, "\n".join(broken)


def test_the_slugs_are_mkdocs_anchors():
    assert _slug("`bayesdoor diagnose`") == "bayesdoor-diagnose"
    assert _slug("Fit adequacy") == "fit-adequacy"
    assert (
        _slug("What it finds on the virtual rig (6 runs)")
        == "what-it-finds-on-the-virtual-rig-6-runs"
    )
