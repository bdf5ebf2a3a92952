"""Scale-out evidence (SPEC R1, §5): seeds over 1 and all local devices — time, scaling, identity.

For AC and EAC on the paper preset: the run of N seeds on all local devices and on
one device (compile timed apart), the scaling efficiency t₁ / (n · tₙ), and a check
that the per-seed results of the first K seeds are bit-identical on 1 and n devices.

    python scripts/scale.py --seeds 1000000 --chunk 1000000 --subset 100000 --out scale.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from jaxeac.runtime import configure

configure("grid", start_jax=False)  # before JAX starts, as `jaxeac` does

import jax  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=1_000_000)
    p.add_argument("--chunk", type=int, default=1_000_000)
    p.add_argument("--subset", type=int, default=100_000, help="seeds compared across device counts")
    p.add_argument("--single", action="store_true", help="also time the whole run on one device")
    p.add_argument("--out", type=Path)
    args = p.parse_args()

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench import command_line, environment

    from jaxeac.algorithm.config import algorithm
    from jaxeac.envs.grid import GridWorld, get_map
    from jaxeac.running.batch import run_seeds
    from jaxeac.running.config import RunConfig

    env = GridWorld(get_map("paper"), 40)
    devices = jax.local_devices()
    record = {"environment": environment(), "command": command_line(), "rows": []}
    for algo in ("ac", "eac"):
        cfg = RunConfig(trials=200, agent=algorithm(algo), alpha=0.1, beta=0.3, gamma=0.9)
        row = {"algo": algo, "seeds": args.seeds, "chunk": args.chunk, "devices": len(devices)}
        for label, devs in [("all", devices)] + ([("one", devices[:1])] if args.single else []):
            first = run_seeds(env, cfg, root_key=0, n_seeds=args.seeds, chunk_size=args.chunk, devices=devs)
            r = run_seeds(env, cfg, root_key=0, n_seeds=args.seeds, chunk_size=args.chunk, devices=devs)
            row[f"{label}_first_run_s"] = first.run_seconds  # includes CUDA-graph capture on GPUs
            row[f"{label}_compile_s"] = first.compile_seconds
            row[f"{label}_run_s"] = r.run_seconds
            row[f"{label}_steps_per_s"] = r.agent_steps / r.run_seconds
            row["mean_successes"] = float(r.successes.mean())
        if args.single and len(devices) > 1:
            row["scaling_efficiency"] = row["one_run_s"] / (len(devices) * row["all_run_s"])
        k = min(args.subset, args.seeds)
        one = run_seeds(env, cfg, root_key=0, n_seeds=k, chunk_size=k, devices=devices[:1])
        many = run_seeds(env, cfg, root_key=0, n_seeds=k, chunk_size=k, devices=devices)
        row["subset"] = k
        row["subset_identical"] = bool(all(np.array_equal(getattr(one, f), getattr(many, f))
                                           for f in ("success", "steps", "policy")))
        print(json.dumps(row), flush=True)
        record["rows"].append(row)
    if args.out:
        args.out.write_text(json.dumps(record, indent=2) + "\n")


if __name__ == "__main__":
    main()
