"""The process's settings, in one place: what the `jaxeac` command and a notebook share.

`configure` applies every process-level setting once, in the order they must come (before
NumPy's BLAS loads, before JAX starts its backend, after JAX is imported). The `jaxeac`
command calls it first thing; `import jaxeac` applies what must precede NumPy and JAX, and the
first library call (`jaxeac.run`, `jaxeac.compare`, ...) applies the rest, so a notebook runs
with the command line's settings and gets the same numbers. ``JAXEAC_RUNTIME=off`` in the
environment leaves a library process as the user set it up. Every setting leaves alone what
the user set already (an environment variable, a flag in ``XLA_FLAGS``).

The settings, each with its reason:

- ``OPENBLAS_NUM_THREADS=1`` / ``MKL_NUM_THREADS=1``: the statistics run their jobs side by side
  on host threads, and a BLAS thread per core for each left a 16-core host oversubscribed
  (10^6-seed statistics 3.49 s -> 2.19 s on one H100's host); with one thread the last bit of
  a long BLAS sum no longer depends on the core count. NumPy already loaded: set through the
  loaded OpenBLAS where it exposes its setter.
- ``--xla_force_host_platform_device_count=<cores>``: XLA runs a computation on one thread; with
  a device per core the runner splits each chunk of seeds over the cores (results identical, R1).
- GPUs, ``--xla_gpu_enable_command_buffer=...`` (`GPU_XLA_FLAGS`): CUDA graphs for whole loop
  bodies, ~10 % faster single-GPU runs.
- GPUs, grid-like work (`GPU_COMPILE_FLAGS`): cuBLAS matrix products and no compile-time
  autotuning; a first 10^6-seed grid run compiled seconds faster with the same results. Not for
  bowling: MJX's float32 physics ran at 0.72x with them.
- ``XLA_PYTHON_CLIENT_PREALLOCATE=false``: JAX's up-front reservation of 75 % of a GPU also held
  ~1.5 GiB of host memory and doubled a 10^6-seed run's peak; growing as needed ran as fast.
- JAX's persistent compilation cache (`use_compilation_cache`): a rerun loads its programs (the
  run's and E8's whole, without tracing them again: `jaxeac.running.programs`).
- At most `MALLOC_ARENAS` glibc malloc arenas (``MALLOC_ARENA_MAX``; glibc's default is 8 per
  core): a 100,000-seed study's many threads each kept what they had freed (peak host RSS
  4.64 -> 2.32 GiB on one H100's 16-core host, walls within the host's noise).
- `trim_host_memory`: what XLA's compiler and pyarrow freed goes back to the system.
- `start_device`: a GPU's context starts on a thread while the host reads files, or while a
  command imports its modules and checks its settings (`jaxeac.cli.DEVICE_COMMANDS`).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import platform
import sys
import threading
from importlib import metadata
from pathlib import Path

#: ``off`` (or 0/false/no): a library process keeps the settings its user made (the command
#: line always applies them).
OPT_OUT = "JAXEAC_RUNTIME"
OFF = ("0", "off", "false", "no")

BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
GPU_XLA_FLAGS = ("--xla_gpu_enable_command_buffer=FUSION,CUSTOM_CALL,WHILE,CONDITIONAL",)
GPU_COMPILE_FLAGS = ("--xla_gpu_enable_triton_gemm=false", "--xla_gpu_autotune_level=0")
#: Work that keeps XLA's compile defaults (`GPU_COMPILE_FLAGS` is for everything else).
DEFAULT_COMPILE_WORK = frozenset({"bowling", "throw"})
PREALLOCATE_VARIABLE = "XLA_PYTHON_CLIENT_PREALLOCATE"
GPU_PREALLOCATE = "false"

CACHE_VARIABLE = "JAXEAC_COMPILATION_CACHE"
#: Programs that compile faster than this are not kept (XLA's default: 1 s). 0, every program: at
#: 0.2 s a warm rerun of a two-task study compiled 18 small programs again (1.6 s of XLA, 2-core CPU).
MIN_COMPILE_SECONDS = 0.0

#: What a run folder's summary.json states (`versions`), in this order.
RUN_PACKAGES = ("jaxeac", "python", "jax", "jaxlib", "numpy", "optax", "mujoco", "matplotlib", "platform")
#: Stated only where installed: the MJX backends' physics.
OPTIONAL_PACKAGES = ("mujoco-mjx", "warp-lang")

#: glibc malloc arenas at most (module docstring); ``M_ARENA_MAX``: mallopt's parameter for it.
MALLOC_ARENAS = 8
M_ARENA_MAX = -8

_LOCK = threading.Lock()
_APPLIED: dict[str, object] = {}


def opted_out(environ=os.environ) -> bool:
    """Whether the user asked a library process to keep its own settings (`OPT_OUT`)."""
    return environ.get(OPT_OUT, "").strip().lower() in OFF


def configure(work: str | None = None, *, start_jax: bool = True, force: bool = False) -> dict:
    """Apply every process setting (module docstring) that can still take effect; idempotent.

    `work` is the command's name (``"grid"``, ``"bowling"``, ...; None: grid-like work) and
    picks the GPU compile flags; until JAX is imported a later call with other work replaces
    the flags an earlier call chose. ``start_jax=False`` applies only what must precede NumPy
    and JAX (environment variables; nothing is imported). `force` ignores `OPT_OUT` (the
    command line). Returns what was applied, by setting.
    """
    if not force and opted_out():
        return {}
    with _LOCK:
        if "malloc_arenas" not in _APPLIED:  # before the threads that would make more
            _APPLIED["malloc_arenas"] = _cap_malloc_arenas()
        if "jax" not in sys.modules:
            _APPLIED["environment"] = _set_environment(work)
        if "blas" not in _APPLIED and "numpy" in sys.modules:
            _APPLIED["blas"] = _set_loaded_blas_threads()
        if start_jax and "compilation_cache" not in _APPLIED:
            _APPLIED["compilation_cache"] = use_compilation_cache()
        return dict(_APPLIED)


#: The variables `configure` sets, as the user had them before its first call.
_USERS: dict[str, str | None] = {}


def _set_environment(work: str | None) -> dict:
    """The variables read when NumPy's BLAS and JAX's backends start, each unless the user set it
    (computed from the user's own values, so a second call replaces what the first added)."""
    environ = os.environ
    if not _USERS:
        _USERS.update({k: environ.get(k) for k in (*BLAS_THREAD_VARIABLES, "XLA_FLAGS", PREALLOCATE_VARIABLE)})
    done = {}
    if "numpy" not in sys.modules:
        for name in BLAS_THREAD_VARIABLES:
            if _USERS[name] is None:
                environ[name] = "1"
        done["blas_threads"] = environ.get("OPENBLAS_NUM_THREADS")
    flags = _USERS["XLA_FLAGS"] or ""
    if "xla_force_host_platform_device_count" not in flags:
        count = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
        flags += f" --xla_force_host_platform_device_count={count or 1}"
    gpu = GPU_XLA_FLAGS + (() if work in DEFAULT_COMPILE_WORK else GPU_COMPILE_FLAGS)
    for flag in gpu:  # each unless set (XLA keeps a flag's last value)
        if flag.split("=")[0] not in flags:
            flags += " " + flag
    environ["XLA_FLAGS"] = done["xla_flags"] = flags.strip()
    if _USERS[PREALLOCATE_VARIABLE] is None:
        environ[PREALLOCATE_VARIABLE] = GPU_PREALLOCATE
    return done


def _set_loaded_blas_threads() -> int | None:
    """One BLAS thread in a process whose NumPy has loaded OpenBLAS already (a notebook that
    imported NumPy first), unless the user chose a count; returns the count set, or None."""
    if any(name in os.environ and os.environ[name] != "1" for name in BLAS_THREAD_VARIABLES):
        return None
    try:
        with open("/proc/self/maps", encoding="utf-8") as maps:
            paths = {line.split()[-1] for line in maps if "openblas" in line.lower() and "/" in line}
    except OSError:
        return None
    for path in sorted(paths):
        with contextlib.suppress(OSError):
            lib = ctypes.CDLL(path)
            for name in ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
                         "openblas_set_num_threads64_", "openblas_set_num_threads"):
                setter = getattr(lib, name, None)
                if setter is not None:
                    setter(1)
                    return 1
    return None


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/jaxeac/xla`` (``~/.cache/jaxeac/xla`` when unset)."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "jaxeac" / "xla"


def _libc() -> ctypes.CDLL:
    """The process's C library (OSError where it cannot be loaded)."""
    return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")


def _cap_malloc_arenas(environ=os.environ) -> int | None:
    """`MALLOC_ARENAS` through glibc's ``mallopt``, unless the user set ``MALLOC_ARENA_MAX`` (glibc
    read it at start) or the C library is not glibc. Returns the cap applied, or None."""
    if environ.get("MALLOC_ARENA_MAX") is not None:
        return None
    try:
        done = _libc().mallopt(M_ARENA_MAX, MALLOC_ARENAS)
    except (OSError, AttributeError):  # not glibc
        return None
    return MALLOC_ARENAS if done == 1 else None


def use_compilation_cache() -> str | None:
    """Turn JAX's persistent compilation cache on at `default_cache_dir` (or the folder in
    ``JAXEAC_COMPILATION_CACHE``); the folder, or None when off, left to JAX
    (``JAX_COMPILATION_CACHE_DIR`` set) or not creatable (compiles still work)."""
    import jax

    choice = os.environ.get(CACHE_VARIABLE)
    if os.environ.get("JAX_COMPILATION_CACHE_DIR") or (choice is not None and choice.lower() in ("", *OFF)):
        return None
    folder = Path(choice) if choice else default_cache_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    return str(folder)


def trim_host_memory() -> None:
    """Hand memory the process has freed back to the system (glibc's ``malloc_trim``, and
    pyarrow's allocator if loaded): XLA's compiler frees gigabytes after a GPU compile that
    malloc would keep, and pyarrow keeps what reading results.parquet freed (1.7 GiB at 10^7
    seeds), so the peak resident memory is the data's."""
    with contextlib.suppress(OSError, AttributeError):  # not glibc
        _libc().malloc_trim(0)
    arrow = sys.modules.get("pyarrow")
    if arrow is not None:
        arrow.default_memory_pool().release_unused()


def start_device() -> threading.Thread:
    """Start JAX's default device on a thread: a GPU's context and libraries take a second or
    two, which reading files can hide (JAX starts a backend once, under a lock). Returns the
    thread: a caller that fails before using the device joins it, since the interpreter aborts
    if it exits while that thread is still inside JAX's start-up."""
    def work() -> None:
        import jax

        with contextlib.suppress(Exception):  # a failure shows up, with its message, at first use
            jax.block_until_ready(jax.numpy.zeros(1))

    thread = threading.Thread(target=work, daemon=True, name=DEVICE_START_THREAD)
    thread.start()
    return thread


DEVICE_START_THREAD = "jaxeac-device-start"


def versions(packages: tuple[str, ...] = RUN_PACKAGES,
             optional: tuple[str, ...] = OPTIONAL_PACKAGES) -> dict[str, str]:
    """Versions of the packages a result depends on, keyed by name (``-`` -> ``_``): each of
    `packages` ("unknown" where not installed), each of `optional` only where installed;
    "python" and "platform" are the interpreter and the machine."""
    from jaxeac import __version__

    builtin = {"jaxeac": lambda: __version__, "python": platform.python_version,
               "platform": platform.platform}
    out = {}
    for name in (*packages, *optional):
        try:
            out[name.replace("-", "_")] = builtin[name]() if name in builtin else metadata.version(name)
        except metadata.PackageNotFoundError:
            if name in packages:
                out[name.replace("-", "_")] = "unknown"
    return out
