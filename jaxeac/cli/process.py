"""The command line's process concerns: one-line errors and exit codes, Ctrl-C, the output
folders a command holds, and the start of a multi-host JAX run.

Bad input, a full disk, a busy output folder and running out of memory are one line
``error: ...`` on stderr and exit code 2; Ctrl-C is one line and exit code 130.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence

from jaxeac.errors import UsageError


def _fail(message: str, code: int = 2) -> int:
    """Print ``error: message`` as one line on stderr; return `code`."""
    line = " ".join(str(message).split("\n")).replace("\r", " ")
    # control characters (from a damaged file's bytes) would break the one line: escaped
    line = "".join(ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii") for ch in line)
    try:
        print(f"error: {line}", file=sys.stderr, flush=True)
    except (OSError, ValueError):  # stderr closed: the exit code still says it
        pass
    return code


def _out_of_device_memory(exc: BaseException) -> bool:
    """An XLA allocation failure (RESOURCE_EXHAUSTED), e.g. a chunk too large for a GPU."""
    text = str(exc)
    return type(exc).__name__ in ("XlaRuntimeError", "JaxRuntimeError") and (
        "RESOURCE_EXHAUSTED" in text or "Out of memory" in text or "out of memory" in text)


def _resend_dropped_ctrl_c(unraisable) -> None:
    """`sys.unraisablehook` while a command runs: a Ctrl-C that landed where Python cannot raise
    it (a garbage-collection or weakref callback, a ``__del__``: JAX runs such code) would be
    printed as "Exception ignored" and dropped, and the run would carry on; instead the signal
    is sent again a moment later, to land in ordinary code. Anything else goes to the
    previous hook."""
    if unraisable.exc_type is KeyboardInterrupt:
        threading.Timer(0.01, os.kill, (os.getpid(), signal.SIGINT)).start()
        return
    _previous_unraisablehook(unraisable)


_previous_unraisablehook = sys.unraisablehook

Command = Callable[[Sequence[str] | None, contextlib.ExitStack], int]


def run_command(argv: Sequence[str] | None, command: Command) -> int:
    """Run `command(argv, cleanup)` with Ctrl-C raised in the main thread and the faults above
    turned into one line and an exit code; `cleanup` releases the folders it held."""
    global _previous_unraisablehook
    if threading.current_thread() is not threading.main_thread():  # signals go to the main thread only
        return _guarded(argv, command)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    _previous_unraisablehook, sys.unraisablehook = sys.unraisablehook, _resend_dropped_ctrl_c
    try:
        return _guarded(argv, command)
    finally:
        signal.signal(signal.SIGINT, before)
        sys.unraisablehook = _previous_unraisablehook


def _guarded(argv: Sequence[str] | None, command: Command) -> int:
    try:
        with contextlib.ExitStack() as cleanup:
            return command(argv, cleanup)
    except UsageError as exc:
        return _fail(str(exc))
    except KeyboardInterrupt:
        return _interrupted(argv)
    except BrokenPipeError:  # the reader of stdout stopped early (`jaxeac throw ... | head`): quietly,
        if argv is None:  # like other command-line tools; no second error when Python flushes stdout
            with contextlib.suppress(OSError, ValueError):
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, what a shell reports for such a writer
    except MemoryError:
        return _fail("out of memory: this run needs more memory than is free on this machine (nothing was "
                     "written); use fewer seeds, trials or chances, a smaller map or a smaller --chunk-size")
    except OSError as exc:
        from jaxeac.io import DiskFullError, is_disk_full

        if not is_disk_full(exc):
            raise
        if isinstance(exc, DiskFullError):
            return _fail(str(exc))
        where = f" while writing {exc.filename}" if exc.filename else ""
        return _fail(f"the disk is full (no space left on device){where}; no file is left half-written: "
                     "free some space or write elsewhere")
    except Exception as exc:
        if _caused_by_ctrl_c(exc):
            return _interrupted(argv)
        if not _out_of_device_memory(exc):
            raise
        return _fail("out of device memory: a chunk of seeds does not fit on the accelerator (nothing was "
                     "written); pass a smaller --chunk-size, or use fewer trials or chances or a smaller map")


def _interrupted(argv) -> int:
    """Ctrl-C: one line, exit code 130."""
    code = _fail("interrupted; files already finished are kept, none is half-written", 130)
    if argv is None:  # the process's entry point: end it now, as XLA may still be running a
        with contextlib.suppress(Exception):  # chunk on its threads (tearing the interpreter
            sys.stdout.flush()  # down under it can crash); folders are cleaned up already
        os._exit(code)
    return code


def _caused_by_ctrl_c(exc: BaseException) -> bool:
    """Whether `exc` wraps a Ctrl-C: Python 3.11 turns one raised while a class body is set up (a
    module being imported, e.g. matplotlib's axes) into ``RuntimeError("Error calling __set_name__
    ...")`` caused by it."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__
    return False


def _ended_with_command(args: argparse.Namespace, helper):
    """`helper` (a `jaxeac.running.helper.Helper` or None), killed when the command ends if nothing
    has ended it before (a check refuses the command after the helper started); returned."""
    stack = getattr(args, "_cleanup", None)
    if helper is not None and stack is not None:
        stack.callback(helper.kill)
    return helper


def _claim_out(args: argparse.Namespace, path, lock_path=None, kind: str = "run", reads: bool = False):
    """Check the output folder `path` and hold it (or `lock_path`, a part of it) for the rest of the
    command: a second run into the same folder is refused until this one ends, and a folder holding
    another kind of output (`jaxeac.io.folder_kind`) is refused before any compute."""
    from jaxeac.io import check_folder_kind, check_writable_dir, folder_lock

    check_folder_kind(path, kind, reads=reads)
    stack = getattr(args, "_cleanup", None)
    if stack is not None:
        stack.enter_context(folder_lock(lock_path or path))
    return check_writable_dir(path)


def _claim_existing(args: argparse.Namespace, path) -> None:
    """Hold a run folder that a command reads and then writes into (compare, merge), if it exists."""
    from pathlib import Path

    if Path(path).is_dir():
        _claim_out(args, path, reads=True)


def _init_distributed(args: argparse.Namespace) -> None:
    """jax.distributed.initialize with --coordinator (once); failures are one-line errors."""
    if not getattr(args, "coordinator", None) or getattr(args, "_distributed", False):
        return
    import socket

    import jax

    host, _, port = args.coordinator.rpartition(":")
    try:
        socket.getaddrinfo(host.strip("[]"), int(port))
    except (OSError, UnicodeError) as exc:
        raise UsageError(f"--coordinator {args.coordinator}: cannot resolve host {host} "
                         f"({getattr(exc, 'strerror', None) or exc}); check the name") from None
    try:
        jax.distributed.initialize(args.coordinator, args.num_processes, args.process_id)
    except Exception as exc:  # noqa: BLE001 - RPC, bind and timeout errors of the runtime
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
        raise UsageError(f"--coordinator {args.coordinator}: could not start or reach the coordinator "
                         f"({first}); check the address, the port and that process 0 runs") from None
    args._distributed = True
