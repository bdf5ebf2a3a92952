"""What a run returns: per-seed records (G7) in narrow integer types on the device, numpy on the host.

A compiled chunk returns `BatchOutput` (the signed trial log and the policy in the
narrowest integer types that hold them). What becomes of it on the host is a
`Collector`'s choice: `HostArrays` unpacks every chunk into preallocated `SeedResult`
arrays (`unpack_output`, the default), `CompactCollector` keeps only the per-seed
measures and the success curves as bits (`SuccessBits`, 1/8 of a bool matrix) and
hands each chunk on (to a file writer, say), so host memory stays bounded at 10^7 seeds;
its measures may be taken on the device (`device_measures`), and `ChunksBehind` runs the
writer on a thread of its own, behind the run.

(Over 400 lines: a chunk's way from the device to the host in each form a run keeps it, and
the writer behind it.)
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from typing import Protocol

import jax
import jax.numpy as jnp
import numpy as np

from jaxeac.bits import SuccessBits, as_bool, measures_of  # noqa: F401 (their home before jaxeac.bits)
from jaxeac.envs.protocol import chance_bound
from jaxeac.pytree import pytree_dataclass
from jaxeac.running.schedule import record


@pytree_dataclass
class SeedResult:
    """G7 per-seed record: success and steps per trial, and the final greedy policy."""

    success: jax.Array  # bool [T]
    steps: jax.Array  # int32 [T]
    policy: jax.Array  # int32 [S]
    finite: jax.Array | None = None  # bool []: every p(s, a) and V(s) finite at the end (no blow-up)


@pytree_dataclass
class BatchOutput:
    """What a compiled chunk returns, in the narrowest integer types that hold it.

    ``log`` is `AgentState.log` per seed (chances used per trial, negated if it failed;
    every trial takes ≥ 1 chance, so the sign is the outcome), ``policy`` the G7 policy.
    Narrow types make the device-to-host transfer, the largest cost after the compute
    on GPUs, 4–5× smaller; `unpack_output` restores `SeedResult` on the host.
    """

    log: jax.Array | None  # int8/16/32 [M, T]
    policy: jax.Array | None  # int8/16/32 [M, S]
    finite: jax.Array | None = None  # bool [M]: the seed's tables stayed finite
    #: `device_measures` of the log, where the collector takes them from the device (the log and
    #: policy then come back only for the chunks that keep rows of them: `measures_on_device`)
    measures: dict | None = None

    @property
    def rows(self) -> int:
        """Seeds in the chunk (with measures, its log and policy may hold only its first rows)."""
        return (self.measures["bits"] if self.measures is not None else self.log).shape[0]


def narrow_int(largest: int) -> np.dtype:
    """The smallest signed integer type holding −largest … largest."""
    for dtype in (np.int8, np.int16):
        if largest <= np.iinfo(dtype).max:
            return np.dtype(dtype)
    return np.dtype(np.int32)


def pack_output(env, log: jax.Array, policy: jax.Array, finite: jax.Array | None = None) -> BatchOutput:
    """A chunk's logs and policies in `narrow_int` types (exact: |log| ≤ C, policy < A)."""
    return BatchOutput(log.astype(narrow_int(chance_bound(env))), policy.astype(narrow_int(env.n_actions)),
                       finite)


def device_measures(log: jax.Array) -> dict:
    """A chunk's per-seed measures (`jaxeac.bits.measures_of`'s, exactly) from its trial logs
    [M, T], on the device that ran it: ~30 bytes a seed come back instead of the T-byte log, and
    the host only copies them into place."""
    success = log > 0
    m, t = success.shape
    padded = jnp.pad(success, ((0, 0), (0, -t % 8))).reshape(m, -1, 8).astype(jnp.uint8)
    bits = (padded << jnp.arange(8, dtype=jnp.uint8)).sum(axis=2, dtype=jnp.uint8)  # low bit first
    return {"bits": bits, "successes": success.sum(axis=1, dtype=jnp.int32),
            "first_success": jnp.where(success.any(axis=1),
                                       jnp.argmax(success, axis=1).astype(jnp.int32) + 1, -1),
            "steps_total": jnp.abs(log.astype(jnp.int32)).sum(axis=1)}


def empty_results(n: int, n_trials: int, n_states: int) -> SeedResult:
    """Host arrays for `n` seeds' results, filled chunk by chunk by `unpack_output`."""
    return SeedResult(success=np.empty((n, n_trials), bool), steps=np.empty((n, n_trials), np.int32),
                      policy=np.empty((n, n_states), np.int32), finite=np.ones(n, bool))


def unpack_output(out: BatchOutput, into: SeedResult | None = None, start: int = 0) -> SeedResult:
    """Host side of `pack_output`: success bool, steps and policy int32 (numpy arrays).

    With `into`, rows ``start …`` of its arrays are written in place (no temporaries, no
    concatenation of chunks: at 10^6 seeds per chunk that host work decides how fast
    several GPUs can go) and `into` is returned.
    """
    log, policy = np.asarray(out.log), np.asarray(out.policy)
    if into is None:
        into = empty_results(*log.shape, policy.shape[1])
        start = 0
    rows = slice(start, start + log.shape[0])
    np.greater(log, 0, out=into.success[rows])
    np.abs(log, out=into.steps[rows])
    into.policy[rows] = policy
    if out.finite is not None:
        into.finite[rows] = np.asarray(out.finite)
    return into


@dataclasses.dataclass
class SeedsResult:
    """Results of all seeds of one algorithm, as numpy arrays on the host."""

    seeds: np.ndarray  # int64 [N]
    success: np.ndarray  # bool [N, T]
    steps: np.ndarray  # int32 [N, T]
    policy: np.ndarray  # int32 [N, S]
    compile_seconds: float
    run_seconds: float
    settings: dict | None = None  # how it ran: the resolved `RunConfig`, chunk size, devices
    finite: np.ndarray | None = None  # bool [N]: False where a seed's p or V blew up to NaN/inf

    @property
    def non_finite_seeds(self) -> np.ndarray:
        """Seeds whose tables ended with a NaN or infinite value (numerical blow-up)."""
        return self.seeds[~self.finite] if self.finite is not None else self.seeds[:0]

    @property
    def successes(self) -> np.ndarray:
        return self.success.sum(axis=1)

    @property
    def first_success(self) -> np.ndarray:
        """1-based trial of the first success, −1 if none (G7)."""
        any_success = self.success.any(axis=1)
        return np.where(any_success, self.success.argmax(axis=1) + 1, -1)

    @property
    def steps_total(self) -> np.ndarray:
        """Agent-steps of each seed over all trials."""
        return self.steps.sum(axis=1, dtype=np.int64)

    @property
    def agent_steps(self) -> int:
        return int(self.steps.sum())

    def logs_of_first(self, n: int) -> np.ndarray:
        """int32 [n, T]: the trial logs (chances used, negated if failed) of the first n seeds."""
        return np.where(self.success[:n], self.steps[:n], -self.steps[:n])

    def policy_of(self, i: int) -> np.ndarray:
        """The final greedy policy of the run's i-th seed."""
        return self.policy[i]


#: Rows per host thread when unpacking a chunk's results (~20 bytes of temporaries per entry):
#: small blocks bound what the threads hold together.
UNPACK_ROWS = 1 << 13


def _row_blocks(size: int) -> list[slice]:
    return [slice(r, min(r + UNPACK_ROWS, size)) for r in range(0, size, UNPACK_ROWS)]


class Collector(Protocol):
    """Where a run's chunks go on the host (`jaxeac.running.run_entries`).

    `prepare` (optional) gets rows ``start …`` of the run as numpy `BatchOutput` (padding
    dropped) on the thread of the device that ran them, in any order and several chunks at
    once: work on the chunk's own rows (unpacking, per-seed measures) runs there, beside the
    other devices. `add` then gets every chunk once, in seed order, on the collecting thread
    (a file writer's work), and a thread pool for work that frees the GIL; `result` is what
    the run returns.
    """

    def add(self, start: int, chunk: BatchOutput, pool: Executor) -> None: ...

    def result(self): ...


def _rows_in_parallel(work: Callable[[slice], None], size: int, pool: Executor) -> None:
    """`work(rows)` for every `UNPACK_ROWS` block of a chunk's `size` rows, on `pool`."""
    list(pool.map(work, _row_blocks(size)))


class HostArrays:
    """The default collector: every seed's G7 record in host arrays (`SeedResult`), each chunk
    unpacked into its rows on its device's thread (`prepare`)."""

    def __init__(self, n: int, n_trials: int, n_states: int):
        self.whole = empty_results(n, n_trials, n_states)

    def prepare(self, start: int, chunk: BatchOutput, pool: Executor) -> None:
        def unpack_rows(rows: slice) -> None:  # numpy frees the GIL: rows in parallel
            unpack_output(jax.tree.map(lambda x: x[rows], chunk), self.whole, start + rows.start)

        _rows_in_parallel(unpack_rows, chunk.log.shape[0], pool)

    def add(self, start: int, chunk: BatchOutput, pool: Executor) -> None:
        """Nothing left to do in seed order: `prepare` wrote the chunk's rows."""

    def result(self) -> SeedResult:
        return self.whole


@dataclasses.dataclass
class CompactSeeds:
    """One algorithm's per-seed measures and success curves (bits), without the per-trial
    steps and policies that take most of the bytes: what a streamed run keeps on the host.

    The properties match `SeedsResult`'s, so summaries, figures and statistics take either.
    """

    seeds: np.ndarray  # int64 [N]
    success: SuccessBits
    successes: np.ndarray  # int [N] (`narrow_int` of T)
    first_success: np.ndarray  # int [N] (`narrow_int` of T), 1-based, −1 if none
    steps_total: np.ndarray  # int [N] (`narrow_int` of T × C; int64 if C is not given): agent-steps
    finite: np.ndarray  # bool [N]
    first_policies: np.ndarray  # int32 [k, S]: the policies of the first k seeds (for figures)
    compile_seconds: float = 0.0
    run_seconds: float = 0.0
    settings: dict | None = None
    first_logs: np.ndarray | None = None  # int [k, T]: trial logs of the first k seeds (`KEEP_LOGS`)

    @property
    def non_finite_seeds(self) -> np.ndarray:
        return self.seeds[~self.finite]

    @property
    def agent_steps(self) -> int:
        return int(self.steps_total.sum())

    def policy_of(self, i: int) -> np.ndarray:
        """The final greedy policy of the run's i-th seed (one of the first k)."""
        return self.first_policies[i]

    def logs_of_first(self, n: int) -> np.ndarray | None:
        """int [n, T]: the trial logs (chances used, negated if failed) of the first n seeds, or
        None where the run kept fewer."""
        if self.first_logs is None or self.first_logs.shape[0] < n:
            return None
        return self.first_logs[:n]

    @classmethod
    def concatenate(cls, parts: list[CompactSeeds]) -> CompactSeeds:
        """Consecutive batches of one algorithm's seeds as one run (a sequential run's batches:
        one program, compiled once, so the compile seconds are the first batch's)."""
        first = parts[0]
        cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
        return cls(seeds=cat("seeds"),
                   success=SuccessBits(np.concatenate([p.success.bits for p in parts]), first.success.trials),
                   successes=cat("successes"), first_success=cat("first_success"),
                   steps_total=cat("steps_total"), finite=cat("finite"),
                   first_policies=np.concatenate([p.first_policies for p in parts])[:KEEP_POLICIES],
                   first_logs=(None if any(p.first_logs is None for p in parts)
                               else np.concatenate([p.first_logs for p in parts])[:KEEP_LOGS]),
                   compile_seconds=first.compile_seconds, run_seconds=sum(p.run_seconds for p in parts),
                   settings=first.settings)


KEEP_POLICIES = 16  # policies of the first seeds a compact run keeps, for figures
#: Trial logs of the first seeds a compact run keeps: E8's counts of an algorithm without memories
#: follow from them (`jaxeac.running.diagnostics.diagnostics_from_logs`), and E8 diagnoses at most
#: this many seeds (`jaxeac.running.diagnostics.DIAGNOSTIC_SEEDS`; 0.4 MB at T = 200).
KEEP_LOGS = 1000


class CompactCollector:
    """Keeps `CompactSeeds` of `n` seeds and passes every chunk, with its per-seed measures,
    to `on_chunk(start, chunk, measures)` (a file writer, say) before dropping it.

    ``measures`` holds numpy arrays of the chunk's rows: ``bits`` (uint8 [M, ⌈T/8⌉]),
    ``successes``, ``first_success``, ``steps_total``, ``finite``. The per-seed counts are
    kept in the narrowest types that hold them (given the chances per trial, `n_chances`, the
    steps too): a few bytes a seed beside the 25 of the bits at T = 200.
    """

    def __init__(self, seeds: np.ndarray, n_trials: int, n_states: int,
                 on_chunk: Callable[[int, BatchOutput, dict], None] | None = None, *,
                 n_chances: int | None = None, whole_chunks: bool = True):
        n = seeds.shape[0]
        counts = narrow_int(n_trials)
        self.out = CompactSeeds(
            seeds=seeds, success=SuccessBits(np.empty((n, -(-n_trials // 8)), np.uint8), n_trials),
            successes=np.empty(n, counts), first_success=np.empty(n, counts),
            steps_total=np.empty(n, np.int64 if n_chances is None else narrow_int(n_trials * n_chances)),
            finite=np.ones(n, bool),
            first_policies=np.zeros((min(n, KEEP_POLICIES), n_states), np.int32),
            first_logs=np.zeros((min(n, KEEP_LOGS), n_trials),
                                np.int32 if n_chances is None else narrow_int(n_chances)),
        )
        self.on_chunk = on_chunk
        #: Whether the measures are taken on the device (`device_measures`): where `on_chunk`
        #: reads no chunk's logs or policies (`whole_chunks` False), only the chunks that keep
        #: rows of them (`keeps_rows`) bring them back.
        self.measures_on_device = not whole_chunks

    def keeps_rows(self, start: int) -> int:
        """How many of the first rows of the chunk from row `start` have their logs or policies
        kept (0: none; a chunk's measures come from the device, these rows only come back)."""
        return max(0, max(self.out.first_policies.shape[0], self.out.first_logs.shape[0]) - start)

    def prepare(self, start: int, chunk: BatchOutput, pool: Executor) -> None:
        """The chunk's per-seed measures, into its own rows (any order, any thread)."""
        o = self.out

        def measures(rows: slice) -> None:
            log = chunk.log[rows]
            at = slice(start + rows.start, start + rows.stop)
            m = measures_of(log > 0, np.abs(log))
            o.success.bits[at], o.successes[at] = m["bits"], m["successes"]
            o.first_success[at], o.steps_total[at] = m["first_success"], m["steps_total"]

        m = chunk.rows
        if chunk.measures is not None:  # measured on the device: into place
            at = slice(start, start + m)
            for name in ("successes", "first_success", "steps_total"):
                getattr(o, name)[at] = chunk.measures[name]
            o.success.bits[at] = chunk.measures["bits"]
        else:
            _rows_in_parallel(measures, m, pool)
        if chunk.finite is not None:
            o.finite[start:start + m] = chunk.finite
        if chunk.policy is not None:
            keep = max(0, min(m, o.first_policies.shape[0] - start))
            o.first_policies[start:start + keep] = chunk.policy[:keep]
        if chunk.log is not None:
            keep = max(0, min(m, o.first_logs.shape[0] - start))
            o.first_logs[start:start + keep] = chunk.log[:keep]

    def add(self, start: int, chunk: BatchOutput, pool: Executor) -> None:
        """The chunk, with its measures (`prepare`), to `on_chunk`, in seed order."""
        if self.on_chunk is not None:
            o, at = self.out, slice(start, start + chunk.rows)
            self.on_chunk(start, chunk, {"bits": o.success.bits[at], "successes": o.successes[at],
                                         "first_success": o.first_success[at],
                                         "steps_total": o.steps_total[at], "finite": o.finite[at]})

    def result(self) -> CompactSeeds:
        return self.out


class ChunksBehind:
    """`CompactCollector` ``on_chunk`` calls (a results file's writer, say) on a thread of their
    own, in the order the chunks come, while the run goes on: the run's results are in memory
    as soon as its last chunk is measured, and the file is written behind it (beside the
    figures and statistics). One `ChunksBehind` serves every algorithm of a run, so their rows
    reach the file in the run's order.

    A chunk handed over keeps only what the writer reads: its trial logs where `keep_log`, its
    policies where `keep_policy` (then at most `AT_MOST` chunks wait, so host memory stays
    bounded); the measures are rows of the collector's own arrays. `finish` waits for every
    chunk and raises the first error; leaving a ``with`` block on an error drops the chunks not
    yet started and waits for the one being written.
    """

    AT_MOST = 4  # chunks handed over and not yet written, where they keep their logs or policies

    def __init__(self, *, keep_log: bool, keep_policy: bool):
        self.keep_log, self.keep_policy = keep_log, keep_policy
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxeac-writer")
        self.room = threading.Semaphore(self.AT_MOST) if keep_log or keep_policy else None
        self.futures: list[Future] = []
        self.seconds = 0.0  # spent in the calls, on the writer's thread

    def of(self, on_chunk: Callable[[int, BatchOutput, dict], None]) -> Callable:
        """`on_chunk`, called behind the run."""
        def handed(start: int, chunk: BatchOutput, measures: dict) -> None:
            for done in self.futures[-2:]:  # a failed write stops the run at the next chunk
                if done.done() and done.exception() is not None:
                    raise done.exception()
            chunk = chunk.replace(log=chunk.log if self.keep_log else None,
                                  policy=chunk.policy if self.keep_policy else None)
            if self.room is not None:
                self.room.acquire()
            self.futures.append(self.pool.submit(self._call, on_chunk, start, chunk, measures))
        return handed

    def _call(self, on_chunk, start: int, chunk: BatchOutput, measures: dict) -> None:
        try:
            t0 = time.perf_counter()
            on_chunk(start, chunk, measures)
            t1 = time.perf_counter()
            self.seconds += t1 - t0
            record({"event": "write", "start": start, "size": len(measures["bits"]), "begin": t0, "end": t1})
        finally:
            if self.room is not None:
                self.room.release()

    def finish(self) -> None:
        """Wait for every chunk handed over; raises the first error of their calls."""
        try:
            for future in self.futures:
                future.result()
        finally:
            self.pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> ChunksBehind:
        return self

    def __exit__(self, *exc) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)
