r"""One run of the paper preset through the fused GPU kernel, for a profiler to read.

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

Where a warp waits, instruction by instruction (ncu's warp-stall sampling, the SourceCounters
section), then summarized here: each instruction's share of the samples, and the global load
each of the most-waited-on instructions waits for (the last load that wrote one of its source
registers):

    ncu --kernel-name regex:chance --launch-skip 4 --launch-count 1 --section SourceCounters \
        --import-source no -o eac python scripts/profile_kernel.py --algo eac --seeds 16384 --lanes 16384
    ncu -i eac.ncu-rep --page source --csv --print-source sass > eac_sass.csv
    python scripts/profile_kernel.py --sass eac_sass.csv

Set ``XLA_PYTHON_CLIENT_PREALLOCATE=false`` for these: ncu saves and restores the memory a
replayed kernel may write, and JAX's up-front reservation of most of the GPU made that slow.
On ncu 2025.3 about half of the attaches end in a segmentation fault before the first kernel,
at random; retry. An EAC run whose chunk goes through the queue (lanes ≥ 32,768: a tail phase)
faulted in every try, so EAC is profiled at 16,384 lanes, a lane per seed.
"""

from __future__ import annotations

import argparse
import csv
import json
import re
import sys
import time
from pathlib import Path

STALL_COLUMN = "Warp Stall Sampling (All Samples)"


def _operands(instruction: str) -> tuple[str | None, list[str]]:
    """(destination register, source registers) of one SASS instruction, predicate stripped."""
    body = re.sub(r"^@!?U?P\w+\s+", "", instruction.strip())
    parts = body.split(None, 1)
    if len(parts) < 2:
        return None, []
    regs = [re.findall(r"\bR(\d+)\b", op) for op in parts[1].split(",")]
    dest = regs[0][0] if regs and regs[0] and not parts[0].startswith(("ST", "RED", "ATOM")) else None
    return dest, [r for op in regs[1 if dest else 0:] for r in op]


def summarize_sass(path: Path, top: int = 12) -> dict:
    """ncu's source page (``--page source --csv --print-source sass``) summarized: stall reasons'
    shares of the samples, global loads and stores, and the `top` instructions by samples waiting
    on a global load (long scoreboard), each with the load it waits for."""
    rows = list(csv.reader(path.open()))
    header = next(i for i, r in enumerate(rows) if "Source" in r and STALL_COLUMN in r)
    col = {name: i for i, name in enumerate(rows[header])}
    data = [r for r in rows[header + 1:] if len(r) == len(rows[header])]

    def num(r, name):
        try:
            return float(r[col[name]].replace(",", ""))
        except (KeyError, ValueError):
            return 0.0

    sass = [r[col["Source"]].strip() for r in data]
    total = sum(num(r, STALL_COLUMN) for r in data) or 1.0
    reasons = {name[len("stall_"):]: round(sum(num(r, name) for r in data) / total, 4)
               for name in col if name.startswith("stall_") and "(Not" not in name}
    executed = [num(r, "Instructions Executed") for r in data]

    def waits_for(i: int) -> int | None:
        dest, sources = _operands(sass[i])
        if sass[i].startswith("@") and dest is not None:  # predicated: the old value is kept, so read
            sources = [*sources, dest]
        loads = []
        for reg in set(sources):  # the last writer of each source; a long-scoreboard wait is on a load
            for j in range(i - 1, -1, -1):
                dest, _ = _operands(sass[j])
                if dest is not None and (dest == reg or (".64" in sass[j] and str(int(dest) + 1) == reg)):
                    if "LDG" in sass[j]:
                        loads.append(j)
                    break
        return max(loads, default=None)

    order = sorted(range(len(data)), key=lambda i: -num(data[i], "stall_long_sb"))[:top]
    order = [i for i in order if num(data[i], "stall_long_sb") / total >= 0.005]
    waits = []
    for i in sorted(order):
        j = waits_for(i)
        share = round(num(data[i], "stall_long_sb") / total, 4)
        waits.append({"index": i, "instruction": sass[i], "long_scoreboard_share": share,
                      "waits_for": None if j is None else {"index": j, "instruction": sass[j]}})
    loads = [{"index": i, "instruction": sass[i], "executed": int(executed[i])} for i in range(len(sass))
             if "LDG" in sass[i]]
    return {"file": path.name, "instructions": len(sass), "samples": int(total),
            "warp_instructions_executed": int(sum(executed)),
            "stall_reasons": {k: v for k, v in sorted(reasons.items(), key=lambda kv: -kv[1]) if v >= 0.005},
            "global_loads": loads, "global_stores": sum("STG" in x for x in sass), "top_waits": waits}


def print_sass_summary(summary: dict) -> None:
    print(f"{summary['file']}: {summary['instructions']} instructions, {summary['samples']} samples, "
          f"{summary['warp_instructions_executed']:,} warp instructions executed")
    print("  stall reasons: " + ", ".join(f"{k} {v:.1%}" for k, v in summary["stall_reasons"].items()))
    per_launch = max(x["executed"] for x in summary["global_loads"])
    hot = [x for x in summary["global_loads"] if x["executed"] == per_launch]
    print(f"  global loads: {len(summary['global_loads'])} in the code, {len(hot)} of them every chance; "
          f"{summary['global_stores']} stores")
    for w in summary["top_waits"]:
        load = w["waits_for"]
        src = f"[{load['index']}] {load['instruction']}" if load else "-"
        at = f"[{w['index']}] {w['instruction'][:44]}"
        print(f"  {w['long_scoreboard_share']:6.1%}  {at:50s} waits for {src}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sass", type=Path, nargs="+", metavar="CSV",
                   help="summarize ncu source pages (see above) instead of running; --out: as JSON")
    p.add_argument("--out", type=Path, help="with --sass: where to write the summaries")
    p.add_argument("--algo", default="eac", choices=["ac", "eac"])
    p.add_argument("--seeds", type=int, default=262_144)
    p.add_argument("--jump", default="auto", choices=["auto", "on", "off"])
    p.add_argument("--lanes", type=int, default=None, help="seeds in flight (default: jaxeac's)")
    args = p.parse_args()
    if args.sass:
        summaries = [summarize_sass(path) for path in args.sass]
        for summary in summaries:
            print_sass_summary(summary)
        if args.out:
            command = " ".join(["python", "scripts/profile_kernel.py", *sys.argv[1:]])
            args.out.write_text(json.dumps({"command": command, "summaries": summaries}, indent=1) + "\n")
        return

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
