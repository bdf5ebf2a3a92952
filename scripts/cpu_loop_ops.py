"""What one chance of the CPU loop costs in XLA:CPU operations, per algorithm.

XLA:CPU runs a while loop's body as a sequence of thunks (mostly fused kernels), each
dispatched on its own; over 256 lanes a thunk's work is small, so their number sets much of
a chance's cost (BENCHMARKS.md, *What a CPU chance costs*). For each algorithm this runs
the paper preset once at a small size with XLA's HLO dump on (``--xla_dump_to``), takes the
compiled program's lane loop (the while loop whose state holds the [lanes, S, A] table; with
a queue there are two: the block's chance loop, and the loop over blocks), and counts the
operations of each body that run as work (not parameters, tuple plumbing, constants or
bitcasts).

    python scripts/cpu_loop_ops.py --algos ac eac --out cpu_loop_ops.json
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

FREE = {"parameter", "get-tuple-element", "tuple", "constant", "bitcast"}
RUN = """
import sys
from jaxeac.runtime import configure
configure("grid", start_jax=False)
from jaxeac.algorithm.config import algorithm
from jaxeac.envs.grid import GridWorld, get_map
from jaxeac.running.batch import run_seeds
from jaxeac.running.config import RunConfig
env = GridWorld(get_map("paper"), 40)
cfg = RunConfig(trials=200, agent=algorithm(sys.argv[1]), jump=sys.argv[2])
run_seeds(env, cfg, root_key=0, n_seeds=1000, chunk_size=16384)
"""


def loop_bodies(hlo: str) -> list[dict]:
    """The lane loops of an optimized HLO module: lanes, and the work operations of each body."""
    comps = {m.group(1).split()[-1]: m.group(2) for m in re.finditer(
        r"^(%[\w.\-]+|ENTRY [%\w.\-]+) \(.*?\) -> .*? \{\n(.*?)\n\}", hlo, re.S | re.M)}
    out = []
    for m in re.finditer(r"%while[\w.]* = \((.*?)\) while\(.*?body=(%[\w.\-]+)", hlo):
        lanes = re.search(r"\[(\d+),121,\d\]", m.group(1))  # the paper grid's 121 states
        if lanes is None:
            continue
        ops: collections.Counter = collections.Counter()
        for line in comps[m.group(2)].splitlines():
            op = re.match(r"\s*(?:ROOT )?%[\w.\-]+ = .*? ([a-z][a-z\-]*)\(", line)
            if op and op.group(1) not in FREE:
                ops[op.group(1)] += 1
        out.append({"lanes": int(lanes.group(1)), "operations": sum(ops.values()), "by_kind": dict(ops)})
    return sorted(out, key=lambda r: r["operations"])


def count(algo: str, jump: str) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} --xla_dump_to={tmp} "
                   "--xla_dump_hlo_as_text".strip())
        proc = subprocess.run([sys.executable, "-c", RUN, algo, jump], env=env, capture_output=True, text=True)
        if proc.returncode != 0:  # e.g. jumps asked of an algorithm without a success memory
            return {"algo": algo, "jump": jump, "error": (proc.stderr.strip().splitlines() or ["?"])[-1]}
        files = sorted(Path(tmp).glob("*jit_batch*after_optimizations.txt"))
        if not files:
            raise SystemExit(f"{algo}: no optimized HLO of the run's program in the dump")
        loops = loop_bodies(files[-1].read_text())
    return {"algo": algo, "jump": jump, "loops": loops}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--algos", nargs="+", default=["ac", "eac"])
    p.add_argument("--jump", nargs="+", choices=["auto", "on", "off"], default=["auto"],
                   help="for EAC-like algorithms: memory jumps as configured, or forced")
    p.add_argument("--out", type=Path, help="write the JSON record here")
    args = p.parse_args()
    rows = []
    for algo in args.algos:
        for jump in (args.jump if algo != "ac" else ["auto"]):
            row = count(algo, jump)
            rows.append(row)
            if "error" in row:
                print(f"{algo:20s} jump {jump:4s}: {row['error']}", flush=True)
                continue
            chance = row["loops"][0] if row["loops"] else {"operations": None, "lanes": None}
            print(f"{algo:20s} jump {jump:4s} lanes {chance['lanes']}: {chance['operations']} operations per "
                  f"chance ({chance.get('by_kind')})", flush=True)
    if args.out:
        import jax

        args.out.write_text(json.dumps({"command": "python scripts/cpu_loop_ops.py " + " ".join(sys.argv[1:]),
                                        "jax": jax.__version__, "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
