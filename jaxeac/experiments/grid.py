"""The grid-world experiment end to end: settings → runs of each algorithm → files on disk.

The same experiment runs any registered environment (``GridSettings.env``, X1: the classic
tabular tasks, a slippery grid) and the value-based baselines (X3); the paper's grid stays
the default.

`GridSettings` is what the CLI and notebooks fill in (validated up front, so bad
input fails before any compute); `run_grid` runs every algorithm over seeds
0..N−1 (SPEC R1) and `write_grid_outputs` writes the run folder atomically.
`run_grid_to_folder` does both at once, writing results.parquet a chunk at a time and
keeping only the per-seed measures and success bits (`CompactSeeds`) in memory: the
form that stays within a few GiB at 10^7 seeds.

(Over 400 lines: the grid experiment's settings, its runs, multi-process parts and their merge,
the summary and the folder.)
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import io
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import jax
import numpy as np

from jaxeac.algorithm.config import algorithm
from jaxeac.algorithm.memory import LAYOUTS
from jaxeac.envs import make as make_env
from jaxeac.envs import registered
from jaxeac.envs.grid import GridMap, GridWorld, get_map, load_map
from jaxeac.errors import UsageError
from jaxeac.experiments.common import (  # noqa: F401  (re-exported: imported from here by older code)
    check_algos,
    check_key,
    check_positive_int,
    check_rate,
    mean_ci95,
    summary_base,
    versions,
    welch_diff_ci95,
)
from jaxeac.experiments.presets import make as make_preset
from jaxeac.io import RUN_FOLDER_FILES, atomic_write_json, json_field, read_json_object, staged_dir
from jaxeac.results import (
    RESULTS_FILE,
    OutputOptions,
    ResultsWriter,
    load_grid_results,
    write_grid_results,
)
from jaxeac.running.batch import run_algorithms, run_seeds
from jaxeac.running.config import RunConfig
from jaxeac.running.outputs import ChunksBehind, CompactCollector, CompactSeeds, SeedsResult, as_bool
from jaxeac.runtime import trim_host_memory


@dataclasses.dataclass(frozen=True)
class GridSettings:
    """Everything that defines a grid run; `None` fields come from the preset."""

    preset: str = "paper"
    map_file: str | None = None
    trials: int | None = None
    chances: int | None = None
    alpha: float | None = None
    beta: float | None = None
    gamma: float | None = None
    temperature: float | None = None
    algos: tuple[str, ...] = ("ac", "eac")
    seeds: int = 1000
    key: int = 0
    chunk_size: int | None = None  # None: `auto_chunk_size` for the backend and devices
    memory: str = "dense"
    capacity: int = 1024
    env: str | None = None  # a registered environment (`jaxeac.registered()`); None: the preset's map or --map
    slip: float = 0.0  # X1: with this probability a move executes a uniformly random action
    epsilon: float = 0.1  # X3: exploration rate of q_learning and sarsa
    lanes: int | None = None  # seeds in flight per device (RunConfig.lanes); None: `default_lanes`

    def resolved(self) -> GridSettings:
        """Fill unset fields from the preset (chances of a registered environment: its own) and
        validate everything (raises `UsageError`)."""
        preset = make_preset(self.preset)
        fields = ("trials", "alpha", "beta", "gamma", "temperature") + (("chances",) if self.env is None else ())
        filled = dataclasses.replace(self, **{f: getattr(preset, f) for f in fields if getattr(self, f) is None})
        if filled.env is not None:
            if filled.map_file is not None:
                raise UsageError("--env and --map both name the world; give one of them")
            if filled.chances is None:
                filled = dataclasses.replace(filled, chances=make_env(filled.env).n_chances)
        filled.validate()
        return filled

    def validate(self) -> None:
        sizes = ("trials", "chances", "seeds", "capacity")
        sizes += ("chunk_size",) if self.chunk_size is not None else ()
        sizes += ("lanes",) if self.lanes is not None else ()
        for name in sizes:
            check_positive_int(name.replace("_", " "), getattr(self, name))
        check_rate("alpha", self.alpha)
        check_rate("beta", self.beta)
        check_rate("gamma", self.gamma, upper=1.0)
        check_rate("temperature", self.temperature, positive=True)
        check_key(self.key)
        check_algos(self.algos)
        check_rate("slip", self.slip, upper=1.0)
        check_rate("epsilon", self.epsilon, upper=1.0)
        if self.memory not in LAYOUTS:
            raise UsageError(f"unknown memory layout {self.memory!r}; choose one of {', '.join(LAYOUTS)}")
        if self.env is not None and self.env not in registered():
            raise UsageError(f"unknown environment {self.env!r}; choose one of {', '.join(registered())}")

    def grid_map(self) -> GridMap | None:
        """The map of a grid run (G1); None for a registered non-grid environment."""
        if self.env is not None:
            return getattr(make_env(self.env), "map", None)
        return load_map(self.map_file) if self.map_file else get_map(make_preset(self.preset).map)

    def make_env(self):
        """The environment of the run (`jaxeac.envs.protocol`): the grid world of the map (G1–G5),
        or the registered one, with `slip` (X1) and `chances`."""
        if self.env is not None:
            return make_env(self.env, chances=self.chances, slip=self.slip)
        from jaxeac.envs.tabular import grid_world

        return grid_world(self.grid_map(), self.chances, self.slip)

    def run_config(self, algo: str) -> RunConfig:
        agent = algorithm(algo, memory=self.memory, capacity=self.capacity)
        return RunConfig(
            trials=self.trials, agent=agent, alpha=self.alpha, beta=self.beta,
            gamma=self.gamma, temperature=self.temperature, epsilon=self.epsilon, lanes=self.lanes,
        )


@dataclasses.dataclass
class GridRun:
    """A finished grid experiment: settings, map (None: a non-grid environment) and per-algorithm
    results."""

    settings: GridSettings
    grid_map: GridMap | None
    results: dict[str, SeedsResult | CompactSeeds]


def process_share(n_seeds: int, index: int, count: int) -> tuple[int, int]:
    """(first seed, number of seeds) of process `index` of `count`: contiguous, near-equal blocks."""
    first = index * n_seeds // count
    return first, (index + 1) * n_seeds // count - first


def run_grid(settings: GridSettings, *, progress: Callable[[int], None] | None = None,
             first_seed: int = 0, n_seeds: int | None = None) -> GridRun:
    """Run every algorithm of `settings` (already `resolved()`) over seeds first_seed… (default all).

    Seed i is ``fold_in(root, i)`` whichever process or device runs it (R1), so the seeds of
    a run can be split over processes and merged afterwards (`merge_parts`).
    """
    env = settings.make_env()
    n = settings.seeds if n_seeds is None else n_seeds
    results = {
        algo: run_seeds(
            env, settings.run_config(algo), root_key=settings.key, n_seeds=n, first_seed=first_seed,
            chunk_size=settings.chunk_size, progress=progress,
        )
        for algo in settings.algos
    }
    return GridRun(settings, settings.grid_map(), results)


PART_PREFIX = "part-"


def part_folder(out: str | Path, index: int, count: int) -> Path:
    """Where process `index` of `count` writes its seeds."""
    return Path(out) / f"{PART_PREFIX}{index:04d}-of-{count:04d}"


def merge_parts(out: str | Path) -> GridRun:
    """Join the part folders of a multi-process run into one `GridRun` (seeds in order).

    Refuses missing parts, parts of different runs and overlapping or missing seeds.
    """
    out = Path(out)
    parts = sorted(out.glob(f"{PART_PREFIX}*-of-*"))
    if not parts:
        raise UsageError(f"{out} has no {PART_PREFIX}NNNN-of-NNNN folders; run `jaxeac grid --num-processes`")
    counts = {p.name.rsplit("-of-", 1)[1] for p in parts}
    if len(counts) != 1 or not next(iter(counts)).isdigit():
        raise UsageError(f"{out}: part folders of different or unreadable counts "
                         f"({', '.join(sorted(counts))}); remove the stray ones or rerun the processes")
    count = int(next(iter(counts)))
    expected = [part_folder(out, i, count).name for i in range(count)]
    missing = sorted(set(expected) - {p.name for p in parts})
    if missing or len(parts) != count:
        raise UsageError(f"{out}: parts missing or extra ({', '.join(missing) or 'mixed counts'}); "
                         "rerun the missing processes")
    fix = "rerun that process"
    summaries = [read_json_object(p / "summary.json", fix) for p in parts]
    configs = [json_field(s, "config", dict, p / "summary.json", fix)
               for s, p in zip(summaries, parts, strict=True)]
    config = configs[0]
    if any(c != config for c in configs):
        raise UsageError(f"{out}: the parts come from runs with different settings; rerun them together")
    fields = {f.name for f in dataclasses.fields(GridSettings)}
    if (config.get("env") is None and not isinstance(config.get("map"), str)) or not set(config) - {"map"} <= fields:
        raise UsageError(f"{parts[0] / 'summary.json'}: its config is not a grid run's; {fix}")
    try:
        settings = dataclasses.replace(GridSettings(), **{k: v for k, v in config.items() if k != "map"})
        settings = dataclasses.replace(settings, algos=tuple(settings.algos)).resolved()
    except (TypeError, UsageError) as exc:
        raise UsageError(f"{parts[0] / 'summary.json'}: its config does not describe a run ({exc}); "
                         f"{fix}") from None
    from jaxeac.envs.grid import parse_map

    grid_map = None
    if isinstance(config.get("map"), str):
        grid_map = parse_map(config["map"], source=f"{parts[0] / 'summary.json'}: the map of its config")
    env = settings.make_env() if grid_map is None else GridWorld(grid_map, settings.chances)
    n_states, n_actions = env.n_states, env.n_actions
    timings = []
    for s, p in zip(summaries, parts, strict=True):
        per_algo = s.get("per_algo", {})
        ok = isinstance(per_algo, dict) and all(
            isinstance(t, dict)
            and all(isinstance(t.get(k, 0.0), int | float) and not isinstance(t.get(k), bool)
                    for k in ("compile_seconds", "run_seconds"))
            for t in per_algo.values())
        if not ok:
            raise UsageError(f"{p / 'summary.json'}: its per_algo timings are damaged; {fix}")
        timings.append(per_algo)
    results = {}
    loaded = [load_grid_results(p, settings.algos, settings.trials) for p in parts]
    for algo in settings.algos:
        for part, p in zip(loaded, parts, strict=True):
            x = part[algo]
            if x.policy is not None and (x.policy.shape[1] != n_states or x.policy.size and (
                    x.policy.min() < 0 or x.policy.max() >= n_actions)):
                raise UsageError(f"{p / 'results.parquet'}: the policies of {algo} are not actions in the "
                                 f"world of its summary.json; {fix}")
            if x.trial_steps is not None and x.trial_steps.size and (
                    x.trial_steps.min() < 0 or x.trial_steps.max() > settings.chances):
                raise UsageError(f"{p / 'results.parquet'}: the per-trial steps of {algo} lie outside "
                                 f"0..{settings.chances} chances; {fix}")
        pieces = [(part[algo], per_algo.get(algo, {}))
                  for part, per_algo in zip(loaded, timings, strict=True)]
        if any(x.trial_steps is None or x.policy is None for x, _ in pieces):
            raise UsageError(f"{out}: a part holds no per-trial steps or policies; run the parts with "
                             "--full-outputs to merge them")
        seeds = np.concatenate([x.seeds for x, _ in pieces])
        if seeds.size != settings.seeds or not np.array_equal(seeds, np.arange(seeds.size)):
            raise UsageError(f"{out}: the parts' seeds do not cover 0..{settings.seeds - 1} exactly once")
        finite = (None if any(x.finite is None for x, _ in pieces)
                  else np.concatenate([x.finite for x, _ in pieces]))
        pieces = [(x.seeds, x.success, x.trial_steps, x.policy, s) for x, s in pieces]
        results[algo] = SeedsResult(
            seeds=seeds, success=np.concatenate([as_bool(x[1]) for x in pieces]),
            steps=np.concatenate([x[2] for x in pieces]).astype(np.int32),
            policy=np.concatenate([x[3] for x in pieces]).astype(np.int32),
            compile_seconds=max(float(x[4].get("compile_seconds", 0.0)) for x in pieces),
            run_seconds=max(float(x[4].get("run_seconds", 0.0)) for x in pieces),  # processes side by side
            finite=finite,
        )
    return GridRun(settings, grid_map, results)


def summarize(run: GridRun) -> dict:
    """summary.json content: config, versions, devices, timings, per-algorithm statistics."""
    out = summary_base("grid", "successes", run.settings, run.results,
                       {a: r.successes for a, r in run.results.items()})
    if run.grid_map is not None:
        out["config"]["map"] = run.grid_map.text
    for algo, r in run.results.items():
        steps = r.agent_steps
        out["per_algo"][algo] |= {
            "mean_steps": steps / len(r.seeds), "agent_steps": steps,
            "agent_steps_per_second": steps / r.run_seconds if r.run_seconds > 0 else None,
        }
        if r.finite is not None:  # numerical blow-ups, per seed (a step size too large for the task)
            bad = r.non_finite_seeds
            out["per_algo"][algo]["non_finite_seeds"] = {"count": int(bad.size), "first": bad[:10].tolist()}
        if r.settings is not None:  # how it ran: every `auto` resolved (RunConfig.resolve), chunk size
            out["per_algo"][algo]["run"] = r.settings
    total_steps = sum(out["per_algo"][a]["agent_steps"] for a in run.results)
    out["agent_steps_per_second"] = total_steps / out["run_seconds"] if out["run_seconds"] > 0 else None
    return out


#: Per JAX backend: compute E8's counts beside the run (`run_grid_to_folder`) rather than after it.
DIAGNOSE_BESIDE_THE_RUN = {"gpu": True, "tpu": True}
#: Per JAX backend: beside the run, E8's counts start once every chunk is handed out to a device
#: rather than at the start, so E8's compiles no longer slow the run's: 4,194,304 seeds on 2x H200,
#: compile 4.78 -> 2.42 s on two GPUs, 2.45 -> 1.56 s on one, for 0.3-0.5 s of waiting for E8 after it.
DIAGNOSE_ONCE_DISPATCHED = {"gpu": True, "tpu": True}


def diagnose_grid(settings: GridSettings, grid_map: GridMap | None, seeds: dict[str, np.ndarray],
                  platform: str | None = None) -> tuple[dict, float]:
    """({algo: E8 counts of its seeds `seeds[algo]`}, seconds): those seeds again through the `trials`
    loop, counting E1's branches, E2's learning steps and the E6 flags on a best action (G2 moves
    along a shortest path, `shortest_actions`; none known off a grid map). The algorithms' programs
    compile and run side by side, on `platform`'s devices (default: JAX's default backend)."""
    from jaxeac.envs.grid import shortest_actions
    from jaxeac.running.diagnostics import diagnose_seeds

    if not seeds:
        return {}, 0.0
    t0 = time.perf_counter()
    env = settings.make_env()
    best = shortest_actions(grid_map) if grid_map is not None else None

    def one(algo: str):
        return diagnose_seeds(env, settings.run_config(algo), root_key=settings.key, seeds=seeds[algo], best=best,
                              platform=platform)

    with ThreadPoolExecutor(max_workers=len(seeds)) as pool:
        counts = dict(zip(seeds, pool.map(one, seeds), strict=True))
    trim_host_memory()  # what the seeds' runs freed goes back (a study's helper idles between tasks)
    return counts, time.perf_counter() - t0


def _diagnosed_count(settings: GridSettings, n_seeds: int) -> int:
    """How many of a run's first `n_seeds` seeds E8 counts (`diagnostic_seed_count` for its T and C)."""
    from jaxeac.running.diagnostics import diagnostic_seed_count

    return diagnostic_seed_count(n_seeds, settings.trials, settings.make_env().n_chances)


def _keeps_memories(settings: GridSettings, algo: str) -> bool:
    return settings.run_config(algo).agent.uses_memory


def diagnostic_seeds(settings: GridSettings) -> dict[str, np.ndarray]:
    """The seeds E8 counts in the `trials` loop for a run of `settings` from seed 0
    (`_diagnosed_count`): those of the algorithms with memories; the others' counts follow from
    the run's own trial logs (`memory_diagnostics`)."""
    n = _diagnosed_count(settings, settings.seeds)
    return {a: np.arange(n, dtype=np.int64) for a in settings.algos if _keeps_memories(settings, a)}


def memory_diagnostics(run: GridRun, max_seeds: int | None = None, diagnosed: tuple[dict, float] | None = None
                       ) -> dict:
    """summary.json's ``diagnostics_seeds``, ``diagnostics_seconds`` and ``memory_diagnostics`` (E8):
    per algorithm, the counts of the run's first min(N, `max_seeds`, default `diagnostic_seed_count`) seeds
    (`diagnose_grid`; `diagnosed`: its result for those seeds, computed earlier, e.g. beside the run).
    An algorithm without memories is counted from those seeds' trial logs in the run's results
    (`diagnostics_from_logs`, the same counts) where the results keep them.
    ``successes_match_run``: those seeds' successes equal the run's (R1, R2)."""
    from jaxeac.running.diagnostics import diagnostics_from_logs, seeds_block

    shortest = min(len(r.seeds) for r in run.results.values())
    n = _diagnosed_count(run.settings, shortest) if max_seeds is None else min(max_seeds, shortest)
    counts, seconds = (dict(diagnosed[0]), diagnosed[1]) if diagnosed else ({}, 0.0)
    n_chances = run.settings.make_env().n_chances
    for algo, r in run.results.items():
        if algo in counts or _keeps_memories(run.settings, algo):
            continue
        if (logs := r.logs_of_first(n)) is not None:
            counts[algo] = diagnostics_from_logs(logs, n_chances)
    rest = {a: r.seeds[:n] for a, r in run.results.items() if a not in counts}
    if rest:
        more, more_seconds = diagnose_grid(run.settings, run.grid_map, rest)
        counts, seconds = counts | more, seconds + more_seconds
    blocks = {}
    for algo, r in run.results.items():
        d = counts[algo]
        if len(d.success) != n:
            raise ValueError(f"diagnosed {len(d.success)} seeds of {algo}, expected {n}")
        blocks[algo] = seeds_block(d, run.grid_map is not None) | {
            "successes_match_run": bool(np.array_equal(d.success.sum(axis=1), r.successes[:n]))}
    return {"diagnostics_seeds": int(n), "diagnostics_seconds": seconds, "memory_diagnostics": blocks}


def summary_table(summary: dict) -> str:
    """The short text table printed at the end of `jaxeac grid`."""
    lines = [f"{'algo':<18}{'seeds':>7}{'mean successes':>16}   95% CI          sd",]
    for algo, st in summary["per_algo"].items():
        lo, hi = st["ci95_successes"]
        lines.append(
            f"{algo:<18}{summary['seeds']:>7}{st['mean_successes']:>16.2f}   "
            f"[{lo:7.2f}, {hi:7.2f}] {st['sd_successes']:6.2f}"
        )
    if "eac_minus_ac" in summary:
        d = summary["eac_minus_ac"]
        lines.append(f"EAC - AC: {d['diff']:+.2f} successes of {summary['trials']} "
                     f"(95% CI [{d['ci95'][0]:+.2f}, {d['ci95'][1]:+.2f}], Welch)")
    for algo, st in summary["per_algo"].items():
        bad = st.get("non_finite_seeds", {})
        if bad.get("count"):
            lines.append(f"warning: {algo}: {bad['count']} seed(s) ended with NaN or infinite p or V (seeds "
                         f"{', '.join(map(str, bad['first']))}{' …' if bad['count'] > 10 else ''}); "
                         "smaller step sizes avoid the blow-up")
    rate = summary.get("agent_steps_per_second")
    lines.append(f"compile {summary['compile_seconds']:.1f} s, run {summary['run_seconds']:.1f} s"
                 + (f", {rate:.3g} agent-steps/s" if rate else ""))
    return "\n".join(lines)


def per_seed_csv(run: GridRun) -> str:
    """per_seed.csv: one row per algorithm and seed (seed = i of fold_in(root, i))."""
    buf = io.StringIO()
    buf.write("algo,seed,successes,steps,first_success\n")
    for algo, r in run.results.items():
        for i, succ, steps, first in zip(r.seeds, r.successes, r.steps_total, r.first_success, strict=True):
            buf.write(f"{algo},{i},{succ},{steps},{first}\n")
    return buf.getvalue()


def curve_inputs(run: GridRun) -> dict:
    """Fig. 3's arguments (`jaxeac.plots.grid_figures`, but the folder) from a run's results, computed
    without matplotlib: its lines per algorithm, counted from every seed's successes; the paper's
    successes are marked on its own world only (no map file, env or slip)."""
    from jaxeac.stats.cumulative import cumulative_counts, cumulative_lines

    s = run.settings
    paper_world = s.map_file is None and s.env is None and not s.slip
    lines = {a: cumulative_lines(cumulative_counts(r.success), spread=True) for a, r in run.results.items()}
    return {"lines": lines, "paper": make_preset(s.preset).paper_successes if paper_world else None}


def policy_inputs(run: GridRun, seed: int = 0) -> dict:
    """Fig. 2's arguments (`jaxeac.plots.grid_figures`, but the folder): on a grid map, seed `seed`'s
    final policies (none off a grid map: nothing to draw)."""
    if run.grid_map is None:
        return {}
    return {"grid_map": run.grid_map, "policies": {a: r.policy_of(seed) for a, r in run.results.items()},
            "seed": seed, "max_steps": run.settings.chances}


def draw_grid_figures(folder: Path, inputs: dict) -> list[str]:
    """`jaxeac.plots.grid_figures` of `curve_inputs` or `policy_inputs` into `folder` (a job a
    helper process can run)."""
    from jaxeac import plots

    return plots.grid_figures(folder, **inputs)


def _finish_folder(run: GridRun, stage: Path, summary: dict, options: OutputOptions, figures: bool,
                   diagnosed: tuple[dict, float] | Future | None = None,
                   timeline: dict | None = None, helper=None) -> dict:
    """Everything of a run folder but results.parquet, into the staging folder. `diagnosed`: E8's
    counts, or a future of them, waited for once the figures are drawn; `timeline`: summary.json's
    ``timeline`` (`_run_into`), stamped when the figures are drawn and E8's counts are in; `helper`:
    a `jaxeac.running.helper.Helper` that draws the figures (None: drawn here)."""
    from jaxeac.running.helper import in_helper

    summary["outputs"] = dataclasses.asdict(options)
    drawn = []  # Fig. 2 first, drawn while Fig. 3's lines are counted (on one H100, 0.3 s of a warm
    try:        # 10^6-seed run); both in the helper while per_seed.csv is written and E8's counts come
        if figures:
            drawn.append(in_helper(helper, draw_grid_figures, stage, policy_inputs(run)))
            drawn.append(in_helper(helper, draw_grid_figures, stage, curve_inputs(run)))
        if options.per_seed_csv:
            (stage / "per_seed.csv").write_text(per_seed_csv(run))
    except BaseException:
        if helper is not None:
            for wait in drawn:
                with contextlib.suppress(Exception):
                    wait()  # the helper no longer writes in the folder when it is dropped
        raise
    if figures:
        policies = drawn[0]()
        drawn = drawn[1]() + policies  # Fig. 3, then Fig. 2
    if timeline is not None:
        timeline["figures"] = time.time()
    if isinstance(diagnosed, Future):
        diagnosed = diagnosed.result()
    if timeline is not None:
        timeline["diagnosed"] = time.time()
        summary["timeline"] = timeline
    summary |= memory_diagnostics(run, diagnosed=diagnosed)
    if figures:
        summary["figures"] = drawn
    atomic_write_json(stage / "summary.json", summary)
    return summary


def write_grid_outputs(run: GridRun, out: str | Path, *, figures: bool = True,
                       options: OutputOptions | None = None) -> dict:
    """Write results.parquet (and per_seed.csv for small runs), summary.json and figures, all
    or nothing. `options`: what the folder holds (default `OutputOptions.auto` for the seed count)."""
    summary = summarize(run)
    options = options or OutputOptions.auto(run.settings.seeds)
    with staged_dir(out, replaces=RUN_FOLDER_FILES) as stage:
        write_grid_results(stage / RESULTS_FILE, run.results, run.settings.trials,
                           run.settings.make_env().n_states, options)
        return _finish_folder(run, stage, summary, options, figures)


def run_grid_to_folder(settings: GridSettings, out: str | Path, *, options: OutputOptions | None = None,
                       figures: bool = True, progress: Callable[[int], None] | None = None,
                       on_results: Callable[[GridRun], None] | None = None,
                       helper=None) -> tuple[GridRun, dict]:
    """Run every algorithm of `settings` (already `resolved()`) and write the run folder as the
    run goes (`run_algorithms`: one pipeline of compiles and chunks): each
    chunk's rows go to results.parquet while the next chunk computes, and only `CompactSeeds`
    stay in memory. The folder appears all at once when everything is written (a run killed
    midway leaves it as it was). `on_results(run)` is called as soon as the results are in, before
    the folder's figures and summary (`jaxeac grid` starts its statistics there); `helper`: a
    `jaxeac.running.helper.Helper` that draws the figures (None: drawn here). Returns the run and
    its summary.json content.
    """
    options = options or OutputOptions.auto(settings.seeds)
    grid_map, env = settings.grid_map(), settings.make_env()
    seeds = np.arange(settings.seeds, dtype=np.int64)
    started = time.time()
    pool = ThreadPoolExecutor(max_workers=1)
    # On accelerators E8's programs compile (and run) while the devices run the seeds (once they
    # hold their last chunks: `DIAGNOSE_ONCE_DISPATCHED`), and then the figures' modules load (half
    # a second); on CPUs the run has every core, and they follow it.
    early: Future | None = None
    on_drained = None
    backend = jax.default_backend()
    if DIAGNOSE_BESIDE_THE_RUN.get(backend, False):
        if diagnosed := diagnostic_seeds(settings):
            if DIAGNOSE_ONCE_DISPATCHED.get(backend, False):
                early = Future()

                def on_drained() -> None:
                    if early.set_running_or_notify_cancel():
                        try:
                            early.set_result(diagnose_grid(settings, grid_map, diagnosed))
                        except BaseException as e:  # noqa: BLE001 (whoever waits gets it)
                            early.set_exception(e)
            else:
                early = pool.submit(diagnose_grid, settings, grid_map, diagnosed)
        if figures and helper is None:
            pool.submit(importlib.import_module, "jaxeac.plots")
    try:
        return _run_into(settings, out, options, figures, progress, grid_map, env, seeds, early,
                         on_results, on_drained, started, helper)
    finally:
        pool.shutdown(wait=False, cancel_futures=True)


def _run_into(settings: GridSettings, out, options: OutputOptions, figures: bool, progress, grid_map, env,
              seeds: np.ndarray, early, on_results, on_drained, started: float,
              helper=None) -> tuple[GridRun, dict]:
    """`run_grid_to_folder`'s run and folder; `early`: a future of E8's counts, or None (set by
    `on_drained`, when given, once the devices hold their last chunks). summary.json's
    ``timeline``: clock times (`time.time()`) of the run's start, its results in memory, the
    figures drawn and E8's counts in, to tell where a command's seconds go."""
    with (staged_dir(out, replaces=RUN_FOLDER_FILES) as stage,
          ResultsWriter(stage / RESULTS_FILE, settings.trials, env.n_states, options) as writer,
          ChunksBehind(keep_log=options.trial_steps, keep_policy=options.policies) as behind):
        # results.parquet is written on a thread of its own, behind the run (`ChunksBehind`): the
        # results are in memory once the last chunk is measured, and the figures, summary and
        # statistics start while the file is still being written.
        algos = settings.algos
        collectors = [CompactCollector(seeds, settings.trials, env.n_states, n_chances=env.n_chances,
                                       on_chunk=behind.of(writer.chunk_writer(algo, seeds)),
                                       whole_chunks=options.trial_steps or options.policies)
                      for algo in algos]
        runs = run_algorithms(env, [settings.run_config(a) for a in algos], root_key=settings.key,
                              n_seeds=settings.seeds, chunk_size=settings.chunk_size, progress=progress,
                              collectors=collectors, on_drained=on_drained)
        results = dict(zip(settings.algos, runs, strict=True))
        run = GridRun(settings, grid_map, results)
        timeline = {"started": started, "results": time.time()}
        if on_results is not None:
            on_results(run)
        # the figures are drawn while E8's counts, started late (`DIAGNOSE_ONCE_DISPATCHED`), finish
        summary = _finish_folder(run, stage, summarize(run), options, figures, diagnosed=early,
                                 timeline=timeline, helper=helper)
        behind.finish()  # the whole file before the folder appears
        return run, summary



def run_grid_sequential(settings: GridSettings, out: str | Path, design, *,
                        options: OutputOptions | None = None, figures: bool = True,
                        progress: Callable[[int], None] | None = None,
                        on_look: Callable[[dict], None] | None = None) -> tuple[GridRun, dict]:
    """A sequential comparison of EAC with AC (`jaxeac.stats.sequential`): seeds in batches of
    ⌊N / K⌋ per method (one compiled program), a look after each, stop at the first decision.

    The run folder holds the seeds run (0 … n − 1, the same results as those seeds of a fixed
    run, R1) and summary.json's ``sequential``: the design (fixed before the first batch), every
    look and the decision, and the design's decision rates simulated from the run's own per-seed
    differences (with random signs: the false "difference" rate under no difference; as they
    are: the rates at the observed effect). Looks are paired: seed i of both shares its key.
    """
    from jaxeac.stats.sequential import calibration_record, run_sequential

    if not {"ac", "eac"} <= set(settings.algos):
        raise UsageError("--sequential compares eac with ac: --algos must include both")
    options = options or OutputOptions.auto(design.sizes[-1])
    grid_map, env = settings.grid_map(), settings.make_env()
    algos = settings.algos
    cfgs = [settings.run_config(a) for a in algos]
    parts: dict[str, list[CompactSeeds]] = {a: [] for a in algos}
    t0 = time.perf_counter()
    with staged_dir(out, replaces=RUN_FOLDER_FILES) as stage:
        with ResultsWriter(stage / RESULTS_FILE, settings.trials, env.n_states, options) as writer:
            def measure(first: int, n: int):
                seeds = np.arange(first, first + n, dtype=np.int64)
                chunk_writers = [writer.chunk_writer(a, seeds) for a in algos]
                collectors = [CompactCollector(seeds, settings.trials, env.n_states, on_chunk=w,
                                               n_chances=env.n_chances) for w in chunk_writers]
                runs = run_algorithms(env, cfgs, root_key=settings.key, n_seeds=n, first_seed=first,
                                      chunk_size=settings.chunk_size, progress=progress,
                                      collectors=collectors)
                for a, r in zip(algos, runs, strict=True):
                    parts[a].append(r)
                return parts["ac"][-1].successes, parts["eac"][-1].successes

            result = run_sequential(design, measure, on_look, paired=True)  # seed i shares its key (R1)
        result["seconds_to_decision"] = time.perf_counter() - t0
        results = {a: CompactSeeds.concatenate(p) for a, p in parts.items()}
        d = results["eac"].successes.astype(np.float64) - results["ac"].successes
        result["calibration"] = calibration_record(design, d, settings.key)
        run = GridRun(dataclasses.replace(settings, seeds=result["seeds_used"]), grid_map, results)
        summary = summarize(run)
        summary["sequential"] = result
        return run, _finish_folder(run, stage, summary, options, figures)
