"""The package's layers, as import-linter's contracts in pyproject.toml state them: concrete
systems (``bayesdoor.door``, ``bayesdoor.bearing``, ``bayesdoor.oscillator``) sit on top of the
generic layers, which never import them, and no package's modules import each other in a cycle."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
LINT_IMPORTS = Path(sys.executable).parent / "lint-imports"

pytestmark = pytest.mark.skipif(
    not LINT_IMPORTS.exists(), reason="import-linter is not installed (pip install -e '.[dev]')"
)


def lint_imports(root: Path) -> subprocess.CompletedProcess:
    """``lint-imports`` on the package under ``root`` with the contracts of its pyproject."""
    env = {**os.environ, "PYTHONPATH": str(root)}
    return subprocess.run(
        [str(LINT_IMPORTS), "--config", str(root / "pyproject.toml"), "--no-cache"],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_the_contracts_hold():
    result = lint_imports(ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Contracts: 2 kept, 0 broken." in result.stdout


#: a stray module, the import it makes, and the contract's complaint
STRAYS = [
    # a generic layer reaching the door
    (
        "io",
        "from ..door import ElevatorDoor",
        "bayesdoor.io is not allowed to import bayesdoor.door",
    ),
    # the door importing the bearing: the concrete systems are independent
    ("door", "from ..bearing import BearingSystem", "bayesdoor.door is not allowed to import"),
    # a lower layer importing a higher one
    ("inference", "from ..pipeline import run_job", "bayesdoor.inference is not allowed to import"),
]


@pytest.mark.parametrize(("package", "imports", "broken"), STRAYS, ids=[s[0] for s in STRAYS])
def test_an_import_across_the_layers_breaks_them(tmp_path, package, imports, broken):
    ignore = shutil.ignore_patterns("__pycache__")
    shutil.copytree(ROOT / "bayesdoor", tmp_path / "bayesdoor", ignore=ignore)
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    stray = tmp_path / "bayesdoor" / package / "_stray.py"
    stray.write_text(f'"""A stray import."""\n\n{imports}\n')
    result = lint_imports(tmp_path)
    assert result.returncode != 0
    assert broken in result.stdout, result.stdout
