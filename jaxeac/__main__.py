"""`python -m jaxeac` and the `jaxeac` console script (`run`).

The command line's modules (JAX, NumPy, ...) take a second or two to import. Until they
are loaded nothing has been written, so Ctrl-C then ends the process at once with one
line and exit code 130 (an interrupt inside an import would otherwise surface as an
ImportError traceback); from `jaxeac.cli.main` on, its own handling takes over.
"""

import os
import signal
import sys


def _interrupted_while_starting(signum, frame) -> None:
    try:
        os.write(2, b"error: interrupted while starting; nothing was written\n")
    finally:
        os._exit(130)


def run() -> int:
    """Import the command line and run it (see the module docstring for Ctrl-C)."""
    signal.signal(signal.SIGINT, _interrupted_while_starting)
    from jaxeac.cli import configure_xla, main

    configure_xla()  # XLA's flags, before JAX is imported
    import jax  # noqa: F401  (the heaviest imports, still under the start-up handler)

    import jaxeac.running.cache  # noqa: F401

    signal.signal(signal.SIGINT, signal.default_int_handler)  # what `main` restores when it ends
    return main()  # installs its own Ctrl-C handling while it runs


if __name__ == "__main__":
    sys.exit(run())
