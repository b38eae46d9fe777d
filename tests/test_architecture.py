"""The figures of ``scripts/architecture.py``: what docs/systems.md quotes is its current
output, no concrete system's name is left in the generic layers, and the scanner finds the
names it is meant to find (and not the words that only look like them)."""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

import architecture  # noqa: E402

DOC = ROOT / "docs" / "systems.md"


def quoted() -> tuple[str, str]:
    """The "Architecture" section of docs/systems.md and the output block it quotes."""
    text = DOC.read_text()
    section = text[text.index("\n## Architecture\n") :]
    block = re.search(r"```text\n(.*?)\n```", section, re.S)
    assert block is not None, "docs/systems.md, Architecture: no ```text block"
    return section, block.group(1)


def test_the_documented_figures_are_the_scripts_current_output():
    section, block = quoted()
    assert block == architecture.render(architecture.measure()), (
        "docs/systems.md quotes figures the code no longer has: run "
        "`python scripts/architecture.py` and quote its output, date and commit"
    )
    assert re.search(r"On \d{4}-\d{2}-\d{2}, at commit [0-9a-f]{7,40}:", section)


def test_no_concrete_system_name_is_left_in_the_generic_layers():
    figures = architecture.measure()
    assert figures.system_names == 0, "\n".join(
        f"{o.path}:{o.line}: {o.name} in {o.text!r}" for o in figures.occurrences
    )


def test_the_generic_layers_are_every_module_but_the_registered_systems():
    assert architecture.concrete_packages() == (
        "bayesdoor.bearing",
        "bayesdoor.door",
        "bayesdoor.oscillator",
    )
    modules = {m.as_posix() for m in architecture.generic_modules()}
    assert "bayesdoor/report/_damage.py" in modules
    assert "bayesdoor/systems/_base.py" in modules
    assert not any(
        m.startswith(("bayesdoor/door/", "bayesdoor/bearing/", "bayesdoor/oscillator/"))
        for m in modules
    )


SOURCE = '''
"""A module docstring may cite the door and its D1 state."""

from .door import wheel_radius as radius


def colour(state, healthy, d2, a, b, c, e, f, g):
    """A function's docstring too: the sill, the rails."""
    # and a comment: the bearing's ball
    if state == "D1":
        return f"{healthy} of the inner race"
    return {"shape": "outer_race", "v": d2, "doors": 2}


class Palette:
    def pick(self, one, two, three, four, five, six, seven, eight, cwru_file):
        return self.ballPass + self.v_max + "d1 and d2"
'''


def test_the_scanner_counts_identifiers_and_strings_but_not_docstrings():
    tree = ast.parse(SOURCE)
    found = sorted((o.line, o.name) for o in architecture.system_names(tree, "x.py"))
    assert found == [
        (4, "door"),  # an imported module
        (4, "wheel"),  # an imported name
        (10, "D1"),  # a string compared with
        (11, "inner_race"),  # the literal part of an f-string, in words
        (12, "door"),  # a dict key, plural
        (12, "outer_race"),  # a string value
        (16, "cwru"),  # a parameter
        (17, "ball"),  # an attribute, in camel case
        (17, "v_max"),  # an attribute
    ]


def test_functions_and_their_parameters_are_counted_as_documented(tmp_path):
    (tmp_path / "pyproject.toml").write_text(
        '[project.entry-points."bayesdoor.systems"]\nmine = "bayesdoor.mine:Mine"\n'
    )
    (tmp_path / "bayesdoor" / "mine").mkdir(parents=True)
    (tmp_path / "bayesdoor" / "mine" / "__init__.py").write_text("x = 'door'\n" * 50)
    (tmp_path / "bayesdoor" / "generic.py").write_text(SOURCE)
    figures = architecture.measure(tmp_path)
    assert figures.modules == 1
    # colour takes 9 parameters, pick 9 besides self
    assert figures.over_max_parameters == 2
    assert (figures.longest_function_lines, figures.longest_function) == (
        6,
        "bayesdoor/generic.py:colour",
    )
    assert (figures.largest_module_lines, figures.largest_module) == (
        len(SOURCE.splitlines()),
        "bayesdoor/generic.py",
    )
    assert figures.system_names == 9
    assert "(bayesdoor less bayesdoor.mine)" in architecture.render(figures, tmp_path)
