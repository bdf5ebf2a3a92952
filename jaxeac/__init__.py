"""jaxeac: vectorised actor-critic (AC) and enhanced actor-critic (EAC) with success-failure
experience (Debnath & Nassour, 2014), for thousands of seeds in one jit-compiled run.

Quick use::

    import jaxeac
    from jaxeac.algorithm import algorithm
    from jaxeac.running import RunConfig, run_seeds

    env = jaxeac.make("grid-paper-v0", chances=40)   # jaxeac.registered() lists the names
    eac = run_seeds(env, RunConfig(trials=200, agent=algorithm("eac")), root_key=0, n_seeds=1000)
    eac.successes.mean()

Layout (docs/ARCHITECTURE.md): `envs` → `algorithm` → `running` → `experiments` →
`stats`, `plots`, `cli`; SPEC ids cited in docstrings are defined in docs/SPEC.md.
"""

__version__ = "0.1.0"

from jaxeac import _compat

_compat.install()


def __getattr__(name: str):
    """`jaxeac.make` and `jaxeac.registered`: the environment registry (`jaxeac.envs`), loaded lazily."""
    if name in ("make", "registered"):
        from jaxeac import envs

        return getattr(envs, name)
    raise AttributeError(f"module 'jaxeac' has no attribute {name!r}")
