"""`jaxeac sweep`: one program per shape, atomic per-unit files, kill-and-resume, refused mismatches."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from jaxeac.cli import main
from jaxeac.experiments.grid import GridSettings
from jaxeac.experiments.sweep import Sweep, run_sweep
from jaxeac.running.batch import run_seeds

ROOT = Path(__file__).resolve().parents[1]
ARGS = ["sweep", "--seeds", "24", "--chunk-size", "3", "--trials", "20", "--chances", "20",
        "--set", "alpha=0.05,0.2", "--set", "beta=0.1,0.3", "--quiet"]


def test_sweep_points_equal_separate_runs(tmp_path):
    """A swept point's results are those of a plain run with its settings (vmapped hyperparameters)."""
    base = GridSettings(seeds=6, chunk_size=4, trials=15, chances=20)
    sweep = Sweep.build(base, ["alpha=0.05,0.3", "gamma=0.5,0.9"])
    rows = run_sweep(sweep, tmp_path / "s")
    from jaxeac.envs.grid import GridWorld

    for row in rows:
        s = sweep.settings({"alpha": row["alpha"], "gamma": row["gamma"]})
        env = GridWorld(s.grid_map(), s.chances)
        ref = run_seeds(env, s.run_config(row["algo"]), root_key=s.key, n_seeds=6, chunk_size=6)
        assert row["mean_successes"] == pytest.approx(ref.successes.mean())
    assert len(rows) == 8 and (tmp_path / "s" / "heatmap.png").exists()


def read_results(folder):
    return (folder / "results.csv").read_text()


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGINT])
def test_killed_sweep_resumes_to_identical_results(tmp_path, sig):
    """A sweep killed or interrupted mid-way (Ctrl-C: one line, exit 130) keeps its finished
    parts, and the rerun completes it with the results of an uninterrupted sweep."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    killed, clean = tmp_path / "killed", tmp_path / "clean"
    cmd = [sys.executable, "-m", "jaxeac", *ARGS]
    proc = subprocess.Popen([*cmd, "--out", str(killed)], env=env, cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.time() + 300
    while time.time() < deadline and len(list((killed / "parts").glob("*.npz"))) < 3:
        time.sleep(0.05)
    proc.send_signal(sig)
    err = proc.communicate(timeout=120)[1].decode()
    if sig == signal.SIGINT:
        assert proc.returncode == 130 and "Traceback" not in err, err[-2000:]
        assert err.rstrip().splitlines()[-1].startswith("error: interrupted"), err[-2000:]
    done_before = len(list((killed / "parts").glob("*.npz")))
    assert 3 <= done_before < 4 * 2 * 8, "the kill should land mid-sweep"
    assert not (killed / "results.csv").exists()
    subprocess.run([*cmd, "--out", str(killed)], env=env, cwd=ROOT, check=True, timeout=600,
                   capture_output=True)
    subprocess.run([*cmd, "--out", str(clean)], env=env, cwd=ROOT, check=True, timeout=600,
                   capture_output=True)
    assert read_results(killed) == read_results(clean)
    rows = list(csv.DictReader((clean / "results.csv").open()))
    assert len(rows) == 8 and {r["algo"] for r in rows} == {"ac", "eac"}
    assert all(int(r["n"]) == 24 for r in rows)


def test_mismatched_resume_refused(tmp_path, capsys):
    out = tmp_path / "s"
    small = ["sweep", "--seeds", "2", "--trials", "3", "--chances", "5", "--quiet", "--out", str(out)]
    assert main([*small, "--set", "alpha=0.1,0.2"]) == 0
    before = read_results(out)
    assert main([*small, "--set", "alpha=0.1,0.3"]) == 2
    err = capsys.readouterr().err
    assert "holds a different sweep" in err and err.count("\n") == 1
    assert read_results(out) == before


@pytest.mark.parametrize(("sets", "message"), [
    (["alpah=0.1"], "unknown key 'alpah'"),
    (["alpha="], "empty list"),
    (["alpha=0.1,zero"], "cannot read 'zero'"),
    (["alpha=0.1,nan"], "not a finite number"),
    (["gamma=0.5,1.5"], r"gamma must lie in [0, 1]"),
    (["trials=0"], "trials must be a positive integer"),
    (["alpha0.1"], "KEY=V1,V2"),
    (["alpha=0.1,0.1"], "listed twice"),
    ([], "nothing to sweep"),
    (["map=/nonexistent/map.txt"], "does not exist"),
])
def test_bad_sweep_input_before_compute(sets, message, tmp_path, capsys):
    out = tmp_path / "never"
    argv = ["sweep", "--seeds", "2", "--out", str(out)]
    for s in sets:
        argv += ["--set", s]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err, err
    assert not out.exists()


def test_vmapped_hyper_shares_one_program(tmp_path):
    from jaxeac.running import batch as runner

    runner._COMPILED.clear()
    base = GridSettings(seeds=4, chunk_size=4, trials=5, chances=5)
    run_sweep(Sweep.build(base, ["alpha=0.1,0.2,0.3", "beta=0.1,0.2"]), tmp_path / "s")
    assert len(runner._COMPILED) == 2  # one per algorithm, not per point


def test_compare_per_point(tmp_path):
    import json

    base = GridSettings(seeds=6, chunk_size=6, trials=12, chances=15)
    rows = run_sweep(Sweep.build(base, ["alpha=0.1,0.3"]), tmp_path / "s", compare=True)
    for point in (0, 1):
        stats = json.loads((tmp_path / "s" / "points" / f"p{point:05d}" / "stats.json").read_text())
        mine = {r["algo"]: r for r in rows if r["point"] == point}
        assert stats["primary"]["mean_treatment"] == pytest.approx(mine["eac"]["mean_successes"])
        assert stats["primary"]["mean_baseline"] == pytest.approx(mine["ac"]["mean_successes"])


def test_one_key_sweep_prints_its_table_and_draws_lines(tmp_path, capsys):
    """The table in the terminal, a line plot for one swept key, and EAC − AC said once per point
    (on EAC's row; not on AC's or the baselines')."""
    out = tmp_path / "s"
    assert main(["sweep", "--seeds", "6", "--trials", "8", "--chances", "20", "--algos", "ac", "eac",
                 "q_learning", "--set", "alpha=0.05,0.2", "--quiet", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    lines = printed.splitlines()
    assert lines[0].split() == ["alpha", "algo", "n", "mean", "successes", "[95%", "CI]", "EAC", "−", "AC",
                                "[95%", "CI]"]
    assert len([ln for ln in lines if " q_learning " in ln]) == 2
    assert f"figure {out}/lines.png" in printed and (out / "lines.png").exists()
    assert not (out / "heatmap.png").exists()
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert {r["algo"]: r["eac_minus_ac"] != "" for r in rows} == {"ac": False, "eac": True, "q_learning": False}
    eac_lines = [ln for ln in lines if " eac " in ln]
    assert all(ln.count("[") == 2 for ln in eac_lines)  # its mean's CI and the difference's
    assert all(ln.count("[") == 1 for ln in lines if " q_learning " in ln or " ac " in ln)
