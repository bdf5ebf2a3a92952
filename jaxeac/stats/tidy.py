"""Compare any algorithms from a tidy table of per-seed results (`jaxeac compare --table`).

Inputs, each turned into one value per seed (run) and algorithm:

* a tidy long table, CSV or Parquet, columns ``algo, seed[, trial], value``. Without
  ``trial`` each (algo, seed) has one row, its value; with ``trial`` the per-seed value
  is the sum over that seed's trials (``aggregate="mean"``: the mean; ``"last"``: the
  value of its largest trial). With ``sum`` every seed of an algorithm must have the same
  number of trials (sums over different numbers of trials are not comparable).
* a folder of Stable-Baselines3 monitor files, ``ALGO/SEED/monitor.csv`` or
  ``ALGO_SEED.monitor.csv`` (a ``#{...}`` JSON line, then columns ``r,l,t``): the
  per-seed value is the mean episode reward ``r`` over the last 10 % of episodes
  (ceil(0.1 · episodes), at least one).
* rliable-style arrays: a ``.npz`` with one ``[runs, tasks]`` array per algorithm (the
  key is the algorithm): the value of a run is its mean over tasks; every algorithm
  must have the same number of tasks.

The family of comparisons is all pairs of algorithms (X listed after Y in the table's
order of first appearance), or each algorithm against ``baseline``; Holm (1979) adjusts
Welch's p over that family. Each row: n and mean of each, mean(X) − mean(Y) with a BCa
CI, Welch's p, Holm's p, Hedges' g, the IQM of each with a BCa CI and the probability
of improvement P(X > Y) + ½ P(X = Y) with a BCa CI. All intervals come from one
stratified bootstrap (Agarwal et al. 2021, "Deep RL at the edge of the statistical
precipice"): the seeds of each algorithm are resampled within that algorithm, the same
`resamples` draws of an algorithm serving its IQM, its mean and every pair it is in
(rliable reports percentile intervals; here they are BCa, as in the rest of
`jaxeac.stats`). Comparisons are unpaired, so algorithms may have different seed counts.

Malformed input raises `UsageError` naming the row, column, file or algorithm, before
anything is written. (Over 400 lines: the three readers, their checks and the
comparison they feed are one feature, kept in one module.)
"""

from __future__ import annotations

import json
import math
import re
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxeac.errors import UsageError
from jaxeac.stats._rng import as_key, uniform_index
from jaxeac.stats.bootstrap import bca_interval, bca_two_sample, iqm_ci
from jaxeac.stats.closed_form import hedges_g, holm, welch_t
from jaxeac.stats.resample import _cap

AGGREGATES = ("sum", "mean", "last")
COLUMNS = ("algo", "seed", "value")
#: Share of the last episodes whose mean reward is the per-seed value of an SB3 run.
SB3_LAST_SHARE = 0.10
#: What a per-seed value is when the table has a trial column, per --aggregate.
#: The largest |value| a table may hold, and the smallest spread (largest minus smallest per-seed
#: value) of one that varies: the bootstrap sums values and their squares in float32 (about 3.4e38 at
#: most, 1.2e-38 at least), and the closed-form tests square them in float64, so values beyond these
#: would overflow or vanish and the intervals and p-values would be wrong (or NaN).
MAX_VALUE = 1e15
MIN_SPREAD = 1e-15
TRIAL_TEXTS = {"sum": "the sum of value over its trials", "mean": "the mean of value over its trials",
               "last": "value at its last (largest) trial"}


# ---------------------------------------------------------------- reading
def _table_frame(path: Path):
    import pandas as pd

    suffix = path.suffix.lower()
    try:
        if suffix in (".parquet", ".pq"):
            return pd.read_parquet(path), "row"
        return pd.read_csv(path, dtype=str, keep_default_na=False, na_filter=False,
                           skipinitialspace=True), "row"
    except (OSError, ValueError, ImportError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise UsageError(f"cannot read the table {path}: {first}") from None


def _numeric(frame, column: str, path: Path, *, finite: bool = True) -> np.ndarray:
    """A float column; the first non-numeric, missing or non-finite entry is named by its row."""
    import pandas as pd

    raw = frame[column]
    textual = raw.dtype == object or pd.api.types.is_string_dtype(raw)
    if not textual and not (pd.api.types.is_integer_dtype(raw) or pd.api.types.is_float_dtype(raw)
                            or pd.api.types.is_bool_dtype(raw)):
        raise UsageError(f"{path}: column {column!r} is of type {raw.dtype}, not real numbers; "
                         f"every {column} must be a finite number")
    vals = pd.to_numeric(raw, errors="coerce").to_numpy(np.float64, na_value=np.nan) \
        if textual else raw.to_numpy(np.float64)
    bad = ~np.isfinite(vals) if finite else np.isnan(vals)
    if bad.any():
        i = int(np.argmax(bad))
        text = str(raw.iloc[i])
        if text.strip() == "" or text.strip().lower() in ("nan", "none", "null", "na", "<na>"):
            what = "a missing or NaN value"
        elif math.isinf(vals[i]) if not np.isnan(vals[i]) else False:
            what = f"the non-finite value {text!r}"
        else:
            what = f"the non-numeric value {text!r}"
        raise UsageError(f"{path}: row {i + 1} (data rows counted from 1), column {column!r}, "
                         f"has {what}; every {column} must be a finite number")
    if finite:
        huge = np.abs(vals) > MAX_VALUE
        if huge.any():
            i = int(np.argmax(huge))
            raise UsageError(f"{path}: row {i + 1} (data rows counted from 1), column {column!r}, has "
                             f"{raw.iloc[i]!s}, beyond ±{MAX_VALUE:g}, where the statistics overflow; "
                             "rescale the column (e.g. divide it by a power of ten)")
    return vals


def _labels(frame, column: str, path: Path) -> np.ndarray:
    raw = frame[column]
    text = raw.astype(str).str.strip().to_numpy()
    missing = raw.isna().to_numpy() | (text == "")
    if missing.any():
        i = int(np.argmax(missing))
        raise UsageError(f"{path}: row {i + 1} (data rows counted from 1), column {column!r}, is empty; "
                         f"name the {column} of every row")
    return text


def read_tidy(path, aggregate: str = "sum") -> tuple[dict[str, np.ndarray], str]:
    """Per-seed values {algo: [seeds]} from a tidy CSV or Parquet table, and what a value is."""
    if aggregate not in AGGREGATES:
        raise UsageError(f"--aggregate must be one of {', '.join(AGGREGATES)} (got {aggregate!r})")
    path = Path(path)
    frame, _ = _table_frame(path)
    frame.columns = [str(c).strip() for c in frame.columns]
    for col in COLUMNS:
        if col not in frame.columns:
            raise UsageError(f"{path}: no column {col!r}; a tidy table has columns algo, seed[, trial], "
                             "value "
                             f"(found: {', '.join(map(str, frame.columns)) or 'none'})")
    if len(frame) == 0:
        raise UsageError(f"{path}: the table has no rows")
    algo = _labels(frame, "algo", path)
    seed = _labels(frame, "seed", path)
    value = _numeric(frame, "value", path)
    has_trial = "trial" in frame.columns
    trial = _numeric(frame, "trial", path) if has_trial else np.zeros(len(frame))
    keys = list(zip(algo, seed, trial, strict=True)) if has_trial else list(zip(algo, seed, strict=True))
    seen: dict = {}
    for i, k in enumerate(keys):
        if k in seen:
            what = f"algo {k[0]!r}, seed {k[1]!r}" + (f", trial {k[2]:g}" if has_trial else "")
            hint = "" if has_trial else " (several rows per seed need a trial column)"
            raise UsageError(f"{path}: row {i + 1} repeats row {seen[k] + 1} ({what}){hint}")
        seen[k] = i
    samples: dict[str, np.ndarray] = {}
    for name in dict.fromkeys(algo):  # order of first appearance
        rows = np.nonzero(algo == name)[0]
        if not has_trial:
            samples[name] = value[rows]
            continue
        s_ids, inv = np.unique(seed[rows], return_inverse=True)
        order = np.lexsort((trial[rows], inv))  # by seed, then trial
        inv_o, val_o = inv[order], value[rows][order]
        counts = np.bincount(inv_o, minlength=s_ids.size)
        if aggregate == "sum" and np.unique(counts).size > 1:
            short = int(np.argmin(counts))
            raise UsageError(f"{path}: algo {name!r}, seed {s_ids[short]!r} has {counts[short]} trial(s) but "
                             f"seed {s_ids[int(np.argmax(counts))]!r} has {counts.max()}; sums over trials "
                             "need "
                             "the same trials for every seed (or pass --aggregate mean or last)")
        if aggregate == "last":
            ends = np.cumsum(counts) - 1
            samples[name] = val_o[ends]
        else:
            sums = np.bincount(inv_o, weights=val_o, minlength=s_ids.size)
            samples[name] = sums if aggregate == "sum" else sums / counts
    return samples, "per-seed value: " + (TRIAL_TEXTS[aggregate] if has_trial else "its row's value")


def _read_monitor(path: Path) -> float:
    import pandas as pd

    try:
        with open(path, encoding="utf-8") as fh:
            first = fh.readline()
            skip = 1 if first.startswith("#") else 0
        frame = pd.read_csv(path, skiprows=skip)
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise UsageError(f"cannot read the SB3 monitor file {path}: {str(exc).splitlines()[0]}") from None
    frame.columns = [str(c).strip() for c in frame.columns]
    if "r" not in frame.columns:
        raise UsageError(f"{path}: no column 'r' (episode reward); an SB3 monitor file has a #{{...}} line, "
                         "then columns r,l,t")
    if len(frame) == 0:
        raise UsageError(f"{path}: no episodes (the file has a header only)")
    try:
        r = _numeric(frame, "r", path)
    except UsageError as exc:
        raise UsageError(str(exc).replace("data rows counted from 1", "episodes counted from 1")) from None
    k = max(1, math.ceil(SB3_LAST_SHARE * r.size))
    return float(r[-k:].mean())


def read_sb3(folder) -> tuple[dict[str, np.ndarray], str]:
    """Per-seed values from SB3 monitor files: ``ALGO/SEED/monitor.csv`` or ``ALGO_SEED.monitor.csv``."""
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
                raise UsageError(f"{path}: an SB3 monitor file is named ALGO_SEED.monitor.csv "
                                 "(or lies in ALGO/SEED/monitor.csv)")
            algo, seed = m.group(1), m.group(2)
        runs.setdefault(algo, {})[seed] = _read_monitor(path)
    if not runs:
        raise UsageError(f"{folder}: no SB3 monitor files (ALGO/SEED/monitor.csv or ALGO_SEED.monitor.csv)")
    samples = {a: np.array([v[s] for s in sorted(v)]) for a, v in runs.items()}
    return samples, (f"per-seed value: mean episode reward over the last {SB3_LAST_SHARE:.0%} of "
                     "episodes (at least one) of each SB3 monitor file")


def read_rliable(path) -> tuple[dict[str, np.ndarray], str]:
    """Per-run values from an rliable-style .npz: one [runs, tasks] array per algorithm."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: np.asarray(data[k]) for k in data.files}
    except (OSError, ValueError, EOFError) as exc:
        raise UsageError(f"cannot read the rliable arrays {path}: {str(exc).splitlines()[0]}") from None
    samples, tasks = {}, {}
    for name, arr in arrays.items():
        if arr.ndim == 1:
            arr = arr[:, None]
        real = np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
        if arr.ndim != 2 or not real or 0 in arr.shape:
            raise UsageError(f"{path}: array {name!r} has shape {arr.shape} and dtype {arr.dtype}; "
                             "each algorithm needs a non-empty [runs, tasks] array of real numbers")
        scores = arr.astype(np.float64)
        bad = ~np.isfinite(scores) | (np.abs(np.nan_to_num(scores)) > MAX_VALUE)
        if bad.any():
            run, task = (int(i) for i in np.argwhere(bad)[0])
            raise UsageError(f"{path}: array {name!r}, run {run}, task {task} is {arr[run, task]}; every "
                             f"score must be a finite number within ±{MAX_VALUE:g}, where the statistics "
                             "do not overflow (rescale the scores if they are larger)")
        samples[name] = arr.astype(np.float64).mean(axis=1)
        tasks[name] = arr.shape[1]
    if len(set(tasks.values())) > 1:
        raise UsageError(f"{path}: algorithms have different numbers of tasks "
                         f"({', '.join(f'{k}: {v}' for k, v in tasks.items())}); a run's value is its "
                         "mean over tasks, so every algorithm needs the same tasks")
    return samples, "per-run value: mean score over tasks"


def read_any(path, aggregate: str = "sum") -> tuple[dict[str, np.ndarray], str, str]:
    """(samples, what a value is, format) from a tidy table, an SB3 folder or an rliable .npz."""
    path = Path(path)
    if not path.exists():
        raise UsageError(f"--table {path} does not exist; pass a CSV or Parquet table, an .npz or an "
                         "SB3 folder")
    if path.is_dir():
        samples, what, fmt = (*read_sb3(path), "sb3")
    elif path.suffix.lower() == ".npz":
        samples, what, fmt = (*read_rliable(path), "rliable")
    else:
        samples, what, fmt = (*read_tidy(path, aggregate), "tidy")
    check_scale(samples, path)
    return samples, what, fmt


def check_scale(samples: dict[str, np.ndarray], path) -> None:
    """Per-seed values the statistics can take: within ±`MAX_VALUE` (sums over trials can pass the
    bound their rows keep) and, unless all equal, spread by at least `MIN_SPREAD`."""
    for name, x in samples.items():
        if not np.all(np.abs(x) <= MAX_VALUE):
            raise UsageError(f"{path}: algo {name!r} has a per-seed value beyond ±{MAX_VALUE:g}, where the "
                             "statistics overflow; rescale the values (e.g. divide them by a power of ten)")
    values = np.concatenate([np.asarray(x, np.float64).reshape(-1) for x in samples.values()])
    spread = float(values.max() - values.min()) if values.size else 0.0
    if 0 < spread < MIN_SPREAD:
        raise UsageError(f"{path}: the per-seed values differ by at most {spread:.3g}, below {MIN_SPREAD:g}, "
                         "where their squares vanish in the statistics; rescale the values (e.g. multiply "
                         "them by a power of ten)")


# ---------------------------------------------------------------- checks
def check_samples(samples: dict[str, np.ndarray], baseline=None, treatment=None):
    """Validate the samples and return the family of comparisons [(x, y)]: diff = mean x − mean y."""
    names = list(samples)
    if len(names) < 2:
        raise UsageError(f"the table has one algorithm only ({', '.join(names) or 'none'}); "
                         "a comparison needs at least 2 (column 'algo')")
    for name, x in samples.items():
        if x.size < 2:
            raise UsageError(f"algo {name!r} has {x.size} seed(s); at least 2 seeds per algorithm are needed")
    for flag, name in (("--baseline", baseline), ("--treatment", treatment)):
        if name is not None and name not in samples:
            raise UsageError(f"{flag} {name!r} is not in the table (algorithms: {', '.join(names)})")
    if treatment is not None and baseline is None:
        raise UsageError("--treatment needs --baseline (or leave both out for all pairs)")
    if baseline is not None and treatment is not None:
        if baseline == treatment:
            raise UsageError("--baseline and --treatment name the same algorithm")
        return [(treatment, baseline)]
    if baseline is not None:
        return [(n, baseline) for n in names if n != baseline]
    return [(names[j], names[i]) for i in range(len(names)) for j in range(i + 1, len(names))]


# ---------------------------------------------------------------- stratified bootstrap
@partial(jax.jit, static_argnames=("chunk", "n"))
def _draw(key, c, z, chunk: int, n: int):
    """Bootstrap counts of one chunk (the draws of `resample._boot_chunk`, so `iqm_ci` with the same
    key sees the same resamples), their column sums of z [n, 2] and exclusive cumulative counts."""
    idx = uniform_index(jax.random.fold_in(key, c), (chunk, n), n)
    flat = (idx + (jnp.arange(chunk, dtype=jnp.int32) * n)[:, None]).reshape(-1)
    counts = jnp.zeros((chunk * n,), jnp.float32).at[flat].add(1.0, mode="promise_in_bounds")
    counts = counts.reshape(chunk, n)
    cum = jnp.concatenate([jnp.zeros((chunk, 1), jnp.float32), jnp.cumsum(counts, axis=1)], axis=1)
    return counts, counts @ z, cum


@jax.jit
def _wins(counts_x, cum_y, lo, hi):
    """Σ_i c_x[i] · (#y* < x_i + ½ #y* = x_i) per resample (y sorted; lo/hi: searchsorted left/right)."""
    below = cum_y[:, lo]
    return jnp.sum(counts_x * (below + 0.5 * (cum_y[:, hi] - below)), axis=1)


def _win_counts(x_sorted, y_sorted):
    """s_i = #y < x_i + ½ #y = x_i for each x_i, and the same for y against x."""
    lo, hi = np.searchsorted(y_sorted, x_sorted, "left"), np.searchsorted(y_sorted, x_sorted, "right")
    s = lo + 0.5 * (hi - lo)
    lo2, hi2 = np.searchsorted(x_sorted, y_sorted, "left"), np.searchsorted(x_sorted, y_sorted, "right")
    t = (x_sorted.size - hi2) + 0.5 * (hi2 - lo2)  # x_i > y_j plus half the ties
    return lo, hi, s, t


def prob_improvement(x, y) -> float:
    """P(X > Y) + ½ P(X = Y) over all pairs of seeds (Agarwal et al. 2021)."""
    xs, ys = np.sort(np.asarray(x, np.float64)), np.sort(np.asarray(y, np.float64))
    return float(_win_counts(xs, ys)[2].sum() / (xs.size * ys.size))


def compare_samples(samples: dict[str, np.ndarray], *, baseline=None, treatment=None, resamples: int = 10_000,
                    alpha: float = 0.05, key=0, chunk: int = 1000) -> dict:
    """All statistics of the family (see the module docstring) as a JSON-ready dict."""
    family = check_samples(samples, baseline, treatment)
    names = list(samples)
    root = as_key(key)
    centre = float(np.mean([x.mean() for x in samples.values()]))
    sorted_ = {a: np.sort(np.asarray(x, np.float64)) for a, x in samples.items()}
    keys = {a: jax.random.fold_in(root, i) for i, a in enumerate(names)}
    used = set(a for pair in family for a in pair)
    prep = {}
    for a in used:
        xs = sorted_[a] - centre
        prep[a] = (xs, jnp.asarray(np.stack([xs, xs**2], 1), jnp.float32), _cap(chunk, resamples, xs.size))
    pair_idx = {}
    for x, y in family:
        lo, hi, s, t = _win_counts(sorted_[x], sorted_[y])
        pair_idx[(x, y)] = (jnp.asarray(lo, jnp.int32), jnp.asarray(hi, jnp.int32), s, t)
    # chunks of resamples: every algorithm's draws of chunk c, then every pair's wins from them
    sums = {a: [] for a in used}
    wins = {p: [] for p in family}
    n_chunks = max(-(-resamples // prep[a][2]) for a in used)
    for c in range(n_chunks):
        drawn = {}
        for a in used:
            xs, z, ch = prep[a]
            if c * ch < resamples:
                drawn[a] = _draw(keys[a], c, z, ch, xs.size)
                sums[a].append(drawn[a][1])
        for p in family:
            x, y = p
            if x in drawn and y in drawn and drawn[x][0].shape[0] == drawn[y][0].shape[0]:
                wins[p].append(_wins(drawn[x][0], drawn[y][2], *pair_idx[p][:2]))
    sums = {a: np.concatenate([np.asarray(s, np.float64) for s in v])[:resamples] for a, v in sums.items()}
    algos = {}
    for a in names:
        ci = iqm_ci(samples[a], keys[a], resamples=resamples, alpha=alpha, chunk=chunk)
        algos[a] = {"n": int(samples[a].size), "mean": float(samples[a].mean()), "iqm": ci.estimate,
                    "iqm_ci95": [ci.low, ci.high]}
    welch = [welch_t(samples[y], samples[x]).pvalue for x, y in family]
    adjusted = holm(welch)
    rows = []
    for k, (x, y) in enumerate(family):
        xs, ys = prep[x][0], prep[y][0]
        sy, sx = sums[y], sums[x]
        d = bca_two_sample("mean_diff", ys, xs, sy[:, 0], sy[:, 1], sx[:, 0], sx[:, 1], alpha)
        _, _, s, t = pair_idx[(x, y)]
        nx, ny = xs.size, ys.size
        p_hat = float(s.sum() / (nx * ny))
        if wins[(x, y)]:
            star = np.concatenate([np.asarray(w, np.float64) for w in wins[(x, y)]])[:resamples] / (nx * ny)
        else:  # different chunk sizes (very many seeds): pair the draws chunk by chunk on the host
            star = _wins_host(prep, keys, x, y, pair_idx[(x, y)], resamples) / (nx * ny)
        jx = (s.sum() - s) / ((nx - 1) * ny)
        jy = (s.sum() - t) / (nx * (ny - 1))
        lo, hi = bca_interval(p_hat, star, [jx, jy], alpha)
        rows.append({
            "x": x, "y": y, "n_x": int(nx), "n_y": int(ny),
            "mean_x": algos[x]["mean"], "mean_y": algos[y]["mean"],
            "diff": d.estimate, "diff_ci95": [d.low, d.high],
            "p_welch": float(welch[k]), "p_holm": float(adjusted[k]),
            "hedges_g": hedges_g(samples[y], samples[x]),
            "iqm_x": algos[x]["iqm"], "iqm_x_ci95": algos[x]["iqm_ci95"],
            "iqm_y": algos[y]["iqm"], "iqm_y_ci95": algos[y]["iqm_ci95"],
            "p_improvement": p_hat, "p_improvement_ci95": [float(lo), float(hi)],
        })
    family_text = ("all pairs" if baseline is None else
                   f"{treatment} vs {baseline}" if treatment is not None else f"all vs baseline {baseline}")
    return {"family": family_text, "comparisons_in_family": len(family), "alpha": alpha,
            "resamples": resamples, "key": key if isinstance(key, int) else None,
            "algorithms": algos, "comparisons": rows}


def _wins_host(prep, keys, x, y, idx, resamples):
    """Wins per resample when x and y were drawn in chunks of different sizes (re-drawn, then aligned)."""
    def counts_and_cum(a):
        xs, z, ch = prep[a]
        parts = [_draw(keys[a], c, z, ch, xs.size) for c in range(-(-resamples // ch))]
        return parts, ch

    px, chx = counts_and_cum(x)
    py, chy = counts_and_cum(y)
    cx = np.concatenate([np.asarray(p[0]) for p in px])[:resamples]
    cy = np.concatenate([np.asarray(p[2]) for p in py])[:resamples]
    step = min(chx, chy)
    return np.concatenate([np.asarray(_wins(cx[i:i + step], cy[i:i + step], idx[0], idx[1]), np.float64)
                           for i in range(0, resamples, step)])


# ---------------------------------------------------------------- outputs
def default_out(path) -> Path:
    path = Path(path)
    return path.parent / f"{path.stem if path.is_file() else path.name}_compare"


def report_markdown(result: dict) -> str:
    from jaxeac.fmt import p_value

    def f(v):
        return f"{v:.4g}"

    def ci(pair):
        return f"[{pair[0]:.4g}, {pair[1]:.4g}]"

    lines = [
        "# Comparison of per-seed results",
        "",
        f"Source: `{result['source']}` ({result['format']}); {result['per_seed_value']}.",
        f"Family: {result['family']} ({result['comparisons_in_family']} comparison(s)); Holm's adjustment "
        f"over the family. Intervals: 95 % BCa from {result['resamples']:,} stratified bootstrap resamples "
        "(seeds resampled within each algorithm; Agarwal et al. 2021), key "
        f"{result['key']}. diff = mean(X) − mean(Y); P(X > Y) counts ties as one half.",
        "",
        "| X | Y | n X | n Y | mean X | mean Y | diff [95% CI] | Welch p | Holm p | Hedges' g "
        "| IQM X [95% CI] | IQM Y [95% CI] | P(X > Y) [95% CI] |",
        "|---|---|---:|---:|---:|---:|---|---:|---:|---:|---|---|---|",
    ]
    for r in result["comparisons"]:
        lines.append(
            f"| {r['x']} | {r['y']} | {r['n_x']} | {r['n_y']} | {f(r['mean_x'])} | {f(r['mean_y'])} "
            f"| {f(r['diff'])} {ci(r['diff_ci95'])} | {p_value(r['p_welch'])} | {p_value(r['p_holm'])} "
            f"| {f(r['hedges_g'])} | {f(r['iqm_x'])} {ci(r['iqm_x_ci95'])} "
            f"| {f(r['iqm_y'])} {ci(r['iqm_y_ci95'])} "
            f"| {r['p_improvement']:.3f} {ci(r['p_improvement_ci95'])} |")
    return "\n".join(lines) + "\n"


def compare_table(path, out=None, *, aggregate: str = "sum", baseline=None, treatment=None,
                  resamples: int = 10_000, alpha: float = 0.05, key=0) -> tuple[dict, Path]:
    """Read a table (tidy CSV/Parquet, SB3 folder or rliable .npz), compare, and write
    stats_table.json and report_table.md into `out` (default `<stem>_compare/` beside it)."""
    from jaxeac.io import staged_dir

    if not 0 < alpha < 1:
        raise UsageError(f"--alpha must lie in (0, 1) (got {alpha})")
    if aggregate not in AGGREGATES:
        raise UsageError(f"--aggregate must be one of {', '.join(AGGREGATES)} (got {aggregate!r})")
    samples, what, fmt = read_any(path, aggregate)
    result = compare_samples(samples, baseline=baseline, treatment=treatment, resamples=resamples,
                             alpha=alpha, key=key)
    result = {"source": str(path), "format": fmt, "per_seed_value": what,
              "aggregate": aggregate if what.endswith(TRIAL_TEXTS[aggregate]) else None, **result}
    out = Path(out) if out is not None else default_out(path)
    with staged_dir(out) as stage:
        (stage / "stats_table.json").write_text(json.dumps(result, indent=2, allow_nan=True) + "\n")
        (stage / "report_table.md").write_text(report_markdown(result))
    return result, out
