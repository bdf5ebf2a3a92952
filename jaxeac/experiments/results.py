"""Deprecated: the run folder's results file moved to `jaxeac.results` (data, not an experiment,
so the statistics read it without importing the experiments). Kept for one release: every name
is looked up there, with a `DeprecationWarning`."""

from __future__ import annotations

import warnings


def __getattr__(name: str):
    if name.startswith("__"):
        raise AttributeError(name)
    from jaxeac import results

    if not hasattr(results, name):
        raise AttributeError(f"module 'jaxeac.experiments.results' has no attribute {name!r} "
                             "(it moved to jaxeac.results)")
    warnings.warn(f"jaxeac.experiments.results.{name} moved to jaxeac.results.{name}; the old path goes in "
                  "the next release", DeprecationWarning, stacklevel=2)
    return getattr(results, name)
