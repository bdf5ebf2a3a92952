"""CLI-facing bowling command: throw at a fresh full rack per angle (SPEC B2-B4, B7).

The argparse wiring lives in ``jaxeac.cli``; this returns a JSON-ready dict.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import jax
import numpy as np

from jaxeac.errors import UsageError

from .api import throw
from .render import render_deck
from .scene import BowlingConfig, check_angles, check_backend, initial_pins


def throw_command(
    angles: list[float],
    noise: float,
    backend: str,
    render: str | None,
    cfg: BowlingConfig,
    seed: int = 0,
) -> dict:
    """Throw each angle at a fresh rack; noise scales cfg's noise (0: exact); render: PNG path or None.

    With several angles and a render path, throw i is saved as ``<stem>_<i><suffix>``.
    """
    backend = check_backend(backend)
    if not angles:
        raise UsageError("no angles given: pass at least one shoulder angle (rad)")
    if not math.isfinite(noise) or noise < 0:
        raise UsageError(f"noise={noise!r}: need a finite scale >= 0 (0 = deterministic)")
    a = check_angles(np.asarray(angles, dtype=np.float64).reshape(-1), cfg)
    if noise > 0 and (cfg.noise_angle * noise == 0 or cfg.noise_speed * noise == 0):
        raise UsageError(f"--noise {noise!r} scales the noise to 0 (it underflows); use 0 for exact throws "
                         "or a scale from about 1e-30 to a few (1: the noise of SPEC B3)")
    try:
        run_cfg = dataclasses.replace(
            cfg, noise_angle=cfg.noise_angle * noise, noise_speed=cfg.noise_speed * noise
        )
    except UsageError as exc:
        raise UsageError(f"--noise {noise:g} scales the noise out of range ({exc}); use a --noise from 0 "
                         "to a few (1: the noise of SPEC B3)") from None
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
        "noise": noise,
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
