"""The `jaxeac` command line: `jaxeac grid`, `jaxeac compare`, ...

Bad input prints one line ``error: ...`` on stderr and exits with code 2, before
any compute and without writing result files. Argument types, flag groups and the
checks run before compute are in `jaxeac.cli_args`; this module holds the parser, one
function per subcommand and the top-level fault handling (under 500 lines,
kept together so every command's path from flags to files reads in one place).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
from collections.abc import Sequence
from concurrent.futures import Future

from jaxeac.cli_args import (  # noqa: F401  (the flag types, importable from here as before)
    KEY_LIMIT,
    MIN_CONTACT_CAP,
    MIN_TEST_ALPHA,
    Parser,
    add_compare_flags,
    add_grid_flags,
    add_output_flags,
    add_sequential_flags,
    add_solver_flags,
    check_compare_size,
    finite_float,
    fit_grid,
    fit_sweep,
    folder_name,
    host_port,
    int_at_least,
    nonneg_int,
    positive_int,
    prng_key,
    render_path,
    render_targets,
    sequential_design,
    show,
    solver_settings,
)
from jaxeac import runtime
from jaxeac.errors import UsageError


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="jaxeac", description="Vectorised AC vs EAC (Debnath & Nassour 2014).")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    for name, text in (("grid", "run AC and EAC on the grid world (or --env NAME) over many seeds"),
                       ("run", "run AC, EAC and baselines on a registered environment (--env NAME) over many "
                               "seeds")):
        g = sub.add_parser(name, help=text)
        add_grid_flags(g, env_required=name == "run")
        g.add_argument("--out", type=folder_name, default=f"runs/{name}", metavar="DIR",
                       help=f"run folder (default runs/{name})")
        g.add_argument("--no-compare", action="store_true", help="skip the statistics report at the end")
        g.add_argument("--quiet", action="store_true", help="no progress bar")
        add_output_flags(g)
        add_sequential_flags(g)
        g.add_argument("--num-processes", type=positive_int, default=1, metavar="P",
                       help="split the seeds over P processes (hosts); each writes DIR/part-I-of-P/")
        g.add_argument("--process-id", type=nonneg_int, default=0, metavar="I", help="this process, 0..P-1")
        g.add_argument("--coordinator", type=host_port, metavar="HOST:PORT",
                       help="call jax.distributed.initialize with this coordinator (multi-host JAX)")

    m = sub.add_parser("merge", help="merge the part folders of a multi-process `jaxeac grid` run")
    m.add_argument("dir", type=folder_name, metavar="DIR")
    m.add_argument("--no-compare", action="store_true", help="skip the statistics report")
    m.add_argument("--quiet", action="store_true")
    add_output_flags(m)

    b = sub.add_parser("bowling", help="run AC and EAC learning to bowl in MuJoCo over many seeds")
    b.add_argument("--seeds", type=positive_int, default=1000, metavar="N", help="seeds per algorithm")
    b.add_argument("--trials", type=positive_int, default=10, metavar="T", help="trials (default 10, B5)")
    b.add_argument("--angles", type=int, default=21, metavar="K", help="shoulder angles K >= 2 (B2)")
    b.add_argument("--theta-max", type=finite_float, default=0.1, metavar="X", help="largest |θ| in rad")
    b.add_argument("--noise-angle", type=finite_float, default=0.003, metavar="S",
                   help="s.d. of the angle noise in rad (B3)")
    b.add_argument("--noise-speed", type=finite_float, default=0.1, metavar="S",
                   help="s.d. of the release-speed noise in m/s (B3)")
    b.add_argument("--backend", default="auto", metavar="auto|c|mjx|warp",
                   help="physics backend (B7; default auto: c on CPUs, warp on NVIDIA GPUs with warp-lang, else "
                        "mjx; warp: MJX on NVIDIA GPUs via MuJoCo Warp)")
    add_solver_flags(b)
    b.add_argument("--scene", default="default", metavar="default|table1",
                   help="ball and pin deck (B1; table1: a smaller ball and wider deck whose first throws "
                        "are like the paper's Table I, B1a)")
    b.add_argument("--state", default="mask", metavar="mask|tree",
                   help="mask: the standing pins (B5, default); tree: chance 2 keyed on the chance-1 angle, "
                        "the paper's Fig. 5 tree (B5a)")
    b.add_argument("--success-pins", type=positive_int, default=10, metavar="N",
                   help="pins a trial must knock to succeed (B5b; default 10, all down)")
    b.add_argument("--algos", nargs="+", default=["ac", "eac"], metavar="ALGO")
    b.add_argument("--alpha", type=finite_float, default=0.1, metavar="A", help="critic step size α")
    b.add_argument("--beta", type=finite_float, default=0.3, metavar="B", help="actor step size β")
    b.add_argument("--gamma", type=finite_float, default=1.0, metavar="G", help="discount γ (B5: 1)")
    b.add_argument("--key", type=prng_key, default=0, metavar="K", help="root PRNG key, 0..2^32-1 (R1)")
    b.add_argument("--chunk-size", type=positive_int, default=1000, metavar="M", help="seeds per batch")
    b.add_argument("--out", type=folder_name, default="runs/bowling", metavar="DIR")
    b.add_argument("--no-compare", action="store_true", help="skip the statistics report at the end")
    b.add_argument("--quiet", action="store_true", help="no progress bar")
    add_sequential_flags(b)

    t = sub.add_parser("throw", help="throw balls at a fresh rack and print what fell (JSON)")
    t.add_argument("--angles", nargs="+", type=finite_float, required=True, metavar="A",
                   help="shoulder angles in rad, within ±theta-max")
    t.add_argument("--noise", type=finite_float, default=0.0, help="noise scale (0: deterministic)")
    t.add_argument("--backend", default="auto", metavar="auto|c|mjx|warp", help="physics backend (B7; default auto)")
    add_solver_flags(t)
    t.add_argument("--theta-max", type=finite_float, default=0.1, metavar="X")
    t.add_argument("--scene", default="default", metavar="default|table1", help="ball and pin deck (B1, B1a)")
    t.add_argument("--key", type=prng_key, default=0, metavar="K", help="noise PRNG key, 0..2^32-1")
    t.add_argument("--render", metavar="FILE.png", help="save a picture of the pin deck after the throw")

    w = sub.add_parser("sweep", help="resumable sweep over grid settings, AC and EAC at each point")
    add_grid_flags(w)
    w.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="values of one swept key: alpha, beta, gamma, temperature, epsilon, trials, chances, slip, "
                        "preset, map (repeat for a product)")
    w.add_argument("--out", type=folder_name, default="runs/sweep", metavar="DIR")
    w.add_argument("--compare", action="store_true", help="also run `jaxeac compare` at every point")
    w.add_argument("--quiet", action="store_true", help="no progress bar")

    st = sub.add_parser("study", help="every task x AC, EAC, its ablations, Q-learning and SARSA, compared "
                                      "with AC (resumable)")
    st.add_argument("--tasks", nargs="+", metavar="NAME[:slip=P]",
                    help="registered environments (default: the paper grid, plain and with slip 0.1, and every "
                         "classic task)")
    st.add_argument("--algos", nargs="+", metavar="ALGO", help="algorithms, ac among them (default: all)")
    st.add_argument("--seeds", type=positive_int, default=10_000, metavar="N", help="seeds per algorithm and task")
    st.add_argument("--trials", type=positive_int, metavar="T", help="trials per run (default: the preset's 200)")
    st.add_argument("--epsilon", type=finite_float, default=0.1, metavar="E", help="ε of q_learning and sarsa")
    st.add_argument("--resamples", type=positive_int, default=10_000, metavar="R", help="bootstrap resamples")
    st.add_argument("--key", type=prng_key, default=0, metavar="K", help="root PRNG key, 0..2^32-1 (R1)")
    st.add_argument("--chunk-size", type=positive_int, default=None, metavar="M", help="seeds per compiled batch")
    st.add_argument("--lanes", type=positive_int, default=None, metavar="L",
                    help="seeds in flight per device (default: automatic; results do not depend on it)")
    st.add_argument("--out", type=folder_name, default="runs/study", metavar="DIR")
    st.add_argument("--quiet", action="store_true", help="no progress lines")

    r = sub.add_parser("reproduce", help="re-run both of the paper's experiments at scale, with a verdict")
    r.add_argument("--quick", action="store_true", help="fewer seeds: a few minutes on a laptop CPU")
    r.add_argument("--out", type=folder_name, default="runs/reproduce", metavar="DIR")
    r.add_argument("--key", type=prng_key, default=0, metavar="K", help="root PRNG key, 0..2^32-1 (R1)")
    r.add_argument("--quiet", action="store_true", help="no progress bars")

    c = sub.add_parser("compare", help="statistics report comparing two algorithms of a run folder, "
                       "or any algorithms of a table (--table)")
    c.add_argument("dir", type=folder_name, metavar="DIR", nargs="?",
                   help="a run folder written by `jaxeac grid` or `jaxeac bowling`")
    c.add_argument("--table", type=folder_name, metavar="PATH",
                   help="instead of DIR: a tidy table (CSV or Parquet: algo, seed[, trial], value), an "
                        "rliable .npz ([runs, tasks] per algorithm) or a folder of SB3 monitor files")
    c.add_argument("--aggregate", choices=("sum", "mean", "last"), default=None,
                   help="with --table and a trial column: per-seed value = sum (default), mean or last "
                        "over trials")
    c.add_argument("--out", type=folder_name, metavar="DIR",
                   help="with --table: output folder (default: <table stem>_compare beside the table)")
    add_compare_flags(c)
    c.set_defaults(baseline=None, treatment=None)  # run folders: ac and eac; tables: all pairs
    return parser


def _claim_out(args: argparse.Namespace, path, lock_path=None, kind: str = "run", reads: bool = False):
    """Check the output folder `path` and hold it (or `lock_path`, a part of it) for the rest of the
    command: a second run into the same folder is refused until this one ends, and a folder holding
    another kind of output (`jaxeac.io.folder_kind`) is refused before any compute."""
    from jaxeac.io import check_folder_kind, check_writable_dir, folder_lock

    check_folder_kind(path, kind, reads=reads)
    stack = getattr(args, "_cleanup", None)
    if stack is not None:
        stack.enter_context(folder_lock(lock_path or path))
    return check_writable_dir(path)


def _claim_existing(args: argparse.Namespace, path) -> None:
    """Hold a run folder that a command reads and then writes into (compare, merge), if it exists."""
    from pathlib import Path

    if Path(path).is_dir():
        _claim_out(args, path, reads=True)


def _init_distributed(args: argparse.Namespace) -> None:
    """jax.distributed.initialize with --coordinator (once); failures are one-line errors."""
    if not getattr(args, "coordinator", None) or getattr(args, "_distributed", False):
        return
    import socket

    import jax

    host, _, port = args.coordinator.rpartition(":")
    try:
        socket.getaddrinfo(host.strip("[]"), int(port))
    except (OSError, UnicodeError) as exc:
        raise UsageError(f"--coordinator {args.coordinator}: cannot resolve host {host} "
                         f"({getattr(exc, 'strerror', None) or exc}); check the name") from None
    try:
        jax.distributed.initialize(args.coordinator, args.num_processes, args.process_id)
    except Exception as exc:  # noqa: BLE001 - RPC, bind and timeout errors of the runtime
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
        raise UsageError(f"--coordinator {args.coordinator}: could not start or reach the coordinator "
                         f"({first}); check the address, the port and that process 0 runs") from None
    args._distributed = True


def cmd_grid(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from jaxeac.experiments.grid import part_folder, run_grid_to_folder, summary_table

    settings = _grid_settings(args).resolved()
    env = settings.make_env()  # a bad map or environment fails here, before any compute
    if args.process_id >= args.num_processes:
        raise UsageError(f"--process-id {args.process_id} must be below --num-processes {args.num_processes}")
    if args.num_processes > settings.seeds:
        raise UsageError(f"--num-processes {args.num_processes} exceeds --seeds {settings.seeds}")
    if args.coordinator and args.num_processes == 1:
        raise UsageError("--coordinator only applies to a multi-process run; add --num-processes P "
                         "--process-id I, or drop --coordinator")
    _init_distributed(args)  # before the size check: JAX's backends must not have started yet
    settings = fit_grid(args, settings, env)  # sizes that cannot fit or finish fail here
    design = sequential_design(args, settings)  # a bad design fails here too
    part = part_folder(args.out, args.process_id, args.num_processes) if args.num_processes > 1 else None
    out = _claim_out(args, args.out, part)
    if args.num_processes > 1:
        return _grid_part(args, settings, out)
    if design is not None:
        return _grid_sequential(args, settings, design, out)
    ahead = _compile_statistics_ahead(settings, compare=not args.no_compare)
    statistics: list[Future] = []  # the comparison's statistics, started as soon as the results are in

    def start_statistics(run) -> None:
        if _compares(run, compare=not args.no_compare) and _statistics_beside_figures(settings.seeds):
            statistics.append(_start_statistics(run, out, ahead))

    with tqdm(total=settings.seeds * len(settings.algos), unit="seed", disable=args.quiet,
              desc="grid", file=sys.stderr) as bar:  # results.parquet is written as the run goes
        run, summary = run_grid_to_folder(settings, out, options=_output_options(args, settings.seeds),
                                          progress=bar.update, on_results=start_statistics)
    print(summary_table(summary))
    print(f"results in {out}/")
    if ahead is not None and not statistics:
        ahead.join()  # the comparison's programs, in the cache before it starts
    return _compare_grid(run, out, compare=not args.no_compare, quiet=args.quiet,
                         analysed=statistics[0] if statistics else None)


#: Per JAX backend, whether `jaxeac grid` computes the comparison's statistics beside the run's own
#: figures (`_start_statistics`). On one H100 the build that brought it (with the pipeline's and the
#: command's end's changes) took the 10^6-seed command's median first run from 17.9 to 16.2 s, same
#: sitting (record gpu_h100_e2e_1m_builds.json); on the 2-core CPU, where E8 follows the run on every
#: core, it gained nothing and held 0.15 GiB more (cpu_e2e_grid_100k_builds.json).
STATISTICS_BESIDE_FIGURES = {"gpu": True, "tpu": True}
#: Up to this many seeds per method: above it the run's other per-seed columns and the statistics'
#: copies would be in host memory at once. At 10^7 seeds on one H100 overlapping raised the peak
#: RSS from 3.0-3.3 GiB to 3.8-4.2 GiB (records gpu_h100_e2e_10m_grow.json and
#: gpu_h100_e2e_10m_overlap.json).
STATISTICS_BESIDE_FIGURES_SEEDS = 1 << 22


def _statistics_beside_figures(seeds: int) -> bool:
    """Whether a grid run of `seeds` seeds per method computes its statistics beside its figures."""
    import jax

    beside = STATISTICS_BESIDE_FIGURES.get(jax.default_backend(), False)
    return beside and seeds <= STATISTICS_BESIDE_FIGURES_SEEDS


def _start_statistics(run, out, ahead) -> Future:
    """`analyse_run_data` of a grid run just finished, on a thread, while the main thread draws
    and writes the run's own figures: a future of (stats, figures' data). It starts once the
    comparison's programs compiled ahead (`ahead`, a thread or None) are in the cache."""
    from concurrent.futures import ThreadPoolExecutor

    from jaxeac.stats.run import analyse_run_data

    data = _grid_run_data(run, out)

    def work():
        if ahead is not None:
            ahead.join()
        return analyse_run_data(data)

    pool = ThreadPoolExecutor(max_workers=1)
    future = pool.submit(work)
    pool.shutdown(wait=False)  # the thread ends with its job
    return future


def _compile_statistics_ahead(settings, *, compare: bool):
    """On accelerators, compile the comparison's device programs on a thread while the run
    computes (`jaxeac.stats.large.compile_ahead`: they land in the compilation cache). On
    CPUs the run needs every core, so nothing is started. Returns the thread, or None."""
    import threading

    import jax

    if not compare or jax.default_backend() == "cpu":
        return None
    from jaxeac.stats import large
    from jaxeac.stats.run import CALIBRATION_SPLITS

    def work() -> None:
        with contextlib.suppress(Exception):  # only a head start: the comparison compiles anyway
            large.compile_ahead(settings.seeds, settings.trials, splits=CALIBRATION_SPLITS)

    thread = threading.Thread(target=work, daemon=True)
    thread.start()
    return thread


def _grid_sequential(args: argparse.Namespace, settings, design, out) -> int:
    """`jaxeac grid --sequential`: batches of seeds until a look decides (`run_grid_sequential`)."""
    from jaxeac.experiments.grid import run_grid_sequential, summary_table
    from jaxeac.fmt import sequential_look

    def on_look(result: dict) -> None:
        if not args.quiet:
            print(sequential_look(result, design.effect, "successes"), file=sys.stderr, flush=True)

    run, summary = run_grid_sequential(settings, out, design, options=_output_options(args, design.sizes[-1]),
                                       on_look=on_look)
    print(summary_table(summary))
    seq = summary["sequential"]
    print(f"sequential decision: {seq['decision']} after {len(seq['looks_taken'])} of {design.looks} looks "
          f"({seq['seeds_used']} seeds per method, {seq['seconds_to_decision']:.1f} s)")
    print(f"results in {out}/")
    return _compare_grid(run, out, compare=not args.no_compare, quiet=args.quiet, sequential=seq)


def _output_options(args: argparse.Namespace, n_seeds: int):
    from jaxeac.experiments.results import OutputOptions

    return OutputOptions.auto(n_seeds, full=True if getattr(args, "full_outputs", False) else None,
                              csv=True if getattr(args, "per_seed_csv", False) else None)


def _finish_grid(run, out, *, compare: bool, quiet: bool, options=None) -> int:
    from jaxeac.experiments.grid import summary_table, write_grid_outputs

    summary = write_grid_outputs(run, out, options=options)
    print(summary_table(summary))
    print(f"results in {out}/")
    return _compare_grid(run, out, compare=compare, quiet=quiet)


def _compares(run, *, compare: bool) -> bool:
    """Whether `jaxeac grid` compares this run (AC and EAC, at least two seeds each)."""
    return compare and {"ac", "eac"} <= set(run.settings.algos) and run.settings.seeds >= 2


def _grid_run_data(run, out, sequential: dict | None = None):
    """The comparison's view (`RunData`) of a grid run in memory: its success curves."""
    from pathlib import Path

    from jaxeac.stats.rundir import RunData

    return RunData(Path(out), "grid", "successes", tuple(run.settings.algos), run.settings.trials,
                   {a: r.success for a, r in run.results.items()}, {}, {}, sequential)


def _compare_grid(run, out, *, compare: bool, quiet: bool, sequential: dict | None = None,
                  analysed: Future | None = None) -> int:
    """The statistics report of a grid run just written, from its results in memory (`analysed`:
    its statistics, already started by `_start_statistics`). The folder is written, so all but
    the success curves are dropped from `run` first: the statistics get the memory of the other
    per-seed columns."""
    if not _compares(run, compare=compare):
        return 0
    from jaxeac.runtime import trim_host_memory

    data = _grid_run_data(run, out, sequential)
    run.results = {}
    trim_host_memory()  # what the run and its figures freed, before the statistics start
    return run_compare(out, quiet=quiet, data=data, analysed=analysed)


def _grid_part(args: argparse.Namespace, settings, out) -> int:
    """One process of a multi-process run: its block of seeds into DIR/part-I-of-P/."""
    from jaxeac.experiments.grid import part_folder, process_share, run_grid, write_grid_outputs
    from jaxeac.experiments.results import CSV_SEEDS, OutputOptions

    _init_distributed(args)  # once (cmd_grid has done it), before anything starts JAX's backends
    first, n = process_share(settings.seeds, args.process_id, args.num_processes)
    run = run_grid(settings, first_seed=first, n_seeds=n)
    folder = part_folder(out, args.process_id, args.num_processes)
    write_grid_outputs(run, folder, figures=False,  # parts keep everything `jaxeac merge` joins
                       options=OutputOptions(trial_steps=True, policies=True, per_seed_csv=n <= CSV_SEEDS))
    print(f"seeds {first}..{first + n - 1} in {folder}/; when every part is done: jaxeac merge {out}")
    return 0


def cmd_merge(args: argparse.Namespace) -> int:
    from jaxeac.experiments.grid import merge_parts

    _claim_existing(args, args.dir)
    run = merge_parts(args.dir)
    return _finish_grid(run, args.dir, compare=not args.no_compare, quiet=args.quiet,
                        options=_output_options(args, run.settings.seeds))


def run_compare(run_dir, *, baseline="ac", treatment="eac", resamples=10_000, alpha=0.05, key=0,
                quiet=False, data=None, unpaired=False, require_paired=False, analysed=None) -> int:
    from jaxeac.fmt import p_value
    from jaxeac.stats import compare_run_dir

    result = compare_run_dir(run_dir, baseline=baseline, treatment=treatment, resamples=resamples,
                             alpha=alpha, key=key, progress=not quiet, data=data, unpaired=unpaired,
                             require_paired=require_paired, analysed=analysed)
    if result.get("analysis") == "paired":
        from jaxeac.fmt import compact, compact_interval

        pr = result["paired"]["measures"][result["primary"]["measure"]]
        print(f"paired (seed i of both shares its key): {treatment} - {baseline} on "
              f"{result['primary']['measure']}: {compact(pr['mean_diff'], 4, sign=True)} "
              f"(95% paired BCa CI {compact_interval(pr['mean_diff_ci95'], 4)}), "
              f"paired t p = {p_value(pr['p_paired_t'], 3, sci_below=None, general=True)}, "
              f"d_z = {compact(pr['d_z'])}, r = {compact(pr['correlation'], 2)}")
    p = result["primary"]
    lo, hi = p["diff_ci95"]
    print(f"{treatment} - {baseline} on {p['measure']}: {p['diff']:+.3f} "
          f"(95% BCa CI [{lo:+.3f}, {hi:+.3f}]), "
          f"Welch p = {p_value(p['p_welch'], 3, sci_below=None, general=True)}, "
          f"Hedges' g = {p['hedges_g']:.3f}, A12 = {p['a12']:.3f}")
    print(f"report in {run_dir}/report.md")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    if not (MIN_TEST_ALPHA <= args.test_alpha < 1):
        why = "" if not 0 < args.test_alpha < 1 else ": smaller levels are beyond double precision"
        raise UsageError(f"--alpha must lie in [{MIN_TEST_ALPHA:g}, 1) (got {args.test_alpha:g}){why}; "
                         "e.g. --alpha 0.05")
    if args.table is not None:
        if args.paired or args.unpaired:
            flag = "--paired" if args.paired else "--unpaired"
            raise UsageError(f"{flag} applies to run folders; a --table comparison is unpaired (its "
                             "algorithms' seeds need not match); drop the flag")
        return compare_table_command(args)
    if args.dir is None:
        raise UsageError("compare needs a run folder DIR or --table PATH")
    if args.out is not None:
        raise UsageError("--out goes with --table; a run folder's report is written into the folder")
    if args.aggregate is not None:
        raise UsageError("--aggregate goes with --table; a run folder's measures are fixed (SPEC §6)")
    check_compare_size(args.dir, args.resamples)
    _claim_existing(args, args.dir)
    return run_compare(args.dir, baseline=args.baseline or "ac", treatment=args.treatment or "eac",
                       resamples=args.resamples, alpha=args.test_alpha, key=args.stats_key,
                       unpaired=args.unpaired, require_paired=args.paired)


def compare_table_command(args: argparse.Namespace) -> int:
    """`jaxeac compare --table PATH`: every pair (or each against --baseline) of a table's algorithms."""
    from jaxeac.fmt import p_value
    from jaxeac.stats.tidy import compare_table

    if args.dir is not None:
        raise UsageError(f"pass either a run folder ({args.dir}) or --table, not both")
    result, out = compare_table(args.table, args.out, aggregate=args.aggregate or "sum",
                                baseline=args.baseline, treatment=args.treatment, resamples=args.resamples,
                                alpha=args.test_alpha, key=args.stats_key)
    print(f"{result['per_seed_value']}; family: {result['family']}, Holm over "
          f"{result['comparisons_in_family']} comparison(s)")
    for r in result["comparisons"]:
        lo, hi = r["diff_ci95"]
        plo, phi = r["p_improvement_ci95"]
        print(f"{r['x']} - {r['y']}: {r['diff']:+.4g} (95% CI [{lo:+.4g}, {hi:+.4g}]), "
              f"Holm p = {p_value(r['p_holm'], 3, sci_below=None, general=True)}, "
              f"P({r['x']} > {r['y']}) = {r['p_improvement']:.3f} [{plo:.3f}, {phi:.3f}]")
    print(f"report in {out}/report_table.md")
    return 0


def cmd_bowling(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from jaxeac.experiments.bowling import BowlingSettings, run_bowling, table_one, write_bowling_outputs

    settings = BowlingSettings(
        seeds=args.seeds, trials=args.trials, angles=args.angles, theta_max=args.theta_max,
        noise_angle=args.noise_angle, noise_speed=args.noise_speed, backend=args.backend,
        algos=tuple(args.algos), key=args.key, chunk_size=args.chunk_size, alpha=args.alpha,
        beta=args.beta, gamma=args.gamma, solver=solver_settings(args), scene=args.scene, state=args.state,
        success_pins=args.success_pins,
    )
    settings.validate()
    settings = settings.resolved()  # the backend `auto` picks here, recorded in summary.json
    from jaxeac.experiments.common import check_bowling_resources

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


def cmd_throw(args: argparse.Namespace) -> int:
    import json

    from jaxeac.envs.bowling import BowlingConfig, throw_command
    from jaxeac.envs.bowling.scene import check_scene

    cfg = BowlingConfig(theta_max=args.theta_max, solver=solver_settings(args), scene=check_scene(args.scene))
    render = None if args.render is None else render_path(args.render, len(args.angles))
    targets = [] if render is None else render_targets(render, len(args.angles))
    fresh = [t for t in targets if not t.exists()]
    try:
        result = throw_command(args.angles, args.noise, args.backend, render, cfg, seed=args.key)
    except BaseException:  # a full disk, Ctrl-C: no half-drawn picture is left behind
        for target in fresh:
            with contextlib.suppress(OSError):
                target.unlink()
        raise
    print(json.dumps(result))
    return 0


def _grid_settings(args: argparse.Namespace):
    from jaxeac.experiments.grid import GridSettings

    return GridSettings(
        preset=args.preset, map_file=args.map_file, trials=args.trials, chances=args.chances,
        alpha=args.alpha, beta=args.beta, gamma=args.gamma, temperature=args.temperature,
        algos=tuple(args.algos), seeds=args.seeds, key=args.key, chunk_size=args.chunk_size,
        memory=args.memory, capacity=args.capacity, env=args.env, slip=args.slip, epsilon=args.epsilon,
        lanes=args.lanes,
    )


def cmd_sweep(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from jaxeac.experiments.sweep import Sweep, run_sweep

    base = _grid_settings(args)
    base.resolved()  # validate the flags before the swept values
    sweep = Sweep.build(base, args.sets)
    sweep = fit_sweep(sweep)  # sizes that cannot fit or finish fail here, at any point
    _claim_out(args, args.out, kind="sweep")
    total = len(sweep.points()) * base.seeds * len(base.algos)
    with tqdm(total=total, unit="run", disable=args.quiet, desc="sweep", file=sys.stderr) as bar:
        rows = run_sweep(sweep, args.out, progress=bar.update, compare=args.compare)
    print(f"{len(sweep.points())} points x {len(base.algos)} algorithms x {base.seeds} seeds; "
          f"{len(rows)} rows in {args.out}/results.csv")
    return 0


def cmd_study(args: argparse.Namespace) -> int:
    from jaxeac.experiments.study import DEFAULT_ALGOS, DEFAULT_TASKS, StudySettings, run_study

    settings = StudySettings(
        tasks=tuple(args.tasks or DEFAULT_TASKS), algos=tuple(args.algos or DEFAULT_ALGOS), seeds=args.seeds,
        trials=args.trials, key=args.key, epsilon=args.epsilon, resamples=args.resamples,
        chunk_size=args.chunk_size, lanes=args.lanes)
    settings.validate()  # bad names and settings fail before any compute
    from jaxeac.experiments.common import check_grid_resources

    for task in settings.tasks:  # sizes that cannot fit or finish fail here, for every task
        grid = settings.task_settings(task)
        check_grid_resources(grid, grid.make_env())
    _claim_out(args, args.out, kind="study")
    result = run_study(settings, args.out, progress=not args.quiet)
    print(f"{len(settings.tasks)} tasks x {len(settings.algos)} algorithms x {settings.seeds:,} seeds; "
          f"{result['comparisons_in_family']} comparisons with ac; report in {args.out}/report.md")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    from jaxeac.experiments.reproduce import reproduce

    _claim_out(args, args.out, kind="reproduce")
    report = reproduce(args.out, quick=args.quick, key=args.key, progress=not args.quiet)
    print(f"report in {report}")
    return 0


COMMANDS = {
    "reproduce": cmd_reproduce,
    "grid": cmd_grid, "run": cmd_grid, "sweep": cmd_sweep, "bowling": cmd_bowling, "throw": cmd_throw,
    "compare": cmd_compare, "merge": cmd_merge, "study": cmd_study,
}


def _fail(message: str, code: int = 2) -> int:
    """Print ``error: message`` as one line on stderr; return `code`."""
    line = " ".join(str(message).split("\n")).replace("\r", " ")
    # control characters (from a damaged file's bytes) would break the one line: escaped
    line = "".join(ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii") for ch in line)
    try:
        print(f"error: {line}", file=sys.stderr, flush=True)
    except (OSError, ValueError):  # stderr closed: the exit code still says it
        pass
    return code


def _out_of_device_memory(exc: BaseException) -> bool:
    """An XLA allocation failure (RESOURCE_EXHAUSTED), e.g. a chunk too large for a GPU."""
    text = str(exc)
    return type(exc).__name__ in ("XlaRuntimeError", "JaxRuntimeError") and (
        "RESOURCE_EXHAUSTED" in text or "Out of memory" in text or "out of memory" in text)


def _resend_dropped_ctrl_c(unraisable) -> None:
    """`sys.unraisablehook` while `main` runs: a Ctrl-C that landed where Python cannot raise it
    (a garbage-collection or weakref callback, a ``__del__``: JAX runs such code) would be
    printed as "Exception ignored" and dropped, and the run would carry on; instead the signal
    is sent again a moment later, to land in ordinary code. Anything else goes to the
    previous hook."""
    if unraisable.exc_type is KeyboardInterrupt:
        threading.Timer(0.01, os.kill, (os.getpid(), signal.SIGINT)).start()
        return
    _previous_unraisablehook(unraisable)


_previous_unraisablehook = sys.unraisablehook


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `jaxeac` console script; returns the exit code.

    Bad input, a full disk, a busy output folder and running out of memory are one line
    ``error: ...`` on stderr and exit code 2; Ctrl-C is one line and exit code 130. Output
    folders are held (`jaxeac.io.folder_lock`) until the command ends.
    """
    global _previous_unraisablehook
    if threading.current_thread() is not threading.main_thread():  # signals go to the main thread only
        return _main(argv)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    _previous_unraisablehook, sys.unraisablehook = sys.unraisablehook, _resend_dropped_ctrl_c
    try:
        return _main(argv)
    finally:
        signal.signal(signal.SIGINT, before)
        sys.unraisablehook = _previous_unraisablehook


def _main(argv: Sequence[str] | None) -> int:
    try:
        words = list(sys.argv[1:] if argv is None else argv)
        runtime.configure(words[0] if words else None, force=True)
        with contextlib.ExitStack() as cleanup:
            args = build_parser().parse_args(argv)
            args._cleanup = cleanup
            return COMMANDS[args.command](args)
    except UsageError as exc:
        return _fail(str(exc))
    except KeyboardInterrupt:
        code = _fail("interrupted; files already finished are kept, none is half-written", 130)
        if argv is None:  # the process's entry point: end it now, as XLA may still be running a
            with contextlib.suppress(Exception):  # chunk on its threads (tearing the interpreter
                sys.stdout.flush()  # down under it can crash); folders are cleaned up already
            os._exit(code)
        return code
    except BrokenPipeError:  # the reader of stdout stopped early (`jaxeac throw ... | head`): quietly,
        if argv is None:  # like other command-line tools; no second error when Python flushes stdout
            with contextlib.suppress(OSError, ValueError):
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, what a shell reports for such a writer
    except MemoryError:
        return _fail("out of memory: this run needs more memory than is free on this machine (nothing was "
                     "written); use fewer seeds, trials or chances, a smaller map or a smaller --chunk-size")
    except OSError as exc:
        from jaxeac.io import DiskFullError, is_disk_full

        if not is_disk_full(exc):
            raise
        if isinstance(exc, DiskFullError):
            return _fail(str(exc))
        where = f" while writing {exc.filename}" if exc.filename else ""
        return _fail(f"the disk is full (no space left on device){where}; no file is left half-written: "
                     "free some space or write elsewhere")
    except Exception as exc:
        if not _out_of_device_memory(exc):
            raise
        return _fail("out of device memory: a chunk of seeds does not fit on the accelerator (nothing was "
                     "written); pass a smaller --chunk-size, or use fewer trials or chances or a smaller map")


if __name__ == "__main__":
    sys.exit(main())
