"""The `jaxeac grid` command line: outputs, and bad input → one-line error, exit 2, nothing written."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys

import numpy as np
import pyarrow.parquet as pq
import pytest

from jaxeac.cli import main
from jaxeac.experiments.results import load_grid_results

SMALL = ["--seeds", "4", "--trials", "6", "--chances", "10", "--quiet", "--no-compare"]


def result_files(folder):
    return sorted(p.name for p in folder.iterdir()) if folder.exists() else []


@pytest.fixture
def bad_map(tmp_path):
    path = tmp_path / "two_goals.txt"
    path.write_text("G..\n..G\n")
    return path


BAD = {
    "map breaks G1": (["--map", "{bad_map}"], "exactly one goal"),
    "missing map": (["--map", "{tmp}/nope.txt"], "does not exist"),
    "zero seeds": (["--seeds", "0"], "must be a positive integer"),
    "negative trials": (["--trials", "-3"], "must be a positive integer"),
    "fractional chances": (["--chances", "2.5"], "is not an integer"),
    "word seeds": (["--seeds", "ten"], "is not an integer"),
    "nan alpha": (["--alpha", "nan"], "not a finite number"),
    "inf beta": (["--beta", "inf"], "not a finite number"),
    "negative alpha": (["--alpha", "-0.1"], "alpha must be non-negative"),
    "gamma above 1": (["--gamma", "1.5"], r"gamma must lie in \[0, 1\]"),
    "gamma below 0": (["--gamma", "-0.5"], "gamma must be non-negative"),
    "zero temperature": (["--temperature", "0"], "temperature must be positive"),
    "unknown preset": (["--preset", "huge"], "unknown preset 'huge'"),
    "unknown algorithm": (["--algos", "ac", "dqn"], "unknown algorithm 'dqn'"),
    "unknown memory": (["--memory", "sparse"], "unknown memory layout 'sparse'"),
    "zero capacity": (["--capacity", "0"], "must be a positive integer"),
    "zero chunk": (["--chunk-size", "0"], "must be a positive integer"),
    "zero lanes": (["--lanes", "0"], "must be a positive integer"),
    "negative key": (["--key", "-1"], "must be a non-negative integer"),
    "out is a file": (["--out", "{tmp}/file.txt"], "is not a directory"),
    "out under a file": (["--out", "{tmp}/file.txt/sub"], "cannot write to --out"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_one_line_exit_2_nothing_written(case, tmp_path, bad_map, capsys):
    flags, message = BAD[case]
    (tmp_path / "file.txt").write_text("not a folder")
    out = tmp_path / "out"
    argv = ["grid", *SMALL, "--out", str(out)]
    argv += [f.format(bad_map=bad_map, tmp=tmp_path) for f in flags]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    import re

    assert re.search(message, err), err
    assert result_files(out) == []
    assert (tmp_path / "file.txt").read_text() == "not a folder"


def test_grid_end_to_end(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["grid", *SMALL, "--out", str(out), "--key", "5"]) == 0
    printed = capsys.readouterr().out
    assert "EAC - AC" in printed and "agent-steps/s" in printed
    assert result_files(out) == ["fig2_policies.png", "fig3_cumulative_successes.png",
                                 "per_seed.csv", "results.parquet", "summary.json"]
    rows = list(csv.DictReader((out / "per_seed.csv").open()))
    assert [(r["algo"], int(r["seed"])) for r in rows] == [(a, i) for a in ("ac", "eac") for i in range(4)]
    results = load_grid_results(out, ("ac", "eac"), 6)
    table = pq.read_table(out / "results.parquet")  # one line for a user, typed columns
    assert table.num_rows == 8 and table.schema.field("success_bits").type.byte_width == 1
    curves = {a: r.success for a, r in results.items()}
    for algo in ("ac", "eac"):
        success, r = curves[algo], results[algo]
        assert success.dtype == bool and success.shape == (4, 6) and r.policy.shape == (4, 121)
        mine = [r for r in rows if r["algo"] == algo]
        np.testing.assert_array_equal([int(r["successes"]) for r in mine], success.sum(1))
        np.testing.assert_array_equal([int(r["steps"]) for r in mine], results[algo].trial_steps.sum(1))
        for r, s in zip(mine, success, strict=True):
            assert int(r["first_success"]) == (np.argmax(s) + 1 if s.any() else -1)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"]["trials"] == 6 and summary["config"]["alpha"] == 0.1  # flag + preset
    assert summary["key"] == 5 and summary["devices"] and summary["versions"]["jax"]
    assert summary["per_algo"]["eac"]["mean_successes"] == pytest.approx(curves["eac"].sum(1).mean())
    assert summary["compile_seconds"] > 0 and summary["agent_steps_per_second"] > 0


def test_cli_results_match_library_and_rerun(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["grid", *SMALL, "--out", str(a), "--chunk-size", "3"]) == 0
    assert main(["grid", *SMALL, "--out", str(b), "--chunk-size", "4", "--lanes", "1"]) == 0  # R1: a queue
    assert (a / "per_seed.csv").read_text() == (b / "per_seed.csv").read_text()
    assert pq.read_table(a / "results.parquet").equals(pq.read_table(b / "results.parquet"))
    runs = {f: json.loads((f / "summary.json").read_text())["per_algo"]["eac"]["run"] for f in (a, b)}
    assert runs[a]["lanes"] == 256 and runs[b]["lanes"] == 1


def test_statistics_beside_the_figures_give_the_same_report(tmp_path, monkeypatch, capsys):
    """`jaxeac grid` on accelerators starts the comparison's statistics as soon as the results are in,
    beside the run's own figures (up to `STATISTICS_BESIDE_FIGURES_SEEDS`): the same stats.json as
    after them."""
    import jaxeac.cli as cli

    monkeypatch.setitem(cli.STATISTICS_BESIDE_FIGURES, "cpu", True)
    started = []
    start = cli._start_statistics
    monkeypatch.setattr(cli, "_start_statistics", lambda *a: started.append(1) or start(*a))
    argv = ["grid", "--seeds", "6", "--trials", "8", "--chances", "12", "--quiet"]
    assert main([*argv, "--out", str(tmp_path / "beside")]) == 0 and started == [1]
    monkeypatch.setattr(cli, "STATISTICS_BESIDE_FIGURES_SEEDS", 5)
    assert main([*argv, "--out", str(tmp_path / "after")]) == 0 and started == [1]

    def stats(name):
        d = json.loads((tmp_path / name / "stats.json").read_text())
        return {k: v for k, v in d.items() if k not in ("timing", "run_dir")}

    assert stats("beside") == stats("after") and stats("beside")["primary"]["measure"] == "successes"
    assert {"report.md", "fig3_cumulative_successes.png"} <= set(result_files(tmp_path / "beside"))


def test_failure_midway_leaves_nothing(tmp_path, monkeypatch, capsys):
    from jaxeac import plots

    def broken(*args, **kwargs):
        raise RuntimeError("disk full while drawing")

    monkeypatch.setattr(plots, "grid_figures", broken)
    out = tmp_path / "run"
    with pytest.raises(RuntimeError):
        main(["grid", *SMALL, "--out", str(out)])
    assert result_files(out) == []


def test_console_entry_points(tmp_path):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.run([sys.executable, "-m", "jaxeac", "grid", "--seeds", "0"],
                          capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()]
    assert proc.stderr.startswith("error: ")
    proc = subprocess.run([sys.executable, "-m", "jaxeac", "--help"], capture_output=True, text=True,
                          env=env, timeout=120)
    assert proc.returncode == 0 and "grid" in proc.stdout


def test_command_uses_every_cpu_core(tmp_path):
    """`jaxeac` exposes each CPU core as a device before JAX starts (results stay identical, R1)."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"} | {"JAX_PLATFORMS": "cpu"}
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "jaxeac", "grid", *SMALL, "--out", str(out)],
                          capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    devices = json.loads((out / "summary.json").read_text())["devices"]
    assert len(devices) == len(os.sched_getaffinity(0))


def test_configure_xla_lets_gpu_memory_grow_and_keeps_the_users_choice():
    """`configure_xla` (run by `jaxeac` before JAX starts) turns JAX's up-front reservation of
    GPU memory off (it held ~1.5 GiB of host memory, BENCHMARKS.md) unless the user set it."""
    code = ("import os; from jaxeac.runtime import configure; configure_xla(); "
            "print(os.environ['XLA_PYTHON_CLIENT_PREALLOCATE'], 'command_buffer' in os.environ['XLA_FLAGS'])")
    base = {k: v for k, v in os.environ.items() if k not in ("XLA_PYTHON_CLIENT_PREALLOCATE", "XLA_FLAGS")}
    for env, expected in (({}, "false True"), ({"XLA_PYTHON_CLIENT_PREALLOCATE": "true"}, "true True")):
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=base | env,
                              timeout=120)
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.split() == expected.split()


def test_command_line_gives_numpy_one_blas_thread_unless_the_user_chose():
    """`jaxeac` sets NumPy's BLAS to one thread per call before NumPy loads (the statistics' own
    threads oversubscribed the host otherwise, BENCHMARKS.md); a value the user set is kept."""
    code = ("import sys, jaxeac.__main__ as m; loaded = 'numpy' in sys.modules; "
            "env = {'MKL_NUM_THREADS': '4'}; m.one_blas_thread(env); "
            "print(loaded, env['OPENBLAS_NUM_THREADS'], env['MKL_NUM_THREADS'])")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["False", "1", "4"]  # NumPy not yet loaded: the setting is in time
    # the command itself (`jaxeac --help` through the console entry point) makes the setting
    command = ("import atexit, os, sys; import jaxeac.__main__ as m; sys.argv = ['jaxeac', '--help']; "
               "atexit.register(lambda: print('BLAS', os.environ.get('OPENBLAS_NUM_THREADS'))); m.run()")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    proc = subprocess.run([sys.executable, "-c", command], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-1] == "BLAS 1"


def test_configure_xla_adds_each_gpu_flag_unless_the_user_set_it():
    """Each of jaxeac's GPU flags is added on its own; one the user set keeps the user's value
    (XLA keeps a flag's last value, so appending jaxeac's would override it). The compile-time
    flags are for the grid-like commands only: bowling's MJX physics is slower with them."""
    code = ("import os, sys; from jaxeac.runtime import configure; configure_xla(sys.argv[1]); "
            "print(os.environ['XLA_FLAGS'])")
    base = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    user = "--xla_gpu_enable_triton_gemm=true"

    def flags(command: str, env: dict) -> list[str]:
        proc = subprocess.run([sys.executable, "-c", code, command], capture_output=True, text=True,
                              env=base | env, timeout=120)
        assert proc.returncode == 0, proc.stderr
        return proc.stdout.split()

    grid = flags("grid", {"XLA_FLAGS": user})
    assert grid.count(user) == 1 and "--xla_gpu_enable_triton_gemm=false" not in grid
    assert "--xla_gpu_autotune_level=0" in grid
    assert any(f.startswith("--xla_gpu_enable_command_buffer=") for f in grid)
    bowling = flags("bowling", {})
    assert any(f.startswith("--xla_gpu_enable_command_buffer=") for f in bowling)
    assert not any("autotune" in f or "triton_gemm" in f for f in bowling)


def test_compilation_cache_is_kept_and_changes_no_result(tmp_path):
    """`jaxeac` keeps compiled programs in JAXEAC_COMPILATION_CACHE (XDG_CACHE_HOME/jaxeac/xla by
    default); a rerun that loads them writes the same results, and ``off`` writes no cache."""
    base = {k: v for k, v in os.environ.items() if k not in ("JAXEAC_COMPILATION_CACHE",
                                                             "JAX_COMPILATION_CACHE_DIR")}
    cache = tmp_path / "cache"
    runs = {}
    for name, env in (("first", {"JAXEAC_COMPILATION_CACHE": str(cache)}),
                      ("cached", {"JAXEAC_COMPILATION_CACHE": str(cache)}),
                      ("off", {"JAXEAC_COMPILATION_CACHE": "off", "XDG_CACHE_HOME": str(tmp_path / "xdg")})):
        out = tmp_path / name
        proc = subprocess.run([sys.executable, "-m", "jaxeac", "grid", *SMALL, "--out", str(out)],
                              capture_output=True, text=True, env=base | env, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        runs[name] = pq.read_table(out / "results.parquet")
        if name == "first":
            assert any(p.is_file() for p in cache.rglob("*")), "no compiled program was cached"
    assert runs["first"].equals(runs["cached"]) and runs["first"].equals(runs["off"])
    assert not (tmp_path / "xdg" / "jaxeac").exists()
