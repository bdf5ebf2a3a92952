"""One throw interface over the physics backends (SPEC B2-B4, B7).

``throw(pins, angle, key_or_noise, backend="c"|"mjx"|"warp")`` runs a batch of throws:
the noise draw (B3) comes from ``jax.random`` in every backend, so the same key
gives the same noisy throw parameters on each engine; only the physics differs.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxeac.errors import UsageError

from . import backend_c, backend_mjx
from .scene import (
    MJX_IMPL,
    N_PINS,
    BowlingConfig,
    PinState,
    ThrowResult,
    as_keys,
    batch_noise,
    check_angles,
    check_backend,
)

DEFAULT_CONFIG = BowlingConfig()


def _check_pins(pins: PinState) -> tuple[PinState, bool]:
    """Pins with a batch axis, and whether one was added; UsageError on bad shapes."""
    if not isinstance(pins, PinState):
        raise UsageError(f"pins is a {type(pins).__name__}: pass a PinState (see initial_pins)")
    qpos, standing = jnp.asarray(pins.qpos), jnp.asarray(pins.standing)
    unbatched = standing.ndim == 1
    if unbatched:
        qpos, standing = qpos[None], standing[None]
    if standing.ndim != 2 or standing.shape[1] != N_PINS or qpos.shape != (
        standing.shape[0],
        N_PINS,
        7,
    ):
        raise UsageError(
            f"pins of shapes qpos {tuple(qpos.shape)}, standing {tuple(standing.shape)}: "
            "need (B, 10, 7) and (B, 10)"
        )
    return PinState(qpos=qpos.astype(jnp.float32), standing=standing.astype(bool)), unbatched


def throw(
    pins: PinState,
    angle,
    key_or_noise,
    *,
    backend: str = "c",
    record_trajectory: bool = False,
    cfg: BowlingConfig = DEFAULT_CONFIG,
) -> ThrowResult:
    """Throw a batch of balls at pins (B, ...) with angles (B,) or one angle; noise from a key.

    key_or_noise: one PRNG key (split into B), B keys, or standard normals (B, 2)
    [angle, speed] scaled by cfg.noise_angle / cfg.noise_speed (B3).
    """
    backend = check_backend(backend)  # "auto": the engine B7 picks here
    pins, unbatched = _check_pins(pins)
    batch = pins.standing.shape[0]
    a = check_angles(angle, cfg)
    if a.ndim == 0:
        a = np.full(batch, float(a))
    if a.shape != (batch,):
        raise UsageError(f"angle of shape {a.shape} for {batch} throws: pass one angle or {batch}")
    keys = as_keys(key_or_noise, batch)
    if backend == "c":
        eps = batch_noise(key_or_noise, batch)
        res = backend_c.throw_c(pins, a, eps, cfg, record_trajectory)
    elif keys is not None:  # the pure batch function, jitted (B7)
        fn = backend_mjx.batched_throw(cfg, record_trajectory, backend_mjx.check_impl(MJX_IMPL[backend]))
        res = fn(pins, jnp.asarray(a, jnp.float32), keys)
    else:
        fn = backend_mjx.batched_throw_eps(cfg, record_trajectory, backend_mjx.check_impl(MJX_IMPL[backend]))
        res = fn(pins, jnp.asarray(a, jnp.float32), batch_noise(key_or_noise, batch))
    if unbatched:
        res = jax.tree_util.tree_map(lambda x: x[0], res)
    return res
