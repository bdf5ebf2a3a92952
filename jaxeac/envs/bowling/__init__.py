"""Bowling for the NAO task, simulated in MuJoCo (SPEC §4, B1-B7).

Scene (B1, ``xmls/bowling.xml``): full-size lane in metres. Ball r 0.11 m, 6 kg,
released rolling at 7 m/s from the arc of radius 0.6 m (the arm) around the
thrower's shoulder axis at the origin, in direction theta. Ten capsule pins
(r 0.06 m, 0.38 m tall, 1.5 kg, three small frictionless foot spheres for a
stable base) in the 1-2-3-4 triangle, 0.30 m apart, head pin 6 m from the
release point (x = 6.6 m). Newton solver 4 iterations / 8 line-search
iterations, 5 ms steps, implicitfast, 400 steps (2 s) per throw; MJX caps
contacts at 32 per condim group.

Action (B2): shoulder angle theta on K = 21 even steps of [-0.1, 0.1] rad;
negative theta -> right side of the deck (y < 0), |theta| >= 0.09 misses every
pin. Noise (B3): Gaussian, s.d. 0.003 rad on theta and 0.1 m/s on speed, drawn
from ``jax.random`` keys so both backends throw the same noisy throws. Pins (B4):
down when tilted > 45 degrees or off the deck; fallen pins are parked out of
play, standing ones stay where they came to rest, the ball returns.

Backends (B7): ``backend="c"`` (MuJoCo C engine batched over threads with
worker threads, pins at rest asleep, each throw ended once settled; the fast
choice on CPU), ``backend="mjx"`` (MJX in JAX, jit +
vmap; ``make_mjx_throw(cfg)`` gives the pure per-throw function for use inside a
jit-compiled learning run) and ``backend="warp"`` (MJX with its Warp
implementation, NVIDIA GPUs, needs warp-lang; ``backend_mjx.make_batch_throw(cfg,
impl=...)`` gives the pure batch function of either MJX implementation).

Public API::

    cfg = BowlingConfig()                       # frozen, validated
    cfg = BowlingConfig(solver=SolverSettings("cg", iterations=12, ls_iterations=4))  # B7
    angles(cfg) -> np.ndarray (K,)
    initial_pins(batch) -> PinState(qpos (B,10,7), standing (B,10))
    throw(pins, angle, key_or_noise, *, backend="c"|"mjx"|"warp", record_trajectory=False, cfg=cfg)
        -> ThrowResult(pins_after, knocked (B,), standing (B,10), rest_qpos, trajectory)
    make_mjx_throw(cfg, record_trajectory=False) -> throw_fn(pins, angle, key)  # one throw
    render_deck(result, path_png, *, index=0, method="auto", title=None) -> method used
    throw_command(angles, backend, render, cfg, *, noise_angle=0, noise_speed=0, seed=0) -> dict
"""

from .api import DEFAULT_CONFIG, throw
from .backend_mjx import make_mjx_throw
from .render import render_deck
from .scene import (
    BACKENDS,
    N_PINS,
    SCENES,
    XML_PATH,
    BowlingConfig,
    PinState,
    Scene,
    SolverSettings,
    ThrowResult,
    Trajectory,
    angles,
    initial_pins,
    throw_noise,
)
from .throw_command import throw_command

__all__ = [
    "BACKENDS",
    "DEFAULT_CONFIG",
    "N_PINS",
    "SCENES",
    "XML_PATH",
    "BowlingConfig",
    "Scene",
    "SolverSettings",
    "PinState",
    "ThrowResult",
    "Trajectory",
    "angles",
    "initial_pins",
    "make_mjx_throw",
    "render_deck",
    "throw",
    "throw_command",
    "throw_noise",
]
