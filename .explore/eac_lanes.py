import sys, jax
import jaxeac
from jaxeac.running.batch import run_seeds
from jaxeac.running.config import RunConfig
from jaxeac.algorithm.config import algorithm
from jaxeac.experiments.study import DEFAULT_TASKS, StudySettings
N = int(sys.argv[1]); algo = sys.argv[2]
for task in DEFAULT_TASKS:
    s = StudySettings(tasks=(task,), algos=("ac", algo), seeds=N).task_settings(task)
    env = s.make_env()
    out = []
    for lanes in (None, 1 << 14, 1 << 15, 1 << 16):
        cfg = RunConfig(trials=200, agent=algorithm(algo), lanes=lanes)
        r = run_seeds(env, cfg, root_key=0, n_seeds=N)
        out.append(f"{lanes or 'auto'}: {r.agent_steps/r.run_seconds:.3g}")
    print(f"{task:30s} {algo} N={N}: " + ", ".join(out), flush=True)
