"""A grid run from settings to a compared run folder: run → folder → statistics report.

`run_and_compare` runs every algorithm (or takes a merged run), writes the run folder
(results.parquet, summary.json, figures) and then compares AC with EAC from the results still
in memory (`jaxeac.stats.compare_run_dir`: stats.json, report.md and its figures). On
accelerators the comparison's programs compile while the run computes, its statistics are
computed on a thread as soon as the results are in, and (up to `STATISTICS_BESIDE_FIGURES_SEEDS`)
the run's and the report's figures are drawn in a helper process meanwhile (`FIGURES_IN_HELPER`),
each as soon as its data are known; the outputs are the same either way.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

#: Per JAX backend, whether the statistics are computed beside the run's own figures: on one
#: H100 a 10^6-seed run and report went from 17.9 to 16.2 s; on a 2-core CPU it gained nothing.
STATISTICS_BESIDE_FIGURES = {"gpu": True, "tpu": True}
#: Up to this many seeds per method: above it the overlap raised a 10^7-seed run's peak host
#: memory from 3.0-3.3 GiB to 3.8-4.2 GiB (the run's columns and the statistics' copies at once).
STATISTICS_BESIDE_FIGURES_SEEDS = 1 << 22
#: Per JAX backend, whether the figures (the run's and the report's) are drawn in a helper process
#: (`jaxeac.running.helper`) where the statistics run beside them, so that matplotlib never holds
#: this process's interpreter lock while they run: a 10^6-seed run and report on one H100, 1.07x
#: first runs and 1.03x warm, faster in each of 6 rounds (BENCHMARKS.md).
FIGURES_IN_HELPER = {"gpu": True, "tpu": True}


def run_and_compare(settings, out, *, options=None, compare: bool = True,
                    progress: Callable[[int], None] | None = None, quiet: bool = False, design=None,
                    on_look: Callable[[dict], None] | None = None, run=None,
                    on_folder: Callable[[object, dict], None] | None = None, helper=None) -> tuple:
    """Run `settings` (a resolved `GridSettings`) into the folder `out`, then compare it.

    `options`: the folder's `OutputOptions`; `progress(n)`: seeds done; `design`: a
    `SequentialDesign` (batches of seeds until a look decides, `on_look(result)` after each);
    `run`: a `GridRun` already computed (`jaxeac merge`), only written and compared;
    `on_folder(run, summary)`: called once the folder is written, before the statistics start;
    `helper`: the figures' helper process, started earlier (`figure_helper`; the call then owns
    it), else one is started here where the figures go to one. The report is made when `compare`
    and the run has AC and EAC with two seeds or more (`quiet`: no progress bar). Returns (run,
    summary.json content, stats.json content or None).
    """
    if run is not None or design is not None:
        if helper is not None:
            helper.kill()
        return _run_and_compare(settings, out, options, compare, progress, quiet, design, on_look, run,
                                on_folder, None)
    helper = helper if helper is not None else figure_helper(settings, compare=compare)
    if helper is None:
        return _run_and_compare(settings, out, options, compare, progress, quiet, design, on_look, run,
                                on_folder, None)
    with helper:  # closed once its jobs are done; killed if the run fails
        return _run_and_compare(settings, out, options, compare, progress, quiet, design, on_look, run,
                                on_folder, helper)


def figure_helper(settings, *, compare: bool = True):
    """Where a grid run's figures go to a helper process (`FIGURES_IN_HELPER`: the statistics run
    beside them, AC and EAC compared), that helper, started now and loading matplotlib; else None.
    `jaxeac grid` starts it before its checks, so that it is ready when the results are in (a warm
    run's come about two seconds after its start)."""
    import jax

    if not (_compares(settings, compare=compare) and _statistics_beside_figures(settings.seeds)
            and FIGURES_IN_HELPER.get(jax.default_backend(), False)):
        return None
    from jaxeac.running.helper import Helper

    try:
        return Helper(threads=2, name="jaxeac-figures", preload=_load_plots)
    except OSError:  # no process could start: the figures are drawn here
        return None


def _run_and_compare(settings, out, options, compare, progress, quiet, design, on_look, run, on_folder,
                     helper) -> tuple:
    """`run_and_compare`, its figures drawn in `helper` (a `jaxeac.running.helper.Helper`, or None:
    drawn here)."""
    from jaxeac.experiments.grid import run_grid_sequential, run_grid_to_folder, write_grid_outputs

    analysed = ahead = None
    early: dict = {}
    if run is not None:
        summary = write_grid_outputs(run, out, options=options)
    elif design is not None:
        run, summary = run_grid_sequential(settings, out, design, options=options, on_look=on_look)
    else:
        ahead = _compile_statistics_ahead(settings, compare=compare)
        started: list[tuple] = []  # the statistics, started as soon as the results are in

        def start_statistics(run) -> None:
            if _compares(run.settings, compare=compare) and _statistics_beside_figures(settings.seeds):
                started.append(_start_statistics(run, out, ahead, helper))

        run, summary = run_grid_to_folder(settings, out, options=options, progress=progress,
                                          on_results=start_statistics, helper=helper)
        analysed, early = started[0] if started else (None, {})
    if on_folder is not None:
        on_folder(run, summary)
    if ahead is not None and analysed is None:
        ahead.join()  # the comparison's programs, in the cache before it starts
    stats = _compare(run, out, compare=compare, quiet=quiet,
                     sequential=summary["sequential"] if design is not None else None, analysed=analysed,
                     helper=helper, early=early)
    return run, summary, stats


def _load_plots() -> None:
    """A figure helper's preload: the modules of the jobs it will be sent (matplotlib, and the
    figure functions' own modules, which reading a job imports), loaded while it waits for the
    first: importing them then took 0.5 s of a warm 10^6-seed `jaxeac grid`."""
    import jaxeac.plots  # noqa: F401
    from jaxeac.experiments.grid import draw_grid_figures  # noqa: F401
    from jaxeac.stats.run import draw_comparison  # noqa: F401


def _compares(settings, *, compare: bool) -> bool:
    """Whether a grid run of `settings` is compared (AC and EAC, at least two seeds each)."""
    return compare and {"ac", "eac"} <= set(settings.algos) and settings.seeds >= 2


def _statistics_beside_figures(seeds: int) -> bool:
    """Whether a grid run of `seeds` seeds per method computes its statistics beside its figures."""
    import jax

    beside = STATISTICS_BESIDE_FIGURES.get(jax.default_backend(), False)
    return beside and seeds <= STATISTICS_BESIDE_FIGURES_SEEDS


def _grid_run_data(run, out, sequential: dict | None = None):
    """The comparison's view (`RunData`) of a grid run in memory: its success curves."""
    from jaxeac.rundir import RunData

    return RunData(Path(out), "grid", "successes", tuple(run.settings.algos), run.settings.trials,
                   {a: r.success for a, r in run.results.items()}, {}, {}, sequential)


def _start_statistics(run, out, ahead, helper=None) -> tuple[Future, dict]:
    """`analyse_run_data` of a grid run just finished, on a thread, while the run's own figures are
    drawn (in a helper process or on the main thread): a future of (stats, figures' data). It
    starts once the comparison's programs compiled ahead (`ahead`, a thread or None) are in the
    cache. With a `helper`, the report's distributions figure is drawn there as soon as the
    per-seed measures are known, while the statistics run (with Fig. 2 drawn as Fig. 3's lines are
    counted, the figures after the statistics of a warm 10^6-seed run on one H100: 0.54 -> 0.21 s):
    returned beside the future, {figure: a function waiting for its PNG bytes}, filled in by then."""
    from jaxeac.stats.run import analyse_run_data, comparison_png

    data = _grid_run_data(run, out)
    early: dict[str, Callable[[], bytes]] = {}

    def on_counts(sides: dict, plot: dict) -> None:
        from jaxeac.running.helper import in_helper

        early["distributions"] = in_helper(helper, comparison_png, "distributions", sides, plot)

    def work():
        if ahead is not None:
            ahead.join()
        return analyse_run_data(data, on_counts=None if helper is None else on_counts)

    pool = ThreadPoolExecutor(max_workers=1)
    future = pool.submit(work)
    pool.shutdown(wait=False)  # the thread ends with its job
    return future, early


def _compile_statistics_ahead(settings, *, compare: bool) -> threading.Thread | None:
    """On accelerators, compile the comparison's device programs on a thread while the run
    computes (`jaxeac.stats.large.compile_ahead`: they land in the compilation cache). On
    CPUs the run needs every core, so nothing is started. Returns the thread, or None."""
    import jax

    if not compare or jax.default_backend() == "cpu":
        return None
    from jaxeac.stats import large
    from jaxeac.stats.run import CALIBRATION_SPLITS

    def work() -> None:
        with contextlib.suppress(Exception):  # only a head start: the comparison compiles anyway
            large.compile_ahead(settings.seeds, settings.trials, splits=CALIBRATION_SPLITS)

    thread = threading.Thread(target=work, daemon=True)
    thread.start()
    return thread


def _compare(run, out, *, compare: bool, quiet: bool, sequential: dict | None = None,
             analysed: Future | None = None, helper=None, early: dict | None = None) -> dict | None:
    """The statistics report of a grid run just written, from its results in memory (`analysed`:
    its statistics, already started by `_start_statistics`; `early`: the figures it had drawn
    meanwhile, as PNG bytes). The folder is written, so all but the success curves are dropped
    from `run` first: the statistics get the memory of the other per-seed columns. Returns
    stats.json's content, or None when the run is not compared."""
    if not _compares(run.settings, compare=compare):
        return None
    from jaxeac.runtime import trim_host_memory
    from jaxeac.stats import compare_run_dir

    data = _grid_run_data(run, out, sequential)
    run.results = {}
    trim_host_memory()  # what the run and its figures freed, before the statistics start
    draw = None
    if helper is not None:
        from jaxeac.running.helper import in_helper
        from jaxeac.stats.run import draw_comparison

        def draw(stats: dict, plot: dict, folder: Path, files: dict[str, str]) -> None:
            drawn = early or {}
            rest = in_helper(helper, draw_comparison, stats, plot, folder, files,
                             tuple(name for name in files if name not in drawn))
            for name, png in drawn.items():
                (folder / files[name]).write_bytes(png())
            rest()
    return compare_run_dir(out, progress=not quiet, data=data, analysed=analysed, draw=draw)
