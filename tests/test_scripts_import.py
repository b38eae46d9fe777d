"""Every name the scripts, benchmarks and notebooks import from bayesdoor exists, and every
documented ``python scripts/...`` command parses.

They import inside functions (so ``--help`` stays fast), where neither ruff nor mypy (which
checks the package only) sees a name that moved: a script that imports ``configure_jax``
from ``bayesdoor.cli._common`` after it moved to ``bayesdoor`` fails at its first line of
work, perhaps hours into a run of ``make_results``. This reads each
file's ``from bayesdoor... import ...`` statements and resolves them, without running them;
and it hands the arguments of every command quoted in the README, results/ and docs/ to that
file's own argument parser, stopping its ``main`` right after parsing.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import importlib.util
import re
import sys
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


_COMMAND = re.compile(r"python ((?:scripts|benchmarks)/\w+\.py)((?: +[^ `#|)\n]+)*)")


def documented_commands(text: str) -> set[tuple[str, str]]:
    """``(file, arguments)`` of every ``python scripts/X.py ...`` in markdown ``text``: in
    fenced blocks line by line, in inline code spans (which may wrap) whole, and in what is
    left (indented blocks) line by line."""
    found: set[tuple[str, str]] = set()
    fenced = re.compile(r"```.*?```", re.S)
    for block in fenced.findall(text):
        found.update(m.group(1, 2) for m in _COMMAND.finditer(block))
    text = fenced.sub("", text)
    inline = re.compile(r"(`+)(.+?)\1", re.S)  # a span closes at as many backticks
    for _, span in inline.findall(text):
        found.update(m.group(1, 2) for m in _COMMAND.finditer(" ".join(span.split())))
    found.update(m.group(1, 2) for m in _COMMAND.finditer(inline.sub("", text)))
    return found


#: commands quoted in the README, results/ and docs/: each file's own argument parser must
#: accept the arguments as written
DOCUMENTED = sorted(
    set().union(
        *(
            documented_commands(p.read_text())
            for p in [
                ROOT / "README.md",
                *sorted((ROOT / "results").glob("*.md")),
                *sorted((ROOT / "docs").glob("*.md")),
            ]
        )
    )
)


class _Parsed(Exception):
    pass


def _parse_only(path: Path, args: list[str], monkeypatch) -> None:
    """Run the file's ``main`` up to its ``parse_args`` and stop there."""
    # a file without a parser would run whole; documented arguments need one to read them
    assert "parse_args(" in path.read_text(), f"{path.name} takes arguments but parses none"
    spec = importlib.util.spec_from_file_location(f"_documented_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # its dataclasses look it up
    monkeypatch.syspath_prepend(str(path.parent))
    spec.loader.exec_module(module)
    original = argparse.ArgumentParser.parse_args

    def parse_args(self, argv=None, namespace=None):
        original(self, argv, namespace)
        raise _Parsed

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_args)
    monkeypatch.setattr(sys, "argv", [str(path), *args])
    with pytest.raises(_Parsed):
        module.main()


def test_documented_commands_are_found():
    wrapped = "(``a``) see (`python scripts/full_size_case.py frame_mode 6\nOUT`, 628 s)"
    assert documented_commands(wrapped) == {("scripts/full_size_case.py", " frame_mode 6 OUT")}
    scripts = {script for script, _ in DOCUMENTED}
    assert "scripts/classification.py" in scripts and "benchmarks/bench_simulate.py" in scripts
    assert len(DOCUMENTED) >= 30
    assert [s for s, _ in DOCUMENTED if not (ROOT / s).is_file()] == []


@pytest.mark.parametrize(
    ("script", "args"),
    [c for c in DOCUMENTED if c[1].split() and not any(a.isupper() for a in c[1].split())],
    ids=lambda v: v if "/" in str(v) else (str(v).strip() or "-"),
)
def test_a_documented_command_parses(script, args, monkeypatch, capsys):
    path = ROOT / script
    assert path.is_file(), script
    try:
        _parse_only(path, args.split(), monkeypatch)
    except SystemExit as err:
        pytest.fail(f"python {script}{args}: exit {err.code}: {capsys.readouterr().err}")
