"""Every name the scripts, benchmarks and notebooks import from bayesdoor exists.

They import inside functions (so ``--help`` stays fast), where neither ruff nor mypy (which
checks the package only) sees a name that moved: ``scripts/classification.py`` imported
``configure_jax`` from ``bayesdoor.cli._common`` for sessions after it had moved to
``bayesdoor``, and failed at its first line of work (found in session 17). This reads each
file's ``from bayesdoor... import ...`` statements and resolves them, without running them.
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FILES = sorted(
    p for folder in ("scripts", "benchmarks", "examples") for p in (ROOT / folder).glob("*.py")
)


def bayesdoor_imports(path: Path) -> list[tuple[int, str, str | None]]:
    """``(line, module, name)`` of every import of bayesdoor in the file (name ``None`` for
    ``import bayesdoor.x``)."""
    out: list[tuple[int, str, str | None]] = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module.split(".")[0] == "bayesdoor":
                out.extend((node.lineno, node.module, a.name) for a in node.names)
        elif isinstance(node, ast.Import):
            out.extend(
                (node.lineno, a.name, None)
                for a in node.names
                if a.name.split(".")[0] == "bayesdoor"
            )
    return out


def unresolved(path: Path) -> list[str]:
    missing = []
    for line, module, name in bayesdoor_imports(path):
        try:
            mod = importlib.import_module(module)
        except ImportError as err:
            missing.append(f"{path.name}:{line}: import {module}: {err}")
            continue
        if name is not None and name != "*" and not hasattr(mod, name):
            try:
                importlib.import_module(f"{module}.{name}")
            except ImportError:
                missing.append(f"{path.name}:{line}: {module} has no {name!r}")
    return missing


def test_the_files_are_found_and_import_bayesdoor():
    assert len(FILES) >= 20
    assert sum(bool(bayesdoor_imports(p)) for p in FILES) >= 15


@pytest.mark.parametrize("path", FILES, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_bayesdoor_name_a_file_imports_exists(path):
    assert unresolved(path) == []


def test_a_moved_name_is_reported(tmp_path):
    script = tmp_path / "old.py"
    script.write_text(
        "def main():\n"
        "    from bayesdoor.cli._common import configure_jax\n"
        "    from bayesdoor import configure_jax as ok\n"
        "    import bayesdoor.no_such_module\n"
    )
    problems = unresolved(script)
    assert len(problems) == 2
    assert "has no 'configure_jax'" in problems[0]
    assert "no_such_module" in problems[1]
