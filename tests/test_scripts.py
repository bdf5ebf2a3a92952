"""The benchmark scripts behind BENCHMARKS.md still run and render, at toy sizes.

Each runs as a subprocess, as a user would run it (the scripts set XLA flags before JAX
starts). Sizes are tiny: these check the plumbing and the records' shape, not speed.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _script(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=ROOT, env=env,
                          timeout=600)


def test_bench_writes_a_record_with_the_peer_beside_jaxeac(tmp_path):
    out = tmp_path / "grid.json"
    proc = _script("scripts/bench.py", "--seeds", "60", "--numpy-seeds", "60", "--chunk", "64",
                   "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    rec = json.loads(out.read_text())
    assert rec["command"].startswith("python scripts/bench.py --seeds 60")
    assert [(r["impl"], r["algo"]) for r in rec["rows"]] == [  # the peer right after its jaxeac row
        ("jaxeac", "ac"), ("numpy", "ac"), ("jaxeac", "eac"), ("numpy", "eac")]
    for r in rec["rows"]:
        assert r["seeds"] == 60 and r["agent_steps"] > 0
        assert abs(r["steps_per_s"] - r["agent_steps"] / r["run_s"]) < 1e-6 * r["steps_per_s"]
    table = _script("scripts/bench.py", "--render", str(out))
    assert table.returncode == 0, table.stderr[-2000:]
    assert "| jaxeac | eac | split | xla, jumps | 60 |" in table.stdout  # EAC jumps by default
    assert "jaxeac / NumPy peer (same run, same seeds): AC at 60 seeds:" in table.stdout


def test_bench_algos_runs_only_the_methods_named(tmp_path):
    out = tmp_path / "eac.json"
    proc = _script("scripts/bench.py", "--algos", "eac", "--seeds", "40", "--numpy-seeds", "40", "--chunk", "64",
                   "--repeats", "1", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = json.loads(out.read_text())["rows"]
    assert [(r["impl"], r["algo"]) for r in rows] == [("jaxeac", "eac"), ("numpy", "eac")]


def test_bench_compares_builds_taking_turns(tmp_path):
    """`--builds`: each source tree's jaxeac rows, the builds taking turns each round, labelled by
    directory, with a line per row kind giving each build's best rate against the first build's."""
    import shutil

    builds = []
    for name in ("one", "two"):
        shutil.copytree(ROOT / "jaxeac", tmp_path / name / "jaxeac",
                        ignore=shutil.ignore_patterns("__pycache__"))
        builds.append(str(tmp_path / name))
    out = tmp_path / "builds.json"
    proc = _script("scripts/bench.py", "--seeds", "40", "--chunk", "64", "--repeats", "1",
                   "--builds", *builds, "--rounds", "2", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    rec = json.loads(out.read_text())
    assert rec["builds"] == ["one", "two"]
    assert [(r["build"], r["round"], r["algo"]) for r in rec["rows"]] == [
        (b, i, a) for i in (0, 1) for b in ("one", "two") for a in ("ac", "eac")]
    # each build's own package, even under the editable install of this checkout
    assert {(r["build"], r["jaxeac_from"]) for r in rec["rows"]} == {(b, str((tmp_path / b).resolve()))
                                                                      for b in ("one", "two")}
    table = _script("scripts/bench.py", "--render", str(out)).stdout
    assert "| jaxeac two | eac |" in table and "AC at 40 seeds, best of 2 rounds: one " in table
    assert "×** one)" in table


def test_check_kernel_compares_every_seed_and_renders(tmp_path):
    out = tmp_path / "check.json"
    proc = _script("scripts/check_kernel.py", "--seeds", "40", "--trials", "6", "--algos", "eac",
                   "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "identical for every seed" in proc.stdout
    rec = json.loads(out.read_text())
    assert rec["all_identical"] is True
    assert rec["rows"][0]["seeds_identical_success_and_steps"] == 40
    table = _script("scripts/bench.py", "--render", str(out))
    assert "| eac | 40 | 6 | 40 |" in table.stdout
    bad = _script("scripts/check_kernel.py", "--seeds", "0")
    assert bad.returncode == 2 and "--seeds and --trials must be ≥ 1" in bad.stderr


def test_check_kernel_runs_registered_tasks(tmp_path):
    out = tmp_path / "check.json"
    proc = _script("scripts/check_kernel.py", "--envs", "CliffWalking-v1", "--seeds", "40", "--trials", "6",
                   "--algos", "ac", "eac", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    rec = json.loads(out.read_text())
    assert [(r["env"], r["algo"], r["seeds_identical_success_and_steps"]) for r in rec["rows"]] == [
        ("CliffWalking-v1", "ac", 40), ("CliffWalking-v1", "eac", 40)]
    table = _script("scripts/bench.py", "--render", str(out)).stdout
    assert "| CliffWalking-v1 | eac | 40 | 6 | 40 |" in table


def test_bench_tasks_records_every_task_and_algorithm(tmp_path):
    out = tmp_path / "tasks.json"
    proc = _script("scripts/bench_tasks.py", "--seeds", "20", "--tasks", "FrozenLake-4x4-v1",
                   "grid-paper-v0:slip=0.1", "--algos", "ac", "sarsa", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    rec = json.loads(out.read_text())
    assert [t["task"] for t in rec["tasks"]] == ["FrozenLake-4x4-v1", "grid-paper-v0:slip=0.1"]
    for t in rec["tasks"]:
        assert [r["algo"] for r in t["rows"]] == ["ac", "sarsa"]
        assert t["wall_s"] == sum(r["compile_s"] + r["run_s"] for r in t["rows"])
        assert all(r["agent_steps"] > 0 and r["kernel"] == "xla" for r in t["rows"])
    assert [t["deterministic"] for t in rec["tasks"]] == [True, False]
    table = _script("scripts/bench_tasks.py", "--render", str(out))
    assert "| FrozenLake-4x4-v1 | 100 |" in table.stdout and "| grid-paper-v0:slip=0.1 | 40 |" in table.stdout


def test_bench_tasks_can_turn_memory_jumps_off(tmp_path):
    """`--jump off`: EAC on a deterministic task, where jumps are on by default, runs without them
    (the record says so) and reaches the same results (the steps it counts are the same); `--lanes`
    sets the seeds in flight."""
    rows = {}
    for jump, lanes in (("auto", []), ("off", ["--lanes", "8"])):  # lanes: seeds in flight, same results
        out = tmp_path / f"{jump}.json"
        proc = _script("scripts/bench_tasks.py", "--seeds", "20", "--tasks", "FrozenLake-4x4-v1",
                       "--algos", "eac", "--jump", jump, *lanes, "--out", str(out))
        assert proc.returncode == 0, proc.stderr[-2000:]
        rows[jump] = json.loads(out.read_text())["tasks"][0]["rows"][0]
    assert rows["auto"]["jump"] == "on" and rows["off"]["jump"] == "off"
    assert rows["auto"]["lanes"] == 256 and rows["off"]["lanes"] == 8  # default: 256 per core
    assert rows["auto"]["agent_steps"] == rows["off"]["agent_steps"]
    assert rows["auto"]["mean_successes"] == rows["off"]["mean_successes"]


def test_bench_bowling_standalone_warp_without_warp_is_refused(tmp_path):
    """`bench_bowling.py --backends mujoco_warp` needs what the warp backend needs (warp-lang,
    an NVIDIA GPU): without it, argparse's usage error naming the fix and no record."""
    import importlib.util

    if importlib.util.find_spec("warp") is not None:
        pytest.skip("warp-lang is installed here")
    out = tmp_path / "b.json"
    proc = _script("scripts/bench_bowling.py", "--backends", "mujoco_warp", "--out", str(out))
    assert proc.returncode == 2
    assert 'pip install "jaxeac[warp]"' in proc.stderr.splitlines()[-1], proc.stderr[-500:]
    assert not out.exists()


@pytest.mark.parametrize("name", ["bench", "bench_tasks", "bench_stats", "bench_bowling", "e2e", "scale",
                                  "check_kernel", "figures"])
def test_every_benchmark_script_documents_itself(name):
    """Each kept benchmark answers --help with its usage and exits 0."""
    proc = _script(f"scripts/{name}.py", "--help")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.startswith("usage:")


def test_figures_are_drawn_from_the_kept_records(tmp_path):
    """scripts/figures.py reads only scripts/bench_results/ and writes its three PNGs."""
    pytest.importorskip("matplotlib")
    proc = _script("scripts/figures.py", "--out", str(tmp_path))
    assert proc.returncode == 0, proc.stderr[-2000:]
    for name in ("throughput_vs_seeds.png", "end_to_end_vs_seeds.png", "peers.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.skipif(not Path("/proc/self/statm").exists(), reason="reads /proc")
def test_e2e_measures_the_peak_of_a_commands_processes_together():
    """`e2e.TreePeak`: the resident memory of a process and its child, summed while both hold theirs
    (a study's helper beside its process), and nothing of the processes around them."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("e2e", ROOT / "scripts" / "e2e.py")
    e2e = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(e2e)
    child = "import time; b = bytearray(160 * 2**20); b[::4096] = b'x' * len(b[::4096]); time.sleep(1.5)"
    parent = (f"import subprocess, sys; a = bytearray(240 * 2**20); a[::4096] = b'y' * len(a[::4096]); "
              f"subprocess.run([sys.executable, '-c', {child!r}])")
    proc = subprocess.Popen([sys.executable, "-c", parent])
    together = e2e.TreePeak(proc.pid)
    proc.wait()
    # both at once (each alone holds under 300 MiB); not this test's own process (its caller's memory)
    assert 400 * 2**20 <= together.stop() < 600 * 2**20


def test_e2e_builds_take_turns_first_runs_then_cached_rounds(tmp_path, monkeypatch):
    """`e2e.builds_record`: each round runs every build once, with an empty cache for its first runs
    and its own cache kept for the cached rounds (``cached``: the first, ``cached_runs``: all)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("e2e", ROOT / "scripts" / "e2e.py")
    e2e = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(e2e)
    calls = []

    def fake(argv, env):
        calls.append((Path(env["PYTHONPATH"]).name, Path(env["JAXEAC_COMPILATION_CACHE"]).name))
        return {"wall_s": float(len(calls))}

    monkeypatch.setattr(e2e, "jaxeac", fake)
    builds = [tmp_path / "old", tmp_path / "new"]
    rows = e2e.builds_record(tmp_path, 10, builds, repeats=2, cached_repeats=3)["builds"]
    assert calls[:4] == [("old", "xla_cache_build0_0"), ("new", "xla_cache_build1_0"),
                         ("old", "xla_cache_build0_1"), ("new", "xla_cache_build1_1")]
    assert calls[4:] == [("old", "xla_cache_build0_1"), ("new", "xla_cache_build1_1")] * 3
    assert [r["wall_s"] for r in rows[str(builds[1])]["first_runs"]] == [2.0, 4.0]
    assert [r["wall_s"] for r in rows[str(builds[1])]["cached_runs"]] == [6.0, 8.0, 10.0]
    assert rows[str(builds[1])]["cached"] == {"wall_s": 6.0}
    once = e2e.builds_record(tmp_path, 10, builds, repeats=1)["builds"]
    assert "cached_runs" not in once[str(builds[0])] and "cached" in once[str(builds[0])]
