"""What defines an agent: static choices (`AgentConfig`, hashed by jit) and traced rates (`Hyper`).

Static structure picks shapes and code paths; numeric settings are traced values so
sweeps vmap over them (STYLE: shapes static, rates traced). Every `auto` setting is
decided once by `resolve`, before tracing, and the resolved config is what a run
records.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Literal

import jax

from jaxeac.errors import UsageError
from jaxeac.pytree import pytree_dataclass

FailureRule = Literal["previous_trial", "within_trial"]
FAILURE_RULES = ("previous_trial", "within_trial")
TableLayout = Literal["auto", "split", "rows"]
TABLE_LAYOUTS = ("auto", "split", "rows")
MemoryLayout = Literal["dense", "buffer"]
MEMORY_LAYOUTS = ("dense", "buffer")
Learner = Literal["actor_critic", "q_learning", "sarsa"]
LEARNERS = ("actor_critic", "q_learning", "sarsa")

#: A step size: a constant, or an optax schedule over the 0-based trial index.
Rate = float | Callable[[jax.Array], jax.Array]


@dataclasses.dataclass(frozen=True)
class AgentConfig:
    """Static choices of the agent (shapes and code paths; hashed by jit).

    `success_memory` / `failure_memory` switch the two memories of Algorithm 1;
    both off is the classic AC. `learn_on_memory_steps` is the E2 variant and
    `failure_rule` the E6 variant. `memory` names the E7 storage layout of the
    memories (`dense` or `buffer` of `capacity` slots) and `tables` that of p and V
    (`split`, `rows`, or `auto`: rows on accelerators); layouts change speed, never results.
    `learner` is the paper's actor-critic, or a value-based baseline (X3: tabular
    Q-learning or SARSA, ε-greedy, without memories) run by the same loops.
    """

    success_memory: bool = True
    failure_memory: bool = True
    learn_on_memory_steps: bool = False
    failure_rule: FailureRule = "previous_trial"
    memory: MemoryLayout = "dense"
    capacity: int = 1024
    tables: TableLayout = "auto"
    learner: Learner = "actor_critic"

    def __post_init__(self):
        if self.learner not in LEARNERS:
            raise UsageError(f"unknown learner {self.learner!r}; choose one of {LEARNERS}")
        if self.learner != "actor_critic" and self.uses_memory:
            raise UsageError(f"the {self.learner} baseline keeps no success/failure memory; "
                             "set success_memory=False and failure_memory=False")
        if self.failure_rule not in FAILURE_RULES:
            raise UsageError(
                f"unknown failure_rule {self.failure_rule!r}; choose one of {FAILURE_RULES}"
            )
        if self.tables not in TABLE_LAYOUTS:
            raise UsageError(f"unknown table layout {self.tables!r}; choose one of {TABLE_LAYOUTS}")
        if self.memory not in MEMORY_LAYOUTS:
            raise UsageError(f"unknown memory layout {self.memory!r}; choose one of {MEMORY_LAYOUTS}")
        if isinstance(self.capacity, bool) or not isinstance(self.capacity, int) or self.capacity <= 0:
            raise UsageError(f"capacity must be a positive integer (got {self.capacity!r})")

    @property
    def uses_memory(self) -> bool:
        return self.success_memory or self.failure_memory

    def resolve(self, backend: str | None = None) -> AgentConfig:
        """The config with `tables="auto"` decided for `backend` (default: JAX's default backend)."""
        if self.tables != "auto":
            return self
        return dataclasses.replace(self, tables=resolve_tables(self.tables, backend))


def resolve_tables(layout: TableLayout, backend: str | None = None) -> Literal["split", "rows"]:
    """`auto`: rows on accelerators, split tables on the CPU (measured in BENCHMARKS.md)."""
    if layout != "auto":
        return layout
    return "split" if (backend or jax.default_backend()) == "cpu" else "rows"


#: The two algorithms of the paper, plus memory ablations (which part of EAC works?).
ALGORITHMS: dict[str, AgentConfig] = {
    "ac": AgentConfig(success_memory=False, failure_memory=False),
    "eac": AgentConfig(),
    "eac_success_only": AgentConfig(failure_memory=False),
    "eac_failure_only": AgentConfig(success_memory=False),
    "eac_learn_on_memory": AgentConfig(learn_on_memory_steps=True),  # E2 variant
    "eac_within_trial": AgentConfig(failure_rule="within_trial"),  # E6 variant
}

#: Standard value-based baselines for context (X3): is EAC good at all, not only better than AC?
BASELINES: dict[str, AgentConfig] = {
    "q_learning": AgentConfig(success_memory=False, failure_memory=False, learner="q_learning"),
    "sarsa": AgentConfig(success_memory=False, failure_memory=False, learner="sarsa"),
}


def algorithm(name: str, **overrides) -> AgentConfig:
    """The `AgentConfig` of a named algorithm (`ALGORITHMS` or `BASELINES`), with overrides."""
    known = ALGORITHMS | BASELINES
    if name not in known:
        raise UsageError(f"unknown algorithm {name!r}; choose from {', '.join(sorted(known))}")
    return dataclasses.replace(known[name], **overrides)


@pytree_dataclass
class Hyper:
    """Traced numeric settings (vmappable for sweeps): rates, discount, temperature."""

    alpha: jax.Array  # critic step size
    beta: jax.Array  # actor step size
    gamma: jax.Array  # discount
    temperature: jax.Array  # softmax temperature τ of (1)
    epsilon: jax.Array | None = None  # X3: exploration rate of the value-based baselines


def rate_at(rate: Rate, traced: jax.Array, trial: jax.Array) -> jax.Array:
    """A step size at a 0-based trial: the optax schedule's value, else the traced constant."""
    return rate(trial) if callable(rate) else traced
