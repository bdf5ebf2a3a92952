"""Decision rates of `jaxeac grid --sequential` from many simulated sequential experiments.

    python scripts/sequential_calibration.py --out scripts/bench_results/cpu_sequential_calibration.json

Runs a pool of seeds of each algorithm once (paper preset), then simulates sequential
comparisons (`jaxeac.stats.sequential.simulate`): each draws N seeds per method without
replacement from the pools and looks at them in K batches. AC against AC and EAC against
EAC have no true difference, so their "difference" rate is the false-positive rate, to
sit at or below the nominal α; AC against EAC gives the decisions and seeds used at the
observed effect. The paired rows follow `jaxeac grid --sequential`, whose looks are paired
(seed i of both methods shares its key): N per-seed differences EAC − AC per experiment,
with random signs for the null. Prints and writes a JSON record (machine, versions,
settings, rates with Monte Carlo standard errors, seconds).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pool", type=int, default=20_000, help="seeds per algorithm in the pools")
    ap.add_argument("--seeds", type=int, default=1000, help="N: the most seeds per method an experiment uses")
    ap.add_argument("--looks", type=int, default=5)
    ap.add_argument("--effect", type=float, default=2.0, help="declared effect (mean successes)")
    ap.add_argument("--alpha", type=float, default=0.05)
    ap.add_argument("--spending", default="obrien_fleming")
    ap.add_argument("--experiments", type=int, default=2000, help="simulated experiments per comparison")
    ap.add_argument("--out", type=Path, help="also write the JSON record here")
    args = ap.parse_args()

    import jax
    import numpy as np

    import jaxeac
    from jaxeac.envs.grid import GridWorld, get_map
    from jaxeac.experiments.grid import GridSettings
    from jaxeac.running.batch import run_algorithms
    from jaxeac.stats.sequential import SequentialDesign, simulate, simulate_paired

    settings = GridSettings(seeds=args.pool).resolved()
    env = GridWorld(get_map("paper"), settings.chances)
    t0 = time.perf_counter()
    runs = run_algorithms(env, [settings.run_config(a) for a in ("ac", "eac")], root_key=0, n_seeds=args.pool)
    pool_seconds = time.perf_counter() - t0
    ac, eac = (r.successes.astype(np.float64) for r in runs)
    design = SequentialDesign(effect=args.effect, max_seeds=args.seeds, looks=args.looks, alpha=args.alpha,
                              spend=args.spending)
    rng = np.random.default_rng(2014)
    t0 = time.perf_counter()
    comparisons = {
        "ac_vs_ac": simulate(design, ac, None, args.experiments, rng),
        "eac_vs_eac": simulate(design, eac, None, args.experiments, rng),
        "ac_vs_eac": simulate(design, ac, eac, args.experiments, rng),
        # paired, as `jaxeac grid --sequential` looks (seed i of both shares its key): the
        # per-seed differences EAC − AC with random signs (null), and as they are
        "paired_null": simulate_paired(design, eac - ac, args.experiments, rng, null=True),
        "paired_observed": simulate_paired(design, eac - ac, args.experiments, rng, null=False),
    }
    record = {
        "command": "python scripts/sequential_calibration.py " + " ".join(sys.argv[1:]),
        "machine": {"platform": platform.platform(), "backend": jax.default_backend()},
        "versions": {"jaxeac": jaxeac.__version__, "jax": jax.__version__, "numpy": np.__version__,
                     "python": platform.python_version()},
        "design": design.describe(),
        "pool_seeds": args.pool,
        "pool_means": {"ac": float(ac.mean()), "eac": float(eac.mean())},
        "pool_seconds": pool_seconds,
        "simulation_seconds": time.perf_counter() - t0,
        "comparisons": comparisons,
        "false_positive_within_nominal": {
            k: comparisons[k]["decisions"]["difference"]["rate"]
            <= args.alpha + 2 * comparisons[k]["decisions"]["difference"]["se"]
            for k in ("ac_vs_ac", "eac_vs_eac", "paired_null")
        },
    }
    text = json.dumps(record, indent=2)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
