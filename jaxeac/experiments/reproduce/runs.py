"""The steps of `jaxeac reproduce`: each runs its experiments into a subfolder of ``out``.

(Over 400 lines: every step of the replication in one place, each with its fingerprint and record.)

Layout of ``out`` (each step a subfolder, finished when its ``reproduce.json`` marker
exists with the same fingerprint; a rerun with the same settings skips finished steps)::

    grid/         paper preset, AC and EAC (run folder + stats.json + Fig. 2, Fig. 3)
    bowling/      C backend, AC and EAC (run folder + stats.json + Table I, Fig. 5)
    bowling_table1/  the same in the table1 scene (B1a), whose first throws are like Table I's
    calibration/  `jaxeac sweep` over grid size, chances, α, β (results.csv, landscape.png)
    bowling_calibration/  bowling over β × θ_max, α, K, noise; ablations at the calibrated point
    ablations/    grid variants and temperatures, bowling noise levels (run folders, figures)
    report.md     the verdicts;  reproduce.json  every number report.md quotes

`reproduce` runs the steps, then hands their records to `claims` and `report`.

Longer than the package's ~400-line aim (about 580 lines): the four steps and `reproduce`,
which runs and resumes them, share one convention for run folders and step markers
(`finished_run`, `_marker`, `_fingerprint`); a separate driver module would split it in two.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import sys
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from jaxeac import __version__, paper
from jaxeac.algorithm.agent import ALGORITHMS
from jaxeac.errors import UsageError
from jaxeac.experiments.common import check_key, finished_run, plain_json, versions
from jaxeac.experiments.reproduce.bowling_calibration import (
    BOWLING_ABLATIONS,
    BOWLING_GRID,
    BOWLING_LINES,
    step_bowling_calibration,
)
from jaxeac.experiments.reproduce.claims import judge_claims
from jaxeac.experiments.reproduce.measures import (
    aim_summary,
    angle_measures,
    contrast,
    finite,
    greedy_reach,
    mean_ci,
    one_sample,
    paper_position,
    path_ratios,
    path_summary,
    speedup_summary,
    split_summary,
    sub_key,
)
from jaxeac.experiments.reproduce.report import (
    ablation_answer,
    calibration_answer,
    headline,
    plain_words,
    render_report,
)
from jaxeac.io import (
    atomic_write_json,
    atomic_write_text,
    check_writable_dir,
    read_json_object,
    staged_dir,
)

#: Calibration: a sweep point "matches" the paper's AC when |AC mean − `paper.GRID_SUCCESSES['ac']`| ≤ this.
CALIBRATION_TOLERANCE = 5.0
#: Fig. 5: "after about 5 trials" — the late window starts at this (1-based) trial.
ANGLE_LATE_FROM = paper.ANGLE_SETTLE_TRIALS + 1
#: GRID-4 and GRID-5: windows of this many trials; with T = 200, the trials after the paper's ~180
#: (181–200) are the last window, GRID-4 compares it with 161–180 and 141–160.
LATE_TRIALS = paper.GRID_TRIALS - paper.GRID_AC_SPEEDUP_TRIAL
STEPS = ("grid", "bowling", "bowling_table1", "calibration", "bowling_calibration", "ablations")


@dataclasses.dataclass(frozen=True)
class Sizes:
    """How much to run; `QUICK` and `FULL` are the two modes, tests pass smaller ones."""

    grid_seeds: int
    bowling_seeds: int
    calibration_seeds: int
    calibration_sets: tuple[str, ...]
    ablation_grid_seeds: int
    ablation_bowling_seeds: int
    ablation_algos: tuple[str, ...] = tuple(ALGORITHMS)
    temperatures: tuple[float, ...] = (0.5, 1.0, 2.0)
    noise_scales: tuple[float, ...] = (0.0, 1.0, 3.0)
    resamples: int = 10_000
    band_resamples: int = 5_000
    grid_chunk: int = 2048
    bowling_chunk: int = 500
    bowling_calibration_seeds: int = 200
    bowling_calibration_grid: tuple = BOWLING_GRID
    bowling_calibration_lines: tuple = BOWLING_LINES
    bowling_ablation_algos: tuple[str, ...] = BOWLING_ABLATIONS


CALIBRATION_SETS = ("preset=paper9,paper,paper13", "chances=20,40,60", "alpha=0.05,0.1,0.2",
                    "beta=0.1,0.3,0.9")
FULL = Sizes(grid_seeds=10_000, bowling_seeds=1_000, calibration_seeds=200, calibration_sets=CALIBRATION_SETS,
             ablation_grid_seeds=10_000, ablation_bowling_seeds=200)
QUICK = Sizes(grid_seeds=2_000, bowling_seeds=150, calibration_seeds=64, calibration_sets=CALIBRATION_SETS,
              ablation_grid_seeds=1_000, ablation_bowling_seeds=40, resamples=2_000, band_resamples=1_000,
              bowling_calibration_seeds=24,
              bowling_calibration_grid=(("beta", (0.03, 0.3)), ("theta_max", (0.1, 0.3))),
              bowling_calibration_lines=())


# ------------------------------------------------------------------ folders
@contextlib.contextmanager
def _bar(progress: bool, total: int, desc: str) -> Iterator[Callable[[int], None] | None]:
    from tqdm import tqdm

    with tqdm(total=total, desc=desc, unit="seed", disable=not progress, file=sys.stderr, leave=False) as bar:
        yield bar.update


def _say(progress: bool, text: str) -> None:
    if progress:
        print(text, file=sys.stderr, flush=True)


# ------------------------------------------------------------------ runs
def _grid_run(folder: Path, settings, progress: bool, *, figures: bool, label: str) -> None:
    """Run (unless already on disk with the same config) and write one grid run folder."""
    from jaxeac.experiments.grid import run_grid, write_grid_outputs
    from jaxeac.results import RESULTS_FILE, OutputOptions

    expect = {k: getattr(settings, k) for k in ("preset", "seeds", "key", "algos", "trials", "chances",
                                                "alpha", "beta", "gamma", "temperature")}
    if finished_run(folder, expect) and (folder / RESULTS_FILE).is_file():
        return
    with _bar(progress, settings.seeds * len(settings.algos), label) as update:
        run = run_grid(settings, progress=update)
    write_grid_outputs(run, folder, figures=figures, options=OutputOptions())  # policies: Fig. 2 reach


def _bowling_run(folder: Path, settings, progress: bool, *, figures: bool, label: str) -> None:
    """Run (unless already on disk with the same config) and write one bowling run folder."""
    from jaxeac.experiments.bowling import run_bowling, write_bowling_outputs

    settings.validate()
    if finished_run(folder, dataclasses.asdict(settings)) and (folder / "curves.npz").is_file():
        return
    with _bar(progress, settings.seeds * len(settings.algos), label) as update:
        run = run_bowling(settings, progress=update)
    write_bowling_outputs(run, folder, figures=figures)


def _grid_data(folder: Path, algos, trials: int) -> tuple[dict, dict]:
    """(success [N, T], final policies [N, S]) per algorithm, read back from a run folder."""
    from jaxeac.results import load_grid_results

    loaded = load_grid_results(folder, algos, trials)
    return ({a: r.success for a, r in loaded.items()},
            {a: r.policy for a, r in loaded.items() if r.policy is not None})


def _bowling_data(folder: Path, algos) -> tuple[dict, dict]:
    """(pins per trial [N, T], angles [N, T, 2] with NaN where not thrown) per algorithm."""
    arrays = _npz_arrays(folder / "curves.npz", [f"{a}_return" for a in algos], algos)
    returns = {a: x.astype(np.int64) for a, x in arrays.items()}
    angles = {}
    if (folder / "bowling.npz").is_file():
        angles = _npz_arrays(folder / "bowling.npz", [f"{a}_angle" for a in algos], algos)
    return returns, angles


def _npz_arrays(path: Path, names: list[str], algos) -> dict:
    """{algo: array `name`} from an .npz file; a damaged file or a missing array is one
    `UsageError` naming the file (delete the step's folder to run it again)."""
    import zipfile

    fix = f"delete {path.parent} and run `jaxeac reproduce` again to rebuild it"
    try:
        with np.load(path) as npz:
            missing = [n for n in names if n not in npz.files]
            if missing:
                raise UsageError(f"{path} has no array {missing[0]!r}; {fix}")
            return {a: np.asarray(npz[n]) for a, n in zip(algos, names, strict=True)}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise UsageError(f"{path} is not a readable .npz file ({exc}); {fix}") from None


# ------------------------------------------------------------------ steps
def step_grid(folder: Path, sizes: Sizes, key: int, progress: bool) -> dict:
    """Paper preset, AC vs EAC: run folder, `jaxeac compare`, Fig. 3 with a sup-t band and AC's speed-up
    (GRID-4), Fig. 2 reach and path lengths (GRID-5)."""
    from jaxeac import plots
    from jaxeac.experiments.grid import GridSettings
    from jaxeac.results import load_grid_results
    from jaxeac.stats import compare_run_dir, curve_bands

    settings = GridSettings(preset="paper", seeds=sizes.grid_seeds, key=key,
                            chunk_size=sizes.grid_chunk).resolved()
    _grid_run(folder, settings, progress, figures=True, label="grid: AC and EAC")
    stats = compare_run_dir(folder, resamples=sizes.resamples, key=key, progress=progress)
    loaded = load_grid_results(folder, ("ac", "eac"), settings.trials)
    success = {a: r.success for a, r in loaded.items()}
    policies = {a: r.policy for a, r in loaded.items() if r.policy is not None}
    cum = {a: np.cumsum(s, axis=1, dtype=np.float64) for a, s in success.items()}
    band_key = sub_key(key, "grid/fig3_band")
    bands = curve_bands(cum["ac"], cum["eac"], band_key, resamples=sizes.band_resamples)
    curves = {}
    for algo, side in (("ac", "baseline"), ("eac", "treatment")):
        lo, hi = np.percentile(cum[algo], [5, 95], axis=0)
        curves[algo] = {"mean": bands[f"mean_{side}"], "band": bands[f"band_{side}"], "spread": (lo, hi),
                        "n": cum[algo].shape[0]}
    reach = {a: greedy_reach(settings.grid_map(), policies[a], settings.chances) for a in ("ac", "eac")}
    marks = paper.GRID_SUCCESSES if settings.trials == paper.GRID_TRIALS else None
    paths = path_summary(_path_ratios(folder, settings, loaded), LATE_TRIALS, sub_key(key, "grid/paths"),
                         sizes.resamples)
    with staged_dir(folder) as stage:
        plots.cumulative_band_figure(curves, stage / "fig3_simultaneous.png", paper=marks,
                                     band_label="sup-t 95% band over all trials")
        plots.path_ratio_figure(paths.pop("curves"), stage / "fig2_path_ratio.png", window=paths["window"])
    successes = {a: s.sum(axis=1) for a, s in success.items()}
    T = settings.trials
    windows = {name: sl for name, sl in (("first 10%", slice(0, max(1, T // 10))),
                                         ("middle", slice(T // 10, T - T // 10)),
                                         ("last 10%", slice(T - max(1, T // 10), T)))}
    return {
        "seeds": settings.seeds, "trials": T, "settings": plain_json(dataclasses.asdict(settings)),
        "successes": {a: mean_ci(x) for a, x in successes.items()},
        "paper_position": {a: paper_position(successes[a], paper.GRID_SUCCESSES[a]) for a in ("ac", "eac")},
        "paper_diff": paper.GRID_SUCCESSES["eac"] - paper.GRID_SUCCESSES["ac"],
        "success_rate_windows": {a: {n: float(s[:, sl].mean()) for n, sl in windows.items()}
                                 for a, s in success.items()},
        "fig3_band": {"method": bands["band_method"], "resamples": sizes.band_resamples, "key": band_key,
                      "critical": bands["sup_t_critical"],
                      "final": {a: {"mean": float(c["mean"][-1]), "band": [float(c["band"][0][-1]),
                                                                            float(c["band"][1][-1])]}
                                for a, c in curves.items()}},
        "greedy_reach": {
            "description": "share of start cells whose greedy path (final policy) reaches the goal "
                           f"within {settings.chances} moves",
            "ac": mean_ci(reach["ac"]), "eac": mean_ci(reach["eac"]),
            "contrast": contrast(reach["ac"], reach["eac"], sub_key(key, "grid/reach"),
                                 resamples=sizes.resamples),
        },
        "speedup": speedup_summary(success, LATE_TRIALS),
        "paths": paths,
        "stats_primary_diff": stats["primary"]["diff"],
        "figures": {"fig2": "grid/fig2_policies.png", "fig3": "grid/fig3_simultaneous.png",
                    "fig3_pointwise": "grid/fig3_cumulative_successes.png",
                    "compare_curves": "grid/compare_curves.png", "paths": "grid/fig2_path_ratio.png"},
    }


def _path_ratios(folder: Path, settings, loaded: dict) -> dict:
    """GRID-5's per-trial path ratios [N, T] per method (`path_ratios`), with each trial's start cell
    recomputed from the seed's stream (`start_states`, G3, R1) and the map's shortest paths."""
    from jaxeac.envs.grid import shortest_steps
    from jaxeac.running.batch import start_states

    env, shortest = settings.make_env(), shortest_steps(settings.grid_map())
    out = {}
    for a, r in loaded.items():
        if r.trial_steps is None:
            raise UsageError(f"{folder} holds no per-trial steps; delete it and run `jaxeac reproduce` again")
        starts = start_states(env, settings.key, r.seeds, settings.trials)
        out[a] = path_ratios(r.success, r.trial_steps, starts, shortest)
    return out


def step_bowling(folder: Path, sizes: Sizes, key: int, progress: bool, scene: str = "default") -> dict:
    """Bowling, AC vs EAC on the C backend in `scene` (B1, B1a): run folder, `jaxeac compare`, Table I,
    Fig. 5 angle analysis, the chances' split of pins and where chance 2 aims."""
    from jaxeac.experiments.bowling import BowlingSettings
    from jaxeac.stats import compare_run_dir

    settings = BowlingSettings(seeds=sizes.bowling_seeds, key=key, chunk_size=sizes.bowling_chunk,
                               backend="c", scene=scene)
    _bowling_run(folder, settings, progress, figures=True, label=f"bowling: AC and EAC ({scene} scene)")
    stats = compare_run_dir(folder, resamples=sizes.resamples, key=key, progress=progress)
    returns, angles = _bowling_data(folder, ("ac", "eac"))
    totals = {a: r.sum(axis=1) for a, r in returns.items()}
    late_from = min(ANGLE_LATE_FROM, settings.trials)
    m = {a: angle_measures(angles[a], late_from) for a in ("ac", "eac")}
    ang = {}
    for a in ("ac", "eac"):
        ang[a] = {"theta1": one_sample(m[a]["theta1"], negative=True),
                  "theta2": one_sample(m[a]["theta2"], negative=False),
                  "sd_theta1": mean_ci(m[a]["sd_theta1"])}

    def both(name):
        return finite(m["ac"][name]), finite(m["eac"][name])

    ang["contrast_theta1"] = contrast(*both("theta1"), sub_key(key, "bowling/theta1"),
                                      resamples=sizes.resamples, higher_is_better=False)
    ang["contrast_theta2"] = contrast(*both("theta2"), sub_key(key, "bowling/theta2"),
                                      resamples=sizes.resamples)
    knocked = _npz_arrays(folder / "bowling.npz", ["ac_knocked", "eac_knocked"], ("ac", "eac"))
    ang["contrast_sd_theta1"] = contrast(*both("sd_theta1"), sub_key(key, "bowling/sd_theta1"),
                                         resamples=sizes.resamples, higher_is_better=False)
    standing = _npz_arrays(folder / "bowling.npz", ["ac_standing", "eac_standing"], ("ac", "eac"))
    with np.load(folder / "bowling.npz") as z:
        pin_xy = z["pin_xy"]
    name = folder.name
    return {
        "scene": scene,
        "aim": aim_summary(standing, angles, pin_xy, late_from, sub_key(key, "bowling/aim"), sizes.resamples),
        "seeds": settings.seeds, "trials": settings.trials,
        "settings": plain_json(dataclasses.asdict(settings)),
        "returns": {a: mean_ci(x) for a, x in totals.items()},
        "paper_position": {a: paper_position(totals[a], paper.BOWLING_PINS[a]) for a in ("ac", "eac")},
        "paper_diff": paper.BOWLING_PINS["eac"] - paper.BOWLING_PINS["ac"],
        "angles": ang, "angle_window": [late_from, settings.trials],
        "chance_split": split_summary(knocked, sub_key(key, "bowling/split"), sizes.resamples),
        "stats_primary_diff": stats["primary"]["diff"],
        "figures": {"fig5": f"{name}/fig5_angles.png", "compare_curves": f"{name}/compare_curves.png"},
        "table1": f"{name}/table1.md",
    }


def step_calibration(folder: Path, sizes: Sizes, key: int, progress: bool) -> dict:
    """`jaxeac sweep` over size, chances, α, β; where AC's mean is the paper's 56, what does EAC do?"""
    from jaxeac import plots
    from jaxeac.experiments.grid import GridSettings
    from jaxeac.experiments.sweep import Sweep, load_point, run_sweep

    base = GridSettings(preset="paper", seeds=sizes.calibration_seeds, key=key,
                        chunk_size=sizes.calibration_seeds)
    sweep = Sweep.build(base, list(sizes.calibration_sets))
    with _bar(progress, len(sweep.points()) * base.seeds * len(base.algos), "calibration sweep") as update:
        rows = run_sweep(sweep, folder, progress=update)
    points = []
    for i, point in enumerate(sweep.points()):
        by = {r["algo"]: r for r in rows if r["point"] == i}
        ac, eac = by["ac"], by["eac"]
        points.append({"point": i, **point, "n": int(ac["n"]), "ac": ac["mean_successes"],
                       "ac_ci95": [ac["ci95_lo"], ac["ci95_hi"]], "eac": eac["mean_successes"],
                       "eac_ci95": [eac["ci95_lo"], eac["ci95_hi"]], "diff": eac["eac_minus_ac"],
                       "diff_ci95": [eac["diff_ci95_lo"], eac["diff_ci95_hi"]]})
    target_ac, target_eac = paper.GRID_SUCCESSES["ac"], paper.GRID_SUCCESSES["eac"]
    closest = min(points, key=lambda p: (abs(p["ac"] - target_ac), p["point"]))
    joint = min(points, key=lambda p: (abs(p["ac"] - target_ac) + abs(p["eac"] - target_eac), p["point"]))
    near = [p for p in points if abs(p["ac"] - target_ac) <= CALIBRATION_TOLERANCE]

    def detail(p):
        ac = load_point(folder, p["point"], "ac", 1)[0].sum(axis=1)
        eac = load_point(folder, p["point"], "eac", 1)[0].sum(axis=1)
        return {**p, "eac_paper_position": paper_position(eac, target_eac),
                "ac_paper_position": paper_position(ac, target_ac),
                "contrast": contrast(ac, eac, sub_key(key, f"calibration/{p['point']}"),
                                     resamples=sizes.resamples)}

    with staged_dir(folder) as stage:  # keys not swept take one value (None): a single panel or cell
        plots.calibration_landscape(points, stage / "landscape.png", facet=("preset", "chances"),
                                    axes=("alpha", "beta"), target=target_ac, tolerance=CALIBRATION_TOLERANCE)
    return {
        "seeds_per_point": base.seeds, "sets": list(sizes.calibration_sets), "n_points": len(points),
        "tolerance": CALIBRATION_TOLERANCE, "points": points,
        "closest": detail(closest), "joint": detail(joint),
        "near": {"count": len(near), "points": [p["point"] for p in near],
                 "eac_range": [min(p["eac"] for p in near), max(p["eac"] for p in near)] if near else None,
                 "diff_range": [min(p["diff"] for p in near), max(p["diff"] for p in near)] if near else None,
                 "eac_ci_contains_163": [p["point"] for p in near
                                         if p["eac_ci95"][0] <= target_eac <= p["eac_ci95"][1]]},
        "eac_minus_ac_range": [min(p["diff"] for p in points), max(p["diff"] for p in points)],
        "points_eac_not_better": [p["point"] for p in points if not p["diff_ci95"][0] > 0],
        "figures": {"landscape": "calibration/landscape.png", "heatmap": "calibration/heatmap.png"},
    }


def step_ablations(folder: Path, sizes: Sizes, key: int, progress: bool, bowling_dir: Path) -> dict:
    """Which part of EAC does the work: memory variants, E2/E6 variants, temperature, bowling noise."""
    from jaxeac import plots
    from jaxeac.experiments.bowling import BowlingSettings
    from jaxeac.experiments.grid import GridSettings
    from jaxeac.stats import holm

    algos = tuple(dict.fromkeys(("ac", *sizes.ablation_algos)))
    base = GridSettings(preset="paper", seeds=sizes.ablation_grid_seeds, key=key, algos=algos,
                        chunk_size=sizes.grid_chunk).resolved()
    _grid_run(folder / "grid_algos", base, progress, figures=False, label="ablations: grid variants")
    success, _ = _grid_data(folder / "grid_algos", algos, base.trials)
    totals = {a: s.sum(axis=1) for a, s in success.items()}
    variants = []
    eac_diff = None
    for a in algos[1:]:
        c = contrast(totals["ac"], totals[a], sub_key(key, f"ablations/{a}"), resamples=sizes.resamples)
        variants.append({"algo": a, "mean": mean_ci(totals[a]), **c})
        if a == "eac":
            eac_diff = c["diff"]
    for v, p in zip(variants, holm([v["p_welch"] for v in variants]) if variants else [], strict=True):
        v["p_holm"] = float(p)
        v["share_of_eac_effect"] = v["diff"] / eac_diff if eac_diff else None

    temps = []
    for tau in sizes.temperatures:
        if tau == base.temperature and {"ac", "eac"} <= set(algos):
            sub = folder / "grid_algos"
        else:
            sub = folder / f"grid_tau{tau:g}"
            s = dataclasses.replace(base, algos=("ac", "eac"), temperature=float(tau)).resolved()
            _grid_run(sub, s, progress, figures=False, label=f"ablations: temperature {tau:g}")
        succ, _ = _grid_data(sub, ("ac", "eac"), base.trials)
        x = {a: v.sum(axis=1) for a, v in succ.items()}
        temps.append({"temperature": float(tau), "folder": sub.name, "ac": mean_ci(x["ac"]),
                      "eac": mean_ci(x["eac"]),
                      **contrast(x["ac"], x["eac"], sub_key(key, f"ablations/tau{tau:g}"),
                                 resamples=sizes.resamples)})

    noise = []
    default = BowlingSettings()
    for scale in sizes.noise_scales:
        if scale == 1.0 and (bowling_dir / "curves.npz").is_file():
            sub = bowling_dir
        else:
            sub = folder / f"bowling_noise{scale:g}"
            s = BowlingSettings(seeds=sizes.ablation_bowling_seeds, key=key, chunk_size=sizes.bowling_chunk,
                                noise_angle=default.noise_angle * scale,
                                noise_speed=default.noise_speed * scale)
            _bowling_run(sub, s, progress, figures=False, label=f"ablations: bowling noise x{scale:g}")
        ret, _ = _bowling_data(sub, ("ac", "eac"))
        x = {a: v.sum(axis=1) for a, v in ret.items()}
        noise.append({"scale": float(scale), "folder": str(sub.relative_to(folder.parent)),
                      "noise_angle": default.noise_angle * scale, "noise_speed": default.noise_speed * scale,
                      "ac": mean_ci(x["ac"]), "eac": mean_ci(x["eac"]),
                      **contrast(x["ac"], x["eac"], sub_key(key, f"ablations/noise{scale:g}"),
                                 resamples=sizes.resamples)})
    with staged_dir(folder) as stage:
        if variants:
            rows = [{"label": v["algo"], "algo": v["algo"], "diff": v["diff"], "ci": v["diff_ci95"]}
                    for v in variants]
            plots.forest_figure(rows, stage / "grid_variants.png",
                                xlabel="mean successes minus AC's (95% BCa CI)",
                                title=f"Grid, paper preset: each variant minus AC ({base.seeds} seeds each)")
        rows = [{"label": f"grid, tau={t['temperature']:g}", "diff": t["diff"], "ci": t["diff_ci95"]}
                for t in temps]
        plots.forest_figure(rows, stage / "grid_temperature.png", xlabel="EAC - AC successes (95% BCa CI)",
                            title="Grid: EAC - AC at each softmax temperature")
        rows = [{"label": f"bowling, noise x{n['scale']:g}", "diff": n["diff"], "ci": n["diff_ci95"]}
                for n in noise]
        if rows:
            plots.forest_figure(rows, stage / "bowling_noise.png", xlabel="EAC - AC pins (95% BCa CI)",
                                title="Bowling: EAC - AC at each execution-noise level")
    return {
        "grid_seeds": base.seeds, "bowling_seeds": sizes.ablation_bowling_seeds,
        "variants": variants, "temperatures": temps, "noise": noise,
        "figures": {"variants": "ablations/grid_variants.png",
                    "temperature": "ablations/grid_temperature.png", "noise": "ablations/bowling_noise.png"},
    }


# ------------------------------------------------------------------ driver
#: The version of each step's record (what its function returns). A step finished under an older
#: version (before GRID-4, GRID-5 and BOWL-4: none) runs again on resume, reusing its run folders.
RECORDS = {"grid": 2, "bowling": 3, "bowling_table1": 1, "calibration": 1, "bowling_calibration": 1,
           "ablations": 1}


def _fingerprint(step: str, sizes: Sizes, key: int) -> dict:
    relevant = {
        "grid": ("grid_seeds", "resamples", "band_resamples"),
        "bowling": ("bowling_seeds", "resamples"),
        "bowling_table1": ("bowling_seeds", "resamples"),
        "calibration": ("calibration_seeds", "calibration_sets", "resamples"),
        "bowling_calibration": ("bowling_calibration_seeds", "bowling_calibration_grid",
                                "bowling_calibration_lines", "bowling_ablation_algos", "resamples"),
        "ablations": ("ablation_grid_seeds", "ablation_bowling_seeds", "ablation_algos", "temperatures",
                      "noise_scales", "resamples", "bowling_seeds"),
    }[step]
    return plain_json({"step": step, "record": RECORDS[step], "key": key, "jaxeac": __version__,
                       **{k: getattr(sizes, k) for k in relevant}})


def _settings(fingerprint) -> dict | None:
    """What a step ran with: its fingerprint less the record version (None if not a fingerprint)."""
    return {k: v for k, v in fingerprint.items() if k != "record"} if isinstance(fingerprint, dict) else None


def _marker(folder: Path) -> dict | None:
    """A finished step's record (fingerprint, seconds, result), or None: no record, or a damaged
    one (the step then runs again and replaces its folder as a whole)."""
    path = folder / "reproduce.json"
    if not path.is_file():
        return None
    try:
        m = read_json_object(path)
    except UsageError:
        return None
    ok = isinstance(m.get("result"), dict) and isinstance(m.get("seconds"), int | float)
    return m if ok and "fingerprint" in m else None


def reproduce(out, *, quick: bool = False, key: int = 0, progress: bool = True,
              sizes: Sizes | None = None) -> Path:
    """Run every step into subfolders of `out` (skipping finished ones) and write `out/report.md`.

    `sizes` overrides the `QUICK` / `FULL` sizes (for tests). Returns the report's path.
    A step is finished when its ``reproduce.json`` exists with the same fingerprint; one of the same
    settings but an older record (`RECORDS`) runs again; a folder holding a step of other settings is
    refused (`UsageError`) before any compute.
    """
    check_key(key)
    mode = "custom" if sizes is not None else "quick" if quick else "full"
    sizes = sizes or (QUICK if quick else FULL)
    out = check_writable_dir(out)
    for step in STEPS:
        m = _marker(out / step)
        if m is not None and _settings(m.get("fingerprint")) != _settings(_fingerprint(step, sizes, key)):
            raise UsageError(f"{out / step} holds a reproduce step run with other settings "
                             f"({m.get('fingerprint')}); choose another --out or remove that folder")
    t_start = time.perf_counter()
    records, timings = {}, {}
    runners = {
        "grid": lambda f: step_grid(f, sizes, key, progress),
        "bowling": lambda f: step_bowling(f, sizes, key, progress),
        "bowling_table1": lambda f: step_bowling(f, sizes, key, progress, scene="table1"),
        "calibration": lambda f: step_calibration(f, sizes, key, progress),
        "bowling_calibration": lambda f: step_bowling_calibration(f, sizes, key, progress, _bar),
        "ablations": lambda f: step_ablations(f, sizes, key, progress, out / "bowling"),
    }
    for i, step in enumerate(STEPS):
        folder = out / step
        m = _marker(folder)
        if m is not None and m.get("fingerprint") == _fingerprint(step, sizes, key):
            _say(progress, f"[{i + 1}/{len(STEPS)}] {step}: finished earlier, reusing {folder}")
            records[step] = m["result"]
            timings[step] = {"seconds": m["seconds"], "resumed": True}
            continue
        _say(progress, f"[{i + 1}/{len(STEPS)}] {step} ...")
        t0 = time.perf_counter()
        check_writable_dir(folder)
        result = runners[step](folder)
        seconds = time.perf_counter() - t0
        atomic_write_json(folder / "reproduce.json", {"fingerprint": _fingerprint(step, sizes, key),
                                                      "seconds": seconds, "result": result})
        records[step] = json.loads((folder / "reproduce.json").read_text())["result"]
        timings[step] = {"seconds": seconds, "resumed": False}
        _say(progress, f"[{i + 1}/{len(STEPS)}] {step}: done in {seconds:.0f} s")

    gstats, bstats, tstats = (read_json_object(out / step / "stats.json", f"delete {out / step} and run "
                                               "`jaxeac reproduce` again to rebuild it")
                              for step in ("grid", "bowling", "bowling_table1"))
    cls = judge_claims(records["grid"], gstats, records["bowling"], bstats)
    for c in cls:
        c["headline"] = headline(c)
    # the bowling claims again on the table1 scene (B1a), judged by the same rules
    cls_table1 = [c for c in judge_claims(records["grid"], gstats, records["bowling_table1"], tstats)
                  if c["experiment"] == "bowling"]
    for c in cls_table1:
        c["headline"] = headline(c)
    command = (f"jaxeac reproduce{' --quick' if quick else ''} --out {out} --key {key}" if mode != "custom"
               else f"jaxeac.experiments.reproduce.reproduce({str(out)!r}, key={key}, "
               "sizes=<see reproduce.json>)")
    import jax

    rec = {
        "schema": "jaxeac.experiments.reproduce/1", "mode": mode, "key": int(key), "command": command,
        "argv": " ".join(["jaxeac", *sys.argv[1:]]), "sizes": plain_json(dataclasses.asdict(sizes)),
        "resamples": sizes.resamples,
        "finished": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "total_seconds": time.perf_counter() - t_start, "timings": timings,
        "versions": versions(), "devices": [str(d) for d in jax.devices()],
        "paper": {"grid": paper.GRID_SUCCESSES, "bowling": paper.BOWLING_PINS},
        "claims": cls, "claims_table1": cls_table1,
        "plain": plain_words(cls, records["grid"], records["bowling"]),
        "calibration_answer": calibration_answer(records["calibration"]),
        "ablation_answer": ablation_answer(records["ablations"]),
        **{step: records[step] for step in STEPS},
    }
    rec = plain_json(rec)
    text = render_report(rec, out)
    atomic_write_json(out / "reproduce.json", rec)
    atomic_write_text(out / "report.md", text)
    return out / "report.md"

