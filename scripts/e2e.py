"""End-to-end cost of whole `jaxeac` commands, as quoted in BENCHMARKS.md (CPU or GPU alike).

    python scripts/e2e.py --out runs/e2e                     # grid 10k, sweep, bowling
    python scripts/e2e.py --out runs/e2e --only grid --grid-seeds 1000000 10000000

Each command runs in its own process. For a grid run the record splits the wall
time of the plain command (both methods, statistics report and figures included)
into compile, run, write and statistics: ``jaxeac grid --no-compare`` (compile and
run seconds from its summary.json, the rest of its wall time is start-up, transfer
and writing), then ``jaxeac compare`` on the same folder. Peak resident memory of
each process and the bytes of the run folder are recorded too.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ALPHAS = "0.02,0.05,0.1,0.15,0.2,0.3,0.4,0.5,0.7,0.9"
BETAS = "0.05,0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9"


def jaxeac(argv: list[str]) -> dict:
    """Run ``jaxeac ARGV`` in a fresh process: wall seconds and peak RSS (GiB)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "jaxeac", *argv], stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"jaxeac {' '.join(argv)} failed with exit code {os.waitstatus_to_exitcode(status)}")
    rss = usage.ru_maxrss * (1 if sys.platform == "darwin" else 1024) / 2**30
    return {"command": " ".join(["jaxeac", *argv]), "wall_s": wall, "peak_rss_gib": rss}


def folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def grid_record(out: Path, seeds: int, plain_only: bool = False) -> dict:
    """The plain command end to end, then (unless `plain_only`) the same run split into
    run+write and compare."""
    base = ["grid", "--preset", "paper", "--seeds", str(seeds), "--quiet"]
    whole = jaxeac([*base, "--out", str(out / f"grid{seeds}")])
    if plain_only:
        summary = json.loads((out / f"grid{seeds}" / "summary.json").read_text())
        return {**whole, "seeds": seeds, "devices": summary["devices"],
                "compile_s": summary["compile_seconds"], "run_s": summary["run_seconds"],
                "output_bytes": folder_bytes(out / f"grid{seeds}")}
    split = out / f"grid{seeds}_split"
    run = jaxeac([*base, "--no-compare", "--out", str(split)])
    summary = json.loads((split / "summary.json").read_text())
    stats = jaxeac(["compare", str(split)])
    compile_s, run_s = summary["compile_seconds"], summary["run_seconds"]
    return {
        **whole, "seeds": seeds, "devices": summary["devices"],
        "compile_s": compile_s, "run_s": run_s,
        "start_write_s": run["wall_s"] - compile_s - run_s,  # start-up, copies back, unpacking, writing
        "grid_no_compare_wall_s": run["wall_s"], "grid_no_compare_peak_rss_gib": run["peak_rss_gib"],
        "compare_wall_s": stats["wall_s"], "compare_peak_rss_gib": stats["peak_rss_gib"],
        "output_bytes": folder_bytes(out / f"grid{seeds}"),
        "agent_steps_per_s": summary.get("agent_steps_per_second"),
        "chunk_size": summary["per_algo"]["ac"].get("run", {}).get("chunk_size"),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("runs/e2e"))
    p.add_argument("--only", nargs="+", choices=["grid", "sweep", "bowling"])
    p.add_argument("--grid-seeds", type=int, nargs="+", default=[10_000])
    p.add_argument("--plain-only", action="store_true",
                   help="grid: only the plain command (no split run, no separate compare)")
    p.add_argument("--record", type=Path, help="write the JSON record here (default OUT/timings.json)")
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    record = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                          "python": platform.python_version()},
              "command": " ".join(["python", *sys.argv]), "grid": []}
    wanted = set(args.only or ["grid", "sweep", "bowling"])
    if "grid" in wanted:
        for seeds in args.grid_seeds:
            record["grid"].append(grid_record(args.out, seeds, args.plain_only))
            print(json.dumps(record["grid"][-1]), flush=True)
    if "sweep" in wanted:
        record["sweep"] = jaxeac(["sweep", "--seeds", "1000", "--quiet", "--out", str(args.out / "sweep"),
                                  "--set", f"alpha={ALPHAS}", "--set", f"beta={BETAS}"])  # 100 points × 2
        print(json.dumps(record["sweep"]), flush=True)
    if "bowling" in wanted:
        record["bowling"] = jaxeac(["bowling", "--seeds", "1000", "--out", str(args.out / "bowling1000"),
                                    "--quiet"])
        print(json.dumps(record["bowling"]), flush=True)
    path = args.record or args.out / "timings.json"
    path.write_text(json.dumps(record, indent=2) + "\n")


if __name__ == "__main__":
    main()
