"""Many seeds of one algorithm: chunks, devices, one compile, results back on the host.

`run_entries` runs entries (seed i, hyper i) in fixed-size chunks through one compiled
program (`make_batch_run`) per device group: on GPUs each device runs its own program on
chunks it takes from a shared queue, at its own pace; on CPUs one program splits each chunk
over the cores with `shard_map` (seeds are independent, R1). The host collects each chunk,
in seed order, while the devices compute the next ones.
Seed i uses ``fold_in(root_key, i)`` (R1), so results never depend on the chunk size,
the device count or the seeds beside it, and reruns are bit-identical (R2).

(Over 400 lines by its entry checks: every argument of the three entry points is checked before
any compile.)
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor

import jax
import numpy as np
from jax.sharding import Mesh, PartitionSpec

from jaxeac.algorithm.config import Hyper
from jaxeac.errors import UsageError, check_int
from jaxeac.rng import KEY_LIMIT, root_key_int, seed_key, seed_words
from jaxeac.running.config import RunConfig, auto_chunk_size
from jaxeac.running.loops import (
    Env,
    bind_inputs,
    check_run_args,
    flat_batch,
    program_inputs,
    program_key,
    trials_batch,
)
from jaxeac.running.outputs import (
    BatchOutput,
    Collector,
    CompactSeeds,
    HostArrays,
    SeedResult,
    SeedsResult,
    device_measures,
)
from jaxeac.running.schedule import (  # noqa: F401  (record_timeline, DEVICES_APART: scripts, tests)
    DEVICES_APART,
    device_groups,
    record,
    record_timeline,
    run_chunks,
)
from jaxeac.running.programs import load_or_build
from jaxeac.running.threads import OnceCache, in_background
from jaxeac.runtime import trim_host_memory

SEEDS_AXIS = "seeds"


def seed_mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A 1-D device mesh whose only axis, ``seeds``, the seed batch is split over."""
    return Mesh(np.array(list(devices) if devices is not None else jax.devices()), (SEEDS_AXIS,))


def make_batch_run(env: Env, cfg: RunConfig, mesh: Mesh | None = None) -> Callable:
    """jit over a chunk: ``(root_key, seeds [M], hyper with leaves [M], tables) -> BatchOutput [M, ...]``;
    `tables`: the env's `program_inputs` (a tabular task's tables; one program serves every task of
    its layout), ``{}`` for an env whose tables are part of the program.

    With a `mesh`, the chunk is split over its ``seeds`` axis with `shard_map`: each
    device runs its own seeds with no communication (seeds are independent, R1).
    """
    cfg = cfg.resolve(env)

    def batch(root_key: jax.Array, seeds: jax.Array, hyper: Hyper, tables: dict) -> BatchOutput:
        keys = jax.vmap(seed_key, in_axes=(None, 0))(root_key, seeds)
        bound = bind_inputs(env, tables)
        if cfg.loop == "trials":
            return trials_batch(bound, cfg, keys, hyper)
        return flat_batch(bound, cfg, jax.vmap(seed_words)(keys), hyper)

    if mesh is not None:
        split = PartitionSpec(SEEDS_AXIS)
        batch = jax.shard_map(batch, mesh=mesh, in_specs=(PartitionSpec(), split, split, PartitionSpec()),
                              out_specs=split, check_vma=False)  # per-seed loops: no collectives to check
    return jax.jit(batch)


def start_states(env: Env, root_key: int, seeds, trials: int) -> np.ndarray:
    """int32 [N, T]: the state each trial of seeds `seeds` of a run with root key `root_key` starts in
    (G3), drawn as the run loops draw it (`env.start` from the seed's words, R1). Runs do not record
    their start states; this recovers them, the same for every algorithm."""
    root = jax.random.key(root_key_int(root_key))
    seeds = _check_seeds(seeds)
    check_int("trials", trials, fix="pass the run's trials per seed")
    words = jax.vmap(lambda s: seed_words(seed_key(root, s)))(seeds.astype(np.int32))
    per_trial = jax.vmap(lambda w, t: env.observation(env.start(w, t)), in_axes=(None, 0))
    starts = jax.jit(jax.vmap(per_trial, in_axes=(0, None)))(words, np.arange(trials, dtype=np.int32))
    return np.asarray(starts, np.int32)


def chunks(n_seeds: int, chunk_size: int) -> Iterator[np.ndarray]:
    """Seed indices 0..N−1 in chunks of `chunk_size` (the last one may be short)."""
    for start in range(0, n_seeds, chunk_size):
        yield np.arange(start, min(start + chunk_size, n_seeds), dtype=np.int32)


def even_chunk(n: int, chunk_size: int, n_devices: int) -> int:
    """The chunk size actually run: N split evenly into ceil(N / chunk_size) chunks (no chunk is
    mostly padding), rounded up to a multiple of the device count."""
    check_int("chunk_size", chunk_size, fix="pass seeds per chunk, or None for the automatic size")
    n_chunks = -(-n // chunk_size)
    even = -(-n // n_chunks)
    return -(-even // n_devices) * n_devices


_measure = jax.jit(device_measures)  # on the device of its input, compiled once per device and shape

_COMPILED = OnceCache()  # key -> (compiled program, seconds its compile took)
_JITTED_LOCK = threading.Lock()

def _check_seeds(seeds) -> np.ndarray:
    """int64 [N]: seed indices, each in 0..2^32−1 (R1: `fold_in` keeps 32 bits)."""
    try:
        out = np.asarray(seeds)
    except (TypeError, ValueError):
        out = np.asarray(None)
    if out.ndim != 1 or not (out.size == 0 or np.issubdtype(out.dtype, np.integer)):
        raise TypeError(f"seeds must be a 1-D sequence of integer seed indices (got {seeds!r}); "
                        "pass e.g. np.arange(100)")
    out = out.astype(np.int64)
    if out.size and (out.min() < 0 or out.max() >= KEY_LIMIT):
        bad = int(out.min() if out.min() < 0 else out.max())
        raise UsageError(f"seeds must lie in 0..{KEY_LIMIT - 1} (got {bad}); seed i's key is "
                         "fold_in(root, i), which keeps 32 bits")
    return out


def _check_chunk(chunk_size) -> None:
    if chunk_size is not None:
        check_int("chunk_size", chunk_size, fix="pass seeds per chunk, or None for the automatic size")


def _check_configs(env, cfgs) -> list:
    """The env and each config (`check_run_args`); `cfgs` a non-empty list or tuple."""
    if not isinstance(cfgs, list | tuple) or not cfgs:
        raise TypeError(f"cfgs must be a non-empty list of RunConfig, one per algorithm (got {cfgs!r})")
    for cfg in cfgs:
        check_run_args(env, cfg)
    return list(cfgs)


def _placed(group: tuple, *inputs) -> tuple:
    """The program's inputs on `group`: on its one device (committed, so the program compiles for
    that device), or as they are for a mesh program (split by its `shard_map`)."""
    if len(group) > 1:
        return inputs
    return jax.device_put(inputs, jax.sharding.SingleDeviceSharding(group[0]))


def _compiled(env: Env, cfg: RunConfig, devices: tuple, root, seeds, hyper, tables: dict):
    """(compiled chunk program, seconds this call spent compiling it) for this env object, config,
    devices (one device, or a mesh of several) and chunk shape, compiled once: a later caller, on
    any thread, waits for the first and gets 0 seconds (cached)."""
    cfg = cfg.resolve(env, seeds.shape[0] // len(devices))  # every `auto`, once, before tracing
    key = (program_key(env), cfg, devices, seeds.shape, jax.tree.map(lambda x: x.dtype, hyper))
    def compile_it() -> tuple:
        t0 = time.perf_counter()
        args = _placed(devices, root, seeds, hyper, tables)
        lowered_s = []

        def build():
            lowered = _jitted(env, cfg, devices).lower(*args)
            lowered_s.append(time.perf_counter() - t0)
            return lowered.compile()

        identity = (program_key(env), cfg, [d.id for d in devices])
        program, loaded = load_or_build("chunk", identity, args, build)
        seconds = time.perf_counter() - t0
        lower_s = lowered_s[0] if lowered_s else 0.0  # 0: loaded whole (`jaxeac.running.programs`)
        record({"event": "lowered", "devices": [d.id for d in devices], "lower_s": lower_s,
                "xla_s": seconds - lower_s, "loaded": loaded})  # trace and lowering; XLA's compile or a load
        if not loaded:
            trim_host_memory()
        return program, seconds

    (program, seconds), mine = _COMPILED.get(key, compile_it)
    return program, seconds if mine else 0.0  # 0 s: compiled by an earlier call (or another thread)


_JITTED: dict = {}  # (program key, config) -> the jitted chunk program of one device


def _jitted(env: Env, cfg: RunConfig, devices: tuple) -> Callable:
    """`make_batch_run` for these devices: a mesh program for several, else one jitted function
    shared by every single device, so each device after the first reuses its trace and lowering
    (only XLA's compile, or the persistent cache's load, is per device)."""
    if len(devices) > 1:
        return make_batch_run(env, cfg, seed_mesh(devices))
    key = (program_key(env), cfg)
    with _JITTED_LOCK:
        if key not in _JITTED:
            if len(_JITTED) >= 64:
                _JITTED.clear()
            _JITTED[key] = make_batch_run(env, cfg)
        return _JITTED[key]


def _persistent_cache_shared(platform: str) -> bool:
    """Whether a program compiled for one device is found in JAX's persistent compilation cache
    by the same program on another: on GPUs the cache's key leaves out the device."""
    return platform == "gpu" and bool(jax.config.jax_compilation_cache_dir)


def _compile_groups(env: Env, cfg: RunConfig, groups: list[tuple], root, seeds, hyper,
                    tables: dict, name: str = "") -> tuple[list[Future], float]:
    """(a future of the compiled program of each device group, seconds the first one's compile
    took). The first group's program is ready on return, so its device starts at once; the
    others come on threads while it runs: loaded from the persistent cache after the first's
    compile where the cache serves them (`_persistent_cache_shared`), else compiled beside it.
    Each device takes chunks once its own program is in (`_Entries.program_pending`)."""
    def compile(i: int) -> tuple:
        t0 = time.perf_counter()
        program, seconds = _compiled(env, cfg, groups[i], root, seeds, hyper, tables)
        record({"event": "compile", "job": name, "group": i, "start": t0, "end": time.perf_counter(),
                "compile_s": seconds, "groups": len(groups)})
        return program, seconds

    def later(i: int) -> Future:
        return in_background(lambda: compile(i)[0], f"jaxeac-compile-{i}")

    shared = _persistent_cache_shared(groups[0][0].platform)
    others = [] if shared else [later(i) for i in range(1, len(groups))]
    program, seconds = compile(0)
    if shared:
        others = [later(i) for i in range(1, len(groups))]
    first: Future = Future()
    first.set_result(program)
    return [first, *others], seconds


def _plan(env: Env, cfg: RunConfig, n: int, chunk_size: int | None, devices) -> tuple[list, int]:
    """(devices, chunk size actually run) for n entries: `auto_chunk_size` when None, then
    `even_chunk` over the devices (all local devices by default). A chunk is split over the
    device groups (`device_groups`), each group running its share as a chunk of its own."""
    devices = list(devices) if devices is not None else jax.local_devices()
    if chunk_size is None:
        chunk_size = auto_chunk_size(env, cfg, n, devices)
    return devices, even_chunk(n, chunk_size, len(devices))


class _Entries:
    """One program's entries (seed i, hyper i), compiled for each device group and cut into
    chunks, each run whole by one group (`run_entries`)."""

    def __init__(self, env: Env, cfg: RunConfig, *, root_key: int, seeds: np.ndarray, hyper: Hyper,
                 chunk_size: int | None, devices, collector: Collector | None, name: str = ""):
        n = int(seeds.size)
        if n < 1:
            raise UsageError("seeds is empty; pass at least one seed index")
        self.devices, self.chunk_size = _plan(env, cfg, n, chunk_size, devices)
        self.groups = device_groups(self.devices)
        # a group's chunk: its devices' share of a chunk (every group has as many devices)
        self.piece = self.chunk_size // len(self.devices) * len(self.groups[0])
        self.n, self.seeds, self.name = n, seeds, name
        root = jax.random.key(root_key)
        self.hyper = jax.tree.map(lambda x: np.broadcast_to(np.asarray(x), (n,)), hyper)
        _, seeds0, hyper0 = self.chunk_inputs(0)
        tables = program_inputs(env)
        self.programs, self.compile_seconds = _compile_groups(env, cfg, self.groups, root, seeds0, hyper0,
                                                              tables, name)
        self.fixed = [_placed(g, root, tables) for g in self.groups]  # each group's root key and tables
        self.collector = collector if collector is not None else HostArrays(n, cfg.trials, env.n_states)
        self.measured = getattr(self.collector, "measures_on_device", False)  # `device_measures`
        self.n_states = env.n_states  # a padded tabular layout's extra states are dropped (`collect`)
        self.first_dispatch = self.last_collect = self.started_after = 0.0

    def chunk_inputs(self, start: int):
        stop = min(start + self.piece, self.n)
        take = np.pad(np.arange(start, stop), (0, self.piece - (stop - start)), mode="edge")
        return stop - start, self.seeds[take].astype(np.int32), jax.tree.map(lambda x: x[take], self.hyper)

    def starts(self) -> range:
        return range(0, self.n, self.piece)

    def program_pending(self, group: int) -> Future | None:
        """The future of group `group`'s program while it is still compiling or loading, else None."""
        program = self.programs[group]
        return None if program.done() else program

    def dispatch(self, start: int, group: int):
        """Start chunk `start` on device group `group`; returns (its size, its output on the device)."""
        t0 = time.perf_counter()
        size, chunk_seeds, chunk_hyper = self.chunk_inputs(start)
        t1 = time.perf_counter()
        chunk_seeds, chunk_hyper = _placed(self.groups[group], chunk_seeds, chunk_hyper)
        t2 = time.perf_counter()
        root, tables = self.fixed[group]
        out = self.programs[group].result()(root, chunk_seeds, chunk_hyper, tables)
        if self.measured:
            # The measures come back, and the logs and policies of the kept rows only, not the whole
            # chunk's (a study's 100,000-seed chunk: 57 MB an algorithm, 8 algorithms, 4 tasks at once).
            kept = min(self.collector.keeps_rows(start), size)
            out = out.replace(log=out.log[:kept] if kept else None, policy=out.policy[:kept] if kept else None,
                              measures=_measure(out.log))
        t3 = time.perf_counter()
        for leaf in jax.tree.leaves(out):
            leaf.copy_to_host_async()  # the copy back starts as soon as the chunk is done
        record({"event": "dispatch", "job": self.name, "start": start, "group": group, "inputs_s": t1 - t0,
                "put_s": t2 - t1, "launch_s": t3 - t2, "copy_s": time.perf_counter() - t3})
        return size, out

    @staticmethod
    def ready(out: BatchOutput) -> None:
        jax.block_until_ready(out)

    @staticmethod
    def fetch(size: int, out: BatchOutput) -> BatchOutput:
        """The chunk's output on the host, padding dropped."""
        return jax.tree.map(lambda x: np.asarray(x)[:size], out)

    def prepare(self, start: int, host: BatchOutput, pool: ThreadPoolExecutor) -> BatchOutput:
        """The chunk's own rows (unpacked, measured: `Collector.prepare`), on its device's thread."""
        if host.policy is not None and host.policy.shape[1] != self.n_states:  # padded (`program_inputs`)
            host = host.replace(policy=host.policy[:, :self.n_states])
        if (prepare := getattr(self.collector, "prepare", None)) is not None:
            prepare(start, host, pool)
        return host

    def collect(self, start: int, host: BatchOutput, pool: ThreadPoolExecutor) -> None:
        """The chunk to the collector in seed order (after `prepare`)."""
        self.collector.add(start, host, pool)

    @property
    def run_seconds(self) -> float:
        """From its first dispatch (or the previous job's last result, if later: the pipeline
        overlaps jobs) to its last result, so the jobs' times add up to the wall time."""
        return self.last_collect - max(self.first_dispatch, self.started_after)


#: Per platform, whether the programs of a pipeline compile side by side (`_prepare_all`). On CPUs
#: they compile one at a time, in order, each while the ones before it run: there compiles and runs
#: share the same cores. Eight algorithms on stochastic Four Rooms, 10,000 seeds, 2-core CPU: peak
#: memory 1.59 GiB against 1.76 GiB side by side, time within this machine's spread (93 s against
#: 89 s on a first run, 74 s against 82 s cached).
COMPILES_SIDE_BY_SIDE = {"gpu": True, "tpu": True}


def _prepare_all(make: Callable[[int], _Entries], count: int, progress, platform: str,
                 on_drained: Callable[[], None] | None = None) -> list[_Entries]:
    """`make(i)` for every job on threads (XLA compiles with the GIL released): side by side on
    accelerators, one at a time on CPUs (`COMPILES_SIDE_BY_SIDE`), each job's chunks starting as
    soon as its program is ready (`_run_chunks`). Returns the jobs, run."""
    pool = ThreadPoolExecutor(max_workers=count if COMPILES_SIDE_BY_SIDE.get(platform, False) else 1)
    try:
        return run_chunks([pool.submit(make, i) for i in range(count)], progress, on_drained)
    finally:  # on Ctrl-C or an error, do not wait for the other compiles to end
        pool.shutdown(wait=False, cancel_futures=True)


def run_entries(
    env: Env,
    cfg: RunConfig,
    *,
    root_key: int,
    seeds: np.ndarray,
    hyper: Hyper,
    chunk_size: int | None = None,
    devices: Sequence[jax.Device] | None = None,
    progress: Callable[[int], None] | None = None,
    collector: Collector | None = None,
) -> tuple[SeedResult, float, float]:
    """Run entries (seed i, hyper i) in fixed-size chunks: one compile, bounded memory.

    `hyper` leaves have one value per entry, so a hyperparameter sweep shares one
    compiled program. `chunk_size` None: `auto_chunk_size` for the devices.
    Chunks are split over `devices` (all local devices by default) as `device_groups`,
    each group running its share as a chunk of its own at its own pace; the chunk size is
    rounded up to a multiple of their number, and a group's last chunk is padded with copies of its final entry whose results are dropped. Each chunk's results
    go, in seed order, to `collector` (default `HostArrays`: every record in host arrays).
    Returns (the collector's result, seconds the program's compile took, run seconds).
    """
    check_run_args(env, cfg, hyper)
    if hyper is None:
        raise TypeError("hyper must be a Hyper with one value per entry (or one for all), e.g. cfg.hyper()")
    root_key, seeds = root_key_int(root_key), _check_seeds(seeds)
    _check_chunk(chunk_size)
    job = _Entries(env, cfg, root_key=root_key, seeds=seeds, hyper=hyper, chunk_size=chunk_size,
                   devices=devices, collector=collector)
    run_chunks([job], progress)
    return job.collector.result(), job.compile_seconds, job.run_seconds


def run_algorithms(
    env: Env,
    cfgs: Sequence[RunConfig],
    *,
    root_key: int,
    n_seeds: int,
    first_seed: int = 0,
    chunk_size: int | None = None,
    devices: Sequence[jax.Device] | None = None,
    progress: Callable[[int], None] | None = None,
    collectors: Sequence[Collector | None] | None = None,
    hypers: Sequence[Hyper | None] | None = None,
    on_drained: Callable[[], None] | None = None,
) -> list[SeedsResult | CompactSeeds]:
    """Seeds first_seed … first_seed+N−1 of each config in `cfgs` (one per algorithm), as one
    pipeline: each program's chunks start as soon as it has compiled (`_prepare_all`), and a
    device takes the next algorithm's chunks once the last one's are handed out. Results as
    `run_seeds` gives them, one per config (`collectors[i]` takes config i's chunks, None: host
    arrays; `hypers[i]` its rates, None: the config's own). `on_drained()`: called once, on a thread
    of its own, when every chunk has been handed out to a device (their queue holds no more work)."""
    cfgs = _check_configs(env, cfgs)
    root_key = root_key_int(root_key)
    n_seeds = check_int("n_seeds", n_seeds, high=KEY_LIMIT, fix="pass how many seeds to run, e.g. 100")
    first_seed = check_int("first_seed", first_seed, low=0, high=KEY_LIMIT - 1,
                           fix="pass the first seed index, e.g. 0")
    if first_seed + n_seeds > KEY_LIMIT:
        raise UsageError(f"first_seed + n_seeds must be at most 2^32 = {KEY_LIMIT} (got {first_seed} + "
                         f"{n_seeds}): seed i's key is fold_in(root, i), which keeps 32 bits; pass fewer "
                         "seeds or a lower first_seed")
    _check_chunk(chunk_size)
    for name, per_cfg in (("collectors", collectors), ("hypers", hypers)):
        if per_cfg is not None and len(per_cfg) != len(cfgs):
            raise UsageError(f"{name} must have one entry per config ({len(cfgs)}), got {len(per_cfg)}")
    for cfg, hyper in zip(cfgs, hypers or [None] * len(cfgs), strict=True):
        check_run_args(env, cfg, hyper)
    seeds = np.arange(first_seed, first_seed + n_seeds, dtype=np.int64)
    collectors = list(collectors) if collectors is not None else [None] * len(cfgs)
    hypers = list(hypers) if hypers is not None else [None] * len(cfgs)
    devices = list(devices) if devices is not None else jax.local_devices()

    def make(i: int) -> _Entries:
        hyper = cfgs[i].hyper() if hypers[i] is None else hypers[i]
        return _Entries(env, cfgs[i], root_key=root_key, seeds=seeds, hyper=hyper,
                        chunk_size=chunk_size, devices=devices, collector=collectors[i], name=str(i))

    jobs = _prepare_all(make, len(cfgs), progress, devices[0].platform, on_drained)
    results = []
    for cfg, job in zip(cfgs, jobs, strict=True):
        resolved = cfg.resolve(env, job.chunk_size // len(job.devices), job.devices[0].platform)
        settings = {**resolved.describe(), "chunk_size": int(job.chunk_size), "devices": len(job.devices),
                    "backend": job.devices[0].platform}
        out = job.collector.result()
        if isinstance(out, CompactSeeds):
            out.compile_seconds, out.run_seconds = job.compile_seconds, job.run_seconds
            out.settings = settings
            results.append(out)
            continue
        results.append(SeedsResult(seeds=seeds, success=out.success, steps=out.steps, policy=out.policy,
                                   compile_seconds=job.compile_seconds, run_seconds=job.run_seconds,
                                   settings=settings, finite=out.finite))
    return results


def run_seeds(
    env: Env,
    cfg: RunConfig,
    *,
    root_key: int,
    n_seeds: int,
    first_seed: int = 0,
    chunk_size: int | None = None,
    hyper: Hyper | None = None,
    devices: Sequence[jax.Device] | None = None,
    progress: Callable[[int], None] | None = None,
    collector: Collector | None = None,
) -> SeedsResult | CompactSeeds:
    """Run seeds first_seed … first_seed+N−1 of one algorithm (see `run_entries`); the result
    records the chunk size and the resolved config (`RunConfig.resolve`) the run used.

    With a `collector` that keeps `CompactSeeds` (`CompactCollector`), the result is those,
    with the timings and settings filled in."""
    return run_algorithms(env, [cfg], root_key=root_key, n_seeds=n_seeds, first_seed=first_seed,
                          chunk_size=chunk_size, devices=devices, progress=progress,
                          collectors=[collector], hypers=[hyper])[0]
