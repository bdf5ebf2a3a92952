"""`python -m jaxeac` and the `jaxeac` console script (`run`).

The command line's modules (JAX, NumPy, ...) take a second or two to import. Until they
are loaded nothing has been written, so Ctrl-C then ends the process at once with one
line and exit code 130 (an interrupt inside an import would otherwise surface as an
ImportError traceback); from `jaxeac.cli.main` on, its own handling takes over.

When the command has finished, the process ends without the interpreter's teardown
(`_end`): freeing JAX's client and the run's arrays object by object took about 1 s
after a 10^6-seed grid run on one H100 (its last line at 17.9 s, 19.0 s wall: record
gpu_h100_memory_timeline_1m_dd7d05a.txt), and by then every file the command wrote is closed.

NumPy's BLAS runs one thread per call (`ONE_BLAS_THREAD`, unless the user set its variable):
the statistics already run their jobs on host threads side by side, and each BLAS call of each
job starting a thread per core left 16 cores oversubscribed on one H100's host (the 10^6-seed
comparison's statistics 3.49 s with OpenBLAS's default, 2.19 s with one thread, same sitting:
record gpu_h100_e2e_1m_builds_blas.json). It also makes the comparison's numbers independent
of the host's core count: OpenBLAS splits a long dot product between its threads, so its last
bit depended on how many there were.
"""

import atexit
import contextlib
import os
import signal
import sys
from typing import NoReturn

#: The environment variables of NumPy's BLAS (the OpenBLAS of NumPy's wheels, MKL) that the
#: command line sets to one thread unless already set (see the module docstring).
ONE_BLAS_THREAD = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread(environ=os.environ) -> None:
    """One thread per BLAS call, where the user has not chosen; before NumPy is imported."""
    for name in ONE_BLAS_THREAD:
        environ.setdefault(name, "1")


def _interrupted_while_starting(signum, frame) -> None:
    try:
        os.write(2, b"error: interrupted while starting; nothing was written\n")
    finally:
        os._exit(130)


def run() -> NoReturn:
    """Import the command line, run it and end the process (see the module docstring)."""
    signal.signal(signal.SIGINT, _interrupted_while_starting)
    one_blas_thread()  # read by the BLAS library as NumPy loads it
    from jaxeac.cli import configure_xla, main

    configure_xla(sys.argv[1] if len(sys.argv) > 1 else None)  # XLA's flags for the command, before JAX
    import jax  # noqa: F401  (the heaviest imports, still under the start-up handler)

    import jaxeac.running.cache  # noqa: F401

    signal.signal(signal.SIGINT, signal.default_int_handler)  # what `main` restores when it ends
    _end(main())  # `main` installs its own Ctrl-C handling while it runs


def _end(code: int) -> NoReturn:
    """End the process with `code`: the exit handlers run and stdout and stderr are flushed, as
    at a normal exit, but the interpreter's teardown is skipped (see the module docstring). The
    command has finished, so a Ctrl-C from here on is ignored: it would only interrupt an exit
    handler (JAX's) with a traceback."""
    with contextlib.suppress(ValueError):  # (not the main thread: signals stay as they are)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # e.g. a reader of stdout that has gone away
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    run()
