"""Throughput of every registered task under every algorithm (X1–X3), as `jaxeac study` runs them.

For each task (a registered name, or ``NAME:slip=P``) and algorithm: compile seconds, the
best run seconds of `--repeats`, useful agent-steps per second (steps actually taken),
and per task the time of all its algorithms (each one's compile plus its best run), the number the
"≤ 60 s per task on the 2-core CPU" target is about. Settings are the study's: the paper
preset's rates (G6), ε = 0.1, 200 trials, C = the task's own limit. The paper grid's AC
row is the peer of the same run (its rate is the one `scripts/bench.py` reports).
Writes JSON; ``--render`` prints the BENCHMARKS.md table.

    python scripts/bench_tasks.py --seeds 10000 --out scripts/bench_results/cpu_tasks.json
    python scripts/bench_tasks.py --render scripts/bench_results/cpu_tasks.json

``--study`` times whole commands instead, each in a fresh process with the persistent
compilation cache off (first-run numbers), taking turns: `jaxeac study` of the first task
alone, of all `--tasks`, and with ``--plain`` the same runs done plainly (`jaxeac run` of
each task with every algorithm, their times added). Wall seconds, each process's peak
resident memory and each study's timeline (study.json's: seconds per task and phase):

    python scripts/bench_tasks.py --study --tasks FrozenLake-4x4-v1 FrozenLake-4x4-slippery-v1 \
        CliffWalking-v1 --seeds 200 --repeats 2 --out scripts/bench_results/cpu_study.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from bench import command_line, environment  # noqa: E402  (sets XLA's CPU devices first)


def bench_task(task: str, algos: list[str], n_seeds: int, repeats: int, chunk: int | None,
               jump: str = "auto", lanes: int | None = None) -> dict:
    from jaxeac.experiments.study import StudySettings
    from jaxeac.running.batch import run_seeds

    settings = StudySettings(tasks=(task,), algos=tuple(algos), seeds=n_seeds).task_settings(task)
    env = settings.make_env()
    rows = []
    for algo in algos:
        cfg = dataclasses.replace(settings.run_config(algo), jump=jump, lanes=lanes)  # auto: wherever exact
        best, compile_s = float("inf"), None
        for _ in range(repeats):
            r = run_seeds(env, cfg, root_key=0, n_seeds=n_seeds, chunk_size=chunk or settings.chunk_size)
            compile_s = r.compile_seconds if compile_s is None else compile_s
            best = min(best, r.run_seconds)
        resolved = cfg.resolve(env)
        rows.append({"algo": algo, "compile_s": compile_s, "run_s": best, "agent_steps": r.agent_steps,
                     "steps_per_s": r.agent_steps / best, "mean_successes": float(r.successes.mean()),
                     "loop": resolved.loop, "kernel": resolved.kernel, "jump": resolved.jump,
                     "lanes": r.settings["lanes"]})
    return {"task": task, "chances": env.n_chances, "states": env.n_states, "deterministic": env.deterministic,
            "wall_s": sum(r["compile_s"] + r["run_s"] for r in rows), "rows": rows}


def timed(argv: list[str]) -> tuple[float, float]:
    """(wall seconds, peak resident GiB) of one command in a fresh process (compilation cache off)."""
    import os
    import subprocess
    import time

    env = {**os.environ, "JAXEAC_COMPILATION_CACHE": "off"}
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"failed ({status}): {' '.join(argv)}")
    return wall, usage.ru_maxrss / 2**20  # KiB on Linux


def bench_study(tasks: list[str], n_seeds: int, repeats: int, plain: bool, out_dir: Path) -> dict:
    """`jaxeac study` of tasks[0] alone and of all tasks (and, with `plain`, `jaxeac run` of each),
    taking turns `repeats` times; the best wall time of each."""
    import shutil
    import tempfile

    from jaxeac.experiments.study import DEFAULT_ALGOS, parse_task

    cli = [sys.executable, "-m", "jaxeac"]
    work = Path(tempfile.mkdtemp(dir=out_dir))

    def study(names):
        return [[*cli, "study", "--tasks", *names, "--seeds", str(n_seeds), "--quiet", "--out", str(work / "s")]]

    def runs():
        cmds = []
        for i, task in enumerate(tasks):
            name, slip = parse_task(task)
            cmds.append([*cli, "run", "--env", name, "--slip", str(slip), "--algos", *DEFAULT_ALGOS, "--seeds",
                         str(n_seeds), "--quiet", "--out", str(work / f"r{i}")])
        return cmds

    variants = {"study_one": study(tasks[:1]), "study_all": study(tasks)} | ({"plain_all": runs()} if plain else {})
    times: dict = {k: [] for k in variants}
    rss: dict = {k: 0.0 for k in variants}
    timelines: dict = {}  # per study variant: its study.json's timeline (per task and phase), last repeat
    for _ in range(repeats):
        for name, cmds in variants.items():
            total = 0.0
            for argv in cmds:
                shutil.rmtree(work, ignore_errors=True)
                wall, peak = timed(argv)
                total, rss[name] = total + wall, max(rss[name], peak)
            times[name].append(total)
            if (work / "s" / "study.json").is_file():
                timelines[name] = json.loads((work / "s" / "study.json").read_text()).get("timeline")
            print(f"{name}: {total:.1f} s, peak RSS {rss[name]:.2f} GiB", flush=True)
    shutil.rmtree(work, ignore_errors=True)
    best = {k: min(v) for k, v in times.items()}
    rec = {"tasks": tasks, "seeds": n_seeds, "repeats": repeats, "wall_s": times, "best_s": best,
           "peak_rss_gib": rss, "study_all_over_one": best["study_all"] / best["study_one"],
           "timelines": timelines}
    if plain:
        rec["study_all_over_plain"] = best["study_all"] / best["plain_all"]
    return rec


def render(paths: list[Path]) -> str:
    out = []
    for path in paths:
        rec = json.loads(path.read_text())
        env = rec["environment"]
        out += [f"`{rec['command']}` ({path.name}; {env['device_kind']}, {env['backend']}, jax {env['jax']}; "
                f"{rec['seeds']:,} seeds, {rec['repeats']} run(s) each after the compile)", "",
                "| task | C | wall, all algorithms | " + " | ".join(rec["algos"]) + " |",
                "|---|---|---|" + "---|" * len(rec["algos"])]
        for t in rec["tasks"]:
            cells = [f"{r['steps_per_s']:.3g}" for r in t["rows"]]
            out.append(f"| {t['task']} | {t['chances']} | {t['wall_s']:.1f} s | " + " | ".join(cells) + " |")
        out.append("")
        out.append("Cells: useful agent-steps per second of the best run (compile apart).")
    return "\n".join(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", help="tasks (default: the study's)")
    parser.add_argument("--algos", nargs="+", help="algorithms (default: the study's)")
    parser.add_argument("--seeds", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--chunk", type=int, default=None, help="seeds per chunk (default: automatic)")
    parser.add_argument("--jump", choices=["auto", "on", "off"], default="auto",
                        help="memory jumps (RunConfig.jump; default auto: wherever exact)")
    parser.add_argument("--lanes", type=int, default=None,
                        help="seeds in flight per device (RunConfig.lanes; default: automatic)")
    parser.add_argument("--study", action="store_true",
                        help="time `jaxeac study` of the first task against all --tasks (fresh processes)")
    parser.add_argument("--plain", action="store_true", help="with --study: also `jaxeac run` of each task")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--render", nargs="+", type=Path, metavar="JSON")
    args = parser.parse_args()
    if args.render:
        print(render(args.render))
        return
    if args.lanes is not None and args.lanes < 1:
        parser.error(f"--lanes {args.lanes}: need at least one lane per device")
    from jaxeac.experiments.study import DEFAULT_ALGOS, DEFAULT_TASKS

    if args.seeds < 1 or args.repeats < 1:
        parser.error("--seeds and --repeats must be positive")
    tasks, algos = args.tasks or list(DEFAULT_TASKS), args.algos or list(DEFAULT_ALGOS)
    if args.study:
        rec = {"command": command_line(), "environment": environment(),
               **bench_study(tasks, args.seeds, args.repeats, args.plain, Path(".").resolve())}
        text = json.dumps(rec, indent=1)
        if args.out:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(text)
        print(text)
        return
    rec = {"command": command_line(), "environment": environment(), "seeds": args.seeds, "repeats": args.repeats,
           "algos": algos, "tasks": []}
    for task in tasks:
        rec["tasks"].append(bench_task(task, algos, args.seeds, args.repeats, args.chunk, args.jump,
                                       args.lanes))
        t = rec["tasks"][-1]
        print(f"{task}: {t['wall_s']:.1f} s; " + ", ".join(f"{r['algo']} {r['steps_per_s']:.3g}/s"
                                                          for r in t["rows"]), flush=True)
        if args.out:  # after every task: a run cut short keeps the tasks it finished
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(json.dumps(rec, indent=1))
    if not args.out:
        print(json.dumps(rec, indent=1))


if __name__ == "__main__":
    main()
