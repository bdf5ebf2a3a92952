"""A rerun with a warm compilation cache compiles nothing.

Two processes run the same small study with one cache folder. The second must load every program:
each of XLA's compile requests answered by JAX's persistent cache and no new file in the folder.
On GPUs the chunk and E8 programs are also kept whole (`jaxeac.running.programs`), so a rerun does
not trace them; on the CPU they are not kept (`programs.KEPT_PLATFORMS`), which is tested here.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from jaxeac.running import programs

# Counts jax.monitoring's events in a `jaxeac` command (the process's settings applied first, as
# the console script does) and prints them as one JSON line.
_COUNTING = r"""
import collections, json, sys
from jaxeac import runtime
runtime.configure(sys.argv[1], force=True)
import jax.monitoring as monitoring
counts = collections.Counter()
monitoring.register_event_listener(lambda name, **kw: counts.update([name]))
def duration(name, seconds, fun_name=None, **kw):
    counts.update([name])
    if name == "/jax/core/compile/jaxpr_trace_duration":
        counts.update([f"traced {fun_name}"])
monitoring.register_event_duration_secs_listener(duration)
from jaxeac.cli import main
code = main(sys.argv[1:])
print("COUNTS " + json.dumps(counts))
sys.exit(code)
"""


def _study(cache, out) -> dict:
    env = {**os.environ, "JAXEAC_COMPILATION_CACHE": str(cache), "MPLBACKEND": "Agg"}
    args = ["study", "--tasks", "FrozenLake-4x4-v1", "CliffWalking-v1", "--algos", "ac", "eac",
            "--seeds", "20", "--resamples", "400", "--quiet", "--out", str(out)]
    done = subprocess.run([sys.executable, "-c", _COUNTING, *args], env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    line = next(x for x in done.stdout.splitlines() if x.startswith("COUNTS "))
    return json.loads(line.removeprefix("COUNTS "))


def _files(folder) -> set:
    return {str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()}


def test_a_warm_rerun_compiles_nothing(tmp_path):
    cache = tmp_path / "cache"
    first = _study(cache, tmp_path / "first")
    assert first.get("traced batch", 0) > 0  # the run and E8 programs, built
    kept = _files(cache)
    assert kept and not any(name.startswith(programs.FOLDER + "/") for name in kept)  # none kept whole on CPUs

    second = _study(cache, tmp_path / "second")
    requests = second.get("/jax/compilation_cache/compile_requests_use_cache", 0)
    assert requests > 0 and second.get("/jax/compilation_cache/cache_hits", 0) == requests  # no XLA compile
    assert second.get("/jax/compilation_cache/cache_misses", 0) == 0
    assert _files(cache) == kept

    for name in ("first", "second"):  # the same per-seed results, loaded or built
        study = json.loads((tmp_path / name / "study.json").read_text())
        study.pop("timeline")
        if name == "first":
            want = study
        else:
            assert study == want


def test_names_hold_across_processes_or_refuse():
    from jaxeac.running.config import RunConfig

    cfg = RunConfig(trials=3, agent=__import__("jaxeac").algorithm("eac"))
    assert programs.name_of(cfg) == programs.name_of(RunConfig(trials=3, agent=cfg.agent))
    assert programs.name_of(np.arange(3)) != programs.name_of(np.arange(1, 4))
    assert programs.name_of(0.1) != programs.name_of(math.nextafter(0.1, 1.0))  # every bit counts
    with pytest.raises(programs.Unnamed):
        programs.name_of(object())
    with pytest.raises(programs.Unnamed):
        programs.name_of(lambda t: t)  # a schedule: named by nothing that holds in another process


def test_an_answer_is_computed_once_across_processes(tmp_path, monkeypatch):
    from jaxeac.running.config import RunConfig

    monkeypatch.setattr(programs, "folder", lambda: tmp_path)
    cfg = RunConfig(trials=3, agent=__import__("jaxeac").algorithm("eac"))
    calls = []

    def probe():
        calls.append(1)
        return "cannot lower"

    assert programs.remembered("probe", (cfg, "gpu"), probe) == "cannot lower"
    assert programs.remembered("probe", (cfg, "gpu"), probe) == "cannot lower"  # read from its file
    assert programs.remembered("probe", (cfg, "cuda"), lambda: None) is None
    assert len(calls) == 1 and len(list(tmp_path.glob("*.json"))) == 2
    assert programs.remembered("probe", (object(),), lambda: "unnamed: computed") == "unnamed: computed"


def test_programs_are_kept_whole_on_gpus_only(tmp_path, monkeypatch):
    """An XLA:CPU executable loaded in another process can lack kernels compiled earlier in its
    writer's process (a second `jaxeac reproduce --quick` failed with "NOT_FOUND: Function
    wrapped_iota not found"), so the store is off where the backend is the CPU."""
    import jax

    before = jax.config.jax_compilation_cache_dir, jax.config.jax_enable_compilation_cache
    jax.config.update("jax_compilation_cache_dir", str(tmp_path))
    jax.config.update("jax_enable_compilation_cache", True)
    try:
        assert jax.default_backend() == "cpu" and programs.folder() is None
        built = []
        program, loaded = programs.load_or_build("test", (1, 2), (), lambda: built.append(1) or "built")
        assert (program, loaded, built) == ("built", False, [1]) and not list(tmp_path.iterdir())
        monkeypatch.setattr(programs, "KEPT_PLATFORMS", ("cpu",))
        assert programs.folder() == tmp_path / programs.FOLDER
    finally:
        jax.config.update("jax_compilation_cache_dir", before[0])
        jax.config.update("jax_enable_compilation_cache", before[1])
