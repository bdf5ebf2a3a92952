"""CLI-facing bowling command: throw at a fresh full rack per angle (SPEC B2-B4, B7).

The argparse wiring lives in ``jaxeac.cli.throw``; this returns a JSON-ready dict.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import numpy as np

from jaxeac.errors import UsageError

from .api import throw
from .render import render_deck
from .scene import BowlingConfig, check_angles, check_backend, initial_pins


def throw_command(
    angles: list[float],
    backend: str,
    render: str | None,
    cfg: BowlingConfig,
    *,
    noise_angle: float = 0.0,
    noise_speed: float = 0.0,
    seed: int = 0,
) -> dict:
    """Throw each angle at a fresh rack, with Gaussian noise of s.d. `noise_angle` (rad) on the
    angle and `noise_speed` (m/s) on the release speed (B3; 0 and 0: exact throws, cfg's own
    noise is not used); render: PNG path or None.

    With several angles and a render path, throw i is saved as ``<stem>_<i><suffix>``.
    """
    backend = check_backend(backend)
    if not angles:
        raise UsageError("no angles given: pass at least one shoulder angle (rad), e.g. --angle 0.05")
    a = check_angles(np.asarray(angles, dtype=np.float64).reshape(-1), cfg)
    try:  # BowlingConfig checks each s.d. (finite, >= 0, not past a meaningful throw, float32)
        run_cfg = dataclasses.replace(cfg, noise_angle=float(noise_angle), noise_speed=float(noise_speed))
    except UsageError as exc:
        raise UsageError(f"--noise-angle/--noise-speed: {exc}") from None
    res = throw(
        initial_pins(len(a), cfg.scene),
        a,
        jax.random.key(seed),
        backend=backend,
        record_trajectory=render is not None,
        cfg=run_cfg,
    )
    knocked = np.asarray(res.knocked)
    standing = np.asarray(res.standing)
    out = {
        "theta_max": cfg.theta_max,
        "backend": backend,
        "noise_angle": run_cfg.noise_angle,
        "noise_speed": run_cfg.noise_speed,
        "throws": [
            {"angle": float(a[i]), "knocked": int(knocked[i]), "standing": standing[i].tolist()}
            for i in range(len(a))
        ],
    }
    if render is not None:
        path = Path(render)
        paths = []
        for i in range(len(a)):
            p = path if len(a) == 1 else path.with_name(f"{path.stem}_{i}{path.suffix}")
            title = f"theta = {a[i]:+.3f} rad: {int(knocked[i])} pins down ({backend})"
            render_deck(res, p, index=i, title=title, scene=cfg.scene)
            paths.append(str(p))
        out["render"] = paths
    return out
