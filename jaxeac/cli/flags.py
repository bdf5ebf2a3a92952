"""The command line's argument types and the parser that turns bad input into one line.

Each bad value is one line naming the fix (`jaxeac.errors.UsageError`, exit code 2).
"""

from __future__ import annotations

import argparse
import math

from jaxeac.errors import KEY_LIMIT, UsageError

#: Every command's help ends with this: where the SPEC ids in its lines are defined.
SPEC_NOTE = ("SPEC ids in this help (G1, E7, B5, R1, ...) name the rules of docs/SPEC.md that the flag "
             "follows.")


class HelpFormatter(argparse.HelpFormatter):
    """Help lines that show each flag's default: "(default: X)" is added unless the line already
    says its default or there is none to say (None, a switch that is off)."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (text is argparse.SUPPRESS or "default" in text.lower() or default is None or default is False
                or default is argparse.SUPPRESS or isinstance(action, argparse._HelpAction)):
            return text
        shown = " ".join(map(str, default)) if isinstance(default, list | tuple) else str(default)
        return f"{text} (default: {shown.replace('%', '%%')})".strip()


class Parser(argparse.ArgumentParser):
    """argparse, but errors are one line (`error: ...`) and exit code 2; help shows every default
    and says where SPEC ids are defined."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", HelpFormatter)
        kwargs.setdefault("epilog", SPEC_NOTE)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # noqa: D401 - argparse API
        raise UsageError(f"{self.prog}: {message}")


class _Renamed(argparse.Action):
    """A flag that was renamed: using it is one error line naming the new spelling."""

    def __init__(self, option_strings, dest, instead: str = "", **kwargs):
        self.instead = instead
        super().__init__(option_strings, dest, nargs="*", help=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        raise UsageError(f"{parser.prog}: {option_string} was renamed: use {self.instead}")


def add_renamed(p: argparse.ArgumentParser, old: str, instead: str) -> None:
    """Refuse the old spelling `old` of a flag with one line pointing to `instead` (hidden from help)."""
    p.add_argument(old, dest=f"_renamed_{old.strip('-').replace('-', '_')}", action=_Renamed, instead=instead,
                   default=None)


def show(text: str, limit: int = 40) -> str:
    """A bad value for a one-line message: quoted, escaped, cut to `limit` characters."""
    return repr(text[:limit]) + ("..." if len(text) > limit else "")


def int_at_least(minimum: int, what: str):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{show(text)} is not an integer") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{show(text.strip())} must be a {what} integer")
        return value

    return parse


positive_int = int_at_least(1, "positive")  # counts: rejects 1.5, 0, -3, 'ten'
nonneg_int = int_at_least(0, "non-negative")  # process ids, caps



def prng_key(text: str) -> int:
    """A root PRNG key in 0..2^32-1: `jax.random.key` keeps only key mod 2^32, so a larger key
    would silently rerun a smaller one's random numbers under another name."""
    value = nonneg_int(text)
    if value >= KEY_LIMIT:
        raise argparse.ArgumentTypeError(
            f"{show(text.strip(), 24)} is out of range: keys are 32-bit, 0..{KEY_LIMIT - 1} (a larger key "
            f"would repeat key {value % KEY_LIMIT}'s results)")
    return value


def finite_float(text: str) -> float:
    """A finite number (rejects nan, inf)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{show(text)} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{show(text.strip())} is not a finite number")
    return value


def host_port(text: str) -> str:
    """HOST:PORT of a coordinator: a host name, IPv4 or [IPv6] address and a port in 1..65535."""
    host, sep, port = text.strip().rpartition(":")
    example = "e.g. host0:1234 or [::1]:1234"
    if not sep or not host:
        raise argparse.ArgumentTypeError(f"{show(text)} is not HOST:PORT ({example})")
    if not (port.isascii() and port.isdigit() and 1 <= int(port) <= 65535):
        raise argparse.ArgumentTypeError(f"port {show(port)} of {show(text)} must be a number in 1..65535 "
                                         f"({example})")
    bracketed = host.startswith("[") and host.endswith("]")
    name = host[1:-1] if bracketed else host
    allowed = set("0123456789abcdefABCDEF:.%") if bracketed else None
    ok = bool(name) and name.isascii() and (
        set(name) <= allowed if bracketed else all(c.isalnum() or c in ".-_" for c in name))
    if not ok:
        raise argparse.ArgumentTypeError(f"host {show(host)} of {show(text)} is not a host name or address "
                                         f"({example}: IPv6 addresses go in brackets)")
    return f"{host}:{int(port)}"


def folder_name(text: str) -> str:
    """An output or run folder: a non-empty name (`''` would mean the current folder) without NUL."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty name is not a folder; name one, e.g. runs/mine")
    if "\0" in text:
        raise argparse.ArgumentTypeError(f"{show(text)} contains a NUL byte; name a folder without one")
    return text


def map_file_name(text: str) -> str:
    """A --map file: a non-empty name (`''` would silently mean the preset's map) without NUL."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty name is not a map file; name one, e.g. --map "
                                         "maps/mine.txt, or leave --map out for the preset's map")
    if "\0" in text:
        raise argparse.ArgumentTypeError(f"{show(text)} contains a NUL byte; name a file without one")
    return text


#: The smallest significance level (1 - `compare --level`) the statistics take: below it the
#: quantiles 1 - α/2 of the tests and intervals round to 1 in double precision.
MIN_TEST_ALPHA = 1e-12


def alpha_of_level(level: float) -> float:
    """The significance level α = 1 - `level` of a confidence level (`--level`), rounded to 12
    decimals so that 0.95 gives exactly 0.05; levels that double precision cannot resolve are refused."""
    alpha = round(1.0 - level, 12)
    if not 0 < level < 1:
        raise UsageError(f"--level must lie in (0, 1) (got {level:g}): it is the confidence level of the "
                         "intervals, e.g. --level 0.99 for 99% intervals")
    if alpha < MIN_TEST_ALPHA:
        raise UsageError(f"--level {level!r} is beyond double precision: use at most {1 - MIN_TEST_ALPHA!r}")
    return alpha


def percent(level: float) -> str:
    """A confidence level as printed: 0.95 -> '95%', 0.999 -> '99.9%'."""
    return f"{100 * level:.6g}%"
