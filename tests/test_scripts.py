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


def test_stats_memory_runs_the_grid_data_path_and_reports_its_peak(tmp_path):
    out = tmp_path / "run"
    proc = _script("scripts/stats_memory.py", "--seeds", "2500", "--base", "50", "--chunk", "1000",
                   "--out", str(out), "--reload")
    assert proc.returncode == 0, proc.stderr[-2000:]
    rec = json.loads(proc.stdout.strip().splitlines()[-1])
    assert rec["seeds_per_method"] == 2500 and rec["peak_gib"] >= rec["baseline_gib"] > 0
    assert rec["compare_dir"]["peak_gib"] >= rec["compare_dir"]["start_gib"] > 0
    assert "'summary and figures end'" in proc.stdout and "'calibrate end'" in proc.stdout
    for name in ("results.parquet", "summary.json", "stats.json", "report.md"):
        assert (out / name).is_file()


def test_bowling_landscape_records_each_scene(tmp_path):
    """scripts/bowling_landscape.py (SPEC B1a's measurement) at one throw per angle."""
    out = tmp_path / "landscape.json"
    proc = _script("scripts/bowling_landscape.py", "--scenes", "table1", "0.08:0.36", "--per-angle", "1",
                   "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    rec = json.loads(out.read_text())
    assert rec["paper_table1"]["most_pins_one_throw"] == 7 and rec["paper_table1"]["trials"] == 20
    assert list(rec["scenes"]) == ["table1", "0.08:0.36"]
    r = rec["scenes"]["table1"]
    assert (r["ball_radius"], r["pin_spacing"], r["throws"]) == (0.06, 0.4, 42)
    assert max(r["chance1_mean_per_angle"]) == r["best_chance1_mean"] <= r["most_pins_one_throw"] <= 10
    assert "| table1 | 0.06 | 0.4 |" in proc.stdout


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


def test_profile_bowling_splits_a_throw_into_phases(tmp_path):
    """`profile_bowling.py` at 3 throws: every step of the engine in one phase, the stages of a step
    as shares below 1, and the outcome final no later than the engine's stop."""
    out = tmp_path / "p.json"
    proc = _script("scripts/profile_bowling.py", "--throws", "3", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    rec = json.loads(out.read_text())
    assert rec["command"] == f"python scripts/profile_bowling.py --throws 3 --out {out}"
    steps = sum(p["steps_per_throw"] for p in rec["phases"].values())
    assert abs(steps - rec["steps_per_throw"]) < 1e-9 and rec["phases"]["settling"]["steps_per_throw"] == 10
    assert abs(sum(p["share_of_time"] for p in rec["phases"].values()) - 1) < 1e-9
    assert 0.5 < sum(rec["stages_share_of_step"].values()) <= 1.0
    assert rec["outcome_final_step_mean"] <= rec["settled_stop_step_mean"] <= 400


def test_startup_times_both_ways_of_starting_the_devices(tmp_path):
    out = tmp_path / "startup.json"
    proc = _script("scripts/startup.py", "--repeats", "1", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = json.loads(out.read_text())["rows"]
    assert [r["mode"] for r in rows] == ["serial", "thread"]
    assert all(0 < r["jax_imported_s"] <= r["modules_imported_s"] <= r["devices_ready_s"] for r in rows)


def test_cpu_loop_ops_counts_the_chance_loops_operations(tmp_path):
    out = tmp_path / "ops.json"
    proc = _script("scripts/cpu_loop_ops.py", "--algos", "ac", "eac_failure_only", "--jump", "on", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    ac, failure_only = json.loads(out.read_text())["rows"]
    assert ac["jump"] == "auto" and ac["loops"][0]["lanes"] == 256 and ac["loops"][0]["operations"] > 10
    assert "memory jumps follow the success memory" in failure_only["error"]  # no jumps without it


def _sass_csv(path: Path) -> None:
    """A toy ncu source page: two loads, a use of each, and a predicated select that keeps a loaded value."""
    head = ["Address", "Source", "Warp Stall Sampling (All Samples)", "Instructions Executed",
            "stall_long_sb", "stall_wait"]
    rows = [
        ["0x00", "LDG.E R5, desc[UR6][R2.64]", "0", "40", "0", "0"],
        ["0x10", "LDG.E R8, desc[UR6][R2.64+0x10]", "0", "40", "0", "0"],
        ["0x20", "IMAD R7, R1, 0x4, R3", "2", "40", "0", "2"],
        ["0x30", "FMUL R6, R5, 0.25", "60", "40", "50", "10"],
        ["0x40", "@P2   FSEL R8, R7, -1, !P5", "38", "40", "30", "8"],
        ["0x50", "STG.E desc[UR6][R2.64], R6", "0", "40", "0", "0"],
    ]
    path.write_text('"Kernel Name","_chance_kernel"\n' + "\n".join(",".join(f'"{x}"' for x in r)
                                                                 for r in [head, *rows]) + "\n")


def test_profile_kernel_summarizes_where_warps_wait(tmp_path):
    _sass_csv(tmp_path / "k.csv")
    out = tmp_path / "sass.json"
    proc = _script("scripts/profile_kernel.py", "--sass", str(tmp_path / "k.csv"), "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    (s,) = json.loads(out.read_text())["summaries"]
    assert s["samples"] == 100 and s["instructions"] == 6 and s["global_stores"] == 1
    assert s["stall_reasons"] == {"long_sb": 0.8, "wait": 0.2}
    assert [x["index"] for x in s["global_loads"]] == [0, 1]
    fmul, fsel = s["top_waits"]  # the IMAD has no long-scoreboard samples
    assert (fmul["long_scoreboard_share"], fmul["waits_for"]["index"]) == (0.5, 0)
    # predicated: R8 keeps its loaded value where P2 is off, so the select waits for that load
    assert (fsel["long_scoreboard_share"], fsel["waits_for"]["index"]) == (0.3, 1)
    assert "FMUL R6, R5, 0.25" in proc.stdout and "waits for [0] LDG.E R5" in proc.stdout


def _profile_cpu():
    import importlib.util

    spec = importlib.util.spec_from_file_location("profile_cpu", ROOT / "scripts" / "profile_cpu.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_profile_cpu_sorts_samples_by_what_they_landed_in():
    m = _profile_cpu()
    report = """# Samples: 1K of event 'cpu-clock'
#
    40.00%  [JIT] tid 31002                                    [.] 0x00007f04b535a074
    25.00%  libjax_common.so                                   [.] xla::cpu::ThunkExecutor::Execute<xla::cpu::X>
    10.00%  libc.so.6                                          [.] _int_malloc
     5.00%  libc.so.6                                          [.] qsort
     8.00%  [kernel.kallsyms]                                  [k] clear_page_erms
     7.00%  libm.so.6                                          [.] __expf_fma
     5.00%  libpython3.11.so.1.0                               [.] _PyEval_EvalFrameDefault
"""
    rows = m.parse_report(report)
    assert rows[0] == (40.0, "[JIT]", "0x00007f04b535a074")
    assert rows[1][2].startswith("xla::cpu::ThunkExecutor::Execute")
    s = m.summarize(rows, top=2)
    assert s["shares"] == {"compiled": 0.47, "runtime": 0.25, "memory": 0.1, "kernel": 0.08, "python": 0.05,
                           "other": 0.05}
    assert [t["object"] for t in s["top"]] == ["[JIT]", "libjax_common.so"]
    assert m.category("c_peer_abc.so", "run") == "compiled" and m.category("libgomp.so.1", "x") == "runtime"


def _perf_works() -> bool:
    import shutil

    if shutil.which("perf") is None:
        return False
    probe = subprocess.run(["perf", "stat", "-e", "cpu-clock", "true"], capture_output=True, text=True)
    return probe.returncode == 0


def test_profile_cpu_samples_a_run(tmp_path):
    if not _perf_works():
        pytest.skip("perf is not installed or may not sample this process here")
    out = tmp_path / "profile.json"
    proc = _script("scripts/profile_cpu.py", "--algos", "ac", "--peers", "--seeds", "256", "--repeats", "1",
                   "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    (row,) = json.loads(out.read_text())["rows"]
    assert row["impl"] == "jaxeac" and row["agent_steps"] > 0
    assert abs(sum(row["shares"].values()) - 1) < 1e-3 and row["shares"]["compiled"] > 0
