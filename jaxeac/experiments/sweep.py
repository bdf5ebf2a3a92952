"""Resumable hyperparameter sweeps: the Cartesian product of grid settings, AC and EAC at each point.

Traced settings (α, β, γ, τ) of one shape share one compiled program: all points
of a group run vmapped together, one value per (point, seed) entry. Static
settings (trials, chances, map) form separate groups. Work is done in units of
(group, algorithm, seed chunk); as each unit finishes, one file per (point,
algorithm, chunk) is written atomically, so a sweep killed at any moment and
rerun with the same command skips finished work and ends with the same
``results.csv`` as an uninterrupted run (R1, R2). A rerun with other settings
into the same folder is refused.
"""

from __future__ import annotations

import dataclasses
import io
import itertools
import json
import math
import zipfile
from collections.abc import Callable
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from jaxeac.algorithm.config import Hyper
from jaxeac.errors import UsageError
from jaxeac.experiments.common import mean_ci95, welch_diff_ci95
from jaxeac.experiments.grid import GridSettings
from jaxeac.io import (
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    check_writable_dir,
    read_json_object,
)
from jaxeac.running.batch import run_entries

TRACED = ("alpha", "beta", "gamma", "temperature", "epsilon")
SAVE_UNIT = 1024  # seeds per saved part when no --chunk-size is given
STATIC = ("trials", "chances", "preset", "map_file", "slip")
KEYS = {"alpha": float, "beta": float, "gamma": float, "temperature": float, "epsilon": float,
        "trials": int, "chances": int, "preset": str, "map_file": str, "slip": float}
ALIASES = {"map": "map_file"}


def parse_set(text: str) -> tuple[str, list]:
    """``KEY=V1,V2,…`` → (key, values); a bad key, value or empty list is a `UsageError`."""
    if "=" not in text:
        raise UsageError(f"--set {text!r}: write KEY=V1,V2,... (e.g. alpha=0.05,0.1)")
    key, _, values = text.partition("=")
    key = ALIASES.get(key.strip(), key.strip())
    if key not in KEYS:
        raise UsageError(f"--set: unknown key {key!r}; sweepable keys: {', '.join(sorted(KEYS))}")
    items = [v.strip() for v in values.split(",")]
    if not any(items):
        raise UsageError(f"--set {key}: empty list of values; give at least one value")
    if not all(items):
        raise UsageError(f"--set {key}={values}: a value between commas is empty; separate the values with "
                         "single commas (e.g. alpha=0.05,0.1)")
    parsed = []
    for item in items:
        try:
            value = KEYS[key](item)
        except ValueError:
            raise UsageError(f"--set {key}: cannot read {item!r} as {KEYS[key].__name__}") from None
        if isinstance(value, float) and not math.isfinite(value):
            raise UsageError(f"--set {key}: {item!r} is not a finite number")
        parsed.append(value)
    if len(set(parsed)) != len(parsed):
        raise UsageError(f"--set {key}: a value is listed twice ({values}); list each once")
    return key, parsed


@dataclasses.dataclass(frozen=True)
class Sweep:
    """A validated sweep: base settings and the lists of values per swept key."""

    base: GridSettings
    grid: tuple[tuple[str, tuple], ...]  # ((key, values), ...) in the order given

    @staticmethod
    def build(base: GridSettings, sets: list[str]) -> Sweep:
        grid: dict[str, list] = {}
        for text in sets:
            key, values = parse_set(text)
            if key in grid:
                raise UsageError(f"--set {key} given twice; put all its values in one --set")
            grid[key] = values
        if not grid:
            raise UsageError("nothing to sweep: give at least one --set KEY=V1,V2,...")
        sweep = Sweep(base, tuple((k, tuple(v)) for k, v in grid.items()))
        for point in sweep.points():  # validate every point before any compute
            settings = sweep.settings(point)
            settings.make_env()
        return sweep

    @property
    def keys(self) -> list[str]:
        return [k for k, _ in self.grid]

    def points(self) -> list[dict]:
        """All points of the product, in a fixed order (the point id is the index)."""
        return [dict(zip(self.keys, combo, strict=True))
                for combo in itertools.product(*(v for _, v in self.grid))]

    def settings(self, point: dict) -> GridSettings:
        """The resolved, validated settings at one point."""
        return dataclasses.replace(self.base, **point).resolved()

    def manifest(self) -> dict:
        """What identifies this sweep; a resume must match it exactly."""
        base = dataclasses.asdict(self.base)
        return {"base": base, "grid": [[k, list(v)] for k, v in self.grid], "format": 1}


def _unit_files(out: Path, point_id: int, algo: str, chunk: int) -> Path:
    return out / "parts" / f"p{point_id:05d}-{algo}-c{chunk:05d}.npz"


def run_sweep(sweep: Sweep, out: str | Path, *, progress: Callable[[int], None] | None = None,
              compare: bool = False) -> list[dict]:
    """Run (or resume) the sweep into `out`; returns the rows of results.csv."""
    out = check_writable_dir(out)
    manifest_path = out / "sweep.json"
    manifest = sweep.manifest()
    if manifest_path.exists():
        if read_json_object(manifest_path, "remove the folder or choose another --out") != json.loads(
                json.dumps(manifest)):
            raise UsageError(f"{out} holds a different sweep (see {manifest_path}); "
                             "rerun with the same settings or choose another --out")
    else:
        atomic_write_json(manifest_path, manifest)
    if (out / "parts").exists() and not (out / "parts").is_dir():
        raise UsageError(f"{out / 'parts'} is not a folder (a sweep keeps its finished parts there); remove "
                         "it or choose another --out")
    (out / "parts").mkdir(exist_ok=True)
    for stale in (out / "parts").glob(".*.tmp"):  # left by a run killed mid-write
        stale.unlink(missing_ok=True)

    points = sweep.points()
    base = sweep.base
    unit = base.chunk_size or SAVE_UNIT  # seeds per saved part: what a killed sweep resumes from
    n_chunks = -(-base.seeds // unit)
    groups: dict[tuple, list[int]] = {}
    for i, point in enumerate(points):
        s = sweep.settings(point)
        groups.setdefault((s.trials, s.chances, s.preset, s.map_file, s.slip), []).append(i)

    for ids in groups.values():
        first = sweep.settings(points[ids[0]])
        env = first.make_env()
        for algo in base.algos:
            cfg = first.run_config(algo)
            for chunk in range(n_chunks):
                todo = [i for i in ids if not _unit_files(out, i, algo, chunk).exists()]
                if not todo:
                    continue
                seeds = np.arange(chunk * unit, min((chunk + 1) * unit, base.seeds))
                hyper = _entry_hyper([sweep.settings(points[i]) for i in todo], seeds.size)
                res, _, _ = run_entries(env, cfg, root_key=base.key, seeds=np.tile(seeds, len(todo)),
                                        hyper=hyper, chunk_size=min(len(todo) * seeds.size, 16384))
                for j, i in enumerate(todo):
                    part = slice(j * seeds.size, (j + 1) * seeds.size)
                    buf = io.BytesIO()
                    np.savez(buf, seeds=seeds, success=res.success[part], steps=res.steps[part])
                    atomic_write_bytes(_unit_files(out, i, algo, chunk), buf.getvalue())
                if progress is not None:
                    progress(len(todo) * seeds.size)

    rows = _results(sweep, out, points, n_chunks)
    _write_results(sweep, out, rows)
    if compare:
        _compare_points(sweep, out, points, n_chunks)
    return rows


def _entry_hyper(settings: list[GridSettings], per_point: int) -> Hyper:
    """Per-entry traced values: each point's α, β, γ, τ, ε repeated for its seeds."""
    def column(name):
        return jnp.asarray(np.repeat([getattr(s, name) for s in settings], per_point), dtype=float)

    return Hyper(*(column(name) for name in TRACED))


def load_point(out: Path, point_id: int, algo: str, n_chunks: int) -> tuple[np.ndarray, np.ndarray]:
    """(success bool [N, T], steps [N, T]) of one algorithm at sweep point `point_id`."""
    parts = []
    for c in range(n_chunks):
        path = _unit_files(out, point_id, algo, c)
        try:
            with np.load(path) as unit:
                part = {"seeds": unit["seeds"], "success": unit["success"], "steps": unit["steps"]}
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            raise UsageError(f"{path} is damaged ({type(exc).__name__}); delete it and rerun the same sweep "
                             "command to redo that part") from None
        success, steps, seeds = part["success"], part["steps"], part["seeds"]
        first = sum(len(q["success"]) for q in parts)
        if not (success.dtype == bool and success.ndim == 2 and steps.shape == success.shape
                and steps.dtype.kind in "iu" and seeds.shape == success.shape[:1] and seeds.dtype.kind in "iu"
                and np.array_equal(seeds, np.arange(first, first + seeds.size))
                and (not parts or success.shape[1] == parts[0]["success"].shape[1])):
            raise UsageError(f"{path} is damaged (not the seeds, success and steps arrays a sweep writes); "
                             "delete it and rerun the same sweep command to redo that part")
        parts.append(part)
    return (np.concatenate([p["success"] for p in parts]), np.concatenate([p["steps"] for p in parts]))


def _results(sweep: Sweep, out: Path, points: list[dict], n_chunks: int) -> list[dict]:
    rows = []
    for i, point in enumerate(points):
        successes = {a: load_point(out, i, a, n_chunks)[0].sum(axis=1) for a in sweep.base.algos}
        diff = None
        if "ac" in successes and "eac" in successes:
            diff = welch_diff_ci95(successes["ac"], successes["eac"])
        for algo, x in successes.items():
            mean, sd, lo, hi = mean_ci95(x)
            row = {"point": i, **point, "algo": algo, "n": x.size, "mean_successes": mean, "sd": sd,
                   "ci95_lo": lo, "ci95_hi": hi}
            if diff is not None and algo == "eac":  # the difference is EAC's row's, said once per point
                row |= {"eac_minus_ac": diff[0], "diff_ci95_lo": diff[1], "diff_ci95_hi": diff[2]}
            rows.append(row)
    return rows


def _fmt(v) -> str:
    return f"{v:.6g}" if isinstance(v, float) else str(v)


def _write_results(sweep: Sweep, out: Path, rows: list[dict]) -> None:
    columns = list(dict.fromkeys(k for row in rows for k in row))
    lines = [",".join(columns)] + [",".join(_fmt(row.get(c, "")) for c in columns) for row in rows]
    atomic_write_text(out / "results.csv", "\n".join(lines) + "\n")
    from jaxeac import plots

    name = figure_name(sweep)
    if name == "heatmap.png":
        multi = [k for k, v in sweep.grid if len(v) > 1]
        plots.sweep_heatmap(rows, multi[0], multi[1], out / name)
    else:
        plots.sweep_lines(rows, _line_key(sweep), out / name)


def _line_key(sweep: Sweep) -> str:
    """The key a line plot runs along: the first with several values (else the first)."""
    return next((k for k, v in sweep.grid if len(v) > 1), sweep.keys[0])


def figure_name(sweep: Sweep) -> str:
    """The sweep's figure: ``heatmap.png`` (EAC − AC over the first two keys with several values,
    when both run), else ``lines.png`` (each algorithm's mean against one key)."""
    multi = [k for k, v in sweep.grid if len(v) > 1]
    if len(multi) >= 2 and {"ac", "eac"} <= set(sweep.base.algos):
        return "heatmap.png"
    return "lines.png"


def format_table(sweep: Sweep, rows: list[dict], *, limit: int = 40) -> str:
    """results.csv for a terminal: one line per point and algorithm, the mean successes with its
    95 % CI and, on EAC's line, EAC − AC with its Welch 95 % CI; at most `limit` lines."""
    keys = sweep.keys
    head = [*keys, "algo", "n", "mean successes [95% CI]", "EAC − AC [95% CI]"]
    body = []
    for row in rows[:limit]:
        mean = f"{row['mean_successes']:.2f} [{row['ci95_lo']:.2f}, {row['ci95_hi']:.2f}]"
        diff = (f"{row['eac_minus_ac']:+.2f} [{row['diff_ci95_lo']:+.2f}, {row['diff_ci95_hi']:+.2f}]"
                if "eac_minus_ac" in row else "")
        body.append([*(_fmt(row[k]) for k in keys), row["algo"], str(row["n"]), mean, diff])
    widths = [max(len(r[i]) for r in [head, *body]) for i in range(len(head))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in [head, *body]]
    lines.insert(1, "  ".join("-" * w for w in widths))
    if len(rows) > limit:
        lines.append(f"... {len(rows) - limit} more rows in results.csv")
    return "\n".join(lines)


def _compare_points(sweep: Sweep, out: Path, points: list[dict], n_chunks: int) -> None:
    """`jaxeac compare` per point: a run folder under points/pNNNNN/ with its report."""
    from jaxeac.io import staged_dir
    from jaxeac.stats import compare_run_dir

    for i, point in enumerate(points):
        folder = out / "points" / f"p{i:05d}"
        if (folder / "stats.json").exists():
            continue
        s = sweep.settings(point)
        data = {a: load_point(out, i, a, n_chunks) for a in s.algos}
        with staged_dir(folder) as stage:
            lines = ["algo,seed,successes,steps,first_success"]
            for a, (success, steps) in data.items():
                first = np.where(success.any(1), success.argmax(1) + 1, -1)
                lines += [f"{a},{j},{int(success[j].sum())},{int(steps[j].sum())},{first[j]}"
                          for j in range(success.shape[0])]
            (stage / "per_seed.csv").write_text("\n".join(lines) + "\n")
            np.savez_compressed(stage / "curves.npz", **{a: d[0] for a, d in data.items()})
            atomic_write_json(stage / "summary.json", {
                "experiment": "grid", "primary_measure": "successes", "algos": list(s.algos),
                "trials": s.trials, "seeds": s.seeds, "key": s.key, "point": point,
                "config": dataclasses.asdict(s)})
        if {"ac", "eac"} <= set(s.algos):
            compare_run_dir(folder, progress=False)
