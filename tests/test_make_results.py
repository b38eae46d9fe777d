"""``scripts/make_results.py``, the one command that regenerates ``results/``, and the
generated-block markers that keep the notes written by hand in those files.

A step that is not the command that made its file (say ten seeds at 8 runs where the
README's table is two seeds at 6) would replace the figures the README quotes, and a rerun
that rewrote a whole file would drop every note written after a run. These tests tie each
step to the command named at the top of its file, parse every step with its script's own
parser, and check that a rerun replaces only the generated block.
"""

from __future__ import annotations

import re
import shlex
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

import make_results  # noqa: E402
from _cases import BEGIN, END, KEPT, merge_results, write_results  # noqa: E402
from test_scripts_import import _parse_only  # noqa: E402

STEPS = {s.name: s for s in make_results.STEPS}
#: options that name where a run keeps its files or how many processes it uses: they do not
#: change the figures, so the comparison with a file's header leaves them out
_WHERE = {"--work", "--out", "--results", "--report", "--verdicts"}
_HOW_MANY = {"--jobs", "--workers"}


def _normalised(words: list[str]) -> list[str]:
    out, skip = [], False
    for w in words:
        if skip:
            skip = False
        elif w in _WHERE or w in _HOW_MANY:
            skip = True
        else:
            out.append(w)
    return out


def _header_command(path: Path) -> tuple[str, list[str]] | None:
    """The script and arguments named in the first lines of a results file, if any."""
    head = "\n".join(path.read_text().splitlines()[:6])
    found = re.search(r"`(?:\.venv/bin/)?python ((?:scripts|benchmarks)/\w+\.py)([^`]*)`", head)
    if found is None:
        return None
    return found.group(1), shlex.split(found.group(2))


GENERATED = sorted((step.out[1], step.name) for step in make_results.STEPS if step.out is not None)


@pytest.mark.parametrize(("filename", "step"), GENERATED, ids=[g[0] for g in GENERATED])
def test_each_results_file_names_the_step_that_regenerates_it(filename, step):
    path = ROOT / "results" / filename
    assert path.is_file(), f"step {step} writes {filename}, which is not in results/"
    header = _header_command(path)
    assert header is not None, f"{filename} does not name the command that made it"
    script, args = header
    command = STEPS[step].command(quick=False)
    assert script == command[1], (filename, script, command[1])
    assert _normalised(args) == _normalised(command[2:]), (
        f"{filename} was made by `python {script} {shlex.join(args)}`, but make_results runs "
        f"`{shlex.join(['python', *command[1:]])}`"
    )


@pytest.mark.parametrize(("filename", "step"), GENERATED, ids=[g[0] for g in GENERATED])
def test_each_results_file_has_one_generated_block(filename, step):
    text = (ROOT / "results" / filename).read_text()
    assert text.count(BEGIN) == 1 and text.count(END) == 1, filename
    assert text.index(BEGIN) < text.index(END)


@pytest.mark.parametrize("quick", [False, True], ids=["full", "quick"])
@pytest.mark.parametrize("name", sorted(STEPS))
def test_every_step_parses_with_its_script(name, quick, monkeypatch, tmp_path):
    command = STEPS[name].command(quick, tmp_path)
    _parse_only(ROOT / command[1], command[2:], monkeypatch)


def test_quick_writes_elsewhere_and_every_file_step_can_be_redirected(tmp_path, capsys):
    assert make_results.main(["--quick", "--list"]) == 0
    listed = capsys.readouterr().out
    assert str(make_results.QUICK_RESULTS) in listed
    assert " results/" not in listed and str(make_results.RESULTS) + "/" not in listed
    assert make_results.main(["--list", "--results", str(tmp_path)]) == 0
    listed = capsys.readouterr().out.splitlines()
    redirected = [line for line in listed if str(tmp_path) in line]
    assert len(redirected) == len(GENERATED)


def test_the_docs_command_list_matches(capsys):
    assert make_results.main(["--list"]) == 0
    listed = capsys.readouterr().out
    # the README's figures are quoted with these commands
    assert "scripts/diagnosis.py --seeds 0 1 --none-seeds 2 --runs 6 --diagnosis quick" in listed
    assert "scripts/classification.py --seeds 0 1 2 3 4 --fit-evals 300 --fit-motion 1.5" in listed


# ---------------------------------------------------------------- the generated-block markers


def test_a_new_file_is_the_block():
    assert merge_results(None, "# T\n\nrow\n") == f"{BEGIN}\n# T\n\nrow\n{END}\n"


def test_a_rerun_replaces_the_block_and_keeps_the_notes():
    old = f"intro\n{BEGIN}\n# T\n\nold row\n{END}\n\n## Notes (by hand)\n\nkept\n"
    new = merge_results(old, "# T\n\nnew row")
    assert new == f"intro\n{BEGIN}\n# T\n\nnew row\n{END}\n\n## Notes (by hand)\n\nkept\n"
    assert merge_results(new, "# T\n\nnew row") == new  # the same run twice: one file


def test_a_file_without_markers_is_kept_whole_after_the_block():
    old = "# T\n\nhand-made table\n"
    new = merge_results(old, "# T\n\nrow")
    assert new.startswith(f"{BEGIN}\n# T\n\nrow\n{END}\n")
    assert new.endswith(f"{KEPT}\n\n# T\n\nhand-made table\n")
    # broken markers (an end before a begin) count as none: nothing is dropped
    broken = f"{END}\nnote\n{BEGIN}\n"
    assert merge_results(broken, "x").endswith(broken.rstrip() + "\n")


def test_write_results_replaces_the_file_in_one_step(tmp_path, capsys):
    path = tmp_path / "sub" / "r.md"
    write_results(path, "# T\n\none", echo=False)
    path.write_text(path.read_text() + "\n## Notes\n\nmine\n")
    write_results(path, "# T\n\ntwo")
    assert "two" in capsys.readouterr().out
    text = path.read_text()
    assert "two" in text and "one" not in text and text.endswith("## Notes\n\nmine\n")
    assert sorted(p.name for p in path.parent.iterdir()) == ["r.md"]  # no partial file left
