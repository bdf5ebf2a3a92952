"""jaxeac: vectorised actor-critic (AC) and enhanced actor-critic (EAC) with success-failure
experience (Debnath & Nassour, 2014), for thousands of seeds in one jit-compiled run.

Quick use::

    from jaxeac.envs.grid import GridWorld, get_map
    from jaxeac.algorithm.config import algorithm
    from jaxeac.running.batch import run_seeds
    from jaxeac.running.config import RunConfig

    env = GridWorld(get_map("paper"), n_chances=40)
    eac = run_seeds(env, RunConfig(trials=200, agent=algorithm("eac")), root_key=0, n_seeds=1000)
    eac.successes.mean()
"""

__version__ = "0.1.0"

from jaxeac import _compat

_compat.install()
