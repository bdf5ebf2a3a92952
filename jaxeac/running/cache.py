"""A persistent cache of compiled programs, so a command's second run skips XLA's compile.

JAX can keep every compiled executable on disk (its ``jax_compilation_cache_dir``); the
key covers the program, the devices, the flags and the JAX/jaxlib versions, so an entry
is only reused where it is exactly the same program. The `jaxeac` command turns it on
(`use_compilation_cache`); per-seed results do not depend on it (it stores the same
executable XLA would build again). ``JAXEAC_COMPILATION_CACHE`` picks the folder, or
turns it off with ``off``; a ``JAX_COMPILATION_CACHE_DIR`` already set is left to JAX.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV = "JAXEAC_COMPILATION_CACHE"
OFF = ("", "0", "off", "false", "no")
#: Programs that compile faster than this are not worth a file (XLA's own default is 1 s,
#: which would leave out the statistics' programs that take 0.2-0.9 s each on a GPU).
MIN_COMPILE_SECONDS = 0.2


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/jaxeac/xla`` (``~/.cache/jaxeac/xla`` when unset)."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "jaxeac" / "xla"


def use_compilation_cache() -> str | None:
    """Turn JAX's persistent compilation cache on at `default_cache_dir` (or the folder in
    ``JAXEAC_COMPILATION_CACHE``); returns the folder, or None when off or left to JAX.
    A folder that cannot be created leaves the cache off (compiles still work)."""
    import jax

    choice = os.environ.get(ENV)
    if os.environ.get("JAX_COMPILATION_CACHE_DIR") or (choice is not None and choice.lower() in OFF):
        return None
    folder = Path(choice) if choice else default_cache_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    return str(folder)
