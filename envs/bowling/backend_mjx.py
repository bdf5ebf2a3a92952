"""MJX bowling backend: the same MJCF stepped by MuJoCo XLA, jit + vmap (SPEC B7).

``make_mjx_throw(cfg)`` loads the model once (``mjx.put_model``) and returns a
pure, jittable ``throw_fn(pins, angle, key) -> ThrowResult`` for ONE throw: noise
draw (B3), initial state (B2, B4), ``lax.scan`` over ``mjx.step`` for
``cfg.n_steps`` steps, judging (B4). A learning agent can vmap it over seeds and
put it inside its own jit-compiled run. ``batched_throw(cfg)`` is jit(vmap(...))
of exactly that function over a leading batch axis, as used by
``envs.bowling.throw`` when given keys.

On CPU MJX is 8-30x slower than the C engine (see the measurement notes); it is
meant for accelerators. Compile takes 6-18 s per batch shape on a 2-core CPU.
"""

from __future__ import annotations

import contextlib
import functools
import io

import jax
import jax.numpy as jnp

with contextlib.redirect_stdout(io.StringIO()):  # MJX prints "Failed to import warp" (optional GPU path)
    from mujoco import mjx

from .backend_c import load_model
from .scene import (
    DEFAULT_SOLVER,
    BowlingConfig,
    PinState,
    SolverSettings,
    ThrowResult,
    Trajectory,
    judge_throw,
    throw_noise,
    throw_start,
)


@functools.lru_cache(maxsize=4)
def mjx_model(solver: SolverSettings = DEFAULT_SOLVER) -> tuple[mjx.Model, mjx.Data]:
    """The bowling model (these solver settings) on the JAX device, and a blank Data to start from."""
    mx = mjx.put_model(load_model(solver))
    return mx, mjx.make_data(mx)


def _step(d: mjx.Data, _, mx: mjx.Model) -> tuple[mjx.Data, None]:
    """One physics step (scan body)."""
    return mjx.step(mx, d), None


def _segment(d: mjx.Data, _, mx: mjx.Model, stride: int) -> tuple[mjx.Data, jax.Array]:
    """stride physics steps, then emit qpos (scan body for trajectories)."""
    d, _ = jax.lax.scan(functools.partial(_step, mx=mx), d, None, length=stride)
    return d, d.qpos


def simulate(
    qpos: jax.Array, qvel: jax.Array, n_steps: int, stride: int = 0, solver: SolverSettings = DEFAULT_SOLVER
):
    """Final qpos (77,) after n_steps from (qpos, qvel), and qpos every stride steps (T, 77)."""
    mx, d0 = mjx_model(solver)
    d = d0.replace(qpos=qpos.astype(d0.qpos.dtype), qvel=qvel.astype(d0.qvel.dtype))
    traj = None
    if stride:
        d, traj = jax.lax.scan(
            functools.partial(_segment, mx=mx, stride=stride), d, None, length=n_steps // stride
        )
        rest = n_steps - stride * (n_steps // stride)
    else:
        rest = n_steps
    if rest:
        d, _ = jax.lax.scan(functools.partial(_step, mx=mx), d, None, length=rest)
    return d.qpos, traj


def throw_eps(
    pins: PinState, angle: jax.Array, eps: jax.Array, cfg: BowlingConfig, record: bool = False
) -> ThrowResult:
    """One MJX throw from a given standard-normal noise draw eps (2,) (B2-B4)."""
    qpos, qvel = throw_start(pins, jnp.asarray(angle, jnp.float32), eps, cfg)
    final, traj = simulate(qpos, qvel, cfg.n_steps, cfg.trajectory_stride if record else 0, cfg.solver)
    res = judge_throw(pins, final[7:].reshape(10, 7), cfg)
    if traj is None:
        return res
    trajectory = Trajectory(ball=traj[:, 0:3], pins=traj[:, 7:].reshape(-1, 10, 7)[..., :3])
    return ThrowResult(
        pins_after=res.pins_after,
        knocked=res.knocked,
        standing=res.standing,
        rest_qpos=res.rest_qpos,
        trajectory=trajectory,
    )


def throw_key(
    pins: PinState, angle: jax.Array, key: jax.Array, cfg: BowlingConfig, record: bool = False
) -> ThrowResult:
    """One MJX throw with its noise drawn from key (B3): pure and jittable."""
    return throw_eps(pins, angle, throw_noise(key), cfg, record)


def make_mjx_throw(cfg: BowlingConfig, record_trajectory: bool = False):
    """Pure jittable throw_fn(pins, angle, key) -> ThrowResult for one throw (vmap it to batch)."""
    mjx_model(cfg.solver)  # put the model on the device once, before any tracing
    return functools.partial(throw_key, cfg=cfg, record=record_trajectory)


@functools.lru_cache(maxsize=16)
def batched_throw(cfg: BowlingConfig, record_trajectory: bool = False):
    """jit(vmap(make_mjx_throw(cfg))) over a leading batch axis of (pins, angle, key)."""
    return jax.jit(jax.vmap(make_mjx_throw(cfg, record_trajectory)))


@functools.lru_cache(maxsize=16)
def batched_throw_eps(cfg: BowlingConfig, record_trajectory: bool = False):
    """jit(vmap(throw_eps)) over a leading batch axis of (pins, angle, eps)."""
    mjx_model(cfg.solver)
    return jax.jit(jax.vmap(functools.partial(throw_eps, cfg=cfg, record=record_trajectory)))
