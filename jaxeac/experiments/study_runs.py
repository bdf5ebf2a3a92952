"""How a study's tasks run: side by side on accelerators, each into its folder under ``tasks/``, with
E8's diagnostics beside the runs (on GPUs in a helper process, `jaxeac.running.helper`).

`jaxeac.experiments.study.run_study` starts the tasks (`start_tasks`), takes each as its runs end
(`as_they_end`) and finishes with the runner (`TaskRunner`): one task's host work (dispatch,
copies, its folder) overlaps another's device runs, and a task's folder is finished (summary.json
with E8's counts, then moved in place) while later tasks run. The `Timeline` records where a
study's time went, per task and phase. Over 400 lines: a task's run, its E8 job in the helper and
its folder's finish share one lifecycle (started, failed or ended together), kept in one place.
"""

from __future__ import annotations

import dataclasses
import functools
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor, as_completed
from contextlib import contextmanager, suppress
from pathlib import Path

import numpy as np

from jaxeac.running.helper import Helper, HelperError


class Timeline:
    """Wall seconds of a study's phases (study.json's ``timeline``): per task its run (compile, device
    run and E8 diagnostics inside, from the run folder's summary), loading and curves; then the
    study's own: ``statistics`` (the wait, once the last task is in, for the tasks' statistics still
    running, the aggregate and Holm), the wait for E8 (and for its helper process to end), tuning,
    the figure (its panels as tasks end and its PNG beside the statistics, summed) and the wait for
    its PNG; ``helper_peak_rss_gib``: the E8 helper's peak memory, where there was one."""

    def __init__(self) -> None:
        self.t0 = time.perf_counter()
        self.tasks: dict[str, dict[str, float]] = {}
        self.study: dict[str, float] = {}
        self.values: dict[str, float] = {}  # other measures (the E8 helper's peak memory)

    @contextmanager
    def phase(self, name: str, task: str | None = None):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            where = self.study if task is None else self.tasks.setdefault(task, {})
            where[name] = where.get(name, 0.0) + time.perf_counter() - t0

    def note(self, task: str, **seconds: float) -> None:
        self.tasks.setdefault(task, {}).update(seconds)

    def record(self) -> dict:
        total = time.perf_counter() - self.t0
        r = {k: round(v, 3) for k, v in self.study.items()}
        per = {t: {k: round(v, 3) for k, v in p.items()} for t, p in self.tasks.items()}
        sums = {}
        for p in per.values():
            for k, v in p.items():
                sums[k] = round(sums.get(k, 0.0) + v, 3)
        return {"total_s": round(total, 3), "tasks_summed": sums, "study": r, "tasks": per, **self.values}


def folder_name(task: str) -> str:
    """A task's folder under ``tasks/``: its name, ``:slip=P`` as ``-slipP``."""
    return task.replace(":slip=", "-slip")


def task_folder(out: Path, task: str) -> Path:
    """`task`'s run folder in the study folder `out`."""
    return out / "tasks" / folder_name(task)


#: A study's task folders hold per-trial steps, policies and per_seed.csv up to this many seeds; beyond,
#: the per-seed measures (taken on the device) and success curves, as a grid run's above
#: `jaxeac.results.FULL_OUTPUT_SEEDS`: 11 tasks x 8 algorithms of whole trial logs, 4 tasks at a time.
STUDY_FULL_OUTPUT_SEEDS = 10_000


#: Per platform, how many of the study's tasks run side by side (threads, each taking every k-th
#: task in turn), so that one task's host work (dispatch, copies, its folder) overlaps another's
#: device runs and a tuning's runs start with the study's; 4, as many as the chance-budget groups
#: that ran side by side before C was data. Not on CPUs: there compiles and runs share the cores.
TASKS_SIDE_BY_SIDE = {"gpu": 4, "tpu": 4}


def side_by_side(todo: dict) -> bool:
    import jax

    return bool(todo) and TASKS_SIDE_BY_SIDE.get(jax.default_backend(), 0) > 1


def as_they_end(order: list[str], ahead: dict):
    """The tasks of `order`: first those not run side by side (loaded, or run in the study's loop,
    in order), then those of `ahead` (`start_tasks`) as their runs end."""
    yield from (task for task in order if task not in ahead)
    by_future = {ahead[task]: task for task in order if task in ahead}
    for done in as_completed(by_future):
        yield by_future[done]


def start_tasks(runner: TaskRunner, todo: dict, out: Path, side: bool, progress: bool) -> dict:
    """Where tasks go side by side (`TASKS_SIDE_BY_SIDE`): {task: future of its run's results}, the
    tasks dealt in order to that many threads, each running its own in turn; else {} (run in the
    loop). Tasks of one program layout on different threads share its programs (the first compiles)."""
    if not side:
        return {}
    import jax

    width = TASKS_SIDE_BY_SIDE[jax.default_backend()]
    order = list(todo)
    lanes = [order[i::width] for i in range(min(width, len(order)))]
    ahead: dict = {}

    def lane(tasks: list) -> None:
        for task in tasks:
            done = ahead[task]
            try:
                done.set_result(runner.run(task, todo[task], task_folder(out, task), None))
                if progress:
                    print(f"study: {task}: runs done", file=sys.stderr, flush=True)
            except BaseException as e:  # noqa: BLE001 (the task's future carries it)
                done.set_exception(e)
                for later in tasks[tasks.index(task) + 1:]:
                    ahead[later].set_exception(e)  # not run: whichever the study reads first, the cause
                return

    for task in order:
        ahead[task] = Future()
    for tasks in lanes:
        threading.Thread(target=lane, args=(tasks,), daemon=True, name="jaxeac-study-tasks").start()
    return ahead


#: Per platform E8 runs on (`DIAGNOSE_ON`), tasks whose E8 diagnostics run at once beside the runs
#: (accelerators only). On the GPU, all 11 tasks' queued on 2 workers at the study's start slowed
#: the runs of one H200 (grid-paper-v0:slip=0.1 at 1,000 seeds: 17.8 s against 2.2 s): one at a
#: time, started with its task. On the host's CPU cores they queue with no run: several.
DIAGNOSTIC_WORKERS = {"cpu": 4}


#: Compiles of E8's programs at once, ahead of the runs (accelerators: `prepare_diagnostics_ahead`).
DIAGNOSTIC_COMPILERS = 8

#: Per default backend, the platform E8's seeds run on beside a study's runs: on GPUs the host's idle
#: CPU cores, where E8's latency-bound `trials` loops no longer queue with the runs' kernels
#: (`jaxeac study --seeds 1000`, one H200, first runs of two builds in one sitting: 101.3 -> 64.0 s;
#: the same counts, R2).
DIAGNOSE_ON = {"gpu": "cpu"}

#: Per default backend, whether E8 beside the runs goes to a helper process on the host's CPU
#: (`jaxeac.running.helper`), so that its compiles and runs neither hold this process's interpreter
#: lock nor take the cores its compiles need first (`jaxeac study --seeds 1000`, one H100: 28.5-29.6
#: -> 20.7-20.8 s, with the tasks taken as they end).
DIAGNOSE_IN_HELPER = {"gpu": True}
#: Jobs the E8 helper runs at once (compiles ahead, then tasks): each compile at once adds about
#: 75 MiB to its peak memory (the default study's 5 programs on a 2-core CPU: 527 MiB on 2 threads,
#: 977 MiB on 8, the compiles 5.1 against 6.1 s).
HELPER_THREADS = 3


@dataclasses.dataclass(frozen=True)
class DiagnosticsHelper:
    """E8's helper process (`diagnostics_helper`) and the E8 jobs already sent to it: task -> a future
    of `jaxeac.experiments.grid.diagnose_grid`'s counts. A `TaskRunner` given it adopts both."""

    process: Helper
    jobs: dict[str, Future]

    def kill(self) -> None:
        self.process.kill()


def diagnostics_helper(todo: dict | None = None) -> DiagnosticsHelper | None:
    """Where a study's E8 goes to a helper process (`DIAGNOSE_IN_HELPER`), that helper, started now;
    else None. With `todo` ({task: its settings, as `TaskRunner` takes them}) every task's E8 goes to
    it at once: the programs' compiles (`prepare_diagnostics_ahead`), then each task's seeds. They need
    nothing from the task's run (the same keys, the same runs: R1, R2), so E8 starts with the command
    instead of with each task's run. `jaxeac study` starts it before its checks: its start (a Python
    with JAX and jaxeac) and E8's compiles overlap them instead of the runs' first seconds."""
    import jax

    from jaxeac.experiments.grid import DIAGNOSE_BESIDE_THE_RUN
    from jaxeac.experiments.study_figure import FIGURE_LANE
    from jaxeac.running.helper import Helper

    backend = jax.default_backend()
    if not (DIAGNOSE_BESIDE_THE_RUN.get(backend, False) and DIAGNOSE_IN_HELPER.get(backend, False)):
        return None
    try:
        helper = Helper(threads=HELPER_THREADS, lanes={FIGURE_LANE: 1})  # the study's figure apart from E8
    except OSError:  # no process could start: E8 runs on this process's threads
        return None
    return DiagnosticsHelper(helper, send_diagnostics(helper, todo or {}))


def send_diagnostics(helper: Helper, todo: dict) -> dict[str, Future]:
    """Every task's E8 to `helper` ({task: its settings}): the programs' compiles
    (`prepare_diagnostics_ahead`), then each task's seeds; {task: a future of its counts}. A helper
    that has ended takes no more (those tasks' E8 is counted in the study's process)."""
    from jaxeac.experiments.grid import diagnose_grid, diagnostic_seeds

    jobs: dict[str, Future] = {}
    with suppress(HelperError):
        prepare_diagnostics_ahead(todo, diagnostic_seeds, helper.submit)
        for task, grid in todo.items():
            if (seeds := diagnostic_seeds(grid)):
                jobs[task] = helper.submit(diagnose_grid, grid, grid.grid_map(), seeds)
    return jobs


def prepare_diagnostics_ahead(todo: dict, diagnostic_seeds, submit: Callable) -> None:
    """Start compiling every program the tasks' E8 diagnostics will run (one per algorithm with
    memories and layout), several at once (`submit(fn, *args, **kwargs)`: a pool's or a helper's), so
    that each task's diagnostics find theirs compiled instead of compiling group after group. Jobs of
    one layout, algorithm, seed count and best-action input go once; the rest that share a program
    wait for its compile (`_EXECUTABLES`)."""
    from jaxeac.envs.grid import shortest_actions
    from jaxeac.running.diagnostics import prepare_diagnostics
    from jaxeac.running.loops import program_key

    jobs: dict = {}
    for grid in todo.values():
        env, grid_map = grid.make_env(), grid.grid_map()
        best = shortest_actions(grid_map) if grid_map is not None else None
        for algo, seeds in diagnostic_seeds(grid).items():
            key = (program_key(env), algo, seeds.size, best is not None)
            jobs.setdefault(key, (env, grid.run_config(algo), seeds.size, best))
    for env, cfg, n, best in jobs.values():
        submit(prepare_diagnostics, env, cfg, n_seeds=n, best=best)


class TaskRunner:
    """Runs a study's tasks into their folders. Where E8's diagnostics go beside the run
    (`jaxeac.experiments.grid.DIAGNOSE_BESIDE_THE_RUN`: accelerators), a task's start with its run
    (queued behind the earlier tasks'), and its folder is finished (summary.json, then moved in
    place) by a finisher thread when they are in, so that the next task's run need not wait for
    them; elsewhere (CPUs: the run has every core) each folder is finished after its run. `helper`:
    E8's helper process with the jobs sent to it, started earlier (`diagnostics_helper`), which the
    runner then owns (with a job there for each task to run: `send_diagnostics`)."""

    def __init__(self, todo: dict, tl: Timeline, helper: DiagnosticsHelper | None = None) -> None:
        import jax

        from jaxeac.experiments.grid import DIAGNOSE_BESIDE_THE_RUN, diagnostic_seeds

        self.tl, self.open, self.done, self.lock = tl, [], [], threading.Lock()
        backend = jax.default_backend()
        self.beside = bool(todo) and DIAGNOSE_BESIDE_THE_RUN.get(backend, False)
        self.diagnosed: dict = {}
        self._jobs: list[Future] = []  # every task's E8 job (`diagnosed` gives them up as folders end)
        self.pool = self.finisher = self.compiler = self._closer = None
        self.helper: Helper | None = helper.process if helper is not None else None  # ended on an error
        self._seeds = diagnostic_seeds
        if not self.beside:
            if helper is not None:  # nothing to diagnose (every task done earlier)
                helper.kill()
                self.helper = None
            return
        self.finisher = ThreadPoolExecutor(max_workers=1)
        try:
            self._start_diagnostics(todo, backend, helper)
        except BaseException as exc:  # nothing left running behind the error
            self.__exit__(type(exc), exc, exc.__traceback__)
            raise

    def _start_diagnostics(self, todo: dict, backend: str, helper: DiagnosticsHelper | None) -> None:
        from jaxeac.experiments.grid import diagnose_grid

        if helper is None and DIAGNOSE_IN_HELPER.get(backend, False):  # a process of its own (the CPU)
            helper = diagnostics_helper(todo)
        if helper is not None:  # its jobs adopted; a task without one gets it now
            self.helper = helper.process
            self.diagnosed = {task: job for task, job in helper.jobs.items() if task in todo}
            missing = {task: grid for task, grid in todo.items() if task not in self.diagnosed}
            self.diagnosed |= send_diagnostics(self.helper, missing)
            self._jobs = list(self.diagnosed.values())
            return
        platform = DIAGNOSE_ON.get(backend)
        self.pool = ThreadPoolExecutor(max_workers=DIAGNOSTIC_WORKERS.get(platform or backend, 1))
        self._diagnose = functools.partial(self.pool.submit, diagnose_grid, platform=platform)
        self.compiler = ThreadPoolExecutor(max_workers=DIAGNOSTIC_COMPILERS, thread_name_prefix="jaxeac-e8-compile")
        prepare_diagnostics_ahead(todo, self._seeds, functools.partial(self.compiler.submit, platform=platform))

    def __enter__(self) -> TaskRunner:
        return self

    def run(self, task: str, grid, folder: Path, progress) -> dict:
        """Run `task` into `folder` (finished now or later); its `CompactSeeds` per algorithm."""
        from jaxeac.experiments.grid import GridRun
        from jaxeac.io import RUN_FOLDER_FILES, staged_dir
        from jaxeac.results import RESULTS_FILE, OutputOptions, ResultsWriter
        from jaxeac.running.batch import run_algorithms
        from jaxeac.running.outputs import CompactCollector

        options = OutputOptions.auto(grid.seeds, full=grid.seeds <= STUDY_FULL_OUTPUT_SEEDS,
                                     csv=grid.seeds <= STUDY_FULL_OUTPUT_SEEDS)
        env, seeds = grid.make_env(), np.arange(grid.seeds, dtype=np.int64)
        if self.pool is not None and (diagnosed := self._seeds(grid)):  # queued: one task's at a time
            self.diagnosed[task] = self._diagnose(grid, grid.grid_map(), diagnosed)
            self._jobs.append(self.diagnosed[task])
        stage_cm = staged_dir(folder, replaces=RUN_FOLDER_FILES)
        stage = stage_cm.__enter__()
        self.open.append(stage_cm)
        t0 = time.perf_counter()
        try:
            with ResultsWriter(stage / RESULTS_FILE, grid.trials, env.n_states, options) as writer:
                collectors = [CompactCollector(seeds, grid.trials, env.n_states, n_chances=env.n_chances,
                                               on_chunk=writer.chunk_writer(a, seeds),
                                               whole_chunks=options.trial_steps or options.policies)
                              for a in grid.algos]  # compact outputs: measures, not logs, come back
                runs = run_algorithms(env, [grid.run_config(a) for a in grid.algos], root_key=grid.key,
                                      n_seeds=grid.seeds, chunk_size=grid.chunk_size, progress=progress,
                                      collectors=collectors)
        except BaseException as exc:
            self._close(stage_cm, exc)
            raise
        run = GridRun(grid, grid.grid_map(), dict(zip(grid.algos, runs, strict=True)))
        self.tl.note(task, run=time.perf_counter() - t0, compile=sum(r.compile_seconds for r in runs),
                     device_run=sum(r.run_seconds for r in runs))
        if self.beside:
            self.done.append(self.finisher.submit(self._finish, task, run, stage, stage_cm, options))
        else:
            with self.tl.phase("finish", task):
                self._finish(task, run, stage, stage_cm, options)
        return run.results

    def _finish(self, task: str, run, stage: Path, stage_cm, options) -> None:
        """The folder's summary.json (with E8's diagnostics), then the folder moved in place."""
        from jaxeac.experiments.grid import memory_diagnostics, per_seed_csv, summarize
        from jaxeac.io import atomic_write_json

        try:
            summary = summarize(run)
            summary["outputs"] = dataclasses.asdict(options)
            diagnosed = None
            if task in self.diagnosed:
                try:
                    diagnosed = self.diagnosed.pop(task).result()
                except HelperError as exc:  # the helper process ended: E8 counted here instead (R2)
                    print(f"study: {task}: {exc}; counting its E8 diagnostics in this process", file=sys.stderr,
                          flush=True)
            summary |= memory_diagnostics(run, diagnosed=diagnosed)
            if options.per_seed_csv:
                (stage / "per_seed.csv").write_text(per_seed_csv(run))
            atomic_write_json(stage / "summary.json", summary)
        except BaseException as exc:
            self._close(stage_cm, exc)
            raise
        self._close(stage_cm, None)
        self.tl.note(task, diagnostics=summary.get("diagnostics_seconds", 0.0))

    def _close(self, stage_cm, exc: BaseException | None) -> None:
        """Move a finished stage in place (`exc` None) or drop it; once, whichever thread comes first."""
        with self.lock:
            if stage_cm not in self.open:
                return
            self.open.remove(stage_cm)
            info = (type(exc), exc, exc.__traceback__) if exc is not None else (None, None, None)
            stage_cm.__exit__(*info)

    def release_helper(self, *waits: Future) -> None:
        """End the helper, on a thread, once `waits` (the figure's PNG) and every task's E8 job are
        done: called when no more jobs will go to it, so that the statistics still running do not
        share the host's memory with an idle helper (a 100,000-seed study ended at 2.41 GiB in its
        own process plus 0.82 GiB in the helper)."""
        if self.helper is None:
            return
        pending = [*waits, *self._jobs]

        def close() -> None:
            for job in pending:
                with suppress(BaseException):  # failures are the study's to report, where it reads them
                    job.result()
            self.helper.close()

        self._closer = threading.Thread(target=close, daemon=True, name="jaxeac-helper-close")
        self._closer.start()

    def finish(self) -> None:
        """Wait for every folder to be finished (re-raising the first failure)."""
        for f in self.done:
            f.result()

    def __exit__(self, *exc) -> None:
        for pool in (self.pool, self.finisher, self.compiler):
            if pool is not None:
                pool.shutdown(wait=exc[0] is None, cancel_futures=exc[0] is not None)
        if self.helper is not None:
            with self.tl.phase("helper_close"):
                if exc[0] is not None:
                    self.helper.kill()
                if self._closer is not None:
                    self._closer.join()
                self.helper.close()
            if (peak := self.helper.peak_rss_bytes) is not None:
                self.tl.values["helper_peak_rss_gib"] = round(peak / 2**30, 3)
        for stage_cm in list(self.open):  # a failure midway: unfinished folders are left as they were
            try:
                self._close(stage_cm, RuntimeError("study stopped"))
            except RuntimeError:
                pass
