"""report.md for `jaxeac compare` (SPEC §6), its file names and progress bar; the figures it shows
(`FIGURES`) are drawn by `jaxeac.plots.comparison_figures`."""

from __future__ import annotations

import json
import math
from pathlib import Path

from jaxeac.fmt import compact, compact_interval, p_is, p_sig, size_word
from jaxeac.stats.family import family_comparison

#: The comparison's figures: their file names in a run folder (a second comparison's get a suffix).
FIGURES = {
    "curves": "compare_curves.png",
    "distributions": "compare_distributions.png",
    "improvement": "compare_improvement.png",
}


def _pct(stats: dict) -> str:
    """The level of the report's intervals, as printed ("95 %", "99 %")."""
    level = stats.get("level", 1 - stats["settings"]["alpha"])
    return f"{100 * level:.6g} %"


def plain_words(stats: dict) -> str:
    """A paragraph in plain words on the primary measure and the curves."""
    pr = stats["primary"]
    b, t = stats["baseline"].upper(), stats["treatment"].upper()
    alpha = stats["settings"]["alpha"]
    p_holm = pr.get("p_holm", pr["p_welch"])
    better = pr["diff"] > 0 if pr["higher_is_better"] else pr["diff"] < 0
    sig = p_holm <= alpha and not (pr["diff_ci"][0] <= 0 <= pr["diff_ci"][1])
    lines = [
        f"On the primary measure ({pr['description']}), {t} averaged {compact(pr['mean_treatment'], 2)} "
        f"and {b} {compact(pr['mean_baseline'], 2)} over {pr['n_treatment']} and {pr['n_baseline']} seeds: "
        f"a difference of {compact(pr['diff'], 2)} ({_pct(stats)} CI {compact_interval(pr['diff_ci'], 2)}, "
        f"Holm-adjusted {p_is(p_holm)})."
    ]
    if sig:
        lines.append(f"{t} is {'better' if better else 'worse'} than {b} on this measure at α = {alpha}.")
    else:
        lines.append(f"At α = {alpha} the data do not show a difference between {t} and {b} on this measure.")
    lines.append(
        f"A randomly chosen {t} seed scores higher than a randomly chosen {b} seed with probability "
        f"{compact(pr['a12'], 2)} ({_pct(stats)} CI {compact_interval(pr['a12_ci'], 2)}); "
        f"the standardised effect is {size_word(pr['hedges_g'])} "
        f"(Hedges' g = {compact(pr['hedges_g'], 2)})."
    )
    n80 = pr["seeds_for_80pct_power"]
    if n80 is None:
        lines.append("The observed effect is zero, so no number of seeds gives 80 % power to detect it.")
    else:
        lines.append(
            f"Detecting an effect of this size with 80 % power at α = {alpha} needs {n80} seeds per method."
        )
    cur = stats.get("curves")
    if cur:
        k = len(cur["significant_trials"])
        what = "success rates" if cur["kind"] == "success_rate" else "mean returns"
        if k == 0:
            lines.append(
                f"No single trial's {what} differ after family-wise control over all {cur['trials']} trials."
            )
        else:
            s = f"Per-trial {what} differ (family-wise α = {alpha}) at {k} of {cur['trials']} trials"
            s += f", first at trial {cur['first_significant_trial']}"
            if cur["sustained_from_trial"] is not None:
                s += f", and at every trial from trial {cur['sustained_from_trial']} on"
            lines.append(s + ".")
    cal = stats.get("calibration", {}).get("false_positive_rate")
    if cal:
        r = cal["welch"][stats["primary"]["measure"]]
        lines.append(
            f"As a check, {b} against itself (random halves) gave Welch's test a false-positive rate of "
            f"{compact(r['rate'], 3)} ({_pct(stats)} CI {compact_interval(r['ci'], 3)}) against the nominal "
            f"{alpha}."
        )
    return " ".join(lines)


def _large(stats: dict) -> bool:
    return stats["settings"].get("scale", {}).get("path") == "large-N"


def scale_paragraph(stats: dict) -> list[str]:
    """Which methods the large-N path used (`jaxeac.stats.large`); nothing below its threshold."""
    if not _large(stats):
        return []
    sc = stats["settings"]["scale"]
    exact = [k for k, m in sc["measures"].items() if m["bootstrap"].startswith("exact")]
    asym = [k for k in sc["measures"] if k not in exact]
    text = (
        f"At this scale (above {sc['large_n_threshold']:,} seeds per method) the statistics take the "
        "large-N path (`jaxeac.stats.large`). "
    )
    if exact:
        text += (
            f"{', '.join(exact)} (at most {sc['max_distinct_values_exact']:,} distinct values): resampled "
            "exactly, as counts per distinct value (bootstrap: multinomial, Efron 1979; permutations: "
            "multivariate hypergeometric), the same law as resampling seeds. "
        )
    if asym:
        text += (
            f"{', '.join(asym)} (more distinct values): ABC intervals, the analytic form of BCa "
            "(DiCiccio & Efron 1992), and the normal limit of the studentised permutation test "
            "(Janssen 1997). "
        )
    if "curves" in sc:
        text += f"Curves: {sc['curves']['bands']}; trials that differ: {sc['curves']['trials_differ']}. "
    text += (
        "ABC agrees with BCa of unlimited resamples to O(N^-3/2); the normal and Gaussian limits of these "
        "two-sided statistics differ from the exact laws by O(1/N) (for 0/1 data plus a lattice term "
        "of order 1/√N times a small constant), below the Monte Carlo error of the resampling at this N."
    )
    return ["", text]


def paired_section(stats: dict) -> list[str]:
    """The paired analysis (`jaxeac.stats.paired`), the default where seed i of both methods
    shares its key: per measure, the mean difference, its paired CI, tests and d_z."""
    paired = stats.get("paired")
    if not paired:
        return []
    b, t = stats["baseline"].upper(), stats["treatment"].upper()
    rows = []
    for name, r in paired["measures"].items():
        rows.append(f"| {name} | {compact(r['mean_diff'], 4, sign=True)} "
                    f"{compact_interval(r['mean_diff_ci'], 4)} | {compact(r['se_diff'])} | "
                    f"{p_sig(r['p_paired_t'])} | {p_sig(r['p_sign_flip'])} | "
                    f"{compact(r['d_z'])} {compact_interval(r['d_z_ci'])} | "
                    f"{compact(r['correlation'], 2)} |")
    primary = stats["primary"]
    pr = paired["measures"][primary["measure"]]
    unpaired_width = primary["diff_ci"][1] - primary["diff_ci"][0]
    width = pr["mean_diff_ci"][1] - pr["mean_diff_ci"][0]
    relative = (f"{width / unpaired_width:.2f}×" if unpaired_width and math.isfinite(width / unpaired_width)
                else "n/a (a zero-width unpaired interval) of")
    return [
        "## Paired analysis (this design's default: it answers the question)",
        "",
        f"Design: {paired['design']}. Differences are {t} − {b} of the same seed; CIs are "
        f"{_pct(stats)} paired "
        "BCa bootstrap (seeds resampled as pairs); p from the paired t test and the sign-flip "
        "permutation test; d_z = mean / sd of the differences; r: correlation of the two methods' "
        f"per-seed values. On the primary measure the paired interval is {relative} the "
        "width of the unpaired one below (`jaxeac compare --unpaired` leaves this section out).",
        "",
        f"| measure | mean difference [{_pct(stats)} CI] | SE | p paired t | p sign-flip | "
        f"d_z [{_pct(stats)} CI] | r |",
        "|---|---|---|---|---|---|---|",
        *rows,
        "",
    ]


def sequential_section(seq: dict | None) -> list[str]:
    """The report's account of a sequential run: design, looks, decision, simulated error rates."""
    if not seq:
        return []
    rows = [f"| {k + 1} | {x['seeds']} | {x['diff']:+.3f} | [{x['rci'][0]:+.3f}, {x['rci'][1]:+.3f}] | "
            f"{x['boundary_z']:.3f} | {x['decision']} |" for k, x in enumerate(seq["looks_taken"])]
    out = [
        "## Sequential decision",
        "",
        f"**{seq['decision']}** after {len(seq['looks_taken'])} of {seq['looks']} looks, at "
        f"{seq['seeds_used']} seeds per method (of at most {seq['sizes'][-1]}). "
        f"Design, fixed before the first batch: {seq['design']} ({seq['spending']} spending), "
        f"error rate {seq['alpha']} each way, declared effect ±{seq['effect']:g}, "
        f"{'paired looks (seed i of both methods shares its key)' if seq.get('paired') else 'Welch looks'}. "
        "“difference”: the repeated CI excludes 0; “no difference”: it lies within ± the effect; "
        "the K repeated CIs cover the true difference at once with probability ≥ 1 − α whenever "
        "the run stops. The fixed-sample tests below are computed on the seeds run and do not "
        "account for the stopping rule; the sequential decision is the one the design controls.",
        "",
        "| look | seeds per method | EAC − AC | repeated CI | z boundary | decision |",
        "|---|---|---|---|---|---|",
        *rows,
        "",
    ]
    cal = seq.get("calibration")
    if cal:
        def rates(r):
            return ", ".join(f"{k} {v['rate']:.3f} ± {v['se']:.3f}" for k, v in r["decisions"].items())

        null, alt = cal["null"], cal["observed"]
        out += [
            f"Simulated from this run's per-seed differences ({null['experiments']} sequential experiments "
            f"each{', drawn with replacement' if null.get('with_replacement') else ''}): with random signs "
            f"(no true difference; “difference” is a false positive, nominal ≤ {seq['alpha']}): "
            f"{rates(null)}; mean {null['mean_seeds_used']:.0f} seeds per method. As observed: "
            f"{rates(alt)}; mean {alt['mean_seeds_used']:.0f} seeds per method.",
            "",
        ]
    return out


def family_section(stats: dict) -> list[str]:
    """Every algorithm of the run against the baseline (`jaxeac.stats.family`), where it ran more than two."""
    if not stats.get("family"):
        return []
    body = family_comparison(stats["family"]).markdown().splitlines()[2:]  # below its own title
    t = stats["treatment"].upper()
    note = (f"The family is drawn with its own resamples, so its {t} row can differ from the full {t} "
            "analysis above in the last digits of an interval.")
    return [f"## Every algorithm against {stats['baseline'].upper()}: the declared family", "", note, "",
            *body, ""]


def render_markdown(stats: dict) -> str:
    """The readable report."""
    b, t = stats["baseline"].upper(), stats["treatment"].upper()
    figures = stats.get("files", {}).get("figures", FIGURES)  # a second comparison's carry its suffix
    st = stats["settings"]
    holm = stats["holm"]
    res = [stats["primary"], *stats["secondary"].values()]
    out = [
        f"# {t} versus {b} on {stats['subject']}" if stats.get("subject")
        else f"# {t} versus {b}: {stats['experiment']} run",
        "",
        f"Run directory: `{stats['run_dir']}`; {stats['trials']} trials per seed; "
        f"{stats['primary']['n_baseline']} {b} seeds and {stats['primary']['n_treatment']} {t} seeds"
        + (f"; algorithms run: {', '.join(stats['algos_run'])}" if len(stats.get("algos_run", ())) > 2
           else "")
        + (f". Settings: {stats['run_settings']} (all of them, and the command: summary.json)"
           if stats.get("run_settings") else "")
        + f". The seed is the unit of analysis. Every interval is at the {_pct(stats)} level; p-values in "
        "three significant figures.",
        "",
        "## In plain words",
        "",
        plain_words(stats),
        "",
        *family_section(stats),
        *sequential_section(stats.get("sequential")),
        *paired_section(stats),
        "## Estimates" + (" as independent samples (unpaired; secondary: the paired results above answer "
                          "the question)" if stats.get("analysis") == "paired" else ""),
        "",
        f"Differences are {t} − {b}. CIs are {_pct(stats)} BCa bootstrap ({st['resamples']} resamples "
        "per method) "
        "except A12 (Brunner–Munzel). p (Holm) adjusts the declared family "
        f"({', '.join(holm['family'])}) with each measure's declared test "
        f"({'; '.join(f'{k}: {v}' for k, v in holm['tests'].items())}).",
        "",
        f"| measure | {b} mean | {t} mean | difference [{_pct(stats)} CI] | Hedges' g [{_pct(stats)} CI] | "
        f"P({t} better) [{_pct(stats)} CI] | p Welch | p perm. | p Brunner–Munzel | p (Holm) | "
        "seeds for 80 % power |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in res:
        role = " (primary)" if r is stats["primary"] else ""
        arrow = "↑" if r["higher_is_better"] else "↓"
        out.append(
            f"| {r['measure']}{role} {arrow} | {compact(r['mean_baseline'])} | "
            f"{compact(r['mean_treatment'])} | {compact(r['diff'])} {compact_interval(r['diff_ci'])} | "
            f"{compact(r['hedges_g'])} {compact_interval(r['hedges_g_ci'])} | "
            f"{compact(r['prob_improvement'])} {compact_interval(r['prob_improvement_ci'])} | "
            f"{p_sig(r['p_welch'])} | {p_sig(r['p_permutation'])} | "
            f"{p_sig(r['brunner_munzel']['p'])} | {p_sig(r.get('p_holm'))} | "
            f"{compact(r['seeds_for_80pct_power'])} |"
        )
    out += scale_paragraph(stats)
    out += ["", "↑ higher is better, ↓ lower is better. Measures:", ""]
    out += [f"- `{r['measure']}`: {r['description']}" for r in res]
    pr = stats["primary"]
    pw = pr["power"]
    out += [
        "",
        f"Interquartile mean of the primary measure: "
        f"{b} {compact(pr['iqm_baseline'])} {compact_interval(pr['iqm_baseline_ci'])}, "
        f"{t} {compact(pr['iqm_treatment'])} {compact_interval(pr['iqm_treatment_ci'])} ({_pct(stats)} BCa).",
        "",
        f"Seeds per method for 80 % power (two-sided t-test, α = {st['alpha']}): observed effect "
        f"(|g| = {compact(pw['observed_d'])}) {compact(pw['seeds_for_80pct_power'])}; "
        f"d = 0.2: {pw['d=0.2']}; d = 0.5: {pw['d=0.5']}; d = 0.8: {pw['d=0.8']}.",
        "",
        "## Time to first success and success proportions",
        "",
        f"Log-rank test on the first successful trial (censored at {stats['trials']} when none): "
        f"χ² = {compact(stats['logrank']['chi2'])}, p = {p_sig(stats['logrank']['p'])}.",
        "",
        f"| outcome per seed | {b} | {t} | risk difference [{_pct(stats)} CI, Newcombe] "
        f"| risk ratio [{_pct(stats)} CI, score] |",
        "|---|---|---|---|---|",
    ]
    for name, pr_ in stats["proportions"].items():
        out.append(
            f"| {name} | {pr_['count_baseline']}/{pr_['n_baseline']} "
            f"| {pr_['count_treatment']}/{pr_['n_treatment']} | "
            f"{compact(pr_['risk_difference'])} {compact_interval(pr_['risk_difference_ci'])} | "
            f"{compact(pr_['risk_ratio'])} {compact_interval(pr_['risk_ratio_ci'])} |"
        )
    cur = stats.get("curves")
    if cur:
        sig = cur["significant_trials"]
        out += [
            "",
            "## Learning curves",
            "",
            f"![learning curves]({figures['curves']})",
            "",
            f"Bands: {cur['band_method']}, holding over all {cur['trials']} trials at once. "
            f"Trials where the methods differ: {cur['test_method']}, {st['permutations']} "
            f"{'draws of that limit' if _large(stats) else 'permutations'}; "
            f"{len(sig)} of {cur['trials']} trials significant"
            + (f" (first: {cur['first_significant_trial']}" if sig else "")
            + (f"; every trial from {cur['sustained_from_trial']} on" if cur["sustained_from_trial"] else "")
            + (")" if sig else "")
            + ".",
        ]
    out += [
        "",
        "## Per-seed distributions",
        "",
        f"![per-seed distributions]({figures['distributions']})",
        "",
        "## Probability of improvement",
        "",
        f"![probability of improvement]({figures['improvement']})",
        "",
    ]
    cal = stats.get("calibration", {})
    if "false_positive_rate" in cal:
        out += [
            "## Calibration: baseline against itself",
            "",
            f"{cal['splits']} random splits of the {b} seeds into two disjoint groups of "
            f"{cal['group_size']}; permutation reference {cal['resamples']} relabellings. "
            f"Each rate should be near α = {cal['alpha']} (with {cal['splits']} splits, a rate is within "
            f"about ±{compact(2 * math.sqrt(cal['alpha'] * (1 - cal['alpha']) / cal['splits']), 3)} "
            "of α by chance)."
            + (
                " At this scale each half of a measure is drawn as counts per distinct value "
                "(multivariate hypergeometric, exact), each half for the curves as an exact random half "
                "of the seeds, and the curve test's reference is its Gaussian limit, as in the comparison."
                if "large_n" in cal
                else ""
            ),
            "",
            f"| test | measure | false-positive rate [{_pct(stats)} CI] |",
            "|---|---|---|",
        ]
        for test, per in cal["false_positive_rate"].items():
            for name, r in per.items():
                out.append(f"| {test} | {name} | {compact(r['rate'])} {compact_interval(r['ci'])} |")
    elif cal:
        out += ["## Calibration", "", f"Skipped: {cal.get('skipped')}"]
    out += [
        "",
        "## Reproducibility",
        "",
        f"Key {st['key']} (bootstrap, permutation and calibration keys derived from it "
        "by `jax.random.split`); "
        f"{st['resamples']} bootstrap resamples per method, {st['permutations']} permutations, "
        f"chunks of {st['chunk']}; calibration {st['calibration_splits']} splits × "
        f"{st['calibration_resamples']} "
        f"relabellings. Versions: {', '.join(f'{k} {v}' for k, v in stats['versions'].items())}. "
        f"Resampling took {compact(stats['timing']['resample_seconds'], 2)} s, "
        f"everything {compact(stats['timing']['total_seconds'], 2)} s.",
        "",
    ]
    return "\n".join(out)


def output_suffix(run_dir, baseline: str, treatment: str) -> str:
    """"" where the folder holds no comparison yet or one of the same two methods (it is redone),
    else ``_<baseline>_vs_<treatment>``: a second comparison of a folder never replaces the first."""
    try:
        first = json.loads((Path(run_dir) / "stats.json").read_text(encoding="utf-8"))
        pair = (first["baseline"], first["treatment"])
    except (OSError, ValueError, KeyError, TypeError):
        return ""
    return "" if pair == (baseline, treatment) else f"_{baseline}_vs_{treatment}"


def progress_bar(progress: bool, baseline: str, treatment: str):
    """The comparison's two-step bar (statistics, report), on a terminal only; None if not `progress`."""
    if not progress:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=2, desc=f"compare {treatment} vs {baseline}: statistics", leave=False,
                disable=None)  # not into a log or a pipe: only on a terminal
