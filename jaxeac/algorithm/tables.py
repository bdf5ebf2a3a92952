"""The actor's preferences p(s, a) and the critic's values V(s), in two storage layouts.

Both layouts apply the same arithmetic, (2) V(s) ← V(s) + α·δ and (4)
p(s, a) ← p(s, a) + β·δ for the taken action (`learning_increments`), so they give
bit-identical runs; they differ only in speed (split on CPUs, rows on GPUs; E7's
"same semantics, different layout" applied to the tables).
"""

from __future__ import annotations

from typing import Literal

import jax
import jax.numpy as jnp

from jaxeac.pytree import pytree_dataclass, static_field


def learning_increments(delta, learn, alpha, beta) -> tuple[jax.Array, jax.Array]:
    """(β·δ, α·δ): the changes of p(s, a) by (4) and of V(s) by (2), or zeros unless `learn` (E2)."""
    step = jnp.where(learn, delta, 0.0)
    return beta * step, alpha * step


@pytree_dataclass
class SplitTables:
    """p(s, a) and V(s) as two arrays: the fewest bytes per seed (CPU default)."""

    preferences: jax.Array  # float [S, A]
    values: jax.Array  # float [S]

    def row(self, state) -> tuple[jax.Array, jax.Array]:
        """(p(s, ·) [A], V(s))."""
        return self.preferences[state], self.values[state]

    def value(self, state) -> jax.Array:
        return self.values[state]

    def learn(self, state, action, delta, alpha, beta, learn) -> SplitTables:
        """(2) and (4) at (state, action), applied when `learn`."""
        actor, critic = learning_increments(delta, learn, alpha, beta)
        return SplitTables(self.preferences.at[state, action].add(actor, unique_indices=True),
                           self.values.at[state].add(critic, unique_indices=True))


ROW_FLOATS = 8  # rows padded to a multiple of 8 floats: 32 bytes, one memory sector on GPUs


@pytree_dataclass
class RowTables:
    """p(s, ·) and V(s) side by side, one padded row per state (GPU default).

    Row s is ``[p(s, 0) … p(s, A−1), V(s), 0 …]`` with W = A + 1 rounded up to a multiple of
    8. A step reads row s once (softmax (1), δ of (3)) and writes it back once with both
    updates (2) and (4), where split tables take two scattered writes; on GPUs, where each
    scattered access costs a memory transaction, that is the cheaper layout.
    """

    rows: jax.Array  # float [S, W]
    n_actions: int = static_field()

    @property
    def preferences(self) -> jax.Array:
        return self.rows[:, :self.n_actions]

    @property
    def values(self) -> jax.Array:
        return self.rows[:, self.n_actions]

    def row(self, state) -> tuple[jax.Array, jax.Array]:
        r = self.rows[state]
        return r[:self.n_actions], r[self.n_actions]

    def value(self, state) -> jax.Array:
        return self.rows[state, self.n_actions]

    def learn(self, state, action, delta, alpha, beta, learn) -> RowTables:
        """(2) and (4) at (state, action) as one row write, applied when `learn`."""
        actor, critic = learning_increments(delta, learn, alpha, beta)
        column = jnp.arange(self.rows.shape[1])
        change = jnp.where(column == self.n_actions, critic, jnp.where(column == action, actor, 0.0))
        return self.replace(rows=self.rows.at[state].set(self.rows[state] + change, unique_indices=True))


Tables = SplitTables | RowTables


def init_tables(layout: Literal["split", "rows"], n_states: int, n_actions: int) -> Tables:
    """p = 0 and V = 0 everywhere (the uniform policy of Alg. 1 line 1), in a resolved layout."""
    if layout == "rows":
        width = -(-(n_actions + 1) // ROW_FLOATS) * ROW_FLOATS
        return RowTables(rows=jnp.zeros((n_states, width), float), n_actions=n_actions)
    if layout == "split":
        return SplitTables(preferences=jnp.zeros((n_states, n_actions), float),
                           values=jnp.zeros((n_states,), float))
    raise ValueError(f"table layout {layout!r} is not resolved; call AgentConfig.resolve() first")
