"""One run of the paper preset through the fused GPU kernel, for a profiler to read.

Runs N seeds of one algorithm once (one chunk, the default lanes). A kernel profiler
then reads the chance kernel's launches, e.g. its DRAM throughput as a fraction of
the GPU's peak (BENCHMARKS.md):

    ncu --kernel-name regex:chance --launch-skip 4 --launch-count 3 \\
        --metrics gpu__time_duration.sum,dram__throughput.avg.pct_of_peak_sustained_elapsed \\
        python scripts/profile_kernel.py --algo eac --seeds 262144

Why a warp waits (the stall reasons, per instruction issued), as in BENCHMARKS.md:

    ncu --kernel-name regex:chance --launch-skip 4 --launch-count 2 \
        --metrics gpu__time_duration.sum,smsp__inst_executed.sum,\
smsp__average_warp_latency_per_inst_issued.ratio,regex:smsp__average_warps_issue_stalled_.*_per_issue_active\.ratio \
        python scripts/profile_kernel.py --algo ac --seeds 32768 --lanes 32768
"""

from __future__ import annotations

import argparse
import time


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--algo", default="eac", choices=["ac", "eac"])
    p.add_argument("--seeds", type=int, default=262_144)
    p.add_argument("--jump", default="auto", choices=["auto", "on", "off"])
    p.add_argument("--lanes", type=int, default=None, help="seeds in flight (default: jaxeac's)")
    args = p.parse_args()

    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxeac.algorithm.config import algorithm
    from jaxeac.envs.grid import GridWorld, get_map
    from jaxeac.running.batch import make_batch_run
    from jaxeac.running.config import RunConfig

    env = GridWorld(get_map("paper"), 40)
    cfg = RunConfig(trials=200, agent=algorithm(args.algo), jump=args.jump, lanes=args.lanes).resolve(
        env, args.seeds)
    run = make_batch_run(env, cfg)
    seeds = jnp.arange(args.seeds, dtype=jnp.int32)
    hyper = jax.tree.map(lambda x: jnp.broadcast_to(x, (args.seeds,)), cfg.hyper())
    t0 = time.perf_counter()
    out = jax.block_until_ready(run(jax.random.key(0), seeds, hyper))
    seconds = time.perf_counter() - t0
    steps = int(np.abs(np.asarray(out.log, np.int64)).sum())
    print(f"{args.algo} jump={cfg.jump} kernel={cfg.kernel} lanes={cfg.lanes} seeds={args.seeds} "
          f"seconds={seconds:.3f} (compile included) agent_steps={steps}")


if __name__ == "__main__":
    main()
