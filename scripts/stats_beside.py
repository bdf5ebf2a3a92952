"""The 10^6-seed comparison's statistics alone, or beside a thread or a process that keeps
drawing Matplotlib figures (what `jaxeac grid` does on GPUs while the statistics run), under
a chosen Python switch interval. Run it under different `OPENBLAS_NUM_THREADS` to see NumPy's
BLAS threads compete with the statistics' own (BENCHMARKS.md, *A tenth rental*). Usage::

    python scripts/stats_beside.py --beside thread --switch-interval 0.005
    OPENBLAS_NUM_THREADS=1 python scripts/stats_beside.py --beside thread

Synthetic packed success curves (10^6 seeds × 200 trials per method), one warm-up comparison,
then the timed one; prints its wall time and stats.json's timing pieces above 0.1 s.
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import threading
import time


def draw_figures(stop) -> None:
    """Draw and save small line plots until `stop` is set (a Python-busy neighbour)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    while not stop.is_set():
        fig, ax = plt.subplots()
        ax.plot(np.arange(2000), np.random.default_rng().random(2000))
        fig.savefig("/dev/null", format="png")
        plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--beside", choices=("none", "thread", "process"), default="none")
    ap.add_argument("--switch-interval", type=float, default=0.005, help="sys.setswitchinterval, seconds")
    ap.add_argument("--seeds", type=int, default=1_000_000, help="seeds per method")
    args = ap.parse_args()
    sys.setswitchinterval(args.switch_interval)
    import numpy as np

    from jaxeac.running.outputs import SuccessBits
    from jaxeac.stats.run import compare_experiment

    rng = np.random.default_rng(0)
    trials = 200

    def bits(p):
        return SuccessBits.pack(rng.random((args.seeds, trials), dtype=np.float32) < p)

    sb, st = bits(0.3), bits(0.6)
    compare_experiment(sb, st, paired=True)  # compiles and warms up
    if args.beside == "thread":
        stop = threading.Event()
        neighbour = threading.Thread(target=draw_figures, args=(stop,))
    elif args.beside == "process":
        ctx = multiprocessing.get_context("spawn")
        stop = ctx.Event()
        neighbour = ctx.Process(target=draw_figures, args=(stop,))
    if args.beside != "none":
        neighbour.start()
        time.sleep(1.0)
    t = time.perf_counter()
    stats, _ = compare_experiment(sb, st, paired=True)
    wall = time.perf_counter() - t
    if args.beside != "none":
        stop.set()
        neighbour.join()
    pieces = {k: round(v, 2) for k, v in stats["timing"]["pieces"].items() if v > 0.1}
    print(f"switch interval {args.switch_interval} beside {args.beside}: statistics {wall:.2f} s", pieces)


if __name__ == "__main__":
    main()
