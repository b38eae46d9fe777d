"""The command line's conventions (docs/cli.md, "Conventions"), checked on every command's
declared options and help rather than command by command."""

import re
from importlib.metadata import version

import pytest
import typer.main
from typer.testing import CliRunner

from bayesdoor.cli._app import app

GROUP = typer.main.get_command(app)
COMMANDS = dict(GROUP.commands)  # type: ignore[attr-defined]
#: options whose default differs between commands, and why (the help must say it)
DIFFERS = {"method": "the default", "state": "the default", "out": "the default"}
#: commands that fit a model or train a classifier, so offer small sizes
FITTING = {"run", "demo", "fit", "diagnose", "plan"}


def _options(command) -> dict:
    """The command's options (not its arguments) by name."""
    return {p.name: p for p in command.params if p.param_type_name == "option" and p.name}


def test_every_command_has_a_one_line_summary_that_is_a_sentence():
    for name, command in COMMANDS.items():
        first = (command.help or "").strip().split("\n\n")[0]
        assert "\n" not in first, f"{name}: its summary runs over lines: {first!r}"
        assert first.endswith("."), f"{name}: its summary is not a sentence: {first!r}"


def test_an_option_has_one_default_in_every_command_unless_its_help_says_why():
    defaults: dict[str, dict[str, object]] = {}
    for name, command in COMMANDS.items():
        for option in _options(command).values():
            if option.required or option.name == "help":
                continue
            defaults.setdefault(option.name, {})[name] = option.default
    for option, by_command in defaults.items():
        if len({repr(v) for v in by_command.values()}) == 1:
            continue
        assert option in DIFFERS, f"--{option} has different defaults: {by_command}"
        for name in by_command:
            text = _options(COMMANDS[name])[option].help or ""
            assert DIFFERS[option] in text, f"{name} --{option}: the help does not say why"


def test_name_value_options_show_their_form_and_commands_that_fit_offer_quick():
    for name, command in COMMANDS.items():
        options = _options(command)
        for option in options.values():
            if "NAME=VALUE" in (option.help or ""):
                assert option.metavar == "NAME=VALUE", f"{name} {option.opts}"
        if name in FITTING:
            assert "quick" in options, f"{name} fits or trains but has no --quick"


def test_a_previous_jobs_products_are_passed_as_model():
    reusing = {
        name
        for name, command in COMMANDS.items()
        if "--model" in _opts(command) or "--posterior" in _opts(command)
    }
    assert reusing == {"classify", "diagnose", "plan"}
    for name in reusing:
        option = next(o for o in _options(COMMANDS[name]).values() if "--model" in o.opts)
        assert option.opts[0] == "--model", name


def _opts(command) -> set[str]:
    return {o for p in _options(command).values() for o in p.opts}


def test_the_version():
    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0
    assert re.fullmatch(rf"bayesdoor {re.escape(version('bayesdoor'))}\n", result.output)


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_commands_help_prints(name):
    result = CliRunner().invoke(app, [name, "--help"])
    assert result.exit_code == 0, result.output
