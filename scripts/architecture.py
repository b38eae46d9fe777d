"""Four figures of the generic layers: the longest function, the functions with more than 8
parameters, the largest module, and the concrete system names left in their code.

The generic layers are the modules of ``bayesdoor`` outside the concrete systems' packages,
which are the packages of the classes that the ``bayesdoor.systems`` entry points of
``pyproject.toml`` name (``bayesdoor.door`` and ``bayesdoor.bearing``): the interface, the
features and files, the fit, the training data, the classifier, the diagnosis, the reports,
the job and the command line (docs/systems.md, "The layers"). Each module is read with
:mod:`ast`, never imported. What counts:

- a function: every ``def`` and ``async def`` (methods and nested functions included); its
  lines run from the ``def`` line (decorators not counted) to its last line, docstring and
  comments included;
- its parameters: every name it takes (positional, keyword-only, ``*args``, ``**kwargs``),
  less a method's leading ``self`` or ``cls``;
- a module's lines: the lines of its file;
- a concrete system name: one of :data:`SYSTEM_NAMES` (the elevator door's, the bearing's and
  the oscillator's states, parts, condition and data set) as words of an identifier (a name, an
  attribute, a function's, class's, parameter's or keyword argument's name, an imported module
  or name; split into words at underscores and case changes) or of a string constant (split at
  every character that is not a letter or a digit; f-strings' literal parts included), singular
  or plural (``wheels``), in any case but the state labels ``D1`` and ``D2``, which count as
  written (``d2`` is a squared distance). A name counts once per identifier or string it occurs
  in.
  Docstrings and comments do not count: they cite the shipped systems as examples of what
  the generic code serves; identifiers and strings are what the code reads, compares and
  shows to users.

Usage::

    .venv/bin/python scripts/architecture.py [--json FILE] [--list]

``--list`` prints where each system name occurs; ``--json FILE`` also writes the figures
there. ``tests/test_architecture.py`` checks that the figures quoted in docs/systems.md
("Architecture") are this script's current output and that no system name is left.
"""

from __future__ import annotations

import argparse
import ast
import json
import re
import tomllib
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "bayesdoor"
#: a function with more parameters than this is counted
MAX_PARAMETERS = 8
#: the concrete systems' names the generic layers must not hold: the door's damage states,
#: parts and operating condition, the bearing's damage states and part, and its data set,
#: the reference oscillator's name, damage states and catalogue cause
SYSTEM_NAMES = (
    "D1",
    "D2",
    "door",
    "sill",
    "rail",
    "wheel",
    "v_max",
    "bearing",
    "inner_race",
    "outer_race",
    "ball",
    "cwru",
    "oscillator",
    "stiffness_loss",
    "loose_mount",
    "second_mode",
)


@dataclass(frozen=True)
class Occurrence:
    """A system name in an identifier or a string of a generic module."""

    path: str
    line: int
    name: str
    text: str


@dataclass(frozen=True)
class Figures:
    """The four figures, and where they were found."""

    modules: int
    longest_function_lines: int
    longest_function: str
    over_max_parameters: int
    largest_module_lines: int
    largest_module: str
    system_names: int
    occurrences: tuple[Occurrence, ...]


def concrete_packages(root: Path = ROOT) -> tuple[str, ...]:
    """The packages of the systems that ``pyproject.toml`` registers (``bayesdoor.door``)."""
    project = tomllib.loads((root / "pyproject.toml").read_text())["project"]
    targets = project["entry-points"]["bayesdoor.systems"].values()
    return tuple(sorted({".".join(t.split(":")[0].split(".")[:2]) for t in targets}))


def generic_modules(root: Path = ROOT) -> list[Path]:
    """The generic layers' modules, relative to ``root``, sorted."""
    concrete = {root / Path(*p.split(".")) for p in concrete_packages(root)}
    return sorted(
        path.relative_to(root)
        for path in (root / PACKAGE).rglob("*.py")
        if not any(path.is_relative_to(c) for c in concrete)
    )


def _words(identifier: str) -> list[str]:
    """An identifier's words: split at underscores and case changes."""
    spaced = re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", identifier)
    return [w for w in spaced.split("_") if w]


def _string_words(text: str) -> list[str]:
    return re.findall(r"[A-Za-z0-9]+", text)


def _fold(name: str):
    """How a name's words compare: as written for a name in capitals (a state label), else
    in lower case."""
    return (lambda w: w) if name != name.lower() else str.lower


_NAMES = tuple((n, [_fold(n)(w) for w in _words(n)], _fold(n)) for n in SYSTEM_NAMES)


def _names_in(words: list[str]) -> list[str]:
    """The system names that occur in ``words`` (the last word of a name may be plural)."""
    found = []
    for name, parts, fold in _NAMES:
        folded = [fold(w) for w in words]
        k = len(parts)
        for i in range(len(folded) - k + 1):
            *head, last = folded[i : i + k]
            if head == parts[:-1] and last in (parts[-1], parts[-1] + "s"):
                found.append(name)
                break
    return found


def _docstrings(tree: ast.AST) -> set[int]:
    """The ids of the docstring constants of a module, its classes and functions."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                if isinstance(body[0].value.value, str):
                    out.add(id(body[0].value))
    return out


def _identifiers(node: ast.AST) -> Iterator[str]:
    """The identifiers a node introduces or reads."""
    if isinstance(node, ast.Name):
        yield node.id
    elif isinstance(node, ast.Attribute):
        yield node.attr
    elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
        yield node.name
    elif isinstance(node, ast.arg):
        yield node.arg
    elif isinstance(node, ast.keyword) and node.arg is not None:
        yield node.arg
    elif isinstance(node, ast.ImportFrom) and node.module:
        yield from node.module.split(".")
    elif isinstance(node, ast.alias):
        yield from (n for part in (node.name, node.asname) if part for n in part.split("."))


def system_names(tree: ast.AST, path: str) -> list[Occurrence]:
    """Every system name in the identifiers and the strings (not docstrings) of a module."""
    skip = _docstrings(tree)
    found = []
    for node in ast.walk(tree):
        line = getattr(node, "lineno", 0)
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            if id(node) not in skip:
                words = _string_words(node.value)
                found += [Occurrence(path, line, n, node.value) for n in _names_in(words)]
            continue
        for identifier in _identifiers(node):
            found += [Occurrence(path, line, n, identifier) for n in _names_in(_words(identifier))]
    return found


def _parameters(node: ast.FunctionDef | ast.AsyncFunctionDef, method: bool) -> int:
    args = node.args
    names = [a.arg for a in (*args.posonlyargs, *args.args)]
    if method and names and names[0] in ("self", "cls"):
        names = names[1:]
    return len(names) + len(args.kwonlyargs) + (args.vararg is not None) + (args.kwarg is not None)


def _functions(
    tree: ast.Module,
) -> Iterator[tuple[str, ast.FunctionDef | ast.AsyncFunctionDef, bool]]:
    """``(qualified name, node, is a method)`` of every function of a module."""

    def visit(node: ast.AST, prefix: str, in_class: bool):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                yield f"{prefix}{child.name}", child, in_class
                yield from visit(child, f"{prefix}{child.name}.", False)
            elif isinstance(child, ast.ClassDef):
                yield from visit(child, f"{prefix}{child.name}.", True)
            else:
                yield from visit(child, prefix, in_class)

    yield from visit(tree, "", False)


def measure(root: Path = ROOT) -> Figures:
    """The figures of the generic layers under ``root``."""
    longest = (0, "")
    largest = (0, "")
    over = 0
    occurrences: list[Occurrence] = []
    modules = generic_modules(root)
    for rel in modules:
        text = (root / rel).read_text()
        path = rel.as_posix()
        tree = ast.parse(text, filename=path)
        largest = max(largest, (len(text.splitlines()), path), key=lambda t: t[0])
        for name, node, method in _functions(tree):
            lines = (node.end_lineno or node.lineno) - node.lineno + 1
            longest = max(longest, (lines, f"{path}:{name}"), key=lambda t: t[0])
            over += _parameters(node, method) > MAX_PARAMETERS
        occurrences += system_names(tree, path)
    return Figures(
        modules=len(modules),
        longest_function_lines=longest[0],
        longest_function=longest[1],
        over_max_parameters=over,
        largest_module_lines=largest[0],
        largest_module=largest[1],
        system_names=len(occurrences),
        occurrences=tuple(occurrences),
    )


def render(figures: Figures, root: Path = ROOT) -> str:
    """The figures as the script prints them (and docs/systems.md quotes them)."""
    concrete = ", ".join(concrete_packages(root))
    return "\n".join(
        [
            f"generic layers: {figures.modules} modules (bayesdoor less {concrete})",
            f"longest function: {figures.longest_function_lines} lines, {figures.longest_function}",
            f"functions with more than {MAX_PARAMETERS} parameters: {figures.over_max_parameters}",
            f"largest module: {figures.largest_module_lines} lines, {figures.largest_module}",
            f"concrete system names in identifiers and strings: {figures.system_names}",
        ]
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write the figures here")
    parser.add_argument("--list", action="store_true", help="list the system names found")
    args = parser.parse_args(argv)
    figures = measure()
    print(render(figures))
    if args.list:
        for o in figures.occurrences:
            print(f"  {o.path}:{o.line}: {o.name} in {o.text!r}")
    if args.json is not None:
        args.json.write_text(json.dumps(asdict(figures), indent=1) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
