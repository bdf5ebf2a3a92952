"""What the experiments share: input checks, per-seed intervals and the summary.json core.

The checks raise `UsageError` so that bad input fails before any compute (the CLI turns
it into a one-line error).
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable

import jax
import numpy as np

from jaxeac.algorithm.config import ALGORITHMS, algorithm
from jaxeac.errors import KEY_LIMIT, UsageError, check_int
from jaxeac.runtime import versions
from jaxeac.stats.closed_form import t_interval, welch_interval

#: The command line a run folder records (summary.json's ``command``), set by the `jaxeac` command;
#: None in a library call, whose process arguments (a notebook's, pytest's) are no jaxeac command.
COMMAND: tuple[str, ...] | None = None

# ------------------------------------------------------------------ input checks


def check_positive_int(name: str, value) -> None:
    """An integer > 0 (not a bool)."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
        raise UsageError(f"{name} must be a positive integer (got {value!r})")


def check_key(value) -> None:
    """A root key (R1): an integer in 0..2^32−1 (`jaxeac.errors.KEY_LIMIT`; `jaxeac.rng.root_key_int`
    also takes JAX keys); seed i is ``fold_in(key(k), i)``."""
    check_int("key", value, low=0, high=KEY_LIMIT - 1,
              fix=f"keys are 32-bit: pass one in 0..{KEY_LIMIT - 1} (a larger key would repeat key "
                  "k mod 2^32's random numbers)")


#: Step sizes and discount: the updates (2)-(4) keep finite tables for rates in [0, 1]; with α or β
#: well above 1 the TD updates overshoot and the tables blow up to inf/NaN without an error.
RATE_RANGES = {"alpha": 1.0, "beta": 1.0, "gamma": 1.0}
_F32_TINY, _F32_MAX = float(np.finfo(np.float32).tiny), float(np.finfo(np.float32).max)  # Python floats


def check_rate(name: str, value, *, upper: float | None = None, positive: bool = False) -> None:
    """A finite number ≥ 0 (> 0 if `positive`), at most `upper` where given (α, β, γ: at most 1,
    `RATE_RANGES`), and one that float32, the type the runs compute in, holds without becoming 0 or inf."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer) \
            or not math.isfinite(value):
        raise UsageError(f"{name} must be a finite number (got {value!r})")
    if value < 0 or (positive and value == 0):
        raise UsageError(f"{name} must be {'positive' if positive else 'non-negative'} (got {value!r})")
    upper = RATE_RANGES.get(name, upper) if upper is None else upper
    if upper is not None and value > upper:
        why = "; larger step sizes make the tables diverge to inf/NaN" if name in ("alpha", "beta") else ""
        raise UsageError(f"{name} must lie in [0, {upper:g}] (got {value!r}){why}")
    if value != 0 and not (_F32_TINY <= abs(value) <= _F32_MAX):
        zero = "" if positive else "0 or "
        with np.errstate(all="ignore"):
            rounded = float(np.float32(value))
        raise UsageError(f"{name} {value!r} is outside float32's normal range (runs compute in float32, "
                         f"where it becomes {rounded:.3g}); use {zero}a value in "
                         f"[{_F32_TINY:.3g}, {_F32_MAX:.3g}]")


def check_algos(algos) -> None:
    """A non-empty list of known algorithm names, each once."""
    if not algos:
        raise UsageError("algos is empty; pass at least one of " + ", ".join(sorted(ALGORITHMS)))
    for name in algos:
        algorithm(name)  # raises on unknown names
    if len(set(algos)) != len(algos):
        raise UsageError(f"algos lists an algorithm twice ({' '.join(algos)}); list each once")


# ------------------------------------------------------------------ resources

#: Seed indices, trial and chance counters are int32 on the device.
INT32_LIMIT = (1 << 31) - 1
#: Work bound: a run whose largest possible work would take longer than this even at
#: `STEPS_PER_SECOND` / `THROWS_PER_SECOND` is refused (with the estimate) instead of hanging.
MAX_RUN_DAYS = 7
#: Optimistic agent-steps/s per device (CPU: per core); about 4x the best measured (BENCHMARKS.md:
#: 2.5e7 per core, 1.3e10 on one H200), so only runs whose largest possible work (every trial
#: using all its chances) could not finish within the limit even at that speed are refused.
STEPS_PER_SECOND = {"cpu": 1e8, "default": 5e10}
#: Memory bandwidth per device (CPU: per core), optimistic: a step of the flat loop also moves a
#: lane's r̃ [chances] (measured: ~0.12 ns per chance and step on a CPU core), so its cost grows
#: with --chances.
BYTES_PER_SECOND = {"cpu": 3e10, "default": 3e12}
#: Optimistic bowling throws/s: C engine per core (measured ~130 with sleeping pins), MJX per GPU
#: (measured ~1e4).
THROWS_PER_SECOND = {"c": 500.0, "default": 1e5}
#: Statistics (`jaxeac compare`): host bytes per bootstrap/permutation resample and trial, a lower
#: bound (measured ~135-150 bytes with 20-200 trials).
COMPARE_BYTES_PER_RESAMPLE_TRIAL = 64


def machine_memory() -> int:
    """Bytes of memory this process can use: physical memory, or a smaller cgroup limit."""
    try:
        total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        total = 1 << 62
    for limit_file in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = open(limit_file).read().strip()
        except OSError:
            continue
        if text.isdigit() and 0 < int(text) < total:
            total = int(text)
    return int(total)


def fmt_bytes(n: float) -> str:
    """A byte count for messages: '23.5 GiB', '7.3e+06 TiB'."""
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024:
            return f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} TiB" if n < 1e4 else f"{n:.2g} TiB"


def fmt_duration(seconds: float) -> str:
    if seconds < 2 * 3600:
        return f"{seconds / 60:.3g} minutes"
    if seconds < 3 * 86400:
        return f"{seconds / 3600:.3g} hours"
    if seconds < 3 * 365 * 86400:
        return f"{seconds / 86400:.3g} days"
    return f"{seconds / (365 * 86400):.3g} years"


def check_int32(name: str, value: int, flag: str | None = None) -> None:
    """Counts the device holds as int32 (seed indices, trials, chances)."""
    if value > INT32_LIMIT:
        raise UsageError(f"{flag or name} {value} is too large: {name} are int32 on the device; "
                         f"use at most {INT32_LIMIT:,}")


def _devices():
    devices = jax.local_devices()
    return devices, devices[0].platform


def _device_memory(device) -> int | None:
    """An accelerator's memory in bytes; None for CPU devices (they share `machine_memory`)."""
    if device.platform == "cpu":
        return None
    try:
        stats = device.memory_stats() or {}
    except Exception:  # noqa: BLE001 - a backend without memory stats
        return None
    return int(stats.get("bytes_limit", 0)) or None


def _largest_fitting(need: Callable[[int], int], budget: int, high: int) -> int:
    """The largest m in [1, high] with need(m) <= budget (need grows with m); 0 if none."""
    if need(1) > budget:
        return 0
    lo, hi = 1, high
    while lo < hi:
        mid = (lo + hi + 1) // 2
        lo, hi = (mid, hi) if need(mid) <= budget else (lo, mid - 1)
    return lo


def check_work(steps: float, rate: float, what: str, fix: str) -> None:
    """Refuse a run whose largest possible work would take more than `MAX_RUN_DAYS` at `rate`/s."""
    seconds = steps / rate
    if seconds > MAX_RUN_DAYS * 86400:
        raise UsageError(f"this run could take far too long: up to {steps:.3g} {what}, at best {rate:.3g} "
                         f"a second here, take up to {fmt_duration(seconds)} (the limit is {MAX_RUN_DAYS} "
                         f"days); {fix}")


def check_grid_resources(settings, env, *, n_seeds: int | None = None, first_seed: int = 0,
                         devices=None) -> int | None:
    """Refuse a grid run (`GridSettings`, resolved; `env` its `make_env()`) that cannot fit in
    memory or finish, up front.

    Host memory holds every seed's results (success, steps, policy: about seeds × (5·trials +
    4·cells) bytes per algorithm); each chunk holds, per device, the state of the seeds in
    flight (tables, memories, trial log, r̃ per chance: `state_bytes_per_seed`) and the chunk's
    packed outputs. Returns the chunk size to run: `settings.chunk_size`, or, when that is
    automatic and the automatic one would not fit, the largest that fits (results do not
    depend on it, R1). Raises `UsageError` with the numbers otherwise.
    """
    from jaxeac.running.batch import even_chunk
    from jaxeac.running.config import auto_chunk_size
    from jaxeac.running.loops import state_bytes_per_seed
    from jaxeac.running.outputs import narrow_int

    n = settings.seeds if n_seeds is None else int(n_seeds)
    trials, chances, cells = settings.trials, settings.chances, env.n_states
    check_int32("seed indices", first_seed + n, "--seeds")
    check_int32("trials", trials, "--trials")
    check_int32("chances", chances, "--chances")
    if settings.memory == "buffer":
        check_int32("memory slots", settings.capacity, "--capacity")
    memory, algos = machine_memory(), len(settings.algos)
    per_seed = 5 * trials + 4 * cells + 8  # success bool, steps int32 [T]; policy int32 [S]; seed int64
    host = algos * n * per_seed
    tables = 64 * cells  # the env's transition tables, on the host and as device constants
    if host + tables > memory:
        most = max(0, (memory - tables) // (algos * per_seed))
        fix = (f"run at most {most:,} seeds (split bigger runs with --num-processes over machines)"
               if most else "use fewer trials or a smaller map")
        raise UsageError(f"this run cannot fit in memory: {algos} algorithm(s) x {n:,} seeds of results "
                         f"({trials:,} trials, {cells:,} cells: {per_seed:,} bytes a seed) need "
                         f"{fmt_bytes(host)}, but this machine has {fmt_bytes(memory)}; {fix}")
    devices, platform = list(devices) if devices is not None else _devices()
    nd = len(devices)
    step_seconds = (1 / STEPS_PER_SECOND.get(platform, STEPS_PER_SECOND["default"])
                    + 4 * chances / BYTES_PER_SECOND.get(platform, BYTES_PER_SECOND["default"]))
    check_work(float(algos) * n * trials * chances, nd / step_seconds,
               "agent-steps (algorithms x seeds x trials x chances)", "use fewer seeds, trials or chances")

    out_bytes = trials * narrow_int(chances).itemsize + cells * narrow_int(env.n_actions).itemsize
    device_memory = _device_memory(devices[0])
    budget = device_memory if device_memory is not None else max(0, memory - host - tables)
    chosen, auto = settings.chunk_size, settings.chunk_size is None
    for algo in settings.algos:
        cfg = settings.run_config(algo)
        chunk = even_chunk(n, chosen if chosen else auto_chunk_size(env, cfg, n, devices), nd)
        per_dev = chunk // nd
        state = state_bytes_per_seed(env, cfg.resolve(env, per_dev, platform))

        def need(m, cfg=cfg, state=state):
            resolved = cfg.resolve(env, m, platform)
            lanes = min(m, resolved.lanes or m) if resolved.loop == "flat" else m
            per_device = lanes * state + m * out_bytes
            # CPU devices share the host's memory, which also holds the chunk copied back
            return per_device if device_memory is not None else nd * per_device + 2 * nd * m * out_bytes

        if need(per_dev) <= budget:
            continue
        fits = _largest_fitting(need, budget, per_dev)
        where = "a device" if device_memory is not None else "this machine"
        what = (f"{fmt_bytes(need(per_dev))} for a chunk of {chunk:,} seeds ({fmt_bytes(state)} of {algo} "
                f"state a seed in flight: {trials:,} trials, {chances:,} chances, {cells:,} cells)")
        if not fits:
            raise UsageError(f"this run cannot fit in memory: even a chunk of one seed needs "
                             f"{fmt_bytes(need(1))} ({fmt_bytes(state)} of {algo} state: {trials:,} trials, "
                             f"{chances:,} chances, {cells:,} cells), but {where} has {fmt_bytes(budget)} "
                             "for it; use fewer trials or chances or a smaller map")
        if not auto:
            raise UsageError(f"--chunk-size {chosen:,} cannot fit in memory: it needs {what}, but {where} "
                             f"has {fmt_bytes(budget)} for it; pass --chunk-size {fits * nd:,} or less")
        chosen = fits * nd  # automatic chunk size: the largest that fits (results do not depend on it)
    return chosen


def check_bowling_resources(settings, devices=None) -> None:
    """Refuse a bowling run (`BowlingSettings`, validated) that cannot fit in memory or finish, up front.

    Host memory holds every seed's record (angle and pins per chance, success per trial) twice
    while the chunks are joined; a chunk holds its seeds' agents (tables over the 1,024 pin
    masks × K angles, memories, trial log); throws take at least 1/`THROWS_PER_SECOND` s each.
    """
    from jaxeac.algorithm.agent import init_agent

    n, trials, angles = settings.seeds, settings.trials, settings.angles
    check_int32("seed indices", n, "--seeds")
    check_int32("trials", trials, "--trials")
    memory, algos = machine_memory(), len(settings.algos)
    per_seed = 2 * 5 * trials + 16  # int8 action, int8 knocked [T, 2], success [T]; joined (x2)
    host = algos * n * per_seed
    if host > memory:
        raise UsageError(f"this run cannot fit in memory: {algos} algorithm(s) x {n:,} seeds x {trials:,} "
                         f"trials of records need {fmt_bytes(host)}, but this machine has "
                         f"{fmt_bytes(memory)}; "
                         f"run at most {memory // (algos * per_seed):,} seeds or fewer trials")
    devices, platform = list(devices) if devices is not None else _devices()
    chunk = min(settings.chunk_size, n)
    device_memory = _device_memory(devices[0])
    budget = device_memory if device_memory is not None else max(0, memory - host)
    where = "a device" if device_memory is not None else "this machine"
    largest = 0
    for algo in settings.algos:
        cfg = settings.run_config(algo)
        shapes = jax.eval_shape(lambda cfg=cfg: init_agent(cfg.agent, 1024, angles, 2, trials))
        state = sum(int(np.prod(x.shape, dtype=np.float64)) * x.dtype.itemsize
                    for x in jax.tree.leaves(shapes))
        largest = max(largest, state)
        need = 3 * chunk * state  # the agents, their update and the chosen-action temporaries
        if need > budget:
            fits = budget // (3 * state)
            fix = (f"pass --chunk-size {fits:,} or less" if fits else
                   f"use fewer angles (one seed's agent holds 1,024 pin masks x {angles:,} angles)")
            raise UsageError(f"this run cannot fit in memory: a chunk of {chunk:,} seeds needs "
                             f"{fmt_bytes(need)} ({fmt_bytes(state)} of {algo} agent a seed: "
                             f"{angles:,} angles, {trials:,} trials), but {where} has "
                             f"{fmt_bytes(budget)}; {fix}")
    if settings.backend == "c" or platform == "cpu":
        units, throws_per_unit = os.cpu_count() or 1, THROWS_PER_SECOND["c"]
    else:
        units, throws_per_unit = len(devices), THROWS_PER_SECOND["default"]
    # a learning step after each throw also updates the seed's whole agent (tables over K angles)
    per_throw = 1 / throws_per_unit + largest / BYTES_PER_SECOND.get(platform, BYTES_PER_SECOND["default"])
    check_work(float(algos) * n * trials * 2, units / per_throw,
               "throws (algorithms x seeds x trials x 2 chances)", "use fewer seeds, trials or angles")


def check_compare_resources(resamples: int, trials: int) -> None:
    """Refuse `jaxeac compare --resamples R` whose resample statistics cannot fit in memory."""
    memory = machine_memory()
    need = resamples * max(1, trials) * COMPARE_BYTES_PER_RESAMPLE_TRIAL
    if need > memory:
        most = memory // (max(1, trials) * COMPARE_BYTES_PER_RESAMPLE_TRIAL)
        raise UsageError(f"--resamples {resamples:,} cannot fit in memory: the resampled statistics of "
                         f"{trials:,} trials need at least {fmt_bytes(need)}, but this machine has "
                         f"{fmt_bytes(memory)}; use at most --resamples {most:,} (10,000 is the default)")


# ------------------------------------------------------------------ per-seed summaries


def mean_ci95(x: np.ndarray) -> tuple[float, float, float, float]:
    """(mean, sd, lo, hi): Student-t 95 % interval of the mean (NaN bounds when n < 2), as
    `jaxeac.stats.closed_form.t_interval` (its one definition)."""
    return t_interval(x)


def welch_diff_ci95(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float]:
    """(mean(b) − mean(a), lo, hi) with the Welch–Satterthwaite 95 % interval
    (`jaxeac.stats.closed_form.welch_interval`, its one definition)."""
    e = welch_interval(a, b)
    return e.estimate, e.low, e.high


def summary_base(experiment: str, primary: str, settings, results: dict, measures: dict) -> dict:
    """The summary.json fields every run folder shares (`measures`: primary measure per algorithm)."""
    per_algo = {}
    for algo, r in results.items():
        mean, sd, lo, hi = mean_ci95(measures[algo])
        per_algo[algo] = {f"mean_{primary}": mean, f"sd_{primary}": sd, f"ci95_{primary}": [lo, hi],
                          "compile_seconds": r.compile_seconds, "run_seconds": r.run_seconds}
    out = {
        "experiment": experiment, "primary_measure": primary, "algos": list(settings.algos),
        "trials": settings.trials, "seeds": settings.seeds, "key": settings.key,
        "config": dataclasses.asdict(settings), "versions": versions(),
        "devices": [str(d) for d in jax.devices()], "command": " ".join(COMMAND) if COMMAND else None,
        "compile_seconds": sum(r.compile_seconds for r in results.values()),
        "run_seconds": sum(r.run_seconds for r in results.values()),
        "per_algo": per_algo,
    }
    if "ac" in measures and "eac" in measures:
        diff, lo, hi = welch_diff_ci95(measures["ac"], measures["eac"])
        out["eac_minus_ac"] = {"diff": diff, "ci95": [lo, hi], "method": "Welch t interval"}
    return out


def plain_json(obj):
    """Plain JSON types (tuples → lists, numpy → Python, NaN → None), as a JSON round trip gives."""
    import json

    from jaxeac.io import to_jsonable

    return json.loads(json.dumps(to_jsonable(obj)))


def finished_run(folder, expect: dict) -> bool:
    """A run folder whose summary.json exists and whose config has every `expect` item. A
    damaged summary.json (not JSON, not an object, no config) is not finished: the step runs
    again and replaces the folder as a whole."""
    from pathlib import Path

    from jaxeac.io import read_json_object

    path = Path(folder) / "summary.json"
    if not path.is_file():
        return False
    try:
        config = read_json_object(path).get("config")
    except UsageError:
        return False
    if not isinstance(config, dict):
        return False
    return all(plain_json(config.get(k)) == plain_json(v) for k, v in expect.items())
