"""Benchmark the bowling physics backends (SPEC B7): throws/s and physics steps/s.

C engine (worker threads, nthread = CPU count; with sleeping pins and throws that end
once settled unless a setting says ``nosleep``), MJX (jit + vmap, on
whatever device JAX uses: CPU here, GPU elsewhere) and MJX with its Warp
implementation (``warp``: NVIDIA GPUs, needs warp-lang). Compile seconds are kept
apart from run seconds. Throws are a mix of the 21 default angles with the
default noise, from a full rack, so hits and misses are both in the batch.

    python scripts/bench_bowling.py --out bench_cpu.json
    python scripts/bench_bowling.py --backends mjx --mjx-batches 1024 4096 16384 65536 --out gpu.json
    python scripts/bench_bowling.py --backends mjx --physics newton:4:8 cg:8:8 cg:6:4:24 --accuracy 2048
    python scripts/bench_bowling.py --backends warp --mjx-batches 4096 16384 65536 --accuracy 2048
    python scripts/bench_bowling.py --backends warp mujoco_warp --mjx-batches 16384 65536 --accuracy 2048

``mujoco_warp`` runs the same throws through the standalone MuJoCo Warp package (not a jaxeac
backend: it steps outside JAX, from captured CUDA graphs), with or without sleeping (``:nosleep``).

``--physics`` lists solver settings (solver:iterations:ls_iterations[:contact_cap[:pair_cap]][:nosleep]);
``--accuracy N`` also scores each setting's pins on the first N throws of its largest
batch against the reference on the same noisy throws: the C engine at 50/50 Newton
iterations, without sleeping, every throw its full length.

    python scripts/bench_bowling.py --backends c --physics newton:4:8 newton:4:8:nosleep --accuracy 1024

``--timesteps DT ...`` runs the C engine's largest batch again with a larger physics step (the
same 2 s in fewer steps), scored against the same reference.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import platform
import sys
import time
from pathlib import Path

# JAX would take 75 % of the GPU at its first allocation and leave Warp's own arrays (the
# standalone package's) too little: it grows as needed instead, as in jaxeac's CLI.
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from jaxeac.envs.bowling import (  # noqa: E402
    BACKENDS,
    BowlingConfig,
    SolverSettings,
    angles,
    backend_c,  # noqa: E402
    backend_mjx,  # noqa: E402
    initial_pins,
    throw,
)
from jaxeac.envs.bowling.scene import MJX_IMPL, check_backend  # noqa: E402
from jaxeac.errors import UsageError  # noqa: E402
from jaxeac.runtime import OPTIONAL_PACKAGES, versions  # noqa: E402


def _inputs(batch: int, cfg: BowlingConfig, seed: int):
    """Full racks, angles cycling over the K default angles, and per-throw keys."""
    a = np.resize(angles(cfg), batch)
    keys = jax.random.split(jax.random.key(seed), batch)
    return initial_pins(batch), a, keys


def bench_c(batch: int, cfg: BowlingConfig, repeats: int, rack_templates: tuple[bool, ...] = (True,)) -> list[dict]:
    """Time the C backend on one batch size (after a warm-up call), a row per setting of
    `rack_templates` (off: every throw from a full rack lets the rack fall asleep itself, the
    engine before its asleep racks), the settings taking turns within each repeat."""
    pins, a, keys = _inputs(batch, cfg, 0)
    eng = backend_c.engine(cfg.nthread, cfg.solver, cfg.scene)
    t0 = time.perf_counter()
    throw(initial_pins(8), np.resize(a, 8), jax.random.split(keys[0], 8), cfg=cfg)  # warm-up
    setup = time.perf_counter() - t0
    best = dict.fromkeys(rack_templates, float("inf"))
    steps, knocked = {}, {}
    for _ in range(repeats):
        for flag in rack_templates:
            eng.rack_templates = flag and cfg.solver.sleep
            t0 = time.perf_counter()
            res = throw(pins, a, keys, backend="c", cfg=cfg)
            best[flag] = min(best[flag], time.perf_counter() - t0)
            steps[flag], knocked[flag] = eng.steps_run, np.asarray(res.knocked)  # each setting's own
    eng.rack_templates = cfg.solver.sleep
    return [{
        "backend": "c",
        "physics": physics_label(cfg),
        "batch": batch,
        "nthread": cfg.nthread or os.cpu_count(),
        "rack_templates": flag and cfg.solver.sleep,
        "setup_s": setup,
        "run_s": best[flag],
        "throws_per_s": batch / best[flag],
        "steps_per_s": batch * cfg.n_steps / best[flag],
        "steps_run_per_throw": steps[flag] / batch,
        "mean_knocked": float(np.mean(knocked[flag])),
        "_knocked": knocked[flag],
    } for flag in rack_templates]


def bench_c_timestep(batch: int, cfg: BowlingConfig, dt: float, repeats: int) -> dict:
    """The C engine with its model's timestep set to dt and the throw's 2 s in round(2 s / dt)
    steps (the package keeps the MJCF file's 5 ms: this measures what a larger step would give)."""
    from jaxeac.envs.bowling.api import batch_noise
    from jaxeac.envs.bowling.scene import TIMESTEP

    pins, a, keys = _inputs(batch, cfg, 0)
    qpos, qvel = backend_c._prepare_fn(cfg)(pins, jnp.asarray(a, jnp.float32), batch_noise(keys, batch))
    qpos, qvel = np.asarray(qpos, np.float64), np.asarray(qvel, np.float64)
    eng = backend_c.CEngine(cfg.nthread, cfg.solver, cfg.scene)
    eng.model.opt.timestep = dt
    steps = round(cfg.n_steps * TIMESTEP / dt)
    best = float("inf")
    try:
        for _ in range(repeats):
            t0 = time.perf_counter()
            final, _ = eng.simulate(qpos, qvel, steps)
            best = min(best, time.perf_counter() - t0)
    finally:
        eng.close()
    rest = jnp.asarray(final[:, 7:].reshape(-1, 10, 7), jnp.float32)
    knocked = np.asarray(backend_c._judge_fn(cfg)(pins, rest).knocked)
    return {
        "backend": "c", "physics": physics_label(cfg) + f":dt={dt:g}", "batch": batch,
        "nthread": cfg.nthread or os.cpu_count(), "timestep_s": dt, "steps_per_throw": steps,
        "run_s": best, "throws_per_s": batch / best, "steps_per_s": batch * steps / best,
        "steps_run_per_throw": eng.steps_run / batch, "mean_knocked": float(np.mean(knocked)),
        "_knocked": knocked,
    }


SPEC_FORMAT = "solver:iterations:ls_iterations[:contact_cap[:pair_cap]][:nosleep]"
#: The accuracy reference: Newton at 50/50 iterations, no sleeping, every throw its full length.
REFERENCE_SOLVER = SolverSettings("newton", 50, 50, sleep=False)


def physics_label(cfg: BowlingConfig) -> str:
    """The --physics spec of cfg's solver settings (the pair cap only where set)."""
    s = cfg.solver
    label = f"{s.method}:{s.iterations}:{s.ls_iterations}:{s.contact_cap}"
    return label + (f":{s.pair_cap}" if s.pair_cap else "") + ("" if s.sleep else ":nosleep")


def parse_physics(spec: str, base: BowlingConfig) -> BowlingConfig:
    """BowlingConfig with the solver settings of a SPEC_FORMAT spec."""
    parts = spec.split(":")
    sleep = parts[-1] != "nosleep"
    parts = parts if sleep else parts[:-1]
    if not 3 <= len(parts) <= 5 or not all(x.isdigit() for x in parts[1:]):
        raise SystemExit(f"error: --physics {spec!r}: use {SPEC_FORMAT}")
    return dataclasses.replace(base, solver=SolverSettings(parts[0], *map(int, parts[1:]), sleep=sleep))


def accuracy(knocked: np.ndarray, batch: int, cfg: BowlingConfig, n: int, reference: dict) -> dict:
    """Pins per throw on the first n throws of a batch against the reference (`REFERENCE_SOLVER`)
    on the same noisy throws (same keys): means, paired difference and its s.e."""
    if "knocked" not in reference or reference["knocked"].size < n:
        ref_cfg = dataclasses.replace(cfg, solver=REFERENCE_SOLVER)
        _, a, keys = _inputs(batch, cfg, 0)  # the batch's own throws: same angles and keys
        res = throw(initial_pins(n), a[:n], keys[:n], backend="c", cfg=ref_cfg)
        reference["knocked"] = np.asarray(res.knocked)
    ref = reference["knocked"][:n].astype(float)
    got = knocked[:n].astype(float)
    diff = got - ref
    return {"accuracy_throws": n, "mean_knocked_first_n": float(got.mean()),
            "reference_mean_knocked": float(ref.mean()), "mean_diff": float(diff.mean()),
            "mean_diff_se": float(diff.std(ddof=1) / np.sqrt(n)), "mean_abs_diff": float(np.abs(diff).mean()),
            "strike_rate": float((got == 10).mean()), "reference_strike_rate": float((ref == 10).mean())}


def _device_row(backend: str, cfg: BowlingConfig, batch: int, device: str, compile_s: float, run_s: float,
                knocked) -> dict:
    """A GPU-style row: one batch's compile and best run seconds, throws/s and pins knocked."""
    knocked = np.asarray(knocked)
    return {
        "backend": backend,
        "physics": physics_label(cfg),
        "batch": batch,
        "device": device,
        "compile_s": compile_s,
        "run_s": run_s,
        "throws_per_s": batch / run_s,
        "steps_per_s": batch * cfg.n_steps / run_s,
        "mean_knocked": float(np.mean(knocked)),
        "_knocked": knocked,
    }


def bench_mjx(batch: int, cfg: BowlingConfig, repeats: int, backend: str = "mjx") -> dict:
    """Compile and time an MJX backend (mjx or warp) on one batch size."""
    pins, a, keys = _inputs(batch, cfg, 0)
    fn = backend_mjx.batched_throw(cfg, impl=MJX_IMPL[backend])
    args = (pins, jnp.asarray(a, jnp.float32), keys)
    t0 = time.perf_counter()
    compiled = fn.lower(*args).compile()
    compile_s = time.perf_counter() - t0
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = jax.block_until_ready(compiled(*args))
        best = min(best, time.perf_counter() - t0)
    return _device_row(backend, cfg, batch, str(jax.devices()[0]), compile_s, best, res.knocked)


#: Throws through the standalone MuJoCo Warp package (`mujoco_warp`; not a jaxeac backend),
#: measured to choose between it and MJX's Warp implementation (backend ``warp``).
STANDALONE_WARP = "mujoco_warp"
#: Steps per captured CUDA graph of the standalone package (a throw launches it n_steps / this times).
GRAPH_STEPS = 50


def bench_mujoco_warp(batch: int, cfg: BowlingConfig, repeats: int) -> dict:
    """The same throws as `bench_mjx` (same inputs and judging) through the standalone MuJoCo
    Warp package: the model as the C engine loads it, with MuJoCo's sleeping when the settings
    keep it (the package's sleeping needs Newton and islands; pins placed upright start at
    their resting height, as in the C engine), contact and row arrays sized as the ``warp``
    backend's, steps replayed from a captured CUDA graph. Compile seconds: model and data on the
    device, the kernels' first step and the capture."""
    import mujoco
    import mujoco_warp as mjw
    import warp as wp

    from jaxeac.envs.bowling.backend_mjx import WARP_CONTACTS, WARP_ROWS
    from jaxeac.envs.bowling.scene import N_PINS, NQ, PIN_CENTRE_Z, throw_noise

    wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)
    pins, a, keys = _inputs(batch, cfg, 0)
    qpos, qvel = backend_c._prepare_fn(cfg)(pins, jnp.asarray(a, jnp.float32), jax.vmap(throw_noise)(keys))
    qpos, qvel = np.array(qpos, np.float32), np.array(qvel, np.float32)
    if cfg.solver.sleep:
        rack = qpos[:, 7:NQ].reshape(batch, N_PINS, 7)
        rack[..., 2] = np.where(np.abs(rack[..., 2] - PIN_CENTRE_Z) < 1e-6, backend_c.PIN_REST_Z, rack[..., 2])
    model = backend_c.load_model(cfg.solver, cfg.scene)
    model.opt.jacobian = mujoco.mjtJacobian.mjJAC_AUTO  # dense is the C engine's CPU choice; Warp: nv <= 60
    t0 = time.perf_counter()
    m = mjw.put_model(model)
    overflow = mjw.OverflowType if hasattr(mjw, "OverflowType") else None
    if overflow is not None:  # the iteration caps are chosen settings (as in the warp backend)
        m.opt.warn_overflow = int(m.opt.warn_overflow) & ~int(overflow.ITERATIONS | overflow.LS_ITERATIONS)
    d = mjw.make_data(model, nworld=batch,
                      naconmax=WARP_CONTACTS * batch, njmax=WARP_ROWS)

    def start():
        mjw.reset_data(m, d)
        d.qpos.assign(qpos)
        d.qvel.assign(qvel)

    start()
    mjw.step(m, d)  # loads the kernels
    with wp.ScopedCapture() as capture:
        for _ in range(GRAPH_STEPS):
            mjw.step(m, d)
    wp.synchronize()
    compile_s = time.perf_counter() - t0
    best = float("inf")
    for _ in range(repeats):
        start()
        wp.synchronize()
        t0 = time.perf_counter()
        for _ in range(cfg.n_steps // GRAPH_STEPS):
            wp.capture_launch(capture.graph)
        for _ in range(cfg.n_steps % GRAPH_STEPS):
            mjw.step(m, d)
        wp.synchronize()
        best = min(best, time.perf_counter() - t0)
    final = d.qpos.numpy()
    res = backend_c._judge_fn(cfg)(pins, jnp.asarray(final[:, 7:].reshape(-1, N_PINS, 7)))
    return _device_row(STANDALONE_WARP, cfg, batch, str(wp.get_device()), compile_s, best, res.knocked)


def command_line(argv: list[str], out: Path | None) -> str:
    """The command as a user would rerun it, writing to scripts/bench_results/<name of --out>."""
    args = list(argv)
    if out is not None:
        for i, a in enumerate(args):
            if a == "--out" and i + 1 < len(args):
                args[i + 1] = f"scripts/bench_results/{out.name}"
            elif a.startswith("--out="):
                args[i] = f"--out=scripts/bench_results/{out.name}"
    return " ".join(["python", "scripts/bench_bowling.py", *args])


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
    p.add_argument("--backends", nargs="+", default=["c", "mjx"], choices=[*BACKENDS, STANDALONE_WARP],
                   help=f"jaxeac's bowling backends, or {STANDALONE_WARP}: the standalone MuJoCo Warp package")
    p.add_argument("--c-batches", nargs="+", type=int, default=[64, 256, 1024])
    p.add_argument("--mjx-batches", nargs="+", type=int, default=None,
                   help="default: 16 64 256 on CPU, 1024 4096 16384 65536 on GPU")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--nthread", type=int, default=0, help="C threads (0 = CPU count)")
    p.add_argument("--physics", nargs="+", default=["newton:4:8"], metavar="SPEC",
                   help=f"solver settings to measure, each {SPEC_FORMAT}")
    p.add_argument("--accuracy", type=int, default=0, metavar="N",
                   help="also compare the first N throws of each setting's largest batch with the C "
                        "engine at 50/50 Newton iterations on the same throws (0: skip)")
    p.add_argument("--timesteps", nargs="+", type=float, default=[], metavar="DT",
                   help="C backend only: also run each setting with the model's timestep DT (s) instead of "
                        "the MJCF file's 0.005, the throw's 2 s in round(2 / DT) steps")
    p.add_argument("--rack-templates", choices=["on", "off", "both"], default="on",
                   help="C engine: throws from a full rack start from it already asleep (on, the engine's "
                        "default), let it fall asleep itself (off), or both, taking turns")
    p.add_argument("--out", type=Path, default=None, help="write the JSON report here")
    args = p.parse_args(argv)
    for name in args.backends:
        try:
            if name == STANDALONE_WARP:
                check_backend("warp")  # the same needs: warp-lang and an NVIDIA GPU
                if importlib.util.find_spec("mujoco_warp") is None:  # MJX brings its own copy, not this
                    raise UsageError("--backends mujoco_warp needs the standalone MuJoCo Warp package: "
                                     "pip install mujoco-warp (its version matching mujoco's)")
                continue
            check_backend(name)
        except UsageError as exc:
            p.error(str(exc))
    if args.out is not None and not args.out.parent.is_dir():
        p.error(f"--out {args.out}: folder {args.out.parent} does not exist; create it or choose another")

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
        "versions": versions(optional=(*OPTIONAL_PACKAGES, "mujoco-warp")),  # where installed
        "config": {"n_steps": cfg.n_steps, "timestep_s": 0.005, "n_angles": cfg.n_angles,
                   "theta_max": cfg.theta_max},
        "commands": [command_line(sys.argv[1:] if argv is None else argv, args.out)],
        "results": [],
    }
    reference: dict = {}
    for spec in args.physics:
        pcfg = parse_physics(spec, cfg)
        for name in args.backends:
            batches = args.c_batches if name == "c" else mjx_batches
            rows = []
            for b in batches:
                if name == "c":
                    flags = {"on": (True,), "off": (False,), "both": (False, True)}[args.rack_templates]
                    rows.extend(bench_c(b, pcfg, args.repeats, flags))
                elif name == STANDALONE_WARP:
                    rows.append(bench_mujoco_warp(b, pcfg, args.repeats))
                else:
                    rows.append(bench_mjx(b, pcfg, args.repeats, name))
            knocked = rows[-1]["_knocked"]
            for row in rows:
                row.pop("_knocked")
                print(json.dumps(row), flush=True)
            if args.accuracy:
                n = min(args.accuracy, rows[-1]["batch"])
                rows[-1].update(accuracy(knocked, rows[-1]["batch"], pcfg, n, reference))
                print(json.dumps({k: v for k, v in rows[-1].items() if "diff" in k or "reference" in k}),
                      flush=True)
            report["results"].extend(rows)
            # over the rows of the engine's default (rack templates on where there are both)
            default_rows = [r for r in rows if r.get("rack_templates", pcfg.solver.sleep) == pcfg.solver.sleep]
            report.setdefault("saturates_at_batch", {})[f"{name} {physics_label(pcfg)}"] = saturation(default_rows)
            for dt in args.timesteps if name == "c" else ():
                row = bench_c_timestep(args.c_batches[-1], pcfg, dt, args.repeats)
                knocked = row.pop("_knocked")
                if args.accuracy:
                    row.update(accuracy(knocked, row["batch"], pcfg, min(args.accuracy, row["batch"]), reference))
                print(json.dumps(row), flush=True)
                report["results"].append(row)
    report["machine"]["loadavg_at_end"] = os.getloadavg()
    if args.out:  # whole file or nothing
        tmp = args.out.with_name(args.out.name + ".tmp")
        tmp.write_text(json.dumps(report, indent=2))
        tmp.replace(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
