"""`compare_run_dir`: the whole AC-versus-EAC comparison of a run directory (SPEC §6).

Writes `stats.json`, `report.md` and the figures together (or none of them)
through `jaxeac.io.staged_dir`.
"""

from __future__ import annotations

import functools
import json
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import jax
import numpy as np

from jaxeac.bits import SuccessBits, as_bool
from jaxeac.errors import UsageError
from jaxeac.io import staged_dir, to_jsonable
from jaxeac.rng import as_key
from jaxeac.rundir import RunData, load_run_dir, read_summary
from jaxeac.runtime import start_device, trim_host_memory, versions
from jaxeac.stats import closed_form as cf
from jaxeac.stats import events as ev
from jaxeac.stats import large
from jaxeac.stats._rng import key_record
from jaxeac.stats.calibration import calibrate, dispatch_calibration
from jaxeac.stats.compare import _analyse
from jaxeac.stats.device_sums import curve_moments
from jaxeac.stats.family import run_family, settings_text, subject
from jaxeac.stats.measures import (
    MEASURES,
    as_values,
    check_measure,
    describe,
    event_counts,
    last_trial,
    per_seed_codes,
    per_seed_measures,
    value_counts,
)
from jaxeac.stats.paired import DESIGN as PAIRED_DESIGN
from jaxeac.stats.paired import paired_analysis
from jaxeac.stats.report import FIGURES, output_suffix, progress_bar, render_markdown

SCHEMA = "jaxeac.stats/1"
#: Random halves of the baseline's seeds in the calibration (each test's false-positive rate).
CALIBRATION_SPLITS = 200
#: fold_in index of the paired analysis under the comparison's key (its own stream: the
#: unpaired results stay as they were).
PAIRED_STREAM = 2_000_000
DECLARED_TESTS = {"first_success": "log-rank"}  # every other measure: Welch
#: What stats.json states the versions of (`jaxeac.runtime.versions`).
STATS_PACKAGES = ("jaxeac", "jax", "jaxlib", "numpy", "scipy")


def _beside(*calls) -> list[Future]:
    """Futures of `calls` (functions of no argument), run one after another on a thread of their
    own beside the caller (NumPy frees the interpreter's lock); the thread ends with the last."""
    pool = ThreadPoolExecutor(max_workers=1)
    futures = [pool.submit(call) for call in calls]
    pool.shutdown(wait=False)
    return futures


def _check_settings(resamples, alpha, calibration_splits, calibration_resamples):
    if not isinstance(resamples, int | np.integer) or resamples < 100:
        raise UsageError(f"--resamples {resamples} is too small; use at least 100 (10000 recommended)")
    if not 0 < alpha < 0.5:
        raise UsageError(f"--alpha {alpha} must be between 0 and 0.5, e.g. 0.05")
    if calibration_splits < 0 or calibration_resamples < 1:
        raise UsageError("calibration splits must be >= 0 and calibration resamples >= 1")


def compare_experiment(
    success_baseline,
    success_treatment,
    *,
    returns_baseline=None,
    returns_treatment=None,
    baseline: str = "ac",
    treatment: str = "eac",
    experiment: str = "grid",
    resamples: int = 10_000,
    alpha: float = 0.05,
    key=0,
    calibration_splits: int = CALIBRATION_SPLITS,
    calibration_resamples: int = 200,
    chunk: int = 1000,
    perm_chunk: int = 1000,
    paired: bool = False,
    on_counts: Callable[[dict, dict], None] | None = None,
) -> tuple[dict, dict]:
    """All statistics from per-trial arrays [seeds, T]; returns (stats dict, data for the figures).

    `paired`: row i of both arrays is the same seed (a jaxeac run: shared keys, R1); the
    paired analysis of every measure (`jaxeac.stats.paired`) is then added and leads the report.
    `on_counts(sides, data)`: called with ``{"baseline": …, "treatment": …}`` and the figures' data
    once the per-seed measures are known (the distributions figure needs no more)."""
    t0 = time.perf_counter()
    _check_settings(resamples, alpha, calibration_splits, calibration_resamples)
    sb, st = (a if isinstance(a, SuccessBits) else np.asarray(a)
              for a in (success_baseline, success_treatment))
    if len(sb.shape) != 2 or len(st.shape) != 2 or sb.shape[1] != st.shape[1]:
        raise UsageError(
            f"success arrays must be [seeds, trials] with the same trials, got {sb.shape} and {st.shape}"
        )
    if not large.is_large(sb.shape[0], st.shape[0]):  # seed resampling works on bools
        sb, st = as_bool(sb), as_bool(st)
    T = sb.shape[1]
    bowling = returns_baseline is not None
    t_measures = time.perf_counter()
    # large: the measures as integer codes, each analysis making its float64 copies in turn
    measures = per_seed_codes if large.is_large(sb.shape[0], st.shape[0]) else per_seed_measures
    mb = measures(sb, returns_baseline)
    mt = measures(st, returns_treatment)
    t_measures = time.perf_counter() - t_measures
    names = [k for k in mb if not k.startswith("_")]
    vb = {k: mb[k] for k in names}
    vt = {k: mt[k] for k in names}
    for name, v in (*vb.items(), *vt.items()):
        check_measure(v, name)
    plot = {"measures": {k: {"baseline": value_counts(vb[k]), "treatment": value_counts(vt[k])}
                         for k in names}}
    if on_counts is not None:
        on_counts({"baseline": baseline, "treatment": treatment}, plot)
    curves = (np.asarray(returns_baseline), np.asarray(returns_treatment)) if bowling else (sb, st)
    k_main, k_cal = jax.random.split(as_key(key))
    # start the calibration draws now so they overlap the main comparison's host work
    cal_labels = (
        dispatch_calibration(k_cal, sb.shape[0], calibration_splits, calibration_resamples)
        if calibration_splits > 0
        else None
    )
    if paired:  # on a host thread beside the rest (NumPy frees the GIL); its own key stream
        if sb.shape[0] != st.shape[0]:
            raise UsageError(f"a paired comparison needs the same seeds of both methods, got {sb.shape[0]} "
                             f"and {st.shape[0]}; compare them unpaired (--unpaired)")
        k_pair = jax.random.fold_in(as_key(key), PAIRED_STREAM)
        pair_keys = [jax.random.fold_in(k_pair, j) for j in range(len(names))]
        def pair(j: int, k: str) -> dict:  # within the host budget, as the unpaired measures are
            with large.HOST_BUDGET.hold(large.job_bytes(vb[k].size, vt[k].size)):
                return paired_analysis(as_values(vb[k]), as_values(vt[k]), pair_keys[j], resamples=resamples,
                                       alpha=alpha)

        paired_jobs = _beside(*(functools.partial(pair, j, k) for j, k in enumerate(names)))
    hib = {k: MEASURES[k][0] for k in names}
    # above large.LARGE_N the curves' sums start on the device now, for the analysis and the calibration
    moments = [curve_moments(c) for c in curves] if large.is_large(sb.shape[0], st.shape[0]) else None
    calibration = None
    if calibration_splits > 0:  # on a host thread beside the analysis: its own keys, the same results
        def calibration_job():
            t = time.perf_counter()
            cal = calibrate(
                vb,
                curves[0] if bowling or large.is_large(sb.shape[0]) else as_bool(curves[0]),
                k_cal,
                splits=calibration_splits,
                resamples=calibration_resamples,
                alpha=alpha,
                time_event=(mb["_time"], mb["_event"]),
                labels=cal_labels,
                moments=None if moments is None else moments[0],
            )
            return cal, time.perf_counter() - t

        (calibration,) = _beside(calibration_job)
    res = _analyse(
        vb,
        vt,
        k_main,
        curves=curves,
        resamples=resamples,
        alpha=alpha,
        chunk=chunk,
        perm_chunk=perm_chunk,
        higher_is_better=hib,
        moments=moments,
    )
    measures = res["measures"]
    for k in names:
        measures[k]["description"] = describe(k, T)
    t_lr = time.perf_counter()
    lr = ev.logrank_tables(event_counts(mb["_time"], mb["_event"]), event_counts(mt["_time"], mt["_event"]))
    measures["first_success"]["logrank"] = {"chi2": lr.statistic, "p": lr.pvalue}
    tests = {k: DECLARED_TESTS.get(k, "Welch t") for k in names}
    p_raw = [lr.pvalue if tests[k] == "log-rank" else measures[k]["p_welch"] for k in names]
    p_adj = cf.holm(p_raw)
    p_perm_adj = cf.holm([measures[k]["p_permutation"] for k in names])
    for k, pa, pp in zip(names, p_adj, p_perm_adj, strict=True):
        measures[k]["p_holm"] = float(pa)
        measures[k]["p_permutation_holm"] = float(pp)
    proportions = {name: ev.proportions(ob, ot, alpha) for name, ob, ot in (
        ("any_success", mb["_event"], mt["_event"]),
        ("final_trial_success", last_trial(sb), last_trial(st)),
    )}
    t_lr = time.perf_counter() - t_lr
    t_cal_wait = time.perf_counter()
    cal, t_cal = (calibration.result() if calibration is not None
                  else ({"skipped": "calibration_splits = 0"}, 0.0))
    t_cal_wait = time.perf_counter() - t_cal_wait
    primary = names[0]
    stats = {
        "schema": SCHEMA,
        "experiment": experiment,
        "baseline": baseline,
        "treatment": treatment,
        "trials": T,
        "primary": measures[primary],
        "secondary": {k: measures[k] for k in names[1:]},
        "holm": {
            "family": names,
            "tests": tests,
            "p_raw": dict(zip(names, p_raw, strict=True)),
            "p_adjusted": dict(zip(names, p_adj.tolist(), strict=True)),
            "method": "Holm (1979) step-down, family-wise error rate",
        },
        "logrank": {
            "chi2": lr.statistic,
            "p": lr.pvalue,
            "measure": "first_success",
            "censoring": f"no success within {T} trials",
        },
        "proportions": proportions,
        "curves": res["curves"],
        "calibration": cal,
        "settings": {
            "key": key if isinstance(key, int) else None,
            "key_record": key_record(key),
            "key_derivation": "main, calibration = split(key); bootstrap baseline, bootstrap treatment, "
            "permutation = split(main); chunk c uses fold_in(subkey, c); calibration splits and "
            "reference relabellings are the first and remaining columns of one subset draw under the "
            "calibration key",
            "resamples": resamples,
            "permutations": resamples,
            "alpha": alpha,
            "chunk": chunk,
            "permutation_chunk": perm_chunk,
            "calibration_splits": calibration_splits,
            "calibration_resamples": calibration_resamples,
            "bootstrap": "BCa (Efron 1987), methods resampled independently",
            "scale": large.path_record(res, sb.shape[0], st.shape[0], calibration_splits),
        },
        "versions": versions(STATS_PACKAGES, optional=()),
        "timing": {
            "resample_seconds": res["resample_seconds"],
            "calibration_seconds": t_cal,
            "pieces": {
                "per_seed_measures": t_measures,
                **res.get("pieces", {}),
                "logrank_and_proportions": t_lr,
                "calibration": t_cal,
                "calibration_wait": t_cal_wait,
            },
        },
    }
    if paired:
        t_wait = time.perf_counter()
        stats["analysis"] = "paired"
        stats["paired"] = {"design": PAIRED_DESIGN,
                           "measures": {k: job.result() for k, job in zip(names, paired_jobs, strict=True)}}
        stats["timing"]["pieces"]["paired_wait"] = time.perf_counter() - t_wait
    else:
        stats["analysis"] = "unpaired"
    stats["timing"]["statistics_seconds"] = time.perf_counter() - t0
    stats = {"schema": SCHEMA, "level": round(1 - alpha, 12), **cf.level_keys(stats, round(1 - alpha, 12))}
    return stats, plot


def _same_seeds(data: RunData, baseline: str, treatment: str) -> bool:
    """Whether row i of both methods is the same seed i (then their results share its key)."""
    nb, nt = len(data.success[baseline]), len(data.success[treatment])
    seeds = [data.per_seed.get(a, {}).get("seed") for a in (baseline, treatment)]
    if seeds[0] is not None and seeds[1] is not None:
        return bool(np.array_equal(seeds[0], seeds[1]))
    return nb == nt  # folders without seed ids (and runs in memory) hold seeds 0 … N − 1


def analyse_run_data(data: RunData, *, baseline: str = "ac", treatment: str = "eac", unpaired: bool = False,
                     require_paired: bool = False, **settings) -> tuple[dict, dict]:
    """The statistics of a run's results (`compare_experiment`, with its `settings`: resamples,
    alpha, key, calibration and chunks): (stats, figures' data), before the report is written
    (`compare_run_dir`). Checks that the results fit the comparison asked for; bad input raises
    `jaxeac.errors.UsageError`."""
    bowling = data.experiment == "bowling"
    expected = "return" if bowling else "successes"
    if data.primary_measure != expected:
        raise UsageError(
            f"summary.json primary_measure {data.primary_measure!r} does not fit a {data.experiment} run "
            f"(expected {expected!r}); fix summary.json or re-run the experiment"
        )
    paired = not unpaired and _same_seeds(data, baseline, treatment)
    if require_paired and not paired:
        nb, nt = len(data.success[baseline]), len(data.success[treatment])
        raise UsageError(f"--paired needs the same seeds of {baseline} and {treatment} (this run has "
                         f"{nb} and {nt}, or different seed ids); drop --paired to compare them unpaired")
    return compare_experiment(data.success[baseline], data.success[treatment],
                              returns_baseline=data.returns.get(baseline) if bowling else None,
                              returns_treatment=data.returns.get(treatment) if bowling else None,
                              baseline=baseline, treatment=treatment, experiment=data.experiment,
                              paired=paired, **settings)


def draw_comparison(stats: dict, plot: dict, folder: Path, files: dict[str, str],
                    only: tuple[str, ...] | None = None) -> None:
    """`jaxeac.plots.comparison_figures` (the figures' layer, imported only to draw them; a job a
    helper process can run); `only`: the figures to draw (None: all)."""
    from jaxeac.plots import comparison_figures

    comparison_figures(stats, plot, folder, files, only=only)


def comparison_png(name: str, stats: dict, plot: dict) -> bytes:
    """`jaxeac.plots.comparison_png`: one comparison figure as PNG bytes (a helper process's job)."""
    from jaxeac.plots import comparison_png as png

    return png(name, stats, plot)


def compare_run_dir(
    run_dir,
    *,
    baseline: str = "ac",
    treatment: str = "eac",
    resamples: int = 10_000,
    alpha: float = 0.05,
    key: int = 0,
    calibration_splits: int = CALIBRATION_SPLITS,
    calibration_resamples: int = 200,
    chunk: int = 1000,
    progress: bool = True,
    data: RunData | None = None,
    unpaired: bool = False,
    require_paired: bool = False,
    analysed: Future | None = None,
    draw: Callable | None = None,
) -> dict:
    """Compare two methods of a grid or bowling run directory; write stats.json, report.md, figures.

    `data`: the run's results already in memory (as `jaxeac grid` has them when it compares
    the run it just wrote), instead of reading them back; `analysed`: a future of
    `analyse_run_data`'s result for them with the same settings, started earlier (`jaxeac grid`
    starts it while the run's own figures are drawn); `draw(stats, plot, folder, files)`: draws the
    figures into the staging folder (default `draw_comparison`; `jaxeac grid` on a GPU: in a helper
    process). The comparison is paired when both methods ran the same seeds (a jaxeac run: seed i
    of each shares its key, R1), unless `unpaired`; `require_paired` makes other seeds an error.
    Returns the content of stats.json.
    Bad input raises `jaxeac.errors.UsageError`.
    """
    t0 = time.perf_counter()
    _check_settings(resamples, alpha, calibration_splits, calibration_resamples)
    settings = dict(baseline=baseline, treatment=treatment, resamples=resamples, alpha=alpha, key=key,
                    calibration_splits=calibration_splits, calibration_resamples=calibration_resamples,
                    chunk=chunk, unpaired=unpaired, require_paired=require_paired)
    t_load, bar = time.perf_counter(), None
    starter = start_device() if analysed is None else None  # a GPU's context starts while the host reads
    try:
        if data is None and analysed is None:
            data = load_run_dir(run_dir, baseline, treatment)
            trim_host_memory()  # what reading the file freed
        t_load = time.perf_counter() - t_load if analysed is None else 0.0
        bar = progress_bar(progress, baseline, treatment)
        stats, plot = analyse_run_data(data, **settings) if analysed is None else analysed.result()
    except BaseException:
        if bar is not None:
            bar.close()
        if starter is not None:
            starter.join()  # a damaged folder: let JAX finish starting before the command ends
        raise
    if bar is not None:
        bar.set_description(f"compare {treatment} vs {baseline}: report")
        bar.update()
    stats["run_dir"] = str(Path(run_dir))
    summary = read_summary(run_dir)  # the report names its subject and, with more algorithms, the family
    stats["subject"], stats["algos_run"] = subject(summary), summary.get("algos", [baseline, treatment])
    stats["run_settings"] = settings_text(summary)
    stats["family"] = run_family(run_dir, summary, baseline, stats["primary"]["measure"],
                                 level=stats["level"], resamples=resamples, key=key)
    if data is not None and data.sequential is not None:  # the run's sequential decision comes first
        stats["sequential"] = data.sequential
    suffix = output_suffix(run_dir, baseline, treatment)
    figures = {k: v.replace(".png", f"{suffix}.png") for k, v in FIGURES.items()}
    stats["files"] = {"stats": f"stats{suffix}.json", "report": f"report{suffix}.md", "figures": figures}
    stats["timing"]["load_seconds"] = t_load
    t_out = time.perf_counter()
    with staged_dir(run_dir) as stage:  # a second comparison's figures beside the first's
        (draw or draw_comparison)(stats, plot, stage, figures)
        stats["timing"]["figures_seconds"] = time.perf_counter() - t_out
        stats["timing"]["total_seconds"] = time.perf_counter() - t0
        clean = to_jsonable(stats)
        (stage / stats["files"]["report"]).write_text(render_markdown(clean), encoding="utf-8")
        (stage / stats["files"]["stats"]).write_text(json.dumps(clean, indent=2) + "\n", encoding="utf-8")
    if bar is not None:
        bar.update()
        bar.close()
    return clean


