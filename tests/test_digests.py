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
