"""Many seeds of one algorithm: chunks, devices, one compile, results back on the host.

`run_entries` runs entries (seed i, hyper i) in fixed-size chunks through one
compiled program (`make_batch_run`), split over the local devices with `shard_map`
(seeds are independent, R1), and copies each chunk back while the next computes.
Seed i uses ``fold_in(root_key, i)`` (R1), so results never depend on the chunk size,
the device count or the seeds beside it, and reruns are bit-identical (R2).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor

import jax
import numpy as np
from jax.sharding import Mesh, PartitionSpec

from jaxeac.algorithm.config import Hyper
from jaxeac.errors import UsageError
from jaxeac.rng import seed_key, seed_words
from jaxeac.running.config import RunConfig, auto_chunk_size
from jaxeac.running.loops import Env, flat_batch, trials_batch
from jaxeac.running.outputs import BatchOutput, Collector, CompactSeeds, HostArrays, SeedResult, SeedsResult

SEEDS_AXIS = "seeds"


def seed_mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A 1-D device mesh whose only axis, ``seeds``, the seed batch is split over."""
    return Mesh(np.array(list(devices) if devices is not None else jax.devices()), (SEEDS_AXIS,))


def make_batch_run(env: Env, cfg: RunConfig, mesh: Mesh | None = None) -> Callable:
    """jit over a chunk: ``(root_key, seeds [M], hyper with leaves [M]) -> BatchOutput [M, ...]``.

    With a `mesh`, the chunk is split over its ``seeds`` axis with `shard_map`: each
    device runs its own seeds with no communication (seeds are independent, R1).
    """
    cfg = cfg.resolve(env)

    def batch(root_key: jax.Array, seeds: jax.Array, hyper: Hyper) -> BatchOutput:
        keys = jax.vmap(seed_key, in_axes=(None, 0))(root_key, seeds)
        if cfg.loop == "trials":
            return trials_batch(env, cfg, keys, hyper)
        return flat_batch(env, cfg, jax.vmap(seed_words)(keys), hyper)

    if mesh is not None:
        split = PartitionSpec(SEEDS_AXIS)
        batch = jax.shard_map(batch, mesh=mesh, in_specs=(PartitionSpec(), split, split), out_specs=split,
                              check_vma=False)  # per-seed loops: no collectives to check
    return jax.jit(batch)


def chunks(n_seeds: int, chunk_size: int) -> Iterator[np.ndarray]:
    """Seed indices 0..N−1 in chunks of `chunk_size` (the last one may be short)."""
    for start in range(0, n_seeds, chunk_size):
        yield np.arange(start, min(start + chunk_size, n_seeds), dtype=np.int32)


def even_chunk(n: int, chunk_size: int, n_devices: int) -> int:
    """The chunk size actually run: N split evenly into ceil(N / chunk_size) chunks (no chunk is
    mostly padding), rounded up to a multiple of the device count."""
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, int | np.integer) or chunk_size < 1:
        raise UsageError(f"chunk size must be a positive integer (got {chunk_size!r})")
    n_chunks = -(-n // chunk_size)
    even = -(-n // n_chunks)
    return -(-even // n_devices) * n_devices


_COMPILED: dict = {}  # key -> Future of (compiled program, seconds its compile took)
_COMPILED_LOCK = threading.Lock()


def _compiled(env: Env, cfg: RunConfig, devices: tuple, root, seeds, hyper):
    """(compiled chunk program, compile seconds) for this env object, config, devices and chunk
    shape, compiled once: a second caller, on any thread, waits for the first (cached)."""
    cfg = cfg.resolve(env, seeds.shape[0] // len(devices))  # every `auto`, once, before tracing
    key = (env, cfg, devices, seeds.shape, jax.tree.map(lambda x: x.dtype, hyper))
    with _COMPILED_LOCK:
        future, mine = _COMPILED.get(key), False
        if future is None:
            if len(_COMPILED) >= 64:
                _COMPILED.clear()
            future, mine = _COMPILED.setdefault(key, Future()), True
    if mine:
        try:
            t0 = time.perf_counter()
            mesh = seed_mesh(devices) if len(devices) > 1 else None
            program = make_batch_run(env, cfg, mesh).lower(root, seeds, hyper).compile()
            future.set_result((program, time.perf_counter() - t0))
        except BaseException as exc:
            with _COMPILED_LOCK:
                _COMPILED.pop(key, None)  # a later call tries again
            future.set_exception(exc)
            raise
    return future.result()


def _plan(env: Env, cfg: RunConfig, n: int, chunk_size: int | None, devices) -> tuple[list, int]:
    """(devices, chunk size actually run) for n entries: `auto_chunk_size` when None, then
    `even_chunk` over the devices (all local devices by default)."""
    devices = list(devices) if devices is not None else jax.local_devices()
    if chunk_size is None:
        chunk_size = auto_chunk_size(env, cfg, n, devices)
    return devices, even_chunk(n, chunk_size, len(devices))


def compile_ahead(env: Env, cfg: RunConfig, *, n_seeds: int, chunk_size: int | None = None,
                  hyper: Hyper | None = None, devices: Sequence[jax.Device] | None = None) -> None:
    """Compile the program `run_seeds` with these arguments will run (XLA compiles with the GIL
    released, so several algorithms' programs compile side by side on threads, and while
    another one runs); `run_seeds` then finds it compiled."""
    devices, chunk_size = _plan(env, cfg, int(n_seeds), chunk_size, devices)
    hyper = cfg.hyper() if hyper is None else hyper
    hyper0 = jax.tree.map(lambda x: np.broadcast_to(np.asarray(x), (chunk_size,)), hyper)
    _compiled(env, cfg, tuple(devices), jax.random.key(0), np.zeros(chunk_size, np.int32), hyper0)


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
    Chunks are split over `devices` (all local devices by default);
    the chunk size is rounded up to a multiple of their number, and the last chunk is
    padded with copies of its final entry whose results are dropped. Each chunk's results
    go, in seed order, to `collector` (default `HostArrays`: every record in host arrays).
    Returns (the collector's result, compile seconds, run seconds).
    """
    n = int(seeds.size)
    if n < 1:
        raise UsageError(f"seeds must be a positive integer (got {n})")
    devices, chunk_size = _plan(env, cfg, n, chunk_size, devices)
    root = jax.random.key(root_key)
    hyper = jax.tree.map(lambda x: np.broadcast_to(np.asarray(x), (n,)), hyper)

    def chunk_inputs(start: int):
        stop = min(start + chunk_size, n)
        take = np.pad(np.arange(start, stop), (0, chunk_size - (stop - start)), mode="edge")
        return stop - start, seeds[take].astype(np.int32), jax.tree.map(lambda x: x[take], hyper)

    _, seeds0, hyper0 = chunk_inputs(0)
    compiled, compile_seconds = _compiled(env, cfg, tuple(devices), root, seeds0, hyper0)

    collector = collector if collector is not None else HostArrays(n, cfg.trials, env.n_states)

    def dispatch(start: int) -> tuple[int, int, BatchOutput]:
        size, chunk_seeds, chunk_hyper = chunk_inputs(start)
        out = compiled(root, chunk_seeds, chunk_hyper)
        for leaf in jax.tree.leaves(out):
            leaf.copy_to_host_async()  # the copy back starts as soon as the chunk is done
        return start, size, out

    def collect(start: int, size: int, out: BatchOutput, pool: ThreadPoolExecutor) -> None:
        host = jax.tree.map(lambda x: np.asarray(x)[:size], jax.device_get(out))  # padding dropped
        collector.add(start, host, pool)
        if progress is not None:
            progress(size)

    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        pending = None  # the chunk in flight: dispatch is asynchronous, so the next chunk
        for start in range(0, n, chunk_size):  # computes while this one's results come back
            running = dispatch(start)
            if pending is not None:
                collect(*pending, pool)
            pending = running
        collect(*pending, pool)
    run_seconds = time.perf_counter() - t0
    return collector.result(), compile_seconds, run_seconds


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
    if isinstance(n_seeds, bool) or not isinstance(n_seeds, int | np.integer) or n_seeds < 1:
        raise UsageError(f"seeds must be a positive integer (got {n_seeds})")
    seeds = np.arange(first_seed, first_seed + n_seeds, dtype=np.int64)
    devices, chunk_size = _plan(env, cfg, int(n_seeds), chunk_size, devices)
    resolved = cfg.resolve(env, chunk_size // len(devices), devices[0].platform)
    out, compile_seconds, run_seconds = run_entries(
        env, cfg, root_key=root_key, seeds=seeds, hyper=cfg.hyper() if hyper is None else hyper,
        chunk_size=chunk_size, devices=devices, progress=progress, collector=collector,
    )
    settings = {**resolved.describe(), "chunk_size": int(chunk_size), "devices": len(devices),
                "backend": devices[0].platform}
    if isinstance(out, CompactSeeds):
        out.compile_seconds, out.run_seconds, out.settings = compile_seconds, run_seconds, settings
        return out
    return SeedsResult(
        seeds=seeds,
        success=out.success,
        steps=out.steps,
        policy=out.policy,
        compile_seconds=compile_seconds,
        run_seconds=run_seconds,
        settings=settings,
        finite=out.finite,
    )
