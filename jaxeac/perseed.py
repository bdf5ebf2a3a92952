"""Per-seed data from anywhere, as one `PerSeed` (the input of `jaxeac.stats.engine.compare`).

Sources, each turned into one value per (task, algorithm, seed):

* a tidy table, CSV or Parquet: columns ``algo, seed[, task][, trial]`` and the value column
  (``value``, or any column named by `value`, e.g. ``successes`` of a run's ``per_seed.csv``).
  With ``trial`` the per-seed value is the sum over its trials (`aggregate` ``"sum"``; every
  seed of an algorithm and task then needs the same trials), their mean (``"mean"``) or the
  value of the largest trial (``"last"``).
* a folder of Stable-Baselines3 monitor files, ``ALGO/SEED/monitor.csv`` or
  ``ALGO_SEED.monitor.csv``: the mean episode reward over the last 10 % of each file's
  episodes (at least one), so seeds with different episode counts are comparable.
* rliable-style arrays: an ``.npz`` (or a dict) with one ``[runs, tasks]`` array per algorithm.
* arrays: ``{algo: 1-D}`` (one task), ``{task: {algo: 1-D}}``, or ``{algo: [runs, tasks]}``.

**Ragged and failed seeds** (the stated rules, recorded in the result): a seed whose value is
missing or NaN (a failed run; with trials: any of its trials) is excluded and counted per task
and algorithm, never silently; text that is no number and infinite values are errors.

Malformed input raises `UsageError` (a `ValueError`) naming the row, column, file or
algorithm, quoting at most a short printable excerpt, before anything is written.

SB3 monitor folders are read by `jaxeac.sb3`; `jaxeac.stats.core.read_any` picks the reader of a
path. Reading files is input and output, so these readers are the base layer's: the statistics
and the public face (`jaxeac.compare`) both take what they read.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from jaxeac.errors import UsageError

AGGREGATES = ("sum", "mean", "last")
#: The largest |value| the statistics take (float32 sums of squares), and the smallest spread.
MAX_VALUE = 1e15
MIN_SPREAD = 1e-15
#: Tables above this size are refused before reading: a Parquet or .npz file (a per-seed table of
#: 10⁸ rows is ~3 GB as CSV, less in Parquet), and a text (CSV) table, which parsing blows up ~10×
#: in memory.
MAX_TABLE_BYTES = 4 << 30
MAX_TEXT_BYTES = 1 << 30
#: The header of a CSV must end within this many bytes.
MAX_HEADER_BYTES = 1 << 16
ONE_TASK = ""
TRIAL_TEXTS = {
    "sum": "the sum of the value column over its trials",
    "mean": "the mean of the value column over its trials",
    "last": "the value column at its last (largest) trial",
}
MISSING = ("", "nan", "none", "null", "na", "<na>")


@dataclass
class PerSeed:
    """Per-seed values by task and algorithm: ``values[task][algo]`` a float64 array, ``seeds[task][algo]``
    the seed ids (str) in the same order, or None where the source has no seed keys (then no pairing)."""

    values: dict
    seeds: dict | None
    what: str
    format: str
    source: str = "arrays"
    excluded: dict = field(default_factory=dict)  # {task: {algo: seeds excluded}}

    @property
    def tasks(self) -> list[str]:
        return list(self.values)

    @property
    def algos(self) -> list[str]:
        return list(dict.fromkeys(a for per in self.values.values() for a in per))


def excerpt(text, limit: int = 40) -> str:
    """At most `limit` printable characters of `text`, quoted; an ellipsis marks a cut."""
    text = "".join(c if c.isprintable() else "?" for c in str(text)[: limit + 1])
    return repr(text[:limit] + ("…" if len(text) > limit else ""))


# ---------------------------------------------------------------- files
def _check_file(path: Path, kind: str) -> None:
    """Size and content sniffed before anything is read."""
    size = path.stat().st_size
    if size == 0:
        raise UsageError(f"{path} is empty; pass a {kind} with a header and rows")
    suffix = path.suffix.lower()
    limit = MAX_TABLE_BYTES if suffix in (".parquet", ".pq", ".npz") else MAX_TEXT_BYTES
    if size > limit:
        raise UsageError(
            f"{path} is {size / 2**30:.1f} GiB, above the {limit >> 30} GiB a "
            f"{'text ' if limit == MAX_TEXT_BYTES else ''}table may have; reduce it to one row per seed "
            f"(and trial){', or save it as Parquet' if limit == MAX_TEXT_BYTES else ''} first"
        )
    with open(path, "rb") as fh:
        head = fh.read(MAX_HEADER_BYTES)
    if suffix in (".parquet", ".pq"):
        if not head.startswith(b"PAR1"):
            raise UsageError(
                f"{path} is not a Parquet file (it does not start with PAR1); pass a Parquet or CSV table"
            )
        return
    if suffix == ".npz":
        if not head.startswith(b"PK"):
            raise UsageError(f"{path} is not an .npz archive; save the arrays with numpy.savez")
        return
    zero = head.find(b"\0")
    if zero >= 0:
        raise UsageError(
            f"{path} holds binary data (a zero byte at byte {zero}), not a CSV "
            "table; pass a text CSV or a Parquet file"
        )
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError as exc:
        if exc.start < len(head) - 4:  # not just a character cut at the end of the sniffed bytes
            raise UsageError(
                f"{path} is not UTF-8 text (byte {exc.start}); pass a UTF-8 CSV or a Parquet file"
            ) from None
        text = head[: exc.start].decode("utf-8")
    if "\n" not in text and size > len(head):
        raise UsageError(
            f"{path}: the first line is over {MAX_HEADER_BYTES // 1024} KiB, so it is no CSV "
            f"header (it starts {excerpt(text)}); pass a CSV whose first line names the columns"
        )


def _frame(path: Path):
    import pandas as pd

    _check_file(path, "table")
    try:
        if path.suffix.lower() in (".parquet", ".pq"):
            return pd.read_parquet(path)
        return pd.read_csv(path, dtype=str, keep_default_na=False, na_filter=False, skipinitialspace=True)
    except (OSError, ValueError, ImportError, UnicodeDecodeError) as exc:
        raise UsageError(
            f"cannot read the table {path}: "
            f"{excerpt(str(exc).splitlines()[0] if str(exc) else type(exc).__name__, 80)}"
        ) from None


def _numeric(frame, column: str, where: str, rows: str = "row") -> np.ndarray:
    """A float column: missing and NaN entries become NaN (failed seeds); text and ±inf are errors."""
    import pandas as pd

    raw = frame[column]
    if raw.dtype == object or pd.api.types.is_string_dtype(raw):
        text = raw.astype(str).str.strip()
        vals = pd.to_numeric(text, errors="coerce").to_numpy(np.float64, na_value=np.nan)
        missing = text.str.lower().isin(MISSING).to_numpy() | raw.isna().to_numpy()
        bad = np.isnan(vals) & ~missing
    elif pd.api.types.is_numeric_dtype(raw) or pd.api.types.is_bool_dtype(raw):
        vals = raw.to_numpy(np.float64, na_value=np.nan)
        bad = np.zeros(vals.shape, bool)
    else:
        raise UsageError(
            f"{where}: column {column!r} is of type {raw.dtype}, not real numbers; "
            f"every {column} must be a number"
        )
    bad |= np.isinf(vals) | (np.abs(np.nan_to_num(vals)) > MAX_VALUE)
    if bad.any():
        i = int(np.argmax(bad))
        what = (
            "a value beyond ±1e15 (rescale the column)"
            if np.isfinite(vals[i])
            else f"the non-numeric value {excerpt(raw.iloc[i])}"
        )
        raise UsageError(
            f"{where}: {rows} {i + 1} ({rows}s counted from 1), column {column!r}, has {what}; "
            f"every {column} must be a finite number (missing or NaN: a failed seed)"
        )
    return vals


def _labels(frame, column: str, where: str) -> np.ndarray:
    raw = frame[column]
    text = raw.astype(str).str.strip().to_numpy()
    missing = raw.isna().to_numpy() | (text == "")
    if missing.any():
        i = int(np.argmax(missing))
        raise UsageError(
            f"{where}: row {i + 1} (rows counted from 1), column {column!r}, is empty; "
            f"name the {column} of every row"
        )
    return text


def is_frame(data) -> bool:
    """Whether `data` is a table in memory (a pandas DataFrame)."""
    return all(hasattr(data, a) for a in ("columns", "iloc", "to_numpy"))


def read_tidy(path, *, value: str = "value", aggregate: str = "sum") -> PerSeed:
    """A tidy CSV or Parquet table (see the module's docstring), or the same table in memory as a
    pandas DataFrame (read as the Parquet file of it would be)."""
    if aggregate not in AGGREGATES:
        raise UsageError(f"--aggregate must be one of {', '.join(AGGREGATES)} (got {excerpt(aggregate)})")
    if is_frame(path):
        frame, path = path.copy(deep=False), "DataFrame"
    else:
        path = Path(path)
        frame = _frame(path)
    frame.columns = [str(c).strip() for c in frame.columns]
    for col in ("algo", "seed", value):
        if col not in frame.columns:
            found = ", ".join(excerpt(c, 20) for c in list(frame.columns)[:8])
            more = " …" if len(frame.columns) > 8 else ""
            hint = " (choose the value column with --value COLUMN)" if col == value else ""
            raise UsageError(
                f"{path}: no column {col!r}; a tidy table has columns algo, seed[, task][, trial] "
                f"and a value column{hint} (found: {found or 'none'}{more})"
            )
    if len(frame) == 0:
        raise UsageError(f"{path}: the table has no rows")
    algo, seed = _labels(frame, "algo", str(path)), _labels(frame, "seed", str(path))
    task = _labels(frame, "task", str(path)) if "task" in frame.columns else np.full(len(frame), ONE_TASK)
    vals = _numeric(frame, value, str(path))
    has_trial = "trial" in frame.columns
    trial = _numeric(frame, "trial", str(path)) if has_trial else np.zeros(len(frame))
    if has_trial and np.isnan(trial).any():
        i = int(np.argmax(np.isnan(trial)))
        raise UsageError(f"{path}: row {i + 1} (rows counted from 1) has no trial; number every trial")
    key_cols = (task, algo, seed, trial) if has_trial else (task, algo, seed)
    codes = np.stack([np.unique(c, return_inverse=True)[1].reshape(-1) for c in key_cols], 1)
    _, first, inverse = np.unique(codes, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    if first.size < len(frame):
        dup = np.nonzero(np.bincount(inverse) > 1)[0][0]
        i, j = np.nonzero(inverse == dup)[0][:2]
        what = (
            f"algo {excerpt(algo[i], 20)}, seed {excerpt(seed[i], 20)}"
            + (f", task {excerpt(task[i], 20)}" if task[i] else "")
            + (f", trial {trial[i]:g}" if has_trial else "")
        )
        hint = (
            "" if has_trial else " (several rows per seed need a trial column; several tasks a task column)"
        )
        raise UsageError(f"{path}: row {j + 1} repeats row {i + 1} ({what}){hint}")
    values: dict = {}
    seeds: dict = {}
    excluded: dict = {}
    for t in dict.fromkeys(task):
        for a in dict.fromkeys(algo[task == t]):
            rows = np.nonzero((task == t) & (algo == a))[0]
            ids, v = _per_seed(seed[rows], trial[rows], vals[rows], has_trial, aggregate, path, t, a)
            ok = ~np.isnan(v)
            values.setdefault(t, {})[a] = v[ok]
            seeds.setdefault(t, {})[a] = ids[ok]
            if not ok.all():
                excluded.setdefault(t, {})[a] = int((~ok).sum())
    what = "per-seed value: " + (TRIAL_TEXTS[aggregate] if has_trial else f"its row's {value!r}")
    return PerSeed(values, seeds, what, "tidy", str(path), excluded)


def _per_seed(seed, trial, vals, has_trial, aggregate, path, task, algo):
    if not has_trial:
        return seed, vals
    ids, inv = np.unique(seed, return_inverse=True)
    inv = inv.reshape(-1)
    order = np.lexsort((trial, inv))
    inv_o, val_o = inv[order], vals[order]
    counts = np.bincount(inv_o, minlength=ids.size)
    if aggregate == "sum" and np.unique(counts).size > 1:
        short = int(np.argmin(counts))
        where = f"task {excerpt(task, 20)}, " if task else ""
        raise UsageError(
            f"{path}: {where}algo {excerpt(algo, 20)}, seed {excerpt(ids[short], 20)} has "
            f"{counts[short]} trial(s) but seed {excerpt(ids[int(np.argmax(counts))], 20)} has "
            f"{counts.max()}; sums over trials need the same trials for every seed (or pass "
            "--aggregate mean or last)"
        )
    if aggregate == "last":
        return ids, val_o[np.cumsum(counts) - 1]
    failed = np.bincount(inv_o, weights=np.isnan(val_o), minlength=ids.size) > 0
    sums = np.bincount(inv_o, weights=np.nan_to_num(val_o), minlength=ids.size)
    out = sums if aggregate == "sum" else sums / counts
    out[failed] = np.nan  # a seed with a failed trial is a failed seed
    return ids, out


def from_arrays(arrays, *, source: str = "arrays", fmt: str = "arrays") -> PerSeed:
    """``{algo: 1-D}``, ``{algo: [runs, tasks]}`` (rliable) or ``{task: {algo: 1-D}}``; NaN runs excluded."""
    if not hasattr(arrays, "items") or not arrays:
        raise UsageError(f"{source}: no arrays; give one array of per-seed values per algorithm")
    nested = all(hasattr(v, "items") for v in arrays.values())
    tasks: dict = {}
    if nested:
        for t, per in arrays.items():
            tasks[str(t)] = {str(a): _array(v, source, a, 1) for a, v in per.items()}
        what = "per-seed value: as given"
    else:
        shaped = {str(a): _array(v, source, a, 2) for a, v in arrays.items()}
        widths = {a: v.shape[1] for a, v in shaped.items()}
        if len(set(widths.values())) > 1:
            raise UsageError(
                f"{source}: algorithms have different numbers of tasks "
                f"({', '.join(f'{k}: {v}' for k, v in list(widths.items())[:6])}); every "
                "algorithm needs a [runs, tasks] array with the same tasks, in the same order"
            )
        k = next(iter(widths.values()))
        for j in range(k):
            tasks[ONE_TASK if k == 1 else f"task{j}"] = {a: v[:, j] for a, v in shaped.items()}
        what = "per-run value: as given" + (f" ({k} tasks: the array's columns)" if k > 1 else "")
    values, excluded = {}, {}
    for t, per in tasks.items():
        for a, v in per.items():
            ok = ~np.isnan(v)
            values.setdefault(t, {})[a] = v[ok]
            if not ok.all():
                excluded.setdefault(t, {})[a] = int((~ok).sum())
    return PerSeed(values, None, what, fmt, source, excluded)


def _array(v, source, name, ndim: int) -> np.ndarray:
    arr = np.asarray(v)
    real = arr.dtype != bool and (
        np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
    )
    if arr.ndim == 1 and ndim == 2:
        arr = arr[:, None]
    if arr.ndim != ndim or not real or 0 in arr.shape:
        want = "a 1-D array of per-seed values" if ndim == 1 else "a non-empty [runs, tasks] array"
        raise UsageError(
            f"{source}: array {excerpt(name, 30)} has shape {arr.shape} and dtype {arr.dtype}; "
            f"each algorithm needs {want} of real numbers"
        )
    arr = arr.astype(np.float64)
    bad = np.isinf(arr) | (np.abs(np.nan_to_num(arr)) > MAX_VALUE)
    if bad.any():
        where = ", ".join(str(int(i)) for i in np.argwhere(bad)[0])
        raise UsageError(
            f"{source}: array {excerpt(name, 30)}, run/task {where} is {arr[bad][0]}; every score "
            f"must be finite and within ±{MAX_VALUE:g} (NaN marks a failed run)"
        )
    return arr


def read_npz(path) -> PerSeed:
    path = Path(path)
    _check_file(path, "npz")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: np.asarray(data[k]) for k in data.files}
    except (OSError, ValueError, EOFError) as exc:
        raise UsageError(f"cannot read the arrays {path}: {excerpt(str(exc).splitlines()[0], 80)}") from None
    if len(arrays) < 2:
        raise UsageError(
            f"{path} holds {len(arrays)} array(s); an rliable-style .npz needs one [runs, tasks] "
            "array per algorithm, at least two (np.savez(path, algo_a=..., algo_b=...))"
        )
    return from_arrays(arrays, source=str(path), fmt="rliable")


def default_out(path) -> Path:
    """A table's output folder: ``<stem>_compare`` beside it."""
    path = Path(path)
    return path.parent / f"{path.stem if path.is_file() else path.name}_compare"


def check_scale(data: PerSeed) -> None:
    """Values the statistics can take: within ±`MAX_VALUE`, and spread by at least `MIN_SPREAD`."""
    for per in data.values.values():
        for a, x in per.items():
            if not np.all(np.abs(x) <= MAX_VALUE):
                raise UsageError(
                    f"{data.source}: algo {excerpt(a, 30)} has a per-seed value beyond ±{MAX_VALUE:g}, "
                    "where the statistics overflow; rescale the values"
                )
        pooled = np.concatenate([x for x in per.values() if x.size])
        spread = float(pooled.max() - pooled.min()) if pooled.size else 0.0
        if 0 < spread < MIN_SPREAD:
            raise UsageError(
                f"{data.source}: the per-seed values differ by at most {spread:.3g}, below "
                f"{MIN_SPREAD:g}, where their squares vanish; rescale the values"
            )
