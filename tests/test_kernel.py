"""The fused GPU kernel (`jaxeac.running.kernel`) against the XLA loop, in Pallas's interpreter on the CPU.

On GPUs the two paths gave identical per-seed results for 20,000 seeds of every algorithm
(BENCHMARKS.md); here the kernel body runs as XLA:CPU ops whose fusions differ from the XLA
loop's, so a table entry may round differently in its last bit (a fused multiply-add). The
discrete run (actions, memories, trial log) must still match exactly.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from jaxeac.algorithm.config import algorithm
from jaxeac.envs import make
from jaxeac.envs.grid import GridWorld, get_map
from jaxeac.envs.tabular import TabularEnv, grid_world
from jaxeac.errors import UsageError
from jaxeac.rng import seed_key, seed_words
from jaxeac.running.batch import run_seeds
from jaxeac.running.config import RunConfig, kernel_unsupported, resolved_kernel
from jaxeac.running.kernel import LANES_PER_PROGRAM, advance_chances
from jaxeac.running.loops import flat_init, flat_slot

ENV = GridWorld(get_map("paper"), 40)
ALGOS = ["ac", "eac", "eac_within_trial", "eac_learn_on_memory", "eac_success_only", "eac_failure_only",
         "q_learning", "sarsa"]


def _lanes(cfg, n, trials_done=0, env=ENV):
    words = jax.vmap(lambda i: seed_words(seed_key(jax.random.key(7), i)))(jnp.arange(n))
    run = jax.vmap(lambda w: flat_init(env, cfg, w))(words)
    hyper = jax.tree.map(lambda x: jnp.broadcast_to(x, (n,)), cfg.hyper())
    return run, words, hyper


def _task(name: str, chances: int | None = None, rtilde: str = "shaped") -> TabularEnv:
    """A registered task's tables, with fewer chances to keep interpreted runs short."""
    return TabularEnv(make(name).task, chances, rtilde)


#: Tabular tasks (X1), run by the kernel from their tables: terminal states that are not successes
#: (FrozenLake's holes), rewards of their own (CliffWalking's −100), r̃ as the reward, and outcomes
#: drawn from the transition stream (slippery FrozenLake: 3, stochastic Four Rooms: 4, the slipping
#: paper grid: A + 1).
TASKS = {
    "frozenlake": _task("FrozenLake-4x4-v1"),
    "cliffwalking": _task("CliffWalking-v1", 40),
    "fourrooms": _task("FourRooms-v0", 60),
    "windy_reward": _task("WindyGridworld-v0", 40, rtilde="reward"),
    "frozenlake_slippery": _task("FrozenLake-4x4-slippery-v1"),
    "fourrooms_stochastic": _task("FourRooms-stochastic-v0", 60),
    "paper_slip": grid_world(get_map("paper"), 40, slip=0.2),
}


def _block_equals_xla_slots(env, algo, blocks=3, rtol=1e-6, atol=1e-7):
    """`blocks` blocks of C chances from fresh lanes: every integer field equal, tables to float rounding.
    With a success memory both paths jump (`flat_slot`), the jumps' own records included."""
    cfg = RunConfig(trials=6, agent=algorithm(algo, tables="rows"), kernel="xla").resolve(env)
    jumps = env.deterministic and algo in ("eac", "eac_within_trial", "eac_success_only")
    assert (cfg.jump == "on") == jumps
    run, words, hyper = _lanes(cfg, LANES_PER_PROGRAM, env=env)
    slot = jax.vmap(lambda c, w, h: flat_slot(env, cfg, c, w, h))
    xla = jax.jit(lambda r: jax.lax.fori_loop(
        0, blocks * env.n_chances, lambda _, x: slot(x, words, hyper), r))
    kernel = jax.jit(lambda r: jax.lax.fori_loop(
        0, blocks, lambda _, x: advance_chances(env, cfg, x, words, hyper, interpret=True), r))
    want, got = xla(run), kernel(run)
    assert int(want.agent.trial.min()) >= 1  # trials ended and restarted inside the blocks
    for (path, a), b in zip(jax.tree_util.tree_flatten_with_path(got)[0], jax.tree.leaves(want), strict=True):
        if jax.tree_util.keystr(path) == ".jumps.shadow.chance":
            continue  # E6's walk along the previous trial's path uses its cell only; the kernel keeps that
        if jnp.issubdtype(a.dtype, jnp.floating):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=rtol, atol=atol,
                                       err_msg=jax.tree_util.keystr(path))
        else:
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=jax.tree_util.keystr(path))
    return want


@pytest.mark.parametrize("algo", ALGOS)
def test_kernel_block_equals_c_xla_slots(algo):
    _block_equals_xla_slots(ENV, algo)


@pytest.mark.parametrize("task", list(TASKS))
@pytest.mark.parametrize("algo", ["ac", "eac", "eac_failure_only", "sarsa"])
def test_kernel_block_equals_xla_slots_on_tabular_tasks(task, algo):
    """The kernel reads a tabular task's move, reward, ends and r̃ from its tables, and draws a
    stochastic move's outcome, as `TabularEnv` does."""
    # Rounding apart in the last bit (module docstring) grows with rewards like CliffWalking's −100
    # over 160 chances; the integer fields (actions, memories, trial log) must still match exactly.
    want = _block_equals_xla_slots(TASKS[task], algo, blocks=4, rtol=1e-4, atol=1e-5)
    assert int(want.agent.log.astype(bool).sum()) > LANES_PER_PROGRAM  # trials ended inside the blocks


@pytest.mark.parametrize("algo", ["ac", "eac", "eac_failure_only", "sarsa"])  # SARSA: its next action per lane
@pytest.mark.parametrize("lanes", [None, LANES_PER_PROGRAM])  # a lane per seed (padded), and a queue
def test_kernel_runs_equal_xla_runs(algo, lanes):
    """Whole runs through `run_seeds`: the same successes and steps per trial for every seed
    (EAC: both jump)."""
    runs = [run_seeds(ENV, RunConfig(trials=25, agent=algorithm(algo, tables="rows"), kernel=k, lanes=lanes),
                      root_key=3, n_seeds=150, chunk_size=150) for k in ("xla", "pallas")]
    np.testing.assert_array_equal(runs[0].success, runs[1].success)
    np.testing.assert_array_equal(runs[0].steps, runs[1].steps)
    assert (runs[0].policy == runs[1].policy).all(axis=1).mean() > 0.9  # argmax ties may round apart


@pytest.mark.parametrize("task", ["frozenlake", "frozenlake_slippery"])
@pytest.mark.parametrize("algo", ["ac", "eac"])
def test_kernel_runs_equal_xla_runs_on_a_tabular_task(algo, task):
    """A whole run of a tabular task fed from a queue (128 lanes): the same per-seed results."""
    env = TASKS[task]
    runs = [run_seeds(env, RunConfig(trials=25, agent=algorithm(algo, tables="rows"), kernel=k, lanes=128),
                      root_key=5, n_seeds=300, chunk_size=300) for k in ("xla", "pallas")]
    np.testing.assert_array_equal(runs[0].success, runs[1].success)
    np.testing.assert_array_equal(runs[0].steps, runs[1].steps)
    assert runs[0].success.any() and not runs[0].success.all()  # holes end trials as failures


def test_kernel_choice_and_errors():
    eac = RunConfig(trials=10, agent=algorithm("eac", tables="rows"))
    assert resolved_kernel(ENV, eac, "gpu") == "pallas" and resolved_kernel(ENV, eac, "cpu") == "xla"
    for task in ("FourRooms-v0", "FourRooms-stochastic-v0"):
        assert resolved_kernel(make(task), eac, "gpu") == "pallas"
    for baseline in ("q_learning", "sarsa"):  # X3's baselines run in the kernel too
        cfg = RunConfig(trials=10, agent=algorithm(baseline, tables="rows"))
        assert kernel_unsupported(ENV, cfg) is None and resolved_kernel(ENV, cfg, "gpu") == "pallas"
    assert "the grid world and the tabular tasks only" in kernel_unsupported(object(), eac)  # e.g. an adapter
    split = RunConfig(trials=10, agent=algorithm("eac", tables="split"))
    assert resolved_kernel(ENV, split, "gpu") == "xla"  # auto falls back where the kernel cannot run
    assert "rows table layout" in kernel_unsupported(ENV, split)
    with pytest.raises(UsageError, match="rows table layout.*kernel='xla'"):
        resolved_kernel(ENV, RunConfig(trials=10, agent=algorithm("eac", tables="split"), kernel="pallas"))
    with pytest.raises(UsageError, match="constant step sizes"):
        resolved_kernel(ENV, RunConfig(trials=10, agent=algorithm("ac", tables="rows"), kernel="pallas",
                                       alpha=optax.constant_schedule(0.1)))
    with pytest.raises(UsageError, match="flat loop"):
        resolved_kernel(ENV, RunConfig(trials=10, agent=algorithm("eac", tables="rows", memory="buffer"),
                                       kernel="pallas"))
    with pytest.raises(UsageError, match="unknown kernel 'cuda'"):
        RunConfig(trials=10, agent=algorithm("ac"), kernel="cuda")
    with pytest.raises(ValueError, match="multiple of 128"):
        advance_chances(ENV, eac, *_lanes(eac, 100), interpret=True)
