"""The agent of Debnath & Nassour (2014): AC equations (1)–(4) and EAC's Algorithm 1 (SPEC E1–E7).

`config` (what defines an agent), `tables` (p and V), `memory` (success/failure
experience, E7 layouts behind one interface) and `agent` (one definition of each
step of Algorithm 1, called by every loop, the GPU kernel and bowling).
"""

from jaxeac.algorithm.config import ALGORITHMS, AgentConfig, Hyper, algorithm

__all__ = ["ALGORITHMS", "AgentConfig", "Hyper", "algorithm"]
