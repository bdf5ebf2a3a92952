"""Module paths of release 0.1, kept importable for one release with a `DeprecationWarning`.

The package was reorganised (docs/ARCHITECTURE.md): `jaxeac.runner` became
`jaxeac.running` and `jaxeac.rng`, `jaxeac.agent` / `jaxeac.memory` moved under
`jaxeac.algorithm`, the experiments under `jaxeac.experiments`, and the top-level
`envs` package into `jaxeac.envs`. An old path imports a stand-in module whose
attributes are looked up, on first use, in the modules that now hold them.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import types
import warnings

#: old module → the modules that hold its names now (searched in order).
MOVED: dict[str, tuple[str, ...]] = {
    "jaxeac.agent": ("jaxeac.algorithm.agent", "jaxeac.algorithm.tables", "jaxeac.algorithm.config"),
    "jaxeac.memory": ("jaxeac.algorithm.memory",),
    "jaxeac.runner": ("jaxeac.running.batch", "jaxeac.running.loops", "jaxeac.running.config",
                      "jaxeac.running.outputs", "jaxeac.rng"),
    "jaxeac.kernel": ("jaxeac.running.kernel",),
    "jaxeac.experiment": ("jaxeac.experiments.grid", "jaxeac.experiments.common"),
    "jaxeac.bowling": ("jaxeac.experiments.bowling",),
    "jaxeac.sweep": ("jaxeac.experiments.sweep",),
    "jaxeac.presets": ("jaxeac.experiments.presets",),
    "jaxeac.reproduce": ("jaxeac.experiments.reproduce",),
}


def _stand_in(old: str, new: tuple[str, ...]) -> types.ModuleType:
    module = types.ModuleType(old, f"Deprecated: moved to {', '.join(new)}.")

    def __getattr__(name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        for target in new:
            try:
                mod = importlib.import_module(target)
            except ModuleNotFoundError:
                continue
            if hasattr(mod, name):
                warnings.warn(f"{old}.{name} moved to {target}.{name}; the old path goes in the next "
                              "release", DeprecationWarning, stacklevel=2)
                return getattr(mod, name)
        raise AttributeError(f"module {old!r} has no attribute {name!r} (it moved to {', '.join(new)})")

    module.__getattr__ = __getattr__
    return module


class _MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports each old path in `MOVED` as its stand-in module."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname in MOVED:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        return _stand_in(spec.name, MOVED[spec.name])

    def exec_module(self, module):
        pass


def install() -> None:
    """Put the finder of old paths on `sys.meta_path` (once)."""
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        sys.meta_path.append(_MovedFinder())
