"""docs/SPEC.md and docs/ARCHITECTURE.md stay in step with the code.

* every SPEC id the package cites (``SPEC E6``, ``(E4)``, ``G3:``, ``B1–B7``) is defined
  in docs/SPEC.md;
* every id docs/SPEC.md defines is cited somewhere in ``jaxeac/`` or ``tests/``;
* every module path the two documents name in backticks exists.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SPEC = ROOT / "docs" / "SPEC.md"
ARCHITECTURE = ROOT / "docs" / "ARCHITECTURE.md"
THIS = Path(__file__).resolve()

# An id is a group letter and one digit, standing alone as a word: "E6", "(E4)", "G3:".
# Word boundaries keep out hex and numbers ("0xE5", "1E5") and longer names ("B12", "GRID-1").
ID = r"\b([GEBRX])([1-9])\b"
# A range cites every id in it: "B1–B7", "B2-B4", "E1..E7".
RANGE = re.compile(r"\b([GEBRX])([1-9])\s*(?:–|—|-|\.\.|…)\s*\1?([1-9])\b")
ID_RE = re.compile(ID)
# A string literal that is nothing but an id ("G1") is data (e.g. a report's claim key), not a
# citation of the SPEC.
LITERAL_RE = re.compile(r"""(["'])[GEBRX][1-9]\1""")
# Where docs/SPEC.md defines an id: a bold label or a heading that starts with it.
DEFINED_RE = re.compile(r"^(?:\*\*|#{1,6}\s+)([GEBRX][1-9])\b", re.MULTILINE)
# A module path in backticks: no spaces, ending in ".py" or "/".
PATH_RE = re.compile(r"`([^`\s]+(?:\.py|/))`")
FENCE_RE = re.compile(r"^```.*?^```", re.MULTILINE | re.DOTALL)


def cited_ids(text: str) -> dict[str, int]:
    """{id: first line number} of the SPEC ids a source text cites."""
    found: dict[str, int] = {}
    for number, line in enumerate(text.splitlines(), 1):
        line = LITERAL_RE.sub("", line)
        for m in RANGE.finditer(line):
            letter, lo, hi = m.group(1), int(m.group(2)), int(m.group(3))
            for k in range(lo, hi + 1):
                found.setdefault(f"{letter}{k}", number)
        for m in ID_RE.finditer(line):
            found.setdefault(m.group(1) + m.group(2), number)
    return found


def citations(*folders: str) -> dict[str, list[str]]:
    """{id: ["path:line", ...]} over the Python files of `folders` (this file left out)."""
    where: dict[str, list[str]] = {}
    for folder in folders:
        for path in sorted((ROOT / folder).rglob("*.py")):
            if path.resolve() == THIS:
                continue
            text = path.read_text(encoding="utf-8")
            for sid, line in cited_ids(text).items():
                where.setdefault(sid, []).append(f"{path.relative_to(ROOT)}:{line}")
    return where


def defined_ids() -> list[str]:
    ids = DEFINED_RE.findall(SPEC.read_text(encoding="utf-8"))
    assert ids, f"{SPEC.relative_to(ROOT)} defines no ids (expected '**E1 …' labels or headings)"
    return ids


def test_cited_ids_are_defined():
    defined = set(defined_ids())
    missing = {sid: places for sid, places in citations("jaxeac").items() if sid not in defined}
    assert not missing, "SPEC ids cited in jaxeac/ but not defined in docs/SPEC.md: " + "; ".join(
        f"{sid} (cited at {', '.join(places[:3])})" for sid, places in sorted(missing.items())
    )


def test_defined_ids_are_cited_and_unique():
    ids = defined_ids()
    twice = sorted({sid for sid in ids if ids.count(sid) > 1})
    assert not twice, f"ids defined more than once in docs/SPEC.md: {', '.join(twice)}"
    cited = citations("jaxeac", "tests")
    uncited = [sid for sid in ids if sid not in cited]
    assert not uncited, (
        "ids defined in docs/SPEC.md but cited nowhere in jaxeac/ or tests/: " + ", ".join(uncited)
    )


def test_cited_ids_regex_skips_non_citations():
    text = 'x = 0xE5 + 1E5  # GRID-1, B12\nclaims["G1"]\n# SPEC E6 and (E4); G3: B2-B4\n'
    assert cited_ids(text) == {"E6": 3, "E4": 3, "G3": 3, "B2": 3, "B3": 3, "B4": 3}


@pytest.mark.parametrize("doc", [SPEC, ARCHITECTURE], ids=lambda p: p.name)
def test_named_module_paths_exist(doc: Path):
    text = FENCE_RE.sub("", doc.read_text(encoding="utf-8"))
    paths = sorted(set(PATH_RE.findall(text)))
    assert paths, f"{doc.relative_to(ROOT)} names no module paths"
    missing = [p for p in paths if not (ROOT / p.removeprefix("./")).exists()]
    assert not missing, f"{doc.relative_to(ROOT)} names paths that do not exist: {', '.join(missing)}"
