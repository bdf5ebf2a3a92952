"""Where a `jaxeac` command's time and host memory go, phase by phase, in one process.

    python scripts/memory_timeline.py grid --preset paper --seeds 10000000 --quiet --out runs/t

Runs the command in this process (the same code as ``jaxeac ...``) and prints a line at
each phase: JAX and its devices ready, imports done, each program compiled, each chunk
back and collected, the statistics' pieces, the figures, the end. Each line holds the
seconds since start and the process's resident memory from /proc/self/status (Linux):
VmRSS, its peak VmHWM, and its parts RssAnon (heap), RssFile (mapped files, e.g. the CUDA
libraries) and RssShmem. Lines ('rss', seconds, GiB) mark every 0.5 GiB of growth of the
peak (``MEMORY_TIMELINE_STEP=0.1`` for finer marks). With ``MEMORY_TIMELINE_COMPILES=1``, a line
for each program JAX traces, lowers and compiles: the phase, the function, its seconds and the
thread (JAX's own compile events), to see which compiles a first run waits on.
"""

from __future__ import annotations

import os
import sys
import threading
import time

T0 = time.perf_counter()
FIELDS = ("VmRSS", "VmHWM", "RssAnon", "RssFile", "RssShmem")


def memory() -> dict:
    out = {}
    with open("/proc/self/status") as fh:
        for line in fh:
            key = line.split(":")[0]
            if key in FIELDS:
                out[key] = round(int(line.split()[1]) / 2**20, 2)
    return out


def mark(name: str) -> None:
    print((round(time.perf_counter() - T0, 2), name, memory()), flush=True)


def wrap(owner, name: str, label: str | None = None) -> None:
    """Mark the start and end of every call of owner.name."""
    f = getattr(owner, name)

    def marked(*args, **kwargs):
        mark(f"{label or name} start")
        out = f(*args, **kwargs)
        mark(f"{label or name} end")
        return out

    setattr(owner, name, marked)


def main() -> int:
    import jaxeac.cli as cli

    cli.configure_xla(sys.argv[1] if len(sys.argv) > 1 else None)
    import jax

    if os.environ.get("MEMORY_TIMELINE_COMPILES") == "1":
        import jax.monitoring

        def compile_event(event: str, seconds: float, **meta) -> None:
            if event.startswith("/jax/core/compile/"):
                phase = event.rsplit("/", 1)[-1].removesuffix("_duration")
                print((round(time.perf_counter() - T0, 2), phase, meta.get("fun_name"), round(seconds, 3),
                       threading.current_thread().name), flush=True)

        jax.monitoring.register_event_duration_secs_listener(compile_event)
    jax.devices()
    mark("jax and devices")
    import jaxeac.experiments.grid as grid
    import jaxeac.running.batch as batch
    import jaxeac.running.outputs as outputs
    import jaxeac.stats.large as large
    import jaxeac.stats.run as stats_run

    mark("imports")
    compiled = batch._compiled

    def compiled_marked(*args, **kwargs):
        out = compiled(*args, **kwargs)
        mark("program compiled")
        return out

    batch._compiled = compiled_marked
    add = outputs.CompactCollector.add

    def add_marked(self, start, chunk, pool):
        mark(f"chunk {start} back")
        add(self, start, chunk, pool)
        mark(f"chunk {start} collected")

    outputs.CompactCollector.add = add_marked
    for name in ("per_seed_measures", "_analyse", "calibrate", "write_figures"):
        wrap(stats_run, name)
    for name in ("diagnose_grid", "_finish_folder"):  # E8 beside the run (GPUs); the run's folder
        wrap(grid, name)
    wrap(large, "compile_ahead")  # the comparison's programs, compiled while the run computes (GPUs)
    step = float(os.environ.get("MEMORY_TIMELINE_STEP", "0.5"))

    def sample() -> None:
        peak = 0.0
        while True:
            rss = memory()["VmRSS"]
            if rss > peak + step:
                peak = rss
                print(("rss", round(time.perf_counter() - T0, 2), rss), flush=True)
            time.sleep(0.05)

    threading.Thread(target=sample, daemon=True).start()
    code = cli.main(sys.argv[1:])
    mark("end")
    return code


if __name__ == "__main__":
    from jaxeac.__main__ import _end

    _end(main())  # as the command ends (no interpreter teardown)
