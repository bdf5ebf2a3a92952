"""`python -m jaxeac` and the `jaxeac` console script (`run`).

The command line's modules (JAX, NumPy, ...) take a second or two to import. Until they are
loaded nothing has been written, so Ctrl-C then ends the process at once with one line and exit
code 130 (an interrupt inside an import would otherwise surface as an ImportError traceback);
from `jaxeac.cli.main` on, its own handling takes over.

When the command has finished, the process ends without the interpreter's teardown (`_end`):
freeing JAX's client and the run's arrays object by object took about 1 s after a 10^6-seed
grid run, and by then every file the command wrote is closed. JAX's own exit handler, which
frees its client and caches the same way, is skipped too (0.1-0.2 s of a GPU study's exit).
"""

import atexit
import contextlib
import os
import signal
import sys
from typing import NoReturn


def _interrupted_while_starting(signum, frame) -> None:
    try:
        os.write(2, b"error: interrupted while starting; nothing was written\n")
    finally:
        os._exit(130)


def run() -> NoReturn:
    """Set the process up (`jaxeac.runtime.configure`), run the command line and end the process."""
    signal.signal(signal.SIGINT, _interrupted_while_starting)
    from jaxeac import runtime

    # every process setting, before NumPy's BLAS and JAX's backend start (the heaviest imports,
    # still under the start-up handler)
    runtime.configure(sys.argv[1] if len(sys.argv) > 1 else None, force=True)
    from jaxeac.cli import main

    signal.signal(signal.SIGINT, signal.default_int_handler)  # what `main` restores when it ends
    _end(main())  # `main` installs its own Ctrl-C handling while it runs


def _end(code: int) -> NoReturn:
    """End the process with `code`: the exit handlers run and stdout and stderr are flushed, as
    at a normal exit, but the interpreter's teardown is skipped (see the module docstring). The
    command has finished, so a Ctrl-C from here on is ignored: it would only interrupt an exit
    handler (JAX's) with a traceback."""
    with contextlib.suppress(ValueError):  # (not the main thread: signals stay as they are)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    _skip_jax_teardown()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # e.g. a reader of stdout that has gone away
            stream.flush()
    os._exit(code)


def _skip_jax_teardown() -> None:
    """Unregister JAX's exit handler (`jax._src.api.clean_up`: it frees the backends' clients and
    the compiled programs one by one, then ends a distributed run), keeping the last part: the
    process ends right after, so only a distributed run's shutdown is still owed."""
    api = sys.modules.get("jax._src.api")
    clean_up = getattr(api, "clean_up", None)
    if clean_up is None:  # JAX not imported, or a version without it: its handler (if any) runs
        return
    atexit.unregister(clean_up)
    with contextlib.suppress(Exception):
        from jax._src import distributed

        distributed.shutdown()  # a no-op unless jax.distributed was initialized


if __name__ == "__main__":
    run()
