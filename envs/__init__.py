"""Deprecated: the environments moved to `jaxeac.envs` (this alias goes in the next release).

``import envs.grid`` and ``from envs.bowling import ...`` still work, with a
`DeprecationWarning`, and give the very same modules as `jaxeac.envs`.
"""

import importlib
import sys
import warnings

warnings.warn("the top-level package 'envs' moved to 'jaxeac.envs'; import from there",
              DeprecationWarning, stacklevel=2)

for _name in ("grid", "bowling", "bowling.api", "bowling.scene", "bowling.backend_c", "bowling.backend_mjx",
              "bowling.render", "bowling.throw_command"):
    sys.modules[f"envs.{_name}"] = importlib.import_module(f"jaxeac.envs.{_name}")
grid = sys.modules["envs.grid"]
bowling = sys.modules["envs.bowling"]
