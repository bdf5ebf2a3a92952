"""What a run returns: per-seed records (G7) in narrow integer types on the device, numpy on the host.

A compiled chunk returns `BatchOutput` (the signed trial log and the policy in the
narrowest integer types that hold them); host threads unpack it straight into the
run's preallocated `SeedResult` arrays (`unpack_output`).
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from jaxeac.pytree import pytree_dataclass


@pytree_dataclass
class SeedResult:
    """G7 per-seed record: success and steps per trial, and the final greedy policy."""

    success: jax.Array  # bool [T]
    steps: jax.Array  # int32 [T]
    policy: jax.Array  # int32 [S]
    finite: jax.Array | None = None  # bool []: every p(s, a) and V(s) finite at the end (no blow-up)


@pytree_dataclass
class BatchOutput:
    """What a compiled chunk returns, in the narrowest integer types that hold it.

    ``log`` is `AgentState.log` per seed (chances used per trial, negated if it failed;
    every trial takes ≥ 1 chance, so the sign is the outcome), ``policy`` the G7 policy.
    Narrow types make the device-to-host transfer, the largest cost after the compute
    on GPUs, 4–5× smaller; `unpack_output` restores `SeedResult` on the host.
    """

    log: jax.Array  # int8/16/32 [M, T]
    policy: jax.Array  # int8/16/32 [M, S]
    finite: jax.Array | None = None  # bool [M]: the seed's tables stayed finite


def narrow_int(largest: int) -> np.dtype:
    """The smallest signed integer type holding −largest … largest."""
    for dtype in (np.int8, np.int16):
        if largest <= np.iinfo(dtype).max:
            return np.dtype(dtype)
    return np.dtype(np.int32)


def pack_output(env, log: jax.Array, policy: jax.Array, finite: jax.Array | None = None) -> BatchOutput:
    """A chunk's logs and policies in `narrow_int` types (exact: |log| ≤ C, policy < A)."""
    return BatchOutput(log.astype(narrow_int(env.n_chances)), policy.astype(narrow_int(env.n_actions)),
                       finite)


def empty_results(n: int, n_trials: int, n_states: int) -> SeedResult:
    """Host arrays for `n` seeds' results, filled chunk by chunk by `unpack_output`."""
    return SeedResult(success=np.empty((n, n_trials), bool), steps=np.empty((n, n_trials), np.int32),
                      policy=np.empty((n, n_states), np.int32), finite=np.ones(n, bool))


def unpack_output(out: BatchOutput, into: SeedResult | None = None, start: int = 0) -> SeedResult:
    """Host side of `pack_output`: success bool, steps and policy int32 (numpy arrays).

    With `into`, rows ``start …`` of its arrays are written in place (no temporaries, no
    concatenation of chunks: at 10^6 seeds per chunk that host work decides how fast
    several GPUs can go) and `into` is returned.
    """
    log, policy = np.asarray(out.log), np.asarray(out.policy)
    if into is None:
        into = empty_results(*log.shape, policy.shape[1])
        start = 0
    rows = slice(start, start + log.shape[0])
    np.greater(log, 0, out=into.success[rows])
    np.abs(log, out=into.steps[rows])
    into.policy[rows] = policy
    if out.finite is not None:
        into.finite[rows] = np.asarray(out.finite)
    return into


@dataclasses.dataclass
class SeedsResult:
    """Results of all seeds of one algorithm, as numpy arrays on the host."""

    seeds: np.ndarray  # int64 [N]
    success: np.ndarray  # bool [N, T]
    steps: np.ndarray  # int32 [N, T]
    policy: np.ndarray  # int32 [N, S]
    compile_seconds: float
    run_seconds: float
    settings: dict | None = None  # how it ran: the resolved `RunConfig`, chunk size, devices
    finite: np.ndarray | None = None  # bool [N]: False where a seed's p or V blew up to NaN/inf

    @property
    def non_finite_seeds(self) -> np.ndarray:
        """Seeds whose tables ended with a NaN or infinite value (numerical blow-up)."""
        return self.seeds[~self.finite] if self.finite is not None else self.seeds[:0]

    @property
    def successes(self) -> np.ndarray:
        return self.success.sum(axis=1)

    @property
    def first_success(self) -> np.ndarray:
        """1-based trial of the first success, −1 if none (G7)."""
        any_success = self.success.any(axis=1)
        return np.where(any_success, self.success.argmax(axis=1) + 1, -1)

    @property
    def agent_steps(self) -> int:
        return int(self.steps.sum())
