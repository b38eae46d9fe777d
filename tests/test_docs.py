"""The documentation site: a strict MkDocs build, one API page per public package, and the
griffe extension that gives ``eqx.Module`` classes their constructors.

The build needs the documentation tools of the dev extras (mkdocs-material, mkdocstrings[python],
griffe-public-redundant-aliases); where they are missing the tests that need them are skipped
with the reason.
"""

import importlib
import inspect
import os
import re
import subprocess
import sys
from pathlib import Path

import equinox as eqx
import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
PACKAGES = sorted(
    path.parent.relative_to(ROOT).as_posix().replace("/", ".")
    for path in (ROOT / "bayesdoor").glob("**/__init__.py")
    if path.parent != ROOT / "bayesdoor"
)


def _require_docs_tools():
    for module in ("mkdocs", "material", "mkdocstrings_handlers.python", "griffe"):
        pytest.importorskip(module, reason=f"{module} is not installed (pip install -e '.[dev]')")
    pytest.importorskip(
        "griffe_public_redundant_aliases",
        reason="griffe-public-redundant-aliases is not installed (pip install -e '.[dev]')",
    )


def test_every_public_package_has_an_api_page():
    pages = {path.name: path.read_text() for path in (DOCS / "api").glob("*.md")}
    nav = (ROOT / "mkdocs.yml").read_text()
    for package in PACKAGES:
        name = package.removeprefix("bayesdoor.") + ".md"
        assert name in pages, f"docs/api/{name} is missing for {package}"
        assert f"::: {package}\n" in pages[name], f"docs/api/{name} does not render {package}"
        assert f"api/{name}" in nav, f"api/{name} is not in the nav of mkdocs.yml"


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site built by ``mkdocs build --strict`` (any warning fails the build)."""
    _require_docs_tools()
    out = tmp_path_factory.mktemp("site")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
        timeout=600,
    )
    assert result.returncode == 0, f"mkdocs build --strict failed:\n{result.stderr[-6000:]}"
    return out


# the two tests of the built site share its build, 9-68 s on a 2-core machine (the higher
# figures with other work beside it; mkdocs renders every page and API reference): in the long
# tier, which CI runs after the default suite
@pytest.mark.long
def test_strict_build_renders_the_re_exported_api(site):
    # Public names are re-exported from private modules (``from ._x import f as f``); without
    # the redundant-alias extension the pages would hold only the package docstrings.
    page = (site / "api" / "inference" / "index.html").read_text()
    for name in ("fit_campaign", "sample_nuts", "minimize_cmaes", "SamplingTransform"):
        assert f'id="bayesdoor.inference.{name}"' in page, name
    # Sphinx roles in the docstrings (``:meth:`from_covariance```) are shown as inline code
    assert ":meth:" not in page and ":func:" not in page
    assert "<code>from_covariance</code>" in page


@pytest.mark.long
def test_results_tables_are_published_and_linked(site):
    page = (site / "features" / "index.html").read_text()
    assert 'href="../results/performance/"' in page
    home = (site / "index.html").read_text()
    for table in (ROOT / "results").glob("*.md"):
        assert (site / "results" / table.stem / "index.html").is_file(), table.name
        assert f'href="results/{table.stem}/"' in home, f"{table.name} is not in the nav"


def _equinox_classes():
    for package in PACKAGES:
        module = importlib.import_module(package)
        for name in sorted(dir(module)):
            obj = getattr(module, name)
            if inspect.isclass(obj) and issubclass(obj, eqx.Module) and not name.startswith("_"):
                yield package, name, obj


def test_griffe_extension_matches_the_constructors_equinox_generates():
    # Reference: the signature of the ``__init__`` equinox actually builds at import time. The
    # extension reconstructs it from source alone, so the two must name the same parameters in
    # the same order for every public ``eqx.Module`` (generated or hand-written constructors).
    _require_docs_tools()
    import griffe

    sys.path.insert(0, str(DOCS / "api"))
    try:
        from griffe_equinox import EquinoxModules
    finally:
        sys.path.remove(str(DOCS / "api"))
    loaded = griffe.load(
        "bayesdoor",
        search_paths=[str(ROOT)],
        extensions=griffe.load_extensions("griffe_public_redundant_aliases", EquinoxModules),
        resolve_aliases=True,
    )
    checked = 0
    for package, name, cls in _equinox_classes():
        documented = loaded[f"{package}.{name}".removeprefix("bayesdoor.")]
        if "__init__" not in documented.all_members:
            pytest.fail(f"{package}.{name}: no constructor in the documentation")
        static = [p.name for p in documented.all_members["__init__"].parameters][1:]
        runtime = list(inspect.signature(cls).parameters)
        assert static == runtime, f"{package}.{name}: documented {static}, equinox {runtime}"
        checked += 1
    assert checked > 20


def test_the_guides_speak_in_the_present_tense():
    """Guides say what the product does; how it came to be lives in git log."""
    narration = re.compile(r"before this change|first version|we tried|was tried", re.IGNORECASE)
    found = [
        f"{page.relative_to(ROOT)}:{number}: {line.strip()}"
        for page in sorted([*DOCS.glob("**/*.md"), ROOT / "README.md"])
        for number, line in enumerate(page.read_text().splitlines(), 1)
        if narration.search(line)
    ]
    assert not found, "\n".join(found)
