"""MJX bowling backends: the same MJCF stepped by MuJoCo XLA, jit + vmap (SPEC B7).

MJX offers two implementations of the physics behind one API, both offered here:

* ``jax`` (backend ``mjx``): MuJoCo written in JAX; runs on any JAX device.
* ``warp`` (backend ``warp``): MJX with its Warp implementation (MuJoCo Warp
  kernels called from JAX); made for NVIDIA GPUs (it also runs, slowly, on CPUs);
  needs ``warp-lang`` (``pip install "jaxeac[warp]"``). Its contact and constraint
  arrays are allotted up front for the whole batch; here they are sized at the
  scene's hard bounds (``WARP_CONTACTS``, ``WARP_ROWS``: capsule-capsule and
  capsule-plane pairs give at most 2 contacts, the others 1), so no contact can
  ever be dropped.

``make_batch_throw(cfg, impl)`` returns a pure, jittable
``throw_fn(pins [B], angle [B], key [B]) -> ThrowResult [B]``: noise draw (B3),
initial state (B2, B4), ``lax.scan`` over the batched ``mjx.step`` for
``cfg.n_steps`` steps, judging (B4). A learning agent calls it inside its own
jit-compiled run. ``make_mjx_throw(cfg)`` is the per-throw function of the ``jax``
implementation (vmap it to batch). ``batched_throw(cfg, impl=...)`` is the jitted
batch function, as used by ``envs.bowling.throw``.

On CPU MJX is 8-30x slower than the C engine (see the measurement notes); it is
meant for accelerators. Compile takes 6-18 s per batch shape on a 2-core CPU.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import io

import jax
import jax.numpy as jnp

with contextlib.redirect_stdout(io.StringIO()):  # MJX prints "Failed to import warp" without warp-lang
    from mujoco import mjx
    from mujoco.mjx import warp as _mjx_warp

from .backend_c import load_model
from .engines import IMPLS, check_impl  # noqa: F401  (IMPLS, check_impl: re-exported)
from .scene import (
    DEFAULT_SCENE,
    DEFAULT_SOLVER,
    BowlingConfig,
    PinState,
    Scene,
    SolverSettings,
    ThrowResult,
    Trajectory,
    judge_throw,
    throw_noise,
    throw_start,
)

# Hard bounds of the scene's contacts, from its explicit pair list (xmls/bowling.xml):
# ball-floor 1, ball-pin 10 x 1, pin-floor 10 x 2 (capsule-plane), foot-floor 30 x 1,
# pin-pin 45 x 2 (capsule-capsule) = 151 contacts; rows: 121 condim-3 contacts x 4
# (pyramidal cone) + 30 condim-1 feet = 514. Sized so, Warp never overflows.
WARP_CONTACTS = 151
WARP_ROWS = 514


def _engine_model(solver: SolverSettings, scene: Scene):
    """The MjModel MJX runs: the solver settings without the C engine's sleeping (B7), the scene."""
    return load_model(dataclasses.replace(solver, sleep=False), scene)


def mjx_model(solver: SolverSettings = DEFAULT_SOLVER, impl: str = "jax",
              scene: Scene = DEFAULT_SCENE) -> mjx.Model:
    """The bowling model (these solver settings, this scene) on the JAX device, in MJX implementation impl."""
    return _put_model(solver, check_impl(impl), scene)


@functools.lru_cache(maxsize=8)
def _put_model(solver: SolverSettings, impl: str, scene: Scene) -> mjx.Model:
    """One device copy per (solver, impl), however the caller spelt the arguments.

    Warp prints a line from the GPU whenever a step uses all its solver or line-search
    iterations. Those counts are chosen caps (B7), as in the C engine, which stays quiet, so
    those two warnings are off; every warning of a real overflow (contacts, rows) stays on.
    Warp's per-module load messages are silenced too (log level at least warnings).
    """
    if impl == "warp":
        wp = _mjx_warp.warp
        wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)
    mx = mjx.put_model(_engine_model(solver, scene), impl=impl)
    if impl == "warp":
        flags = _mjx_warp.mjwp_types.OverflowType
        opt = mx.opt._impl.replace(
            warn_overflow=int(mx.opt._impl.warn_overflow) & ~int(flags.ITERATIONS | flags.LS_ITERATIONS))
        mx = mx.replace(opt=mx.opt.replace(_impl=opt))
    return mx


def blank_data(batch: int, solver: SolverSettings = DEFAULT_SOLVER, impl: str = "jax",
               scene: Scene = DEFAULT_SCENE) -> mjx.Data:
    """A blank batch of Data [batch] to start throws from, made inside the caller's trace
    (warp: its contact and constraint arrays sized for the batch)."""
    if impl == "jax":
        mx = mjx_model(solver, "jax", scene)
        return jax.vmap(lambda _: mjx.make_data(mx))(jnp.arange(batch))
    m = _engine_model(solver, scene)

    def one(_):
        # naconmax counts the contacts of all worlds together; njmax is per world.
        return mjx.make_data(m, impl="warp", naconmax=WARP_CONTACTS * batch, njmax=WARP_ROWS)

    return jax.vmap(one)(jnp.arange(batch))


def simulate_batch(qpos: jax.Array, qvel: jax.Array, n_steps: int, stride: int = 0,
                   solver: SolverSettings = DEFAULT_SOLVER, impl: str = "jax", scene: Scene = DEFAULT_SCENE):
    """Final qpos [B, 77] after n_steps from (qpos, qvel) [B, ...], and qpos every stride steps [B, T, 77]."""
    mx = mjx_model(solver, impl, scene)
    d = blank_data(qpos.shape[0], solver, impl, scene)
    d = d.replace(qpos=qpos.astype(d.qpos.dtype), qvel=qvel.astype(d.qvel.dtype))
    step = jax.vmap(mjx.step, in_axes=(None, 0))

    def steps(d, length):
        return jax.lax.scan(lambda d, _: (step(mx, d), None), d, None, length=length)[0]

    traj = None
    if stride:
        def segment(d, _):
            d = steps(d, stride)
            return d, d.qpos

        d, traj = jax.lax.scan(segment, d, None, length=n_steps // stride)
        traj = jnp.swapaxes(traj, 0, 1)
    rest = n_steps - stride * (n_steps // stride) if stride else n_steps
    if rest:
        d = steps(d, rest)
    return d.qpos, traj


def throw_batch_eps(pins: PinState, angle: jax.Array, eps: jax.Array, cfg: BowlingConfig,
                    record: bool = False, impl: str = "jax") -> ThrowResult:
    """A batch of throws [B] from given standard-normal noise draws eps [B, 2] (B2-B4)."""
    qpos, qvel = jax.vmap(throw_start, in_axes=(0, 0, 0, None))(pins, jnp.asarray(angle, jnp.float32),
                                                                eps, cfg)
    final, traj = simulate_batch(qpos, qvel, cfg.n_steps, cfg.trajectory_stride if record else 0,
                                 cfg.solver, impl, cfg.scene)
    res = jax.vmap(judge_throw, in_axes=(0, 0, None))(pins, final[:, 7:].reshape(-1, 10, 7), cfg)
    if traj is None:
        return res
    trajectory = Trajectory(ball=traj[..., 0:3], pins=traj[..., 7:].reshape(*traj.shape[:2], 10, 7)[..., :3])
    return ThrowResult(pins_after=res.pins_after, knocked=res.knocked, standing=res.standing,
                       rest_qpos=res.rest_qpos, trajectory=trajectory)


def throw_batch(pins: PinState, angle: jax.Array, key: jax.Array, cfg: BowlingConfig,
                record: bool = False, impl: str = "jax") -> ThrowResult:
    """A batch of throws [B], throw i's noise drawn from key[i] (B3): pure and jittable."""
    return throw_batch_eps(pins, angle, jax.vmap(throw_noise)(key), cfg, record, impl)


def make_batch_throw(cfg: BowlingConfig, record_trajectory: bool = False, impl: str = "jax"):
    """Pure jittable throw_fn(pins [B], angle [B], key [B]) -> ThrowResult [B] in MJX implementation impl."""
    mjx_model(cfg.solver, impl, cfg.scene)  # put the model on the device once, before any tracing
    return functools.partial(throw_batch, cfg=cfg, record=record_trajectory, impl=impl)


def throw_key(pins: PinState, angle: jax.Array, key: jax.Array, cfg: BowlingConfig,
              record: bool = False) -> ThrowResult:
    """One throw (jax implementation) with its noise drawn from key (B3): pure, jittable, vmappable."""
    batch = jax.tree.map(lambda x: x[None], (pins, jnp.asarray(angle, jnp.float32), key))
    return jax.tree.map(lambda x: x[0], throw_batch(*batch, cfg=cfg, record=record))


def make_mjx_throw(cfg: BowlingConfig, record_trajectory: bool = False):
    """Pure jittable throw_fn(pins, angle, key) -> ThrowResult for one throw (vmap it to batch)."""
    mjx_model(cfg.solver, "jax", cfg.scene)
    return functools.partial(throw_key, cfg=cfg, record=record_trajectory)


@functools.lru_cache(maxsize=16)
def batched_throw(cfg: BowlingConfig, record_trajectory: bool = False, impl: str = "jax"):
    """jit(make_batch_throw(cfg)) over a leading batch axis of (pins, angle, key)."""
    return jax.jit(make_batch_throw(cfg, record_trajectory, impl))


@functools.lru_cache(maxsize=16)
def batched_throw_eps(cfg: BowlingConfig, record_trajectory: bool = False, impl: str = "jax"):
    """jit(throw_batch_eps) over a leading batch axis of (pins, angle, eps)."""
    mjx_model(cfg.solver, impl, cfg.scene)
    return jax.jit(functools.partial(throw_batch_eps, cfg=cfg, record=record_trajectory, impl=impl))
