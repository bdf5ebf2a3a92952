"""Benchmark `jaxeac compare` on synthetic data (SPEC §6; BENCHMARKS.md).

Builds a grid run folder with N seeds × T trials × 2 methods (results.parquet as
`jaxeac grid` writes it, or the older per_seed.csv + curves.npz with --format npz),
then runs the full comparison (statistics, calibration, report and figures) with R
resamples, compile included, and prints a JSON record with the seconds of each
piece (`stats["timing"]["pieces"]`), the machine and the versions. Usage::

    python scripts/bench_stats.py                 # 10,000 seeds, 200 trials, 10,000 resamples
    python scripts/bench_stats.py --seeds 10000 100000 1000000 --repeat 2 --out bench.json

With several --seeds the record holds one entry per size under "sizes"; its top-level
timing keys repeat the largest size (what `scripts/bench.py --render` shows).
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


def synthetic_success(seeds: int, trials: int, seed: int = 0, block: int = 65_536) -> dict:
    """Success curves {algo: bool [seeds, trials]} where EAC learns a little faster than AC.

    Bernoulli trials with a per-seed ability and a rate rising over the trials; drawn
    `block` seeds at a time (the same numbers as one draw, in less memory).
    """
    import numpy as np

    rng = np.random.default_rng(seed)
    t = np.arange(1, trials + 1)
    curves = {}
    for algo, shift in (("ac", 0.0), ("eac", 0.15)):
        ability = rng.normal(0.0, 0.6, (seeds, 1))
        s = np.empty((seeds, trials), bool)
        for i in range(0, seeds, block):
            logit = -1.2 + 2.4 * t / trials + shift + ability[i : i + block]
            s[i : i + block] = rng.random((logit.shape[0], trials)) < 1 / (1 + np.exp(-logit))
        curves[algo] = s
    return curves


def write_synthetic_run(path: Path, seeds: int, trials: int, seed: int = 0, fmt: str = "npz") -> None:
    """A grid run directory from `synthetic_success`: summary.json and either results.parquet
    (fmt="parquet", as `jaxeac grid` writes it) or per_seed.csv and curves.npz (fmt="npz")."""
    import numpy as np

    curves = synthetic_success(seeds, trials, seed)
    summary = {"experiment": "grid", "primary_measure": "successes", "algos": ["ac", "eac"], "trials": trials}
    if fmt == "parquet":
        from types import SimpleNamespace

        from jaxeac.results import OutputOptions, write_grid_results

        results = {
            algo: SimpleNamespace(
                seeds=np.arange(seeds),
                success=s,
                steps=np.broadcast_to(np.int16(40), s.shape),
                policy=np.broadcast_to(np.int8(0), (seeds, 1)),
            )
            for algo, s in curves.items()
        }
        options = OutputOptions(trial_steps=False, policies=False, per_seed_csv=False)
        write_grid_results(path / "results.parquet", results, trials, 1, options)
        (path / "summary.json").write_text(json.dumps(summary))
        return
    lines = ["algo,seed,successes,steps,first_success"]
    for algo, s in curves.items():
        first = np.where(s.any(1), s.argmax(1) + 1, -1)
        succ = s.sum(1)
        lines += [f"{algo},{i},{succ[i]},{40 * trials},{first[i]}" for i in range(seeds)]
    np.savez(path / "curves.npz", **curves)
    (path / "per_seed.csv").write_text("\n".join(lines) + "\n")
    (path / "summary.json").write_text(json.dumps(summary))


def _machine() -> dict:
    import jax

    cpu = ""
    try:
        cpu = next(
            line.split(":", 1)[1].strip()
            for line in Path("/proc/cpuinfo").read_text().splitlines()
            if line.startswith("model name")
        )
    except (OSError, StopIteration):
        cpu = platform.processor()
    dev = jax.devices()[0]
    return {
        "platform": platform.platform(),
        "cpu": cpu,
        "cpus": os.cpu_count(),
        "backend": jax.default_backend(),
        "device": getattr(dev, "device_kind", str(dev)),
        "devices": jax.device_count(),
        "loadavg_before": os.getloadavg(),
    }


def bench_size(args, seeds: int, compare_run_dir) -> dict:
    """Time `compare_run_dir` on a fresh synthetic folder of `seeds` seeds per method."""
    rec: dict = {
        "seeds_per_method": seeds,
        "trials": args.trials,
        "resamples": args.resamples,
        "format": args.format,
        "runs": [],
    }
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp)
        t0 = time.perf_counter()
        write_synthetic_run(run, seeds, args.trials, fmt=args.format)
        rec["make_data_seconds"] = time.perf_counter() - t0
        for i in range(args.repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            stats = compare_run_dir(run, resamples=args.resamples, key=i, progress=False)
            rec["runs"].append(
                {
                    "wall_seconds": time.perf_counter() - t0,
                    "cpu_seconds": time.process_time() - c0,
                    "includes_compile": i == 0,
                    "timing": stats["timing"],
                }
            )
        rec["statistics_path"] = stats["settings"]["scale"]["path"]
        rec["primary"] = {k: stats["primary"][k] for k in ("diff", "diff_ci95", "p_welch", "p_permutation")}
        if args.rliable:
            import numpy as np

            try:
                from rliable import library as rly
                from rliable import metrics

                curves = np.load(run / "curves.npz")
                scores = {a: curves[a].sum(1, keepdims=True).astype(float) for a in ("ac", "eac")}
                t0 = time.perf_counter()
                rly.get_interval_estimates(
                    {"ac": scores["ac"]}, lambda x: np.array([metrics.aggregate_iqm(x)]), reps=args.resamples
                )
                rec["rliable_iqm_ci_seconds"] = time.perf_counter() - t0
            except (ImportError, FileNotFoundError) as exc:
                rec["rliable_iqm_ci_seconds"] = f"not available ({exc})"
    runs = rec["runs"]
    rec["first_run_seconds"] = runs[0]["wall_seconds"]  # compile included
    rec["first_run_plus_import_seconds"] = runs[0]["wall_seconds"] + args.import_seconds
    best = runs[0]
    if len(runs) > 1:
        best = min(runs[1:], key=lambda r: r["wall_seconds"])
        rec["warm_run_seconds"] = best["wall_seconds"]
        rec["compile_and_warmup_seconds"] = runs[0]["wall_seconds"] - best["wall_seconds"]
    t = best["timing"]
    rec["pieces_seconds"] = {
        "load": t.get("load_seconds"),
        **t.get("pieces", {}),
        "figures_and_report": t["total_seconds"] - t.get("load_seconds", 0) - t["statistics_seconds"],
        "total": t["total_seconds"],
    }
    return rec


def bench_tidy(args) -> None:
    """`jaxeac compare --table` on a tidy CSV of A algorithms × N seeds (per-seed values with
    different means), compile included, in this process; prints and writes a JSON record."""
    import numpy as np

    t_start = time.perf_counter()
    import jax

    from jaxeac.stats.engine import compare

    import_seconds = time.perf_counter() - t_start
    seeds = args.seeds[0]
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        table = Path(tmp) / "runs.csv"
        tasks = max(1, args.tidy_tasks)
        lines = ["task,algo,seed,value"]
        for t in range(tasks):
            for a in range(args.tidy_algos):
                values = rng.normal(100 + 2 * a, 15, seeds) * (1 + t)
                lines += [f"t{t},algo{a},{i},{v:.6f}" for i, v in enumerate(values)]
        table.write_text("\n".join(lines) + "\n")
        runs = []
        load_before = os.getloadavg()
        for i in range(args.repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            result = compare(table, resamples=args.resamples, key=i, baseline="algo0" if tasks > 1 else None,
                             normalize="baseline" if tasks > 1 else None)
            runs.append({"wall_seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
                         "includes_compile": i == 0})
    record = {
        "command": "python scripts/bench_stats.py " + " ".join(sys.argv[1:]),
        "algorithms": args.tidy_algos, "seeds_per_algorithm": seeds, "resamples": args.resamples,
        "tasks": tasks, "comparisons": result.family_size, "aggregates": result.aggregate is not None,
        "import_seconds": import_seconds, "runs": runs,
        "first_run_plus_import_seconds": runs[0]["wall_seconds"] + import_seconds,
        "versions": {"python": sys.version.split()[0], "jax": jax.__version__, "numpy": np.__version__},
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "backend": jax.default_backend(), "loadavg_before": load_before,
                    "loadavg_after": os.getloadavg()},
    }
    text = json.dumps(record, indent=2)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")


def main() -> None:
    from jaxeac.runtime import configure

    configure("compare", start_jax=False)  # as the `jaxeac` command: one BLAS thread, before NumPy loads
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[10_000], help="seeds per method (one or more)")
    ap.add_argument("--trials", type=int, default=200)
    ap.add_argument("--resamples", type=int, default=10_000)
    ap.add_argument("--repeat", type=int, default=2, help="runs in one process; the first includes compile")
    ap.add_argument(
        "--format",
        choices=("parquet", "npz"),
        default="parquet",
        help="run folder files: results.parquet (as jaxeac grid writes) or per_seed.csv + curves.npz",
    )
    ap.add_argument("--rliable", action="store_true", help="also time rliable's IQM interval if installed")
    ap.add_argument("--out", type=Path, help="also write the JSON record here")
    ap.add_argument("--tidy-tasks", type=int, default=0, metavar="K",
                    help="with --tidy-algos: K tasks, each vs algo0, with the aggregates and profiles across them")
    ap.add_argument("--tidy-algos", type=int, default=0, metavar="A",
                    help="instead: time `jaxeac compare --table` on a synthetic tidy table of A algorithms "
                         "× --seeds seeds (all pairs, Holm, IQM and probability of improvement)")
    args = ap.parse_args()
    if args.tidy_algos:
        return bench_tidy(args)

    t_start = time.perf_counter()
    import jax
    import numpy as np
    import scipy

    import jaxeac
    from jaxeac.stats import compare_run_dir

    args.import_seconds = time.perf_counter() - t_start
    shared = {
        "command": "python scripts/bench_stats.py " + " ".join(sys.argv[1:]),
        "import_seconds": args.import_seconds,
        "versions": {
            "python": sys.version.split()[0],
            "jaxeac": getattr(jaxeac, "__version__", "?"),
            "jax": jax.__version__,
            "jaxlib": jax.lib.__version__,
            "numpy": np.__version__,
            "scipy": scipy.__version__,
        },
        "machine": _machine(),
    }
    sizes = [bench_size(args, n, compare_run_dir) for n in args.seeds]
    shared["machine"]["loadavg_after"] = os.getloadavg()
    record = {**sizes[-1], **shared}
    if len(sizes) > 1:
        record["sizes"] = sizes
    text = json.dumps(record, indent=2, default=float)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
