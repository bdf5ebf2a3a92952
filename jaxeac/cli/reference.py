"""docs/CLI.md, generated from the parser: ``python -m jaxeac.cli.reference [--check] [FILE]``.

Writes FILE (default docs/CLI.md); with ``--check`` compares instead and exits 1 when it is stale.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

#: Columns of the help text in the reference, whatever the terminal's width.
WIDTH = 100
HEADER = """# The `jaxeac` command line

Generated from the parser by `python -m jaxeac.cli.reference`; do not edit by hand
(tests/test_cli_reference.py fails when this file is stale).

Every flag name has one meaning across the commands. Bad input is one line `error: ...`
on stderr and exit code 2, before any compute.
"""


def _formatted(parser: argparse.ArgumentParser) -> str:
    from jaxeac.cli.flags import HelpFormatter

    parser.formatter_class = lambda prog: HelpFormatter(prog, width=WIDTH)
    return parser.format_help().rstrip() + "\n"


def reference(parser: argparse.ArgumentParser | None = None) -> str:
    """The markdown reference of `parser` (default `jaxeac.cli.build_parser()`) and each subcommand."""
    if parser is None:
        from jaxeac.cli import build_parser

        parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    names: dict[int, list[str]] = {}
    for name, p in sub.choices.items():
        names.setdefault(id(p), []).append(name)
    parts = [HEADER, "## jaxeac\n", "```text\n" + _formatted(parser) + "```\n"]
    for choice in sub._choices_actions:
        p = sub.choices[choice.dest]
        aliases = [n for n in names[id(p)] if n != choice.dest]
        title = f"## jaxeac {choice.dest}\n"
        note = "".join(f"\n\n`jaxeac {a}` is an alias: the same flags, defaults and outputs.\n"
                       for a in aliases)
        parts.append(f"{title}\n{choice.help}{note}\n```text\n{_formatted(p)}```\n")
    return "\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    from jaxeac.cli import build_parser

    args = list(sys.argv[1:] if argv is None else argv)
    check = "--check" in args
    rest = [a for a in args if a != "--check"]
    path = Path(rest[0] if rest else Path(__file__).resolve().parents[2] / "docs" / "CLI.md")
    text = reference(build_parser())
    if check:
        if not path.is_file() or path.read_text() != text:
            print(f"{path} is stale; regenerate it with python -m jaxeac.cli.reference", file=sys.stderr)
            return 1
        return 0
    path.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
