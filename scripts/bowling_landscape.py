"""The landscape of a bowling scene: what each shoulder angle knocks, chance 1 and chance 2 (B1, B1a).

For each scene (the presets of ``jaxeac.envs.bowling.SCENES``, or ``RADIUS:SPACING`` in metres),
throws ``--per-angle`` noisy throws (B3 noise) at each of the K default angles from a full
rack with the C engine, then, from the racks the best chance-1 angle leaves, the same at
every angle for chance 2. Prints and records per-angle mean pins, the best angle's mean, the
most pins one throw knocked, the strike rate, the best two-throw total per trial and how
often all ten fall in it — the numbers that place a scene beside the paper's Table I (first
throws of at most 7 pins; all ten down once in 20 trials).

    python scripts/bowling_landscape.py --scenes default table1 0.07:0.40 --out landscape.json
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from jaxeac import paper  # noqa: E402
from jaxeac.envs.bowling import SCENES, BowlingConfig, Scene, angles, initial_pins, throw  # noqa: E402
from jaxeac.experiments.grid import versions  # noqa: E402
from jaxeac.io import atomic_write_json  # noqa: E402


def parse_scene(text: str) -> tuple[str, Scene]:
    """A preset name, or RADIUS:SPACING in metres."""
    if text in SCENES:
        return text, SCENES[text]
    try:
        radius, spacing = (float(x) for x in text.split(":"))
    except ValueError:
        raise SystemExit(f"error: scene {text!r}: use one of {', '.join(SCENES)} or RADIUS:SPACING") from None
    return text, Scene(ball_radius=radius, pin_spacing=spacing)


def landscape(scene: Scene, per_angle: int, seed: int) -> dict:
    """Chance-1 and chance-2 pins per angle for one scene."""
    cfg = BowlingConfig(scene=scene)
    grid = angles(cfg)
    k = len(grid)
    a = np.repeat(grid, per_angle)
    keys = jax.random.split(jax.random.key(seed), a.size)
    t0 = time.perf_counter()
    first = throw(initial_pins(a.size, scene), a, keys, cfg=cfg)
    knocked1 = np.asarray(first.knocked).reshape(k, per_angle)
    mean1 = knocked1.mean(axis=1)
    best1 = int(np.argmax(mean1))
    # chance 2 from the racks the best chance-1 angle left, at every angle
    racks = jax.tree.map(lambda x: np.asarray(x).reshape(k, per_angle, *np.shape(x)[1:])[best1], first.pins_after)
    racks = jax.tree.map(lambda x: np.tile(x, (k,) + (1,) * (x.ndim - 1)), racks)
    keys2 = jax.random.split(jax.random.key(seed + 1), k * per_angle)
    second = throw(racks, np.repeat(grid, per_angle), keys2, cfg=cfg)
    knocked2 = np.asarray(second.knocked).reshape(k, per_angle)
    mean2 = knocked2.mean(axis=1)
    best2 = int(np.argmax(mean2))
    seconds = time.perf_counter() - t0
    total = knocked1[best1] + knocked2[best2]
    return {
        "ball_radius": scene.ball_radius, "pin_spacing": scene.pin_spacing, "per_angle": per_angle,
        "angles": grid.tolist(), "chance1_mean_per_angle": mean1.tolist(),
        "best_chance1_angle": float(grid[best1]), "best_chance1_mean": float(mean1[best1]),
        "most_pins_one_throw": int(knocked1.max()), "strike_rate": float((knocked1 == 10).mean()),
        "share_over_7": float((knocked1 > 7).mean()),
        "chance2_mean_per_angle_after_best": mean2.tolist(), "best_chance2_angle": float(grid[best2]),
        "best_chance2_mean": float(mean2[best2]), "best_trial_mean": float(total.mean()),
        "best_trial_all_ten": float((total == 10).mean()), "throws": int(2 * a.size), "seconds": seconds,
    }


def paper_landscape() -> dict:
    """Table I's single runs, pooled: first throws' mean and most, trials with all ten down."""
    rows = [t for runs in paper.TABLE_ONE.values() for t in runs]
    first = [c1 for c1, _ in rows]
    return {"chance1_mean": float(np.mean(first)), "most_pins_one_throw": int(max(first)),
            "trial_mean": float(np.mean([c1 + c2 for c1, c2 in rows])),
            "all_ten_share": float(np.mean([c1 + c2 == 10 for c1, c2 in rows])), "trials": len(rows)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", nargs="+", default=list(SCENES), metavar="SCENE")
    p.add_argument("--per-angle", type=int, default=48, metavar="N", help="noisy throws per angle and chance")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=None, help="write the JSON record here")
    args = p.parse_args(argv)
    scenes = [parse_scene(s) for s in args.scenes]
    record = {"machine": {"platform": platform.platform(), "cpu_count": os.cpu_count()},
              "versions": versions(), "command": " ".join(["python", "scripts/bowling_landscape.py",
                                                            *(sys.argv[1:] if argv is None else argv)]),
              "paper_table1": paper_landscape(), "scenes": {}}
    print("| scene | ball r (m) | spacing (m) | best chance-1 mean | most pins, one throw | strikes "
          "| > 7 pins | best trial mean | all ten in a trial |")
    print("|---|---|---|---|---|---|---|---|---|")
    t = record["paper_table1"]
    print(f"| paper, Table I ({t['trials']} trials) | – | – | {t['chance1_mean']:.2f} (mean) | "
          f"{t['most_pins_one_throw']} | – | – | {t['trial_mean']:.2f} | {100 * t['all_ten_share']:.0f} % |")
    for name, scene in scenes:
        r = landscape(scene, args.per_angle, args.seed)
        record["scenes"][name] = r
        print(f"| {name} | {r['ball_radius']:g} | {r['pin_spacing']:g} | {r['best_chance1_mean']:.2f} "
              f"(θ {r['best_chance1_angle']:+.3f}) | {r['most_pins_one_throw']} | "
              f"{100 * r['strike_rate']:.1f} % | {100 * r['share_over_7']:.1f} % | {r['best_trial_mean']:.2f} | "
              f"{100 * r['best_trial_all_ten']:.1f} % |", flush=True)
    if args.out:
        atomic_write_json(args.out, record)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
