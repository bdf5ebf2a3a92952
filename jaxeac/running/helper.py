"""Host work in a process of its own: a study's E8 diagnostics on the CPU beside its GPU runs, the
figures of a study and of a grid run on a GPU.

A study on a GPU counts E8's seeds again on the host's CPU (`jaxeac.experiments.study`). In the
study's own process, tracing and compiling those programs held the interpreter lock that the
runs' programs need, and running them took the cores: with E8 in a helper, `jaxeac study --seeds
1000` on one H100 took 20.7-20.8 s against 28.5-29.6 s (BENCHMARKS.md, `gpu_h100_study_builds.json`).

A `Helper` is a spawned process with JAX on the CPU alone (one host device, as E8's calls use
beside a GPU), at a lower scheduling priority (`NICE`), that runs jobs (a module-level function
and its arguments, pickled) on a few threads of its own, or on a lane of threads apart (jobs that
must not wait behind the others: `submit_to`), and hands back futures. It ignores
Ctrl-C (its parent handles it and ends the helper) and ends when its parent's end of the pipe
closes, so an interrupted or killed command leaves no process behind. `in_helper` runs a job there
and, if the helper has gone, here instead.
"""

from __future__ import annotations

import os
import pickle
import queue
import signal
import sys
import threading
from collections.abc import Callable
from concurrent.futures import Future
from contextlib import contextmanager, suppress

#: The helper's scheduling priority, above its parent's (lower priority): the parent's threads
#: (the runs' compiles and dispatch) come first on a busy host.
NICE = 10
#: Jobs a helper runs at once unless told otherwise (`threads`); a study's E8 helper runs fewer
#: (`jaxeac.experiments.study_runs.HELPER_THREADS`: each compile at once adds to its memory).
THREADS = 8


_STOP = object()  # ends a helper's writer thread (`Helper.kill`)


class HelperError(RuntimeError):
    """The helper process ended before a job finished, or a job's result could not come back."""


def helper_environment(environ: dict | None = None) -> dict[str, str]:
    """The variables a helper starts JAX with: the CPU only, one host device (the XLA flags
    otherwise kept)."""
    environ = os.environ if environ is None else environ
    count = "--xla_force_host_platform_device_count"
    flags = [f for f in environ.get("XLA_FLAGS", "").split() if not f.startswith(count)]
    return {"JAX_PLATFORMS": "cpu", "XLA_FLAGS": " ".join([*flags, f"{count}=1"])}


class Helper:
    """A helper process (module docstring): `submit(fn, *args, **kwargs)` → a future of
    ``fn(*args, **kwargs)`` computed there; `close` waits for it to end, `kill` ends it now. A job
    whose function raises gives that exception; one the process did not finish, or whose job or
    result could not cross between the processes, `HelperError`.

    `preload` (a module-level function) runs there before the first job is read: the modules of the
    jobs to come, imported once, not by two jobs at once (a job read while another imported the
    same package saw it half made: ``ImportError ... partially initialized module``).

    The process is spawned without importing the caller's main module again (`_main_not_imported`),
    so a script need not keep its top level under ``if __name__ == "__main__":``; jobs are functions
    of importable modules."""

    def __init__(self, *, threads: int = THREADS, lanes: dict[str, int] | None = None, nice: int = NICE,
                 name: str = "jaxeac-helper", preload: Callable[[], None] | None = None) -> None:
        import multiprocessing

        self._lanes = dict(lanes or {})  # lane name -> its threads, beside the `threads` of `submit`'s jobs
        context = multiprocessing.get_context("spawn")  # no fork of a process running JAX's threads
        self._conn, child = context.Pipe()
        self._process = context.Process(target=_serve, args=(child, threads, nice, helper_environment(),
                                                             self._lanes, preload), name=name, daemon=True)
        with _main_not_imported():
            self._process.start()
        child.close()
        self._lock = threading.Lock()  # the pending jobs and whether more may come
        self._pending: dict[int, Future] = {}
        self._jobs = 0
        self._open = True
        self._peak_rss: Future = Future()
        # Messages go out on a thread of their own: the pipe holds 64 KiB, and until the process has
        # started (a Python with JAX: 1-2 s) a study's first jobs (its E8, 1.1 s on one H200) would
        # otherwise keep the caller writing.
        self._outbox: queue.SimpleQueue = queue.SimpleQueue()
        self._writer = threading.Thread(target=self._write, daemon=True, name=f"{name}-writer")
        self._writer.start()
        self._reader = threading.Thread(target=self._read, daemon=True, name=f"{name}-reader")
        self._reader.start()

    @property
    def lanes(self) -> tuple[str, ...]:
        """The names of the helper's lanes (`submit_to`)."""
        return tuple(self._lanes)

    def submit(self, fn: Callable, /, *args, **kwargs) -> Future:
        """A future of ``fn(*args, **kwargs)``, run on the helper's `threads` in the order sent."""
        return self._send(None, fn, args, kwargs)

    def submit_to(self, lane: str, fn: Callable, /, *args, **kwargs) -> Future:
        """As `submit`, on the threads of `lane` (one of the helper's `lanes`), so that the job never
        waits behind `submit`'s (a figure's panels behind E8's diagnostics)."""
        if lane not in self._lanes:
            raise ValueError(f"no lane {lane!r} in this helper (its lanes: {sorted(self._lanes)})")
        return self._send(lane, fn, args, kwargs)

    def _send(self, lane: str | None, fn: Callable, args: tuple, kwargs: dict) -> Future:
        payload = pickle.dumps((fn, args, kwargs))  # what cannot be pickled is the caller's error, here
        future: Future = Future()
        future.set_running_or_notify_cancel()  # a job sent cannot be called back
        with self._lock:
            if not self._open:
                raise HelperError("the helper process has ended; no more jobs can go to it")
            job, self._jobs = self._jobs, self._jobs + 1
            self._pending[job] = future
            self._outbox.put((job, payload, lane))  # in the order sent (`_write`)
        return future

    def _write(self) -> None:
        """Send the outbox's messages in order until `close`'s None or the end; a pipe that breaks
        (the process has gone) leaves the jobs sent to `_read`, which fails them as the process ends."""
        while (message := self._outbox.get()) is not _STOP:
            try:
                self._conn.send(message)
            except OSError:  # the process has gone: its reader fails what is pending
                return
            if message is None:
                return

    @property
    def peak_rss_bytes(self) -> int | None:
        """The helper's peak resident memory, once `close` has ended it (None before, or if killed)."""
        if not self._peak_rss.done() or self._peak_rss.exception() is not None:
            return None
        return self._peak_rss.result()

    def close(self, timeout: float = 30.0) -> None:
        """End the helper once its jobs are done (at most `timeout` s, then it is killed)."""
        with self._lock:
            was_open, self._open = self._open, False
            if was_open:
                self._outbox.put(None)  # after every job sent: the helper ends once they are done
        self._reader.join(timeout)
        self.kill()

    def kill(self) -> None:
        """End the helper now; jobs not finished fail with `HelperError`."""
        if self._process.is_alive():  # first: a helper that stopped reading cannot hold this up
            self._process.kill()
        self._process.join()
        with self._lock:
            self._open = False
        self._reader.join()
        self._outbox.put(_STOP)
        self._writer.join()  # a send under way has failed by now (the process is gone)
        self._conn.close()

    def __enter__(self) -> Helper:
        return self

    def __exit__(self, kind, *exc) -> None:
        self.close() if kind is None else self.kill()

    def _read(self) -> None:
        """Hand each result to its future until the process ends; then fail the jobs left. A message
        that cannot be read (a result that does not unpickle here) ends the helper the same way."""
        why = "the helper process ended before this job finished"
        try:
            while True:
                try:
                    message = self._conn.recv()
                except (EOFError, OSError):
                    break
                if message[0] == "closed":
                    self._peak_rss.set_result(message[1])
                    break
                job, ok, blob = message
                with self._lock:
                    future = self._pending.pop(job, None)
                if future is None:
                    continue
                try:
                    value = pickle.loads(blob)
                except Exception as exc:  # noqa: BLE001 (e.g. a class that does not unpickle here)
                    why_not = f"a job's result could not be read here ({type(exc).__name__}: {exc})"
                    ok, value = False, HelperError(why_not)
                future.set_result(value) if ok else future.set_exception(value)
        except Exception as exc:  # noqa: BLE001 (every waiting job is told, and the process ends)
            why = f"a message from the helper process could not be read ({type(exc).__name__}: {exc})"
            if self._process.is_alive():
                self._process.kill()
        with self._lock:
            self._open, pending, self._pending = False, self._pending, {}
        if not self._peak_rss.done():
            self._peak_rss.set_exception(HelperError("the helper process was ended"))
        for future in pending.values():
            future.set_exception(HelperError(why))


def in_helper(helper: Helper | None, fn: Callable, /, *args, **kwargs) -> Callable[[], object]:
    """Start ``fn(*args, **kwargs)`` in `helper`'s process and return a function that waits for its
    value. Without a helper, or where it has ended (`HelperError`, before or while the job ran),
    that function computes the value here instead; what `fn` itself raises is raised. A job whose
    result (or error) cannot come back is also run again here: jobs must be safe to repeat (the
    figures' jobs write the same files)."""
    future = None
    if helper is not None:
        with suppress(HelperError):
            future = helper.submit(fn, *args, **kwargs)

    def value():
        if future is not None:
            with suppress(HelperError):
                return future.result()
        return fn(*args, **kwargs)

    return value


@contextmanager
def _main_not_imported():
    """While a helper starts: its process is not told the caller's main module, which spawning
    otherwise imports there (running a script's unguarded top level again: the study it starts, on
    the GPU, before the helper serves a job); the helper's code and jobs are in importable modules."""
    main = sys.modules.get("__main__")
    if main is None:
        yield
        return
    saved = {name: getattr(main, name) for name in ("__spec__", "__file__") if hasattr(main, name)}
    try:
        for name in saved:
            setattr(main, name, None)
        yield
    finally:
        for name, value in saved.items():
            setattr(main, name, value)


def _portable(exc: BaseException) -> BaseException:
    """`exc` if it survives pickling, else a `HelperError` naming it."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001 (any failure to pickle: described instead)
        return HelperError(f"{type(exc).__name__}: {exc}")


def _own_peak_rss() -> int:
    """This process's peak resident bytes. On Linux its memory's high-water mark (``VmHWM``): the
    rusage maximum also holds the parent's resident memory when it was forked to start this process
    (kept across exec), 4.0 GiB for a helper spawned by a long test process."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux, bytes on macOS
    return peak * (1 if sys.platform == "darwin" else 1024)


def _serve(conn, threads: int, nice: int, environment: dict[str, str], lanes: dict[str, int],
           preload: Callable[[], None] | None = None) -> None:
    """The helper process: `preload`, then read jobs until the parent closes (None) or goes away
    (end of file)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and ends this process
    os.environ.update(environment)
    try:
        os.nice(nice)
    except OSError:
        pass
    from concurrent.futures import ThreadPoolExecutor

    import jax

    from jaxeac import runtime

    jax.config.update("jax_platforms", "cpu")  # also where the parent's main module imported JAX first
    runtime.use_compilation_cache()  # as in the parent
    if preload is not None:
        with suppress(Exception):  # only a head start: a job needing what failed fails alone
            preload()
    send = threading.Lock()

    def reply(message) -> None:
        with send:
            conn.send(message)

    def run(job: int, payload: bytes) -> None:
        name = "the job"
        try:
            fn, args, kwargs = pickle.loads(payload)  # a job that cannot be read here fails alone
            name = getattr(fn, "__name__", repr(fn))
            outcome = (job, True, fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 (the parent's future carries it)
            outcome = (job, False, _portable(exc))
        try:
            blob = pickle.dumps(outcome[2])
        except Exception as exc:  # noqa: BLE001 (a result that cannot be pickled)
            failed = HelperError(f"the result of {name} cannot come back: {exc}")
            outcome, blob = (job, False, None), pickle.dumps(failed)
        reply((outcome[0], outcome[1], blob))

    pools = {None: ThreadPoolExecutor(threads, thread_name_prefix="jaxeac-helper"),
             **{lane: ThreadPoolExecutor(n, thread_name_prefix=f"jaxeac-helper-{lane}")
                for lane, n in lanes.items()}}
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):  # the parent has gone: nobody waits for the jobs
            os._exit(0)
        if message is None:
            break
        job, payload, lane = message
        pools[lane].submit(run, job, payload)
    for pool in pools.values():
        pool.shutdown(wait=True)
    reply(("closed", _own_peak_rss()))
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    os._exit(0)  # no interpreter teardown (JAX's clients freed object by object): nothing is left to save
