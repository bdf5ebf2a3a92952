"""Where a CPU grid run's time goes: compiled code, the runtime that dispatches it, memory, Python.

Samples the run phase of the paper preset (after its compile and one warm run, in a child
process) with Linux perf (``perf record -e cpu-clock -p PID``), for jaxeac and for the compiled
peers on the same work, and sorts each sample by what it landed in (`CATEGORIES`):

- ``compiled``: code generated for the work: XLA:CPU's kernels and numba's loop (perf's
  ``[JIT]`` / ``[unknown]`` objects: run-time code has no symbols), the C peer's library, and
  the maths library they call (numba's ``expf``);
- ``runtime``: what runs that code: XLA:CPU's thunk executor and thread pool, which dispatch
  each operation of the lane loop on its own (BENCHMARKS.md, *What a CPU chance costs*),
  OpenMP's and numba's thread pools;
- ``memory``: allocation (malloc/free) and copies in the C library;
- ``kernel``: the operating system (mostly clearing pages newly touched);
- ``python``: the interpreter; ``other``: anything else.

    python scripts/profile_cpu.py --algos ac eac --peers numba c --seeds 100000 \\
        --out scripts/bench_results/cpu_profile.json

Needs ``perf`` (linux-tools) with sampling of one's own processes allowed
(``kernel.perf_event_paranoid`` ≤ 2); no hardware counters are needed. The peers are those of
``scripts/bench.py`` (``--c-peer``, ``--numba-peer``). The shares are of the samples taken while
the child ran its ``--repeats`` runs, on all of its threads.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CATEGORIES = ("compiled", "runtime", "memory", "kernel", "python", "other")
RUNTIME_LIBRARIES = ("libjax_common", "libgomp", "libomp", "libiomp", "libtbb", "workqueue", "omppool",
                     "tbbpool")
MEMORY_SYMBOLS = ("malloc", "free", "memmove", "memcpy", "memset", "_int_", "unlink_chunk", "memalign",
                  "brk", "mmap", "munmap")


def category(dso: str, symbol: str) -> str:
    """The `CATEGORIES` entry of one perf sample's shared object and symbol."""
    if dso.startswith("[JIT]") or dso == "[unknown]" or "c_peer" in dso or dso.startswith("libm."):
        return "compiled"  # run-time code, the C peer's library, and the maths it calls
    if dso == "[kernel.kallsyms]":
        return "kernel"
    if any(name in dso for name in RUNTIME_LIBRARIES):
        return "runtime"
    if dso.startswith("libc.so") or dso.startswith("libc-"):
        return "memory" if any(s in symbol for s in MEMORY_SYMBOLS) else "other"
    if "libpython" in dso or dso.startswith("python"):
        return "python"
    return "other"


def parse_report(text: str) -> list[tuple[float, str, str]]:
    """(percent, shared object, symbol) rows of ``perf report --sort dso,sym --stdio``."""
    rows = []
    for line in text.splitlines():
        parts = line.split(None, 3)
        if len(parts) < 4 or not parts[0].endswith("%") or parts[0].startswith("#"):
            continue
        try:
            pct = float(parts[0].rstrip("%"))
        except ValueError:
            continue
        if parts[1] == "[JIT]":  # "[JIT] tid 123  [.] 0x7f…": run-time code has addresses, not names
            rows.append((pct, "[JIT]", parts[3].split("] ", 1)[-1].strip()))
            continue
        symbol = parts[3].split("] ", 1)[-1] if parts[2].startswith("[") else parts[3]
        rows.append((pct, parts[1], symbol.strip()))
    return rows


def summarize(rows: list[tuple[float, str, str]], top: int = 8) -> dict:
    """Shares by category (fractions of all samples) and the `top` symbols."""
    total = sum(p for p, _, _ in rows) or 1.0
    shares: dict[str, float] = collections.Counter()
    for pct, dso, sym in rows:
        shares[category(dso, sym)] += pct / total
    hottest = sorted(rows, key=lambda r: -r[0])[:top]
    return {"shares": {c: round(shares.get(c, 0.0), 4) for c in CATEGORIES},
            "top": [{"share": round(p / total, 4), "object": d, "symbol": s[:120]} for p, d, s in hottest]}


def child(impl: str, algo: str, seeds: int, jump: str, repeats: int, chunk: int) -> None:
    """Warm up and say READY; on a line from stdin run `repeats` times and say DONE; on another line
    print the row as JSON. Only the runs lie between the two lines (the parent samples them alone):
    counting the steps afterwards converts arrays on the host, which is no part of a run."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench  # noqa: E402  (configures XLA before JAX starts, as jaxeac does)

    if impl == "jaxeac":
        from jaxeac.running.batch import run_seeds

        env, cfg = bench.paper_preset(algo, jump=jump)

        def run():
            r = run_seeds(env, cfg, root_key=0, n_seeds=seeds, chunk_size=chunk)
            return r.run_seconds, r

        def steps(r) -> int:
            return r.agent_steps
    else:
        if not bench.prepare_peers([impl], None):
            print(json.dumps({"skip": f"the {impl} peer cannot run here"}), flush=True)
            return
        def run():
            return bench.run_peer(impl, algo, seeds)

        def steps(out) -> int:
            return int(out["agent_steps"].sum())
    run()
    print("READY", flush=True)
    sys.stdin.readline()
    timed = [run() for _ in range(repeats)]
    print("DONE", flush=True)
    sys.stdin.readline()
    best = min(t for t, _ in timed)
    n = steps(timed[0][1])
    print(json.dumps({"run_s": best, "agent_steps": n, "steps_per_s": n / best}), flush=True)


def profile(impl: str, algo: str, seeds: int, jump: str, repeats: int, chunk: int, frequency: int) -> dict:
    """One child's run phase under perf: the row and its `summarize`d samples."""
    cmd = [sys.executable, __file__, "--child", impl, algo, str(seeds), jump, str(repeats), str(chunk)]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline().strip()
    if line != "READY":
        proc.wait()
        skip = json.loads(line).get("skip") if line.startswith("{") else f"the child said {line!r}"
        return {"impl": impl, "algo": algo, "skipped": skip}
    with tempfile.TemporaryDirectory() as tmp:
        data = os.path.join(tmp, "perf.data")
        perf = subprocess.Popen(["perf", "record", "-q", "-e", "cpu-clock", "-F", str(frequency), "-p",
                                 str(proc.pid), "-o", data], stderr=subprocess.DEVNULL)
        time.sleep(1.0)  # perf attached to every thread before the runs start
        proc.stdin.write("go\n")
        proc.stdin.flush()
        done = proc.stdout.readline().strip()
        perf.send_signal(signal.SIGINT)
        perf.wait()
        if done != "DONE":
            proc.kill()
            raise RuntimeError(f"the {impl} child stopped before its runs ended (said {done!r})")
        proc.stdin.write("go\n")
        proc.stdin.flush()
        row = json.loads(proc.stdout.readline())
        proc.wait()
        report = subprocess.run(["perf", "report", "-i", data, "--sort", "dso,sym", "--stdio",
                                 "--no-children", "--percent-limit", "0"],
                                capture_output=True, text=True, check=True).stdout
    rows = parse_report(report)
    return {"impl": impl, "algo": algo, "jump": jump if impl == "jaxeac" else None, "seeds": seeds, **row,
            **summarize(rows)}


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        impl, algo, seeds, jump, repeats, chunk = sys.argv[2:8]
        child(impl, algo, int(seeds), jump, int(repeats), int(chunk))
        return
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--algos", nargs="+", default=["ac", "eac"], choices=["ac", "eac"])
    p.add_argument("--peers", nargs="*", default=["numba", "c"], choices=["numba", "c"])
    p.add_argument("--seeds", type=int, default=100_000)
    p.add_argument("--jump", default="auto", choices=["auto", "on", "off"], help="jaxeac's EAC memory jumps")
    p.add_argument("--chunk", type=int, default=8192, help="jaxeac's seeds per compiled chunk (as bench.py)")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--frequency", type=int, default=2000, help="samples per second per thread")
    p.add_argument("--out", type=Path)
    args = p.parse_args()
    if shutil.which("perf") is None:
        sys.exit("error: perf is not installed (linux-tools); install it or run on a machine that has it")
    record = {"command": " ".join(["python", *sys.argv]), "rows": []}
    for algo in args.algos:
        for impl in ["jaxeac", *args.peers]:
            row = profile(impl, algo, args.seeds, args.jump, args.repeats, args.chunk, args.frequency)
            record["rows"].append(row)
            shares = " ".join(f"{k} {v:.0%}" for k, v in row.get("shares", {}).items())
            rate = row.get("steps_per_s", 0)
            print(f"{impl:7s} {algo:4s} {rate:.3g} steps/s  {shares or row.get('skipped')}", flush=True)
    if args.out:
        args.out.write_text(json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
