"""Wall time of a study (`jaxeac study`, with ``--tune`` a tuned one: issue 43; without, issue 40),
end to end, in a fresh process, and its peak resident memory; the persistent compilation cache off
(first-run numbers) unless `--cache` names its folder (a second run there: warm-cache numbers).

Targets: on the 2-core CPU, 2 tasks x 8 algorithms x 8 settings x 200 tuning seeds, then 2,000
evaluation seeds, within 5 minutes; on one GPU, 11 tasks x 8 algorithms x 27 settings x 1,000 tuning
seeds, then 10,000 evaluation seeds, full report, within 10 minutes; the untuned study of 1,000
seeds within 15 s and of 100,000 seeds within 45 s at most 3 GiB resident. Writes JSON with the
command, machine, wall seconds, peak memory, the load average around the run (the CPU may be
shared), the study's timeline and tuned summary (what the run found), and with `--log` every
progress line with the seconds since the start; `--limit` stops the study after that many seconds
and still writes the record (``finished``: false, the lines say where it got):

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
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from bench import command_line, environment  # noqa: E402  (sets XLA's CPU devices first)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", nargs="+", default=None, help="default: the study's 11")
    p.add_argument("--seeds", type=int, default=2000, help="(evaluation) seeds")
    p.add_argument("--tune-seeds", type=int, default=200)
    p.add_argument("--tune", action="append", default=None, metavar="KEY=V1,V2,...",
                   help="a tuning grid (repeat per key); none: the untuned study")
    p.add_argument("--resamples", type=int, default=None, help="bootstrap resamples (default: the study's)")
    p.add_argument("--cache", type=Path, default=None,
                   help="persistent compilation cache folder (default: off, first-run numbers)")
    p.add_argument("--limit", type=float, default=None, help="stop the study after this many seconds")
    p.add_argument("--timeline", action="store_true", help="the study prints its timeline as it goes")
    p.add_argument("--keep", type=Path, default=None,
                   help="keep the study folder here (default: a temporary one)")
    p.add_argument("--log", type=Path, default=None,
                   help="write the study's progress lines here, each with the seconds since the start")
    p.add_argument("--out", type=Path, required=True, help="JSON record")
    args = p.parse_args()

    folder = args.keep or Path(tempfile.mkdtemp(prefix="bench_tune_")) / "study"
    argv = [sys.executable, "-m", "jaxeac", "study", "--seeds", str(args.seeds), "--out", str(folder)]
    argv += [] if args.log else ["--quiet"]
    argv += ["--timeline"] if args.timeline else []
    argv += ["--tasks", *args.tasks] if args.tasks else []
    argv += ["--resamples", str(args.resamples)] if args.resamples else []
    if args.tune:
        argv += ["--tune-seeds", str(args.tune_seeds)]
        for t in args.tune:
            argv += ["--tune", t]
    cache = str(args.cache) if args.cache else "off"
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, env={**os.environ, "JAXEAC_COMPILATION_CACHE": cache},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE if args.log else None, text=True)
    phases: dict = {}
    lines: list = []
    if args.log:
        log = args.log.open("w")

        def follow(stream):
            for line in stream:
                at = time.perf_counter() - t0
                phase = "tuning" if "tuning seeds" in line else "evaluation" if "evaluating" in line else None
                if phase:
                    phases.setdefault(phase, [at, at])[1] = at
                text = f"[{at:7.1f} s] {line.rstrip()}"
                lines.append(text)
                log.write(text + "\n")
                log.flush()

        reader = threading.Thread(target=follow, args=(proc.stderr,), daemon=True)
        reader.start()
    out_lines: list = []
    collector = threading.Thread(target=lambda: out_lines.extend(proc.stdout.read().splitlines()),
                                 daemon=True)
    collector.start()
    stopped = False
    while True:  # reaped here (`os.wait4`: its peak memory), stopped at the limit
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG if args.limit is not None else 0)
        if pid:
            break
        if time.perf_counter() - t0 > args.limit:
            proc.kill()
            stopped = True
            _, status, usage = os.wait4(proc.pid, 0)
            break
        time.sleep(0.2)
    wall = time.perf_counter() - t0
    collector.join(timeout=10)
    if args.log:
        reader.join(timeout=10)
    code = os.waitstatus_to_exitcode(status)
    finished = code == 0 and not stopped
    record = {
        "command": command_line(),
        "study": " ".join(["jaxeac", *argv[3:]]).replace(str(folder), "DIR"),
        "environment": environment(),
        "compilation_cache": "off" if cache == "off" else "on (--cache)",
        "finished": finished, "exit_code": code, "stopped_at_limit_s": args.limit if stopped else None,
        "wall_s": wall, "peak_rss_gib": usage.ru_maxrss / 2**20,
        "progress_s": {k: {"first_line": round(v[0], 1), "last_line": round(v[1], 1)}
                       for k, v in phases.items()},
        "load_average_1min": {"before": load_before[0], "after": os.getloadavg()[0]},
        "summary": out_lines,
    }
    if finished:
        study = json.loads((folder / "study.json").read_text())
        record["timeline"] = study.get("timeline")
        record["size"] = {"tasks": len(study["tasks"]), "seeds": study["seeds"]}
        if (tu := study.get("tuning")) is not None:
            record["size"] |= {"algorithms": len(tu["algorithms"]),
                               "settings": {a: len(s["points"]) for a, s in tu["algorithms"].items()},
                               "tuning_seeds": tu["seeds"], "evaluation_seeds": tu["evaluation_seeds"]}
            record["sensitivity_claim"] = tu["sensitivity"]["claim"]
    else:
        record["progress_lines"] = lines[-400:]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=1) + "\n")
    print(f"{wall:.1f} s wall, {record['peak_rss_gib']:.2f} GiB peak, finished: {finished}; "
          f"record in {args.out}")
    if args.keep is None:
        shutil.rmtree(folder.parent, ignore_errors=True)
    if not finished and not stopped:
        raise SystemExit(f"failed ({code}): {' '.join(argv)}\n" + "\n".join(out_lines[-20:]))


if __name__ == "__main__":
    main()
