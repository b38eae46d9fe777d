"""MkDocs hook: publish ``results/`` with the documentation.

The pages in ``docs/`` link the measured tables as ``../results/NAME.md`` so that the links work
where the repository is read as files. The site has no ``..``: this hook adds every file of
``results/`` (the tables and the figures they show) to the site under ``results/`` and rewrites
those links to point there, so the strict build still checks that each linked table exists.
The ``Results`` section of the nav is filled with every Markdown file there (titled by its
first heading), so a new table needs no edit of ``mkdocs.yml``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import File, Files
from mkdocs.structure.pages import Page

_RESULTS = "results"
_LINK = re.compile(r"\]\((?:\.\./)+results/")


def _results_dir(config: MkDocsConfig) -> Path:
    return Path(config.config_file_path).parent / _RESULTS


def _title(path: Path) -> str:
    for line in path.read_text().splitlines():
        if line.startswith("# "):
            return line[2:].strip()
    return path.stem.replace("_", " ")


def on_config(config: MkDocsConfig, **kwargs: Any) -> MkDocsConfig:
    """Fill the nav's ``Results`` section with every Markdown file of ``results/``."""
    pages = [
        {_title(path): f"{_RESULTS}/{path.name}"}
        for path in sorted(_results_dir(config).glob("*.md"))
    ]
    for entry in config.nav or []:
        if isinstance(entry, dict) and "Results" in entry:
            entry["Results"] = pages
    return config


def on_files(files: Files, *, config: MkDocsConfig, **kwargs: Any) -> Files:
    """Add the files of ``results/`` (tables and the figures they show) under ``results/``."""
    for path in sorted(_results_dir(config).iterdir()):
        if not path.is_file() or path.name.startswith("."):
            continue
        files.append(
            File.generated(config, f"{_RESULTS}/{path.name}", abs_src_path=str(path.resolve()))
        )
    return files


def on_page_markdown(markdown: str, *, page: Page, **kwargs: Any) -> str:
    """Point ``../results/NAME.md`` links at the published copy, relative to the page."""
    depth = page.file.src_uri.count("/")
    return _LINK.sub("](" + "../" * depth + f"{_RESULTS}/", markdown)
