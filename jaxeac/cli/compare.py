"""`jaxeac compare`: the statistics report of a run folder, or of any table (`--table`)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from jaxeac.cli.checks import check_compare_size
from jaxeac.cli.flags import add_renamed, alpha_of_level, folder_name, percent
from jaxeac.cli.groups import add_compare_flags
from jaxeac.cli.process import _claim_existing
from jaxeac.errors import UsageError

#: Files `jaxeac compare PATH` reads as a table, as `--table PATH` does.
TABLE_SUFFIXES = (".csv", ".parquet", ".npz")
TABLES = ("a tidy table (CSV or Parquet: algo, seed[, trial], value), an rliable .npz or a folder of SB3 "
          "monitor files")


def add_parser(sub) -> None:
    c = sub.add_parser("compare", help="statistics report comparing two algorithms of a run folder, "
                       "or any algorithms of a table (--table)")
    c.add_argument("dir", type=folder_name, metavar="PATH", nargs="?",
                   help="a run folder written by `jaxeac run` or `jaxeac bowling`; a .csv, .parquet or .npz "
                        "file, or a folder of SB3 monitor files, is read as with --table")
    c.add_argument("--table", type=folder_name, metavar="PATH", help=f"instead of a run folder: {TABLES}")
    c.add_argument("--aggregate", choices=("sum", "mean", "last"), default=None,
                   help="with a table and a trial column: per-seed value = sum (default), mean or last "
                        "over trials")
    c.add_argument("--out", type=folder_name, metavar="DIR",
                   help="with a table: output folder (default: <table stem>_compare beside the table)")
    add_compare_flags(c)
    add_renamed(c, "--alpha", "--level L, the confidence level (--level 0.95 for --alpha 0.05)")
    c.set_defaults(baseline=None, treatment=None)  # run folders: ac and eac; tables: all pairs


def _is_table(path: str) -> bool:
    """Whether a PATH given to compare is a table: a file with a table suffix, or a folder of SB3
    monitor files that is no run folder (nor another kind of output)."""
    if os.path.isfile(path):
        return Path(path).suffix.lower() in TABLE_SUFFIXES
    if os.path.isdir(path):
        from jaxeac.io import folder_kind

        return folder_kind(path) is None and next(Path(path).rglob("*monitor.csv"), None) is not None
    return False


def _check_run_folder(path: str) -> None:
    """A PATH that is neither a table nor a run folder: one line saying that `--table PATH` reads tables."""
    hint = f"--table PATH reads tables ({TABLES})"
    if not os.path.lexists(path):
        raise UsageError(f"{path} does not exist; pass a run folder, or a table: {hint}")
    if not os.path.isdir(path):
        raise UsageError(f"{path} is not a run folder (nor a {', '.join(TABLE_SUFFIXES)} table); {hint}")
    if not os.path.lexists(os.path.join(path, "summary.json")):
        raise UsageError(f"{path} has no summary.json, so it is not a run folder; {hint}")


def cmd_compare(args: argparse.Namespace) -> int:
    alpha = alpha_of_level(args.level)
    if args.dir is not None and args.table is None and _is_table(args.dir):
        args.table, args.dir = args.dir, None
    if args.table is not None:
        if args.paired or args.unpaired:
            flag = "--paired" if args.paired else "--unpaired"
            raise UsageError(f"{flag} applies to run folders; a table comparison is unpaired (its "
                             "algorithms' seeds need not match); drop the flag")
        return compare_table_command(args, alpha)
    if args.dir is None:
        raise UsageError("compare needs a run folder or a table: jaxeac compare PATH, or --table PATH")
    if args.out is not None:
        raise UsageError("--out goes with a table; a run folder's report is written into the folder")
    if args.aggregate is not None:
        raise UsageError("--aggregate goes with a table; a run folder's measures are fixed (SPEC §6)")
    check_compare_size(args.dir, args.resamples)
    _claim_existing(args, args.dir)
    _check_run_folder(args.dir)
    return run_compare(args.dir, baseline=args.baseline or "ac", treatment=args.treatment or "eac",
                       resamples=args.resamples, level=args.level, alpha=alpha, key=args.stats_key,
                       unpaired=args.unpaired, require_paired=args.paired)


def run_compare(run_dir, *, baseline="ac", treatment="eac", resamples=10_000, level=0.95, alpha=0.05, key=0,
                quiet=False, unpaired=False, require_paired=False) -> int:
    """Compare two methods of a run folder (`jaxeac.stats.compare_run_dir`) and print the result."""
    from jaxeac.stats import compare_run_dir

    result = compare_run_dir(run_dir, baseline=baseline, treatment=treatment, resamples=resamples,
                             alpha=alpha, key=key, progress=not quiet, unpaired=unpaired,
                             require_paired=require_paired)
    print_comparison(result, run_dir, baseline=baseline, treatment=treatment, level=level)
    return 0


def print_comparison(result: dict, run_dir, *, baseline="ac", treatment="eac", level=0.95) -> None:
    """The paired line (where the analysis is paired), the Welch line and where the report is."""
    from jaxeac.fmt import compact, compact_interval, p_value

    pct = percent(level)
    if result.get("analysis") == "paired":
        pr = result["paired"]["measures"][result["primary"]["measure"]]
        print(f"paired (seed i of both shares its key): {treatment} - {baseline} on "
              f"{result['primary']['measure']}: {compact(pr['mean_diff'], 4, sign=True)} "
              f"({pct} paired BCa CI {compact_interval(pr['mean_diff_ci95'], 4)}), "
              f"paired t p = {p_value(pr['p_paired_t'], 3, sci_below=None, general=True)}, "
              f"d_z = {compact(pr['d_z'])}, r = {compact(pr['correlation'], 2)}")
    p = result["primary"]
    lo, hi = p["diff_ci95"]
    print(f"{treatment} - {baseline} on {p['measure']}: {p['diff']:+.3f} "
          f"({pct} BCa CI [{lo:+.3f}, {hi:+.3f}]), "
          f"Welch p = {p_value(p['p_welch'], 3, sci_below=None, general=True)}, "
          f"Hedges' g = {p['hedges_g']:.3f}, A12 = {p['a12']:.3f}")
    print(f"report in {run_dir}/report.md")


def compare_table_command(args: argparse.Namespace, alpha: float) -> int:
    """`jaxeac compare --table PATH`: every pair (or each against --baseline) of a table's algorithms."""
    from jaxeac.fmt import p_value
    from jaxeac.stats.tidy import compare_table

    if args.dir is not None:
        raise UsageError(f"pass either a run folder ({args.dir}) or --table, not both")
    result, out = compare_table(args.table, args.out, aggregate=args.aggregate or "sum",
                                baseline=args.baseline, treatment=args.treatment, resamples=args.resamples,
                                alpha=alpha, key=args.stats_key)
    print(f"{result['per_seed_value']}; family: {result['family']}, Holm over "
          f"{result['comparisons_in_family']} comparison(s)")
    pct = percent(args.level)
    for r in result["comparisons"]:
        lo, hi = r["diff_ci95"]
        plo, phi = r["p_improvement_ci95"]
        print(f"{r['x']} - {r['y']}: {r['diff']:+.4g} ({pct} CI [{lo:+.4g}, {hi:+.4g}]), "
              f"Holm p = {p_value(r['p_holm'], 3, sci_below=None, general=True)}, "
              f"P({r['x']} > {r['y']}) = {r['p_improvement']:.3f} [{plo:.3f}, {phi:.3f}]")
    print(f"report in {out}/report_table.md")
    return 0
