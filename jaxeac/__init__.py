"""jaxeac: vectorised actor-critic (AC) and enhanced actor-critic (EAC) with success-failure
experience (Debnath & Nassour, 2014), for thousands of seeds in one jit-compiled run.

Everything a notebook needs is here, one name per job::

    import jaxeac

    env = jaxeac.make("grid-paper-v0")                 # jaxeac.registered() lists the names
    cfg = jaxeac.RunConfig(trials=200, agent=jaxeac.algorithm("eac"))
    eac = jaxeac.run(env, cfg, seeds=1000, key=0)      # success [N, T], steps, policy
    ac = jaxeac.run(env, "ac", seeds=1000, key=0)      # an algorithm's name: 200 trials, paper rates
    stats = jaxeac.compare(ac, eac)                    # BCa CI, Welch, permutation, Hedges' g, A12
    agent, trials = jaxeac.trace(env, cfg, key=0, seed=7)  # one seed, a pure function
    folder = jaxeac.load("runs/run")                   # a run folder of `jaxeac run`

The rest of the package is internal. Importing it applies the process settings that must
precede NumPy and JAX (`jaxeac.runtime`; ``JAXEAC_RUNTIME=off`` keeps yours). Layout:
docs/ARCHITECTURE.md; SPEC ids cited in docstrings: docs/SPEC.md.
"""

__version__ = "0.1.0"

from jaxeac import _compat, runtime

runtime.configure(start_jax=False)
_compat.install()

#: public name -> (module, attribute), imported on first use (JAX loads only when needed)
_PUBLIC = {
    "make": ("jaxeac.envs", "make"),
    "registered": ("jaxeac.envs", "registered"),
    "algorithm": ("jaxeac.algorithm", None),  # the package itself, callable as the factory
    "RunConfig": ("jaxeac.running.config", "RunConfig"),
    "run": ("jaxeac._api", "run"),
    "trace": ("jaxeac._api", "trace"),
    "compare": ("jaxeac._api", "compare"),
    "load": ("jaxeac._api", "load"),
}

__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    if name in _PUBLIC:
        import importlib

        module, attribute = _PUBLIC[name]
        value = importlib.import_module(module)
        value = value if attribute is None else getattr(value, attribute)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'jaxeac' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
