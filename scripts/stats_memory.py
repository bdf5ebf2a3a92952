"""Host memory of `jaxeac grid`'s data path at 10^7 seeds, measured on a CPU without running the agents.

    JAX_PLATFORMS=cpu python scripts/stats_memory.py --seeds 10000000 --out runs/mem

What it measures: the resident memory that `jaxeac grid --preset paper --seeds N` (both
methods, compare report and figures) adds above the process's baseline once the agents have
run: collecting each chunk (`CompactCollector`), writing results.parquet (`ResultsWriter`),
summary.json and the run's figures, then the comparison of the run held in memory
(`compare_run_dir`: per-seed measures, the large-N statistics, the paired analysis,
calibration, report and figures). The same functions `jaxeac grid` calls run in this
process; only the agents' runs are replaced. Their chunks are synthesised from a base of
real seeds of each method run with the library on this CPU (--base seeds, key --key),
drawn with replacement (the same rows for both methods, so the pairing of seed i
stays) with one trial of each drawn seed flipping its outcome, a chunk of --chunk seeds at
a time, as the GPU hands them back. The same arguments give the same folder, byte for byte.

The comparison's device programs (curve sums, calibration halves) keep their data in the
GPU's memory on a GPU, so here they are replaced by host stand-ins of the same output
shapes (sums of independent trials, empty halves) unless --device-programs runs them (on a
CPU their arrays then count as host memory: gigabytes and minutes at 10^7 seeds).

--reload then also compares the folder as `jaxeac compare DIR` does (read back from
results.parquet), in the same process, its peak measured from the RSS it starts at.

Prints a line per phase: (seconds, phase, {VmRSS, VmHWM, RssAnon, RssFile, RssShmem} in GiB),
then one JSON record: the baseline (RSS after the base run, before the first chunk), the
peak (VmHWM) and the peak above the baseline, in GiB.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import memory_timeline as tl  # scripts/: the phase marks and /proc/self/status readings

CHUNK = 1 << 20


def reset_peak() -> None:
    """Make VmHWM the current RSS (Linux: /proc/self/clear_refs)."""
    gc.collect()
    from jaxeac.running.batch import trim_host_memory

    trim_host_memory()
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")


def base_logs(settings) -> dict:
    """{algo: (log int8 [B, T] as a chunk returns it, policy int8 [B, S])} of real seeds 0 … B − 1."""
    import numpy as np

    from jaxeac.experiments.grid import run_grid

    run = run_grid(settings)
    return {a: (np.where(r.success, r.steps, -r.steps).astype(np.int8), r.policy.astype(np.int8))
            for a, r in run.results.items()}


def synthetic_runs(base: dict, seed: int, chunk: int):
    """A stand-in for `run_algorithms`: every chunk of every algorithm (`base`'s, in the run's
    order), drawn from `base`, to the collectors in the order the pipeline hands them back."""
    import numpy as np

    from jaxeac.running.outputs import BatchOutput

    def run_algorithms(env, cfgs, *, root_key, n_seeds, chunk_size=None, progress=None, collectors=None,
                       **_):
        results = []
        with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
            for i, ((log0, policy0), collector) in enumerate(zip(base.values(), collectors, strict=True)):
                t0 = time.perf_counter()
                for start in range(0, n_seeds, chunk):
                    m = min(chunk, n_seeds - start)
                    rows = np.random.default_rng([seed, start]).integers(0, log0.shape[0], m)
                    flip = np.random.default_rng([seed, start, i + 1]).integers(0, log0.shape[1], m)
                    log = log0[rows]
                    log[np.arange(m), flip] *= -1
                    collector.add(start, BatchOutput(log, policy0[rows], np.ones(m, bool)), pool)
                    del log, rows, flip
                    if progress is not None:
                        progress(m)
                out = collector.result()
                out.run_seconds = time.perf_counter() - t0
                out.settings = {"synthetic": f"chunks of {chunk} seeds drawn from {log0.shape[0]} real seeds"}
                results.append(out)
        return results

    return run_algorithms


def host_device_programs() -> None:
    """Replace the comparison's device programs by host stand-ins of the same output shapes."""
    import numpy as np

    from jaxeac.running.outputs import SuccessBits
    from jaxeac.stats import large

    def on_device(c):
        return c  # SuccessBits stay on the host; nothing is copied

    def gram(c, block):
        s = c.column_sums() if isinstance(c, SuccessBits) else np.asarray(c, np.float64).sum(0)
        n = c.shape[0]
        return (np.outer(s, s) / n + np.diag(s - s * s / n)).astype(np.int32), s.astype(np.int32)

    def subset_sums(key, c, need, block, exact, steps=32):
        return np.zeros((need.shape[0], c.shape[1]), np.int32), np.zeros(need.shape, np.uint32)

    large.on_device, large._gram, large._subset_sums = on_device, gram, subset_sums


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=10_000_000, help="seeds per method")
    p.add_argument("--out", type=Path, required=True, help="run folder to write")
    p.add_argument("--base", type=int, default=10_000, help="real seeds per method the chunks are drawn from")
    p.add_argument("--key", type=int, default=0, help="root key of the base run and the draws")
    p.add_argument("--chunk", type=int, default=CHUNK, help="seeds per chunk")
    p.add_argument("--device-programs", action="store_true", help="run the device programs on this CPU")
    p.add_argument("--reload", action="store_true", help="then also compare the folder as read back")
    args = p.parse_args()

    import jaxeac.cli as cli

    cli.configure_xla("compare")
    import jax

    jax.devices()
    import jaxeac.experiments.grid as grid
    import jaxeac.running.outputs as outputs
    import jaxeac.stats.run as stats_run
    from jaxeac.experiments.results import OutputOptions

    settings = grid.GridSettings(preset="paper", seeds=args.base, key=args.key).resolved()
    base = base_logs(settings)
    tl.mark(f"base run of {args.base} seeds per method")
    grid.run_algorithms = synthetic_runs(base, args.key, args.chunk)
    if not args.device_programs:
        host_device_programs()
    add = outputs.CompactCollector.add
    chunks = -(-args.seeds // args.chunk)

    def add_marked(self, start, chunk, pool):
        add(self, start, chunk, pool)
        if start // args.chunk in (0, chunks - 1):
            tl.mark(f"chunk {start} collected and written")

    outputs.CompactCollector.add = add_marked
    for name in ("per_seed_measures", "per_seed_codes", "_analyse", "calibrate", "write_figures"):
        if hasattr(stats_run, name):
            tl.wrap(stats_run, name)
    tl.wrap(grid, "_finish_folder", "summary and figures")
    reset_peak()
    baseline = tl.memory()["VmRSS"]
    tl.mark("baseline")
    settings = grid.GridSettings(preset="paper", seeds=args.seeds, key=args.key).resolved()
    run, summary = grid.run_grid_to_folder(settings, args.out, options=OutputOptions.auto(args.seeds))
    print(grid.summary_table(summary))
    cli._compare_grid(run, args.out, compare=True, quiet=True)
    end = tl.memory()
    tl.mark("end")
    record = {"seeds_per_method": args.seeds, "device_programs": args.device_programs,
              "baseline_gib": baseline, "peak_gib": end["VmHWM"],
              "peak_above_baseline_gib": round(end["VmHWM"] - baseline, 2)}
    if args.reload:
        del run, summary
        reset_peak()
        start = tl.memory()["VmRSS"]
        tl.mark("compare DIR: start")
        stats_run.compare_run_dir(args.out, progress=False)
        peak = tl.memory()["VmHWM"]
        tl.mark("compare DIR: end")
        record["compare_dir"] = {"start_gib": start, "peak_gib": peak,
                                 "peak_above_start_gib": round(peak - start, 2)}
    print(json.dumps(record), flush=True)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    raise SystemExit(main())
