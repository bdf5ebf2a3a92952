"""The agent of Debnath & Nassour (2014): AC equations (1)–(4) and EAC's Algorithm 1 (SPEC E1–E7).

`config` (what defines an agent), `tables` (p and V), `memory` (success/failure
experience, E7 layouts behind one interface) and `agent` (one definition of each
step of Algorithm 1, called by every loop, the GPU kernel and bowling).

The package is also the public factory: ``jaxeac.algorithm("eac", memory="buffer")`` calls
`jaxeac.algorithm.config.algorithm` (the name ``jaxeac.algorithm`` is both, so it never
depends on which was imported first).
"""

import sys
import types

from jaxeac.algorithm.config import ALGORITHMS, AgentConfig, Hyper, algorithm

__all__ = ["ALGORITHMS", "AgentConfig", "Hyper", "algorithm"]


class _Factory(types.ModuleType):
    """This package, callable as `algorithm`."""

    def __call__(self, name: str, **variants) -> AgentConfig:
        return algorithm(name, **variants)

    @property
    def __signature__(self):
        import inspect

        return inspect.signature(algorithm)


sys.modules[__name__].__class__ = _Factory
