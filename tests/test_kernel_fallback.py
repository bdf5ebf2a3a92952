"""When Pallas's Triton backend is gone or cannot lower the fused kernel (`jaxeac.running.kernel`):
`kernel="auto"` runs XLA ops with one warning per process, `kernel="pallas"` is one clear error.

The missing backend is simulated in a subprocess (its module made unimportable); the lowering
failure by making the kernel's builder raise. Per-seed results are those of XLA ops either way.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest

from jaxeac.algorithm.config import algorithm
from jaxeac.envs.grid import GridWorld, get_map
from jaxeac.errors import UsageError
from jaxeac.running import config as config_module
from jaxeac.running import kernel as kernel_module
from jaxeac.running.batch import run_seeds
from jaxeac.running.config import RunConfig, resolved_kernel

ENV = GridWorld(get_map("paper"), 40)

MISSING_BACKEND = textwrap.dedent("""
    import sys, warnings
    sys.modules["jax.experimental.pallas.triton"] = None  # as in a JAX without the Triton backend
    import numpy as np
    from jaxeac.algorithm.config import algorithm
    from jaxeac.cli.process import run_command
    from jaxeac.envs import make
    from jaxeac.envs.grid import GridWorld, get_map
    from jaxeac.errors import UsageError
    from jaxeac.running.batch import run_seeds
    from jaxeac.running.config import RunConfig

    env = GridWorld(get_map("paper"), 40)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for algo in ("ac", "eac", "eac_failure_only"):  # every config, every chunk: one warning
            for _ in range(3):
                cfg = RunConfig(trials=10, agent=algorithm(algo)).resolve(env, 1 << 20, "gpu")
                assert cfg.kernel == "xla", cfg
        task = RunConfig(trials=10, agent=algorithm("eac")).resolve(make("FourRooms-v0"), 4096, "gpu")
        assert task.kernel == "xla"
    texts = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    print("WARNINGS", len(texts))
    print("WARNING", texts[0])
    try:
        RunConfig(trials=10, agent=algorithm("eac", tables="rows"), kernel="pallas").resolve(env)
    except UsageError as exc:
        print("ERROR", exc)

    def command(argv, cleanup):
        RunConfig(trials=10, agent=algorithm("eac", tables="rows"), kernel="pallas").resolve(env, 256, "gpu")
        return 0
    print("EXIT", run_command([], command))

    runs = [run_seeds(env, RunConfig(trials=20, agent=algorithm("eac"), kernel=k), root_key=3, n_seeds=64,
                      chunk_size=64) for k in ("auto", "xla")]
    same = all((np.asarray(getattr(runs[0], f)) == np.asarray(getattr(runs[1], f))).all()
               for f in ("success", "steps", "policy"))
    print("SAME", same)
""")


def test_missing_triton_backend_falls_back_once_or_errors():
    """A JAX without `jax.experimental.pallas.triton`: the package imports; `auto` on a GPU picks XLA
    ops with one warning for the whole process; `pallas` is a `UsageError` (the command line's one
    ``error:`` line, exit 2) naming the cause and ``kernel='xla'``; runs are unchanged."""
    done = subprocess.run([sys.executable, "-c", MISSING_BACKEND], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    out = dict(line.split(" ", 1) for line in done.stdout.splitlines())
    assert out["WARNINGS"] == "1"
    assert out["WARNING"].startswith("kernel='auto' runs XLA ops instead of the fused GPU kernel (the same "
                                     "per-seed results, slower): Pallas's Triton backend cannot be imported")
    assert "jax.experimental.pallas.triton" in out["WARNING"] and "kernel='xla'" in out["WARNING"]
    assert out["ERROR"].startswith("kernel='pallas' cannot run: Pallas's Triton backend cannot be imported")
    assert out["ERROR"].endswith("use kernel='xla' (the same per-seed results as XLA ops) or 'auto'")
    assert out["EXIT"] == "2"
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "kernel='pallas' cannot run" in errors[0] and "kernel='xla'" in errors[0]
    assert out["SAME"] == "True"


@pytest.fixture
def broken_lowering(monkeypatch):
    """The kernel's builder raises, as a Triton lowering that no longer works would."""
    def build(*args, **kwargs):
        raise NotImplementedError("the Triton lowering is gone")

    monkeypatch.setattr(kernel_module, "_build", build)
    monkeypatch.setattr(kernel_module, "_PROBED", {})
    monkeypatch.setattr(config_module, "_fallback_warned", False)
    yield
    kernel_module._PROBED.clear()  # answers given under the broken builder are not kept


def test_lowering_failure_falls_back_once_or_errors(broken_lowering):
    eac = RunConfig(trials=10, agent=algorithm("eac", tables="rows"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert resolved_kernel(ENV, eac, "gpu") == "xla"
        assert resolved_kernel(ENV, eac, "gpu") == "xla"
        assert RunConfig(trials=10, agent=algorithm("ac")).resolve(ENV, 1 << 20, "gpu").kernel == "xla"
        assert resolved_kernel(ENV, eac, "cpu") == "xla"
    fallbacks = [w for w in caught if issubclass(w.category, RuntimeWarning)]  # (not a deprecation of JAX's)
    assert [str(w.message) for w in fallbacks] == [
        "kernel='auto' runs XLA ops instead of the fused GPU kernel (the same per-seed results, slower): "
        "Pallas's Triton backend could not lower the fused kernel in JAX " + kernel_module.jax.__version__
        + " (NotImplementedError: the Triton lowering is gone). Pass kernel='xla' to choose XLA ops "
        "without this warning."]
    with pytest.raises(UsageError, match=r"^kernel='pallas' cannot run: Pallas's Triton backend could not "
                                         r"lower the fused kernel .*\(NotImplementedError: the Triton "
                                         r"lowering is gone\); use kernel='xla'"):
        pallas = RunConfig(trials=10, agent=algorithm("eac", tables="rows"), kernel="pallas")
        resolved_kernel(ENV, pallas, "gpu")


def test_fallback_runs_are_xla_runs(broken_lowering):
    """The fallback is XLA ops: a run resolved for a GPU under the broken lowering gives the
    per-seed results of ``kernel='xla'``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        auto = RunConfig(trials=20, agent=algorithm("eac", tables="rows")).resolve(ENV, 64, "gpu")
    assert auto.kernel == "xla"
    runs = [run_seeds(ENV, cfg, root_key=3, n_seeds=64, chunk_size=64)
            for cfg in (auto, RunConfig(trials=20, agent=algorithm("eac", tables="rows"), kernel="xla"))]
    for field in ("success", "steps", "policy"):
        np.testing.assert_array_equal(getattr(runs[0], field), getattr(runs[1], field))


def test_the_kernel_lowers_in_this_jax():
    """This JAX's Triton backend lowers the kernel (for CUDA, from the CPU), so `auto` keeps it."""
    for algo in ("ac", "eac", "eac_failure_only"):
        cfg = RunConfig(trials=10, agent=algorithm(algo, tables="rows"))
        assert config_module._backend_problem(ENV, cfg, "gpu") is None
        assert resolved_kernel(ENV, cfg, "gpu") == "pallas"


DIALECT_LOOKUPS = textwrap.dedent("""
    import hashlib, importlib.abc, json, sys
    tried = []  # the Triton dialect's module, looked up by the name MLIR's bindings import

    class Tried(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path, target=None):
            if name.rsplit(".", 1)[-1] == "tt":
                tried.append(name)

    sys.meta_path.insert(0, Tried())
    from jaxeac.algorithm.config import algorithm
    from jaxeac.envs.grid import GridWorld, get_map
    from jaxeac.running import kernel
    from jaxeac.running.config import RunConfig, _kernel_config

    if sys.argv[1] == "as-before":
        kernel._name_triton_dialect = lambda: None
    env, texts = GridWorld(get_map("paper"), 40), []
    for algo in ("ac", "eac"):
        run = _kernel_config(env, RunConfig(trials=10, agent=algorithm(algo, tables="rows")), "gpu")
        texts.append(hashlib.sha256(kernel._lower(env, run, "cuda").as_text().encode()).hexdigest())
    print(json.dumps([len(tried), texts]))
""")


def test_the_kernels_lowering_finds_the_triton_dialect_at_its_first_lookup():
    """Lowering the kernel (for CUDA, from the CPU) imports the Triton dialect's module under the
    name MLIR's bindings look for once (`kernel._name_triton_dialect`), where it failed three times
    per op before (hundreds of imports through the import lock); the kernel is the same, byte
    for byte."""
    seen = {}
    for how in ("named", "as-before"):
        proc = subprocess.run([sys.executable, "-c", DIALECT_LOOKUPS, how], capture_output=True, text=True,
                              timeout=600)
        assert proc.returncode == 0, proc.stderr[-2000:]
        seen[how] = json.loads(proc.stdout.splitlines()[-1])
    assert seen["named"][0] <= 1 and seen["as-before"][0] > 500, seen
    assert seen["named"][1] == seen["as-before"][1]
