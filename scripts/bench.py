"""Grid-world throughput of jaxeac against same-run peers: NumPy, C (OpenMP) and numba.

Measures, for AC and EAC on the paper preset (SPEC G6) and each seed count:
compile seconds, run seconds, *useful* agent-steps per second (steps actually
taken, learning and memories included), bytes of state per seed, and the peers'
rates on the same work (ratios, since machines are noisy). The NumPy peer
(``--numpy-seeds``) gets rows of its own; the C peer (``--c-peer``, built with the
system C compiler, skipped without one) and the numba peer (``--numba-peer``, the
``bench`` extra) run right after each jaxeac row at its seed count and add
``c_steps_per_s`` / ``jaxeac_over_c`` (and ``numba_…``) to it. Writes JSON;
``--render`` turns one or more JSON files into the tables of BENCHMARKS.md.

    python scripts/bench.py --seeds 100 1000 10000 100000 --numpy-seeds 10000 --c-peer --numba-peer \
        --out scripts/bench_results/cpu.json
    python scripts/bench.py --render scripts/bench_results/*.json

(Over 400 lines: the benchmark and the Markdown of every kind of record under bench_results/.)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from jaxeac.runtime import configure

configure("grid", start_jax=False)  # before JAX starts: one host device per core, as `jaxeac` does


def environment() -> dict:
    """Machine, devices and versions, stated with every row."""
    import jax

    devices = jax.devices()
    info = {
        "machine": platform.machine(), "processor": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version(),
        "jax": jax.__version__, "numpy": np.__version__, "backend": jax.default_backend(),
        "devices": [str(d) for d in devices], "device_kind": devices[0].device_kind,
    }
    try:
        import jaxeac

        info["jaxeac"] = jaxeac.__version__
        info["jaxeac_from"] = str(Path(jaxeac.__file__).resolve().parent.parent)
    except ImportError:  # pragma: no cover
        pass
    return info


def command_line() -> str:
    """The command as a user would type it (no machine-specific interpreter path)."""
    return " ".join(["python", *sys.argv])


def paper_preset(algo: str, tables: str = "auto", lanes: int | None = None, kernel: str = "auto",
                 jump: str = "auto"):
    """(env, RunConfig) of the paper preset (SPEC G6) that every grid row runs."""
    from jaxeac.algorithm.config import algorithm
    from jaxeac.envs.grid import GridWorld, get_map
    from jaxeac.running.config import RunConfig

    env = GridWorld(get_map("paper"), 40)
    return env, RunConfig(trials=200, agent=algorithm(algo, tables=tables), alpha=0.1, beta=0.3, gamma=0.9,
                          lanes=lanes, kernel=kernel, jump=jump)


def bench_grid(algo: str, n_seeds: int, chunk: int, repeats: int, tables: str = "auto",
               lanes: int | None = None, kernel: str = "auto", jump: str = "auto") -> dict:
    """One row: compile and best-of-`repeats` run time of `n_seeds` seeds of the paper preset."""
    from jaxeac.running.batch import run_seeds
    from jaxeac.running.loops import state_bytes_per_seed

    env, cfg = paper_preset(algo, tables, lanes, kernel, jump)
    resolved = cfg.resolve(env)  # what the row ran: every `auto` decided
    best, compile_s, steps, mean = float("inf"), None, 0, 0.0
    for _ in range(repeats):
        r = run_seeds(env, cfg, root_key=0, n_seeds=n_seeds, chunk_size=chunk)
        compile_s = r.compile_seconds if compile_s is None else compile_s  # the first is the real one
        best = min(best, r.run_seconds)
        steps, mean = r.agent_steps, float(r.successes.mean())
    return {
        "impl": "jaxeac", "algo": algo, "seeds": n_seeds, "chunk": min(chunk, n_seeds),
        "loop": resolved.loop, "tables": resolved.agent.tables, "lanes": lanes or "auto",
        "kernel": resolved.kernel, "jump": resolved.jump,
        "compile_s": compile_s, "run_s": best, "agent_steps": steps, "steps_per_s": steps / best,
        "state_bytes_per_seed": state_bytes_per_seed(env, cfg), "mean_successes": mean,
    }


def bench_numpy(algo: str, n_seeds: int, repeats: int = 1) -> dict:
    """The hand-vectorised NumPy peer on the same work (SPEC-equal in distribution), best of `repeats`."""
    from peers.numpy_peer import run_numpy

    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = run_numpy("paper", algo=algo, trials=200, chances=40, alpha=0.1, beta=0.3, gamma=0.9,
                        temperature=1.0, n_seeds=n_seeds, seed=0)
        best = min(best, time.perf_counter() - t0)
    steps = int(out["steps"].sum())
    return {"impl": "numpy", "algo": algo, "seeds": n_seeds, "run_s": best, "agent_steps": steps,
            "steps_per_s": steps / best, "mean_successes": float(out["success"].sum(1).mean())}


#: The compiled peers: name → (module, run function name), imported lazily from scripts/peers.
COMPILED_PEERS = {"c": ("peers.c_peer", "run_c"), "numba": ("peers.numba_peer", "run_numba")}


def prepare_peers(names: list[str], threads: int | None) -> dict:
    """Build the C peer / compile the numba peer before any timing; a peer that cannot run here
    is left out with a note on stderr. Returns {name: info} for the peers that will run."""
    import importlib

    ready = {}
    for name in names:
        module = importlib.import_module(COMPILED_PEERS[name][0])
        if not module.available():
            why = "no working C compiler" if name == "c" else "numba is not installed (the `bench` extra)"
            print(f"bench.py: skipping the {name} peer: {why}", file=sys.stderr, flush=True)
            continue
        if name == "c":
            info = module.info()
            info["threads"] = threads or info["max_threads"]
        else:
            import numba

            info = {"numba": module.version(), "compile_s": module.warm_up(),
                    "threads": threads or numba.get_num_threads(), "threading_layer": numba.threading_layer()}
        ready[name] = info
    return ready


def run_peer(name: str, algo: str, n_seeds: int, threads: int | None = None) -> tuple[float, dict]:
    """(seconds, output) of one run of a compiled peer on the paper preset's work."""
    import importlib

    module, fn = COMPILED_PEERS[name]
    run = getattr(importlib.import_module(module), fn)
    t0 = time.perf_counter()
    out = run("paper", algo=algo, trials=200, chances=40, alpha=0.1, beta=0.3, gamma=0.9,
              temperature=1.0, n_seeds=n_seeds, seed=0, threads=threads)
    return time.perf_counter() - t0, out


def bench_peer(name: str, algo: str, n_seeds: int, repeats: int = 1, threads: int | None = None) -> dict:
    """A compiled peer (C or numba, SPEC-equal in distribution) on the same work, best of `repeats`.

    Useful agent-steps as jaxeac counts them: chances actually taken, over all trials and seeds."""
    best = float("inf")
    for _ in range(repeats):
        seconds, out = run_peer(name, algo, n_seeds, threads)
        best = min(best, seconds)
    steps = int(out["agent_steps"].sum())
    return {"run_s": best, "agent_steps": steps, "steps_per_s": steps / best,
            "mean_successes": float(out["successes"].mean())}


def measure(args) -> dict:
    """jaxeac rows, each followed by the compiled peers and the NumPy peer at the same seed count
    (if asked for), so a drifting machine slows both sides of a ratio alike; all take the best of
    `--repeats`."""
    record = {"environment": environment(), "command": command_line(), "rows": []}
    asked = [name for name, flag in (("c", args.c_peer), ("numba", args.numba_peer)) if flag]
    peers = prepare_peers(asked, args.peer_threads)
    if asked:
        record["peers"] = peers

    def add(row: dict) -> None:
        print(json.dumps(row), flush=True)
        record["rows"].append(row)

    for n in args.seeds:
        for algo, jump in [(a, j) for a in args.algos for j in (args.jump if a == "eac" else ["auto"])]:
            row = bench_grid(algo, n, args.chunk, args.repeats, args.tables, args.lanes, args.kernel, jump)
            for name in peers:
                peer = bench_peer(name, algo, n, args.repeats, args.peer_threads)
                row |= {f"{name}_{key}": value for key, value in peer.items()}
                row[f"jaxeac_over_{name}"] = row["steps_per_s"] / peer["steps_per_s"]
            add(row)
            if n in args.numpy_seeds:
                add(bench_numpy(algo, n, args.repeats))
    for n in args.numpy_seeds:
        if n not in args.seeds:
            for algo in args.algos:
                add(bench_numpy(algo, n, args.repeats))
    return record


def builds_record(args) -> dict:
    """`--builds`: this benchmark's jaxeac rows for each source tree on one machine, the builds
    taking turns for `--rounds` rounds (a drifting machine slows each alike). Each row is
    labelled ``jaxeac <dir name>`` and keeps its round."""
    import subprocess
    import tempfile

    child = ["--seeds", *map(str, args.seeds), "--numpy-seeds", "--chunk", str(args.chunk),
             "--repeats", str(args.repeats), "--tables", args.tables, "--kernel", args.kernel,
             "--algos", *args.algos, "--jump", *args.jump,
             *(["--lanes", str(args.lanes)] if args.lanes else [])]
    record = {"environment": environment(), "command": command_line(), "rows": [],
              "builds": [b.name for b in args.builds]}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.rounds):
            for build in args.builds:
                out = Path(tmp) / f"{build.name}_{i}.json"
                env = dict(os.environ, PYTHONPATH=os.pathsep.join(
                    [str(build.resolve()), *filter(None, [os.environ.get("PYTHONPATH")])]))
                subprocess.run([sys.executable, __file__, *child, "--out", str(out)], env=env, check=True,
                               stdout=subprocess.DEVNULL)
                got = json.loads(out.read_text())
                for row in got["rows"]:
                    row |= {"impl": f"jaxeac {build.name}", "build": build.name, "round": i,
                            "jaxeac_from": got["environment"].get("jaxeac_from")}
                    print(json.dumps(row), flush=True)
                    record["rows"].append(row)
    return record


def _builds_lines(rec: dict) -> list[str]:
    """Each build's best rate per (algo, jump, seeds) over the rounds, as a ratio to the first build."""
    best: dict = {}
    for r in rec["rows"]:
        key = (r["algo"], r.get("jump"), r["seeds"])
        best.setdefault(key, {})
        best[key][r["build"]] = max(best[key].get(r["build"], 0.0), r["steps_per_s"])
    first, *others = rec["builds"]
    rounds = max(r["round"] for r in rec["rows"]) + 1
    jumps = {"on": " with jumps", "off": " without jumps"}
    lines = []
    for (algo, jump, seeds), rates in best.items():
        label = algo.upper() + (jumps.get(jump, "") if algo != "ac" else "")
        lines.append(f"{label} at {seeds:,} seeds, best of {rounds} rounds: "
                     + "; ".join(f"{b} {rates[b]:.3g}" for b in rec["builds"] if b in rates)
                     + "".join(f" (**{rates[b] / rates[first]:.2f}×** {first})" for b in others
                               if b in rates and first in rates))
    return ["", *lines]


def _devices_heading(path: Path, rec: dict) -> list[str]:
    """Title (devices, versions) and command of a record written by scale.py or check_kernel.py."""
    env = rec["environment"]
    return [f"#### `{path.name}`: {len(env['devices'])} × {env['device_kind']}, jax {env['jax']}\n",
            f"Command: `{rec['command']}`\n"]


def _render_scale(path: Path, rec: dict) -> list[str]:
    out = [*_devices_heading(path, rec),
           "| algo | seeds | devices | compile s | first run s | run s (warm) | agent-steps/s | "
           "1-device run s | scaling efficiency | first K seeds identical on 1 and n devices |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rec["rows"]:
        one = f"{r['one_run_s']:.2f}" if "one_run_s" in r else "–"
        eff = f"{r['scaling_efficiency']:.2f}" if "scaling_efficiency" in r else "–"
        first = f"{r['all_first_run_s']:.2f}" if "all_first_run_s" in r else "–"
        out.append(f"| {r['algo']} | {r['seeds']:,} | {r['devices']} | {r['all_compile_s']:.2f} | {first} | "
                   f"{r['all_run_s']:.2f} | {r['all_steps_per_s']:.3g} | {one} | {eff} | "
                   f"{'yes' if r['subset_identical'] else 'NO'} (K = {r['subset']:,}) |")
    return out + [""]


def _render_kernel_check(path: Path, rec: dict) -> list[str]:
    env = any("env" in r for r in rec["rows"])  # --envs: a column naming each row's task
    first = "| env " if env else ""
    out = [*_devices_heading(path, rec),
           first + "| algo | seeds | trials | seeds with identical successes and steps | "
           "seeds with identical policy | mean successes | XLA run s | kernel run s |",
           "|---" * (9 if env else 8) + "|"]
    for r in rec["rows"]:
        cell = f"| {r['env']} " if env else ""
        out.append(cell + f"| {r['algo']} | {r['seeds']:,} | {r['trials']} | "
                   f"{r['seeds_identical_success_and_steps']:,} | {r['seeds_identical_policy']:,} | "
                   f"{r['mean_successes']:.2f} | {r['xla_run_s']:.2f} | {r['kernel_run_s']:.2f} |")
    return out + [""]


def _render_bowling(path: Path, rec: dict) -> list[str]:
    m, v = rec["machine"], rec["versions"]
    out = [f"#### `{path.name}`: {', '.join(m['jax_devices'])}, {m['cpu_count']} CPUs, mujoco {v['mujoco']}, "
           f"mujoco-mjx {v.get('mujoco_mjx', '?')}"
           + (f", warp-lang {v['warp_lang']}" if "warp_lang" in v else "") + f", jax {v['jax']}\n",
           *([f"Command: `{c}`\n" for c in rec["commands"]] if "commands" in rec else
             ["Command: `python scripts/bench_bowling.py` (flags in the text)\n"]),
           "400 physics steps per throw (physics steps/s counts 400 per throw; a throw of the sleeping C "
           "engine ends once settled, after the steps in *steps run*).\n",
           "| backend | solver:iters:ls:cap[:pairs] | batch | threads | compile s | run s | throws/s | "
           "physics steps/s | steps run per throw | mean pins |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rec["results"]:
        compile_s = f"{r['compile_s']:.1f}" if "compile_s" in r else "–"
        threads = r.get("nthread", "–")
        ran = f"{r['steps_run_per_throw']:.0f}" if "steps_run_per_throw" in r else "–"
        out.append(f"| {r['backend']} | {r.get('physics', 'newton:4:8:32')} | {r['batch']:,} | {threads} | "
                   f"{compile_s} | {r['run_s']:.2f} | {r['throws_per_s']:.0f} | {r['steps_per_s']:.3g} | "
                   f"{ran} | {r['mean_knocked']:.2f} |")
    acc = [r for r in rec["results"] if "accuracy_throws" in r]
    if acc:
        out += ["", "Accuracy on the first N throws of the largest batch, against the C engine at 50/50 "
                "Newton iterations on the same noisy throws (same keys; since sleeping exists, the reference "
                "runs without it, every throw its full length):", "",
                "| backend | solver:iters:ls:cap[:pairs] | N | mean pins | reference | difference ± s.e. | "
                "mean abs difference per throw | strike rate (reference) |",
                "|---|---|---|---|---|---|---|---|"]
        for r in acc:
            out.append(f"| {r['backend']} | {r['physics']} | {r['accuracy_throws']:,} | "
                       f"{r['mean_knocked_first_n']:.2f} | {r['reference_mean_knocked']:.2f} | "
                       f"{r['mean_diff']:+.2f} ± {r['mean_diff_se']:.2f} | {r['mean_abs_diff']:.2f} | "
                       f"{r['strike_rate']:.3f} ({r['reference_strike_rate']:.3f}) |")
    return out + [""]


def _render_stats(path: Path, rec: dict) -> list[str]:
    m, v = rec["machine"], rec["versions"]
    return [f"#### `{path.name}`: {m['cpus']} CPUs, jax {v['jax']}, numpy {v['numpy']}, "
            f"scipy {v['scipy']}\n",
            "Command: `python scripts/bench_stats.py --repeat 2` (synthetic run folder; the full "
            "`compare_run_dir`: statistics, calibration, report and figures)\n",
            "| seeds per method | trials | resamples | import s | first run s (compile incl.) | "
            "compile + warm-up s | warm run s |", "|---|---|---|---|---|---|---|",
            f"| {rec['seeds_per_method']:,} | {rec['trials']} | {rec['resamples']:,} | "
            f"{rec['import_seconds']:.2f} | {rec['first_run_seconds']:.2f} | "
            f"{rec['compile_and_warmup_seconds']:.2f} | {rec['warm_run_seconds']:.2f} |", ""]


def _render_commands(path: Path, rec: dict) -> list[str]:
    """A `scripts/scale.py --commands` record (runs of the `jaxeac grid` command, bundled): per
    seed count and report, each build's runs on one and two GPUs and the two-over-one ratios."""
    env = rec.get("environment", {})
    out = [f"#### `{path.name}`: {env.get('cards', '?')}, {env.get('cpus', '?')} CPUs\n",
           "| runs | build | GPUs | seeds | report | cache | wall s | compile s | run s | AC run s "
           "| EAC run s | results digest |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    groups = {k: v for k, v in rec["runs"].items() if k.startswith("cmd")}
    for label, runs in groups.items():
        for r in runs:
            algo = r.get("per_algo", {})
            gpus = len(r["visible"].split(","))
            out.append(f"| {label} | {r['build']} | {gpus} | {r['seeds']:,} | "
                       f"{'yes' if r['report'] else 'no'} | {r['cache']} | {r['wall_s']:.2f} | "
                       f"{r.get('compile_s', 0):.2f} | {r.get('run_s', 0):.2f} | "
                       f"{algo.get('ac', {}).get('run_s', 0):.2f} | "
                       f"{algo.get('eac', {}).get('run_s', 0):.2f} | "
                       f"`{r.get('results_digest', '–')[:8]}` |")
    out.append("")
    for runs in groups.values():
        by = {(r["build"], r["seeds"], r["report"], r["cache"], len(r["visible"].split(","))): r
              for r in runs if r.get("rc") == 0}
        for (build, seeds, report, cache, gpus), two in by.items():
            one = by.get((build, seeds, report, cache, 1))
            if gpus == 2 and one is not None:
                out.append(f"- {build}, {seeds:,} seeds, {'with' if report else 'no'} report ({cache}): "
                           + _two_over_one(one, two))
    out.append("")
    return out + _render_record_extras(rec)


def _render_record_extras(rec: dict) -> list[str]:
    """A `scripts/scale.py --record`'s other parts: where each command's seconds went, the
    per-device timelines, the multi-host recipe and bench.py on one and two GPUs."""
    runs, out = rec["runs"], []
    phased = [(label, r) for label, rs in runs.items() if label.startswith("cmd")
              for r in rs if r.get("phases")]
    if phased:
        keys = ["startup_s", "run_s", "figures_s", "diagnostics_wait_s", "folder_s", "report_s", "exit_s"]
        out += ["Where each command's seconds went (summary.json's timeline; run = compile and chunks):\n",
                "| runs | build | GPUs | seeds | report | cache | wall s | "
                + " | ".join(k[:-2] for k in keys) + " |",
                "|---|---|---|---|---|---|---|" + "---|" * len(keys)]
        for label, r in phased:
            out.append(f"| {label} | {r['build']} | {len(r['visible'].split(','))} | {r['seeds']:,} | "
                       f"{'yes' if r['report'] else 'no'} | {r['cache']} | {r['wall_s']:.2f} | "
                       + " | ".join(f"{r['phases'].get(k, 0):.2f}" for k in keys) + " |")
        out.append("")
    for r in runs.get("timeline", []):
        if "devices" not in r:
            continue
        how = " ".join([*r.get("flags", []), *(f"{k}={v}" for k, v in r.get("env", {}).items())]) or "default"
        for label, part in (("first run", r.get("first", {})), ("second run", r)):
            devs = "; ".join(f"GPU {g}: {d['chunks']} chunks, busy {d['kernel_s']:.2f} s, "
                             f"idle {d['idle_s']:.2f} s" for g, d in part.get("devices", {}).items())
            out.append(f"- timeline, {r['build']}, {len(r['visible'].split(','))} GPU(s), "
                       f"{r['seeds']:,} seeds ({how}), {label}: chunks {part.get('wall_s', 0):.2f} s; {devs}")
    hosts = [r for r in runs.get("cmd_hosts", []) if "parts_s" in r]
    for r in hosts:
        one = [o for o in runs["cmd_hosts"]
               if "parts_s" not in o and o["seeds"] == r["seeds"] and o.get("rc") == 0]
        out.append(f"- multi-host recipe, {r['seeds']:,} seeds: two processes of one GPU "
                   + (f"{max(r['parts_s']):.2f} s, merge {r['merge_s']:.2f} s, wall {r['wall_s']:.2f} s"
                      if r.get("rc") == 0 else f"failed ({r.get('rc')})")
                   + (f"; one process with two GPUs {one[0]['wall_s']:.2f} s" if one else ""))
    bench = [r for r in runs.get("bench", []) if "steps_per_s" in r]
    best: dict = {}
    for r in bench:
        key = (r["build"], r["algo"], r["seeds"], len(r["visible"].split(",")))
        best[key] = max(best.get(key, 0.0), r["steps_per_s"])
    for (build, algo, seeds, gpus), rate in best.items():
        one = best.get((build, algo, seeds, 1))
        if gpus == 2 and one:
            out.append(f"- bench.py, {build}, {algo.upper()} at {seeds:,} seeds: two GPUs over one "
                       f"**{rate / one:.2f}×** ({one:.3g} -> {rate:.3g} agent-steps/s)")
    return out + [""] if out else out


def _two_over_one(one: dict, two: dict) -> str:
    """Two GPUs' speed over one's, from two `--commands` runs."""
    per = {a: one["per_algo"][a]["run_s"] / two["per_algo"][a]["run_s"] for a in two["per_algo"]}
    return (f"two GPUs over one: wall {one['wall_s'] / two['wall_s']:.2f}×, "
            f"run {one['run_s'] / two['run_s']:.2f}× ("
            + ", ".join(f"{a.upper()} {x:.2f}×" for a, x in per.items())
            + f"); compile on two / on one {two['compile_s'] / one['compile_s']:.2f}")


def render(paths: list[Path]) -> str:
    """Markdown tables from benchmark JSON files (grid, scale, kernel-check, bowling and stats records)."""
    out = []
    for path in paths:
        rec = json.loads(path.read_text())
        if "first_run_seconds" in rec:
            out += _render_stats(path, rec)
            continue
        if "results" in rec:
            out += _render_bowling(path, rec)
            continue
        if isinstance(rec.get("runs"), dict) and (any(k.startswith("cmd") for k in rec["runs"])
                                                  or "scale.py --record" in rec.get("what", "")):
            out += _render_commands(path, rec)
            continue
        if rec["rows"] and "subset_identical" in rec["rows"][0]:
            out += _render_scale(path, rec)
            continue
        if "all_identical" in rec:
            out += _render_kernel_check(path, rec)
            continue
        env = rec["environment"]
        out.append(f"#### `{path.name}`: {env['device_kind']} ({env['backend']}), {env['cpus']} CPUs, "
                   f"jax {env['jax']}, numpy {env['numpy']}, Python {env['python']}\n")
        out.append(f"Command: `{rec['command']}`\n")
        compiled = [name for name in COMPILED_PEERS if any(f"{name}_steps_per_s" in r for r in rec["rows"])]
        labels = {"c": "C", "numba": "numba"}
        peer_info = rec.get("peers", {})
        for name in compiled:
            i = peer_info.get(name, {})
            omp = "on" if i.get("openmp") else "off"
            how = (f"{i.get('compiler', '?')} `{i.get('flags', '')}`, OpenMP {omp}" if name == "c"
                   else f"numba {i.get('numba', '?')} ({i.get('threading_layer', '?')} layer)")
            out.append(f"{labels[name]} peer: {how}, {i.get('threads', '?')} threads.\n")
        out.append("| impl | algo | tables | kernel | seeds | chunk | lanes | compile s | run s | "
                   "useful agent-steps/s | state bytes/seed | mean successes |"
                   + "".join(f" {labels[n]} peer steps/s | jaxeac / {labels[n]} |" for n in compiled))
        out.append("|---|---|---|---|---|---|---|---|---|---|---|---|" + "---|---|" * len(compiled))
        for r in rec["rows"]:
            compile_s = f"{r['compile_s']:.2f}" if r.get("compile_s") is not None else "–"
            chunk = r.get("chunk", "–")
            tables = r.get("tables", "split" if r["impl"] == "jaxeac" else "–")  # older records: split
            lanes = r.get("lanes", "auto" if r["impl"] == "jaxeac" else "–")
            kernel = r.get("kernel", "xla" if r["impl"] == "jaxeac" else "–")  # older records: XLA ops
            kernel += ", jumps" if r.get("jump") == "on" else ""  # older records: no memory jumps
            out.append(f"| {r['impl']} | {r['algo']} | {tables} | {kernel} | {r['seeds']:,} | {chunk} | "
                       f"{lanes} | {compile_s} | {r['run_s']:.2f} | {r['steps_per_s']:.3g} | "
                       f"{r.get('state_bytes_per_seed', '–')} | {r['mean_successes']:.2f} |"
                       + "".join(f" {r[f'{n}_steps_per_s']:.3g} | {r[f'jaxeac_over_{n}']:.2f}× |"
                                 if f"{n}_steps_per_s" in r else " – | – |" for n in compiled))
        def algo(r: dict) -> str:  # EAC rows say whether they jumped (records since memory jumps)
            jump = {"on": " with jumps", "off": " without jumps"}.get(r.get("jump"), "") if r["algo"] != "ac" else ""
            return r["algo"].upper() + jump

        peers = {(r["algo"], r["seeds"]): r for r in rec["rows"] if r["impl"] == "numpy"}
        ratios = [(algo(r), r["seeds"], r["steps_per_s"] / peers[(r["algo"], r["seeds"])]["steps_per_s"])
                  for r in rec["rows"] if r["impl"] == "jaxeac" and (r["algo"], r["seeds"]) in peers]
        if ratios:
            out.append("")
            out.append("jaxeac / NumPy peer (same run, same seeds): "
                       + "; ".join(f"{a} at {n:,} seeds: **{x:.1f}×**" for a, n, x in ratios))
        for name in compiled:
            pairs = [(algo(r), r["seeds"], r[f"jaxeac_over_{name}"]) for r in rec["rows"]
                     if r["impl"] == "jaxeac" and f"jaxeac_over_{name}" in r]
            out.append("")
            out.append(f"jaxeac / {labels[name]} peer (same run, same seeds): "
                       + "; ".join(f"{a} at {n:,} seeds: **{x:.2f}×**" for a, n, x in pairs))
        if "builds" in rec:
            out += _builds_lines(rec)
        out.append("")
    return "\n".join(out)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[100, 1000, 10_000, 100_000])
    p.add_argument("--numpy-seeds", type=int, nargs="*", default=[10_000])
    p.add_argument("--c-peer", action="store_true",
                   help="time the C peer (scripts/peers/c_peer.c, OpenMP) after each jaxeac row")
    p.add_argument("--numba-peer", action="store_true",
                   help="time the numba peer (scripts/peers/numba_peer.py, the `bench` extra) after each "
                   "jaxeac row")
    p.add_argument("--peer-threads", type=int, default=None,
                   help="threads for the C and numba peers (default: every core, as jaxeac)")
    p.add_argument("--algos", nargs="+", choices=["ac", "eac"], default=["ac", "eac"], help="methods to run")
    p.add_argument("--chunk", type=int, default=8192, help="seeds per compiled chunk (split over devices)")
    p.add_argument("--repeats", type=int, default=2, help="runs per row; the best run time is kept")
    p.add_argument("--tables", choices=["auto", "split", "rows"], default="auto",
                   help="agent table layout (auto: split on CPUs, rows on accelerators)")
    p.add_argument("--lanes", type=int, default=None,
                   help="seeds in flight per device (default auto: 256 on CPU, every seed of a chunk on GPU)")
    p.add_argument("--kernel", choices=["auto", "xla", "pallas"], default="auto",
                   help="the flat loop's chances: fused GPU kernel (pallas) or XLA ops; auto as jaxeac")
    p.add_argument("--jump", nargs="+", choices=["auto", "on", "off"], default=["auto"],
                   help="EAC's memory jumps (RunConfig.jump), a row for each (e.g. `--jump on off` for "
                        "a same-run ratio); auto as jaxeac")
    p.add_argument("--builds", type=Path, nargs="+", metavar="DIR",
                   help="compare these source trees (e.g. `git archive` of two commits) on one machine: "
                        "jaxeac rows only, each build in turn (`--rounds` times), no peers")
    p.add_argument("--rounds", type=int, default=2, help="--builds: rounds of the builds taking turns")
    p.add_argument("--out", type=Path, help="write the JSON record here")
    p.add_argument("--render", type=Path, nargs="+", help="print Markdown tables of these JSON files")
    args = p.parse_args()
    if args.peer_threads is not None and args.peer_threads < 1:
        p.error(f"--peer-threads {args.peer_threads}: need at least one thread")
    if args.lanes is not None and args.lanes < 1:
        p.error(f"--lanes {args.lanes}: need at least one lane per device")
    if args.render:
        print(render(args.render))
        return
    record = builds_record(args) if args.builds else measure(args)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(record, indent=2) + "\n")


if __name__ == "__main__":
    main()
