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
