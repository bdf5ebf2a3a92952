"""The `jaxeac` command line: `jaxeac grid`, `jaxeac compare`, ...

Bad input prints one line ``error: ...`` on stderr and exits with code 2, before
any compute and without writing result files.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
from collections.abc import Sequence

from jaxeac.errors import UsageError


class _Parser(argparse.ArgumentParser):
    """argparse, but errors are one line (`error: ...`) and exit code 2."""

    def error(self, message: str):  # noqa: D401 - argparse API
        raise UsageError(f"{self.prog}: {message}")


def _show(text: str, limit: int = 40) -> str:
    """A bad value for a one-line message: quoted, escaped, cut to `limit` characters."""
    return repr(text[:limit]) + ("..." if len(text) > limit else "")


def _int_at_least(minimum: int, what: str):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{_show(text)} is not an integer") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{_show(text.strip())} must be a {what} integer")
        return value

    return parse


positive_int = _int_at_least(1, "positive")  # counts: rejects 1.5, 0, -3, 'ten'
nonneg_int = _int_at_least(0, "non-negative")  # process ids, caps

KEY_LIMIT = 1 << 32  # = jaxeac.experiments.common.KEY_LIMIT


def prng_key(text: str) -> int:
    """A root PRNG key in 0..2^32-1: `jax.random.key` keeps only key mod 2^32, so a larger key
    would silently rerun a smaller one's random numbers under another name."""
    value = nonneg_int(text)
    if value >= KEY_LIMIT:
        raise argparse.ArgumentTypeError(
            f"{_show(text.strip(), 24)} is out of range: keys are 32-bit, 0..{KEY_LIMIT - 1} (a larger key "
            f"would repeat key {value % KEY_LIMIT}'s results)")
    return value


def finite_float(text: str) -> float:
    """A finite number (rejects nan, inf)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{_show(text)} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{_show(text.strip())} is not a finite number")
    return value


def host_port(text: str) -> str:
    """HOST:PORT of a coordinator: a host name, IPv4 or [IPv6] address and a port in 1..65535."""
    host, sep, port = text.strip().rpartition(":")
    example = "e.g. host0:1234 or [::1]:1234"
    if not sep or not host:
        raise argparse.ArgumentTypeError(f"{_show(text)} is not HOST:PORT ({example})")
    if not (port.isascii() and port.isdigit() and 1 <= int(port) <= 65535):
        raise argparse.ArgumentTypeError(f"port {_show(port)} of {_show(text)} must be a number in 1..65535 "
                                         f"({example})")
    bracketed = host.startswith("[") and host.endswith("]")
    name = host[1:-1] if bracketed else host
    allowed = set("0123456789abcdefABCDEF:.%") if bracketed else None
    ok = bool(name) and name.isascii() and (
        set(name) <= allowed if bracketed else all(c.isalnum() or c in ".-_" for c in name))
    if not ok:
        raise argparse.ArgumentTypeError(f"host {_show(host)} of {_show(text)} is not a host name or address "
                                         f"({example}: IPv6 addresses go in brackets)")
    return f"{host}:{int(port)}"


def folder_name(text: str) -> str:
    """An output or run folder: a non-empty name (`''` would mean the current folder) without NUL."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty name is not a folder; name one, e.g. runs/mine")
    if "\0" in text:
        raise argparse.ArgumentTypeError(f"{_show(text)} contains a NUL byte; name a folder without one")
    return text


def add_grid_flags(p: argparse.ArgumentParser) -> None:
    """The grid-world flags shared by `grid` and `sweep`; unset flags come from the preset."""
    p.add_argument("--preset", default="paper", help="settings preset (default: paper, SPEC G6)")
    p.add_argument("--map", dest="map_file", metavar="FILE", help="ASCII map file (SPEC G1)")
    p.add_argument("--trials", type=positive_int, metavar="T", help="trials per run")
    p.add_argument("--chances", type=positive_int, metavar="C", help="steps per trial (G5)")
    p.add_argument("--alpha", type=finite_float, metavar="A", help="critic step size α")
    p.add_argument("--beta", type=finite_float, metavar="B", help="actor step size β")
    p.add_argument("--gamma", type=finite_float, metavar="G", help="discount γ in [0, 1]")
    p.add_argument("--temperature", type=finite_float, metavar="TAU", help="softmax temperature τ > 0")
    p.add_argument("--algos", nargs="+", default=["ac", "eac"], metavar="ALGO",
                   help="algorithms: ac, eac, eac_success_only, eac_failure_only (default: ac eac)")
    p.add_argument("--seeds", type=positive_int, default=1000, metavar="N", help="seeds per algorithm")
    p.add_argument("--key", type=prng_key, default=0, metavar="K", help="root PRNG key, 0..2^32-1 (R1)")
    p.add_argument("--chunk-size", type=positive_int, default=None, metavar="M",
                   help="seeds per compiled batch; bounds memory (default: chosen for the backend and "
                        "free device memory; results do not depend on it)")
    p.add_argument("--memory", default="dense", metavar="LAYOUT", help="memory layout: dense | buffer (E7)")
    p.add_argument("--capacity", type=positive_int, default=1024, metavar="K",
                   help="slots per memory for --memory buffer")


def add_output_flags(p: argparse.ArgumentParser) -> None:
    """What a grid run folder holds beyond results.parquet's per-seed measures and success curves."""
    p.add_argument("--full-outputs", action="store_true",
                   help="keep per-trial steps and final policies at any seed count "
                        "(default: up to 100,000 seeds)")
    p.add_argument("--per-seed-csv", action="store_true",
                   help="write per_seed.csv at any seed count (default: up to 100,000 seeds)")


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


#: The smallest --contact-cap that keeps the physics: MJX caps each condim group of candidate
#: contacts, and the pins' 30 foot-floor contacts form one group (envs/bowling/xmls/bowling.xml),
#: so a lower cap drops feet of standing pins and changes which pins fall.
MIN_CONTACT_CAP = 30


def _solver_settings(args: argparse.Namespace):
    """The SolverSettings of the flags add_solver_flags adds (validated on construction)."""
    from jaxeac.envs.bowling import SolverSettings

    if args.contact_cap < MIN_CONTACT_CAP:
        raise UsageError(f"--contact-cap {args.contact_cap} is below {MIN_CONTACT_CAP}: the pins' "
                         f"{MIN_CONTACT_CAP} foot contacts form one contact group, so a lower cap drops "
                         f"feet of standing pins and changes the physics; use {MIN_CONTACT_CAP} or more "
                         "(default 32)")
    return SolverSettings(args.solver, args.iterations, args.ls_iterations, args.contact_cap, args.pair_cap)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="jaxeac", description="Vectorised AC vs EAC (Debnath & Nassour 2014).")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    g = sub.add_parser("grid", help="run AC and EAC on the grid world over many seeds")
    add_grid_flags(g)
    g.add_argument("--out", type=folder_name, default="runs/grid", metavar="DIR",
                   help="run folder (default runs/grid)")
    g.add_argument("--no-compare", action="store_true", help="skip the statistics report at the end")
    g.add_argument("--quiet", action="store_true", help="no progress bar")
    add_output_flags(g)
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
    b.add_argument("--backend", default="c", metavar="c|mjx|warp",
                   help="physics backend (B7; default c; warp: MJX on NVIDIA GPUs via MuJoCo Warp)")
    add_solver_flags(b)
    b.add_argument("--algos", nargs="+", default=["ac", "eac"], metavar="ALGO")
    b.add_argument("--alpha", type=finite_float, default=0.1, metavar="A", help="critic step size α")
    b.add_argument("--beta", type=finite_float, default=0.3, metavar="B", help="actor step size β")
    b.add_argument("--gamma", type=finite_float, default=1.0, metavar="G", help="discount γ (B5: 1)")
    b.add_argument("--key", type=prng_key, default=0, metavar="K", help="root PRNG key, 0..2^32-1 (R1)")
    b.add_argument("--chunk-size", type=positive_int, default=1000, metavar="M", help="seeds per batch")
    b.add_argument("--out", type=folder_name, default="runs/bowling", metavar="DIR")
    b.add_argument("--no-compare", action="store_true", help="skip the statistics report at the end")
    b.add_argument("--quiet", action="store_true", help="no progress bar")

    t = sub.add_parser("throw", help="throw balls at a fresh rack and print what fell (JSON)")
    t.add_argument("--angles", nargs="+", type=finite_float, required=True, metavar="A",
                   help="shoulder angles in rad, within ±theta-max")
    t.add_argument("--noise", type=finite_float, default=0.0, help="noise scale (0: deterministic)")
    t.add_argument("--backend", default="c", metavar="c|mjx|warp")
    add_solver_flags(t)
    t.add_argument("--theta-max", type=finite_float, default=0.1, metavar="X")
    t.add_argument("--key", type=prng_key, default=0, metavar="K", help="noise PRNG key, 0..2^32-1")
    t.add_argument("--render", metavar="FILE.png", help="save a picture of the pin deck after the throw")

    w = sub.add_parser("sweep", help="resumable sweep over grid settings, AC and EAC at each point")
    add_grid_flags(w)
    w.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="values of one swept key: alpha, beta, gamma, temperature, trials, chances, "
                        "preset, map (repeat for a product)")
    w.add_argument("--out", type=folder_name, default="runs/sweep", metavar="DIR")
    w.add_argument("--compare", action="store_true", help="also run `jaxeac compare` at every point")
    w.add_argument("--quiet", action="store_true", help="no progress bar")

    r = sub.add_parser("reproduce", help="re-run both of the paper's experiments at scale, with a verdict")
    r.add_argument("--quick", action="store_true", help="fewer seeds: a few minutes on a laptop CPU")
    r.add_argument("--out", type=folder_name, default="runs/reproduce", metavar="DIR")
    r.add_argument("--key", type=prng_key, default=0, metavar="K", help="root PRNG key, 0..2^32-1 (R1)")
    r.add_argument("--quiet", action="store_true", help="no progress bars")

    c = sub.add_parser("compare", help="statistics report comparing two algorithms of a run folder")
    c.add_argument("dir", type=folder_name, metavar="DIR",
                   help="a run folder written by `jaxeac grid` or `jaxeac bowling`")
    add_compare_flags(c)
    return parser


def add_compare_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--baseline", default="ac", help="baseline algorithm (default ac)")
    p.add_argument("--treatment", default="eac", help="treatment algorithm (default eac)")
    p.add_argument("--resamples", type=positive_int, default=10_000, metavar="R",
                   help="bootstrap and permutation resamples (default 10000)")
    p.add_argument("--alpha", dest="test_alpha", type=finite_float, default=0.05,
                   help="significance level (default 0.05)")
    p.add_argument("--key", dest="stats_key", type=prng_key, default=0, metavar="K",
                   help="PRNG key of the resampling, 0..2^32-1")


def _claim_out(args: argparse.Namespace, path, lock_path=None):
    """Check the output folder `path` and hold it (or `lock_path`, a part of it) for the rest of the
    command: a second run into the same folder is refused until this one ends."""
    from jaxeac.io import check_writable_dir, folder_lock

    stack = getattr(args, "_cleanup", None)
    if stack is not None:
        stack.enter_context(folder_lock(lock_path or path))
    return check_writable_dir(path)


def _claim_existing(args: argparse.Namespace, path) -> None:
    """Hold a run folder that a command reads and then writes into (compare, merge), if it exists."""
    from pathlib import Path

    if Path(path).is_dir():
        _claim_out(args, path)


def _fit_grid(args: argparse.Namespace, settings, grid_map):
    """Refuse sizes that cannot fit in memory or finish (`check_grid_resources`), with the numbers;
    an automatic chunk size that would not fit becomes the largest that does."""
    import dataclasses

    from jaxeac.experiments.common import check_grid_resources
    from jaxeac.experiments.grid import process_share

    first, n = process_share(settings.seeds, args.process_id, args.num_processes)
    chunk = check_grid_resources(settings, grid_map, n_seeds=n, first_seed=first)
    return settings if chunk == settings.chunk_size else dataclasses.replace(settings, chunk_size=chunk)


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

    from jaxeac.experiments.grid import part_folder, run_grid

    settings = _grid_settings(args).resolved()
    grid_map = settings.grid_map()  # a bad map fails here, before any compute
    if args.process_id >= args.num_processes:
        raise UsageError(f"--process-id {args.process_id} must be below --num-processes {args.num_processes}")
    if args.num_processes > settings.seeds:
        raise UsageError(f"--num-processes {args.num_processes} exceeds --seeds {settings.seeds}")
    if args.coordinator and args.num_processes == 1:
        raise UsageError("--coordinator only applies to a multi-process run; add --num-processes P "
                         "--process-id I, or drop --coordinator")
    _init_distributed(args)  # before the size check: JAX's backends must not have started yet
    settings = _fit_grid(args, settings, grid_map)  # sizes that cannot fit or finish fail here
    part = part_folder(args.out, args.process_id, args.num_processes) if args.num_processes > 1 else None
    out = _claim_out(args, args.out, part)
    if args.num_processes > 1:
        return _grid_part(args, settings, out)
    with tqdm(total=settings.seeds * len(settings.algos), unit="seed", disable=args.quiet,
              desc="grid", file=sys.stderr) as bar:
        run = run_grid(settings, progress=bar.update)
    return _finish_grid(run, out, compare=not args.no_compare, quiet=args.quiet,
                        options=_output_options(args, settings.seeds))


def _output_options(args: argparse.Namespace, n_seeds: int):
    from jaxeac.experiments.results import OutputOptions

    return OutputOptions.auto(n_seeds, full=True if getattr(args, "full_outputs", False) else None,
                              csv=True if getattr(args, "per_seed_csv", False) else None)


def _finish_grid(run, out, *, compare: bool, quiet: bool, options=None) -> int:
    from jaxeac.experiments.grid import summary_table, write_grid_outputs

    summary = write_grid_outputs(run, out, options=options)
    print(summary_table(summary))
    print(f"results in {out}/")
    if compare and {"ac", "eac"} <= set(run.settings.algos) and run.settings.seeds >= 2:
        return run_compare(out, quiet=quiet)
    return 0


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
                quiet=False) -> int:
    from jaxeac.fmt import p_value
    from jaxeac.stats import compare_run_dir

    result = compare_run_dir(run_dir, baseline=baseline, treatment=treatment, resamples=resamples,
                             alpha=alpha, key=key, progress=not quiet)
    p = result["primary"]
    lo, hi = p["diff_ci95"]
    print(f"{treatment} - {baseline} on {p['measure']}: {p['diff']:+.3f} "
          f"(95% BCa CI [{lo:+.3f}, {hi:+.3f}]), "
          f"Welch p = {p_value(p['p_welch'], 3, sci_below=None, general=True)}, "
          f"Hedges' g = {p['hedges_g']:.3f}, A12 = {p['a12']:.3f}")
    print(f"report in {run_dir}/report.md")
    return 0


def _check_compare_size(run_dir, resamples: int) -> None:
    """Refuse --resamples whose statistics cannot fit in memory (trials from the run's summary.json)."""
    import json
    from pathlib import Path

    from jaxeac.experiments.common import check_compare_resources

    try:
        trials = int(json.loads((Path(run_dir) / "summary.json").read_text())["trials"])
    except (OSError, ValueError, KeyError, TypeError):
        trials = 1  # compare_run_dir names what is wrong with the folder
    check_compare_resources(resamples, trials)


def cmd_compare(args: argparse.Namespace) -> int:
    if not (0 < args.test_alpha < 1):
        raise UsageError(f"--alpha must lie in (0, 1) (got {args.test_alpha})")
    _check_compare_size(args.dir, args.resamples)
    _claim_existing(args, args.dir)
    return run_compare(args.dir, baseline=args.baseline, treatment=args.treatment,
                       resamples=args.resamples, alpha=args.test_alpha, key=args.stats_key)


def _check_bowling_memory_layout(settings) -> None:
    """EAC's memories (dense layout: bowling has no other) hold at most 24 actions and, with K
    angles, fewer than min(2^(31-K), 32767) trials: say so in the bowling flags' terms."""
    from jaxeac.algorithm.config import algorithm
    from jaxeac.algorithm.memory import MAX_DENSE_ACTIONS

    if not any(algorithm(a).uses_memory for a in settings.algos):
        return
    if settings.angles > MAX_DENSE_ACTIONS:
        raise UsageError(f"--angles {settings.angles}: EAC's memories hold at most {MAX_DENSE_ACTIONS} "
                         f"angles; use --angles {MAX_DENSE_ACTIONS} or fewer (or --algos ac)")
    most = min(1 << (31 - settings.angles), 32_767) - 1
    if settings.trials > most:
        raise UsageError(f"--trials {settings.trials}: with {settings.angles} angles EAC's memories hold "
                         f"at most {most:,} trials; use --trials {most:,} or fewer (or fewer angles)")


def cmd_bowling(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from jaxeac.experiments.bowling import BowlingSettings, run_bowling, table_one, write_bowling_outputs

    settings = BowlingSettings(
        seeds=args.seeds, trials=args.trials, angles=args.angles, theta_max=args.theta_max,
        noise_angle=args.noise_angle, noise_speed=args.noise_speed, backend=args.backend,
        algos=tuple(args.algos), key=args.key, chunk_size=args.chunk_size, alpha=args.alpha,
        beta=args.beta, gamma=args.gamma, solver=_solver_settings(args),
    )
    settings.validate()
    _check_bowling_memory_layout(settings)
    from jaxeac.experiments.common import check_bowling_resources

    check_bowling_resources(settings)  # sizes that cannot fit or finish fail here, with the numbers
    out = _claim_out(args, args.out)
    with tqdm(total=settings.seeds * len(settings.algos), unit="seed", disable=args.quiet,
              desc=f"bowling ({settings.backend})", file=sys.stderr) as bar:
        run = run_bowling(settings, progress=bar.update)
    summary = write_bowling_outputs(run, out)
    print("\n".join(line for line in table_one(run).splitlines() if line.startswith("- ")))
    if "eac_minus_ac" in summary:
        d = summary["eac_minus_ac"]
        print(f"EAC - AC: {d['diff']:+.2f} pins of {10 * settings.trials} "
              f"(95% CI [{d['ci95'][0]:+.2f}, {d['ci95'][1]:+.2f}], Welch)")
    throws = sum(r.throws for r in run.results.values())
    print(f"{throws} throws, compile {summary['compile_seconds']:.1f} s, "
          f"run {summary['run_seconds']:.1f} s; results in {out}/")
    if not args.no_compare and {"ac", "eac"} <= set(settings.algos) and settings.seeds >= 2:
        return run_compare(out, quiet=args.quiet)
    return 0


def _render_targets(path, n_throws: int) -> list:
    """The files `throw_command` draws for `n_throws` throws into `path` (`<stem>_<i>.png` for several)."""
    from pathlib import Path

    path = Path(path)
    if n_throws == 1:
        return [path]
    return [path.with_name(f"{path.stem}_{i}{path.suffix}") for i in range(n_throws)]


def _render_path(text: str, n_throws: int) -> str:
    """The PNG file `throw --render` writes (``.png`` added to a name without a suffix, so the
    path reported is the one written); refuses empty names, folders, other suffixes and
    folders that do not exist (nothing is created)."""
    from pathlib import Path

    if not text.strip() or "\0" in text:
        raise UsageError(f"--render {_show(text)} is not a file name; name a .png file, e.g. "
                         "--render deck.png")
    path = Path(text)
    for probe in (path, path.parent):
        try:
            os.stat(probe)
        except (FileNotFoundError, NotADirectoryError):
            pass
        except OSError as exc:  # a name too long, a loop of links
            raise UsageError(f"--render {text}: {exc.strerror or exc}; pick another path") from None
    if path.is_dir() or text.endswith(("/", os.sep)):
        raise UsageError(f"--render {text} is a folder; name a file in it, e.g. --render "
                         f"{(path / 'deck.png').as_posix()}")
    if path.suffix == "":
        path = path.with_name(path.name + ".png")
    elif path.suffix.lower() != ".png":
        raise UsageError(f"--render {text}: pictures are PNG files; name a .png file, e.g. "
                         f"{path.with_suffix('.png')}")
    folder = path.parent
    if not folder.is_dir():
        problem = "is not a folder" if folder.exists() else "does not exist"
        raise UsageError(f"--render {text}: folder {folder} {problem}; create it first or pick "
                         "another path")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"--render {text}: cannot write to folder {folder}; pick a writable folder")
    for target in _render_targets(path, n_throws):
        if target.is_dir():
            raise UsageError(f"--render would write {target}, which is a folder; pick another file name")
    return str(path)


def cmd_throw(args: argparse.Namespace) -> int:
    import json

    from jaxeac.envs.bowling import BowlingConfig, throw_command

    cfg = BowlingConfig(theta_max=args.theta_max, solver=_solver_settings(args))
    render = None if args.render is None else _render_path(args.render, len(args.angles))
    targets = [] if render is None else _render_targets(render, len(args.angles))
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
        memory=args.memory, capacity=args.capacity,
    )


def _fit_sweep(sweep):
    """`check_grid_resources` at every point of a sweep (each distinct size once); an automatic
    chunk size too large for some point becomes the largest that fits them all."""
    import dataclasses

    from jaxeac.experiments.common import check_grid_resources

    seen, chunks = set(), []
    for point in sweep.points():
        settings = sweep.settings(point)
        size = (settings.preset, settings.map_file, settings.trials, settings.chances)
        if size in seen:
            continue
        seen.add(size)
        chunks.append(check_grid_resources(settings, settings.grid_map()))
    if sweep.base.chunk_size is None and any(c is not None for c in chunks):
        sweep = dataclasses.replace(sweep, base=dataclasses.replace(
            sweep.base, chunk_size=min(c for c in chunks if c is not None)))
    return sweep


def cmd_sweep(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from jaxeac.experiments.sweep import Sweep, run_sweep

    base = _grid_settings(args)
    base.resolved()  # validate the flags before the swept values
    sweep = Sweep.build(base, args.sets)
    sweep = _fit_sweep(sweep)  # sizes that cannot fit or finish fail here, at any point
    _claim_out(args, args.out)
    total = len(sweep.points()) * base.seeds * len(base.algos)
    with tqdm(total=total, unit="run", disable=args.quiet, desc="sweep", file=sys.stderr) as bar:
        rows = run_sweep(sweep, args.out, progress=bar.update, compare=args.compare)
    print(f"{len(sweep.points())} points x {len(base.algos)} algorithms x {base.seeds} seeds; "
          f"{len(rows)} rows in {args.out}/results.csv")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    from jaxeac.experiments.reproduce import reproduce

    _claim_out(args, args.out)
    report = reproduce(args.out, quick=args.quick, key=args.key, progress=not args.quiet)
    print(f"report in {report}")
    return 0


COMMANDS = {
    "reproduce": cmd_reproduce,
    "grid": cmd_grid, "sweep": cmd_sweep, "bowling": cmd_bowling, "throw": cmd_throw,
    "compare": cmd_compare, "merge": cmd_merge,
}


#: CUDA graphs for whole loop bodies: ~10 % faster single-GPU runs, better multi-GPU scaling.
GPU_XLA_FLAGS = "--xla_gpu_enable_command_buffer=FUSION,CUSTOM_CALL,WHILE,CONDITIONAL"


def use_all_cpu_cores() -> None:
    """Set XLA up for jaxeac before JAX starts: every CPU core a device, CUDA graphs on GPUs.

    XLA runs one computation on one thread; with ``n`` host devices the runner splits each
    chunk of seeds over ``n`` threads (results are identical, SPEC R1). Settings already in
    ``XLA_FLAGS`` are kept; nothing changes once JAX has started.
    """
    if "jax" in sys.modules:
        return
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        count = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
        flags += f" --xla_force_host_platform_device_count={count or 1}"
    if "xla_gpu_enable_command_buffer" not in flags:
        flags += " " + GPU_XLA_FLAGS
    os.environ["XLA_FLAGS"] = flags.strip()


def _fail(message: str, code: int = 2) -> int:
    """Print ``error: message`` as one line on stderr; return `code`."""
    line = " ".join(str(message).split("\n")).replace("\r", " ")
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


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `jaxeac` console script; returns the exit code.

    Bad input, a full disk, a busy output folder and running out of memory are one line
    ``error: ...`` on stderr and exit code 2; Ctrl-C is one line and exit code 130. Output
    folders are held (`jaxeac.io.folder_lock`) until the command ends.
    """
    try:
        use_all_cpu_cores()
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
