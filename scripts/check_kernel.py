"""Per-seed check of the fused GPU kernel against XLA ops: the same run, seed by seed.

For every algorithm the kernel supports, N seeds × T trials of the paper preset (or of
each registered task named by ``--envs``) run once with ``kernel="xla"`` and once with
``kernel="pallas"`` (same seeds, all local devices), and the per-seed records are
compared: successes and steps per trial must be identical for every seed; greedy
policies are counted as identical or not (an argmax tie may round apart, see
tests/test_kernel.py). Exit status 1 if any seed differs.

    python scripts/check_kernel.py --seeds 20000 --out kernel_check.json
    python scripts/check_kernel.py --envs FourRooms-v0 CliffWalking-v1 --seeds 20000
    python scripts/check_kernel.py --envs grid-paper-v0 FourRooms-v0 CliffWalking-v1 --padded

With ``--padded`` the tasks' tables are padded to the layout covering them all (C among them, as
`jaxeac study` pads them) and the kernel runs them so, against XLA ops on each task's own tables.

Off GPUs the kernel runs in Pallas's interpreter: use a few hundred seeds there.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from jaxeac.runtime import configure

configure("grid", start_jax=False)  # before JAX starts, as `jaxeac` does

ALGOS = ("ac", "eac", "eac_within_trial", "eac_learn_on_memory", "eac_success_only", "eac_failure_only",
         "q_learning", "sarsa")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=20_000)
    p.add_argument("--trials", type=int, default=200)
    p.add_argument("--algos", nargs="+", default=list(ALGOS), choices=ALGOS)
    p.add_argument("--envs", nargs="+", metavar="NAME",
                   help="registered tasks (jaxeac.registered()); default: the paper preset")
    p.add_argument("--padded", action="store_true",
                   help="the kernel on the tasks' tables padded to one layout (as a study runs them)")
    p.add_argument("--out", type=Path, help="write the JSON record here")
    args = p.parse_args()
    if args.seeds < 1 or args.trials < 1:
        p.error("--seeds and --trials must be ≥ 1")
    if args.padded and not args.envs:
        p.error("--padded needs --envs: the registered tasks to pad to one layout")

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench import command_line, environment

    from jaxeac.algorithm.config import algorithm
    from jaxeac.envs import make
    from jaxeac.envs.grid import GridWorld, get_map
    from jaxeac.running.batch import run_seeds
    from jaxeac.running.config import RunConfig

    paper = {"paper": GridWorld(get_map("paper"), 40)}
    envs = {name: make(name) for name in args.envs} if args.envs else paper
    fused_envs = dict(envs)
    if args.padded:
        from jaxeac.envs.tabular import TableLayout, TabularEnv
        from jaxeac.envs.tasks import grid_task

        own = {n: TabularEnv(grid_task(e.map, e.n_chances, name=n)) if isinstance(e, GridWorld) else e
               for n, e in envs.items()}
        layout = TableLayout.covering(own.values())
        fused_envs = {n: e.padded(layout) for n, e in own.items()}
    record = {"environment": environment(), "command": command_line(), "rows": []}
    all_equal = True
    for (name, env), algo in [(e, a) for e in envs.items() for a in args.algos]:
        runs = {kernel: run_seeds(on, RunConfig(trials=args.trials, agent=algorithm(algo, tables="rows"),
                                                kernel=kernel),
                                  root_key=0, n_seeds=args.seeds, chunk_size=args.seeds)
                for kernel, on in (("xla", env), ("pallas", fused_envs[name]))}
        xla, fused = runs["xla"], runs["pallas"]
        same_run = (xla.success == fused.success).all(axis=1) & (xla.steps == fused.steps).all(axis=1)
        row = {
            **({"env": name} if args.envs else {}), **({"padded": True} if args.padded else {}),
            "algo": algo, "seeds": args.seeds, "trials": args.trials,
            "seeds_identical_success_and_steps": int(same_run.sum()),
            "seeds_identical_policy": int((xla.policy == fused.policy).all(axis=1).sum()),
            "mean_successes": float(fused.successes.mean()),
            "xla_run_s": xla.run_seconds, "kernel_run_s": fused.run_seconds,
        }
        all_equal &= row["seeds_identical_success_and_steps"] == args.seeds
        print(json.dumps(row), flush=True)
        record["rows"].append(row)
    record["all_identical"] = bool(all_equal)
    if args.out:
        args.out.write_text(json.dumps(record, indent=2) + "\n")
    print("identical for every seed" if all_equal else "SEEDS DIFFER", flush=True)
    return 0 if all_equal else 1


if __name__ == "__main__":
    sys.exit(main())
