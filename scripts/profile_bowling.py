"""Where a throw of the sleeping C engine spends its time, step by step (SPEC B7; BENCHMARKS.md).

    python scripts/profile_bowling.py --throws 256 --out scripts/bench_results/cpu_bowling_profile.json

Runs full-rack throws of the benchmark's mix (the 21 default angles with their noise, as
``bench_bowling.py``) on one thread of the C engine, in the engine's blocks of 10 steps, and splits
each throw into three phases, block by block: the rack settling (until every pin is asleep), the
ball rolling alone (the rack asleep) and the contacts (from the block where a pin wakes, touched by
the ball, to the engine's stop). Per phase: steps, microseconds per step (MuJoCo's own timer of
``mj_step``), awake trees, contacts and constraint rows at the blocks' ends. Over all steps,
MuJoCo's own timers per stage of ``mj_step`` (collision, making the constraints, the solver, the
integrator, ...), as shares of the step.

It also measures how much any exact early stop could still gain: for each throw, the first step
after which the throw's outcome no longer changes (the set of pins down, and the float32 poses of
the pins left standing, which the next chance starts from), against the step where the engine's
`settled` check stops it. Throws are checked every 10 steps, as the engine checks.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from jaxeac.envs.bowling import BowlingConfig, angles, initial_pins  # noqa: E402
from jaxeac.envs.bowling import backend_c as bc  # noqa: E402
from jaxeac.envs.bowling.scene import N_PINS, NQ, throw_noise  # noqa: E402
from jaxeac.experiments.common import versions  # noqa: E402
from jaxeac.io import atomic_write_json  # noqa: E402

PHASES = ("settling", "rolling", "contacts")
STAGES = ("POS_KINEMATICS", "POS_INERTIA", "POS_COLLISION", "POS_MAKE", "POS_PROJECT", "VELOCITY",
          "ACTUATION", "CONSTRAINT", "ADVANCE")


def throws(n: int, cfg: BowlingConfig, seed: int = 0):
    """qpos, qvel (float64) of n full-rack throws over the default angles, as the benchmark's."""
    a = np.resize(angles(cfg), n)
    keys = jax.random.split(jax.random.key(seed), n)
    qpos, qvel = bc._prepare_fn(cfg)(initial_pins(n), jnp.asarray(a, jnp.float32), jax.vmap(throw_noise)(keys))
    return np.asarray(qpos, np.float64), np.asarray(qvel, np.float64)


def pins_down(qpos: np.ndarray, cfg: BowlingConfig) -> np.ndarray:
    """bool (10,): the judge's rule (B4), in NumPy: tilted beyond the limit or off the deck."""
    p = qpos[7:NQ].reshape(N_PINS, 7)
    quat = p[:, 3:] / np.linalg.norm(p[:, 3:], axis=1, keepdims=True)
    cos_tilt = 1 - 2 * (quat[:, 1] ** 2 + quat[:, 2] ** 2)
    (x0, x1), half = cfg.scene.deck_x, cfg.scene.deck_half_width
    return (cos_tilt < math.cos(math.radians(cfg.tilt_down_deg))) | (p[:, 0] < x0) | (p[:, 0] > x1) | (
        np.abs(p[:, 1]) > half)


def outcome(qpos: np.ndarray, cfg: BowlingConfig) -> tuple:
    """What a throw hands on: the pins down and the float32 poses of those standing."""
    down = pins_down(qpos, cfg)
    return tuple(down), qpos[7:NQ].reshape(N_PINS, 7)[~down].astype(np.float32).tobytes()


def profile(n: int, cfg: BowlingConfig) -> dict:
    """The phases, the stages and the exact-stop bound over n throws (one thread, step by step)."""
    qpos, qvel = throws(n, cfg)
    eng = bc.CEngine(1, cfg.solver, cfg.scene)
    model, data = eng.model, eng.datas[0]
    phase = {p: {"steps": 0, "seconds": 0.0, "awake": 0, "contacts": 0, "rows": 0} for p in PHASES}
    stages = np.zeros(len(STAGES))
    step_total = 0.0
    stops, finals = [], []
    for i in range(n):
        mujoco.mj_resetData(model, data)
        data.qpos[:] = qpos[i]
        data.qvel[:] = qvel[i]
        rack = data.qpos[7:NQ].reshape(N_PINS, 7)
        rack[np.abs(rack[:, 2] - bc.PIN_CENTRE_Z) < 1e-6, 2] = bc.PIN_REST_Z  # as the engine starts a throw
        in_play = qpos[i][9:NQ:7] < bc.IN_PLAY_Z
        now, stop, seen = "settling", None, []
        for s in range(0, cfg.n_steps, bc.SETTLE_CHECK):  # blocks of steps, as the engine runs them
            block = min(bc.SETTLE_CHECK, cfg.n_steps - s)
            before = data.timer[mujoco.mjtTimer.mjTIMER_STEP].duration
            mujoco.mj_step(model, data, nstep=block)
            dt = data.timer[mujoco.mjtTimer.mjTIMER_STEP].duration - before  # MuJoCo's own clock
            if stop is None:  # the engine's own steps: those of the throw until it stops
                rec = phase[now]  # the block's phase: settling until a block ends with the rack asleep,
                rec["steps"] += block
                rec["seconds"] += dt
                rec["awake"] += block * data.ntree_awake
                rec["contacts"] += block * data.ncon
                rec["rows"] += block * data.nefc
                if now == "settling" and data.ntree_awake == 1:
                    now = "rolling"  # then rolling (only the ball moves) until a pin wakes, touched
                elif now == "rolling" and data.ntree_awake > 1:
                    rec["steps"] -= block  # ... and a block in which a pin woke counts as contacts
                    rec["seconds"] -= dt
                    rec["awake"] -= block * data.ntree_awake
                    rec["contacts"] -= block * data.ncon
                    rec["rows"] -= block * data.nefc
                    now = "contacts"
                    for key, value in (("steps", block), ("seconds", dt), ("awake", block * data.ntree_awake),
                                       ("contacts", block * data.ncon), ("rows", block * data.nefc)):
                        phase[now][key] += value
            seen.append(outcome(data.qpos, cfg))
            if stop is None and bc.settled(data, in_play, eng.reach):
                stop = s + block
                stages += [data.timer[getattr(mujoco.mjtTimer, f"mjTIMER_{k}")].duration for k in STAGES]
                step_total += data.timer[mujoco.mjtTimer.mjTIMER_STEP].duration
        if stop is None:
            stop = cfg.n_steps
            stages += [data.timer[getattr(mujoco.mjtTimer, f"mjTIMER_{k}")].duration for k in STAGES]
            step_total += data.timer[mujoco.mjtTimer.mjTIMER_STEP].duration
        final = len(seen)
        while final > 1 and seen[final - 2] == seen[-1]:
            final -= 1
        stops.append(stop)
        finals.append(final * bc.SETTLE_CHECK)
    steps = sum(r["steps"] for r in phase.values())
    seconds = sum(r["seconds"] for r in phase.values())
    return {
        "throws": n,
        "throws_per_s_one_thread_in_mj_step": n / seconds,
        "steps_per_throw": steps / n,
        "phases": {p: {"share_of_time": r["seconds"] / seconds, "steps_per_throw": r["steps"] / n,
                       "us_per_step": 1e6 * r["seconds"] / max(r["steps"], 1),
                       "awake_trees": r["awake"] / max(r["steps"], 1),
                       "contacts": r["contacts"] / max(r["steps"], 1),
                       "constraint_rows": r["rows"] / max(r["steps"], 1)} for p, r in phase.items()},
        "stages_share_of_step": {k.lower(): float(v / step_total) for k, v in zip(STAGES, stages, strict=True)},
        "settled_stop_step_mean": float(np.mean(stops)),
        "outcome_final_step_mean": float(np.mean(finals)),
        "outcome_final_at_end_share": float(np.mean(np.asarray(finals) >= cfg.n_steps)),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--throws", type=int, default=256)
    p.add_argument("--out", type=Path, default=None, help="write the JSON record here")
    args = p.parse_args(argv)
    if args.throws < 1:
        p.error(f"--throws {args.throws}: give at least 1")
    if args.out is not None and not args.out.parent.is_dir():
        p.error(f"--out {args.out}: folder {args.out.parent} does not exist; create it or choose another")
    cfg = BowlingConfig()
    record = {
        "command": " ".join(["python", "scripts/profile_bowling.py", *(sys.argv[1:] if argv is None else argv)]),
        "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count()},
        "versions": versions(),
        **profile(args.throws, cfg),
    }
    print(json.dumps(record, indent=2))
    if args.out is not None:
        atomic_write_json(args.out, record)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
