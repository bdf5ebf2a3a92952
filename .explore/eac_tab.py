import sys, time, jax
import jaxeac
from jaxeac.running.batch import run_seeds
from jaxeac.running.config import RunConfig
from jaxeac.algorithm.config import algorithm
N = int(sys.argv[1])
def go(task, algo, **kw):
    chances = kw.pop("chances", None)
    env = jaxeac.make(task, **({"chances": chances} if chances else {}))
    cfg = RunConfig(trials=200, agent=algorithm(algo), **kw)
    r = run_seeds(env, cfg, root_key=0, n_seeds=N)
    r = run_seeds(env, cfg, root_key=0, n_seeds=N)
    rc = cfg.resolve(env, N)
    print(f"{task:28s} {algo:4s} {str(kw):38s} C={env.n_chances:4d} lanes={rc.lanes} jump={rc.jump} kern={rc.kernel}: "
          f"{r.agent_steps/r.run_seconds:.3g} steps/s, run {r.run_seconds:.2f}s, steps/seed {r.agent_steps/N:.0f}", flush=True)
go("grid-paper-v0", "eac", kernel="xla")
go("grid-paper-v0", "ac", kernel="xla")
go("FourRooms-v0", "eac")
go("FourRooms-v0", "eac", jump="off")
go("FourRooms-v0", "eac", lanes=1<<15)
go("FourRooms-v0", "eac", chances=100)
go("FourRooms-v0", "ac", chances=100)
go("FrozenLake-8x8-slippery-v1", "eac")
go("FrozenLake-8x8-slippery-v1", "eac", lanes=1<<15)
go("FrozenLake-8x8-slippery-v1", "eac_success_only")
go("FrozenLake-8x8-slippery-v1", "eac_failure_only")
