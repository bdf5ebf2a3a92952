"""Benchmark the bowling physics backends (SPEC B7): throws/s and physics steps/s.

C engine (``mujoco.rollout``, nthread = CPU count) and MJX (jit + vmap, on
whatever device JAX uses: CPU here, GPU elsewhere). Compile seconds are kept
apart from run seconds. Throws are a mix of the 21 default angles with the
default noise, from a full rack, so hits and misses are both in the batch.

    python scripts/bench_bowling.py --out bench_cpu.json
    python scripts/bench_bowling.py --backends mjx --mjx-batches 1024 4096 16384 65536 --out gpu.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from envs.bowling import (  # noqa: E402
    BowlingConfig,
    angles,
    backend_mjx,  # noqa: E402
    initial_pins,
    throw,
)


def _inputs(batch: int, cfg: BowlingConfig, seed: int):
    """Full racks, angles cycling over the K default angles, and per-throw keys."""
    a = np.resize(angles(cfg), batch)
    keys = jax.random.split(jax.random.key(seed), batch)
    return initial_pins(batch), a, keys


def bench_c(batch: int, cfg: BowlingConfig, repeats: int) -> dict:
    """Time the C backend on one batch size (after a warm-up call)."""
    pins, a, keys = _inputs(batch, cfg, 0)
    t0 = time.perf_counter()
    throw(initial_pins(8), np.resize(a, 8), jax.random.split(keys[0], 8), cfg=cfg)  # warm-up
    setup = time.perf_counter() - t0
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = throw(pins, a, keys, backend="c", cfg=cfg)
        best = min(best, time.perf_counter() - t0)
    return {
        "backend": "c",
        "batch": batch,
        "nthread": cfg.nthread or os.cpu_count(),
        "setup_s": setup,
        "run_s": best,
        "throws_per_s": batch / best,
        "steps_per_s": batch * cfg.n_steps / best,
        "mean_knocked": float(np.mean(res.knocked)),
    }


def bench_mjx(batch: int, cfg: BowlingConfig, repeats: int) -> dict:
    """Compile and time the MJX backend on one batch size."""
    pins, a, keys = _inputs(batch, cfg, 0)
    fn = backend_mjx.batched_throw(cfg)
    args = (pins, jnp.asarray(a, jnp.float32), keys)
    t0 = time.perf_counter()
    compiled = fn.lower(*args).compile()
    compile_s = time.perf_counter() - t0
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = jax.block_until_ready(compiled(*args))
        best = min(best, time.perf_counter() - t0)
    return {
        "backend": "mjx",
        "batch": batch,
        "device": str(jax.devices()[0]),
        "compile_s": compile_s,
        "run_s": best,
        "throws_per_s": batch / best,
        "steps_per_s": batch * cfg.n_steps / best,
        "mean_knocked": float(np.mean(np.asarray(res.knocked))),
    }


def saturation(rows: list[dict]) -> int | None:
    """Smallest batch after which throws/s grows by less than 10 %."""
    rows = sorted(rows, key=lambda r: r["batch"])
    for prev, nxt in zip(rows, rows[1:], strict=False):
        if nxt["throws_per_s"] < 1.1 * prev["throws_per_s"]:
            return prev["batch"]
    return rows[-1]["batch"] if rows else None


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and write the JSON report."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--backends", nargs="+", default=["c", "mjx"], choices=["c", "mjx"])
    p.add_argument("--c-batches", nargs="+", type=int, default=[64, 256, 1024])
    p.add_argument("--mjx-batches", nargs="+", type=int, default=None,
                   help="default: 16 64 256 on CPU, 1024 4096 16384 65536 on GPU")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--nthread", type=int, default=0, help="C threads (0 = CPU count)")
    p.add_argument("--out", type=Path, default=None, help="write the JSON report here")
    args = p.parse_args(argv)

    cfg = BowlingConfig(nthread=args.nthread)
    on_cpu = jax.devices()[0].platform == "cpu"
    mjx_batches = args.mjx_batches or ([16, 64, 256] if on_cpu else [1024, 4096, 16384, 65536])
    report = {
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(),
            "loadavg_at_start": os.getloadavg(),
            "jax_devices": [str(d) for d in jax.devices()],
        },
        "versions": {
            "python": platform.python_version(),
            "jax": jax.__version__,
            "mujoco": mujoco.__version__,
            "numpy": np.__version__,
        },
        "config": {"n_steps": cfg.n_steps, "timestep_s": 0.005, "n_angles": cfg.n_angles,
                   "theta_max": cfg.theta_max},
        "results": [],
    }
    try:
        import importlib.metadata as md

        report["versions"]["mujoco_mjx"] = md.version("mujoco-mjx")
        report["versions"]["jaxlib"] = md.version("jaxlib")
    except Exception:  # metadata missing in odd installs: the report still stands
        pass
    for name in args.backends:
        batches = args.c_batches if name == "c" else mjx_batches
        rows = []
        for b in batches:
            row = bench_c(b, cfg, args.repeats) if name == "c" else bench_mjx(b, cfg, args.repeats)
            rows.append(row)
            print(json.dumps(row), flush=True)
        report["results"].extend(rows)
        report[f"{name}_saturates_at_batch"] = saturation(rows)
    report["machine"]["loadavg_at_end"] = os.getloadavg()
    if args.out:
        args.out.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
