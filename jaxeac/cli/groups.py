"""Flag groups shared by several commands, and the settings built from them.

Each name has one meaning across every command (docs/CLI.md lists them all).
"""

from __future__ import annotations

import argparse

from jaxeac.cli.flags import (
    finite_float,
    map_file_name,
    nonneg_int,
    positive_int,
    prng_key,
)
from jaxeac.errors import UsageError


def add_grid_flags(p: argparse.ArgumentParser) -> None:
    """The grid-world flags shared by `run` (alias `grid`) and `sweep`; unset flags come from the preset."""
    from jaxeac.experiments.presets import GRID_PRESETS

    paper = GRID_PRESETS["paper"]

    world = p.add_argument_group(
        "the world (alternatives)",
        "Which world runs: the preset's own grid map (the default: --preset paper), a map file "
        "(--map FILE) or a registered environment (--env NAME); --map and --env exclude each other. "
        "Whichever world runs, the preset gives every rate and size not set below.")
    world.add_argument("--preset", default="paper", metavar="PRESET",
                       help=f"settings preset: {', '.join(GRID_PRESETS)} (default: paper, SPEC G6)")
    world.add_argument("--map", dest="map_file", type=map_file_name, metavar="FILE",
                       help="an ASCII map file instead of the preset's map (SPEC G1)")
    world.add_argument("--env", metavar="NAME",
                       help="a registered environment instead of the preset's map: the classic tabular tasks "
                            "(FrozenLake-4x4-v1, CliffWalking-v1, …; an unknown name lists them all)")
    p.add_argument("--trials", type=positive_int, metavar="T",
                   help=f"trials per run (default: the preset's; paper: {paper.trials})")
    p.add_argument("--chances", type=positive_int, metavar="C",
                   help=f"steps per trial, SPEC G5 (default: the preset's, paper: {paper.chances}; with "
                        "--env the environment's own episode limit)")
    p.add_argument("--alpha", type=finite_float, metavar="A",
                   help=f"critic step size α (default: the preset's; paper: {paper.alpha:g})")
    p.add_argument("--beta", type=finite_float, metavar="B",
                   help=f"actor step size β (default: the preset's; paper: {paper.beta:g})")
    p.add_argument("--gamma", type=finite_float, metavar="G",
                   help=f"discount γ in [0, 1] (default: the preset's; paper: {paper.gamma:g})")
    p.add_argument("--temperature", type=finite_float, metavar="TAU",
                   help=f"softmax temperature τ > 0 (default: the preset's; paper: {paper.temperature:g})")
    p.add_argument("--slip", type=finite_float, default=0.0, metavar="P",
                   help="with probability P a move executes a uniformly random action (default 0)")
    p.add_argument("--algos", nargs="+", default=["ac", "eac"], metavar="ALGO",
                   help="algorithms: ac, eac, eac_success_only, eac_failure_only, eac_learn_on_memory, "
                        "eac_within_trial, and the baselines q_learning, sarsa (default: ac eac)")
    p.add_argument("--epsilon", type=finite_float, default=0.1, metavar="E",
                   help="exploration rate of q_learning and sarsa, in [0, 1] (default 0.1)")
    p.add_argument("--seeds", type=positive_int, default=1000, metavar="N", help="seeds per algorithm")
    p.add_argument("--key", type=prng_key, default=0, metavar="K", help="root PRNG key, 0..2^32-1 (SPEC R1)")
    p.add_argument("--chunk-size", type=positive_int, default=None, metavar="M",
                   help="seeds per compiled batch; bounds memory (default: chosen for the backend and "
                        "free device memory; results do not depend on it)")
    p.add_argument("--lanes", type=positive_int, default=None, metavar="L",
                   help="seeds in flight per device (default: chosen for the backend and algorithm; "
                        "results do not depend on it)")
    p.add_argument("--memory", default="dense", metavar="LAYOUT",
                   help="memory layout: dense | buffer (SPEC E7)")
    p.add_argument("--capacity", type=positive_int, default=1024, metavar="K",
                   help="slots per memory for --memory buffer")


def grid_settings(args: argparse.Namespace):
    """The `GridSettings` of the flags `add_grid_flags` adds (not yet validated)."""
    from jaxeac.experiments.grid import GridSettings

    return GridSettings(
        preset=args.preset, map_file=args.map_file, trials=args.trials, chances=args.chances,
        alpha=args.alpha, beta=args.beta, gamma=args.gamma, temperature=args.temperature,
        algos=tuple(args.algos), seeds=args.seeds, key=args.key, chunk_size=args.chunk_size,
        memory=args.memory, capacity=args.capacity, env=args.env, slip=args.slip, epsilon=args.epsilon,
        lanes=args.lanes,
    )


def add_report_flags(p: argparse.ArgumentParser) -> None:
    """The run commands' statistics report (on by default) and progress bar."""
    p.add_argument("--no-compare", action="store_true", help="skip the statistics report at the end")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def add_output_flags(p: argparse.ArgumentParser) -> None:
    """What a grid run folder holds beyond results.parquet's per-seed measures and success curves."""
    p.add_argument("--full-outputs", action="store_true",
                   help="keep per-trial steps and final policies at any seed count "
                        "(default: up to 100,000 seeds)")
    p.add_argument("--per-seed-csv", action="store_true",
                   help="write per_seed.csv at any seed count (default: up to 100,000 seeds)")


def output_options(args: argparse.Namespace, n_seeds: int):
    """The `OutputOptions` of the flags `add_output_flags` adds, for a run of `n_seeds` seeds."""
    from jaxeac.results import OutputOptions

    return OutputOptions.auto(n_seeds, full=True if getattr(args, "full_outputs", False) else None,
                              csv=True if getattr(args, "per_seed_csv", False) else None)


def add_sequential_flags(p: argparse.ArgumentParser) -> None:
    """A sequential comparison (`jaxeac.stats.sequential`): --seeds is then the most it may use."""
    p.add_argument("--sequential", action="store_true",
                   help="run seeds in batches and stop at the first look that decides EAC vs AC "
                        "(repeated confidence intervals; --seeds is the most per method)")
    p.add_argument("--effect", type=finite_float, metavar="E",
                   help="with --sequential: the smallest difference of the primary measure that matters "
                        "(mean successes on the grid, mean pins in bowling)")
    p.add_argument("--looks", type=positive_int, metavar="K",
                   help="with --sequential: looks, after equal batches of seeds (default 5)")
    p.add_argument("--spending", metavar="obrien_fleming|pocock",
                   help="with --sequential: alpha-spending function (default obrien_fleming)")
    p.add_argument("--error-rate", type=finite_float, metavar="A",
                   help="with --sequential: chance of a wrong decision, each way, in (0, 0.5) (default 0.05)")


def sequential_design(args: argparse.Namespace, settings):
    """The `SequentialDesign` of `--sequential` (None without it); bad flags raise `UsageError`."""
    if not getattr(args, "sequential", False):
        flags = (("--effect", "effect"), ("--looks", "looks"), ("--spending", "spending"),
                 ("--error-rate", "error_rate"))
        given = [flag for flag, name in flags if getattr(args, name, None) is not None]
        if given:
            raise UsageError(f"{given[0]} only applies with --sequential; add --sequential or drop it")
        return None
    from jaxeac.stats.sequential import SequentialDesign

    if args.effect is None:
        raise UsageError("--sequential needs --effect E: the smallest difference of the primary measure "
                         "that matters (e.g. --effect 5)")
    if getattr(args, "num_processes", 1) > 1:
        raise UsageError("--sequential runs in one process; drop --num-processes")
    if not {"ac", "eac"} <= set(settings.algos):
        raise UsageError("--sequential compares eac with ac: --algos must include both")
    return SequentialDesign(effect=float(args.effect), max_seeds=int(settings.seeds),
                            looks=5 if args.looks is None else args.looks,
                            alpha=0.05 if args.error_rate is None else float(args.error_rate),
                            spend=args.spending or "obrien_fleming")


def add_physics_flags(p: argparse.ArgumentParser, *, noise_angle: float, noise_speed: float) -> None:
    """The bowling physics shared by `bowling` and `throw`: backend, deck, angle range, noise (B1-B3, B7)."""
    p.add_argument("--backend", default="auto", metavar="auto|c|mjx|warp",
                   help="physics backend (SPEC B7; default auto: c on CPUs, warp on NVIDIA GPUs with "
                        "warp-lang, else mjx; warp: MJX on NVIDIA GPUs via MuJoCo Warp)")
    p.add_argument("--scene", default="default", metavar="default|table1",
                   help="ball and pin deck (SPEC B1; table1: a smaller ball and wider deck whose first "
                        "throws are like the paper's Table I, SPEC B1a)")
    p.add_argument("--theta-max", type=finite_float, default=0.1, metavar="X",
                   help="largest |θ| in rad (default 0.1)")
    p.add_argument("--noise-angle", type=finite_float, default=noise_angle, metavar="S",
                   help=f"s.d. of the angle noise in rad (SPEC B3; default {noise_angle:g})")
    p.add_argument("--noise-speed", type=finite_float, default=noise_speed, metavar="S",
                   help=f"s.d. of the release-speed noise in m/s (SPEC B3; default {noise_speed:g})")
    add_solver_flags(p)


def add_solver_flags(p: argparse.ArgumentParser) -> None:
    """The bowling physics' constraint-solver settings (B7)."""
    p.add_argument("--solver", default="newton", metavar="newton|cg",
                   help="constraint solver (default newton; cg is faster in MJX on GPUs, less exact)")
    p.add_argument("--iterations", type=positive_int, default=4, metavar="N", help="solver iterations")
    p.add_argument("--ls-iterations", type=positive_int, default=8, metavar="N",
                   help="line-search iterations")
    p.add_argument("--contact-cap", type=positive_int, default=32, metavar="N",
                   help="MJX: contacts kept per condim group (keep >= 30: the pins' 30 feet are one group)")
    p.add_argument("--pair-cap", type=nonneg_int, default=0, metavar="N",
                   help="MJX: closest geom pairs tested per collision group (0 = every pair)")
    p.add_argument("--no-sleep", dest="sleep", action="store_false",
                   help="C engine: no sleeping of pins at rest, every throw its full length (the engine "
                        "before sleeping, step for step; 2-3x slower, same accuracy)")


#: The smallest --contact-cap that keeps the physics: MJX caps each condim group of candidate
#: contacts, and the pins' 30 foot-floor contacts form one group (envs/bowling/xmls/bowling.xml),
#: so a lower cap drops feet of standing pins and changes which pins fall.
MIN_CONTACT_CAP = 30


def solver_settings(args: argparse.Namespace):
    """The SolverSettings of the flags add_solver_flags adds (validated on construction)."""
    from jaxeac.envs.bowling import SolverSettings

    if args.contact_cap < MIN_CONTACT_CAP:
        raise UsageError(f"--contact-cap {args.contact_cap} is below {MIN_CONTACT_CAP}: the pins' "
                         f"{MIN_CONTACT_CAP} foot contacts form one contact group, so a lower cap drops "
                         f"feet of standing pins and changes the physics; use {MIN_CONTACT_CAP} or more "
                         "(default 32)")
    return SolverSettings(args.solver, args.iterations, args.ls_iterations, args.contact_cap, args.pair_cap,
                          sleep=args.sleep)


def add_compare_flags(p: argparse.ArgumentParser) -> None:
    """The statistics report's settings (`jaxeac compare`)."""
    p.add_argument("--baseline", default="ac", help="baseline algorithm (default ac)")
    p.add_argument("--treatment", default="eac", help="treatment algorithm (default eac)")
    p.add_argument("--resamples", type=positive_int, default=10_000, metavar="R",
                   help="bootstrap and permutation resamples (default 10000)")
    p.add_argument("--level", type=finite_float, default=0.95, metavar="L",
                   help="confidence level of the intervals, e.g. 0.99 for 99%% intervals; the tests' "
                        "significance level is 1 - L (default 0.95)")
    p.add_argument("--key", dest="stats_key", type=prng_key, default=0, metavar="K",
                   help="PRNG key of the resampling, 0..2^32-1")
    pairing = p.add_mutually_exclusive_group()
    pairing.add_argument("--unpaired", action="store_true",
                         help="run folders: compare the methods as independent samples only (default: "
                              "also paired where both ran the same seeds, which then share their keys)")
    pairing.add_argument("--paired", action="store_true",
                         help="run folders: require the paired analysis (an error if the methods ran "
                              "different seeds)")
