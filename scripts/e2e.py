"""End-to-end cost of whole `jaxeac` commands, as quoted in BENCHMARKS.md (CPU or GPU alike).

    python scripts/e2e.py --out runs/e2e                     # grid 10k, sweep, bowling, sequential
    python scripts/e2e.py --out runs/e2e --only grid --grid-seeds 1000000 10000000

Each command runs in its own process. A grid run is timed twice: with an empty
compilation cache (what a first run pays, compile included) and again with the
programs that run cached (``cached``). The record splits the plain command's wall
time (both methods, statistics report and figures included) into compile, run and
compare from its own summary.json and stats.json; the rest is start-up, copies
back, writing and the run's figures. Unless ``--plain-only``, the run is repeated as
``jaxeac grid --no-compare`` then ``jaxeac compare`` (each command's own wall time
and memory). Peak resident memory of each process and the bytes of the run folder
are recorded too.

    python scripts/e2e.py --only grid --grid-seeds 1000000 --warm-up --builds A B --repeats 3

compares source trees A and B (e.g. ``git worktree add A COMMIT``) on one machine:
the plain command's first runs taking turns, then a cached run of each.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

ALPHAS = "0.02,0.05,0.1,0.15,0.2,0.3,0.4,0.5,0.7,0.9"
BETAS = "0.05,0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9"


def jaxeac(argv: list[str], env: dict | None = None) -> dict:
    """Run ``jaxeac ARGV`` in a fresh process: wall seconds, its peak RSS and, on Linux, the peak of
    its processes' RSS together (GiB). Python's ``-P`` keeps the working directory off the front of
    its path, so a build put first on PYTHONPATH (`builds_record`) is the jaxeac imported even when
    run from a checkout's root."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-P", "-m", "jaxeac", *argv], stdout=subprocess.DEVNULL,
                            env=None if env is None else os.environ | env)
    together = TreePeak(proc.pid)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    tree = together.stop()
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"jaxeac {' '.join(argv)} failed with exit code {os.waitstatus_to_exitcode(status)}")
    rss = usage.ru_maxrss * (1 if sys.platform == "darwin" else 1024) / 2**30
    out = {"command": " ".join(["jaxeac", *argv]), "wall_s": wall, "peak_rss_gib": rss}
    if tree is not None:
        out["peak_tree_rss_gib"] = tree / 2**30
    return out


class TreePeak:
    """The peak of the summed resident memory of process `pid` and its descendants, sampled every
    `every` seconds from /proc on a thread of its own until `stop` (None where there is no /proc).
    Sampling misses peaks shorter than a tick: a lower bound of the true peak together, where each
    process's own peak (``ru_maxrss``) is exact."""

    def __init__(self, pid: int, every: float = 0.05) -> None:
        self.pid, self.every, self.peak = pid, every, 0
        self.page = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._watch, daemon=True)
        self.ok = Path("/proc/self/statm").exists()
        if self.ok:
            self.thread.start()

    def stop(self) -> int | None:
        self.done.set()
        if not self.ok:
            return None
        self.thread.join()
        return self.peak

    def _watch(self) -> None:
        while not self.done.wait(self.every):
            self.peak = max(self.peak, self.sample())

    def sample(self) -> int:
        """Resident bytes of the process and its descendants now."""
        parent = {}
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rpartition(")")[2].split()
            except OSError:  # ended meanwhile
                continue
            parent[int(stat.parent.name)] = int(fields[1])
        tree, grew = {self.pid}, True
        while grew:
            more = {p for p, pp in parent.items() if pp in tree} - tree
            tree |= more
            grew = bool(more)
        total = 0
        for p in tree:
            try:
                total += int(Path(f"/proc/{p}/statm").read_text().split()[1]) * self.page
            except (OSError, IndexError, ValueError):
                continue
        return total


def breakdown(folder: Path, wall: float) -> dict:
    """Where the plain command's wall time went, from its own summary.json and stats.json."""
    summary = json.loads((folder / "summary.json").read_text())
    out = {"compile_s": summary["compile_seconds"], "run_s": summary["run_seconds"]}
    if (folder / "stats.json").is_file():
        timing = json.loads((folder / "stats.json").read_text())["timing"]
        out["compare_s"] = timing["total_seconds"]
        out["compare_statistics_s"] = timing["statistics_seconds"]
        out["compare_figures_s"] = timing.get("figures_seconds")
        out["compare_pieces_s"] = timing.get("pieces")
    # compile_s and run_s add up the algorithms' (their compiles overlap, and one's run overlaps the
    # other's compile); compare_s is the comparison after the run's folder is written (its statistics
    # start before, beside the run's figures). The rest, roughly: interpreter and JAX start-up, device
    # set-up, copies back, writing, the run's figures
    out["start_write_figures_s"] = wall - sum(out[k] for k in ("compile_s", "run_s", "compare_s") if k in out)
    return out


def folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def grid_record(out: Path, seeds: int, plain_only: bool = False) -> dict:
    """The plain command end to end, twice: with an empty compilation cache (a first run), then
    again with the programs it cached (a rerun). Unless `plain_only`, the same run is then
    split into run+write and compare (with the cache warm)."""
    base = ["grid", "--preset", "paper", "--seeds", str(seeds), "--quiet"]
    cache = out / f"xla_cache_{seeds}"
    if cache.exists():
        shutil.rmtree(cache)
    env = {"JAXEAC_COMPILATION_CACHE": str(cache)}
    folder = out / f"grid{seeds}"
    whole = jaxeac([*base, "--out", str(folder)], env)
    record = {**whole, "seeds": seeds, **breakdown(folder, whole["wall_s"])}
    rerun = jaxeac([*base, "--out", str(folder)], env)
    record["cached"] = {**rerun, **breakdown(folder, rerun["wall_s"])}
    summary = json.loads((folder / "summary.json").read_text())
    record |= {"devices": summary["devices"], "output_bytes": folder_bytes(folder),
               "agent_steps_per_s": summary.get("agent_steps_per_second"),
               "chunk_size": summary["per_algo"]["ac"].get("run", {}).get("chunk_size")}
    if plain_only:
        return record
    split = out / f"grid{seeds}_split"
    run = jaxeac([*base, "--no-compare", "--out", str(split)], env)
    summary = json.loads((split / "summary.json").read_text())
    stats = jaxeac(["compare", str(split)], env)
    return record | {
        "grid_no_compare_wall_s": run["wall_s"], "grid_no_compare_peak_rss_gib": run["peak_rss_gib"],
        "compare_wall_s": stats["wall_s"], "compare_peak_rss_gib": stats["peak_rss_gib"],
    }


def warm_up() -> float:
    """Seconds of a process that only imports JAX and starts its devices: afterwards the GPU
    libraries are in the OS file cache, as on any machine that ran JAX before (the first process
    on a freshly started machine reads them from disk, a few seconds more)."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import jax; jax.devices()"], check=True)
    return time.perf_counter() - t0


def _timeline(folder: Path) -> dict | None:
    """The ``timeline`` a command kept in its folder (study.json's, else summary.json's), if any."""
    for name in ("study.json", "summary.json"):
        if (folder / name).is_file():
            return json.loads((folder / name).read_text()).get("timeline")
    return None


def builds_record(out: Path, seeds: int, builds: list[Path], repeats: int, command: list[str] | None = None,
                  cached_repeats: int = 1) -> dict:
    """A comparison on one machine of source trees (`git worktree` checkouts or `git archive`
    exports of commits, each put first on PYTHONPATH): the plain grid command (or `command`, the
    arguments of another jaxeac command, without --out) with an empty compilation cache, the
    builds taking turns, `repeats` rounds, then `cached_repeats` rounds with each build's cache
    (``cached``: the first; ``cached_runs``: all, where more than one)."""
    base = command or ["grid", "--preset", "paper", "--seeds", str(seeds), "--quiet"]
    rows = {str(b): {"first_runs": []} for b in builds}
    caches = {}
    for r in range(repeats):
        for i, build in enumerate(builds):
            caches[i] = out / f"xla_cache_build{i}_{r}"
            shutil.rmtree(caches[i], ignore_errors=True)
            env = {"PYTHONPATH": str(build.resolve()), "JAXEAC_COMPILATION_CACHE": str(caches[i])}
            folder = out / f"build{i}"
            shutil.rmtree(folder, ignore_errors=True)  # a first run (a study would reuse its tasks)
            rows[str(build)]["first_runs"].append(jaxeac([*base, "--out", str(folder)], env))
            timeline = _timeline(folder)
            if timeline is not None:
                rows[str(build)]["first_runs"][-1]["timeline"] = timeline
            print(json.dumps({k: v for k, v in rows[str(build)]["first_runs"][-1].items() if k != "timeline"}),
                  flush=True)
    for _ in range(cached_repeats):
        for i, build in enumerate(builds):
            env = {"PYTHONPATH": str(build.resolve()), "JAXEAC_COMPILATION_CACHE": str(caches[i])}
            row = rows[str(build)]
            row.setdefault("cached_runs", []).append(jaxeac([*base, "--out", str(out / f"build{i}")], env))
            row["cached"] = row["cached_runs"][0]
            print(json.dumps({"cached": row["cached_runs"][-1]}), flush=True)
    for row in rows.values():
        if cached_repeats == 1:
            row.pop("cached_runs", None)
    return {"seeds": seeds, "command": " ".join(["jaxeac", *base]), "builds": rows}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("runs/e2e"))
    p.add_argument("--only", nargs="+", choices=["grid", "sweep", "bowling", "sequential"])
    p.add_argument("--grid-seeds", type=int, nargs="+", default=[10_000])
    p.add_argument("--plain-only", action="store_true",
                   help="grid: only the plain command (no split run, no separate compare)")
    p.add_argument("--record", type=Path, help="write the JSON record here (default OUT/timings.json)")
    p.add_argument("--warm-up", action="store_true",
                   help="first start JAX once in a process of its own (`warm_up`), so the first run's time "
                        "is its compiles, not the OS reading the GPU libraries from disk")
    p.add_argument("--builds", type=Path, nargs="+", metavar="DIR",
                   help="grid only: compare these source trees on one machine, taking turns (`builds_record`)")
    p.add_argument("--repeats", type=int, default=3, help="--builds: rounds of first runs")
    p.add_argument("--cached-repeats", type=int, default=1,
                   help="--builds: rounds with each build's compilation cache, after the first runs")
    p.add_argument("--builds-command", metavar="ARGS",
                   help="--builds: time `jaxeac ARGS --out DIR` instead of the grid command (e.g. 'run --env "
                        "FourRooms-stochastic-v0 --seeds 10000 --quiet')")
    args = p.parse_args()
    if args.cached_repeats < 1 or args.repeats < 1:
        p.error("--repeats and --cached-repeats must be at least 1")
    args.out.mkdir(parents=True, exist_ok=True)
    record = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                          "python": platform.python_version()},
              "command": " ".join(["python", *sys.argv]), "grid": []}
    if args.warm_up:
        record["warm_up_s"] = warm_up()
    if args.builds:
        command = args.builds_command.split() if args.builds_command else None
        record["grid"] = [builds_record(args.out, n, args.builds, args.repeats, command, args.cached_repeats)
                          for n in (args.grid_seeds if command is None else [None])]
        (args.record or args.out / "timings.json").write_text(json.dumps(record, indent=2) + "\n")
        return
    wanted = set(args.only or ["grid", "sweep", "bowling", "sequential"])
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
    if "sequential" in wanted:  # the paper preset decided sequentially, with and without the report,
        # every program compiled (no compilation cache): what a first run pays
        base = ["grid", "--preset", "paper", "--seeds", "1000", "--sequential", "--effect", "5",
                "--looks", "10", "--quiet"]
        record["sequential"] = []
        for extra in (["--no-compare"], []):
            folder = args.out / ("sequential" + "".join(extra).replace("-", "_"))
            row = jaxeac([*base, *extra, "--out", str(folder)], {"JAXEAC_COMPILATION_CACHE": "off"})
            seq = json.loads((folder / "summary.json").read_text())["sequential"]
            row |= {"decision": seq["decision"], "seeds_used": seq["seeds_used"],
                    "seconds_to_decision": seq["seconds_to_decision"]}
            record["sequential"].append(row)
            print(json.dumps(row), flush=True)
    path = args.record or args.out / "timings.json"
    path.write_text(json.dumps(record, indent=2) + "\n")


if __name__ == "__main__":
    main()
