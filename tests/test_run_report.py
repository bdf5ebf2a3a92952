"""A run report names its subject and, with more than two algorithms, compares the declared family:
every algorithm against the baseline, Holm over the family (issue: every report says what it shows)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from jaxeac.stats.family import settings_text, subject

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(("summary", "expected"), [
    ({"experiment": "grid", "trials": 200, "config": {"env": "FrozenLake-8x8-slippery-v1", "slip": 0.0,
                                                       "chances": 200, "preset": "paper"}},
     "FrozenLake-8x8-slippery-v1, C = 200, 200 trials"),
    ({"experiment": "grid", "trials": 50, "config": {"env": "grid-paper-v0", "slip": 0.1, "chances": 40}},
     "grid-paper-v0, slip 0.1, C = 40, 50 trials"),
    ({"experiment": "grid", "trials": 200, "config": {"preset": "paper", "map_file": None, "env": None,
                                                       "chances": 40, "slip": 0.0}},
     "the paper preset's grid world, C = 40, 200 trials"),
    ({"experiment": "grid", "trials": 9, "config": {"map_file": "maps/my room.txt", "chances": 5}},
     "the grid world of my room.txt, C = 5, 9 trials"),
    ({"experiment": "bowling", "trials": 100, "config": {"backend": "c", "chances": 3}},
     "bowling (c backend), 100 trials"),
])
def test_subject_names_what_was_run(summary, expected):
    assert subject(summary) == expected


def test_settings_text_states_rates_key_and_command():
    summary = {"algos": ["ac", "eac"], "key": 3, "command": "jaxeac run --seeds 5",  # not quoted
               "config": {"alpha": 0.1, "beta": 3.0, "gamma": 0.9, "temperature": 1.0, "epsilon": 0.1}}
    want = "α = 0.1, β = 3, γ = 0.9, τ = 1; key 3"
    assert settings_text(summary) == want
    assert settings_text({}) == ""


def test_a_run_of_four_algorithms_reports_each_against_the_baseline(tmp_path):
    out = tmp_path / "run"
    env = dict(os.environ, JAXEAC_COMPILATION_CACHE="off", MPLBACKEND="Agg")
    proc = subprocess.run(
        [sys.executable, "-m", "jaxeac", "run", "--env", "FrozenLake-4x4-v1", "--algos", "ac", "eac",
         "q_learning", "sarsa", "--seeds", "12", "--trials", "20", "--out", str(out)],
        capture_output=True, text=True, env=env, cwd=ROOT, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "FrozenLake-4x4-v1: " in proc.stderr  # the progress bar names the environment
    assert "every algorithm against ac (the declared family):" in proc.stdout
    report = (out / "report.md").read_text(encoding="utf-8")
    assert report.splitlines()[0] == "# EAC versus AC on FrozenLake-4x4-v1, C = 100, 20 trials"
    assert "algorithms run: ac, eac, q_learning, sarsa" in report
    assert ("Settings: α = 0.1, β = 0.3, γ = 0.9, τ = 1 (ε = 0.1 for q_learning, sarsa); key 0 (all of them, "
            "and the command: summary.json)") in report
    command = json.loads((out / "summary.json").read_text(encoding="utf-8"))["command"]
    assert command.startswith("jaxeac run --env FrozenLake-4x4-v1 --algos ac eac q_learning sarsa")
    assert "## Every algorithm against AC: the declared family" in report
    stats = json.loads((out / "stats.json").read_text(encoding="utf-8"))
    family = stats["family"]
    assert family["family"] == "all vs baseline ac" and family["family_size"] == 3
    rows = {(r["x"], r["y"]): r for r in family["rows"]}
    assert set(rows) == {("eac", "ac"), ("q_learning", "ac"), ("sarsa", "ac")}
    for r in rows.values():
        assert r["analysis"] == "paired"  # one key: seed i of each algorithm shares its key (R1)
        assert r["p_holm"] >= r["paired"]["p_paired_t"]  # Holm never lowers a p-value
        for line in (f"| {r['x']} | ac | paired |",):
            assert line in report
    assert stats["primary"]["n_treatment"] == 12
    assert stats["algos_run"] == ["ac", "eac", "q_learning", "sarsa"]

    from jaxeac.cli import main  # a second comparison of the folder: its own files, its own figures linked

    assert main(["compare", str(out), "--treatment", "sarsa"]) == 0
    second = (out / "report_ac_vs_sarsa.md").read_text(encoding="utf-8")
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", second)
    assert len(links) == 3 and all(link.endswith("_ac_vs_sarsa.png") and (out / link).is_file() for link in links)


def test_a_two_algorithm_run_has_no_family_section(tmp_path):
    from jaxeac.cli import main

    out = tmp_path / "run"
    assert main(["run", "--seeds", "6", "--trials", "6", "--chances", "10", "--quiet",
                 "--out", str(out)]) == 0
    stats = json.loads((out / "stats.json").read_text(encoding="utf-8"))
    assert stats["family"] is None and stats["algos_run"] == ["ac", "eac"]
    report = (out / "report.md").read_text(encoding="utf-8")
    assert report.startswith("# EAC versus AC on the paper preset's grid world, C = 10, 6 trials\n")
    assert "## Every algorithm against" not in report


def test_a_figure_helper_loads_its_jobs_modules_before_they_come():
    """A figure helper's first job (`pipeline._load_plots`) loads matplotlib and the modules of the
    jobs it is sent next (reading a job imports its function's module), while it waits for them."""
    from jaxeac.experiments.grid import draw_grid_figures
    from jaxeac.stats.run import draw_comparison

    jobs = sorted({draw_grid_figures.__module__, draw_comparison.__module__, "matplotlib.pyplot"})
    code = ("import json, sys; from jaxeac.experiments.pipeline import _load_plots; "
            f"jobs = {jobs!r}; before = [m in sys.modules for m in jobs]; _load_plots(); "
            "print(json.dumps([before, [m in sys.modules for m in jobs]]))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300,
                          env=dict(os.environ, JAXEAC_COMPILATION_CACHE="off", MPLBACKEND="Agg"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads(proc.stdout.splitlines()[-1]) == [[False] * 3, [True] * 3]


FIGURES_IN_HELPER = """
import hashlib, json, multiprocessing, pathlib, sys
from jaxeac.experiments import pipeline
from jaxeac.cli import main
if sys.argv[1] == "helper":  # as on a GPU: statistics beside the figures, drawn in a helper process
    pipeline.STATISTICS_BESIDE_FIGURES = pipeline.FIGURES_IN_HELPER = {"cpu": True}
argv = ["grid", "--preset", "paper", "--seeds", "40", "--trials", "12", "--quiet", "--out"]
pathlib.Path(sys.argv[2] + ".txt").write_text("a file, not a folder")
refused = main([*argv, sys.argv[2] + ".txt"])  # the helper starts before this check, and is ended
rc = main([*argv, sys.argv[2]])
pngs = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in pathlib.Path(sys.argv[2]).glob("*.png")}
print(json.dumps([rc, "matplotlib" in sys.modules, pngs, refused, len(multiprocessing.active_children())]))
"""


def test_a_grid_runs_figures_drawn_in_a_helper_are_those_drawn_here(tmp_path):
    """With its figures in a helper process (`FIGURES_IN_HELPER`, GPUs), a grid run and its report
    write the same PNGs, byte for byte, and matplotlib is never imported in the command's process;
    the helper, started before the checks, is gone after a run refused by one and after a run."""
    env = dict(os.environ, JAXEAC_COMPILATION_CACHE="off", MPLBACKEND="Agg")
    seen = {}
    for where in ("here", "helper"):
        proc = subprocess.run([sys.executable, "-c", FIGURES_IN_HELPER, where, str(tmp_path / where)],
                              capture_output=True, text=True, env=env, cwd=ROOT, timeout=600)
        assert proc.returncode == 0, proc.stderr[-2000:]
        seen[where] = json.loads(proc.stdout.splitlines()[-1])
    assert seen["here"][:2] == [0, True] and seen["helper"][:2] == [0, False]
    assert len(seen["here"][2]) == 5 and seen["helper"][2] == seen["here"][2]
    assert seen["helper"][3:] == [2, 0] and seen["here"][3:] == [2, 0]
