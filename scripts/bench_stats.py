"""Benchmark `jaxeac compare` on synthetic data (SPEC §6; BENCHMARKS.md).

Builds a grid-style run directory with N seeds × T trials × 2 methods, then runs
the full comparison (statistics, calibration, report and figures) with R
resamples, compile included, and prints a JSON record. Usage::

    python scripts/bench_stats.py                 # 10,000 seeds, 200 trials, 10,000 resamples
    python scripts/bench_stats.py --seeds 1000 --out bench.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path


def write_synthetic_run(path: Path, seeds: int, trials: int, seed: int = 0) -> None:
    """A grid run directory where EAC learns a little faster than AC."""
    import numpy as np

    rng = np.random.default_rng(seed)
    t = np.arange(1, trials + 1)
    curves, rows = {}, ["algo,seed,successes,steps,first_success"]
    for algo, shift in (("ac", 0.0), ("eac", 0.15)):
        ability = rng.normal(0.0, 0.6, (seeds, 1))
        logit = -1.2 + 2.4 * t / trials + shift + ability
        s = rng.random((seeds, trials)) < 1 / (1 + np.exp(-logit))
        curves[algo] = s
        first = np.where(s.any(1), s.argmax(1) + 1, -1)
        succ = s.sum(1)
        rows += [f"{algo},{i},{succ[i]},{40 * trials},{first[i]}" for i in range(seeds)]
    np.savez(path / "curves.npz", **curves)
    (path / "per_seed.csv").write_text("\n".join(rows) + "\n")
    (path / "summary.json").write_text(
        json.dumps(
            {"experiment": "grid", "primary_measure": "successes", "algos": ["ac", "eac"], "trials": trials}
        )
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10_000)
    ap.add_argument("--trials", type=int, default=200)
    ap.add_argument("--resamples", type=int, default=10_000)
    ap.add_argument("--repeat", type=int, default=2, help="runs in one process; the first includes compile")
    ap.add_argument("--rliable", action="store_true", help="also time rliable's IQM interval if installed")
    ap.add_argument("--out", type=Path, help="also write the JSON record here")
    args = ap.parse_args()

    t_start = time.perf_counter()
    import jax
    import numpy as np
    import scipy

    from jaxeac.stats import compare_run_dir

    t_import = time.perf_counter() - t_start
    record = {
        "seeds_per_method": args.seeds,
        "trials": args.trials,
        "resamples": args.resamples,
        "import_seconds": t_import,
        "runs": [],
        "versions": {
            "python": sys.version.split()[0],
            "jax": jax.__version__,
            "jaxlib": jax.lib.__version__,
            "numpy": np.__version__,
            "scipy": scipy.__version__,
        },
        "machine": {
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "loadavg_before": os.getloadavg(),
        },
    }
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp)
        t0 = time.perf_counter()
        write_synthetic_run(run, args.seeds, args.trials)
        record["make_data_seconds"] = time.perf_counter() - t0
        for i in range(args.repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            stats = compare_run_dir(run, resamples=args.resamples, key=i, progress=False)
            record["runs"].append(
                {
                    "wall_seconds": time.perf_counter() - t0,
                    "cpu_seconds": time.process_time() - c0,
                    "includes_compile": i == 0,
                    "timing": stats["timing"],
                }
            )
        record["primary"] = {
            k: stats["primary"][k] for k in ("diff", "diff_ci95", "p_welch", "p_permutation")
        }
        if args.rliable:
            try:
                from rliable import library as rly
                from rliable import metrics

                curves = np.load(run / "curves.npz")
                scores = {a: curves[a].sum(1, keepdims=True).astype(float) for a in ("ac", "eac")}
                t0 = time.perf_counter()
                rly.get_interval_estimates(
                    {"ac": scores["ac"]}, lambda x: np.array([metrics.aggregate_iqm(x)]), reps=args.resamples
                )
                record["rliable_iqm_ci_seconds"] = time.perf_counter() - t0
            except ImportError as exc:
                record["rliable_iqm_ci_seconds"] = f"not installed ({exc})"
    runs = record["runs"]
    record["first_run_seconds"] = runs[0]["wall_seconds"]  # compile included
    record["first_run_plus_import_seconds"] = runs[0]["wall_seconds"] + t_import
    if len(runs) > 1:
        warm = min(r["wall_seconds"] for r in runs[1:])
        record["warm_run_seconds"] = warm
        record["compile_and_warmup_seconds"] = runs[0]["wall_seconds"] - warm
    record["machine"]["loadavg_after"] = os.getloadavg()
    text = json.dumps(record, indent=2, default=float)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
