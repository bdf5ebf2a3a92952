"""The paper's claims and the fixed rules that decide whether each holds (`VERDICT_RULES`).

Claim ids: GRID-1…5 (§V-A: Fig. 2, Fig. 3) and BOWL-1…4 (§V-B: Table I, Fig. 5). They are
not SPEC ids: SPEC G1… and B1… pin the grid world and the bowling scene. Claims added after
the first six (GRID-4, GRID-5, BOWL-4) carry their own rule (``rule``), which the report states
before the result.
"""

from __future__ import annotations

from jaxeac import paper

#: Significance level of every verdict.
ALPHA = 0.05
VERDICT_RULES = (
    "Verdicts follow fixed rules, set before looking at the results. A comparison *supports* a "
    f"direction when its 95 % CI excludes 0 and its (Holm-adjusted where declared) p ≤ {ALPHA}. "
    "A claim **holds** when the direction is supported and, for the paper's single-run numbers, "
    "each lies within the central 90 % (5th–95th percentile) of our seeds; it **partly holds** "
    "when the direction is supported but a single-run number lies outside that range (or only one "
    "half of a two-part claim is supported); it **does not hold** when the direction is not "
    "supported or is reversed."
)


def supported(c: dict, p_key: str = "p_welch") -> int:
    """+1 / −1 when the CI excludes 0 and p ≤ α (in that direction), else 0."""
    lo, hi = c["diff_ci95"]
    p = c.get(p_key, c["p_welch"])
    if p is None or not p <= ALPHA:
        return 0
    return 1 if lo > 0 else -1 if hi < 0 else 0


def _outside(pos: dict) -> str:
    far = [f"the paper's {a.upper()} {pos[a]['value']:.3g} lies at percentile {pos[a]['percentile']:.1f} "
           "of our seeds"
           for a in ("ac", "eac") if not pos[a]["within_5_95"]]
    return "; " + ", ".join(far) + " (outside the 5-95% range)"


def _one_sample_direction(s: dict) -> int:
    """`supported` for a one-sample summary (`measures.one_sample`): its t CI and p against 0."""
    return supported({"diff_ci95": s["ci95"], "p_welch": s["p_ttest_vs_0"]})


def _headline_verdict(cid, experiment, claim, paper_says, measure, stats, pos, what,
                      reversed_why=None) -> dict:
    """A headline claim (GRID-1, BOWL-1): EAC > AC on the primary measure (Holm), and whether both of the
    paper's single-run results lie within our seeds' 5-95% range."""
    d = supported(stats, "p_holm")
    within = pos["ac"]["within_5_95"] and pos["eac"]["within_5_95"]
    against = reversed_why if d < 0 and reversed_why else "EAC > AC is not supported"
    return {
        "id": cid, "experiment": experiment, "claim": claim, "paper": paper_says, "measure": measure,
        "stats": stats,
        "verdict": "holds" if d > 0 and within else "partly holds" if d > 0 else "does not hold",
        "why": ("EAC > AC is supported" if d > 0 else against)
        + (f"; both single-run {what} lie within our seeds' 5-95% range" if within else _outside(pos)),
    }


def judge_claims(grid: dict, gstats: dict, bowl: dict, bstats: dict) -> list[dict]:
    """The paper's claims, each with what we found and a verdict (`VERDICT_RULES`)."""
    g, b = paper.GRID_SUCCESSES, paper.BOWLING_PINS
    out = []
    # GRID-1: the end points of Fig. 3.
    out.append(_headline_verdict(
        "GRID-1", "grid",
        f"EAC reaches the goal more often than AC: {g['eac']} vs {g['ac']} of {paper.GRID_TRIALS} trials",
        f"EAC {g['eac']}, AC {g['ac']} (one run each; difference +{g['eac'] - g['ac']})", "successes",
        gstats["primary"], grid["paper_position"], "numbers"))
    # GRID-2: faster learning / steeper curve from the first trials.
    auc = gstats["secondary"]["auc_cumulative"]
    fs = gstats["secondary"]["first_success"]
    cur = gstats["curves"]
    early = max(1, grid["trials"] // 10)
    d_auc = supported(auc, "p_holm")
    sustained = cur.get("sustained_from_trial")
    early_ok = sustained is not None and sustained <= early and cur["diff"][-1] > 0
    out.append({
        "id": "GRID-2", "experiment": "grid",
        "claim": "EAC learns faster (steeper cumulative curve), steadily from the first trials; "
                 "AC learns slowly",
        "paper": "Fig. 3: EAC's slope higher throughout; AC speeds up only after trial "
                 f"~{paper.GRID_AC_SPEEDUP_TRIAL}",
        "measure": "auc_cumulative", "stats": auc, "first_success": fs, "curve": {
            "sustained_from_trial": sustained, "first_significant_trial": cur.get("first_significant_trial"),
            "n_significant_trials": len(cur.get("significant_trials", [])), "trials": cur["trials"]},
        "verdict": "holds" if d_auc > 0 and early_ok else "partly holds" if d_auc > 0 else "does not hold",
        "why": ("the area under EAC's cumulative curve is larger" if d_auc > 0 else
                "the area under the cumulative curves does not favour EAC")
        + (f"; EAC's per-trial success rate is higher on every trial from trial {sustained} on "
           f"(max-T permutation, FWER {ALPHA})" if sustained else "; no sustained per-trial advantage")
        + ("" if early_ok or d_auc <= 0 else f", which is later than the first {early} trials"),
    })
    # GRID-3: Fig. 2 — EAC's final policy is more optimised.
    rc = grid["greedy_reach"]["contrast"]
    d = supported(rc)
    out.append({
        "id": "GRID-3", "experiment": "grid",
        "claim": "EAC ends with a better policy than AC (Fig. 2: greedy paths reach the goal)",
        "paper": "Fig. 2: one EAC and one AC policy drawn; EAC's 'more optimized'",
        "measure": "greedy_reach", "stats": rc,
        "verdict": "holds" if d > 0 else "does not hold",
        "why": "greedy paths of EAC's final policies reach the goal from more start cells" if d > 0 else
        "EAC's final greedy policies do not reach the goal from more start cells than AC's",
    })
    out.append(_speedup_claim(grid["speedup"]))
    out.append(_paths_claim(grid["paths"]))
    # BOWL-1: the totals of Table I.
    out.append(_headline_verdict(
        "BOWL-1", "bowling",
        f"EAC knocks more pins than AC: {b['eac']} vs {b['ac']} of {paper.BOWLING_MAX_PINS} (Table I)",
        f"EAC {b['eac']}, AC {b['ac']} (one run each; difference +{b['eac'] - b['ac']})", "return",
        bstats["primary"], bowl["paper_position"], "totals",
        reversed_why="EAC < AC: the difference is reversed"))
    # BOWL-2: EAC's chance-1 angle negative, chance-2 positive after ~5 trials.
    ang = bowl["angles"]
    e1, e2 = ang["eac"]["theta1"], ang["eac"]["theta2"]
    neg = e1["ci95"][1] < 0 and e1["share_claimed_side_ci95"][0] > 0.5
    posi = e2["ci95"][0] > 0 and e2["share_claimed_side_ci95"][0] > 0.5
    lo_t, hi_t = bowl["angle_window"]
    out.append({
        "id": "BOWL-2", "experiment": "bowling",
        "claim": f"After ~{paper.ANGLE_SETTLE_TRIALS} trials EAC's chance-1 angle settles negative "
                 "(right pins), chance-2 positive (left pins)",
        "paper": "Fig. 5: one EAC run converges to θ₁ < 0, θ₂ > 0", "measure": "theta", "stats": ang,
        "verdict": "holds" if neg and posi else "partly holds" if neg or posi else "does not hold",
        "why": f"over trials {lo_t}-{hi_t}, EAC's mean chance-1 angle is {e1['mean']:+.4f} rad "
               f"({'negative' if neg else 'not reliably negative'}; "
               f"{100 * e1['share_claimed_side']:.0f}% of seeds below 0) and its chance-2 angle "
               f"{e2['mean']:+.4f} rad ({'positive' if posi else 'not reliably positive'}; "
               f"{100 * e2['share_claimed_side']:.0f}% of seeds above 0)",
    })
    # BOWL-3: AC finds no well-defined policy, EAC does.
    c = ang["contrast_sd_theta1"]
    d = supported(c)
    out.append({
        "id": "BOWL-3", "experiment": "bowling", "claim": "AC finds no well-defined policy; EAC does",
        "paper": "Fig. 5: AC's angles keep wandering", "measure": "sd_theta1", "stats": c,
        "verdict": "holds" if d < 0 else "does not hold",
        "why": (f"EAC's chance-1 angle varies less over trials {lo_t}-{hi_t} than AC's" if d < 0 else
                f"EAC's chance-1 angle varies more than AC's over trials {lo_t}-{hi_t} (reversed)" if d > 0
                else f"EAC's chance-1 angle does not vary less than AC's over trials {lo_t}-{hi_t}"),
    })
    out.append(_split_claim(bowl["chance_split"], bowl["trials"]))
    if "aim" in bowl:
        out.append(_aim_claim(bowl["aim"]))
    return out


def _speedup_claim(sp: dict) -> dict:
    """GRID-4: Fig. 3's AC curve steepens after trial ~180 (`measures.rate_change`, one-sample t)."""
    (e0, e1), (b0, b1), (a0, a1) = sp["windows"]
    rise, bend = sp["ac"]["rise"], sp["ac"]["bend"]
    d_rise, d_bend = _one_sample_direction(rise), _one_sample_direction(bend)
    rule = (
        "The slope of Fig. 3's curve over a window of trials is the success rate in it (successes per "
        f"trial). Per seed, the *rise* at trial {b1} is the rate over trials {a0}–{a1} minus the rate over "
        f"{b0}–{b1}, and the *bend* is that rise minus the rise one window earlier ({b0}–{b1} minus "
        f"{e0}–{e1}): above 0 when the curve steepens at trial {b1} more than it did before. Each is tested "
        "against 0 over seeds (one-sample t test, 95 % t CI). GRID-4 **holds** when AC's rise and bend are "
        f"both supported (CI above 0, p ≤ {ALPHA}); it **partly holds** when only the rise is (AC's rate "
        f"still grows, but no faster at trial {b1} than before); it **does not hold** when the rise is not "
        "supported. EAC's numbers are shown beside AC's, not judged (GRID-2 judges EAC's early learning).")
    why = (f"AC's success rate over trials {a0}-{a1} is {rise['mean']:+.3f} per trial against {b0}-{b1} ("
           + ("a supported rise" if d_rise > 0 else "a supported fall" if d_rise < 0
              else "not a supported rise")
           + f"), and that rise is {bend['mean']:+.3f} against the one before it ("
           + ("a supported bend" if d_bend > 0 else "no supported bend") + ")")
    return {
        "id": "GRID-4", "experiment": "grid",
        "claim": f"AC learns faster after trial ~{paper.GRID_AC_SPEEDUP_TRIAL}: its cumulative curve "
                 "steepens",
        "paper": f"Fig. 3: AC's curve steepens after trial ~{paper.GRID_AC_SPEEDUP_TRIAL}; EAC's slope is "
                 "steady and high", "measure": "rate_change", "stats": sp, "rule": rule,
        "verdict": ("holds" if d_rise > 0 and d_bend > 0 else "partly holds" if d_rise > 0
                    else "does not hold"),
        "why": why,
    }


def _paths_claim(paths: dict) -> dict:
    """GRID-5: Fig. 2's EAC paths are "more optimized" (`measures.path_ratios`, EAC against AC)."""
    w0, w1 = paths["window"]
    d_ratio, d_opt = supported(paths["contrast_ratio"]), supported(paths["contrast_optimal"])
    both = (d_ratio < 0) + (d_opt > 0)
    rule = (
        "A successful trial's *path ratio* is the chances it used over the fewest moves (G2, G4) from its "
        "start cell to the goal, by breadth-first search on the map; start cells are recomputed from the "
        "seeds' streams (G3, R1); 1 is a shortest path. Per seed, over trials "
        f"{w0}–{w1}: the mean ratio of its successful trials and the share of them on a shortest path "
        "(seeds with no success there are left out). GRID-5 **holds** when EAC's mean ratio is lower "
        "and its share of shortest paths higher than AC's, both supported; it **partly holds** when one of "
        "the two is; it **does not hold** when neither is. Both measures count successful trials only: "
        "each method is judged on the paths it completed.")
    ac, eac = paths["ac"], paths["eac"]
    why = (f"over trials {w0}-{w1}, successful paths are {eac['ratio']['mean']:.3f} (EAC) vs "
           f"{ac['ratio']['mean']:.3f} (AC) times the shortest ("
           + ("EAC shorter" if d_ratio < 0 else "EAC longer" if d_ratio > 0 else "no reliable difference")
           + f") and {100 * eac['optimal']['mean']:.1f} % vs {100 * ac['optimal']['mean']:.1f} % are "
           "shortest ("
           + ("EAC more" if d_opt > 0 else "EAC fewer" if d_opt < 0 else "no reliable difference") + ")")
    return {
        "id": "GRID-5", "experiment": "grid",
        "claim": "EAC's paths to the goal are closer to the shortest than AC's",
        "paper": "Fig. 2: one EAC and one AC policy drawn; EAC's paths 'more optimized'",
        "measure": "path_ratio", "stats": paths, "rule": rule,
        "verdict": "holds" if both == 2 else "partly holds" if both == 1 else "does not hold", "why": why,
    }


def _split_claim(split: dict, trials: int) -> dict:
    """BOWL-4: Table I's split of pins between the chances (`measures.chance_split`), by the headline rule."""
    pp = {a: split[a]["paper"] for a in ("ac", "eac")}

    def run(a):
        return f"{pp[a]['chance2']} of {pp[a]['chance1'] + pp[a]['chance2']}"

    c = _headline_verdict(
        "BOWL-4", "bowling",
        f"EAC knocks a larger share of its pins with chance 2 than AC: {run('eac')} vs {run('ac')} (Table I)",
        f"EAC {pp['eac']['chance1']} + {pp['eac']['chance2']}, AC {pp['ac']['chance1']} + "
        f"{pp['ac']['chance2']} pins (chance 1 + chance 2; one run each)", "share_chance2", split["contrast"],
        split["paper_position"], "shares",
        reversed_why="EAC's share of chance-2 pins is lower than AC's (reversed)")
    c["rule"] = (
        f"Per seed, the share of its pins knocked with chance 2: chance-2 pins over all pins of its {trials} "
        "trials (a strike's trial has no chance 2: its pins count for chance 1; seeds with no pins are left "
        f"out). Table I's runs give EAC {pp['eac']['share_chance2']:.3f} and AC "
        f"{pp['ac']['share_chance2']:.3f}. "
        "BOWL-4 follows the rule of the headline claims: it **holds** when EAC's share is higher than AC's "
        "(supported) and each of the paper's shares lies within the 5–95 % range of our seeds of its method; "
        "it **partly holds** when the direction is supported but a share lies outside; it **does not hold** "
        "otherwise.")
    return c



def _aim_claim(aim: dict) -> dict:
    """BOWL-5: Fig. 5 in a form the scene's symmetry does not decide: does EAC's chance-2 angle aim at
    the pins still standing (`measures.toward_standing`), more often than chance and than AC's?"""
    above_half = _one_sample_direction(aim["eac"])
    beats_ac = supported(aim["contrast"])
    lo, hi = aim["window"]
    c = {"id": "BOWL-5", "experiment": "bowling",
         "claim": "EAC's chance-2 angle aims at the pins still standing after chance 1 (Fig. 5: θ₂ on the "
                  "side of the pins θ₁ left)",
         "paper": "Fig. 5: after ~5 trials EAC's θ₁ < 0 (right pins), θ₂ > 0 (left pins); one run",
         "measure": "share_chance2_toward_standing", "stats": aim["contrast"],
         "verdict": "holds" if above_half > 0 and beats_ac > 0 else
                    "partly holds" if above_half > 0 or beats_ac > 0 else "does not hold",
         "why": ("EAC aims at the standing side more often than not" if above_half > 0 else
                 "EAC does not aim at the standing side more often than not")
                + (", and more often than AC" if beats_ac > 0 else ", but not more often than AC")}
    c["rule"] = (
        f"In our symmetric scene θ₁ < 0, θ₂ > 0 cannot be the one optimum, so BOWL-2 tests the scene as much "
        f"as EAC. BOWL-5 asks what Fig. 5 shows in a form symmetry does not decide: per seed, over trials "
        f"{lo}–{hi}, the share of its chance-2 throws whose angle has the sign of the side where the pins "
        f"standing after chance 1 lie (their mean lateral position at least {aim['side_min_m']:g} m off the "
        "centre line; θ₂ = 0 and centred racks count for no side). It **holds** when EAC's mean share "
        "is above ½ (one-sample t on share − ½, supported) and above AC's (supported); it **partly holds** "
        "when one of the two is supported; it **does not hold** otherwise.")
    return c
