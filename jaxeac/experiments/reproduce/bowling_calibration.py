"""Bowling calibration for `jaxeac reproduce`: where does our AC score the paper's 67 pins, and
what does EAC score there?

The grid was calibrated so that AC matches the paper's AC (step ``calibration``); bowling's
settings never were, and its EAC-vs-AC result depends on them. This step sweeps the actor's
step size β against the angle range θ_max (a heatmap of EAC − AC), then α, the number of
angles K and the execution noise (B3) one at a time at the defaults, all with AC and EAC on
the same seeds and key (R1). The *calibrated point* is the one whose AC mean lies closest to
the paper's 67 (`BOWLING_TOLERANCE` says which count as near). There it reports EAC − AC with
its BCa CI and where the paper's 81 lies among our EAC seeds, runs the ablations
(success memory only, failure memory only, E6's within-trial variant) against AC with Holm's
correction, and the numbers that explain the result: how often a success (all ten pins down)
happens in 10 trials, how often chance 1 strikes, and how often E6's failure condition
r̃(c | t) < r̃(c | t − 1) holds in a failed trial.

Layout of the step's folder: ``points/point_<i>.npz`` per sweep point (per-seed totals,
successes, strikes, failure-rule counts of each algorithm, and the settings they ran with;
written atomically as each point finishes, so a killed run resumes point by point and a point of
other settings runs again), ``ablations/point_<i>.npz`` likewise, and
``heatmap.png``.
"""

from __future__ import annotations

import dataclasses
import io
import itertools
import json
from pathlib import Path

import numpy as np

from jaxeac import paper
from jaxeac.experiments.reproduce.measures import contrast, mean_ci, paper_position, sub_key
from jaxeac.io import atomic_write_bytes, staged_dir

#: A sweep point is "near" the paper's AC when |AC mean − 67| ≤ this many pins (of 100).
BOWLING_TOLERANCE = 3.0
#: Swept together (the heatmap): β (actor step size) × θ_max (rad).
BOWLING_GRID = (("beta", (0.03, 0.1, 0.3, 0.9)), ("theta_max", (0.1, 0.15, 0.2, 0.3)))
#: Swept one at a time at the defaults: α, K angles (EAC's memories hold at most 24), execution-noise
#: scale (× the B3 defaults).
BOWLING_LINES = (("alpha", (0.05, 0.2, 0.5)), ("angles", (11, 23)), ("noise", (0.0, 3.0)))
#: Run against AC at the calibrated point.
BOWLING_ABLATIONS = ("eac_success_only", "eac_failure_only", "eac_within_trial")


def sweep_points(grid=BOWLING_GRID, lines=BOWLING_LINES) -> list[dict]:
    """The sweep's points in order: the grid's product, then each line's values with every other
    setting at its default (a line value equal to the default is left out)."""
    (ka, va), (kb, vb) = grid
    points = [{ka: a, kb: b} for a, b in itertools.product(va, vb)]
    for key, values in lines:
        points += [{key: v} for v in values if v != _default(key)]
    return points


def _default(key: str):
    from jaxeac.experiments.bowling import BowlingSettings

    return 1.0 if key == "noise" else getattr(BowlingSettings(), key)


def point_settings(point: dict, *, seeds: int, key: int, chunk: int, algos: tuple[str, ...]):
    """The `BowlingSettings` of a sweep point (``noise`` scales both B3 noise levels)."""
    from jaxeac.experiments.bowling import BowlingSettings

    base = BowlingSettings()
    fields = {k: v for k, v in point.items() if k != "noise"}
    scale = point.get("noise", 1.0)
    settings = BowlingSettings(seeds=seeds, key=key, chunk_size=min(chunk, seeds), algos=algos,
                               noise_angle=base.noise_angle * scale, noise_speed=base.noise_speed * scale,
                               **fields)
    settings.validate()  # K within what EAC's memories hold, too
    return settings


def failure_rule_counts(knocked: np.ndarray, success: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per seed: (chances where E6's condition r̃(c | t) < r̃(c | t − 1) holds in a failed trial
    t ≥ 2, chances where it was tested). knocked int [N, T, 2] with −1 where no throw was made
    (pins knocked: bowling's r̃, E5); success bool [N, T]."""
    k = np.asarray(knocked, np.int16)
    both = (k[:, 1:] >= 0) & (k[:, :-1] >= 0)  # chance c reached in trial t and in trial t − 1
    tested = both & ~np.asarray(success, bool)[:, 1:, None]
    fires = tested & (k[:, 1:] < k[:, :-1])
    return fires.sum(axis=(1, 2)), tested.sum(axis=(1, 2))


def seed_measures(result) -> dict[str, np.ndarray]:
    """Per-seed arrays of one algorithm's `BowlingResult`: total pins, successes (trials with all
    ten down), chance-1 strikes, E6 condition met / tested."""
    knocked = np.where(result.action >= 0, result.knocked, -1)
    fires, tested = failure_rule_counts(knocked, result.success)
    return {"total": result.total_return.astype(np.int16),
            "successes": result.success.sum(axis=1).astype(np.int16),
            "strikes": (result.knocked[:, :, 0] == 10).sum(axis=1).astype(np.int16),
            "rule_fires": fires.astype(np.int16), "rule_tested": tested.astype(np.int16)}


def _run_measures(path: Path, settings, progress) -> dict[str, dict[str, np.ndarray]]:
    """{algo: seed_measures} of a bowling run, from `path` if an earlier call saved it for the same
    settings, else run and save it (with its settings) atomically."""
    from jaxeac.experiments.bowling import run_bowling
    from jaxeac.experiments.common import plain_json

    said = json.dumps(plain_json(dataclasses.asdict(settings)), sort_keys=True)
    if path.is_file():
        with np.load(path) as z:
            saved = dict(z)
        if str(saved.pop("settings", "")) == said:
            return _unflatten(saved)
    run = run_bowling(settings, progress=progress)
    measures = {a: seed_measures(r) for a, r in run.results.items()}
    buf = io.BytesIO()
    np.savez_compressed(buf, settings=np.array(said),
                        **{f"{a}/{k}": v for a, m in measures.items() for k, v in m.items()})
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, buf.getvalue())
    return measures


def _unflatten(flat: dict[str, np.ndarray]) -> dict[str, dict[str, np.ndarray]]:
    out: dict[str, dict[str, np.ndarray]] = {}
    for name, v in flat.items():
        algo, _, k = name.partition("/")
        out.setdefault(algo, {})[k] = v
    return out


def _explain(m: dict[str, np.ndarray]) -> dict:
    """The numbers that explain a point's result for one algorithm."""
    tested = int(m["rule_tested"].sum())
    return {"total": mean_ci(m["total"]), "successes_per_seed": float(m["successes"].mean()),
            "seeds_with_a_success": float((m["successes"] > 0).mean()),
            "strikes_per_seed": float(m["strikes"].mean()),
            "rule_fires_share": float(m["rule_fires"].sum() / tested) if tested else None,
            "rule_fires_per_seed": float(m["rule_fires"].mean())}


def step_bowling_calibration(folder: Path, sizes, key: int, progress: bool, bar) -> dict:
    """Run the sweep and the ablations at the calibrated point; draw the heatmap; return the record."""
    from jaxeac import plots
    from jaxeac.stats import holm

    grid, lines = sizes.bowling_calibration_grid, sizes.bowling_calibration_lines
    points = sweep_points(grid, lines)
    n = sizes.bowling_calibration_seeds
    rows, seeds = [], {}
    with bar(progress, len(points) * 2 * n, "bowling calibration") as update:
        for i, point in enumerate(points):
            settings = point_settings(point, seeds=n, key=key, chunk=sizes.bowling_chunk, algos=("ac", "eac"))
            m = _run_measures(folder / "points" / f"point_{i}.npz", settings, update)
            seeds[i] = m
            ac, eac = m["ac"]["total"], m["eac"]["total"]
            lo, hi = _diff_ci(ac, eac)
            rows.append({"point": i,
                         **{k: point.get(k) for k in ("beta", "theta_max", "alpha", "angles", "noise")},
                         "ac": float(ac.mean()), "eac": float(eac.mean()),
                         "diff": float(eac.mean() - ac.mean()), "diff_ci95": [lo, hi],
                         "ac_explain": _explain(m["ac"]), "eac_explain": _explain(m["eac"])})
    target_ac, target_eac = paper.BOWLING_PINS["ac"], paper.BOWLING_PINS["eac"]
    best = min(rows, key=lambda r: (abs(r["ac"] - target_ac), r["point"]))
    near = [r for r in rows if abs(r["ac"] - target_ac) <= BOWLING_TOLERANCE]
    m = seeds[best["point"]]
    calibrated = {**best, "contrast": contrast(m["ac"]["total"], m["eac"]["total"],
                                               sub_key(key, "bowling_calibration/eac"),
                                               resamples=sizes.resamples),
                  "eac_paper_position": paper_position(m["eac"]["total"], target_eac),
                  "ac_paper_position": paper_position(m["ac"]["total"], target_ac)}

    settings_at = point_settings(points[best["point"]], seeds=n, key=key, chunk=sizes.bowling_chunk,
                                 algos=tuple(sizes.bowling_ablation_algos))
    ablations = []
    if sizes.bowling_ablation_algos:
        with bar(progress, n * len(sizes.bowling_ablation_algos),
                 "bowling ablations at the calibrated point") as update:
            variants = _run_measures(folder / "ablations" / f"point_{best['point']}.npz", settings_at, update)
        for a in sizes.bowling_ablation_algos:
            c = contrast(m["ac"]["total"], variants[a]["total"], sub_key(key, f"bowling_calibration/{a}"),
                         resamples=sizes.resamples)
            ablations.append({"algo": a, **c, "explain": _explain(variants[a])})
    family = [calibrated["contrast"]["p_welch"], *(v["p_welch"] for v in ablations)]
    adjusted = holm(family)
    calibrated["contrast"]["p_holm"] = float(adjusted[0])
    for v, p in zip(ablations, adjusted[1:], strict=True):
        v["p_holm"] = float(p)

    (ka, va), (kb, vb) = grid
    heat = rows[: len(va) * len(vb)]  # the grid's points come first (`sweep_points`)
    with staged_dir(folder, replaces=("heatmap.png",)) as stage:
        plots.calibration_landscape(heat, stage / "heatmap.png", facet=("alpha", "angles"), axes=(ka, kb),
                                    target=target_ac, tolerance=BOWLING_TOLERANCE, unit="pins")
    return {
        "seeds_per_point": n, "grid": [[k, list(v)] for k, v in grid],
        "lines": [[k, list(v)] for k, v in lines],
        "tolerance": BOWLING_TOLERANCE, "points": rows, "calibrated": calibrated,
        "near": {"count": len(near), "points": [r["point"] for r in near],
                 "diff_range": [min(r["diff"] for r in near), max(r["diff"] for r in near)]
                 if near else None},
        "eac_minus_ac_range": [min(r["diff"] for r in rows), max(r["diff"] for r in rows)],
        "points_eac_better": [r["point"] for r in rows if r["diff_ci95"][0] > 0],
        "points_eac_worse": [r["point"] for r in rows if r["diff_ci95"][1] < 0],
        "ablations": ablations,
        "figures": {"heatmap": "bowling_calibration/heatmap.png"},
    }


def _diff_ci(ac: np.ndarray, eac: np.ndarray) -> tuple[float, float]:
    """Welch 95 % CI of EAC − AC mean pins (`jaxeac.experiments.common.welch_diff_ci95`)."""
    from jaxeac.experiments.common import welch_diff_ci95

    _, lo, hi = welch_diff_ci95(np.asarray(ac, float), np.asarray(eac, float))
    return float(lo), float(hi)


def _where(r: dict) -> str:
    """A sweep point in words: its swept settings, every other one at its default."""
    names = {"beta": "β", "theta_max": "θ_max", "alpha": "α", "angles": "K", "noise": "noise ×"}
    said = [f"{names[k]} {r[k]:g}" if k == "noise" else f"{names[k]} = {r[k]:g}"
            for k in names if r.get(k) is not None]
    return ", ".join(said) + " (the rest at their defaults)"


def _explain_line(label: str, e: dict) -> str:
    from jaxeac.fmt import number

    fires = "–" if e["rule_fires_share"] is None else f"{100 * e['rule_fires_share']:.0f} %"
    return (f"| {label} | {number(e['total']['mean'])} | {e['successes_per_seed']:.2f} | "
            f"{100 * e['seeds_with_a_success']:.0f} % | {e['strikes_per_seed']:.2f} | {fires} | "
            f"{e['rule_fires_per_seed']:.2f} |")


def bowling_calibration_section(bc: dict) -> list[str]:
    """The report's section on the bowling calibration (`step_bowling_calibration`'s record)."""
    from jaxeac.fmt import interval, number, p_value

    ac, eac = paper.BOWLING_PINS["ac"], paper.BOWLING_PINS["eac"]
    c = bc["calibrated"]
    k = c["contrast"]
    grid = " × ".join(f"{name} ∈ {{{', '.join(f'{v:g}' for v in values)}}}" for name, values in bc["grid"])
    lines = "; ".join(f"{name} ∈ {{{', '.join(f'{v:g}' for v in values)}}}" for name, values in bc["lines"])
    near = bc["near"]
    L = [f"## Bowling calibration: where does AC score the paper's {ac}, and what does EAC do there?", "",
         f"The grid was calibrated so that AC matches the paper's AC; this does the same for bowling. "
         f"AC and EAC on the same {bc['seeds_per_point']} seeds at every point of {grid}"
         + (f", then one at a time {lines}" if lines else "")
         + f" (noise × s scales both B3 noise levels). The calibrated point is the one whose AC mean lies "
         f"closest to {ac}; points within ±{bc['tolerance']:g} pins of it count as near.", "",
         f"- **Calibrated point:** {_where(c)}: AC {number(c['ac'])}, EAC {number(c['eac'])}; "
         f"EAC − AC {number(c['diff'], 2, sign=True)} {interval(c['diff_ci95'], 2, sign=True)} "
         f"(Welch 95 % CI, as in the table), g {number(k['hedges_g'], 3)}, A12 {number(k['a12'], 3)}, "
         "p (Welch, Holm over this family) "
         f"{p_value(k['p_holm'])}. The paper's EAC total {eac} lies at percentile "
         f"{c['eac_paper_position']['percentile']:.1f} of our EAC seeds there "
         f"({'inside' if c['eac_paper_position']['within_5_95'] else 'outside'} their 5–95 % range), "
         f"its AC total {ac} at percentile {c['ac_paper_position']['percentile']:.1f} of our AC seeds.",
         f"- Points with AC within ±{bc['tolerance']:g} of {ac}: {near['count']}"
         + (f"; EAC − AC there ranges over {interval(near['diff_range'], 2, sign=True)}."
            if near["count"] else "."),
         f"- Over the sweep EAC − AC ranges over {interval(bc['eac_minus_ac_range'], 2, sign=True)}: EAC is "
         f"reliably better (Welch CI above 0) at {len(bc['points_eac_better'])} of {len(bc['points'])} "
         f"points and reliably worse at {len(bc['points_eac_worse'])}.", "",
         "![bowling calibration heatmap](bowling_calibration/heatmap.png)", "",
         "| point | AC | EAC | EAC − AC [Welch 95 % CI] | "
         "successes per seed (AC / EAC) | E6 condition met (EAC) |",
         "|---|---|---|---|---|---|"]
    for r in bc["points"]:
        e = r["eac_explain"]
        fires = "–" if e["rule_fires_share"] is None else f"{100 * e['rule_fires_share']:.0f} %"
        L.append(f"| {_where(r).removesuffix(' (the rest at their defaults)')} | {number(r['ac'])} | "
                 f"{number(r['eac'])} | {number(r['diff'], 2, sign=True)} "
                 f"{interval(r['diff_ci95'], 2, sign=True)} | "
                 f"{r['ac_explain']['successes_per_seed']:.2f} / {e['successes_per_seed']:.2f} | {fires} |")
    L += ["", "Why, at the calibrated point (per seed over its 10 trials; a success is all ten pins down; "
          "*E6 condition met* is the share of chances of failed trials t ≥ 2, reached in t and t − 1, where "
          "r̃(c | t) < r̃(c | t − 1), the chances EAC flags as failures):", "",
          "| method | mean pins | successes | seeds with a success | chance-1 strikes | E6 condition met "
          "| E6 condition met per seed |", "|---|---|---|---|---|---|---|",
          _explain_line("AC", c["ac_explain"]), _explain_line("EAC", c["eac_explain"])]
    for v in bc["ablations"]:
        L.append(_explain_line(v["algo"], v["explain"]))
    if bc["ablations"]:
        L += ["",
              "Ablations at the calibrated point, each minus AC (same seeds; Holm over EAC and these):", "",
              "| variant | mean pins | − AC [95 % CI] | Hedges' g | p (Holm) |", "|---|---|---|---|---|"]
        for v in bc["ablations"]:
            L.append(f"| {v['algo']} | {number(v['mean_treatment'])} | {number(v['diff'], 2, sign=True)} "
                     f"{interval(v['diff_ci95'], 2, sign=True)} | {number(v['hedges_g'], 3)} | "
                     f"{p_value(v['p_holm'])} |")
    return L + [""]


def bowling_calibration_answer(bc: dict) -> str:
    """The bowling calibration in two sentences, for the report's plain words."""
    from jaxeac.fmt import interval, number

    c, near = bc["calibrated"], bc["near"]
    text = (f"Calibrated as the grid was (AC closest to the paper's {paper.BOWLING_PINS['ac']} pins: "
            f"{_where(c).removesuffix(' (the rest at their defaults)')}, AC {number(c['ac'])}), EAC − AC is "
            f"{number(c['diff'], 2, sign=True)} {interval(c['diff_ci95'], 2, sign=True)} pins")
    if near["count"] > 1:
        text += (f", and over the {near['count']} settings with AC within ±{bc['tolerance']:g} "
                 f"it ranges over {interval(near['diff_range'], 2, sign=True)}")
    return (text + f"; over the whole bowling sweep EAC is reliably better at {len(bc['points_eac_better'])} "
            f"and reliably worse at {len(bc['points_eac_worse'])} of {len(bc['points'])} settings.")
