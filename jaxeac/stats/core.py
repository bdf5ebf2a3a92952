"""The engine's core, `compare_per_seed`: per-seed results from anywhere, across tasks (SPEC §6).

``compare_per_seed(data, ...)`` (the whole of `jaxeac.stats.engine.compare` but run folders) takes a
tidy table (with optional ``task`` and ``trial`` columns), SB3 monitor folders, rliable-style arrays
or arrays in a notebook
(`jaxeac.perseed`, `jaxeac.sb3`), a declared family (all pairs, or each algorithm against `baseline`),
pairing (``"auto"``: paired where both algorithms ran the same seed ids of a task) and a
confidence `level`, and returns one `Comparison` (`jaxeac.stats.result`): a row per task and
pair, a row per task and algorithm, and the aggregate across tasks (`jaxeac.stats.tasks`).

Per task and pair (X − Y, X the later algorithm or the treatment): the difference of means
with a BCa interval (Efron 1987), Welch's test (Welch 1947), Hedges' g, the probability of
improvement P(X > Y) + ½ P(X = Y) with a BCa interval, and where paired the mean per-seed
difference with a paired BCa interval and the paired t test; Holm (1979) over the family
(tasks × pairs) on the answering test: the paired t where paired, else Welch. Per algorithm:
mean and IQM with a BCa interval. One bootstrap draw per task and algorithm (seeds
resampled within each: the stratified bootstrap of Agarwal et al. 2021) serves all of them;
paired rows resample seed ids together (one shared draw per task).

The resampling path of each group is chosen once, by `resampling_path`, and recorded.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import jax
import numpy as np

from jaxeac.errors import UsageError
from jaxeac.perseed import PerSeed, check_scale, excerpt, from_arrays, is_frame, read_npz, read_tidy
from jaxeac.rng import as_key
from jaxeac.sb3 import read_sb3
from jaxeac.stats import closed_form as cf
from jaxeac.stats.groups import (
    MAX_KEPT_BYTES,
    aggregate_draws,
    pair_row,
    paired_row,
    shared_draw,
    task_groups,
)
from jaxeac.stats.large import PATH_RULE, RAW, resampling_path
from jaxeac.stats.result import Comparison

#: fold_in stream of a task's shared (paired) draw under the task's key.
PAIRED_STREAM = 1 << 20
#: Host threads for the paired rows (NumPy's samplers release the interpreter's lock): 11 tasks x 8
#: algorithms x 1,000 seeds x 10,000 resamples took 9.0-9.6 s against 12.8-13.3 s one row after another (2 cores).
PAIRED_WORKERS = min(8, os.cpu_count() or 1)
#: Tasks whose groups, rows and draws are computed at once (their draws are independent: task i's
#: key is fold_in(key, i)); rows and results keep the tasks' order. 8 rather than 4 on one H100's 16
#: cores: a 1,000-seed study's statistics after its last runs 3.5-3.8 s against 4.0-5.4 s.
TASK_WORKERS = min(8, os.cpu_count() or 1)
#: Each tail of an interval needs at least this many resamples beyond it.
MIN_TAIL_RESAMPLES = 10
#: Unit resamples (resamples × seeds) a comparison may ask for: about an hour on a 2-core CPU.
MAX_WORK = 2e11
WORK_PER_SECOND = 5e7
def check_resamples(resamples, level: float, units: int = 1) -> None:
    """Resamples enough for the level's tails, and not days of work."""
    if isinstance(resamples, bool) or not isinstance(resamples, int | np.integer) or resamples < 1:
        raise UsageError(f"--resamples must be a positive integer (got {excerpt(resamples)})")
    need = math.ceil(MIN_TAIL_RESAMPLES / ((1 - level) / 2) - 1e-9)
    if resamples < need:
        raise UsageError(
            f"--resamples {resamples} is too few for {level:g} intervals: each tail needs "
            f"{MIN_TAIL_RESAMPLES} resamples beyond it; use at least {need} (10000 recommended)"
        )
    work = float(resamples) * max(units, 1)
    if work > MAX_WORK:
        hours = work / WORK_PER_SECOND / 3600
        when = f"{hours / 24:,.0f} days" if hours >= 48 else f"{hours:,.1f} hours"
        raise UsageError(
            f"--resamples {resamples} over {units:,} seeds is about {when} of work; use at most "
            f"{int(MAX_WORK // max(units, 1)):,} (10000 gives intervals to about 0.5 %)"
        )


def check_level(level) -> float:
    if isinstance(level, bool) or not isinstance(level, int | float) or not 0.5 <= level < 1:
        raise UsageError(f"level is the confidence level, in [0.5, 1) (got {excerpt(level)}); e.g. 0.95")
    return float(level)


# ---------------------------------------------------------------- inputs
def read_any(path, *, value: str = "value", aggregate: str = "sum") -> PerSeed:
    """A tidy table, an SB3 folder or an rliable .npz."""
    path = Path(path)
    if not path.exists():
        raise UsageError(
            f"--table {path} does not exist; pass a CSV or Parquet table, an .npz or an SB3 folder"
        )
    if path.is_dir():
        return read_sb3(path)
    if path.suffix.lower() == ".npz":
        return read_npz(path)
    return read_tidy(path, value=value, aggregate=aggregate)


def as_per_seed(data, *, value: str = "value", aggregate: str = "sum") -> PerSeed:
    if isinstance(data, PerSeed):
        return data
    if isinstance(data, str | os.PathLike):
        return read_any(data, value=value, aggregate=aggregate)
    if is_frame(data):  # a tidy table in memory: as the same table read from a file
        return read_tidy(data, value=value, aggregate=aggregate)
    if hasattr(data, "items"):
        return from_arrays(data)
    raise TypeError(
        "compare takes a run folder or table path, a tidy DataFrame, a dict of per-seed arrays "
        "({algo: values}, {task: {algo: values}} or {algo: [runs, tasks]}), or a PerSeed"
    )


def select(data: PerSeed, tasks=None, baseline=None, treatment=None) -> list[tuple[str, str]]:
    """Check the data against the family asked for; return the family [(x, y)], diff = x − y."""
    if tasks is not None:
        tasks = [tasks] if isinstance(tasks, str) else list(tasks)
        for t in tasks:
            if t not in data.values:
                raise UsageError(
                    f"--tasks names {excerpt(t, 30)}, which is not in {data.source} (tasks: "
                    f"{', '.join(excerpt(x, 20) for x in data.tasks[:8])}); name tasks it has"
                )
        data.values = {t: data.values[t] for t in tasks}
        if data.seeds is not None:
            data.seeds = {t: data.seeds[t] for t in tasks}
    names = data.algos
    for t, per in data.values.items():
        if list(per) != names and set(per) != set(names):
            missing = [a for a in names if a not in per]
            raise UsageError(
                f"task {excerpt(t, 30)} lacks algorithm(s) {', '.join(excerpt(a, 20) for a in missing)};"
                " every task needs the same algorithms (drop the task with --tasks, or add its runs)"
            )
        for a, x in per.items():
            if x.size < 2:
                where = f"task {excerpt(t, 30)}, " if t else ""
                dropped = data.excluded.get(t, {}).get(a, 0)
                also = f" ({dropped} failed seed(s) excluded)" if dropped else ""
                raise UsageError(
                    f"{where}algo {excerpt(a, 30)} has {x.size} seed(s){also}; at least 2 seeds per "
                    "algorithm and task are needed (add seeds, or leave the task out with --tasks)"
                )
    if len(names) < 2:
        raise UsageError(
            f"the data hold one algorithm only ({', '.join(excerpt(a, 20) for a in names) or 'none'}); "
            "a comparison needs at least 2 (column 'algo', or one array per algorithm)"
        )
    for flag, name in (("--baseline", baseline), ("--treatment", treatment)):
        if name is not None and name not in names:
            raise UsageError(
                f"{flag} {excerpt(name, 30)} is not in the data (algorithms: "
                f"{', '.join(excerpt(a, 20) for a in names[:10])})"
            )
    if treatment is not None and baseline is None:
        raise UsageError("--treatment needs --baseline (or leave both out for all pairs)")
    if baseline is not None and treatment is not None:
        if baseline == treatment:
            raise UsageError("--baseline and --treatment name the same algorithm")
        return [(treatment, baseline)]
    if baseline is not None:
        return [(a, baseline) for a in names if a != baseline]
    return [(names[j], names[i]) for i in range(len(names)) for j in range(i + 1, len(names))]


# ---------------------------------------------------------------- the engine
def compare_per_seed(
    data,
    *,
    baseline: str | None = None,
    treatment: str | None = None,
    paired: str = "auto",
    level: float = 0.95,
    resamples: int = 10_000,
    key=0,
    value: str = "value",
    aggregate: str = "sum",
    tasks=None,
    normalize: str | None = None,
    reference_scores: dict | None = None,
    profile_points=101,
    chunk: int = 1000,
) -> Comparison:
    """Compare per-seed results (see the module docstring); returns a `Comparison`.

    `data`: a table path, a `PerSeed` or a dict of arrays (a run folder: `jaxeac.stats.engine.compare`).
    `paired`: "auto", "paired" (refuse unpaired designs) or "unpaired". `normalize`
    (several tasks): "minmax" with `reference_scores` {task: (low, high)}, "baseline" (divide by
    the baseline's mean on the task), or "none" (raw scores are on one scale); the aggregates
    across tasks need one of them; `profile_points`: the number of performance-profile thresholds
    (evenly spread over the scores), or the thresholds. Bad input raises `UsageError` (a
    `ValueError`)."""
    level = check_level(level)
    if paired not in ("auto", "paired", "unpaired"):
        raise UsageError(f"paired must be 'auto', 'paired' or 'unpaired' (got {excerpt(paired)})")
    per = as_per_seed(data, value=value, aggregate=aggregate)
    family = select(per, tasks, baseline, treatment)
    _check_values(per, resamples, level, normalize, reference_scores, baseline)
    return _engine_pass(per, family, baseline=baseline, treatment=treatment, paired=paired, level=level,
                        resamples=resamples, key=key, aggregate=aggregate, normalize=normalize,
                        reference_scores=reference_scores, profile_points=profile_points, chunk=chunk)


def compare_as_tasks_end(per: PerSeed, *, ready, baseline: str, level: float = 0.95, resamples: int = 10_000,
                         key=0, normalize: str | None = None, reference_scores: dict | None = None,
                         profile_points=101, chunk: int = 1000) -> Comparison:
    """`compare_per_seed` of `per` against `baseline` while its values are filled in, task by task (a
    study's, as each task's runs end): every task and algorithm is in `per` from the start, each
    array of its final size, and ``ready(task)`` returns once the task's arrays hold their values.
    Each task's statistics start then, on the engine's task threads, beside the runs of the tasks
    after it; the numbers are `compare_per_seed`'s of the filled `per`. The values are checked once
    all are in (they are the caller's own: a study's runs)."""
    level = check_level(level)
    family = select(per, None, baseline, None)
    result = _engine_pass(per, family, baseline=baseline, treatment=None, paired="auto", level=level,
                          resamples=resamples, key=key, aggregate="sum", normalize=normalize,
                          reference_scores=reference_scores, profile_points=profile_points, chunk=chunk,
                          ready=ready)
    _check_values(per, resamples, level, normalize, reference_scores, baseline)
    return result


def _check_values(per: PerSeed, resamples, level: float, normalize, reference_scores, baseline) -> None:
    """The checks of the values themselves: spread, resamples for their number, normalization."""
    check_scale(per)
    check_resamples(resamples, level, sum(x.size for v in per.values.values() for x in v.values()))
    if normalize is not None and len(per.tasks) > 1:
        from jaxeac.stats.tasks import check_normalization

        check_normalization(per, normalize, reference_scores, baseline)


def _engine_pass(per: PerSeed, family, *, baseline, treatment, paired, level, resamples, key, aggregate,
                 normalize, reference_scores, profile_points, chunk, ready=None) -> Comparison:
    """The one pass of `compare_per_seed` over checked values (`ready`: `compare_as_tasks_end`'s)."""
    units = sum(x.size for v in per.values.values() for x in v.values())
    alpha = round(1 - level, 12)
    root = as_key(key)
    used = list(dict.fromkeys(a for p in family for a in p))
    rows, algos, paths, drawn = [], [], {}, []
    aggregating = len(per.tasks) > 1 and normalize is not None
    keep = units * resamples * 4 <= MAX_KEPT_BYTES
    beside = ThreadPoolExecutor(max_workers=PAIRED_WORKERS, thread_name_prefix="jaxeac-paired")
    by_task = ThreadPoolExecutor(max_workers=TASK_WORKERS, thread_name_prefix="jaxeac-task-stats")
    aggregate_result = None

    def one_task(i: int, task):
        """Task i's algorithm entries, rows (paired rows as futures), draws for the aggregate and paths."""
        if ready is not None:
            ready(task)
        tkey = jax.random.fold_in(root, i)
        shared, order = shared_draw(per, task, used, paired, jax.random.fold_in(tkey, PAIRED_STREAM), resamples,
                                     chunk)
        # the paired rows first: their host draws run on `beside` while this thread makes the groups
        diffs, pkey = {}, jax.random.fold_in(tkey, PAIRED_STREAM + 1)  # every paired row's key
        for x, y in family:
            if order is not None and x in order and y in order:
                diffs[x, y] = order[x] - order[y]
            elif paired == "paired":
                raise UsageError(
                    f"--paired needs the same seed ids of {excerpt(x, 20)} and {excerpt(y, 20)}"
                    f"{' on task ' + excerpt(task, 20) if task else ''}; drop --paired to compare "
                    "them unpaired"
                )
        by_pair = {}
        for p, d in diffs.items():
            path = resampling_path(d.size, np.unique(d).size, paired=True)
            units = shared.units() if shared is not None and path == RAW else None
            by_pair[p] = beside.submit(paired_row, d, alpha, pkey, resamples, path=path, per_seed=units)
        groups = task_groups({a: per.values[task][a] for a in per.algos},
                             {a: jax.random.fold_in(tkey, j) for j, a in enumerate(per.algos)}, resamples, chunk)
        entries, rows, drawn, paths = [], [], None, {}
        for a in per.algos:
            g = groups[a]
            paths[g.path] = paths.get(g.path, 0) + 1
            est, lo, hi = g.iqm(alpha)
            entries.append({"task": task, "algo": a, "n": g.n, "mean": g.mean, "iqm": est, "iqm_ci": [lo, hi],
                            "excluded": per.excluded.get(task, {}).get(a, 0)})
        if aggregating:
            drawn = aggregate_draws(per, task, tkey, groups, shared, order, resamples, chunk, keep)
        for x, y in family:
            rows.append({"task": task, "x": x, "y": y, **pair_row(groups[x], groups[y], alpha),
                         "paired": by_pair.get((x, y))})
        return entries, rows, drawn, paths

    try:
        for entries, task_rows, task_drawn, task_paths in by_task.map(one_task, *zip(*enumerate(per.tasks))):
            algos += entries
            rows += task_rows
            if aggregating:
                drawn.append(task_drawn)
            for k, v in task_paths.items():
                paths[k] = paths.get(k, 0) + v
        if aggregating:
            from jaxeac.stats.tasks import aggregate_across_tasks

            aggregate_result = aggregate_across_tasks(
                per,
                family,
                normalize=normalize,
                drawn=drawn,
                reference=reference_scores,
                baseline=baseline,
                level=level,
                points=profile_points,
            )
        for row in rows:  # the paired rows, drawn on host threads beside the groups and the aggregate
            row["paired"] = row["paired"].result() if row["paired"] is not None else None
            row["analysis"] = "paired" if row["paired"] else "unpaired"
            row["p"] = row["paired"]["p_paired_t"] if row["paired"] else row["p_welch"]
    finally:
        by_task.shutdown(cancel_futures=True)
        beside.shutdown(cancel_futures=True)
    for r, p, pw in zip(
        rows, cf.holm([r["p"] for r in rows]), cf.holm([r["p_welch"] for r in rows]), strict=True
    ):
        r["p_holm"], r["p_welch_holm"] = float(p), float(pw)
    family_text = (
        "all pairs"
        if baseline is None
        else f"{treatment} vs {baseline}"
        if treatment is not None
        else f"all vs baseline {baseline}"
    )
    return Comparison(
        level=level,
        family=family_text,
        family_size=len(rows),
        resamples=resamples,
        key=key if isinstance(key, int) else None,
        source={
            "source": per.source,
            "format": per.format,
            "per_seed_value": per.what,
            "aggregate": aggregate if "trials" in per.what else None,
            "excluded": per.excluded,
            "excluded_total": sum(sum(v.values()) for v in per.excluded.values()),
            "failed_seed_rule": "a seed with a missing or NaN value (with trials: any trial) is failed: "
            "excluded, and counted here",
        },
        tasks=per.tasks,
        algorithms=algos,
        rows=rows,
        aggregate=aggregate_result,
        resampling={"rule": PATH_RULE, "groups": paths},
    )
