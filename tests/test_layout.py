"""The house: environment registry, deprecated import paths, and no import cycles (docs/ARCHITECTURE.md)."""

from __future__ import annotations

import ast
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

import jaxeac
from jaxeac.errors import UsageError

PACKAGE = Path(jaxeac.__file__).parent


def test_registry_builds_named_grid_worlds():
    names = jaxeac.registered()
    assert "grid-paper-v0" in names and names == sorted(names)
    env = jaxeac.make("grid-paper-v0", chances=25)
    assert (env.n_states, env.n_actions, env.n_chances) == (121, 4, 25)  # G1 11×11, G2, G5
    assert env.map.goal == (5, 5)
    assert jaxeac.make("grid-paper7-v0").n_states == 49


def test_registry_unknown_name_lists_the_known_ones():
    with pytest.raises(UsageError, match="unknown environment 'grid-nowhere-v0'; choose one of .*grid-paper"):
        jaxeac.make("grid-nowhere-v0")


def test_old_module_paths_warn_and_give_the_same_objects():
    from jaxeac.running.batch import run_seeds
    from jaxeac.running.config import RunConfig

    with pytest.warns(DeprecationWarning, match="jaxeac.runner.run_seeds moved to jaxeac.running.batch"):
        from jaxeac.runner import run_seeds as old_run_seeds
    assert old_run_seeds is run_seeds
    with pytest.warns(DeprecationWarning):
        from jaxeac.runner import RunConfig as old_config
    assert old_config is RunConfig
    with pytest.raises(ImportError):
        from jaxeac.runner import no_such_name  # noqa: F401


def test_top_level_envs_alias_is_the_same_module():
    code = ("import warnings; warnings.simplefilter('error')\n"
            "try:\n    import envs.grid\nexcept DeprecationWarning as e:\n    print('warned:', e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "moved to 'jaxeac.envs'" in out
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import envs.grid

        import jaxeac.envs.grid
    assert envs.grid is jaxeac.envs.grid


def _module_imports() -> dict[str, set[str]]:
    """Module → the jaxeac modules it imports at module level (imports inside functions are lazy).

    ``from package import submodule`` counts as importing the submodule.
    """
    paths = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        paths[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = (path, parts)
    graph = {}
    for name, (path, parts) in paths.items():
        deps = set()
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.ImportFrom):
                if node.level:  # relative, inside a package
                    base = parts[:len(parts) - node.level] if parts[-1] != "__init__" else parts[:-node.level]
                    module = ".".join(base + ((node.module,) if node.module else ()))
                else:
                    module = node.module or ""
                subs = [f"{module}.{a.name}" for a in node.names if f"{module}.{a.name}" in paths]
                deps.update(subs or [module])
            elif isinstance(node, ast.Import):
                deps.update(a.name for a in node.names)
        graph[name] = {d for d in deps if d.startswith("jaxeac") and d != name}
    return graph


def test_no_import_cycles():
    graph = _module_imports()
    state: dict[str, int] = {}

    def visit(node, trail):
        state[node] = 1
        for dep in graph.get(node, ()):
            if state.get(dep) == 1:
                pytest.fail("import cycle: " + " -> ".join(trail + [node, dep]))
            if dep in graph and state.get(dep) is None:
                visit(dep, trail + [node])
        state[node] = 2

    for module in sorted(graph):
        if state.get(module) is None:
            visit(module, [])


LAYERS = ["jaxeac.errors", "jaxeac.pytree", "jaxeac.rng", "jaxeac.algorithm", "jaxeac.envs", "jaxeac.running",
          "jaxeac.experiments", "jaxeac.stats"]


def test_lower_layers_never_import_higher_ones():
    def layer(module):
        hits = [i for i, prefix in enumerate(LAYERS) if module == prefix or module.startswith(prefix + ".")]
        return hits[0] if hits else None

    for module, deps in _module_imports().items():
        lm = layer(module)
        for dep in deps:
            ld = layer(dep)
            if lm is not None and ld is not None and ld > lm:
                pytest.fail(f"{module} (layer {LAYERS[lm]}) imports {dep} (higher layer {LAYERS[ld]})")
