"""A hand-written C peer (`c_peer.c`) of the grid-world runner, for same-run speed comparisons.

The C file follows SPEC G3–G5, (1)–(4) and E1–E7 (dense tables), one seed per OpenMP
iteration with its own splitmix64 stream seeded from (run seed, seed index): a seed's
results do not depend on the number of seeds or threads beside it, and the same seed
gives the same output. The random numbers are not jaxeac's, so the two agree in
distribution only (checked in ``tests/test_peers.py``).

The library is compiled on first use with the system C compiler (``$CC``, else ``cc``,
``gcc`` or ``clang``) with ``-O3 -march=native -fopenmp -ffp-contract=off``, falling back
to fewer flags (no OpenMP: one thread) where the compiler refuses them, into a cache
folder keyed by the source's hash (``$JAXEAC_PEER_CACHE``, else
``$XDG_CACHE_HOME/jaxeac-peers`` or ``~/.cache/jaxeac-peers``, else a temporary folder).
jaxeac itself never needs a compiler: this is a benchmark peer only.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxeac.algorithm.config import ALGORITHMS
from jaxeac.envs.grid import GridMap, GridWorld, get_map
from jaxeac.errors import UsageError

SOURCE = Path(__file__).with_name("c_peer.c")

#: Algorithm flags, as in c_peer.c.
F_SUCCESS, F_FAILURE, F_LEARN_MEMORY, F_WITHIN_TRIAL = 1, 2, 4, 8

#: Compiler flag sets, tried in order; the first that builds wins.
FLAG_SETS = (
    ("-O3", "-march=native", "-fopenmp", "-ffp-contract=off"),
    ("-O3", "-fopenmp", "-ffp-contract=off"),
    ("-O3", "-march=native", "-ffp-contract=off"),
    ("-O3", "-ffp-contract=off"),
    ("-O2",),
)


# --- shared with numba_peer.py -----------------------------------------------------------------


def algo_flags(algo: str) -> int:
    """The C/numba flag word of a named algorithm of `jaxeac.algorithm.agent.ALGORITHMS`."""
    if algo not in ALGORITHMS:
        raise UsageError(f"unknown algorithm {algo!r}; choose from {sorted(ALGORITHMS)}")
    cfg = ALGORITHMS[algo]
    return ((F_SUCCESS if cfg.success_memory else 0) | (F_FAILURE if cfg.failure_memory else 0)
            | (F_LEARN_MEMORY if cfg.learn_on_memory_steps else 0)
            | (F_WITHIN_TRIAL if cfg.failure_rule == "within_trial" else 0))


@dataclass(frozen=True)
class Problem:
    """A grid world as flat, contiguous arrays (G1–G5, E5), the peers' input."""

    n_states: int
    goal: int
    next_state: np.ndarray  # int32 [S·4]
    bumped: np.ndarray  # uint8 [S·4]
    reward: np.ndarray  # float32 [S·4]
    shaped: np.ndarray  # float32 [S]: E5's R_max / (1 + ‖s − g‖₂), computed in float32 as jaxeac
    starts: np.ndarray  # int32 [n_starts] (G3)
    chances: int


def problem(grid: GridWorld | GridMap | str, chances: int | None = None) -> Problem:
    """Transition tables of a `GridWorld`, or of a `GridMap` or preset name with `chances` chances."""
    if isinstance(grid, GridWorld):
        world = grid if chances is None or chances == grid.n_chances else GridWorld(grid.map, chances)
    else:
        if chances is None:
            raise UsageError("chances is needed with a map (it is part of a GridWorld)")
        world = GridWorld(get_map(grid) if isinstance(grid, str) else grid, chances)
    if world.n_actions != 4:
        raise ValueError("the peers pack the 4 failure flags of a state into one byte")
    next_state, reward, bumped = world.tables
    dist = world.goal_distance.astype(np.float32)
    shaped = (np.float32(1.0) / (np.float32(1.0) + dist)).astype(np.float32)
    return Problem(
        n_states=int(world.n_states), goal=int(world.map.goal_index),
        next_state=np.ascontiguousarray(next_state.reshape(-1), np.int32),
        bumped=np.ascontiguousarray(bumped.reshape(-1), np.uint8),
        reward=np.ascontiguousarray(reward.reshape(-1), np.float32),
        shaped=np.ascontiguousarray(shaped), starts=np.ascontiguousarray(world.map.start_cells, np.int32),
        chances=int(world.n_chances),
    )


def check_args(trials, n_seeds, temperature, threads) -> None:
    for name, value in (("trials", trials), ("seeds", n_seeds)):
        if isinstance(value, bool) or int(value) != value or value < 1:
            raise UsageError(f"{name} must be a positive integer (got {value!r})")
    if not temperature > 0:
        raise UsageError(f"temperature must be positive (got {temperature!r})")
    if threads is not None and (int(threads) != threads or threads < 1):
        raise UsageError(f"threads must be a positive integer (got {threads!r})")


def root_seed(seed: int) -> int:
    """The run seed as an unsigned 64-bit integer (negative seeds wrap)."""
    return int(seed) & 0xFFFF_FFFF_FFFF_FFFF


# --- build --------------------------------------------------------------------------------------


def compilers() -> list[str]:
    """Candidate C compilers on PATH: ``$CC`` first, then cc, gcc, clang."""
    names = [os.environ["CC"]] if os.environ.get("CC") else []
    names += ["cc", "gcc", "clang"]
    found = []
    for name in names:
        path = shutil.which(name)
        if path and path not in found:
            found.append(path)
    return found


def cache_dir() -> Path:
    if os.environ.get("JAXEAC_PEER_CACHE"):
        return Path(os.environ["JAXEAC_PEER_CACHE"])
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "jaxeac-peers"


@dataclass(frozen=True)
class Build:
    lib: ctypes.CDLL
    path: Path
    compiler: str
    flags: tuple[str, ...]
    openmp: bool
    max_threads: int
    compile_s: float  # 0 when the library came from the cache


_BUILD: Build | None = None
_BUILD_ERROR: str | None = None


def _writable(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        return os.access(folder, os.W_OK)
    except OSError:
        return False


def _compile(compiler: str, flags: tuple[str, ...], target: Path) -> bool:
    """Compile SOURCE into `target` (atomically: a temporary name, then a rename)."""
    tmp = target.with_name(f"{target.stem}.{os.getpid()}.tmp{target.suffix}")
    cmd = [compiler, *flags, "-fPIC", "-shared", str(SOURCE), "-o", str(tmp), "-lm"]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired):
        return False
    if proc.returncode != 0 or not tmp.exists():
        tmp.unlink(missing_ok=True)
        return False
    os.replace(tmp, target)
    return True


def _load(path: Path) -> ctypes.CDLL:
    lib = ctypes.CDLL(str(path))
    ptr = ctypes.c_void_p
    lib.jaxeac_peer_run.restype = ctypes.c_int
    lib.jaxeac_peer_run.argtypes = [
        ctypes.c_int, ctypes.c_int, ptr, ptr, ptr, ptr, ptr, ctypes.c_int,  # world
        ctypes.c_int, ctypes.c_int, ctypes.c_int,  # flags, trials, chances
        ctypes.c_float, ctypes.c_float, ctypes.c_float, ctypes.c_float,  # alpha, beta, gamma, tau
        ctypes.c_int64, ctypes.c_uint64, ctypes.c_int,  # n_seeds, root seed, threads
        ptr, ptr, ptr, ptr, ptr, ptr, ptr, ptr,  # outputs
    ]
    lib.jaxeac_peer_openmp.restype = ctypes.c_int
    lib.jaxeac_peer_max_threads.restype = ctypes.c_int
    return lib


def build() -> Build:
    """Compile (or reuse the cached build of) c_peer.c and load it; RuntimeError if no compiler works."""
    global _BUILD, _BUILD_ERROR
    if _BUILD is not None:
        return _BUILD
    if _BUILD_ERROR is not None:
        raise RuntimeError(_BUILD_ERROR)
    source = SOURCE.read_bytes()
    ext = ".dylib" if sys.platform == "darwin" else ".so"
    folder = cache_dir()
    if not _writable(folder):
        folder = Path(tempfile.gettempdir()) / f"jaxeac-peers-{os.getuid() if hasattr(os, 'getuid') else 0}"
        folder.mkdir(parents=True, exist_ok=True)
    tried = []
    for compiler in compilers():
        for flags in FLAG_SETS:
            key = hashlib.sha256(b"\0".join([source, compiler.encode(), " ".join(flags).encode(),
                                             platform.machine().encode(), platform.node().encode()]))
            target = folder / f"c_peer-{key.hexdigest()[:16]}{ext}"
            t0 = time.perf_counter()
            fresh = False
            if not target.exists():
                if not _compile(compiler, flags, target):
                    tried.append(f"{Path(compiler).name} {' '.join(flags)}")
                    continue
                fresh = True
            compile_s = time.perf_counter() - t0 if fresh else 0.0
            try:
                lib = _load(target)
            except OSError as exc:
                tried.append(f"{target}: {exc}")
                continue
            _BUILD = Build(lib, target, compiler, flags, bool(lib.jaxeac_peer_openmp()),
                           int(lib.jaxeac_peer_max_threads()), compile_s)
            return _BUILD
    _BUILD_ERROR = ("no working C compiler for the C peer" + (f" (tried: {'; '.join(tried)})" if tried
                                                              else " (none of $CC, cc, gcc, clang on PATH)"))
    raise RuntimeError(_BUILD_ERROR)


def available() -> bool:
    """True when c_peer.c compiles and loads here (compiles once, then uses the cache)."""
    try:
        build()
    except RuntimeError:
        return False
    return True


def info() -> dict:
    """Compiler, flags, OpenMP and thread count of the build (for benchmark records)."""
    b = build()
    version = ""
    try:
        version = subprocess.run([b.compiler, "--version"], capture_output=True, text=True,
                                 timeout=30).stdout.splitlines()[0]
    except (OSError, subprocess.TimeoutExpired, IndexError):
        pass
    return {"compiler": version or b.compiler, "flags": " ".join(b.flags), "openmp": b.openmp,
            "max_threads": b.max_threads, "compile_s": b.compile_s}


# --- run ----------------------------------------------------------------------------------------


def _ptr(a: np.ndarray | None):
    return None if a is None else a.ctypes.data


def run_c(
    grid: GridWorld | GridMap | str,
    *,
    algo: str,
    trials: int,
    chances: int | None = None,
    alpha: float = 0.1,
    beta: float = 0.3,
    gamma: float = 0.9,
    temperature: float = 1.0,
    n_seeds: int,
    seed: int = 0,
    threads: int | None = None,
    per_trial: bool = True,
    tables: bool = False,
) -> dict[str, np.ndarray]:
    """Run `n_seeds` seeds of `algo` (``"ac"``, ``"eac"``, or an ablation) on `grid` in C.

    Returns per seed ``successes int32 [N]`` (total over trials), ``agent_steps int64 [N]``
    (chances taken over all trials), ``first_success int32 [N]`` (−1: never); with
    `per_trial` also ``success bool [N, T]``, ``steps int32 [N, T]`` and ``policy int8 [N, S]``
    (G7); with `tables` also the final ``preferences float32 [N, S, 4]`` and ``values
    float32 [N, S]``. `threads`: OpenMP threads (default: OpenMP's, i.e. $OMP_NUM_THREADS or
    every core). Same `seed` → same output, whatever `threads` and `n_seeds` (per seed).
    """
    flags = algo_flags(algo)
    check_args(trials, n_seeds, temperature, threads)
    p = problem(grid, chances)
    lib = build().lib
    n, t, s = int(n_seeds), int(trials), p.n_states
    success = np.zeros((n, t), np.uint8) if per_trial else None
    steps = np.zeros((n, t), np.int32) if per_trial else None
    policy = np.zeros((n, s), np.int8) if per_trial else None
    prefs = np.zeros((n, s, 4), np.float32) if tables else None
    values = np.zeros((n, s), np.float32) if tables else None
    total_success = np.zeros(n, np.int32)
    total_steps = np.zeros(n, np.int64)
    first = np.zeros(n, np.int32)
    rc = lib.jaxeac_peer_run(
        s, p.goal, _ptr(p.next_state), _ptr(p.bumped), _ptr(p.reward), _ptr(p.shaped), _ptr(p.starts),
        int(p.starts.size), flags, t, p.chances, float(alpha), float(beta), float(gamma), float(temperature),
        n, root_seed(seed), int(threads or 0),
        _ptr(success), _ptr(steps), _ptr(policy), _ptr(prefs), _ptr(values),
        _ptr(total_success), _ptr(total_steps), _ptr(first),
    )
    if rc != 0:
        raise MemoryError("the C peer could not allocate its per-thread workspace")
    out = {"successes": total_success, "agent_steps": total_steps, "first_success": first}
    if per_trial:
        out |= {"success": success.view(bool), "steps": steps, "policy": policy}
    if tables:
        out |= {"preferences": prefs, "values": values}
    return out
