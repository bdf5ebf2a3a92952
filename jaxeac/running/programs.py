"""Compiled programs kept across processes: a rerun loads each program instead of tracing it.

JAX's persistent compilation cache (`jaxeac.runtime.use_compilation_cache`) keys a program by its
lowered module, so a rerun still traces and lowers every program in Python before the cache can
load it, the study's programs all at once under one interpreter lock: `jaxeac study --seeds 1000`
on one H100, every program in JAX's cache, still spent 416 s of compile summed over its tasks
(672 s cold), and 7-10 s with the programs loaded from this store. This store keys
a program by what it is built from instead: what its maker's in-process cache keys it by (the
environment's `program_key`, the resolved `RunConfig`, the devices), its inputs' types and
placements, the package's source, the versions, XLA's flags and JAX's settings. It keeps the
serialized executable in a folder of JAX's cache folder (`FOLDER`), on when that cache is on and
the backend is a GPU (`KEPT_PLATFORMS`).

Whatever cannot be named the same way in another process (an object known by its address, a
schedule function) is not stored: that program is built as before. A file that cannot be loaded
is removed and the program built again; the per-seed results are those of the built program (the
same executable, loaded). `remembered` keeps a small answer the same way (whether this JAX lowers
the fused kernel: `jaxeac.running.kernel.backend_problem`).
"""

from __future__ import annotations

import dataclasses
import enum
import hashlib
import json
import os
import pickle
import sys
import threading
import types
import zlib
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np

FOLDER = "jaxeac-programs"
FORMAT = 1  # of a stored file: (payload, in_tree, out_tree) pickled, then zlib
#: Files kept; beyond them the least recently used go (each edit of the package's source starts a
#: new set of keys).
MAX_FILES = 512

_LOCK = threading.Lock()
_PROCESS: list[str] = []  # the package's source and the versions, named once per process


class Unnamed(Exception):
    """A value with no name that holds in another process (`name_of`)."""


def name_of(value) -> str:
    """A text naming `value` the same way in every process, from its fields, not its address:
    numbers, strings, None, types and functions of this package by their module and name, enums,
    tuples, lists, dicts, dataclasses (every field), NumPy arrays (dtype, shape, bytes' hash), and
    objects of this package's classes by their attributes. Anything else raises `Unnamed`."""
    if value is None or isinstance(value, bool | int | str | bytes):
        return repr(value)
    if isinstance(value, float):
        return float.hex(value)
    if isinstance(value, np.generic):
        return f"{value.dtype}:{name_of(value.item())}"
    if isinstance(value, enum.Enum):
        return f"{_type_name(type(value))}.{value.name}"
    if isinstance(value, type):
        return _type_name(value)
    if isinstance(value, np.ndarray):
        digest = hashlib.sha256(np.ascontiguousarray(value).view(np.uint8)).hexdigest()
        return f"ndarray({value.dtype},{value.shape},{digest})"
    if isinstance(value, tuple | list):
        return f"{type(value).__name__}({','.join(name_of(v) for v in value)})"
    if isinstance(value, dict):
        items = sorted((name_of(k), name_of(v)) for k, v in value.items())
        return "dict(" + ",".join(f"{k}:{v}" for k, v in items) + ")"
    if isinstance(value, frozenset | set):
        return f"{type(value).__name__}({','.join(sorted(name_of(v) for v in value))})"
    if dataclasses.is_dataclass(value):
        fields = ",".join(f"{f.name}={name_of(getattr(value, f.name))}" for f in dataclasses.fields(value))
        return f"{_type_name(type(value))}({fields})"
    if isinstance(value, types.FunctionType) and _ours(value.__module__) and "<" not in value.__qualname__:
        return f"function:{value.__module__}.{value.__qualname__}"
    if _ours(type(value).__module__) and hasattr(value, "__dict__"):
        return f"{_type_name(type(value))}{name_of(vars(value))}"
    raise Unnamed(f"{type(value).__name__} has no name that holds across processes")


def _ours(module: str | None) -> bool:
    return module is not None and (module == "jaxeac" or module.startswith("jaxeac."))


def _type_name(t: type) -> str:
    if "<" in t.__qualname__:  # defined in a function: not found again by its name
        raise Unnamed(f"{t.__qualname__} is a local class")
    return f"{t.__module__}.{t.__qualname__}"


def inputs_name(args) -> str:
    """The inputs' tree, and each leaf's type (shape, dtype, weak type) and, where it is committed
    to devices, its sharding: what the compiled program was made for."""
    leaves, tree = jax.tree.flatten(args)
    parts = [str(tree)]
    for leaf in leaves:
        aval = jax.typeof(leaf)
        placed = repr(leaf.sharding) if isinstance(leaf, jax.Array) and leaf.committed else "-"
        parts.append(f"{aval}|{getattr(aval, 'weak_type', False)}|{placed}")
    return ";".join(parts)


#: Platforms whose executables are kept. Not the CPU: an XLA:CPU executable loaded in another
#: process can lack kernels its writer's process had compiled before it (`jaxeac reproduce --quick`
#: run twice: "NOT_FOUND: Function wrapped_iota not found" on the second run).
KEPT_PLATFORMS = ("gpu",)


def folder(platform: str | None = None) -> Path | None:
    """Where programs for `platform` (default: JAX's default backend) are kept: `FOLDER` in JAX's
    persistent cache folder, None while that cache is off (``JAXEAC_COMPILATION_CACHE=off``) or not
    a local folder, or where the platform is not one of `KEPT_PLATFORMS`."""
    where = jax.config.jax_compilation_cache_dir
    if not where or not jax.config.jax_enable_compilation_cache or "://" in str(where):
        return None
    if (platform or jax.default_backend()) not in KEPT_PLATFORMS:
        return None
    return Path(where) / FOLDER


def _process_name() -> str:
    """The package's source (every .py file) and the versions of what traces and compiles programs,
    hashed once per process."""
    with _LOCK:
        if not _PROCESS:
            import jaxlib

            root = Path(__file__).resolve().parents[1]
            source = hashlib.sha256()
            for path in sorted(root.rglob("*.py")):
                source.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
            _PROCESS.append(";".join([f"format {FORMAT}", source.hexdigest(), sys.version, jax.__version__,
                                      jaxlib.__version__, np.__version__]))
        return _PROCESS[0]


def _setting_name() -> str:
    """JAX's settings, XLA's flags and the devices, as they are now."""
    devices = [(d.id, d.platform, d.device_kind, d.process_index) for d in jax.devices()]
    client = jax.devices()[0].client
    settings = sorted((k, repr(v)) for k, v in jax.config.values.items())
    return repr((devices, client.platform_version, os.environ.get("XLA_FLAGS", ""), settings))


def program_name(kind: str, identity, args) -> str | None:
    """The file name (a hash) of a program of `kind` made from `identity` for inputs `args`; None
    where some part of them has no name that holds across processes."""
    try:
        text = "\n".join([kind, name_of(identity), inputs_name(args), _process_name(), _setting_name()])
    except Unnamed:
        return None
    return hashlib.sha256(text.encode()).hexdigest()


def load_or_build(kind: str, identity, args, build: Callable[[], jax.stages.Compiled],
                  platform: str | None = None) -> tuple[jax.stages.Compiled, bool]:
    """(the compiled program, whether it was loaded): loaded from `folder` where a program of this
    `kind`, `identity` and inputs' types, for `platform` (default: JAX's default backend), was kept
    by an earlier process, else `build()` (lower and compile) and kept for the next one."""
    where = folder(platform)
    name = program_name(kind, identity, args) if where is not None else None
    if name is None:
        return build(), False
    path = where / f"{name}.bin"
    program = _load(path)
    if program is not None:
        return program, True
    program = build()
    _keep(path, program)
    return program, False


def remembered(kind: str, identity, compute: Callable[[], str | None]) -> str | None:
    """`compute()`, a text or None that `identity`, the package's source, the versions and the
    settings decide, computed once across processes where the cache is on: kept as a file in
    `folder` (a probe of what this JAX can lower, say)."""
    where = folder()
    name = program_name(kind, identity, ()) if where is not None else None
    if name is None:
        return compute()
    path = where / f"{name}.json"
    try:
        return json.loads(path.read_text())["answer"]
    except (OSError, ValueError, KeyError, TypeError):
        pass
    answer = compute()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        part = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.part")
        part.write_text(json.dumps({"answer": answer}))
        os.replace(part, path)
    except OSError:
        pass
    return answer


def _load(path: Path):
    from jax.experimental.serialize_executable import deserialize_and_load

    try:
        data = path.read_bytes()
    except OSError:
        return None
    try:
        payload, in_tree, out_tree = pickle.loads(zlib.decompress(data))
        program = deserialize_and_load(payload, in_tree, out_tree)
    except Exception:  # noqa: BLE001 (a damaged or outdated file: built again)
        path.unlink(missing_ok=True)
        return None
    try:
        os.utime(path)  # recently used (`_prune`)
    except OSError:
        pass
    return program


def _keep(path: Path, program) -> None:
    """Write the program's file (whole or not at all); a program that cannot be serialized (one
    with constants of its own) or a folder that cannot be written is left out."""
    from jax.experimental.serialize_executable import serialize

    try:
        payload, in_tree, out_tree = serialize(program)
        data = zlib.compress(pickle.dumps((payload, in_tree, out_tree)), 1)
        path.parent.mkdir(parents=True, exist_ok=True)
        part = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.part")
        part.write_bytes(data)
        os.replace(part, path)
    except Exception:  # noqa: BLE001 (not kept: the next process builds it again)
        return
    _prune(path.parent)


def _prune(where: Path) -> None:
    """Remove the least recently used files (programs and answers) beyond `MAX_FILES`."""
    try:
        files = [(p.stat().st_mtime, p) for p in where.iterdir() if p.suffix in (".bin", ".json")]
    except OSError:
        return
    if len(files) <= MAX_FILES:
        return
    for _, p in sorted(files)[:len(files) - MAX_FILES]:
        p.unlink(missing_ok=True)

