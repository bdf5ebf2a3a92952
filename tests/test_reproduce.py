"""`jaxeac reproduce` end to end at a tiny size: report, verdicts, numbers from the step JSONs, resume."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from jaxeac.envs.grid import parse_map
from jaxeac.errors import UsageError
from jaxeac.experiments.reproduce import (
    QUICK,
    Sizes,
    greedy_reach,
    paper_position,
    reproduce,
)
from jaxeac.experiments.reproduce import supported as _supported

TINY = Sizes(grid_seeds=24, bowling_seeds=4, calibration_seeds=8,
             calibration_sets=("alpha=0.05,0.1", "beta=0.3,0.9"), ablation_grid_seeds=16,
             ablation_bowling_seeds=4, ablation_algos=("ac", "eac", "eac_success_only"),
             temperatures=(0.5, 1.0), noise_scales=(0.0, 1.0), resamples=200, band_resamples=200)
VERDICTS = ("holds", "partly holds", "does not hold")
CLAIMS = ("GRID-1", "GRID-2", "GRID-3", "BOWL-1", "BOWL-2", "BOWL-3")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("repro")
    report = reproduce(out, key=3, progress=False, sizes=TINY)
    return out, report


def section(text: str, head: str) -> str:
    """The report text from the heading starting with `head` to the next heading of level ≤ 3."""
    start = text.index(head)
    nxt = re.search(r"\n#{2,3} ", text[start + len(head):])
    return text[start: start + len(head) + (nxt.start() if nxt else len(text))]


def row_cells(s: dict, nd: int = 2) -> list[str]:
    """How report.md must print one comparison from its JSON record."""
    return [f"{s['diff']:+.{nd}f} [{s['diff_ci95'][0]:+.{nd}f}, {s['diff_ci95'][1]:+.{nd}f}]",
            f"{s['hedges_g']:.3f} [{s['hedges_g_ci95'][0]:.3f}, {s['hedges_g_ci95'][1]:.3f}]",
            f"{s['a12']:.3f} [{s['a12_ci95'][0]:.3f}, {s['a12_ci95'][1]:.3f}]",
            f"| {s['n_baseline']} / {s['n_treatment']} |"]


def test_report_has_a_verdict_per_claim(run):
    out, report = run
    assert report == out / "report.md" and report.is_file()
    text = report.read_text()
    glance = section(text, "## Verdicts at a glance")
    for cid in CLAIMS:
        line = next(ln for ln in glance.splitlines() if ln.startswith(f"| {cid} |"))
        assert re.search(r"\*\*(holds|partly holds|does not hold)\*\* \|$", line), line
    rec = json.loads((out / "reproduce.json").read_text())
    assert [c["id"] for c in rec["claims"]] == list(CLAIMS)
    for c in rec["claims"]:
        assert c["verdict"] in VERDICTS
        assert f"| {c['id']} |" in glance
        assert f"**Verdict: {c['verdict']}**" in section(text, f"### {c['id']} ")
    for link in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text):  # every embedded figure exists
        assert (out / link).is_file(), link


def test_report_numbers_equal_the_step_json(run):
    out, report = run
    text = report.read_text()
    gstats = json.loads((out / "grid" / "stats.json").read_text())
    bstats = json.loads((out / "bowling" / "stats.json").read_text())
    grid = json.loads((out / "grid" / "reproduce.json").read_text())["result"]
    bowl = json.loads((out / "bowling" / "reproduce.json").read_text())["result"]
    cal = json.loads((out / "calibration" / "reproduce.json").read_text())["result"]
    abl = json.loads((out / "ablations" / "reproduce.json").read_text())["result"]

    g1 = section(text, "### GRID-1 ")
    for cell in row_cells(gstats["primary"]):
        assert cell in g1, cell
    assert gstats["primary"]["n_baseline"] == TINY.grid_seeds
    assert f"{gstats['primary']['mean_treatment']:.2f}" in g1
    assert f"lies at percentile {grid['paper_position']['eac']['percentile']:.1f} of our seeds" in g1
    g2 = section(text, "### GRID-2 ")
    for cell in row_cells(gstats["secondary"]["auc_cumulative"], 4):
        assert cell in g2, cell
    for cell in row_cells(grid["greedy_reach"]["contrast"], 3):
        assert cell in section(text, "### GRID-3 "), cell

    b1 = section(text, "### BOWL-1 ")
    for cell in row_cells(bstats["primary"]):
        assert cell in b1, cell
    assert bstats["primary"]["n_treatment"] == TINY.bowling_seeds
    b2 = section(text, "### BOWL-2 ")
    e1 = bowl["angles"]["eac"]["theta1"]
    assert f"{e1['mean']:+.4f} [{e1['ci95'][0]:+.4f}, {e1['ci95'][1]:+.4f}]" in b2
    for cell in row_cells(bowl["angles"]["contrast_sd_theta1"], 4):
        assert cell in section(text, "### BOWL-3 "), cell

    calib = section(text, "## Calibration")
    cc = cal["closest"]
    assert f"AC {cc['ac']:.2f} [{cc['ac_ci95'][0]:.2f}, {cc['ac_ci95'][1]:.2f}]" in calib
    assert f"EAC {cc['eac']:.2f} [{cc['eac_ci95'][0]:.2f}, {cc['eac_ci95'][1]:.2f}]" in calib
    assert cal["n_points"] == 4 and f"{cal['n_points']} points" in calib
    ab = section(text, "## Ablations")
    for v in abl["variants"]:
        assert f"| {v['algo']} | {v['n_treatment']} | {v['mean']['mean']:.2f}" in ab
        assert f"{v['diff']:+.2f} [{v['diff_ci95'][0]:+.2f}, {v['diff_ci95'][1]:+.2f}]" in ab
    for t in abl["temperatures"]:
        row = f"τ = {t['temperature']:g} | {t['n_baseline']} / {t['n_treatment']} | {t['mean_baseline']:.2f}"
        assert row in ab

    # the step JSONs agree with the run folders they summarise
    from jaxeac.experiments.results import load_grid_results

    npz = {a: r.success for a, r in load_grid_results(out / "grid", ("ac", "eac"), 200).items()}
    assert grid["successes"]["eac"]["mean"] == pytest.approx(npz["eac"].sum(1).mean())
    assert gstats["primary"]["diff"] == pytest.approx(npz["eac"].sum(1).mean() - npz["ac"].sum(1).mean())
    with np.load(out / "bowling" / "curves.npz") as npz:
        assert bstats["primary"]["mean_baseline"] == pytest.approx(npz["ac_return"].sum(1).mean())


def test_verdicts_follow_the_rules(run):
    out, _ = run
    rec = json.loads((out / "reproduce.json").read_text())
    c = {x["id"]: x for x in rec["claims"]}
    pr, pos = c["GRID-1"]["stats"], rec["grid"]["paper_position"]
    supported = pr["diff_ci95"][0] > 0 and pr["p_holm"] <= 0.05
    within = pos["ac"]["within_5_95"] and pos["eac"]["within_5_95"]
    expect = "holds" if supported and within else "partly holds" if supported else "does not hold"
    assert c["GRID-1"]["verdict"] == expect
    # EAC's advantage on the paper's grid is large even at 24 seeds
    assert supported and c["GRID-3"]["verdict"] == "holds"


def test_rerun_resumes_and_other_settings_are_refused(run):
    out, _ = run
    before = json.loads((out / "reproduce.json").read_text())
    reproduce(out, key=3, progress=False, sizes=TINY)
    after = json.loads((out / "reproduce.json").read_text())
    assert all(t["resumed"] for t in after["timings"].values())
    assert [c["verdict"] for c in after["claims"]] == [c["verdict"] for c in before["claims"]]
    assert after["grid"] == before["grid"]
    with pytest.raises(UsageError, match="other settings"):
        reproduce(out, key=4, progress=False, sizes=TINY)


def test_supported_needs_ci_and_p():
    assert _supported({"diff_ci95": [0.1, 2.0], "p_welch": 0.01}) == 1
    assert _supported({"diff_ci95": [-2.0, -0.1], "p_welch": 0.01}) == -1
    assert _supported({"diff_ci95": [-0.1, 2.0], "p_welch": 0.01}) == 0
    assert _supported({"diff_ci95": [0.1, 2.0], "p_welch": 0.2}) == 0
    assert _supported({"diff_ci95": [0.1, 2.0], "p_welch": 0.01, "p_holm": 0.3}, "p_holm") == 0


def test_greedy_reach_by_hand():
    grid = parse_map("...\n.#G\n...\n")
    n = grid.n_cells
    right = np.zeros((1, n), np.int64)  # all "right": only (0,1)→blocked; row 0 and 2 run to the edge
    reach = greedy_reach(grid, right, max_steps=10)
    assert reach[0] == 0.0  # nobody reaches G at (2, 1) moving right only
    towards = np.zeros(n, np.int64)
    for y in range(3):
        for x in range(3):
            s = y * 3 + x
            towards[s] = 0 if x < 2 else (3 if y == 0 else 2)  # right, then down/up in the last column
    towards[3] = 2  # (0,1) is left of the obstacle: go up first
    reach = greedy_reach(grid, towards[None], max_steps=10)
    assert reach[0] == 1.0
    assert greedy_reach(grid, towards[None], max_steps=1)[0] == pytest.approx(2 / 7)


def test_paper_position():
    pos = paper_position(np.arange(100), 10)
    assert pos["percentile"] == pytest.approx(10.5) and pos["within_5_95"]
    assert not paper_position(np.arange(100), 99)["within_5_95"]
    assert paper_position(np.full(10, 5.0), 163)["share_at_least"] == 0.0


def test_modes_meet_the_issue_sizes():
    from jaxeac.experiments.reproduce import FULL

    assert FULL.grid_seeds >= 10_000 and FULL.bowling_seeds >= 1_000
    assert 100 <= QUICK.bowling_seeds <= 200
    assert set(FULL.ablation_algos) >= {"ac", "eac", "eac_success_only", "eac_failure_only",
                                        "eac_learn_on_memory", "eac_within_trial"}
