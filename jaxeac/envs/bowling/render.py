"""Pictures of the pin deck after a throw (SPEC B1, B4).

``render_deck`` draws a top-down matplotlib picture (works everywhere): lane,
pin deck, pins standing (filled) and fallen (crossed, where they came to rest),
and the ball's path when the throw recorded a trajectory. With ``method="mujoco"``
it renders the MuJoCo scene instead; that needs an offscreen GL context, chosen
by MuJoCo when it is first imported, e.g. ``MUJOCO_GL=egl`` in the environment
("auto" uses it when MUJOCO_GL is egl or osmesa and falls back to matplotlib).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from jaxeac.errors import UsageError

from .scene import DEFAULT_SCENE, PIN_RADIUS, PinState, Scene, ThrowResult

METHODS = ("auto", "matplotlib", "mujoco")


def _pick(x, index: int) -> np.ndarray:
    """Element index of a batched array (or the array itself when unbatched)."""
    a = np.asarray(x)
    return a[index] if a.ndim and index is not None else a


def _unpack(result, index: int):
    """(pin poses (10, 7), standing after the throw (10,), ball path (T, 3) or None)."""
    if isinstance(result, ThrowResult):
        standing = np.asarray(result.standing)
        batched = standing.ndim == 2
        i = index if batched else None
        qpos = _pick(result.rest_qpos, i)
        after = _pick(result.standing, i)
        ball = None
        if result.trajectory is not None:
            ball = _pick(result.trajectory.ball, i)
        return qpos, after, ball
    if isinstance(result, PinState):
        standing = np.asarray(result.standing)
        i = index if standing.ndim == 2 else None
        return _pick(result.qpos, i), _pick(result.standing, i), None
    raise UsageError(f"cannot draw a {type(result).__name__}: pass a ThrowResult or PinState")


def render_deck(
    result: ThrowResult | PinState,
    path_png: str | os.PathLike,
    *,
    index: int = 0,
    method: str = "auto",
    title: str | None = None,
    scene: Scene = DEFAULT_SCENE,
) -> str:
    """Save a picture of the pin deck of `scene` after a throw to path_png; return the method used."""
    if method not in METHODS:
        raise UsageError(f"unknown render method {method!r}: use one of {', '.join(METHODS)}")
    path = Path(path_png)
    if not path.parent.exists():
        raise UsageError(f"folder {path.parent} does not exist: create it or pick another path")
    qpos, standing, ball = _unpack(result, index)
    if method == "mujoco" or (
        method == "auto" and os.environ.get("MUJOCO_GL", "").lower() in ("egl", "osmesa")
    ):
        try:
            _render_mujoco(qpos, standing, ball, path, scene)
            return "mujoco"
        except Exception as err:  # no GL context: fall back unless asked for explicitly
            if method == "mujoco":
                raise UsageError(
                    f"MuJoCo offscreen rendering failed ({err}): set MUJOCO_GL=egl or use "
                    "method='matplotlib'"
                ) from err
    _render_matplotlib(qpos, standing, ball, path, title, scene)
    return "matplotlib"


def _render_matplotlib(qpos, standing, ball, path: Path, title: str | None, scene: Scene) -> None:
    """Top-down drawing of lane end, deck, pins and ball path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle

    fig, ax = plt.subplots(figsize=(5, 6.5))
    deck_x, half = scene.deck_x, scene.deck_half_width
    x0, x1 = deck_x[0] - 1.2, deck_x[1] + 0.6
    ax.add_patch(Rectangle((-0.525, x0), 1.05, x1 - x0, color="#d9b27a", zorder=0))
    ax.add_patch(
        Rectangle(
            (-half, deck_x[0]),
            2 * half,
            deck_x[1] - deck_x[0],
            fill=False,
            ls="--",
            ec="0.4",
            label="deck",
        )
    )
    # The plot's horizontal axis is -y so the thrower's left is on the left of the picture.
    for (x, y) in scene.pin_xy():
        ax.add_patch(Circle((-y, x), PIN_RADIUS, fill=False, ec="0.6", lw=0.5, ls=":"))
    if ball is not None:
        ball = np.asarray(ball)
        ax.plot(-ball[:, 1], ball[:, 0], "-", color="k", lw=1, label="ball path")
        ax.add_patch(Circle((-ball[-1, 1], ball[-1, 0]), scene.ball_radius, color="k", alpha=0.5))
    for k in range(10):
        x, y = qpos[k, 0], qpos[k, 1]
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        if standing[k]:
            ax.add_patch(Circle((-y, x), PIN_RADIUS, color="tab:blue", zorder=3))
        else:
            ax.plot(-y, x, "x", color="tab:red", ms=9, mew=2, zorder=3)
        ax.annotate(str(k + 1), (-y, x), xytext=(5, 5), textcoords="offset points", fontsize=8)
    ax.plot([], [], "o", color="tab:blue", label=f"standing ({int(np.sum(standing))})")
    ax.plot([], [], "x", color="tab:red", mew=2, label=f"down ({10 - int(np.sum(standing))})")
    ax.set_xlim(-1.2, 1.2)
    ax.set_ylim(x0, x1)
    ax.set_aspect("equal")
    ax.set_xlabel("<- thrower's left      lateral (m)      thrower's right ->")
    ax.set_ylabel("down the lane (m)")
    ax.set_title(title or "pin deck after the throw (top view)")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _render_mujoco(qpos, standing, ball, path: Path, scene: Scene) -> None:
    """MuJoCo offscreen render of the scene with pins where they came to rest."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import mujoco

    from .backend_c import load_model

    model = load_model(scene=scene)
    data = mujoco.MjData(model)
    data.qpos[7:] = np.asarray(qpos, np.float64).reshape(-1)
    if ball is not None:
        data.qpos[:3] = np.asarray(ball)[-1]
    else:
        data.qpos[:3] = (scene.deck_x[1] + 1.0, 0.0, scene.ball_radius)
    mujoco.mj_forward(model, data)
    cam = mujoco.MjvCamera()
    cam.lookat[:] = (scene.pin_xy()[:, 0].mean(), 0.0, 0.1)
    cam.distance, cam.azimuth, cam.elevation = 2.6, 0.0, -35.0  # from the thrower's side
    with mujoco.Renderer(model, 480, 640) as renderer:
        renderer.update_scene(data, camera=cam)
        image = renderer.render()
    plt.imsave(path, image)
