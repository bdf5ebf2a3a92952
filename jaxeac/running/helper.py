"""Host work in a process of its own: a study's E8 diagnostics on the CPU beside its GPU runs.

A study on a GPU counts E8's seeds again on the host's CPU (`jaxeac.experiments.study`). In the
study's own process, tracing and compiling those programs held the interpreter lock that the
runs' programs need, and running them took the cores: with E8 in a helper, `jaxeac study --seeds
1000` on one H100 took 20.7-20.8 s against 28.5-29.6 s (BENCHMARKS.md, `gpu_h100_study_builds.json`).

A `Helper` is a spawned process with JAX on the CPU alone (one host device, as E8's calls use
beside a GPU), at a lower scheduling priority (`NICE`), that runs jobs (a module-level function
and its arguments, pickled) on a few threads of its own and hands back futures. It ignores
Ctrl-C (its parent handles it and ends the helper) and ends when its parent's end of the pipe
closes, so an interrupted or killed command leaves no process behind.
"""

from __future__ import annotations

import os
import pickle
import signal
import threading
from collections.abc import Callable
from concurrent.futures import Future

#: The helper's scheduling priority, above its parent's (lower priority): the parent's threads
#: (the runs' compiles and dispatch) come first on a busy host.
NICE = 10
#: Jobs the helper runs at once (a study's E8: one compile per algorithm ahead, then its tasks).
THREADS = 8


class HelperError(RuntimeError):
    """The helper process ended before a job finished, or a job's result could not come back."""


def helper_environment(environ: dict | None = None) -> dict[str, str]:
    """The variables a helper starts JAX with: the CPU only, one host device (the XLA flags
    otherwise kept)."""
    environ = os.environ if environ is None else environ
    flags = [f for f in environ.get("XLA_FLAGS", "").split() if not f.startswith("--xla_force_host_platform_device_count")]
    return {"JAX_PLATFORMS": "cpu", "XLA_FLAGS": " ".join([*flags, "--xla_force_host_platform_device_count=1"])}


class Helper:
    """A helper process (module docstring): `submit(fn, *args, **kwargs)` → a future of
    ``fn(*args, **kwargs)`` computed there; `close` waits for it to end, `kill` ends it now. A job
    whose function raises gives that exception; one the process did not finish, `HelperError`."""

    def __init__(self, *, threads: int = THREADS, nice: int = NICE, name: str = "jaxeac-helper") -> None:
        import multiprocessing

        context = multiprocessing.get_context("spawn")  # no fork of a process running JAX's threads
        self._conn, child = context.Pipe()
        self._process = context.Process(target=_serve, args=(child, threads, nice, helper_environment()),
                                        name=name, daemon=True)
        self._process.start()
        child.close()
        self._lock = threading.Lock()
        self._pending: dict[int, Future] = {}
        self._jobs = 0
        self._open = True
        self._peak_rss: Future = Future()
        self._reader = threading.Thread(target=self._read, daemon=True, name=f"{name}-reader")
        self._reader.start()

    def submit(self, fn: Callable, /, *args, **kwargs) -> Future:
        future: Future = Future()
        with self._lock:
            if not self._open:
                raise HelperError("the helper process has ended; no more jobs can go to it")
            job, self._jobs = self._jobs, self._jobs + 1
            self._pending[job] = future
            try:
                self._conn.send((job, fn, args, kwargs))
            except BaseException:
                del self._pending[job]
                raise
        return future

    @property
    def peak_rss_bytes(self) -> int | None:
        """The helper's peak resident memory, once `close` has ended it (None before, or if killed)."""
        if not self._peak_rss.done() or self._peak_rss.exception() is not None:
            return None
        return self._peak_rss.result()

    def close(self, timeout: float = 30.0) -> None:
        """End the helper once its jobs are done (at most `timeout` s, then it is killed)."""
        with self._lock:
            if self._open:
                self._open = False
                try:
                    self._conn.send(None)
                except OSError:
                    pass
        self._reader.join(timeout)
        self._process.join(timeout)
        self.kill()

    def kill(self) -> None:
        """End the helper now; jobs not finished fail with `HelperError`."""
        with self._lock:
            self._open = False
        if self._process.is_alive():
            self._process.kill()
        self._process.join()
        self._conn.close()
        self._reader.join()

    def __enter__(self) -> Helper:
        return self

    def __exit__(self, kind, *exc) -> None:
        self.close() if kind is None else self.kill()

    def _read(self) -> None:
        while True:
            try:
                message = self._conn.recv()
            except (EOFError, OSError):
                break
            if message[0] == "closed":
                self._peak_rss.set_result(message[1])
                break
            job, ok, value = message
            with self._lock:
                future = self._pending.pop(job, None)
            if future is not None:
                future.set_result(value) if ok else future.set_exception(value)
        with self._lock:
            self._open, pending, self._pending = False, self._pending, {}
        if not self._peak_rss.done():
            self._peak_rss.set_exception(HelperError("the helper process was ended"))
        for future in pending.values():
            future.set_exception(HelperError("the helper process ended before this job finished"))


def _portable(exc: BaseException) -> BaseException:
    """`exc` if it survives pickling, else a `HelperError` naming it."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001 (any failure to pickle: described instead)
        return HelperError(f"{type(exc).__name__}: {exc}")


def _serve(conn, threads: int, nice: int, environment: dict[str, str]) -> None:
    """The helper process: read jobs until the parent closes (None) or goes away (end of file)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and ends this process
    os.environ.update(environment)
    try:
        os.nice(nice)
    except OSError:
        pass
    from concurrent.futures import ThreadPoolExecutor

    from jaxeac import runtime

    runtime.use_compilation_cache()  # as in the parent (JAX starts here, with `environment`)
    send = threading.Lock()

    def reply(message) -> None:
        with send:
            conn.send(message)

    def run(job: int, fn: Callable, args: tuple, kwargs: dict) -> None:
        try:
            outcome = (job, True, fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 (the parent's future carries it)
            outcome = (job, False, _portable(exc))
        try:
            reply(outcome)
        except Exception as exc:  # noqa: BLE001 (a result that cannot be pickled)
            reply((job, False, HelperError(f"the result of {getattr(fn, '__name__', fn)} cannot come back: {exc}")))

    with ThreadPoolExecutor(threads, thread_name_prefix="jaxeac-helper") as pool:
        while True:
            try:
                message = conn.recv()
            except (EOFError, OSError):  # the parent has gone: nobody waits for the jobs
                os._exit(0)
            if message is None:
                break
            pool.submit(run, *message)
    import resource
    import sys

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux, bytes on macOS
    reply(("closed", peak * (1 if sys.platform == "darwin" else 1024)))
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    os._exit(0)  # no interpreter teardown (JAX's clients freed object by object): nothing is left to save
