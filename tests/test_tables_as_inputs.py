"""Tabular tasks as data (X1): a task's tables are inputs of its compiled program, padded to a layout
shared by a group of tasks, so one program per algorithm serves every task of the group whatever its
C, on the XLA loop and in the fused kernel, with each task's own per-seed results (R2)."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

from jaxeac.algorithm.config import algorithm
from jaxeac.envs import make
from jaxeac.envs.tabular import TableLayout, TabularEnv
from jaxeac.errors import UsageError
from jaxeac.running import batch
from jaxeac.running.batch import run_algorithms, run_seeds
from jaxeac.running.config import RunConfig

#: Same C (100), same actions: a deterministic task with jumps, a stochastic one (K = 3), a bigger one.
GROUP = ("FrozenLake-4x4-v1", "FrozenLake-4x4-slippery-v1", "CliffWalking-v1")
ALGOS = ("ac", "eac", "eac_within_trial", "q_learning")


def _plain(name: str, chances: int | None = None) -> TabularEnv:
    return TabularEnv(make(name).task, chances)


def _padded(names, chances: int | None | tuple = None) -> list[TabularEnv]:
    per_task = chances if isinstance(chances, tuple) else (chances,) * len(names)
    plain = [_plain(n, c) for n, c in zip(names, per_task, strict=True)]
    layout = TableLayout.covering(plain)
    return [env.padded(layout) for env in plain]


def _same(a, b):
    np.testing.assert_array_equal(a.success, b.success)
    np.testing.assert_array_equal(a.steps, b.steps)
    np.testing.assert_array_equal(a.policy, b.policy)


def test_layout_covers_the_group_and_gates_jumps():
    envs = _padded(GROUP)
    layout = envs[0].layout
    assert layout == TableLayout(states=48, outcomes=3, starts=1, chances=100, gated_jumps=True)
    assert [env.n_states for env in envs] == [16, 16, 48]  # the task's own, outside the program
    assert len({env.program_key() for env in envs}) == 1
    assert {RunConfig(trials=20, agent=algorithm("eac")).resolve(env).jump for env in envs} == {"on"}
    with pytest.raises(UsageError, match="does not hold its tables"):
        _plain("CliffWalking-v1").padded(TableLayout(16, 1, 1, 100))
    with pytest.raises(UsageError, match="does not hold its tables"):
        _plain("CliffWalking-v1").padded(TableLayout(48, 1, 1, 99))


@pytest.mark.parametrize("algo", ALGOS)
def test_padded_tables_give_each_task_its_own_results(algo):
    """Padded states are never entered, padded outcomes never drawn, and the jump gate keeps the
    stochastic task's steps: each task's seeds as with its own tables (policies of its own states)."""
    cfg = RunConfig(trials=30, agent=algorithm(algo))
    for name, env in zip(GROUP, _padded(GROUP), strict=True):
        _same(run_seeds(env, cfg, root_key=4, n_seeds=20, chunk_size=10),
              run_seeds(_plain(name), cfg, root_key=4, n_seeds=20, chunk_size=10))


@pytest.mark.parametrize("chances", [None, (20, 35, 50)])
def test_one_program_per_algorithm_serves_every_task(monkeypatch, chances):
    """Three tasks × four algorithms compile four programs: the first task's; the others reuse them,
    whether their C are the same or not."""
    built = []
    make_batch_run = batch.make_batch_run
    monkeypatch.setattr(batch, "make_batch_run", lambda *a, **k: built.append(a[1]) or make_batch_run(*a, **k))
    batch._COMPILED.clear()
    cfgs = [RunConfig(trials=20, agent=algorithm(a)) for a in ALGOS]
    compile_seconds = []
    for env in _padded(GROUP, chances):
        runs = run_algorithms(env, cfgs, root_key=1, n_seeds=12, chunk_size=12)
        compile_seconds.append([r.compile_seconds for r in runs])
    assert len(built) == len(ALGOS)
    assert all(s > 0 for s in compile_seconds[0]) and not any(compile_seconds[1] + compile_seconds[2])


@pytest.mark.parametrize("algo", ["ac", "eac"])
def test_kernel_runs_padded_tables_as_the_xla_loop(algo):
    """The fused kernel (Pallas's interpreter here) reads the padded tables and the jump gate as
    `TabularEnv` does: the same per-seed successes and steps, equal to the task's own run."""
    for name, env in zip(GROUP[:2], _padded(GROUP, chances=30)[:2], strict=True):
        runs = [run_seeds(e, RunConfig(trials=15, agent=algorithm(algo, tables="rows"), kernel=k, lanes=128),
                          root_key=6, n_seeds=128, chunk_size=128)
                for e, k in ((env, "pallas"), (env, "xla"), (_plain(name, 30), "xla"))]
        for other in runs[1:]:
            np.testing.assert_array_equal(runs[0].success, other.success)
            np.testing.assert_array_equal(runs[0].steps, other.steps)


#: C is data too: tasks of different C (each cut after its own, drawing its own counters, R1)
#: share one program per algorithm.
MIXED_C = (20, 35, 50)


def test_tasks_of_different_c_share_a_program_with_their_own_results():
    envs = _padded(GROUP, MIXED_C)
    assert len({env.program_key() for env in envs}) == 1
    assert envs[0].layout.chances == 50 and envs[0].layout.mixed_chances
    assert not _padded(GROUP)[0].layout.mixed_chances  # one C: part of the program, as for one task
    assert [env.n_chances for env in envs] == list(MIXED_C)  # the task's own, outside the program
    for algo in ALGOS + ("sarsa",):
        cfg = RunConfig(trials=25, agent=algorithm(algo))
        for name, c, env in zip(GROUP, MIXED_C, envs, strict=True):
            _same(run_seeds(env, cfg, root_key=9, n_seeds=12, chunk_size=12),
                  run_seeds(_plain(name, c), cfg, root_key=9, n_seeds=12, chunk_size=12))


@pytest.mark.parametrize("memory", ["dense", "buffer"])
def test_trials_loop_skips_chances_past_the_task_c(memory):
    """The literal loop runs the bound's chances, those past the task's C skipped (not taken)."""
    cfg = RunConfig(trials=15, agent=algorithm("eac", memory=memory), loop="trials")
    for name, c, env in zip(GROUP[:2], MIXED_C[:2], _padded(GROUP, MIXED_C)[:2], strict=True):
        _same(run_seeds(env, cfg, root_key=2, n_seeds=8, chunk_size=8),
              run_seeds(_plain(name, c), cfg, root_key=2, n_seeds=8, chunk_size=8))


def test_diagnostics_of_tasks_of_different_c_share_a_program_with_their_own_counts():
    """E8 (`count_runs`: the `trials` loop's chances up to the task's C, C read from the tables) of the
    tasks of a mixed-C layout: one compiled program per algorithm for all of them, in chunks of
    `MIXED_CHUNK` seeds, and each task's counts, per chance index up to its own C, those of its own
    tables (dense and buffer memories)."""
    from jaxeac.running import diagnostics

    diagnostics._EXECUTABLES.clear()
    built = []
    program = diagnostics._program
    pad = dict(zip(GROUP, _padded(GROUP, MIXED_C), strict=True))
    for memory in ("dense", "buffer"):
        cfg = RunConfig(trials=12, agent=algorithm("eac", memory=memory))
        for name, c in zip(GROUP[:2], MIXED_C[:2], strict=True):  # C 20 and 35 in a layout bound by 50
            with pytest.MonkeyPatch.context() as mp:
                mp.setattr(diagnostics, "_program", lambda *a: built.append(a[1]) or program(*a))
                mp.setattr(diagnostics, "MIXED_CHUNK", 4)
                ours = diagnostics.diagnose_seeds(pad[name], cfg, root_key=3, seeds=np.arange(6))
            own = diagnostics.diagnose_seeds(_plain(name, c), cfg, root_key=3, seeds=np.arange(6))
            assert ours.routes.taken.shape == (6, c) and ours.routes.taken[:, 0].sum() == 6 * 12
            for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(own), strict=True):
                np.testing.assert_array_equal(a, b)
    assert len(built) == 2  # one per memory layout, whatever the task and its C


def test_kernel_reads_each_task_c_from_its_tables():
    """The fused kernel (Pallas's interpreter here) loops and draws with the task's own C."""
    for name, c, env in zip(GROUP[:2], MIXED_C[:2], _padded(GROUP, MIXED_C)[:2], strict=True):
        cfg = RunConfig(trials=10, agent=algorithm("eac", tables="rows"), lanes=128)
        ours = run_seeds(env, dataclasses.replace(cfg, kernel="pallas"), root_key=6, n_seeds=128,
                         chunk_size=128)
        own = run_seeds(_plain(name, c), dataclasses.replace(cfg, kernel="xla"), root_key=6, n_seeds=128,
                        chunk_size=128)
        np.testing.assert_array_equal(ours.success, own.success)
        np.testing.assert_array_equal(ours.steps, own.steps)
