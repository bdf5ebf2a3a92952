"""Reading a run directory (SPEC §6): a run folder of either experiment, in every layout since
release 0.1, read with the cross-checks that name a damaged file.

A run directory holds `summary.json`, `per_seed.csv` and `curves.npz` (written by
the grid and bowling runners), or `results.parquet`. Reading files is input and output, so this is
the base layer's: the comparison (`jaxeac.stats.run`) and `jaxeac.load` both read folders through
it. The per-seed measures computed from what it holds are `jaxeac.stats.measures`.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxeac.errors import UsageError
from jaxeac.io import json_field, read_json_object
from jaxeac.results import load_grid_results


@dataclass(frozen=True)
class RunData:
    """What `compare` needs from a run directory."""

    path: Path
    experiment: str
    primary_measure: str
    algos: tuple[str, ...]
    trials: int
    success: dict  # algo -> bool [N, T] or `SuccessBits`
    returns: dict  # algo -> int [N, T] (bowling) or empty
    per_seed: dict  # algo -> {column: np.ndarray} (results.parquet: the seed ids alone)
    sequential: dict | None = None  # a sequential run's design, looks and decision (summary.json)


#: The decisions of a sequential record's looks (`jaxeac.stats.sequential.look`), the last while
#: more batches are to come; a finished comparison ends with one of the first three.
DECISIONS = ("difference", "no difference", "undecided", "continue")
#: per_seed.csv columns jaxeac writes as numbers (a value that is not one is a damaged file).
NUMERIC_COLUMNS = ("seed", "successes", "return", "steps", "first_success")


def _read_per_seed(path: Path) -> dict:
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise UsageError(f"{path} is not a readable CSV file ({exc.__class__.__name__}); "
                         "re-run the experiment to rewrite it") from None
    if not rows or "algo" not in rows[0]:
        raise UsageError(f"{path} has no rows or no 'algo' column; re-run the experiment to rewrite it")
    out: dict = {}
    for row in rows:
        out.setdefault(row["algo"], []).append(row)
    table = {}
    for algo, rs in out.items():
        cols = {}
        for col in rs[0]:
            if col == "algo":
                continue
            try:
                cols[col] = np.array([float(r[col]) for r in rs])
            except (TypeError, ValueError):
                if col in NUMERIC_COLUMNS:
                    raise UsageError(f"{path}: column {col!r} of {algo} holds a value that is not a number; "
                                     "re-run the experiment to rewrite it") from None
                continue  # ignore non-numeric extra columns
            if col in NUMERIC_COLUMNS:  # counts and seed ids: whole numbers (NaN, inf, 1e308 are damage)
                v = cols[col]
                whole = np.isfinite(v) & (np.abs(v) <= 2.0**53)
                whole[whole] = v[whole] == np.round(v[whole])
                if not whole.all():
                    raise UsageError(f"{path}: column {col!r} of {algo} holds {v[np.argmin(whole)]:g}, not a "
                                     "whole number as a run writes; re-run the experiment to rewrite it")
        table[algo] = cols
    return table


def read_summary(run_dir) -> dict:
    """summary.json as a dict, or {} where it is missing or unreadable (the report's title and
    family then do without it)."""
    try:
        return json.loads((Path(run_dir) / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def load_run_dir(run_dir, baseline: str = "ac", treatment: str = "eac") -> RunData:
    """Read and cross-check summary.json and the per-seed results: results.parquet (grid runs,
    `jaxeac.results`) or per_seed.csv and curves.npz (bowling, and older grid runs)."""
    path = Path(run_dir)
    columnar = (path / "results.parquet").is_file()
    for name in ("summary.json",) + (() if columnar else ("per_seed.csv", "curves.npz")):
        if not (path / name).is_file():
            raise UsageError(
                f"{path} has no {name}; pass a run directory written by 'jaxeac grid' or 'jaxeac bowling'"
            )
    summary = read_json_object(path / "summary.json", "re-run the experiment")
    experiment = summary.get("experiment")
    if experiment not in ("grid", "bowling"):
        raise UsageError(f"summary.json experiment is {experiment!r}, expected 'grid' or 'bowling'")
    primary = summary.get("primary_measure", "successes" if experiment == "grid" else "return")
    if primary not in ("successes", "return"):
        raise UsageError(f"summary.json primary_measure is {primary!r}, expected 'successes' or 'return'")
    where = path / "summary.json"
    trials = json_field(summary, "trials", int, where, "re-run the experiment")
    algos = json_field(summary, "algos", list, where, "re-run the experiment")
    if trials < 1 or not all(isinstance(a, str) for a in algos) or len(set(algos)) != len(algos):
        raise UsageError(f"{where}: trials must be a positive integer and algos a list of distinct names "
                         f"(got {trials!r}, {algos!r}); re-run the experiment")
    algos = tuple(algos)
    for algo, flag in ((baseline, "--baseline"), (treatment, "--treatment")):
        if algo not in algos:
            raise UsageError(f"{flag} {algo!r} is not in this run (algos: {', '.join(algos) or 'none'})")
    if baseline == treatment:
        raise UsageError("--baseline and --treatment are the same method; choose two different ones")
    if columnar:
        data = _load_columnar(path, experiment, primary, algos, trials, (baseline, treatment))
        return dataclasses.replace(data, sequential=sequential_record(summary, where))
    try:
        with np.load(path / "curves.npz") as npz:
            arrays = {k: np.asarray(npz[k]) for k in npz.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise UsageError(f"{path / 'curves.npz'} is not a readable .npz file ({str(exc).splitlines()[0]}); "
                         "re-run the experiment to rewrite it") from None
    per_seed = _read_per_seed(path / "per_seed.csv")
    success, returns = {}, {}
    for algo in (baseline, treatment):
        if algo not in arrays:
            raise UsageError(f"curves.npz has no array {algo!r}; re-run the experiment")
        c = arrays[algo]
        if c.ndim != 2 or c.shape[1] != trials:
            hint = (
                " (trials axis first? expected [seeds, trials])"
                if c.ndim == 2 and c.shape[0] == trials
                else ""
            )
            raise UsageError(f"curves.npz[{algo!r}] has shape {c.shape}, expected [seeds, {trials}]{hint}")
        if c.shape[0] < 2:
            raise UsageError(f"{algo} has {c.shape[0]} seed(s); at least 2 seeds per method are needed")
        success[algo] = c.astype(bool)
        if experiment == "bowling":
            r = arrays.get(f"{algo}_return")
            if r is None or r.shape != c.shape:
                raise UsageError(
                    f"curves.npz has no {algo}_return of shape {c.shape}; re-run the bowling experiment"
                )
            returns[algo] = r.astype(np.int64)
        cols = per_seed.get(algo)
        if cols is not None and "successes" not in cols:
            raise UsageError(f"per_seed.csv has no numeric 'successes' column for {algo} (columns: "
                             f"{', '.join(cols) or 'none'}); re-run the experiment to rewrite it")
        if cols is None or cols["successes"].shape[0] != c.shape[0]:
            n_csv = 0 if cols is None else len(next(iter(cols.values()), []))
            raise UsageError(
                f"per_seed.csv has {n_csv} rows for {algo} but curves.npz has {c.shape[0]} seeds; "
                "the files come from different runs"
            )
        if not np.array_equal(cols["successes"], c.sum(1)):
            raise UsageError(
                f"per_seed.csv successes for {algo} do not match curves.npz; "
                "the files come from different runs"
            )
        if "first_success" in cols:
            fs = np.where(c.any(1), np.argmax(c, 1) + 1, -1)
            if not np.array_equal(cols["first_success"], fs):
                raise UsageError(
                    f"per_seed.csv first_success for {algo} does not match curves.npz; re-run the experiment"
                )
        if (
            experiment == "bowling"
            and "return" in cols
            and not np.array_equal(cols["return"], returns[algo].sum(1))
        ):
            raise UsageError(
                f"per_seed.csv return for {algo} does not match curves.npz; re-run the experiment"
            )
    return RunData(path, experiment, primary, algos, trials, success, returns, per_seed,
                   sequential_record(summary, where))


def _load_columnar(path: Path, experiment, primary, algos, trials, pair) -> RunData:
    loaded = load_grid_results(path, pair, trials, compact=True)
    success, per_seed = {}, {}
    for algo, r in loaded.items():
        if r.success.shape[0] < 2:
            raise UsageError(f"{algo} has {r.success.shape[0]} seed(s); at least 2 seeds per method "
                             "are needed")
        success[algo] = r.success
        per_seed[algo] = {"seed": r.seeds}  # what the comparison reads (are the seeds paired?)
    return RunData(path, experiment, primary, algos, trials, success, {}, per_seed)


def sequential_record(summary: dict, where: Path) -> dict | None:
    """summary.json's ``sequential`` record (a sequential run's design, looks and decision), checked
    so the report can rely on it; absent: None; damaged: one `UsageError` naming the file."""
    if "sequential" not in summary:
        return None
    seq = summary["sequential"]

    def number(x) -> bool:
        return isinstance(x, int | float) and not isinstance(x, bool)

    def look_ok(x) -> bool:
        return (isinstance(x, dict) and isinstance(x.get("seeds"), int) and number(x.get("diff"))
                and number(x.get("boundary_z")) and x.get("decision") in DECISIONS
                and isinstance(x.get("rci"), list) and len(x["rci"]) == 2 and all(map(number, x["rci"])))

    def rates_ok(x) -> bool:
        return (isinstance(x, dict) and isinstance(x.get("experiments"), int)
                and number(x.get("mean_seeds_used")) and isinstance(x.get("decisions"), dict)
                and all(isinstance(v, dict) and number(v.get("rate")) and number(v.get("se"))
                        for v in x["decisions"].values()))

    ok = (isinstance(seq, dict) and isinstance(seq.get("looks_taken"), list) and seq["looks_taken"]
          and all(map(look_ok, seq["looks_taken"])) and seq.get("decision") in DECISIONS[:3]
          and isinstance(seq.get("looks"), int) and isinstance(seq.get("seeds_used"), int)
          and isinstance(seq.get("sizes"), list) and seq["sizes"]
          and all(isinstance(v, int) for v in seq["sizes"])
          and all(number(seq.get(k)) for k in ("alpha", "effect"))
          and all(isinstance(seq.get(k), str) for k in ("design", "spending"))
          and (seq.get("calibration") is None or (isinstance(seq["calibration"], dict) and all(
              rates_ok(seq["calibration"].get(k)) for k in ("null", "observed")))))
    if not ok:
        raise UsageError(f"{where}: its 'sequential' record is damaged (not the design, looks and decision "
                         "a sequential run writes); re-run the experiment")
    return seq
