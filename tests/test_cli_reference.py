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
