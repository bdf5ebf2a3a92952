"""Shared fixtures: small maps and a float64 switch for exact comparisons."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))  # tests/reference.py
sys.path.insert(0, str(Path(__file__).parent.parent / "scripts"))  # scripts/peers (same-run peers)
# commands run by the tests compile afresh and leave nothing in the user's cache
# (tests/test_cli.py checks the cache itself in a folder of its own)
os.environ["JAXEAC_COMPILATION_CACHE"] = "off"


def random_map_text(rng: np.random.Generator) -> str:
    """A random rectangular map (2..6 × 2..6) with one goal and some obstacles (G1)."""
    h, w = int(rng.integers(2, 7)), int(rng.integers(2, 7))
    cells = np.where(rng.random((h, w)) < 0.25, "#", ".")
    gy, gx = int(rng.integers(h)), int(rng.integers(w))
    cells[gy, gx] = "G"
    free = [(y, x) for y in range(h) for x in range(w) if cells[y, x] == "."]
    if not free:  # G1 needs a start cell
        y, x = (gy + 1) % h, gx if h > 1 else (gx + 1) % w
        cells[y if h > 1 else gy, x] = "."
    return "\n".join("".join(row) for row in cells) + "\n"


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20141013)
