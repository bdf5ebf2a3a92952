"""Per-seed values of Stable-Baselines3 runs (a source of `jaxeac.perseed`): a folder of
monitor files, ``ALGO/SEED/monitor.csv`` or ``ALGO_SEED.monitor.csv``; each seed's value is the
mean episode reward over the last 10 % of its file's episodes (at least one), so seeds with
different episode counts are comparable. A file without episodes is a failed seed (excluded
and counted); a malformed one raises `UsageError` naming it.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from jaxeac.errors import UsageError
from jaxeac.perseed import ONE_TASK, PerSeed, _check_file, _numeric, excerpt

#: Share of the last episodes whose mean reward is the per-seed value of an SB3 run.
SB3_LAST_SHARE = 0.10


def _read_monitor(path: Path) -> float:
    import pandas as pd

    _check_file(path, "SB3 monitor file")
    try:
        with open(path, encoding="utf-8") as fh:
            skip = 1 if fh.readline().startswith("#") else 0
        frame = pd.read_csv(path, skiprows=skip)
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise UsageError(
            f"cannot read the SB3 monitor file {path}: {excerpt(str(exc).splitlines()[0], 80)}"
        ) from None
    frame.columns = [str(c).strip() for c in frame.columns]
    if "r" not in frame.columns:
        raise UsageError(
            f"{path}: no column 'r' (episode reward); an SB3 monitor file has a #{{...}} line, "
            "then columns r,l,t"
        )
    r = _numeric(frame, "r", str(path), rows="episode")
    r = r[~np.isnan(r)]
    if r.size == 0:
        return math.nan  # no episode: a failed seed
    k = max(1, math.ceil(SB3_LAST_SHARE * r.size))
    return float(r[-k:].mean())


def read_sb3(folder) -> PerSeed:
    """SB3 monitor files: ``ALGO/SEED/monitor.csv`` or ``ALGO_SEED.monitor.csv``."""
    folder = Path(folder)
    runs: dict[str, dict[str, float]] = {}
    for path in sorted(folder.rglob("*monitor.csv")):
        rel = path.relative_to(folder)
        if path.name == "monitor.csv":
            if len(rel.parts) < 3:
                raise UsageError(f"{path}: a monitor.csv must lie in ALGO/SEED/monitor.csv under {folder}")
            algo, seed = rel.parts[-3], rel.parts[-2]
        else:
            m = re.fullmatch(r"(.+)_([^_]+)\.monitor\.csv", path.name)
            if not m:
                raise UsageError(
                    f"{path}: an SB3 monitor file is named ALGO_SEED.monitor.csv "
                    "(or lies in ALGO/SEED/monitor.csv)"
                )
            algo, seed = m.group(1), m.group(2)
        runs.setdefault(algo, {})[seed] = _read_monitor(path)
    if not runs:
        raise UsageError(f"{folder}: no SB3 monitor files (ALGO/SEED/monitor.csv or ALGO_SEED.monitor.csv)")
    values, seeds, excluded = {ONE_TASK: {}}, {ONE_TASK: {}}, {}
    for a, per in runs.items():
        ids = np.array(sorted(per))
        v = np.array([per[s] for s in ids])
        ok = ~np.isnan(v)
        values[ONE_TASK][a], seeds[ONE_TASK][a] = v[ok], ids[ok]
        if not ok.all():
            excluded.setdefault(ONE_TASK, {})[a] = int((~ok).sum())
    what = (
        f"per-seed value: mean episode reward over the last {SB3_LAST_SHARE:.0%} of episodes (at least one) "
        "of each SB3 monitor file, whatever its number of episodes"
    )
    return PerSeed(values, seeds, what, "sb3", str(folder), excluded)
