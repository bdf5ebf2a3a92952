"""The house: environment registry, deprecated import paths, and the layers of the package with no
import cycles (docs/ARCHITECTURE.md)."""

from __future__ import annotations

import ast
import dataclasses
import functools
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


def test_results_module_moved_to_base_with_a_warning():
    import jaxeac.experiments.results as old
    import jaxeac.results

    with pytest.warns(DeprecationWarning, match="moved to jaxeac.results.load_grid_results"):
        assert old.load_grid_results is jaxeac.results.load_grid_results
    with pytest.raises(AttributeError, match="moved to jaxeac.results"):
        old.no_such_name  # noqa: B018


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


@dataclasses.dataclass(frozen=True)
class Import:
    """One import of a jaxeac module by another, where it is written."""

    source: str  # the importing module, e.g. "jaxeac.stats.run"
    target: str  # the imported module, e.g. "jaxeac.results"
    file: str  # the importing file, relative to the repository
    line: int
    deferred: bool  # inside a function or method (run when called, not when imported)
    root_attribute: bool = False  # ``from jaxeac import __version__``: a name of the package root

    def __str__(self) -> str:
        where = "inside a function" if self.deferred else "at module level"
        return f"{self.file}:{self.line} imports {self.target} ({where})"


def _modules() -> dict[str, tuple[Path, tuple[str, ...]]]:
    """Every module of the package: dotted name → (file, path parts)."""
    modules = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = (path, parts)
    return modules


def _import_module_strings(node: ast.Call) -> list[str]:
    """The jaxeac module names a call hands to ``importlib.import_module`` (``import_module("jaxeac.x")``,
    ``pool.submit(importlib.import_module, "jaxeac.x")``) or ``__import__``: a literal name, or the
    literal head of an f-string (``f"jaxeac.envs.{name}"`` counts as ``jaxeac.envs``)."""
    def is_loader(n) -> bool:
        return ((isinstance(n, ast.Attribute) and n.attr == "import_module")
                or (isinstance(n, ast.Name) and n.id in ("import_module", "__import__")))

    if not (is_loader(node.func) or any(is_loader(a) for a in node.args)):
        return []
    names = []
    for arg in node.args:
        if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
            names.append(arg.value)
        elif isinstance(arg, ast.JoinedStr) and arg.values and isinstance(arg.values[0], ast.Constant):
            names.append(str(arg.values[0].value).rsplit(".", 1)[0])
    return [n for n in names if n == "jaxeac" or n.startswith("jaxeac.")]


def _imports_in(source: str, parts: tuple[str, ...], file: str, text: str, modules) -> list[Import]:
    """Every import of a jaxeac module in one module's text (`source`, its path `parts`): at module
    level and inside functions and methods (``ast.walk``), ``import_module`` strings included.

    ``from package import submodule`` imports the submodule; ``from package import name``
    imports the package (its ``__init__``).
    """
    def known(name: str) -> str:  # the module itself, or the closest package above a dotted name
        while name not in modules and "." in name:
            name = name.rsplit(".", 1)[0]
        return name

    tree = ast.parse(text)
    functions = [f for f in ast.walk(tree)
                 if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))]
    deferred_nodes = {id(n) for f in functions for n in ast.walk(f) if n is not f}
    found = []
    for node in ast.walk(tree):
        targets: list[tuple[str, bool]] = []  # (module, a name of the package root)
        if isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from the module's own package upwards
                package = parts[:-1]  # a module's package, or an __init__'s own
                base = package[:len(package) - node.level + 1]
                module = ".".join(base + ((node.module,) if node.module else ()))
            else:
                module = node.module or ""
            if not (module == "jaxeac" or module.startswith("jaxeac.")):
                continue
            for alias in node.names:
                sub = f"{module}.{alias.name}"
                targets.append((sub, False) if sub in modules else (known(module), module == "jaxeac"))
        elif isinstance(node, ast.Import):
            targets += [(known(a.name), False) for a in node.names
                        if a.name == "jaxeac" or a.name.startswith("jaxeac.")]
        elif isinstance(node, ast.Call):
            targets += [(known(name), False) for name in _import_module_strings(node)]
        found += [Import(source, target, file, node.lineno, id(node) in deferred_nodes, attribute)
                  for target, attribute in targets if target != source]
    return list(dict.fromkeys(found))  # one line importing two names of a module: one import


@functools.cache
def _imports() -> list[Import]:
    """Every import of a jaxeac module by a module of the package (`_imports_in`)."""
    modules = _modules()
    return [imp for source, (path, parts) in modules.items()
            for imp in _imports_in(source, parts, str(path.relative_to(PACKAGE.parent)),
                                   path.read_text(encoding="utf-8"), modules)]


#: The layers, bottom to top: a module may import its own layer and those below, never one above.
#: ``jaxeac.stats`` and ``jaxeac.plots`` share a layer (both read a run's results).
LAYERS: list[tuple[str, tuple[str, ...]]] = [
    ("base", ("jaxeac.errors", "jaxeac.pytree", "jaxeac.rng", "jaxeac.io", "jaxeac.fmt", "jaxeac.paper",
              "jaxeac.runtime", "jaxeac.bits", "jaxeac.results", "jaxeac.style", "jaxeac.rundir",
              "jaxeac.perseed", "jaxeac.sb3")),
    ("algorithm", ("jaxeac.algorithm",)),
    ("envs", ("jaxeac.envs",)),
    ("running", ("jaxeac.running",)),
    ("stats and figures", ("jaxeac.stats", "jaxeac.plots")),
    ("experiments", ("jaxeac.experiments",)),
    ("cli", ("jaxeac.cli", "jaxeac.__main__")),
    # The public face: the package root (``jaxeac`` alone, not the modules under it) and its
    # functions (`_api`) may import anything (lazily). `_compat` stands in for release 0.1's
    # module paths and looks the moved names up by their new paths, whatever their layer.
    ("root", ("jaxeac", "jaxeac._api", "jaxeac._compat")),
]

#: Imports that must never happen, at module level or inside a function: (source, target, why).
NEVER: list[tuple[str, str, str]] = [
    ("jaxeac.stats", "jaxeac.running", "statistics read results, they never run seeds"),
    ("jaxeac.stats", "jaxeac.experiments", "statistics know no experiment"),
    ("jaxeac.stats", "jaxeac.cli", "statistics know no command line"),
    ("jaxeac.plots", "jaxeac.experiments", "figures take what they draw as arguments, know no experiment"),
    ("jaxeac.running", "jaxeac.stats", "the runner computes no statistics"),
    ("jaxeac.running", "jaxeac.experiments", "the runner knows no experiment"),
    ("jaxeac.envs", "jaxeac.running", "an environment knows no runner"),
    ("jaxeac.envs", "jaxeac.experiments", "an environment knows no experiment"),
    ("jaxeac.algorithm", "jaxeac.running", "the algorithm knows no runner"),
    ("jaxeac.algorithm", "jaxeac.experiments", "the algorithm knows no experiment"),
    *[(base, above, "base modules import nothing above base") for base in LAYERS[0][1]
      for _, prefixes in LAYERS[1:-1] for above in prefixes],
]


def _under(module: str, prefix: str) -> bool:
    """Whether `module` is `prefix` or inside it (the package root ``jaxeac`` only itself)."""
    return module == prefix or (prefix != "jaxeac" and module.startswith(prefix + "."))


def _layer(module: str) -> int | None:
    hits = [(len(p), i) for i, (_, prefixes) in enumerate(LAYERS) for p in prefixes if _under(module, p)]
    return max(hits)[1] if hits else None


def _exempt(imp: Import) -> bool:
    """The package root as a source, and ``from jaxeac import __version__``-style names of it as a target."""
    return imp.source == "jaxeac" or (imp.target == "jaxeac" and imp.root_attribute)


def test_the_import_reader_reads_every_kind_of_import():
    text = """
import importlib
import jaxeac.envs.grid
from jaxeac import __version__, running
from jaxeac.stats import large, bca_ci
from ..running import outputs


class Thing:
    def method(self, pool):
        from jaxeac.experiments.grid import run_grid
        importlib.import_module("jaxeac.cli")
        pool.submit(importlib.import_module, "jaxeac.plots")
        return lambda name: importlib.import_module(f"jaxeac.envs.{name}")
"""
    modules = _modules()
    read = _imports_in("jaxeac.stats.example", ("jaxeac", "stats", "example"), "x.py", text, modules)
    found = {(i.target, i.line, i.deferred, i.root_attribute) for i in read}
    assert found == {
        ("jaxeac.envs.grid", 3, False, False),
        ("jaxeac", 4, False, True),  # __version__: a name of the root
        ("jaxeac.running", 4, False, False),  # a subpackage
        ("jaxeac.stats.large", 5, False, False),  # a submodule
        ("jaxeac.stats", 5, False, False),  # a name of the package: its __init__
        ("jaxeac.running.outputs", 6, False, False),  # relative
        ("jaxeac.experiments.grid", 11, True, False),  # inside a method
        ("jaxeac.cli", 12, True, False),
        ("jaxeac.plots", 13, True, False),
        ("jaxeac.envs", 14, True, False),  # the literal head of an f-string
    }
    stats = {i.target for i in _imports() if i.file == "jaxeac/stats/__init__.py"}
    assert {"jaxeac.stats.groups", "jaxeac.stats.compare"} <= stats


def test_every_module_has_a_layer():
    missing = sorted(m for m in _modules() if _layer(m) is None)
    assert not missing, f"module(s) in no layer of tests/test_layout.py LAYERS: {', '.join(missing)}"


def test_no_import_cycles():
    """No cycle at all, deferred imports included (the package root, which imports lazily, aside)."""
    edges: dict[str, dict[str, Import]] = {}
    for imp in _imports():
        if not _exempt(imp) and imp.target != "jaxeac":
            edges.setdefault(imp.source, {}).setdefault(imp.target, imp)
    # Tarjan's strongly connected components: every cycle lies inside one of more than one module.
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges.get(v, {}):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for module in sorted(edges):
        if module not in index:
            connect(module)

    def cycle_in(component: list[str]) -> list[Import]:  # one shortest cycle through the first module
        inside, start = set(component), component[0]
        paths = {start: []}
        queue = [start]
        while queue:
            v = queue.pop(0)
            for w, imp in sorted(edges.get(v, {}).items()):
                if w == start:
                    return paths[v] + [imp]
                if w in inside and w not in paths:
                    paths[w] = paths[v] + [imp]
                    queue.append(w)
        raise AssertionError(component)

    messages = [f"import cycle among {', '.join(c)}:\n    " + "\n    ".join(map(str, cycle_in(c)))
                for c in components]
    assert not messages, "\n".join(messages)


def test_lower_layers_never_import_higher_ones():
    problems = []
    for imp in _imports():
        if _exempt(imp):
            continue
        ls, lt = _layer(imp.source), _layer(imp.target)
        if ls is not None and lt is not None and lt > ls:
            problems.append(f"{imp}: layer {LAYERS[ls][0]!r} imports the higher layer {LAYERS[lt][0]!r} "
                            f"(rule: a layer imports only its own and lower layers)")
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("source, target, why", NEVER, ids=[f"{s}->{t}" for s, t, _ in NEVER])
def test_never_imports(source, target, why):
    problems = [f"{imp}: rule {source} never imports {target} ({why})"
                for imp in _imports() if _under(imp.source, source) and _under(imp.target, target)]
    assert not problems, "\n".join(problems)
