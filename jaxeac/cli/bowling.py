"""`jaxeac bowling`: AC and EAC learning to bowl in MuJoCo over many seeds, into a run folder."""

from __future__ import annotations

import argparse
import sys

from jaxeac.cli.compare import run_compare
from jaxeac.cli.flags import finite_float, folder_name, positive_int, prng_key
from jaxeac.cli.groups import (
    add_physics_flags,
    add_report_flags,
    add_sequential_flags,
    sequential_design,
    solver_settings,
)


def add_parser(sub) -> None:
    b = sub.add_parser("bowling", help="run AC and EAC learning to bowl in MuJoCo over many seeds")
    b.add_argument("--seeds", type=positive_int, default=1000, metavar="N", help="seeds per algorithm")
    b.add_argument("--trials", type=positive_int, default=10, metavar="T",
                   help="trials (default 10, SPEC B5)")
    b.add_argument("--angles", type=int, default=21, metavar="K",
                   help="number of shoulder angles, K >= 2 (SPEC B2)")
    add_physics_flags(b, noise_angle=0.003, noise_speed=0.1)
    b.add_argument("--state", default="mask", metavar="mask|tree",
                   help="mask: the standing pins (SPEC B5, default); tree: chance 2 keyed on the chance-1 "
                        "angle, the paper's Fig. 5 tree (SPEC B5a)")
    b.add_argument("--success-pins", type=positive_int, default=10, metavar="N",
                   help="pins a trial must knock to succeed (SPEC B5b; default 10, all down)")
    b.add_argument("--algos", nargs="+", default=["ac", "eac"], metavar="ALGO",
                   help="algorithms: ac, eac, eac_success_only, eac_failure_only, eac_learn_on_memory, "
                        "eac_within_trial")
    b.add_argument("--alpha", type=finite_float, default=0.1, metavar="A", help="critic step size α")
    b.add_argument("--beta", type=finite_float, default=0.3, metavar="B", help="actor step size β")
    b.add_argument("--gamma", type=finite_float, default=1.0, metavar="G", help="discount γ (B5: 1)")
    b.add_argument("--key", type=prng_key, default=0, metavar="K", help="root PRNG key, 0..2^32-1 (SPEC R1)")
    b.add_argument("--chunk-size", type=positive_int, default=None, metavar="M",
                   help="seeds per batch; bounds memory (default: up to 1000, fewer where they would not "
                        "fit; results do not depend on it)")
    b.add_argument("--out", type=folder_name, default="runs/bowling", metavar="DIR",
                   help="run folder (default runs/bowling)")
    add_report_flags(b)
    add_sequential_flags(b)


def cmd_bowling(args: argparse.Namespace) -> int:
    import dataclasses

    from tqdm import tqdm

    from jaxeac.cli.process import _claim_out
    from jaxeac.experiments.bowling import (
        AUTO_CHUNK,
        BowlingSettings,
        auto_chunk_size,
        run_bowling,
        table_one,
        write_bowling_outputs,
    )
    from jaxeac.experiments.common import check_bowling_resources

    settings = BowlingSettings(
        seeds=args.seeds, trials=args.trials, angles=args.angles, theta_max=args.theta_max,
        noise_angle=args.noise_angle, noise_speed=args.noise_speed, backend=args.backend,
        algos=tuple(args.algos), key=args.key, chunk_size=args.chunk_size or AUTO_CHUNK, alpha=args.alpha,
        beta=args.beta, gamma=args.gamma, solver=solver_settings(args), scene=args.scene, state=args.state,
        success_pins=args.success_pins,
    )
    settings.validate()
    settings = settings.resolved()  # the backend `auto` picks here, recorded in summary.json
    if args.chunk_size is None:  # automatic: at most AUTO_CHUNK seeds, fewer where they would not fit
        settings = dataclasses.replace(settings, chunk_size=auto_chunk_size(settings))
    check_bowling_resources(settings)  # sizes that cannot fit or finish fail here, with the numbers
    design = sequential_design(args, settings)
    out = _claim_out(args, args.out)
    seq = None
    with tqdm(total=settings.seeds * len(settings.algos), unit="seed", disable=args.quiet,
              desc=f"bowling ({settings.backend})", file=sys.stderr) as bar:
        if design is None:
            run = run_bowling(settings, progress=bar.update)
        else:
            from jaxeac.experiments.bowling import run_bowling_sequential
            from jaxeac.fmt import sequential_look

            def on_look(result: dict) -> None:
                if not args.quiet:
                    bar.write(sequential_look(result, design.effect, "pins"), file=sys.stderr)

            run, seq = run_bowling_sequential(settings, design, progress=bar.update, on_look=on_look)
    summary = write_bowling_outputs(run, out, sequential=seq)
    print("\n".join(line for line in table_one(run).splitlines() if line.startswith("- ")))
    if "eac_minus_ac" in summary:
        d = summary["eac_minus_ac"]
        print(f"EAC - AC: {d['diff']:+.2f} pins of {10 * settings.trials} "
              f"(95% CI [{d['ci95'][0]:+.2f}, {d['ci95'][1]:+.2f}], Welch)")
    throws = sum(r.throws for r in run.results.values())
    print(f"{throws} throws, compile {summary['compile_seconds']:.1f} s, "
          f"run {summary['run_seconds']:.1f} s; results in {out}/")
    if seq is not None:
        print(f"sequential decision: {seq['decision']} after {len(seq['looks_taken'])} of {design.looks} "
              f"looks ({seq['seeds_used']} seeds per method, {seq['seconds_to_decision']:.1f} s)")
    if not args.no_compare and {"ac", "eac"} <= set(settings.algos) and run.settings.seeds >= 2:
        return run_compare(out, quiet=args.quiet)
    return 0
