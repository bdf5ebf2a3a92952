"""C-engine bowling backend: MuJoCo's C physics, a batch of throws over worker threads (SPEC B7).

The fast choice on CPUs. Each of ``nthread`` persistent worker threads owns one ``MjData``
and takes the batch's throws one at a time (``mj_step`` releases Python's lock, so the
threads run in parallel); every throw starts from a freshly reset ``MjData``, so its result
does not depend on the thread, the batch or the throws before it (R1).

With ``SolverSettings.sleep`` (the default) MuJoCo puts bodies at rest to sleep, so the
standing pins cost nothing until something touches them, and a throw stops as soon as it is
``settled``: every pin in play asleep and the ball unable to reach any of them. Nothing can
wake a sleeping pin after that, so the pins end exactly where the full-length throw leaves
them (``tests/test_bowling_physics.py`` checks it). ``sleep=False`` runs the full
``n_steps`` of the engine without sleeping, bit for bit as ``mujoco.rollout`` did.

Throw preparation and judging are the same JAX functions as in the MJX backend
(``scene.throw_start`` / ``scene.judge_throw``), so the two backends differ only in the
engine (float64 C vs float32 JAX). Inputs and outputs are numpy.
"""

from __future__ import annotations

import functools
import itertools
import os
import threading
from concurrent.futures import ThreadPoolExecutor

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from .scene import (
    DEFAULT_SCENE,
    DEFAULT_SOLVER,
    N_PINS,
    NQ,
    PIN_CENTRE_Z,
    PIN_RADIUS,
    XML_PATH,
    BowlingConfig,
    PinState,
    Scene,
    SolverSettings,
    ThrowResult,
    Trajectory,
    judge_throw,
    throw_start,
)

SETTLE_CHECK = 10  # steps between two checks of whether a throw has settled
# Centre height of an upright pin at rest on its feet: the soft foot contacts sink it 0.11 mm below
# the MJCF's 0.19 m (measured by letting the rack settle; tests check it). The sleeping engine
# starts a pin placed upright at the nominal height here, so it sleeps after MuJoCo's 10 quiet
# steps instead of settling awake for ~30.
PIN_REST_Z = 0.189886
# A pin in play is a body within this height; removed pins are parked 1000 m up (B4).
IN_PLAY_Z = 10.0
# Steps a rack placed upright may take to fall asleep before a throw may start from it asleep
# (MuJoCo puts a body to sleep after 10 quiet steps; the ball needs ~170 steps to reach the rack).
RACK_SETTLE_STEPS = 40
MAX_RACKS = 8  # racks kept asleep per engine (a bowling run has one: the full rack of its scene)


def reach(scene: Scene) -> float:
    """Centre distance beyond which the ball cannot touch a pin, however the pin lies (ball radius
    plus the pin's half-length and radius), with a margin."""
    return scene.ball_radius + PIN_CENTRE_Z + PIN_RADIUS + 0.05


def load_model(solver: SolverSettings = DEFAULT_SOLVER, scene: Scene = DEFAULT_SCENE) -> mujoco.MjModel:
    """The bowling MjModel from the package's MJCF file (B1), with these solver settings; another
    scene (B1a) resizes the ball and moves the pins before compiling (masses stay, inertia follows)."""
    if scene == DEFAULT_SCENE:
        model = mujoco.MjModel.from_xml_path(str(XML_PATH))
    else:
        spec = mujoco.MjSpec.from_file(str(XML_PATH))
        spec.geom("ball").size[0] = scene.ball_radius
        spec.body("ball").pos[2] = scene.ball_radius
        for i, (x, y) in enumerate(scene.pin_xy()):
            spec.body(f"pin{i + 1}").pos[:2] = (x, y)
        model = spec.compile()
    model.opt.solver = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}[
        solver.method]
    model.opt.iterations = solver.iterations
    model.opt.ls_iterations = solver.ls_iterations
    if solver.sleep:  # the C engine's fast path (SolverSettings.sleep); MJX models load without it
        model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_SLEEP
        model.opt.jacobian = mujoco.mjtJacobian.mjJAC_DENSE  # faster than sparse at 66 dofs, same pins
    # MJX's caps (the C engine ignores them); max_geom_pairs -1 = test every pair
    caps = (("max_contact_points", solver.contact_cap), ("max_geom_pairs", solver.pair_cap or -1))
    for name, value in caps:
        index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, name)
        model.numeric_data[model.numeric_adr[index]] = value
    return model


def floor_park_qpos() -> np.ndarray:
    """qpos (10, 7) of the sleeping engine's parking spots of removed pins (B4): lying at rest on
    the floor 10 m behind the thrower, 1 m apart, where they fall asleep within a few steps and
    touch nothing in play. (The scene's own parking spot, 1000 m up, keeps them falling, awake,
    for the whole throw; both are out of play, so the pins in play move the same.)"""
    q = np.zeros((N_PINS, 7))
    q[:, :3] = np.stack([np.full(N_PINS, -10.0), np.arange(N_PINS) - 4.5, np.full(N_PINS, PIN_RADIUS)], 1)
    q[:, 3:5] = np.sqrt(0.5)  # a quarter turn about x: the pin lies along y
    return q


FLOOR_PARK = floor_park_qpos()


def settled(data: mujoco.MjData, in_play: np.ndarray, reach_m: float) -> bool:
    """Whether nothing can move a pin in play (bool (10,)) any more: every pin in play asleep
    (MuJoCo's sleeping; an awake tree's sleep counter is negative) and the ball either asleep
    too or, on its straight roll over the flat floor, out of reach of every pin in play and
    moving away from it."""
    if data.ntree_awake > 1:  # more than the ball awake (removed pins too: asleep a few steps in)
        return False
    asleep = data.tree_asleep >= 0  # tree 0 is the ball, trees 1..10 the pins (the MJCF's order)
    if not np.all(asleep[1:][in_play]):
        return False
    if asleep[0] or not np.any(in_play):
        return True
    away = data.qpos[7:NQ].reshape(N_PINS, 7)[in_play, :3] - data.qpos[:3]
    moving_away = away @ data.qvel[:3] < 0.0
    out_of_reach = np.einsum("ij,ij->i", away, away) > reach_m**2
    return bool(np.all(moving_away & out_of_reach))


class CEngine:
    """A loaded model and nthread worker threads with one MjData each: runs batches of throws."""

    def __init__(self, nthread: int = 0, solver: SolverSettings = DEFAULT_SOLVER,
                 scene: Scene = DEFAULT_SCENE):
        """Load the model and start nthread worker threads (0: one per CPU core)."""
        self.model = load_model(solver, scene)
        self.reach = reach(scene)
        self.sleep = solver.sleep
        self.floor_park = solver.sleep  # removed pins lie asleep on the floor instead of falling
        self.nthread = nthread or os.cpu_count() or 1
        self.datas = [mujoco.MjData(self.model) for _ in range(self.nthread)]
        self.pool = ThreadPoolExecutor(self.nthread, thread_name_prefix="jaxeac-throws")
        self.steps_run = 0  # physics steps run by the last simulate call, all throws together
        # Racks placed upright fall asleep in the same steps whatever the ball does (each pin is its
        # own island, the ball is metres away), so a throw from one starts from the rack already
        # asleep (`_asleep_rack`): the same state, bit for bit, without its ~10 awake steps.
        self.rack_templates = solver.sleep
        self._racks: dict[bytes, mujoco.MjData | None] = {}  # rack qpos -> the rack asleep (its time: when)
        self._racks_lock = threading.Lock()
        fresh = mujoco.MjData(self.model)
        self._ball_sleep_reset = int(fresh.tree_asleep[0])  # the ball's sleep counter after a reset

    def _asleep_rack(self, data: mujoco.MjData) -> mujoco.MjData | None:
        """`data` (a throw's start, every pin placed upright) stepped until its rack fell asleep,
        made once per rack (at most MAX_RACKS) and shared read-only by the threads; None where
        its pins did not all fall asleep within RACK_SETTLE_STEPS, or where this throw's ball
        could come near a pin before the rack would be asleep."""
        key = data.qpos[7:NQ].tobytes()
        with self._racks_lock:
            if key not in self._racks and len(self._racks) < MAX_RACKS:
                rack = mujoco.MjData(self.model)
                mujoco.mj_copyData(rack, self.model, data)
                for _ in range(RACK_SETTLE_STEPS):
                    mujoco.mj_step(self.model, rack)
                    if np.all(rack.tree_asleep[1:] >= 0):  # trees 1..10 are the pins
                        break
                asleep = np.all(rack.tree_asleep[1:] >= 0) and rack.tree_asleep[0] < 0  # the ball still rolls
                self._racks[key] = rack if asleep else None
            rack = self._racks.get(key)
        if rack is None:
            return None
        # the ball rolls straight at about its start speed: with a margin, where it can be meanwhile
        travel = 2.0 * float(np.linalg.norm(data.qvel[:3])) * rack.time + 0.1
        gap = np.sqrt(np.min(np.sum((data.qpos[7:NQ].reshape(N_PINS, 7)[:, :3] - data.qpos[:3]) ** 2,
                                    axis=1)))
        return rack if gap - travel > self.reach else None

    def _throw(self, data: mujoco.MjData, qpos, qvel, n_steps: int, stride: int, traj, stop: bool) -> int:
        """One throw from a reset MjData; qpos snapshots into traj every stride steps; with stop, it
        ends once `settled`. Returns the steps run."""
        mujoco.mj_resetData(self.model, data)
        data.qpos[:] = qpos
        data.qvel[:] = qvel
        in_play = qpos[9:NQ:7] < IN_PLAY_Z  # z of pins 1..10; removed pins are parked 1000 m up
        if self.floor_park and not stride:  # (a drawn trajectory keeps them out of the picture, 1000 m up)
            data.qpos[7:NQ].reshape(N_PINS, 7)[~in_play] = FLOOR_PARK[~in_play]
        if self.sleep:
            pins = data.qpos[7:NQ].reshape(N_PINS, 7)
            placed = np.abs(pins[:, 2] - PIN_CENTRE_Z) < 1e-6  # placed upright, not yet at rest
            pins[placed, 2] = PIN_REST_Z
            rack = self._asleep_rack(data) if self.rack_templates and not stride and placed.all() else None
            if rack is not None:  # the rack asleep already, the ball at its start
                mujoco.mj_copyData(data, self.model, rack)
                data.time = 0.0
                data.qpos[:7] = qpos[:7]
                data.qvel[:6] = qvel[:6]
                data.qacc_warmstart[:6] = 0.0
                data.tree_asleep[0] = self._ball_sleep_reset
        if stride:
            for k in range(n_steps // stride):
                mujoco.mj_step(self.model, data, nstep=stride)
                traj[k] = data.qpos
            if n_steps % stride:
                mujoco.mj_step(self.model, data, nstep=n_steps % stride)
            return n_steps
        done = 0
        while done < n_steps:
            block = min(SETTLE_CHECK, n_steps - done)
            mujoco.mj_step(self.model, data, nstep=block)
            done += block
            if stop and settled(data, in_play, self.reach):
                break
        return done

    def simulate(self, qpos: np.ndarray, qvel: np.ndarray, n_steps: int, stride: int = 0,
                 stop_when_settled: bool = True):
        """Final qpos (B, 77) and, if stride > 0, qpos every stride steps (B, T, 77). With sleep and
        stop_when_settled, a throw without a trajectory ends once `settled` (the pins in play end
        where its full n_steps leave them); otherwise every throw runs its full n_steps."""
        stop = self.sleep and stop_when_settled and not stride
        batch = qpos.shape[0]
        final = np.empty((batch, NQ))
        traj = np.empty((batch, n_steps // stride, NQ)) if stride else None
        steps = np.zeros(batch, np.int64)
        order = itertools.count()  # throws handed out one at a time (their lengths differ)

        def work(data: mujoco.MjData) -> None:
            while (i := next(order)) < batch:
                steps[i] = self._throw(data, qpos[i], qvel[i], n_steps, stride,
                                       traj[i] if stride else None, stop)
                final[i] = data.qpos

        list(self.pool.map(work, self.datas))
        self.steps_run = int(steps.sum())
        return final, traj

    def close(self) -> None:
        """Stop the worker threads."""
        self.pool.shutdown()


@functools.lru_cache(maxsize=4)
def engine(nthread: int = 0, solver: SolverSettings = DEFAULT_SOLVER,
           scene: Scene = DEFAULT_SCENE) -> CEngine:
    """A cached CEngine for nthread threads, these solver settings and this scene."""
    return CEngine(nthread, solver, scene)


@functools.lru_cache(maxsize=16)
def _prepare_fn(cfg: BowlingConfig):
    """Jitted batched throw_start for cfg."""
    return jax.jit(jax.vmap(functools.partial(throw_start, cfg=cfg)))


@functools.lru_cache(maxsize=16)
def _judge_fn(cfg: BowlingConfig):
    """Jitted batched judge_throw for cfg."""
    return jax.jit(jax.vmap(functools.partial(judge_throw, cfg=cfg)))


def throw_c(
    pins: PinState,
    angle: jax.Array,
    eps: jax.Array,
    cfg: BowlingConfig,
    record_trajectory: bool = False,
) -> ThrowResult:
    """Batched throw on the C engine: pins (B,...), angle (B,), eps (B, 2) -> numpy ThrowResult (B7)."""
    qpos, qvel = _prepare_fn(cfg)(pins, jnp.asarray(angle, jnp.float32), eps)
    eng = engine(cfg.nthread, cfg.solver, cfg.scene)
    stride = cfg.trajectory_stride if record_trajectory else 0
    final, traj = eng.simulate(
        np.asarray(qpos, np.float64), np.asarray(qvel, np.float64), cfg.n_steps, stride
    )
    rest = jnp.asarray(final[:, 7:].reshape(-1, 10, 7), jnp.float32)
    res = _judge_fn(cfg)(pins, rest)
    res = jax.tree_util.tree_map(np.asarray, res)
    if traj is not None:
        res = _with_trajectory(res, traj)
    return res


def _with_trajectory(res: ThrowResult, traj: np.ndarray) -> ThrowResult:
    """res with a Trajectory built from qpos snapshots (B, T, 77)."""
    ball = traj[:, :, 0:3]
    pins = traj[:, :, 7:].reshape(traj.shape[0], traj.shape[1], 10, 7)[..., :3]
    return ThrowResult(
        pins_after=res.pins_after,
        knocked=res.knocked,
        standing=res.standing,
        rest_qpos=res.rest_qpos,
        trajectory=Trajectory(ball=ball, pins=pins),
    )
