"""Wall time of a tuned study (`jaxeac study --tune`, issue 43), end to end, in a fresh process with
the persistent compilation cache off (first-run numbers), and its peak resident memory.

Targets: on the 2-core CPU, 2 tasks x 8 algorithms x 8 settings x 200 tuning seeds, then 2,000
evaluation seeds, within 5 minutes; on one GPU, 11 tasks x 8 algorithms x 27 settings x 1,000 tuning
seeds, then 10,000 evaluation seeds, full report, within 10 minutes. Writes JSON with the command,
machine, wall seconds, peak memory, the load average around the run (the CPU may be shared) and the
study's tuned summary (what the run found):

    python scripts/bench_tune.py --tasks FrozenLake-4x4-v1 FourRooms-stochastic-v0 --seeds 2000 \
        --tune-seeds 200 --tune alpha=0.1,0.3 --tune beta=0.3,1 --tune gamma=0.9,0.99 \
        --tune epsilon=0.05,0.2 --out scripts/bench_results/cpu_tune_2x8x8.json
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from bench import command_line, environment  # noqa: E402  (sets XLA's CPU devices first)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", nargs="+", default=None, help="default: the study's 11")
    p.add_argument("--seeds", type=int, default=2000, help="evaluation seeds")
    p.add_argument("--tune-seeds", type=int, default=200)
    p.add_argument("--tune", action="append", required=True, metavar="KEY=V1,V2,...")
    p.add_argument("--resamples", type=int, default=None, help="bootstrap resamples (default: the study's)")
    p.add_argument("--keep", type=Path, default=None,
                   help="keep the study folder here (default: a temporary one)")
    p.add_argument("--log", type=Path, default=None,
                   help="write the study's progress lines here, each with the seconds since the start")
    p.add_argument("--out", type=Path, required=True, help="JSON record")
    args = p.parse_args()

    folder = args.keep or Path(tempfile.mkdtemp(prefix="bench_tune_")) / "study"
    argv = [sys.executable, "-m", "jaxeac", "study", "--seeds", str(args.seeds),
            "--tune-seeds", str(args.tune_seeds), "--out", str(folder)] + ([] if args.log else ["--quiet"])
    argv += ["--tasks", *args.tasks] if args.tasks else []
    argv += ["--resamples", str(args.resamples)] if args.resamples else []
    for t in args.tune:
        argv += ["--tune", t]
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, env={**os.environ, "JAXEAC_COMPILATION_CACHE": "off"},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE if args.log else None, text=True)
    phases: dict = {}
    if args.log:
        import threading

        log = args.log.open("w")

        def follow(stream):
            for line in stream:
                at = time.perf_counter() - t0
                phase = "tuning" if "tuning seeds" in line else "evaluation" if "evaluating" in line else None
                if phase:
                    phases.setdefault(phase, [at, at])[1] = at
                log.write(f"[{at:7.1f} s] {line.rstrip()}\n")
                log.flush()

        reader = threading.Thread(target=follow, args=(proc.stderr,), daemon=True)
        reader.start()
    stdout = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if args.log:
        reader.join(timeout=10)
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"failed ({status}): {' '.join(argv)}\n{stdout}")
    study = json.loads((folder / "study.json").read_text())
    tu = study["tuning"]
    record = {
        "command": command_line(),
        "study": " ".join(["jaxeac", *argv[3:]]).replace(str(folder), "DIR"),
        "environment": environment(),
        "wall_s": wall, "peak_rss_gib": usage.ru_maxrss / 2**20,
        "progress_s": {k: {"first_line": round(v[0], 1), "last_line": round(v[1], 1)}
                       for k, v in phases.items()},
        "load_average_1min": {"before": load_before[0], "after": os.getloadavg()[0]},
        "size": {"tasks": len(study["tasks"]), "algorithms": len(tu["algorithms"]),
                 "settings": {a: len(s["points"]) for a, s in tu["algorithms"].items()},
                 "tuning_seeds": tu["seeds"], "evaluation_seeds": tu["evaluation_seeds"]},
        "sensitivity_claim": tu["sensitivity"]["claim"],
        "summary": stdout.strip().splitlines(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=1) + "\n")
    print(f"{wall:.1f} s wall, {record['peak_rss_gib']:.2f} GiB peak; record in {args.out}")
    if args.keep is None:
        shutil.rmtree(folder.parent, ignore_errors=True)


if __name__ == "__main__":
    main()
