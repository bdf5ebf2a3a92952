"""Running many seeds: `RunConfig` (resolved once), the per-seed loops, the fused GPU kernel, chunks,
and the memory diagnostics of a run's seeds (`jaxeac.running.diagnostics`, SPEC E8).

Internal: the public names are `jaxeac.RunConfig` and `jaxeac.run`. See docs/ARCHITECTURE.md for
the flow of one run.
"""

import importlib
import warnings

#: names this package re-exported in release 0.1 -> (module that holds it, its public spelling)
_MOVED = {
    "RunConfig": ("jaxeac.running.config", "jaxeac.RunConfig"),
    "SeedsResult": ("jaxeac.running.outputs", "the result of jaxeac.run"),
    "run_seeds": ("jaxeac.running.batch", "jaxeac.run"),
    "run_entries": ("jaxeac.running.batch", "jaxeac.run"),
}


def __getattr__(name: str):
    if name in _MOVED:
        module, public = _MOVED[name]
        warnings.warn(f"jaxeac.running.{name} is internal; use {public} (the old path goes in the next "
                      "release)", DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(module), name)
    raise AttributeError(f"module 'jaxeac.running' has no attribute {name!r}")
