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
    c.add_argument("--value", metavar="COLUMN",
                   help="with a tidy table: the column of per-seed values (default value; e.g. successes)")
    c.add_argument("--tasks", metavar="T1,T2",
                   help="with a table holding a task column: compare these tasks only")
    c.add_argument("--normalize", choices=("minmax", "baseline", "none"),
                   help="with several tasks: put scores on one scale for the aggregates across tasks: minmax "
                        "(with --reference-scores), baseline (divide by --baseline's mean per task) or none")
    c.add_argument("--reference-scores", metavar="CSV",
                   help="with --normalize minmax: a CSV with columns task,low,high")
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
        return compare_table_command(args, alpha)
    if args.dir is None:
        raise UsageError("compare needs a run folder or a table: jaxeac compare PATH, or --table PATH")
    if args.out is not None:
        raise UsageError("--out goes with a table; a run folder's report is written into the folder")
    for flag, given in (("--aggregate", args.aggregate), ("--value", args.value), ("--tasks", args.tasks),
                        ("--normalize", args.normalize), ("--reference-scores", args.reference_scores)):
        if given is not None:
            raise UsageError(f"{flag} goes with a table; a run folder's measures are fixed (SPEC §6)")
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
    """The paired line (where the analysis is paired: it answers), the unpaired Welch line and
    where the report is."""
    from jaxeac.fmt import compact, compact_interval, p_sig

    pct = percent(result.get("level", level))
    p = result["primary"]
    lead = f"{treatment} - {baseline} on {p['measure']}: "
    if result.get("analysis") == "paired":
        pr = result["paired"]["measures"][p["measure"]]
        print(f"{lead}paired (seed i of both shares its key): {compact(pr['mean_diff'], 4, sign=True)} "
              f"({pct} paired BCa CI {compact_interval(pr['mean_diff_ci'], 4)}), "
              f"paired t p = {p_sig(pr['p_paired_t'])}, d_z = {compact(pr['d_z'])}, "
              f"r = {compact(pr['correlation'], 2)}")
        lead = "  unpaired (secondary): "
    lo, hi = p["diff_ci"]
    print(f"{lead}{p['diff']:+.3f} ({pct} BCa CI [{lo:+.3f}, {hi:+.3f}]), "
          f"Welch p = {p_sig(p['p_welch'])}, Hedges' g = {p['hedges_g']:.3f}, A12 = {p['a12']:.3f}")
    if result.get("family"):  # a run of more algorithms: each against the baseline, Holm over them
        from jaxeac.stats.family import family_comparison

        print(f"every algorithm against {baseline} (the declared family):")
        print("\n".join(f"  {line}" for line in family_comparison(result["family"]).lines()[1:]))
    print(f"report in {run_dir}/{result.get('files', {}).get('report', 'report.md')}")


def table_stem(baseline, treatment) -> str:
    """The name of a table comparison's files: every family has its own, so none replaces another's."""
    if baseline is None:
        return "table"
    return f"{baseline}_vs_{treatment}" if treatment is not None else f"vs_{baseline}"


def read_reference(path) -> dict:
    """--reference-scores FILE: a CSV with columns task, low, high."""
    from jaxeac.perseed import _frame, _labels, _numeric

    frame = _frame(Path(path))
    frame.columns = [str(c).strip() for c in frame.columns]
    for col in ("task", "low", "high"):
        if col not in frame.columns:
            raise UsageError(f"--reference-scores {path}: no column {col!r}; "
                             "give a CSV with columns task,low,high")
    tasks = _labels(frame, "task", str(path))
    low, high = _numeric(frame, "low", str(path)), _numeric(frame, "high", str(path))
    return {t: (lo, hi) for t, lo, hi in zip(tasks, low, high, strict=True)}


def compare_table_command(args: argparse.Namespace, alpha: float) -> int:
    """`jaxeac compare --table PATH`: every pair (or each against --baseline) of a table's algorithms,
    per task, and the aggregate across tasks (`jaxeac.stats.engine.compare`)."""
    import json

    from jaxeac.io import staged_dir
    from jaxeac.perseed import default_out
    from jaxeac.stats.engine import compare

    if args.dir is not None:
        raise UsageError(f"pass either a run folder ({args.dir}) or --table, not both")
    reference = read_reference(args.reference_scores) if args.reference_scores else None
    tasks = [t.strip() for t in args.tasks.split(",")] if args.tasks else None
    result = compare(args.table, baseline=args.baseline, treatment=args.treatment, level=args.level,
                     resamples=args.resamples, key=args.stats_key, value=args.value or "value",
                     aggregate=args.aggregate or "sum", tasks=tasks, normalize=args.normalize,
                     reference_scores=reference,
                     paired="paired" if args.paired else "unpaired" if args.unpaired else "auto")
    out = Path(args.out) if args.out is not None else default_out(args.table)
    stem = table_stem(args.baseline, args.treatment)
    with staged_dir(out) as stage:
        (stage / f"stats_{stem}.json").write_text(
            json.dumps(result.to_dict(), indent=2, allow_nan=True) + "\n")
        (stage / f"report_{stem}.md").write_text(result.markdown())
    for line in result.lines():
        print(line)
    print(f"report in {out}/report_{stem}.md")
    return 0
