"""`jaxeac merge`: join the part folders of a multi-process run into its run folder, and compare."""

from __future__ import annotations

import argparse

from jaxeac.cli.compare import print_comparison
from jaxeac.cli.flags import folder_name
from jaxeac.cli.groups import add_output_flags, add_report_flags, output_options
from jaxeac.cli.process import _claim_existing


def add_parser(sub) -> None:
    m = sub.add_parser("merge", help="merge the part folders of a multi-process `jaxeac run` into its run "
                                     "folder")
    m.add_argument("dir", type=folder_name, metavar="DIR",
                   help="the run folder given to `jaxeac run --out DIR --num-processes P`; its part-I-of-P/ "
                        "folders are joined into it")
    add_report_flags(m)
    add_output_flags(m)


def cmd_merge(args: argparse.Namespace) -> int:
    from jaxeac.experiments.grid import merge_parts, summary_table
    from jaxeac.experiments.pipeline import run_and_compare

    _claim_existing(args, args.dir)
    run = merge_parts(args.dir)

    def on_folder(run, summary) -> None:
        print(summary_table(summary))
        print(f"results in {args.dir}/")

    _, _, stats = run_and_compare(run.settings, args.dir, run=run, compare=not args.no_compare,
                                  quiet=args.quiet, options=output_options(args, run.settings.seeds),
                                  on_folder=on_folder)
    if stats is not None:
        print_comparison(stats, args.dir)
    return 0
