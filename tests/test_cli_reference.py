"""docs/CLI.md is generated from the parser: a flag added, renamed or re-documented without
regenerating it fails here (``python -m jaxeac.cli.reference`` writes it)."""

from __future__ import annotations

import re
from pathlib import Path

from jaxeac.cli import build_parser
from jaxeac.cli.reference import main, reference

CLI_MD = Path(__file__).resolve().parents[1] / "docs" / "CLI.md"


def test_cli_reference_is_current():
    assert CLI_MD.read_text() == reference(), "docs/CLI.md is stale: run python -m jaxeac.cli.reference"


def test_cli_reference_lists_every_command_and_flag():
    """Each command's section lists its flags; renamed spellings (hidden) are not listed."""
    text = reference()
    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    sections = {part.split("\n", 1)[0]: part for part in text.split("\n## jaxeac ")[1:]}
    for name, command in sub.choices.items():
        section = sections[command.prog.split()[-1]]
        assert f"jaxeac {name}" in text
        for action in command._actions:
            for flag in action.option_strings:
                listed = re.search(re.escape(flag) + r"(?![\w-])", section) is not None
                assert listed == (action.help != "==SUPPRESS=="), (name, flag)


def test_check_mode_finds_a_stale_reference(tmp_path):
    stale = tmp_path / "CLI.md"
    stale.write_text("# old\n")
    assert main(["--check", str(stale)]) == 1
    assert main([str(stale)]) == 0 and main(["--check", str(stale)]) == 0
    assert stale.read_text() == reference()


def _commands():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    return parser, sub.choices


def test_every_flag_has_a_help_line_that_states_its_default():
    """--help of every command: a line for every flag and positional, each default said (by the
    line itself or the formatter's "(default: X)"), and where SPEC ids are defined."""
    import argparse

    parser, commands = _commands()
    for name, command in commands.items():
        formatter = command._get_formatter()
        text = command.format_help()
        assert "docs/SPEC.md" in text, name
        for action in command._actions:
            if action.help is argparse.SUPPRESS or isinstance(action, argparse._HelpAction):
                continue
            assert action.help and action.help.strip(), (name, action.option_strings or action.dest)
            if action.default not in (None, False):
                line = formatter._get_help_string(action)
                assert "default" in line.lower(), (name, action.option_strings, line)
    assert "(default: 1000)" in commands["bowling"].format_help()
    assert "(default: 10000)" in commands["study"].format_help()


def test_version_and_the_world_alternatives_in_run_help(capsys):
    import pytest

    import jaxeac
    from jaxeac.cli import main as cli_main

    with pytest.raises(SystemExit) as stop:
        cli_main(["--version"])
    assert stop.value.code == 0 and capsys.readouterr().out.strip() == f"jaxeac {jaxeac.__version__}"
    _, commands = _commands()
    text = " ".join(commands["run"].format_help().split())
    assert "the world (alternatives):" in text
    assert "--map and --env exclude each other" in text and "(the default: --preset paper)" in text
