"""`jaxeac throw`: throw balls at a fresh rack and print what fell, as JSON."""

from __future__ import annotations

import argparse
import contextlib

from jaxeac.cli.checks import render_path, render_targets
from jaxeac.cli.flags import add_renamed, finite_float, prng_key
from jaxeac.cli.groups import add_physics_flags, solver_settings


def add_parser(sub) -> None:
    t = sub.add_parser("throw", help="throw balls at a fresh rack and print what fell (JSON)")
    t.add_argument("--angle", dest="angles", action="append", type=finite_float, required=True, metavar="A",
                   help="a shoulder angle in rad, within ±theta-max; repeat for several throws "
                        "(--angle 0.05 --angle -0.02)")
    add_physics_flags(t, noise_angle=0.0, noise_speed=0.0)  # deterministic unless asked
    t.add_argument("--key", type=prng_key, default=0, metavar="K", help="noise PRNG key, 0..2^32-1")
    t.add_argument("--render", metavar="FILE.png", help="save a picture of the pin deck after the throw")
    add_renamed(t, "--angles", "--angle A, once per throw (--angle 0.05 --angle -0.02)")
    add_renamed(t, "--noise", "--noise-angle S and --noise-speed S, the noise's s.d.s in rad and m/s "
                              "(--noise X was --noise-angle 0.003X --noise-speed 0.1X)")


def cmd_throw(args: argparse.Namespace) -> int:
    import json

    from jaxeac.envs.bowling import BowlingConfig, throw_command
    from jaxeac.envs.bowling.scene import check_scene

    cfg = BowlingConfig(theta_max=args.theta_max, solver=solver_settings(args), scene=check_scene(args.scene))
    render = None if args.render is None else render_path(args.render, len(args.angles))
    targets = [] if render is None else render_targets(render, len(args.angles))
    fresh = [t for t in targets if not t.exists()]
    try:
        result = throw_command(args.angles, args.backend, render, cfg, noise_angle=args.noise_angle,
                               noise_speed=args.noise_speed, seed=args.key)
    except BaseException:  # a full disk, Ctrl-C: no half-drawn picture is left behind
        for target in fresh:
            with contextlib.suppress(OSError):
                target.unlink()
        raise
    print(json.dumps(result))
    return 0
