"""`jaxeac sweep`: a resumable sweep over grid settings, AC and EAC at each point."""

from __future__ import annotations

import argparse
import sys

from jaxeac.cli.checks import fit_sweep
from jaxeac.cli.flags import add_renamed, folder_name
from jaxeac.cli.groups import add_grid_flags, grid_settings


def add_parser(sub) -> None:
    w = sub.add_parser("sweep", help="resumable sweep over grid settings, AC and EAC at each point")
    add_grid_flags(w)
    w.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="values of one swept key: alpha, beta, gamma, temperature, epsilon, trials, chances, "
                        "slip, preset, map (repeat for a product)")
    w.add_argument("--out", type=folder_name, default="runs/sweep", metavar="DIR",
                   help="sweep folder (default runs/sweep)")
    w.add_argument("--point-reports", action="store_true",
                   help="also write the statistics report of every point (as `jaxeac compare`; default: "
                        "none, the sweep's table only)")
    w.add_argument("--quiet", action="store_true", help="no progress bar")
    add_renamed(w, "--compare", "--point-reports (a report at every point)")


def cmd_sweep(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from jaxeac.cli.process import _claim_out
    from jaxeac.experiments.sweep import Sweep, figure_name, format_table, run_sweep

    base = grid_settings(args)
    base.resolved()  # validate the flags before the swept values
    sweep = Sweep.build(base, args.sets)
    sweep = fit_sweep(sweep)  # sizes that cannot fit or finish fail here, at any point
    _claim_out(args, args.out, kind="sweep")
    total = len(sweep.points()) * base.seeds * len(base.algos)
    with tqdm(total=total, unit="run", disable=args.quiet, desc="sweep", file=sys.stderr) as bar:
        rows = run_sweep(sweep, args.out, progress=bar.update, compare=args.point_reports)
    print(format_table(sweep, rows))
    print(f"{len(sweep.points())} points x {len(base.algos)} algorithms x {base.seeds:,} seeds; "
          f"{len(rows)} rows in {args.out}/results.csv; figure {args.out}/{figure_name(sweep)}")
    return 0
