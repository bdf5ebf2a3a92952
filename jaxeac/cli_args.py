"""The command line's argument types, flag groups and the checks run before any compute.

Each bad value is one line naming the fix; `jaxeac.cli` builds the parser from these
and runs the commands.
"""

from __future__ import annotations

import argparse
import math
import os

from jaxeac.errors import UsageError


class Parser(argparse.ArgumentParser):
    """argparse, but errors are one line (`error: ...`) and exit code 2."""

    def error(self, message: str):  # noqa: D401 - argparse API
        raise UsageError(f"{self.prog}: {message}")


def show(text: str, limit: int = 40) -> str:
    """A bad value for a one-line message: quoted, escaped, cut to `limit` characters."""
    return repr(text[:limit]) + ("..." if len(text) > limit else "")


def int_at_least(minimum: int, what: str):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{show(text)} is not an integer") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{show(text.strip())} must be a {what} integer")
        return value

    return parse


positive_int = int_at_least(1, "positive")  # counts: rejects 1.5, 0, -3, 'ten'
nonneg_int = int_at_least(0, "non-negative")  # process ids, caps

KEY_LIMIT = 1 << 32  # = jaxeac.experiments.common.KEY_LIMIT


def prng_key(text: str) -> int:
    """A root PRNG key in 0..2^32-1: `jax.random.key` keeps only key mod 2^32, so a larger key
    would silently rerun a smaller one's random numbers under another name."""
    value = nonneg_int(text)
    if value >= KEY_LIMIT:
        raise argparse.ArgumentTypeError(
            f"{show(text.strip(), 24)} is out of range: keys are 32-bit, 0..{KEY_LIMIT - 1} (a larger key "
            f"would repeat key {value % KEY_LIMIT}'s results)")
    return value


def finite_float(text: str) -> float:
    """A finite number (rejects nan, inf)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{show(text)} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{show(text.strip())} is not a finite number")
    return value


def host_port(text: str) -> str:
    """HOST:PORT of a coordinator: a host name, IPv4 or [IPv6] address and a port in 1..65535."""
    host, sep, port = text.strip().rpartition(":")
    example = "e.g. host0:1234 or [::1]:1234"
    if not sep or not host:
        raise argparse.ArgumentTypeError(f"{show(text)} is not HOST:PORT ({example})")
    if not (port.isascii() and port.isdigit() and 1 <= int(port) <= 65535):
        raise argparse.ArgumentTypeError(f"port {show(port)} of {show(text)} must be a number in 1..65535 "
                                         f"({example})")
    bracketed = host.startswith("[") and host.endswith("]")
    name = host[1:-1] if bracketed else host
    allowed = set("0123456789abcdefABCDEF:.%") if bracketed else None
    ok = bool(name) and name.isascii() and (
        set(name) <= allowed if bracketed else all(c.isalnum() or c in ".-_" for c in name))
    if not ok:
        raise argparse.ArgumentTypeError(f"host {show(host)} of {show(text)} is not a host name or address "
                                         f"({example}: IPv6 addresses go in brackets)")
    return f"{host}:{int(port)}"


def folder_name(text: str) -> str:
    """An output or run folder: a non-empty name (`''` would mean the current folder) without NUL."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty name is not a folder; name one, e.g. runs/mine")
    if "\0" in text:
        raise argparse.ArgumentTypeError(f"{show(text)} contains a NUL byte; name a folder without one")
    return text


def map_file_name(text: str) -> str:
    """A --map file: a non-empty name (`''` would silently mean the preset's map) without NUL."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty name is not a map file; name one, e.g. --map "
                                         "maps/mine.txt, or leave --map out for the preset's map")
    if "\0" in text:
        raise argparse.ArgumentTypeError(f"{show(text)} contains a NUL byte; name a file without one")
    return text


def add_grid_flags(p: argparse.ArgumentParser, env_required: bool = False) -> None:
    """The grid-world flags shared by `grid`, `run` and `sweep`; unset flags come from the preset."""
    p.add_argument("--preset", default="paper", help="settings preset (default: paper, SPEC G6)")
    p.add_argument("--map", dest="map_file", type=map_file_name, metavar="FILE",
                   help="ASCII map file (SPEC G1)")
    p.add_argument("--trials", type=positive_int, metavar="T", help="trials per run")
    p.add_argument("--chances", type=positive_int, metavar="C", help="steps per trial (G5)")
    p.add_argument("--alpha", type=finite_float, metavar="A", help="critic step size α")
    p.add_argument("--beta", type=finite_float, metavar="B", help="actor step size β")
    p.add_argument("--gamma", type=finite_float, metavar="G", help="discount γ in [0, 1]")
    p.add_argument("--temperature", type=finite_float, metavar="TAU", help="softmax temperature τ > 0")
    p.add_argument("--env", metavar="NAME", required=env_required,
                   help="a registered environment instead of the preset's map: the classic tabular tasks "
                        "(FrozenLake-4x4-v1, CliffWalking-v1, …; an unknown name lists them all)")
    p.add_argument("--slip", type=finite_float, default=0.0, metavar="P",
                   help="with probability P a move executes a uniformly random action (default 0)")
    p.add_argument("--algos", nargs="+", default=["ac", "eac"], metavar="ALGO",
                   help="algorithms: ac, eac, eac_success_only, eac_failure_only, eac_learn_on_memory, "
                        "eac_within_trial, and the baselines q_learning, sarsa (default: ac eac)")
    p.add_argument("--epsilon", type=finite_float, default=0.1, metavar="E",
                   help="exploration rate of q_learning and sarsa, in [0, 1] (default 0.1)")
    p.add_argument("--seeds", type=positive_int, default=1000, metavar="N", help="seeds per algorithm")
    p.add_argument("--key", type=prng_key, default=0, metavar="K", help="root PRNG key, 0..2^32-1 (R1)")
    p.add_argument("--chunk-size", type=positive_int, default=None, metavar="M",
                   help="seeds per compiled batch; bounds memory (default: chosen for the backend and "
                        "free device memory; results do not depend on it)")
    p.add_argument("--lanes", type=positive_int, default=None, metavar="L",
                   help="seeds in flight per device (default: chosen for the backend and algorithm; "
                        "results do not depend on it)")
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
                   help="with --sequential: chance of a wrong decision, each way (default 0.05)")


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


#: The smallest significance level `compare --alpha` takes: below it the quantiles 1 - α/2 of the
#: tests and intervals round to 1 in double precision (infinite critical values).
MIN_TEST_ALPHA = 1e-12


def add_compare_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--baseline", default="ac", help="baseline algorithm (default ac)")
    p.add_argument("--treatment", default="eac", help="treatment algorithm (default eac)")
    p.add_argument("--resamples", type=positive_int, default=10_000, metavar="R",
                   help="bootstrap and permutation resamples (default 10000)")
    p.add_argument("--alpha", dest="test_alpha", type=finite_float, default=0.05,
                   help="significance level (default 0.05)")
    p.add_argument("--key", dest="stats_key", type=prng_key, default=0, metavar="K",
                   help="PRNG key of the resampling, 0..2^32-1")
    pairing = p.add_mutually_exclusive_group()
    pairing.add_argument("--unpaired", action="store_true",
                         help="run folders: compare the methods as independent samples only (default: "
                              "also paired where both ran the same seeds, which then share their keys)")
    pairing.add_argument("--paired", action="store_true",
                         help="run folders: require the paired analysis (an error if the methods ran "
                              "different seeds)")


def fit_grid(args: argparse.Namespace, settings, env):
    """Refuse sizes that cannot fit in memory or finish (`check_grid_resources`), with the numbers;
    an automatic chunk size that would not fit becomes the largest that does."""
    import dataclasses

    from jaxeac.experiments.common import check_grid_resources
    from jaxeac.experiments.grid import process_share

    first, n = process_share(settings.seeds, args.process_id, args.num_processes)
    chunk = check_grid_resources(settings, env, n_seeds=n, first_seed=first)
    return settings if chunk == settings.chunk_size else dataclasses.replace(settings, chunk_size=chunk)


def check_compare_size(run_dir, resamples: int) -> None:
    """Refuse --resamples whose statistics cannot fit in memory (trials from the run's summary.json)."""
    import json
    from pathlib import Path

    from jaxeac.experiments.common import check_compare_resources

    try:
        trials = json.loads((Path(run_dir) / "summary.json").read_text())["trials"]
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        trials = None
    if not isinstance(trials, int) or isinstance(trials, bool) or trials < 1:
        trials = 1  # compare_run_dir names what is wrong with the folder
    check_compare_resources(resamples, trials)


def render_targets(path, n_throws: int) -> list:
    """The files `throw_command` draws for `n_throws` throws into `path` (`<stem>_<i>.png` for several)."""
    from pathlib import Path

    path = Path(path)
    if n_throws == 1:
        return [path]
    return [path.with_name(f"{path.stem}_{i}{path.suffix}") for i in range(n_throws)]


def render_path(text: str, n_throws: int) -> str:
    """The PNG file `throw --render` writes (``.png`` added to a name without a suffix, so the
    path reported is the one written); refuses empty names, folders, other suffixes and
    folders that do not exist (nothing is created)."""
    from pathlib import Path

    if not text.strip() or "\0" in text:
        raise UsageError(f"--render {show(text)} is not a file name; name a .png file, e.g. "
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
    for target in render_targets(path, n_throws):
        if target.is_dir():
            raise UsageError(f"--render would write {target}, which is a folder; pick another file name")
    return str(path)


def fit_sweep(sweep):
    """`check_grid_resources` at every point of a sweep (each distinct size once); an automatic
    chunk size too large for some point becomes the largest that fits them all."""
    import dataclasses

    from jaxeac.experiments.common import check_grid_resources

    seen, chunks = set(), []
    for point in sweep.points():
        settings = sweep.settings(point)
        size = (settings.preset, settings.map_file, settings.env, settings.slip, settings.trials, settings.chances)
        if size in seen:
            continue
        seen.add(size)
        chunks.append(check_grid_resources(settings, settings.make_env()))
    if sweep.base.chunk_size is None and any(c is not None for c in chunks):
        sweep = dataclasses.replace(sweep, base=dataclasses.replace(
            sweep.base, chunk_size=min(c for c in chunks if c is not None)))
    return sweep
