"""`jaxeac run` (alias `jaxeac grid`): AC, EAC and baselines over many seeds, into a run folder.

The run, its folder and its statistics report are `jaxeac.experiments.pipeline.run_and_compare`;
this module turns the flags into settings and prints what the run found.
"""

from __future__ import annotations

import argparse
import sys

from jaxeac.cli.checks import fit_grid
from jaxeac.cli.compare import print_comparison
from jaxeac.cli.flags import folder_name, host_port, nonneg_int, positive_int
from jaxeac.cli.groups import (
    add_grid_flags,
    add_output_flags,
    add_report_flags,
    add_sequential_flags,
    grid_settings,
    output_options,
    sequential_design,
)
from jaxeac.cli.process import _claim_out, _ended_with_command, _init_distributed
from jaxeac.errors import UsageError

#: Where `jaxeac run` and `jaxeac grid` write when no --out is given.
DEFAULT_OUT = "runs/grid"


def add_parser(sub) -> None:
    g = sub.add_parser(
        "run", aliases=["grid"],
        help="run AC, EAC and baselines over many seeds: the paper's grid world (default), --map FILE or "
             "--env NAME; `grid` is an alias of run",
        description="Run AC, EAC and baselines over many seeds: the paper's grid world (default preset "
                    "paper), a map file (--map) or a registered environment (--env). `jaxeac grid` is an "
                    "alias of `jaxeac run`: the same flags, defaults and outputs.")
    add_grid_flags(g)
    g.add_argument("--out", type=folder_name, default=DEFAULT_OUT, metavar="DIR",
                   help=f"run folder (default {DEFAULT_OUT})")
    add_report_flags(g)
    add_output_flags(g)
    add_sequential_flags(g)
    g.add_argument("--num-processes", type=positive_int, default=1, metavar="P",
                   help="split the seeds over P processes (hosts); each writes DIR/part-I-of-P/")
    g.add_argument("--process-id", type=nonneg_int, default=0, metavar="I", help="this process, 0..P-1")
    g.add_argument("--coordinator", type=host_port, metavar="HOST:PORT",
                   help="call jax.distributed.initialize with this coordinator (multi-host JAX)")


def cmd_run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from jaxeac.experiments.grid import part_folder
    from jaxeac.experiments.pipeline import figure_helper, run_and_compare

    settings = grid_settings(args).resolved()
    if settings.seeds < 2:
        raise UsageError(f"--seeds {settings.seeds}: a run reports each algorithm's mean with a 95% CI, "
                         "which needs at least 2 seeds (e.g. --seeds 100)")
    env = settings.make_env()  # a bad map or environment fails here, before any compute
    if args.process_id >= args.num_processes:
        raise UsageError(f"--process-id {args.process_id} must be below --num-processes {args.num_processes}")
    if args.num_processes > settings.seeds:
        raise UsageError(f"--num-processes {args.num_processes} exceeds --seeds {settings.seeds}")
    if args.coordinator and args.num_processes == 1:
        raise UsageError("--coordinator only applies to a multi-process run; add --num-processes P "
                         "--process-id I, or drop --coordinator")
    _init_distributed(args)  # before the size check: JAX's backends must not have started yet
    helper = None
    if args.num_processes == 1 and not args.sequential:  # on GPUs the figures' helper starts meanwhile
        helper = _ended_with_command(args, figure_helper(settings, compare=not args.no_compare))
    settings = fit_grid(args, settings, env)  # sizes that cannot fit or finish fail here
    design = sequential_design(args, settings)  # a bad design fails here too
    part = part_folder(args.out, args.process_id, args.num_processes) if args.num_processes > 1 else None
    out = _claim_out(args, args.out, part)
    if args.num_processes > 1:
        return _run_part(args, settings, out)
    compare = not args.no_compare
    if design is not None:
        from jaxeac.fmt import sequential_look

        def on_look(result: dict) -> None:
            if not args.quiet:
                print(sequential_look(result, design.effect, "successes"), file=sys.stderr, flush=True)

        _, _, stats = run_and_compare(settings, out, options=output_options(args, design.sizes[-1]),
                                      compare=compare, quiet=args.quiet, design=design, on_look=on_look,
                                      on_folder=lambda run, summary: _print_run(summary, out, design))
    else:
        with tqdm(total=settings.seeds * len(settings.algos), unit="seed", disable=args.quiet,
                  desc=settings.env or "grid", file=sys.stderr) as bar:  # results.parquet: written as it goes

            def on_folder(run, summary) -> None:
                bar.close()  # the run is done: its bar ends before the summary and the report's bar
                _print_run(summary, out)

            _, _, stats = run_and_compare(settings, out, options=output_options(args, settings.seeds),
                                          compare=compare, quiet=args.quiet, progress=bar.update,
                                          on_folder=on_folder, helper=helper)
    if stats is not None:
        print_comparison(stats, out)
    return 0


def _print_run(summary: dict, out, design=None) -> None:
    """The summary table, a sequential run's decision and where the folder is."""
    from jaxeac.experiments.grid import summary_table

    print(summary_table(summary))
    if design is not None:
        seq = summary["sequential"]
        print(f"sequential decision: {seq['decision']} after {len(seq['looks_taken'])} of {design.looks} "
              f"looks ({seq['seeds_used']} seeds per method, {seq['seconds_to_decision']:.1f} s)")
    print(f"results in {out}/")


def _run_part(args: argparse.Namespace, settings, out) -> int:
    """One process of a multi-process run: its block of seeds into DIR/part-I-of-P/."""
    from jaxeac.experiments.grid import part_folder, process_share, run_grid, write_grid_outputs
    from jaxeac.results import CSV_SEEDS, OutputOptions

    _init_distributed(args)  # once (cmd_run has done it), before anything starts JAX's backends
    first, n = process_share(settings.seeds, args.process_id, args.num_processes)
    run = run_grid(settings, first_seed=first, n_seeds=n)
    folder = part_folder(out, args.process_id, args.num_processes)
    write_grid_outputs(run, folder, figures=False,  # parts keep everything `jaxeac merge` joins
                       options=OutputOptions(trial_steps=True, policies=True, per_seed_csv=n <= CSV_SEEDS))
    print(f"seeds {first}..{first + n - 1} in {folder}/; when every part is done: jaxeac merge {out}")
    return 0
