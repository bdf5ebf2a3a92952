"""Chunks through the devices: each device group's worker takes the next chunk from one shared
queue and keeps `CHUNKS_IN_FLIGHT` dispatched, so every device computes at its own pace, while
the calling thread collects the chunks in seed order (`run_chunks`); `record_timeline` logs when
each chunk was dispatched, ready, copied back and collected. A job is duck-typed: `starts()`,
`dispatch`, `ready`, `fetch`, `collect` and its timing fields (`jaxeac.running.batch._Entries`).
"""

from __future__ import annotations

import collections
import contextlib
import os
import threading
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import Executor, Future, ThreadPoolExecutor

import jax

from jaxeac.runtime import trim_host_memory

#: Per platform, whether each device runs its own program on its own share of chunks
#: (`device_groups`) rather than one program spanning every device with `shard_map`. On GPUs,
#: one program per device fed from a shared queue of chunks (`run_chunks`) keeps a device from
#: waiting on another or on the host. On CPUs the devices are the host's cores: one program over
#: all of them, compiled once (an XLA:CPU program per core would compile once per core).
DEVICES_APART = {"gpu": True, "tpu": True}


def device_groups(devices: Sequence[jax.Device], platform: str | None = None) -> list[tuple]:
    """The devices as groups that each run one program: a group per device where the platform
    runs its devices apart (`DEVICES_APART`), else one group of them all."""
    devices = tuple(devices)
    platform = platform or devices[0].platform
    return [(d,) for d in devices] if DEVICES_APART.get(platform, False) else [devices]


#: Chunks a device holds dispatched and not yet collected, per program: with two, the next
#: chunk is queued on the device while the host collects the one before.
CHUNKS_IN_FLIGHT = 2

_TIMELINE: list | None = None  # `record_timeline`'s events, or None
_TIMELINE_LOCK = threading.Lock()


@contextlib.contextmanager
def record_timeline() -> Iterator[list[dict]]:
    """Within the block, every run records its compiles and, per chunk and device group, when it
    was dispatched, ready on the device, copied to the host and collected (`time.perf_counter`
    seconds): the list of these events (dicts, `scripts/scale.py --timeline` reads them)."""
    global _TIMELINE
    events: list[dict] = []
    _TIMELINE = events
    try:
        yield events
    finally:
        _TIMELINE = None


def record(event: dict) -> None:
    if _TIMELINE is not None:
        with _TIMELINE_LOCK:
            _TIMELINE.append(event)


class _Queue:
    """Every chunk of every job, in order, handed out one at a time to the device groups. A job
    may be a future of one still compiling: taking its first chunk waits for it."""

    def __init__(self, jobs: Sequence, on_drained=None):
        self.lock = threading.Lock()
        self.on_drained = on_drained  # called once, when the last chunk has been handed out
        self.jobs, self.done = collections.deque(jobs), []
        self.starts: collections.deque = collections.deque()
        self.taken = 0
        self.total: int | None = None  # chunks in all, once the last one is handed out

    def blocks(self, group: int = 0) -> bool:
        """Whether taking the next chunk would wait: for a compile, or for group `group`'s own
        program of the next job (`_pending`)."""
        with self.lock:
            if self.starts:
                return _pending(self.done[-1], group) is not None
            if not self.jobs:
                return False
            job = self.jobs[0]
            if isinstance(job, Future):
                if not job.done() or job.exception() is not None:
                    return not job.done()
                job = job.result()
            return _pending(job, group) is not None

    def take(self, group: int = 0):
        """(sequence number, job, start) of the next chunk; None when none is left; or the future
        of group `group`'s program of the next job while it is not in yet (nothing is taken)."""
        with self.lock:
            while not self.starts:
                if not self.jobs:
                    if self.total is None and self.on_drained is not None:
                        threading.Thread(target=self.on_drained, daemon=True, name="jaxeac-drained").start()
                    self.total = self.taken
                    return None
                item = self.jobs[0]
                job = item.result() if isinstance(item, Future) else item
                self.jobs.popleft()
                self.done.append(job)
                self.starts.extend(job.starts())
            job = self.done[-1]
            if (pending := _pending(job, group)) is not None:
                return pending
            self.taken += 1
            return self.taken - 1, job, self.starts.popleft()


def _pending(job, group: int) -> Future | None:
    """The future of `job`'s program for device group `group` while it is still compiling or
    loading (the first group's is in before the job's chunks start: the others join as theirs
    come in), else None."""
    pending = getattr(job, "program_pending", None)
    return pending(group) if pending is not None else None


class _Pipeline:
    """The device groups' workers and the collecting thread's hand-over (`run_chunks`)."""

    def __init__(self, jobs: Sequence, n_groups: int, pool: Executor, on_drained=None):
        self.queue = _Queue(jobs, on_drained)
        self.pool = pool  # threads for work that frees the GIL (`prepare`), shared by the workers
        self.cond = threading.Condition()
        self.ready: dict[int, tuple] = {}  # sequence number -> (job, start, group, size, host output, times)
        self.error: BaseException | None = None
        self.stop = False
        self.room = [threading.Semaphore(CHUNKS_IN_FLIGHT + 1) for _ in range(n_groups)]

    def work(self, group: int) -> None:
        """Group `group`'s worker: take chunks, keep `CHUNKS_IN_FLIGHT` of them dispatched, and
        hand each, copied to the host and prepared (`prepare`: its own rows unpacked or measured,
        here, beside the other devices' workers), to the collecting thread; at most
        `CHUNKS_IN_FLIGHT` + 1 dispatched and not yet collected (host memory stays bounded when
        the host is behind). A group whose program is still loading finishes its chunks in flight
        and waits for it while the others take chunks."""
        flight: collections.deque = collections.deque()
        try:
            while not self.stop:
                if flight and (len(flight) >= CHUNKS_IN_FLIGHT or self.queue.blocks(group)):
                    self.finish(flight.popleft())  # the device is busy; nothing waits on a compile
                    continue
                if not self.room[group].acquire(blocking=False):  # the host is behind: hand over
                    while flight:  # everything held, so the collector can move on
                        self.finish(flight.popleft())
                    self.room[group].acquire()
                item = self.queue.take(group)
                if item is None:
                    self.room[group].release()
                    break
                if isinstance(item, Future):  # this group's program is not in yet
                    self.room[group].release()
                    while flight:
                        self.finish(flight.popleft())
                    item.result()
                    continue
                seq, job, start = item
                t = time.perf_counter()
                size, out = job.dispatch(start, group)
                if job.first_dispatch == 0.0 or t < job.first_dispatch:
                    job.first_dispatch = t
                times = {"dispatch": t, "launched": time.perf_counter()}
                flight.append((seq, job, start, group, size, out, times))
            while flight and not self.stop:
                self.finish(flight.popleft())
        except BaseException as e:  # noqa: BLE001 (re-raised on the collecting thread)
            with self.cond:
                self.error = self.error or e
                self.cond.notify_all()
        finally:
            with self.cond:
                self.cond.notify_all()

    def finish(self, item) -> None:
        seq, job, start, group, size, out, times = item
        job.ready(out)
        times["ready"] = time.perf_counter()
        host = job.fetch(size, out)
        times["fetched"] = time.perf_counter()
        if (prepare := getattr(job, "prepare", None)) is not None:
            host = prepare(start, host, self.pool)
        times["prepared"] = time.perf_counter()
        with self.cond:
            self.ready[seq] = (job, start, group, size, host, times)
            self.cond.notify_all()

    def next_ready(self, seq: int):
        """Chunk `seq` once a worker has it on the host, or None after the last one."""
        with self.cond:
            while seq not in self.ready and self.error is None:
                if self.queue.total is not None and seq >= self.queue.total:
                    return None
                self.cond.wait()
            if self.error is not None:
                raise self.error
            return self.ready.pop(seq)


def run_chunks(jobs: Sequence, progress, on_drained=None) -> list:
    """Every chunk of every job, each run whole by one device group: each group's worker takes
    the next chunk from a shared queue and keeps `CHUNKS_IN_FLIGHT` dispatched, so every device
    computes at its own pace; this thread collects the chunks, in seed order, as they come back.
    A job may be a future of one still compiling (`_prepare_all`): the jobs before it run
    meanwhile, and chunks in flight come back while it compiles. `on_drained()` is called once,
    on a thread of its own, as soon as every chunk is handed out (the devices have their last
    work). Returns the jobs."""
    first = next((j for j in jobs if not isinstance(j, Future)), None) or jobs[0].result()
    n_groups = len(first.groups)
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        pipe = _Pipeline(jobs, n_groups, pool, on_drained)
        workers = [threading.Thread(target=pipe.work, args=(g,), daemon=True, name=f"jaxeac-device-{g}")
                   for g in range(n_groups)]
        for w in workers:
            w.start()
        try:
            seq = 0
            while (got := pipe.next_ready(seq)) is not None:
                job, start, group, size, host, times = got
                times["collect"] = time.perf_counter()
                job.collect(start, host, pool)
                del host  # the chunk's host arrays go before the next one is waited for
                job.last_collect = time.perf_counter()
                pipe.room[group].release()
                record({"event": "chunk", "job": job.name, "start": start, "size": size, "group": group,
                        **times, "collected": job.last_collect})
                if progress is not None:
                    progress(size)
                seq += 1
        finally:
            pipe.stop = True
            for room in pipe.room:  # a worker waiting for room stops
                room.release()
        for w in workers:
            w.join()
    done = pipe.queue.done
    for before, job in zip(done[:-1], done[1:], strict=True):  # time starts where the last job ended
        job.started_after = before.last_collect
    trim_host_memory()
    return done
