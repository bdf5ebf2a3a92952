"""`python -m jaxeac` and the `jaxeac` console script (`run`).

The command line's modules (JAX, NumPy, ...) take a second or two to import. Until they are
loaded nothing has been written, so Ctrl-C then ends the process at once with one line and exit
code 130 (an interrupt inside an import would otherwise surface as an ImportError traceback);
from `jaxeac.cli.main` on, its own handling takes over.

When the command has finished, the process ends without the interpreter's teardown (`_end`):
freeing JAX's client and the run's arrays object by object took about 1 s after a 10^6-seed
grid run, and by then every file the command wrote is closed.
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
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # e.g. a reader of stdout that has gone away
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    run()
