"""The sequential comparison (`jaxeac.stats.sequential`) beside AdaStop on the same simulated
experiments: false-positive rate and mean seeds per method to a decision (BENCHMARKS.md).

AdaStop (Mathieu et al. 2023, the `adastop` package) is a benchmark-only dependency: it runs
in its own environment. Both sides draw each experiment from NumPy's generator seeded with
(seed, experiment), so they see the same seeds' values::

    python scripts/bench_sequential.py --method jaxeac  --out seq_jaxeac.json
    /tmp/ads/bin/python scripts/bench_sequential.py --method adastop --out seq_adastop.json

(`python3 -m venv /tmp/ads && /tmp/ads/bin/pip install adastop` makes that environment.)
Each experiment compares two methods whose per-seed values are normal, sd 1, means 0 and
`--shift` (0: no difference, for the false-positive rate); both procedures take K = `--looks`
looks of `--batch` seeds per method and α = `--alpha`. The jaxeac design's declared effect
(`--effect`) also lets it stop early for "no difference"; AdaStop's β = 0 (its default) does not.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np


def draws(seed: int, experiment: int, n: int, shift: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng([seed, experiment])
    return rng.normal(0.0, 1.0, n), rng.normal(shift, 1.0, n)


def run_jaxeac(args, shift: float) -> tuple[int, float]:
    from jaxeac.stats.sequential import SequentialDesign, look

    design = SequentialDesign(effect=args.effect, max_seeds=args.looks * args.batch, looks=args.looks,
                              alpha=args.alpha)
    c = design.boundaries()
    differ, used = 0, 0
    for e in range(args.experiments):
        b, t = draws(args.seed, e, design.max_seeds, shift)
        for k, size in enumerate(design.sizes):
            r = look(b[:size], t[:size], c[k], design.effect, k + 1 == design.looks)
            if r["decision"] != "continue":
                differ += r["decision"] == "difference"
                used += size
                break
    return differ, used / args.experiments


def run_adastop(args, shift: float) -> tuple[int, float]:
    from adastop import MultipleAgentsComparator

    differ, used = 0, 0
    n = args.batch
    for e in range(args.experiments):
        b, t = draws(args.seed, e, args.looks * n, shift)
        comp = MultipleAgentsComparator(n=n, K=args.looks, B=args.permutations, alpha=args.alpha, seed=e)
        for k in range(args.looks):
            comp.partial_compare({"baseline": b[: (k + 1) * n], "treatment": t[: (k + 1) * n]}, verbose=False)
            if comp.is_finished:
                break
        differ += any(d != "equal" for d in comp.decisions.values())
        used += int(np.max(comp.n_iters["baseline"] if isinstance(comp.n_iters, dict) else comp.n_iters))
    return differ, used / args.experiments


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", choices=("jaxeac", "adastop"), required=True)
    ap.add_argument("--experiments", type=int, default=1000)
    ap.add_argument("--looks", type=int, default=5)
    ap.add_argument("--batch", type=int, default=10, help="seeds per method per look")
    ap.add_argument("--alpha", type=float, default=0.05)
    ap.add_argument("--effect", type=float, default=0.5, help="jaxeac's declared effect (sd units)")
    ap.add_argument("--shift", type=float, nargs="+", default=[0.0, 0.5, 1.0])
    ap.add_argument("--permutations", type=int, default=2000, help="AdaStop's B")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out")
    args = ap.parse_args()
    run = run_jaxeac if args.method == "jaxeac" else run_adastop
    rows = []
    for shift in args.shift:
        t0 = time.perf_counter()
        differ, seeds = run(args, shift)
        p = differ / args.experiments
        rows.append({"shift_sd": shift, "rate_difference": p, "se": math.sqrt(p * (1 - p) / args.experiments),
                     "mean_seeds_per_method": seeds, "seconds": time.perf_counter() - t0})
    record = {"method": args.method, **{k: v for k, v in vars(args).items() if k not in ("method", "out")},
              "rows": rows}
    text = json.dumps(record, indent=1)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")


if __name__ == "__main__":
    main()
