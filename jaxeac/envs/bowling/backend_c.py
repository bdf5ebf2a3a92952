"""C-engine bowling backend: MuJoCo's C physics batched with ``mujoco.rollout`` (SPEC B7).

The fast choice on CPUs: the batch of throws is split over ``nthread`` worker
threads (one ``MjData`` each) in a persistent ``mujoco.rollout.Rollout`` pool.
Throw preparation and judging are the same JAX functions as in the MJX backend
(``scene.throw_start`` / ``scene.judge_throw``), so the two backends differ only
in the engine (float64 C vs float32 JAX). Inputs and outputs are numpy.
"""

from __future__ import annotations

import functools
import os

import jax
import jax.numpy as jnp
import mujoco
import mujoco.rollout
import numpy as np

from .scene import (
    DEFAULT_SOLVER,
    NQ,
    NV,
    XML_PATH,
    BowlingConfig,
    PinState,
    SolverSettings,
    ThrowResult,
    Trajectory,
    judge_throw,
    throw_start,
)

_CHUNK = 128  # throws per rollout call: bounds the (chunk, n_steps, nstate) output buffer
_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS


def load_model(solver: SolverSettings = DEFAULT_SOLVER) -> mujoco.MjModel:
    """The bowling MjModel from the package's MJCF file (B1), with these solver settings."""
    model = mujoco.MjModel.from_xml_path(str(XML_PATH))
    model.opt.solver = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}[
        solver.method]
    model.opt.iterations = solver.iterations
    model.opt.ls_iterations = solver.ls_iterations
    # MJX's caps (the C engine ignores them); max_geom_pairs -1 = test every pair
    caps = (("max_contact_points", solver.contact_cap), ("max_geom_pairs", solver.pair_cap or -1))
    for name, value in caps:
        index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, name)
        model.numeric_data[model.numeric_adr[index]] = value
    return model


def _state_offsets(model: mujoco.MjModel) -> tuple[int, int, int]:
    """(nstate, qpos offset, qvel offset) of the full-physics state vector, found by probing."""
    data = mujoco.MjData(model)
    data.qpos[:] = 1000.0 + np.arange(model.nq)
    data.qvel[:] = 5000.0 + np.arange(model.nv)
    nstate = mujoco.mj_stateSize(model, _SPEC)
    state = np.empty(nstate)
    mujoco.mj_getState(model, data, state, _SPEC)
    return nstate, int(np.flatnonzero(state == 1000.0)[0]), int(np.flatnonzero(state == 5000.0)[0])


class CEngine:
    """A loaded model, one MjData per thread and a rollout pool: runs batches of throws."""

    def __init__(self, nthread: int = 0, solver: SolverSettings = DEFAULT_SOLVER):
        """Load the model and start a pool of nthread threads (0: one per CPU core)."""
        self.model = load_model(solver)
        self.nthread = nthread or os.cpu_count() or 1
        self.datas = [mujoco.MjData(self.model) for _ in range(self.nthread)]
        self.pool = mujoco.rollout.Rollout(nthread=self.nthread)
        self.nstate, self.iq, self.iv = _state_offsets(self.model)
        template = np.zeros(self.nstate)
        mujoco.mj_getState(self.model, mujoco.MjData(self.model), template, _SPEC)
        self.template = template

    def simulate(self, qpos: np.ndarray, qvel: np.ndarray, n_steps: int, stride: int = 0):
        """Final qpos (B, 77) and, if stride > 0, qpos every stride steps (B, T, 77)."""
        batch = qpos.shape[0]
        init = np.tile(self.template, (batch, 1))
        init[:, self.iq : self.iq + NQ] = qpos
        init[:, self.iv : self.iv + NV] = qvel
        final = np.empty((batch, NQ))
        traj = np.empty((batch, n_steps // stride, NQ)) if stride else None
        buf = np.empty((min(batch, _CHUNK), n_steps, self.nstate))
        for lo in range(0, batch, _CHUNK):
            hi = min(batch, lo + _CHUNK)
            out = buf[: hi - lo]
            self.pool.rollout(self.model, self.datas, init[lo:hi], nstep=n_steps, state=out)
            final[lo:hi] = out[:, -1, self.iq : self.iq + NQ]
            if stride:
                traj[lo:hi] = out[:, stride - 1 :: stride, self.iq : self.iq + NQ]
        return final, traj

    def close(self) -> None:
        """Stop the thread pool."""
        self.pool.close()


@functools.lru_cache(maxsize=4)
def engine(nthread: int = 0, solver: SolverSettings = DEFAULT_SOLVER) -> CEngine:
    """A cached CEngine for nthread threads and these solver settings."""
    return CEngine(nthread, solver)


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
    eng = engine(cfg.nthread, cfg.solver)
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
