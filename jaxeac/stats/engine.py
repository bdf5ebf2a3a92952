"""`compare`: one statistics engine for per-seed results from anywhere, across tasks (SPEC §6).

``compare(data, ...)`` takes a run folder (its full report: `jaxeac.stats.run.compare_run_dir`,
returned as a `Comparison` whose ``stats`` is the folder's stats.json) or anything
`jaxeac.stats.core.compare_per_seed` takes — a tidy table with optional ``task`` and ``trial``
columns, SB3 monitor folders, rliable-style arrays, arrays in a notebook — with a declared family
(all pairs, or each algorithm against `baseline`), pairing and a confidence `level`. The
estimators, the stratified bootstrap and the one resampling rule are `jaxeac.stats.core`'s.
"""

from __future__ import annotations

import os
from pathlib import Path

from jaxeac.errors import UsageError
from jaxeac.stats.core import check_level, check_resamples, compare_per_seed
from jaxeac.stats.result import Comparison

__all__ = ["compare", "check_level", "check_resamples"]


def compare(data, *, baseline: str | None = None, treatment: str | None = None, paired: str = "auto",
            level: float = 0.95, resamples: int = 10_000, key=0, **options) -> Comparison:
    """Compare per-seed results; returns a `Comparison`.

    `data`: a run folder (then `baseline`/`treatment` default to ac/eac, and the folder's report,
    stats.json and figures are written into it), or what `jaxeac.stats.core.compare_per_seed`
    takes (its `options`: `value`, `aggregate`, `tasks`, `normalize`, `reference_scores`,
    `profile_points`, `chunk`; a run folder ignores them). `paired`: "auto", "paired" (refuse
    unpaired designs) or
    "unpaired". Bad input raises `UsageError` (a `ValueError`)."""
    if isinstance(data, str | os.PathLike) and (Path(data) / "summary.json").is_file():
        from jaxeac.stats.run import compare_run_dir

        level = check_level(level)
        if paired not in ("auto", "paired", "unpaired"):
            raise UsageError(f"paired must be 'auto', 'paired' or 'unpaired' (got {paired!r})")
        check_resamples(resamples, level)
        stats = compare_run_dir(data, baseline=baseline or "ac", treatment=treatment or "eac",
                                resamples=resamples, alpha=round(1 - level, 12), key=key, progress=False,
                                unpaired=paired == "unpaired", require_paired=paired == "paired")
        return Comparison.from_run(stats)
    return compare_per_seed(data, baseline=baseline, treatment=treatment, paired=paired, level=level,
                            resamples=resamples, key=key, **options)
