"""Per-seed results pinned by digest (SPEC R2): a refactor or a speed-up must keep every one.

Each case runs a small but complete experiment on the CPU and hashes its per-seed
arrays (success, steps, policy; bowling: angles, pins, success). The expected
digests were computed before the architecture was consolidated; a change in any
of them means per-seed behaviour changed, which no refactor may do. Regenerate
(only for a deliberate, documented change of behaviour) with
``python tests/test_digests.py``.
"""

from __future__ import annotations

import hashlib
import sys

import numpy as np
import optax
import pytest

from jaxeac.algorithm.config import Hyper, algorithm
from jaxeac.envs.grid import GridWorld, get_map
from jaxeac.experiments.grid import GridSettings, run_grid
from jaxeac.running.batch import run_entries, run_seeds
from jaxeac.running.config import RunConfig


def digest(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    return h.hexdigest()[:16]


def seeds_digest(r) -> str:
    return digest(r.success, r.steps, r.policy)


def grid_all_algorithms() -> dict[str, str]:
    algos = ("ac", "eac", "eac_success_only", "eac_failure_only", "eac_learn_on_memory", "eac_within_trial")
    run = run_grid(GridSettings(seeds=48, trials=60, chunk_size=16, key=3, algos=algos).resolved())
    return {a: seeds_digest(r) for a, r in run.results.items()}


def grid_buffer_memory() -> dict[str, str]:
    run = run_grid(GridSettings(seeds=16, trials=40, key=5, memory="buffer", capacity=256,
                                algos=("eac",)).resolved())
    return {"eac": seeds_digest(run.results["eac"])}


ENV = GridWorld(get_map("paper"), 40)


def grid_row_tables() -> dict[str, str]:
    out = {}
    for algo in ("ac", "eac"):
        cfg = RunConfig(trials=50, agent=algorithm(algo, tables="rows"), loop="flat")
        out[algo] = seeds_digest(run_seeds(ENV, cfg, root_key=7, n_seeds=24, chunk_size=24))
    cfg = RunConfig(trials=30, agent=algorithm("eac", tables="split"), loop="trials")
    out["eac_trials_loop"] = seeds_digest(run_seeds(ENV, cfg, root_key=7, n_seeds=12, chunk_size=12))
    return out


def grid_schedule_and_sweep() -> dict[str, str]:
    sched = optax.linear_schedule(0.5, 0.05, 40)
    cfg = RunConfig(trials=50, agent=algorithm("eac"), beta=sched)
    out = {"schedule": seeds_digest(run_seeds(ENV, cfg, root_key=9, n_seeds=16, chunk_size=8))}
    cfg = RunConfig(trials=50, agent=algorithm("eac"))
    n = 12
    hyper = Hyper(alpha=np.linspace(0.05, 0.3, n), beta=np.full(n, 0.3), gamma=np.full(n, 0.9),
                  temperature=np.linspace(0.5, 2.0, n))
    res, _, _ = run_entries(ENV, cfg, root_key=2, seeds=np.arange(n), hyper=hyper, chunk_size=5)
    out["sweep"] = seeds_digest(res)
    return out


TASK_ALGOS = ("ac", "eac", "eac_success_only", "eac_failure_only", "eac_learn_on_memory", "eac_within_trial",
              "q_learning", "sarsa")


def tabular_task(env: str, slip: float = 0.0, algos=TASK_ALGOS, chances: int | None = None) -> dict[str, str]:
    """A tabular task (X1) under the study's algorithms (X4), seeds over several chunks."""
    settings = GridSettings(env=env, slip=slip, seeds=24, trials=40, chunk_size=10, key=11, chances=chances,
                            algos=algos).resolved()
    return {a: seeds_digest(r) for a, r in run_grid(settings).results.items()}


def tabular_frozen_lake() -> dict[str, str]:
    return tabular_task("FrozenLake-4x4-v1")


def tabular_frozen_lake_slippery() -> dict[str, str]:
    return tabular_task("FrozenLake-4x4-slippery-v1")


def tabular_cliff_walking() -> dict[str, str]:
    return tabular_task("CliffWalking-v1")


def tabular_four_rooms_stochastic() -> dict[str, str]:
    return tabular_task("FourRooms-stochastic-v0", algos=("ac", "eac", "q_learning"), chances=60)


def tabular_grid_slip() -> dict[str, str]:
    return tabular_task("grid-paper-v0", slip=0.1, algos=("ac", "eac", "sarsa"))


def bowling_c(sleep: bool = True) -> dict[str, str]:
    from jaxeac.envs.bowling import SolverSettings
    from jaxeac.experiments.bowling import BowlingSettings, run_bowling

    settings = BowlingSettings(seeds=4, trials=3, key=1, chunk_size=4, solver=SolverSettings(sleep=sleep))
    run = run_bowling(settings)
    return {a: digest(r.action, r.knocked, r.success) for a, r in run.results.items()}


def bowling_c_no_sleep() -> dict[str, str]:
    """The C engine without sleeping: the engine before sleeping existed, bit for bit."""
    return bowling_c(sleep=False)


CASES = {
    "grid_all_algorithms": grid_all_algorithms,
    "grid_buffer_memory": grid_buffer_memory,
    "grid_row_tables": grid_row_tables,
    "grid_schedule_and_sweep": grid_schedule_and_sweep,
    "bowling_c": bowling_c,
    "tabular_frozen_lake": tabular_frozen_lake,
    "tabular_frozen_lake_slippery": tabular_frozen_lake_slippery,
    "tabular_cliff_walking": tabular_cliff_walking,
    "tabular_four_rooms_stochastic": tabular_four_rooms_stochastic,
    "tabular_grid_slip": tabular_grid_slip,
    "bowling_c_no_sleep": bowling_c_no_sleep,
}

EXPECTED: dict[str, dict[str, str]] = {
    'grid_all_algorithms': {
        'ac': 'c7cc6b2cf868577a',
        'eac': '51b80c7820fd7bf6',
        'eac_success_only': '4463c9c271d80a97',
        'eac_failure_only': '2d3d3937d401f882',
        'eac_learn_on_memory': '3d28d45d3cdca270',
        'eac_within_trial': 'ebf8c914aba3e96d',
    },
    'grid_buffer_memory': {
        'eac': '40b1fcbb242798ed',
    },
    'grid_row_tables': {
        'ac': '6e9528ac1cb70b29',
        'eac': '4df59500d7de471d',
        'eac_trials_loop': 'b82634b7b55f58ab',
    },
    'grid_schedule_and_sweep': {
        'schedule': '6d92503a7d4b6b39',
        'sweep': '62c035bdf92a5d6c',
    },
    'tabular_frozen_lake': {
        'ac': 'ca99d42c212397d1',
        'eac': '2748a8b7d5d9b06a',
        'eac_failure_only': '0a51a357cdbd1c62',
        'eac_learn_on_memory': '2748a8b7d5d9b06a',
        'eac_success_only': 'ba661a9712f8786c',
        'eac_within_trial': '14458aff26b81cd5',
        'q_learning': 'cfadb62e12779304',
        'sarsa': 'cfadb62e12779304',
    },
    'tabular_frozen_lake_slippery': {
        'ac': 'f7cbb2b187f13cb2',
        'eac': 'ccf33cfe4ed43a9f',
        'eac_failure_only': '541667fbc687abe3',
        'eac_learn_on_memory': '64495f524b60864d',
        'eac_success_only': '39b6bbafa14ff215',
        'eac_within_trial': 'a0a22acc72ea90a9',
        'q_learning': 'aa5ce8bd4172c7ea',
        'sarsa': '448f78ecc52f143d',
    },
    'tabular_cliff_walking': {
        'ac': '25831cd6ca0a2c2a',
        'eac': 'e98d152191d41233',
        'eac_failure_only': 'b8912565149c01de',
        'eac_learn_on_memory': 'e36af8ada81c2bdd',
        'eac_success_only': 'e36af8ada81c2bdd',
        'eac_within_trial': 'b585df4a31e7c1d0',
        'q_learning': 'a3c287cf6c39be6d',
        'sarsa': '00665671f63faf65',
    },
    'tabular_four_rooms_stochastic': {
        'ac': '828a20cf66724569',
        'eac': 'cbdfdbaa2f96b505',
        'q_learning': '1ca005df3d54ebc7',
    },
    'tabular_grid_slip': {
        'ac': '45acfee73d937a2e',
        'eac': '24673df41b135858',
        'sarsa': 'c652f035d5549a42',
    },
    'bowling_c': {
        'ac': '80d291f6bb20d7e8',
        'eac': '31a400833ff70fc2',
    },
    'bowling_c_no_sleep': {
        'ac': 'f9fb59a4caddd30c',
        'eac': '768014369411bdde',
    },
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_per_seed_digests_unchanged_r2(case):
    assert CASES[case]() == EXPECTED[case]


if __name__ == "__main__":
    print({name: fn() for name, fn in CASES.items()}, file=sys.stdout)
