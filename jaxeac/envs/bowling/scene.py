"""Bowling scene constants, configuration, pin state and the throw maths shared by both backends.

SPEC ids: B1 (scene, see ``xmls/bowling.xml``), B2 (shoulder angles), B3 (execution
noise), B4 (pins down / removed / standing), B7 (both backends prepare and judge a
throw with the functions here, so they differ only in the physics engine).

Everything here is backend-neutral JAX: ``throw_start`` builds the initial
``qpos``/``qvel`` of a throw from the pin state, the angle and the noise draw, and
``judge_throw`` turns the final pin poses into the next pin state.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxeac.errors import UsageError

from .engines import BACKENDS, MJX_IMPL, check_backend, default_backend  # noqa: F401  (re-exported)

XML_PATH = Path(__file__).resolve().parent / "xmls" / "bowling.xml"

N_PINS = 10
BALL_RADIUS = 0.11  # m (B1)
ARM_LENGTH = 0.6  # m: radius of the release arc around the shoulder axis (B2)
PIN_RADIUS = 0.06  # m
PIN_CENTRE_Z = 0.19  # m: centre height of an upright pin (0.38 m tall)
PIN_SPACING = 0.30  # m between neighbouring pin centres
HEAD_PIN_X = 6.6  # m: 6.0 m from the theta = 0 release point
ROW_GAP = PIN_SPACING * math.sqrt(3.0) / 2.0
_F32_TINY = float(np.finfo(np.float32).tiny)  # smallest normal float32


def _pin_xy(spacing: float = PIN_SPACING) -> np.ndarray:
    """Pin centres (10, 2), standard numbering; +y is the thrower's left (B1)."""
    gap = spacing * math.sqrt(3.0) / 2.0
    xy = []
    for row in range(4):
        for j in range(row + 1):
            xy.append((HEAD_PIN_X + row * gap, (row / 2.0 - j) * spacing))
    return np.asarray(xy, dtype=np.float64)


PIN_XY = _pin_xy()


@dataclasses.dataclass(frozen=True)
class Scene:
    """The sizes of the ball and the pin deck (B1, B1a); the MJCF file holds the default's.

    ``SCENES["table1"]`` (B1a): a smaller ball (6 cm radius) and wider pin spacing (0.40 m),
    chosen by measurement so that the landscape of first throws is like the paper's Table I:
    no throw knocks more than 7 pins and strikes are rare (BENCHMARKS.md, *A scene like Table I*).
    """

    ball_radius: float = BALL_RADIUS  # m
    pin_spacing: float = PIN_SPACING  # m between neighbouring pin centres

    def __post_init__(self) -> None:
        """Check both sizes; raise UsageError naming the problem and the fix."""
        if not isinstance(self.ball_radius, int | float) or not 0.02 <= self.ball_radius <= 0.2:
            raise UsageError(f"ball_radius={self.ball_radius!r}: need a radius in [0.02, 0.2] m")
        lo = 2 * PIN_RADIUS + 0.02
        if not isinstance(self.pin_spacing, int | float) or not lo <= self.pin_spacing <= 1.0:
            raise UsageError(f"pin_spacing={self.pin_spacing!r}: need a spacing in [{lo:g}, 1] m "
                             "(pins must not touch)")

    def pin_xy(self) -> np.ndarray:
        """Pin centres (10, 2) of this deck."""
        return _pin_xy(self.pin_spacing)

    @property
    def deck_x(self) -> tuple[float, float]:
        """The deck's extent along the lane: from 0.5 m before the head pin to 0.3 m behind the last row."""
        return HEAD_PIN_X - 0.5, HEAD_PIN_X + 3 * (self.pin_spacing * math.sqrt(3.0) / 2.0) + 0.3

    @property
    def deck_half_width(self) -> float:
        """Half the deck's width: 0.15 m beyond the outer pins of the back row."""
        return 1.5 * self.pin_spacing + 0.15


SCENES = {"default": Scene(), "table1": Scene(ball_radius=0.06, pin_spacing=0.40)}
DEFAULT_SCENE = SCENES["default"]
# The default pin deck (B4 "leaves the deck"): a pin whose centre ends outside this box is down.
DECK_X = DEFAULT_SCENE.deck_x
DECK_HALF_WIDTH = DEFAULT_SCENE.deck_half_width


def check_scene(name: str) -> Scene:
    """The scene preset of this name, or UsageError listing them."""
    if name not in SCENES:
        raise UsageError(f"unknown scene {name!r}: use one of {', '.join(SCENES)}")
    return SCENES[name]


# Fallen pins are parked here (B4 "removed"): 1000 m up, 1 m apart, behind the thrower.
# They free-fall during a throw (20 m in 2 s; 10 s allowed), touching nothing, and are
# put back here before every throw.
PARK_XYZ = np.stack(
    [np.full(N_PINS, -10.0), np.arange(N_PINS) - 4.5, np.full(N_PINS, 1000.0)], axis=1
)
# qpos/qvel layout of the model: ball free joint first, then pin1..pin10.
BALL_QPOS = slice(0, 7)
PINS_QPOS = slice(7, 77)
NQ, NV = 77, 66
TIMESTEP = 0.005  # s, as in the MJCF file
MAX_STEPS = 2000  # 10 s: parked pins must not reach the floor

SOLVERS = ("newton", "cg")  # MuJoCo's constraint solvers offered (B7: chosen by measurement)


@dataclasses.dataclass(frozen=True)
class SolverSettings:
    """The constraint solver a loaded model runs with, in both backends (B7); validated.

    The defaults are the MJCF file's: Newton, 4 iterations, 8 line-search iterations,
    the accurate setting. ``sleep`` (the C engine's default) lets MuJoCo put bodies at rest to
    sleep, so standing pins cost nothing until something touches them, and ends a throw as soon
    as nothing can move a pin any more (``backend_c.settled``): 2-3x faster at the same accuracy
    (BENCHMARKS.md, *Bowling on the CPU*); ``sleep=False`` is the engine before it, step for step.
    CG with enough iterations is faster under MJX on GPUs at the same accuracy; fewer iterations
    or a lower contact cap trade accuracy for speed (measured in BENCHMARKS.md with
    scripts/bench_bowling.py --accuracy).
    """

    method: str = "newton"  # one of SOLVERS
    iterations: int = 4
    ls_iterations: int = 8
    contact_cap: int = 32  # MJX only: candidate contacts kept per condim group (max_contact_points)
    pair_cap: int = 0  # MJX only: closest geom pairs tested per collision group (max_geom_pairs; 0 = all)
    sleep: bool = True  # C engine only: bodies at rest sleep (MuJoCo's island sleeping), and a throw
    #                     ends early

    def __post_init__(self) -> None:
        """Check every field; raise UsageError naming the problem and the fix."""
        if self.method not in SOLVERS:
            raise UsageError(f"unknown solver {self.method!r}: use one of {', '.join(SOLVERS)}")
        if not isinstance(self.sleep, bool):
            raise UsageError(f"sleep={self.sleep!r}: need True or False")
        for name, low in (("iterations", 1), ("ls_iterations", 1), ("contact_cap", 1), ("pair_cap", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= 1000:
                raise UsageError(f"{name}={value!r}: need an integer in [{low}, 1000]")


DEFAULT_SOLVER = SolverSettings()


@dataclasses.dataclass(frozen=True)
class BowlingConfig:
    """Static settings of the bowling throw (B2, B3, B4); validated on construction."""

    n_angles: int = 21  # K shoulder angles (B2)
    theta_max: float = 0.1  # rad; +-theta_max lie in the no-pin zone (B2)
    noise_angle: float = 0.003  # rad, s.d. of the Gaussian noise on theta (B3)
    noise_speed: float = 0.1  # m/s, s.d. of the Gaussian noise on release speed (B3)
    release_speed: float = 7.0  # m/s (ball released rolling, no slip)
    n_steps: int = 400  # physics steps per throw (5 ms each: 2 s)
    tilt_down_deg: float = 45.0  # a pin tilted more than this is down (B4)
    trajectory_stride: int = 5  # record every k-th step when a trajectory is asked for
    nthread: int = 0  # C backend threads; 0 = os.cpu_count()
    solver: SolverSettings = DEFAULT_SOLVER  # constraint solver, both backends (B7)
    scene: Scene = DEFAULT_SCENE  # ball and deck sizes (B1, B1a)

    def __post_init__(self) -> None:
        """Check every field; raise UsageError naming the problem and the fix."""
        if not isinstance(self.n_angles, int) or self.n_angles < 2:
            raise UsageError(f"n_angles={self.n_angles!r}: need an integer >= 2 (K angles)")
        if not math.isfinite(self.theta_max) or self.theta_max <= 0:
            raise UsageError(f"theta_max={self.theta_max!r}: need a finite angle > 0 (rad)")
        if self.theta_max >= math.pi / 2:
            raise UsageError(f"theta_max={self.theta_max!r}: need < pi/2 so throws go down-lane")
        if not math.isfinite(self.release_speed) or self.release_speed <= 0:
            raise UsageError(f"release_speed={self.release_speed!r}: need a speed > 0 (m/s)")
        for name in ("noise_angle", "noise_speed"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0:
                raise UsageError(f"{name}={value!r}: need a finite value >= 0 (0 = exact)")
        # Limits of a meaningful throw: noise past them turns throws away from the pins or makes the
        # ball faster than the physics steps resolve (it passes through pins, or the simulation blows up).
        for name, most in (("noise_angle", math.pi / 2), ("noise_speed", self.release_speed)):
            if getattr(self, name) > most:
                raise UsageError(f"{name}={getattr(self, name)!r}: need at most {most:.4g} (the s.d. of the "
                                 "noise; larger noise makes throws meaningless)")
        for name in ("theta_max", "noise_angle", "noise_speed"):  # throws are prepared in float32
            value = getattr(self, name)
            if 0 < value < _F32_TINY:
                zero = "" if name == "theta_max" else "0 or "
                raise UsageError(f"{name}={value!r}: below float32's smallest normal number, where throws "
                                 f"are prepared (it acts as 0); use {zero}a value of at least "
                                 f"{_F32_TINY:.3g}")
        if not isinstance(self.n_steps, int) or not 1 <= self.n_steps <= MAX_STEPS:
            raise UsageError(f"n_steps={self.n_steps!r}: need an integer in [1, {MAX_STEPS}]")
        if not 0 < self.tilt_down_deg < 90:
            raise UsageError(f"tilt_down_deg={self.tilt_down_deg!r}: need a value in (0, 90)")
        if not isinstance(self.trajectory_stride, int) or self.trajectory_stride < 1:
            raise UsageError(f"trajectory_stride={self.trajectory_stride!r}: need an integer >= 1")
        if not isinstance(self.nthread, int) or self.nthread < 0:
            raise UsageError(f"nthread={self.nthread!r}: need an integer >= 0 (0 = all cores)")
        if not isinstance(self.solver, SolverSettings):
            raise UsageError(f"solver={self.solver!r}: pass a SolverSettings")
        if not isinstance(self.scene, Scene):
            raise UsageError(f"scene={self.scene!r}: pass a Scene (e.g. SCENES['table1'])")


def angles(cfg: BowlingConfig) -> np.ndarray:
    """The K shoulder angles evenly spaced on [-theta_max, theta_max] (B2)."""
    return np.linspace(-cfg.theta_max, cfg.theta_max, cfg.n_angles)


def check_angles(angle, cfg: BowlingConfig) -> np.ndarray:
    """Return the angles as float array, or raise UsageError if outside +-theta_max (B2)."""
    a = np.asarray(angle, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        raise UsageError("throw angle is NaN or infinite: pass finite angles in radians")
    tol = 1e-9 * max(1.0, cfg.theta_max)
    if np.any(np.abs(a) > cfg.theta_max + tol):
        bad = float(a.flat[int(np.argmax(np.abs(a)))])
        raise UsageError(
            f"throw angle {bad:g} rad lies outside +-theta_max={cfg.theta_max:g}: "
            "use an angle in range or raise theta_max"
        )
    return a


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class PinState:
    """Pins before a throw (B4, B5): qpos (..., 10, 7) pose per pin, standing bool (..., 10)."""

    qpos: jax.Array
    standing: jax.Array


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Trajectory:
    """Recorded positions every cfg.trajectory_stride steps: ball (..., T, 3), pins (..., T, 10, 3)."""

    ball: jax.Array
    pins: jax.Array


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ThrowResult:
    """Outcome of a throw (B4, B5): the next pin state, pins knocked, and what the deck looked like."""

    pins_after: PinState  # fallen pins parked, standing pins at rest (B4)
    knocked: jax.Array  # int32 (...,): pins that fell in this throw (reward, E5)
    standing: jax.Array  # bool (..., 10): pins standing after the throw
    rest_qpos: jax.Array  # (..., 10, 7): every pin's pose at the end of the throw, fallen included
    trajectory: Trajectory | None = None


def upright_qpos(scene: Scene = DEFAULT_SCENE) -> np.ndarray:
    """qpos (10, 7) of the full rack, upright at the triangle positions of `scene` (B1)."""
    q = np.zeros((N_PINS, 7))
    q[:, :2] = scene.pin_xy()
    q[:, 2] = PIN_CENTRE_Z
    q[:, 3] = 1.0
    return q


def park_qpos() -> np.ndarray:
    """qpos (10, 7) of the parking spots of removed pins (B4)."""
    q = np.zeros((N_PINS, 7))
    q[:, :3] = PARK_XYZ
    q[:, 3] = 1.0
    return q


def initial_pins(batch: int | None = None, scene: Scene = DEFAULT_SCENE) -> PinState:
    """A full rack of `scene`, batched over a leading axis of size batch (None: unbatched) (B5)."""
    qpos = jnp.asarray(upright_qpos(scene), dtype=jnp.float32)
    standing = jnp.ones(N_PINS, dtype=bool)
    if batch is None:
        return PinState(qpos=qpos, standing=standing)
    if not isinstance(batch, int) or batch < 1:
        raise UsageError(f"batch={batch!r}: need an integer >= 1")
    return PinState(
        qpos=jnp.broadcast_to(qpos, (batch, N_PINS, 7)),
        standing=jnp.broadcast_to(standing, (batch, N_PINS)),
    )


def throw_noise(key: jax.Array) -> jax.Array:
    """Standard-normal draws (2,) for one throw: [angle, speed] (B3); same key, same draw."""
    return jax.random.normal(key, (2,))


def throw_start(
    pins: PinState, angle: jax.Array, eps: jax.Array, cfg: BowlingConfig
) -> tuple[jax.Array, jax.Array]:
    """Initial (qpos (77,), qvel (66,)) of one throw from pins, angle and noise draw eps (B2-B4)."""
    theta = angle + cfg.noise_angle * eps[0]
    speed = jnp.maximum(cfg.release_speed + cfg.noise_speed * eps[1], 0.1 * cfg.release_speed)
    c, s = jnp.cos(theta), jnp.sin(theta)
    radius = cfg.scene.ball_radius
    ball_q = jnp.stack([ARM_LENGTH * c, ARM_LENGTH * s, jnp.full_like(c, radius),
                        jnp.ones_like(c), jnp.zeros_like(c), jnp.zeros_like(c),
                        jnp.zeros_like(c)])
    vx, vy = speed * c, speed * s
    # Rolling without slip; free-joint angular velocity is in the body frame (identity here).
    ball_v = jnp.stack([vx, vy, jnp.zeros_like(c), -vy / radius, vx / radius,
                        jnp.zeros_like(c)])
    pin_q = pins.qpos.astype(ball_q.dtype)
    pin_q = jnp.where(pins.standing[:, None], pin_q, jnp.asarray(park_qpos(), pin_q.dtype))
    qpos = jnp.concatenate([ball_q, pin_q.reshape(-1)])
    qvel = jnp.concatenate([ball_v, jnp.zeros(NV - 6, ball_v.dtype)])
    return qpos, qvel


def pin_down(rest_qpos: jax.Array, cfg: BowlingConfig) -> jax.Array:
    """bool (10,): pin tilted beyond cfg.tilt_down_deg, off the deck, or non-finite (B4)."""
    pos, quat = rest_qpos[:, :3], rest_qpos[:, 3:]
    quat = quat / jnp.linalg.norm(quat, axis=-1, keepdims=True)
    # z-component of the pin's axis in the world frame = cos(tilt).
    cos_tilt = 1.0 - 2.0 * (quat[:, 1] ** 2 + quat[:, 2] ** 2)
    tilted = cos_tilt < math.cos(math.radians(cfg.tilt_down_deg))
    (x0, x1), half = cfg.scene.deck_x, cfg.scene.deck_half_width
    off_deck = (pos[:, 0] < x0) | (pos[:, 0] > x1) | (jnp.abs(pos[:, 1]) > half)
    bad = ~jnp.all(jnp.isfinite(rest_qpos), axis=-1)
    return tilted | off_deck | bad


def judge_throw(pins: PinState, rest_qpos: jax.Array, cfg: BowlingConfig) -> ThrowResult:
    """Next pin state and pins knocked from the pin poses at the end of a throw (B4, B5)."""
    down = pin_down(rest_qpos, cfg)
    standing = pins.standing & ~down
    knocked = jnp.sum(pins.standing & down).astype(jnp.int32)
    park = jnp.asarray(park_qpos(), pins.qpos.dtype)
    qpos_after = jnp.where(standing[:, None], rest_qpos.astype(pins.qpos.dtype), park)
    # pins removed before the throw are reported at their parking spot, wherever their free fall
    # took them (it touches nothing; its length depends on when the throw stopped simulating)
    rest = jnp.where(pins.standing[:, None], rest_qpos.astype(pins.qpos.dtype), park)
    return ThrowResult(
        pins_after=PinState(qpos=qpos_after, standing=standing),
        knocked=knocked,
        standing=standing,
        rest_qpos=rest,
    )


def as_keys(key_or_noise, batch: int) -> jax.Array | None:
    """Batch of PRNG keys (batch,) from one key or a batch of keys; None if given a noise array."""
    arr = key_or_noise
    if isinstance(arr, jax.Array) and jnp.issubdtype(arr.dtype, jax.dtypes.prng_key):
        keys = arr if arr.ndim == 1 else jax.random.split(arr, batch)
    else:
        a = np.asarray(arr)
        if a.dtype == np.uint32 and a.shape == (2,):
            keys = jax.random.split(jnp.asarray(a), batch)
        elif a.dtype == np.uint32 and a.shape == (batch, 2):
            keys = jnp.asarray(a)
        else:
            return None
    if keys.shape[0] != batch:
        raise UsageError(f"got {keys.shape[0]} keys for a batch of {batch}: pass one key or one per throw")
    return keys


def batch_noise(key_or_noise, batch: int) -> jax.Array:
    """Standard-normal draws (batch, 2) from a key, a batch of keys, or given directly (B3)."""
    keys = as_keys(key_or_noise, batch)
    if keys is None:
        eps = jnp.asarray(key_or_noise, dtype=jnp.float32)
        if eps.shape == (2,):
            eps = jnp.broadcast_to(eps, (batch, 2))
        if eps.shape != (batch, 2):
            raise UsageError(
                f"noise array of shape {tuple(eps.shape)}: pass a PRNG key or "
                f"standard normals of shape ({batch}, 2)"
            )
        return eps
    return jax.vmap(throw_noise)(keys)
