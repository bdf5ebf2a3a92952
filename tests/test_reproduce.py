"""`jaxeac reproduce` end to end at a tiny size: report, verdicts, numbers from the step JSONs, resume;
and the per-seed measures of the claims by hand on tiny made-up inputs."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from jaxeac import paper
from jaxeac.envs.grid import parse_map, shortest_steps
from jaxeac.errors import UsageError
from jaxeac.experiments.reproduce import (
    QUICK,
    Sizes,
    chance_split,
    greedy_reach,
    paper_position,
    path_ratios,
    path_window,
    rate_change,
    reproduce,
)
from jaxeac.experiments.reproduce import supported as _supported

TINY = Sizes(grid_seeds=24, bowling_seeds=4, calibration_seeds=8,
             calibration_sets=("alpha=0.05,0.1", "beta=0.3,0.9"), ablation_grid_seeds=16,
             ablation_bowling_seeds=4, ablation_algos=("ac", "eac", "eac_success_only"),
             temperatures=(0.5, 1.0), noise_scales=(0.0, 1.0), resamples=200, band_resamples=200,
             bowling_calibration_seeds=4, bowling_calibration_grid=(("beta", (0.1, 0.3)), ("theta_max", (0.1, 0.2))),
             bowling_calibration_lines=(("alpha", (0.2,)),), bowling_ablation_algos=("eac_success_only",))
VERDICTS = ("holds", "partly holds", "does not hold")
CLAIMS = ("GRID-1", "GRID-2", "GRID-3", "GRID-4", "GRID-5", "BOWL-1", "BOWL-2", "BOWL-3", "BOWL-4", "BOWL-5")


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
    from jaxeac.results import load_grid_results

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


def test_new_claims_state_their_rule_before_the_result(run):
    out, report = run
    text = report.read_text()
    rec = json.loads((out / "reproduce.json").read_text())
    c = {x["id"]: x for x in rec["claims"]}
    for cid in ("GRID-4", "GRID-5", "BOWL-4"):
        sec = section(text, f"### {cid} ")
        assert sec.index(f"*Rule, fixed before the run.* {c[cid]['rule']}") < sec.index("| ") < sec.index(
            "**Verdict:")

    sp, g4 = rec["grid"]["speedup"], section(text, "### GRID-4 ")
    assert sp["windows"] == [[141, 160], [161, 180], [181, 200]]
    for a in ("ac", "eac"):
        rise, bend = sp[a]["rise"], sp[a]["bend"]
        rates = " | ".join(f"{sp[a]['rates'][w]['mean']:.3f}" for w in ("earlier", "before", "after"))
        assert (f"| {a.upper()} | {rates} | {rise['mean']:+.3f} [{rise['ci95'][0]:+.3f}, "
                f"{rise['ci95'][1]:+.3f}]") in g4
        assert f"{bend['mean']:+.3f} [{bend['ci95'][0]:+.3f}, {bend['ci95'][1]:+.3f}]" in g4
        assert rise["n"] == TINY.grid_seeds
    pa, g5 = rec["grid"]["paths"], section(text, "### GRID-5 ")
    assert pa["window"] == [181, 200] and "](grid/fig2_path_ratio.png)" in g5
    for name in ("ratio", "optimal"):
        for cell in row_cells(pa[f"contrast_{name}"], 3):
            assert cell in g5, cell
    split, b4 = rec["bowling"]["chance_split"], section(text, "### BOWL-4 ")
    for cell in row_cells(split["contrast"], 3):
        assert cell in b4, cell
    assert "| AC |" in b4 and "40 + 27 (0.403)" in b4 and "40 + 41 (0.506)" in b4
    assert f"{split['paper_position']['eac']['percentile']:.1f} | {TINY.bowling_seeds} |" in b4

    # the per-seed measures behind the numbers, recomputed from the run folders
    from jaxeac.results import load_grid_results

    success = {a: r.success for a, r in load_grid_results(out / "grid", ("ac", "eac"), 200).items()}
    rise = rate_change(success["ac"], 180, 20)["rise"]
    assert sp["ac"]["rise"]["mean"] == pytest.approx(rise.mean())
    assert sp["ac"]["rates"]["after"]["mean"] == pytest.approx(success["ac"][:, 180:].mean())
    with np.load(out / "bowling" / "bowling.npz") as npz:
        share = chance_split(npz["eac_knocked"])["share_chance2"]
    assert split["eac"]["share_chance2"]["mean"] == pytest.approx(np.nanmean(share))


def test_new_verdicts_follow_their_rules(run):
    out, _ = run
    rec = json.loads((out / "reproduce.json").read_text())
    c = {x["id"]: x for x in rec["claims"]}

    def up(s):  # a one-sample summary supports "above 0"
        return s["ci95"][0] > 0 and s["p_ttest_vs_0"] <= 0.05

    def direction(s):
        if not s["p_welch"] <= 0.05:
            return 0
        return 1 if s["diff_ci95"][0] > 0 else -1 if s["diff_ci95"][1] < 0 else 0

    ac = rec["grid"]["speedup"]["ac"]
    assert c["GRID-4"]["verdict"] == ("holds" if up(ac["rise"]) and up(ac["bend"]) else
                                      "partly holds" if up(ac["rise"]) else "does not hold")
    pa = rec["grid"]["paths"]
    n = (direction(pa["contrast_ratio"]) < 0) + (direction(pa["contrast_optimal"]) > 0)
    assert c["GRID-5"]["verdict"] == ("holds", "partly holds", "does not hold")[2 - n]
    split = rec["bowling"]["chance_split"]
    within = all(split["paper_position"][a]["within_5_95"] for a in ("ac", "eac"))
    d = direction(split["contrast"])
    assert c["BOWL-4"]["verdict"] == ("holds" if d > 0 and within else "partly holds" if d > 0 else
                                      "does not hold")


def test_start_cells_of_the_run_fit_its_paths(run):
    """Every successful trial of the recorded run took at least the fewest moves from the start cell
    `start_states` gives it; start cells of another root key break this, so the check has teeth."""
    from jaxeac.experiments.grid import GridSettings
    from jaxeac.results import load_grid_results
    from jaxeac.running.batch import start_states

    out, _ = run
    settings = GridSettings(preset="paper", seeds=TINY.grid_seeds, key=3).resolved()
    env, shortest = settings.make_env(), shortest_steps(settings.grid_map())
    for r in load_grid_results(out / "grid", ("ac", "eac"), settings.trials).values():
        starts = start_states(env, 3, r.seeds, settings.trials)
        ratios = path_ratios(r.success, r.trial_steps, starts, shortest)
        assert np.nanmin(ratios) == 1.0
        wrong = shortest[start_states(env, 4, r.seeds, settings.trials)]
        assert (r.trial_steps[r.success] < wrong[r.success]).any()


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


def test_step_of_an_older_record_runs_again(run):
    """A grid step finished before its record had GRID-4 and GRID-5 (a fingerprint with no record
    version) is recomputed on resume, from its run folder; the other steps are reused."""
    out, _ = run
    before = json.loads((out / "reproduce.json").read_text())
    marker = out / "grid" / "reproduce.json"
    m = json.loads(marker.read_text())
    del m["fingerprint"]["record"]
    for field in ("speedup", "paths"):
        del m["result"][field]
    marker.write_text(json.dumps(m))
    reproduce(out, key=3, progress=False, sizes=TINY)
    after = json.loads((out / "reproduce.json").read_text())
    assert {s: t["resumed"] for s, t in after["timings"].items()} == {
        "grid": False, "bowling": True, "bowling_table1": True, "calibration": True,
        "bowling_calibration": True, "ablations": True}
    assert after["grid"] == before["grid"]
    assert [c["verdict"] for c in after["claims"]] == [c["verdict"] for c in before["claims"]]


def test_rate_change_by_hand():
    success = np.array([[0, 1, 0, 0, 1, 1],
                        [1, 1, 1, 1, 0, 0]], bool)
    m = rate_change(success, at=4, width=2)  # windows: trials 1-2, 3-4, 5-6
    np.testing.assert_allclose(m["earlier"], [0.5, 1.0])
    np.testing.assert_allclose(m["before"], [0.0, 1.0])
    np.testing.assert_allclose(m["after"], [1.0, 0.0])
    np.testing.assert_allclose(m["rise"], [1.0, -1.0])
    np.testing.assert_allclose(m["bend"], [1.5, -1.0])  # (1 − 0) − (0 − 0.5); (0 − 1) − (1 − 1)
    m = rate_change(success, at=4, width=1)  # windows: trials 3, 4, 5
    np.testing.assert_allclose([m["rise"], m["bend"]], [[1.0, -1.0], [1.0, -1.0]])
    with pytest.raises(ValueError):
        rate_change(success, at=3, width=2)  # no room for the earlier window


def test_shortest_steps_and_path_ratios_by_hand():
    grid = parse_map("...\n.#G\n...\n")  # goal (2, 1), obstacle (1, 1)
    shortest = shortest_steps(grid)
    np.testing.assert_array_equal(shortest, [3, 2, 1, 4, -1, 0, 3, 2, 1])  # (0, 1) goes round: 4 moves
    walled = parse_map("G#.\n.#.\n")  # the right column cannot reach the goal
    np.testing.assert_array_equal(shortest_steps(walled), [0, -1, -1, 1, -1, -1])

    success = np.array([[True, True, False, True]])
    steps = np.array([[4, 5, 40, 1]])
    starts = np.array([[3, 0, 2, 8]])  # shortest 4, 3, 1, 1
    ratios = path_ratios(success, steps, starts, shortest)
    np.testing.assert_allclose(ratios, [[1.0, 5 / 3, np.nan, 1.0]])
    w = path_window(ratios, slice(0, 4))
    np.testing.assert_allclose([w["ratio"][0], w["optimal"][0]], [(1 + 5 / 3 + 1) / 3, 2 / 3])
    w = path_window(ratios, slice(1, 3))
    np.testing.assert_allclose([w["ratio"][0], w["optimal"][0]], [5 / 3, 0.0])
    assert np.isnan(path_window(ratios, slice(2, 3))["ratio"][0])  # no success there
    with pytest.raises(ValueError):  # a success from a cell that cannot reach the goal
        path_ratios(success, steps, np.array([[4, 0, 2, 8]]), shortest)


def test_chance_split_by_hand():
    knocked = np.array([[[3, 5], [10, 0]],  # a strike in trial 2: its pins are chance 1's
                        [[0, 0], [0, 0]]])
    s = chance_split(knocked)
    np.testing.assert_array_equal(s["chance1"], [13, 0])
    np.testing.assert_array_equal(s["chance2"], [5, 0])
    assert s["share_chance2"][0] == pytest.approx(5 / 18) and np.isnan(s["share_chance2"][1])
    # Table I: EAC 40 + 41 = 81 pins, AC 40 + 27 = 67
    for algo, (c1, c2) in (("eac", (40, 41)), ("ac", (40, 27))):
        s = chance_split(np.asarray(paper.TABLE_ONE[algo])[None])
        assert (s["chance1"][0], s["chance2"][0]) == (c1, c2)
        assert s["share_chance2"][0] == pytest.approx(c2 / (c1 + c2))


def test_start_states_are_the_runs():
    """`start_states` gives the start cell each trial of the `trials` loop starts in (G3, R1)."""
    import jax

    from jaxeac.algorithm.config import algorithm
    from jaxeac.envs.grid import GridWorld
    from jaxeac.rng import seed_key
    from jaxeac.running.batch import start_states
    from jaxeac.running.config import RunConfig
    from jaxeac.running.loops import trace_run

    env = GridWorld(parse_map("....\n.#G.\n....\n"), 6)
    cfg = RunConfig(trials=8, agent=algorithm("eac"), alpha=0.1, beta=0.3, gamma=0.9, temperature=1.0)
    starts = start_states(env, 11, [0, 5], cfg.trials)
    for row, seed in enumerate((0, 5)):
        _, records = trace_run(env, cfg, seed_key(jax.random.key(11), seed), cfg.hyper())
        np.testing.assert_array_equal(starts[row], np.asarray(records.states)[:, 0])
    assert len(set(starts.ravel().tolist())) > 1


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


# ---------------------------------------------------------------- bowling calibration
def test_failure_rule_counts_by_hand():
    """E6's condition r̃(c | t) < r̃(c | t − 1) in failed trials t ≥ 2, counted by hand."""
    from jaxeac.experiments.reproduce.bowling_calibration import failure_rule_counts

    knocked = np.array([[[7, 2], [6, 3], [10, -1], [5, 1]],    # t2 fails: c1 6<7 fires, c2 3<2 no;
                        [[9, 0], [9, 1], [8, 2], [8, 1]]])     # t3 a strike (succeeds), t4 fails: 5<10
    success = np.array([[False, False, True, False],            # tested only on c1 (c2 not reached in t3)
                        [False, False, False, True]])           # seed 2: t2 none fire, t3 8<9 fires,
    fires, tested = failure_rule_counts(knocked, success)       # c2 2<1 no; t4 succeeds: not tested
    np.testing.assert_array_equal(fires, [2, 1])
    np.testing.assert_array_equal(tested, [3, 4])


def test_bowling_sweep_points_in_order():
    """The grid's product first (the heatmap), then each line's values that differ from the default."""
    from jaxeac.experiments.reproduce.bowling_calibration import sweep_points

    pts = sweep_points((("beta", (0.1, 0.3)), ("theta_max", (0.1, 0.2))), (("alpha", (0.1, 0.2)),))
    assert pts == [{"beta": 0.1, "theta_max": 0.1}, {"beta": 0.1, "theta_max": 0.2},
                   {"beta": 0.3, "theta_max": 0.1}, {"beta": 0.3, "theta_max": 0.2}, {"alpha": 0.2}]


def test_bowling_calibration_record_and_report(run):
    """Every point's numbers are the bowling experiment's own at that point (same seeds and key);
    the calibrated point is the one with AC closest to the paper's 67; the report prints it."""
    from jaxeac.experiments.bowling import run_bowling
    from jaxeac.experiments.reproduce.bowling_calibration import point_settings, sweep_points

    out, report = run
    rec = json.loads((out / "bowling_calibration" / "reproduce.json").read_text())["result"]
    points = sweep_points(TINY.bowling_calibration_grid, TINY.bowling_calibration_lines)
    assert len(rec["points"]) == len(points) == 5
    last = run_bowling(point_settings(points[-1], seeds=4, key=3, chunk=500, algos=("ac", "eac")))
    for algo in ("ac", "eac"):
        assert rec["points"][-1][algo] == pytest.approx(last.results[algo].total_return.mean())
    target = paper.BOWLING_PINS["ac"]
    best = min(rec["points"], key=lambda r: (abs(r["ac"] - target), r["point"]))
    assert rec["calibrated"]["point"] == best["point"]
    assert [v["algo"] for v in rec["ablations"]] == ["eac_success_only"]
    assert (out / "bowling_calibration" / "heatmap.png").stat().st_size > 0
    text = section(report.read_text(), "## Bowling calibration")
    c = rec["calibrated"]  # one CI for the calibrated comparison: the table's, in the text too
    ci = f"{c['diff']:+.2f} [{c['diff_ci95'][0]:+.2f}, {c['diff_ci95'][1]:+.2f}]"
    assert f"EAC − AC {ci} (Welch 95 % CI, as in the table)" in text
    table_row = next(ln for ln in text.splitlines() if ln.startswith("| ") and f"| {c['diff']:+.2f} [" in ln)
    assert ci in table_row
    k = c["contrast"]
    if k["diff_ci95"] != c["diff_ci95"]:
        assert f"[{k['diff_ci95'][0]:+.2f}, {k['diff_ci95'][1]:+.2f}]" not in text.split("Ablations at")[0]
    assert "eac_success_only" in text and "heatmap.png" in text
    plain = section(report.read_text(), "## In plain words")
    assert f"EAC − AC is {ci} pins" in plain


# ---------------------------------------------------------------- BOWL-5 and the table1 scene
def test_toward_standing_by_hand():
    """BOWL-5: a chance-2 angle aims at the standing pins' side when it has the sign of their mean y."""
    from jaxeac.envs.bowling.scene import PIN_XY
    from jaxeac.experiments.reproduce.measures import toward_standing

    left = 1 << 1 | 1 << 3  # pins 2 and 4: y = +0.15, +0.30 (the thrower's left, θ > 0)
    right = 1 << 2  # pin 3: y = −0.15
    centre = 1 << 0  # pin 1: y = 0, no side
    standing = np.array([[[left, 0], [right, 0], [centre, 0], [left, -1]],
                         [[0, -1], [0, -1], [0, -1], [0, -1]]])  # seed 2: all strikes, no chance 2
    angle = np.array([[[0.0, 0.05], [0.0, 0.04], [0.0, 0.02], [0.0, np.nan]],
                      [[0.0, np.nan]] * 4])
    share = toward_standing(standing, angle, PIN_XY, first_trial=1)
    assert share[0] == pytest.approx(0.5)  # trial 1 toward (left, +), trial 2 away (right, +); 3, 4 no side
    assert np.isnan(share[1])
    assert toward_standing(standing, angle, PIN_XY, first_trial=2)[0] == pytest.approx(0.0)


def test_bowl5_and_the_table1_scene_in_the_report(run):
    """BOWL-5's verdict follows its rule; the table1 scene's run is its own and its claims are printed
    beside the default scene's."""
    from jaxeac.experiments.reproduce.claims import supported

    out, report = run
    rec = json.loads((out / "reproduce.json").read_text())
    c = {x["id"]: x for x in rec["claims"]}["BOWL-5"]
    aim = rec["bowling"]["aim"]
    above = supported({"diff_ci95": aim["eac"]["ci95"], "p_welch": aim["eac"]["p_ttest_vs_0"]}) > 0
    beats = supported(aim["contrast"]) > 0
    assert c["verdict"] == ("holds" if above and beats else "partly holds" if above or beats else "does not hold")
    summary = json.loads((out / "bowling_table1" / "summary.json").read_text())
    assert summary["config"]["scene"] == "table1" and summary["physics"]["scene"]["ball_radius"] == 0.06
    text = section(report.read_text(), "### The bowling claims on a deck like Table I's")
    assert [x["id"] for x in rec["claims_table1"]] == ["BOWL-1", "BOWL-2", "BOWL-3", "BOWL-4", "BOWL-5"]
    for x in rec["claims_table1"]:
        assert x["headline"] in text


def test_every_full_bowling_calibration_point_can_run():
    """The full sweep's points are valid bowling settings (K within what EAC's memories hold)."""
    from jaxeac.experiments.reproduce import FULL
    from jaxeac.experiments.reproduce.bowling_calibration import point_settings, sweep_points

    points = sweep_points(FULL.bowling_calibration_grid, FULL.bowling_calibration_lines)
    assert len(points) == 16 + 7
    for p in points:
        point_settings(p, seeds=2, key=0, chunk=2, algos=("ac", "eac", *FULL.bowling_ablation_algos))


def test_table_one_puts_totals_under_their_columns_and_its_means_have_cis(run):
    """Table I of our seed: per-chance totals under each chance's column, the seed's totals in
    words; the means table titled "(95% CI)" gives a CI in every cell; the paper's table in the
    same column order (AC, then EAC)."""
    out, report = run
    text = report.read_text()
    ours = section(text, "#### Table I — pins per chance, seed 0").split("#### Means over")[0]
    rows = [ln for ln in ours.splitlines() if ln.startswith("| ") and not ln.startswith("| trial")]
    cells = [[c.strip() for c in ln.strip("|").split("|")] for ln in rows]
    trials = [r for r in cells if r[0].isdigit()]
    (total,) = [r for r in cells if r[0] == "total per chance"]
    assert len(total) == 5
    for col in range(1, 5):
        assert int(total[col]) == sum(int(r[col]) for r in trials if r[col] != "–")
    seed_totals = re.search(r"Seed 0's totals \(both chances, \d+ trials\): AC \*\*(\d+)\*\*, EAC \*\*(\d+)\*\*",
                            ours)
    assert seed_totals and int(seed_totals[1]) == int(total[1]) + int(total[2])
    assert int(seed_totals[2]) == int(total[3]) + int(total[4])
    means = section(text, "#### Means over")
    assert "(95% CI)" in means.splitlines()[0]
    mean_rows = [ln for ln in means.splitlines() if re.match(r"\| \d+ \|", ln)]
    assert mean_rows and all(ln.count("[") == 4 for ln in mean_rows)
    assert "| trial | paper AC (chance 1 + chance 2) | paper EAC (chance 1 + chance 2) |" in text
    assert f"| total | {paper.BOWLING_PINS['ac']} | {paper.BOWLING_PINS['eac']} |" in text
