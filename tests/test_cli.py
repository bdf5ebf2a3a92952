"""The `jaxeac run` (alias `grid`) command line: outputs, and bad input → one-line error, exit 2,
nothing written; one meaning per flag name."""

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
from jaxeac.results import load_grid_results

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
    import jaxeac.experiments.pipeline as pipeline

    monkeypatch.setitem(pipeline.STATISTICS_BESIDE_FIGURES, "cpu", True)
    started = []
    start = pipeline._start_statistics
    monkeypatch.setattr(pipeline, "_start_statistics", lambda *a: started.append(1) or start(*a))
    argv = ["grid", "--seeds", "6", "--trials", "8", "--chances", "12", "--quiet"]
    assert main([*argv, "--out", str(tmp_path / "beside")]) == 0 and started == [1]
    monkeypatch.setattr(pipeline, "STATISTICS_BESIDE_FIGURES_SEEDS", 5)
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


# ------------------------------------------------------------------ one meaning per flag name

RENAMED = [  # (argv with the old spelling, the new spelling the one error line names)
    (["compare", "runs/x", "--alpha", "0.05"], "--level"),
    (["compare", "--table", "t.csv", "--alpha=0.01"], "--level"),
    (["throw", "--angles", "0", "0.05"], "--angle A"),
    (["throw", "--angle", "0", "--noise", "1"], "--noise-angle S and --noise-speed S"),
    (["sweep", "--set", "alpha=0.1,0.2", "--compare"], "--point-reports"),
]


@pytest.mark.parametrize(("argv", "new"), RENAMED)
def test_old_flag_spellings_name_the_new_one(argv, new, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "was renamed" in err, err
    assert new in err, err
    assert result_files(tmp_path) == []


def test_renamed_flags_are_hidden_and_each_name_has_one_meaning():
    """No old spelling shows in the help, and the names shared by commands are listed once in
    docs/CLI.md with the same meaning: bowling's --angles is the count, throw's --angle one angle."""
    from jaxeac.cli import build_parser
    from jaxeac.cli.reference import reference

    text = reference()
    for old in ("--noise N", "--noise S ", "--compare ", "--alpha ALPHA", "TEST_ALPHA"):
        assert old not in text
    args = build_parser().parse_args(
        ["throw", "--angle", "0.05", "--angle", "-0.02"])
    assert args.angles == [0.05, -0.02] and args.noise_angle == 0.0 and args.noise_speed == 0.0


def test_grid_is_an_alias_of_run(tmp_path):
    """`jaxeac grid` and `jaxeac run` (the paper's grid world by default) write the same folder."""
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["run", *SMALL, "--out", str(a)]) == 0
    assert main(["grid", *SMALL, "--out", str(b)]) == 0
    assert pq.read_table(a / "results.parquet").equals(pq.read_table(b / "results.parquet"))
    from jaxeac.cli import build_parser

    parse = build_parser().parse_args
    assert vars(parse(["run"])) | {"command": "grid"} == vars(parse(["grid"]))


def test_compare_level_sets_the_intervals_and_the_printed_percentage(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", *SMALL[:-1], "--out", str(out)]) == 0
    assert "95% BCa CI" in capsys.readouterr().out
    assert main(["compare", str(out), "--level", "0.99", "--resamples", "200"]) == 0
    printed = capsys.readouterr().out
    assert "99% BCa CI" in printed and "95%" not in printed
    assert json.loads((out / "stats.json").read_text())["settings"]["alpha"] == 0.01


def _tidy_table(path):
    rows = ["algo,seed,value"] + [f"{a},{i},{i * (2 if a == 'b' else 1) % 7}" for a in "ab" for i in range(8)]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_compare_reads_a_table_file_given_as_path(tmp_path, capsys):
    """`jaxeac compare results.csv` reads the file as a table, as `--table results.csv` does."""
    table = _tidy_table(tmp_path / "results.csv")
    assert main(["compare", str(table), "--resamples", "400", "--out", str(tmp_path / "as_path")]) == 0
    by_path = capsys.readouterr().out
    argv = ["compare", "--table", str(table), "--resamples", "400", "--out", str(tmp_path / "as_table")]
    assert main(argv) == 0
    assert capsys.readouterr().out.replace("as_table", "as_path") == by_path and "95% CI" in by_path
    stats = [json.loads((tmp_path / d / "stats_table.json").read_text()) for d in ("as_path", "as_table")]
    assert stats[0] == stats[1]


@pytest.mark.parametrize("name", ["notes.txt", "empty_folder", "missing"])
def test_compare_of_something_not_a_run_folder_names_table(name, tmp_path, capsys):
    path = tmp_path / name
    if name.endswith(".txt"):
        path.write_text("algo,seed,value\n")
    elif name == "empty_folder":
        path.mkdir()
    assert main(["compare", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "--table PATH reads tables" in err, err


def test_bowling_chunk_size_is_automatic_and_changes_no_result(tmp_path):
    """`jaxeac bowling` without --chunk-size picks the chunk (`auto_chunk_size`); per-seed results
    do not depend on it."""
    from jaxeac.experiments.bowling import AUTO_CHUNK, BowlingSettings, auto_chunk_size

    assert auto_chunk_size(BowlingSettings(seeds=3)) == 3
    assert auto_chunk_size(BowlingSettings(seeds=10**6)) == AUTO_CHUNK
    base = ["bowling", "--seeds", "3", "--trials", "2", "--quiet", "--no-compare"]
    assert main([*base, "--out", str(tmp_path / "auto")]) == 0
    assert main([*base, "--chunk-size", "1", "--out", str(tmp_path / "one")]) == 0
    assert (tmp_path / "auto" / "per_seed.csv").read_text() == (tmp_path / "one" / "per_seed.csv").read_text()


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
def test_throw_render_to_a_device_is_refused_before_any_throw(tmp_path, capsys, monkeypatch):
    from jaxeac.envs import bowling

    monkeypatch.setattr(bowling, "throw_command", lambda *a, **k: pytest.fail("threw"))
    for target in ("/dev/full", "/dev/null"):
        assert main(["throw", "--angle", "0", "--render", target]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1 and "not a regular file" in err, err
    assert not os.path.exists("/dev/full.png")


def test_sequential_error_rate_names_the_flag(tmp_path, capsys):
    argv = ["run", *SMALL, "--seeds", "50", "--out", str(tmp_path / "o"), "--sequential", "--effect", "1"]
    assert main([*argv, "--error-rate", "0.7"]) == 2
    err = capsys.readouterr().err
    assert err == "error: --error-rate must lie in (0, 0.5) (got 0.7)\n", err


def test_device_commands_start_the_device_at_once_and_end_after_it(tmp_path, monkeypatch):
    """`run`, `grid`, `study` and `sweep` start the device on a thread as soon as their flags parse
    (`jaxeac.cli.DEVICE_COMMANDS`), and return only once that thread has ended, also on bad input;
    a multi-host run (--coordinator) does not, as its JAX starts after jax.distributed.initialize."""
    import threading

    from jaxeac import runtime

    started = []

    def start():
        started.append(threading.Thread(target=threading.Event().wait, args=(0.3,),
                                        name=runtime.DEVICE_START_THREAD))
        started[-1].start()
        return started[-1]

    monkeypatch.setattr(runtime, "start_device", start)
    assert main(["study", "--algos", "ac", "--seeds", "4", "--out", str(tmp_path / "s")]) == 2
    assert main(["grid", *SMALL, "--out", str(tmp_path / "g"), "--coordinator", "localhost:1",
                 "--num-processes", "1"]) == 2
    assert len(started) == 1 and not started[0].is_alive()
    assert not (tmp_path / "s").exists() and not (tmp_path / "g").exists()
    assert main(["compare", str(tmp_path / "nothing")]) == 2 and len(started) == 1
