"""What a run folder's report says beyond its two methods: the subject, and the declared family.

`subject` names what was run (the environment or map, its slip, C, the trials) for the report's
title. `run_family`: where a run holds more algorithms than the two compared in full, every one
of them against the baseline (the declared family, Holm over it), by `compare_per_seed` on the
folder's per-seed table: paired where the seeds share keys (R1).
"""

from __future__ import annotations

from pathlib import Path

from jaxeac.stats.core import compare_per_seed
from jaxeac.stats.result import Comparison


def subject(summary: dict) -> str:
    """``FrozenLake-8x8-slippery-v1, slip 0.1, C = 200, 200 trials`` from summary.json."""
    cfg = summary.get("config") or {}
    if summary.get("experiment") == "bowling":
        what = f"bowling ({cfg['backend']} backend)" if cfg.get("backend") else "bowling"
    elif cfg.get("env"):
        what = str(cfg["env"])
    elif cfg.get("map_file"):
        what = f"the grid world of {Path(str(cfg['map_file'])).name}"
    else:
        what = f"the {cfg.get('preset', 'paper')} preset's grid world"
    parts = [what]
    if cfg.get("slip"):
        parts.append(f"slip {cfg['slip']:g}")
    if cfg.get("chances") and summary.get("experiment") != "bowling":
        parts.append(f"C = {cfg['chances']}")
    if summary.get("trials"):
        parts.append(f"{summary['trials']} trials")
    return ", ".join(parts)


def settings_text(summary: dict) -> str:
    """``α = 0.1, β = 0.3, γ = 0.9, τ = 1 (ε = 0.1 for q_learning, sarsa); key 0`` from summary.json
    (its ``command`` and ``config`` hold the rest)."""
    cfg = summary.get("config") or {}
    names = (("alpha", "α"), ("beta", "β"), ("gamma", "γ"), ("temperature", "τ"))
    rates = ", ".join(f"{sym} = {cfg[k]:g}" for k, sym in names if isinstance(cfg.get(k), int | float))
    greedy = [a for a in summary.get("algos") or () if a in ("q_learning", "sarsa")]
    if greedy and isinstance(cfg.get("epsilon"), int | float):
        rates += f" (ε = {cfg['epsilon']:g} for {', '.join(greedy)})"
    parts = [rates]
    if summary.get("key") is not None:
        parts.append(f"key {summary['key']}")
    return "; ".join(p for p in parts if p)


def run_family(run_dir, summary: dict, baseline: str, primary: str, *, level: float, resamples: int,
               key: int) -> dict | None:
    """Every algorithm of the run against `baseline` on the primary measure (a `Comparison`'s
    dict), or None where the run holds two algorithms only (the full report is that pair)."""
    algos = list(summary.get("algos") or [])
    if len(algos) <= 2 or baseline not in algos:
        return None
    folder = Path(run_dir)
    table = folder / "results.parquet"
    if not table.is_file():
        table = folder / "per_seed.csv"
    result = compare_per_seed(str(table), baseline=baseline, level=level, resamples=resamples, key=key,
                              value=primary)
    return result.to_dict()


def family_comparison(family: dict) -> Comparison:
    """The `Comparison` of a `run_family` dict (as stats.json holds it)."""
    return Comparison(**{k: v for k, v in family.items() if k != "schema"})
