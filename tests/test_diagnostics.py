"""Memory diagnostics (SPEC E8): E1's branch per step, E2's learning steps and the E6 flags on
best actions, by hand, against the literal reference of tests/reference.py, against the run's
own seeds, and in the summary.json of `jaxeac grid` and `jaxeac bowling`."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_map_text
from reference import reference_run
from test_cli import SMALL

from jaxeac.algorithm.agent import StepRoute, init_agent, select_action
from jaxeac.algorithm.config import Hyper, algorithm
from jaxeac.algorithm.memory import with_committed
from jaxeac.cli import main
from jaxeac.envs.grid import GridWorld, get_map, parse_map, shortest_actions
from jaxeac.experiments.grid import GridSettings, memory_diagnostics, run_grid, run_grid_to_folder
from jaxeac.rng import action_uniform, seed_key, seed_words
from jaxeac.running.config import RunConfig
from jaxeac.running.diagnostics import diagnose_seeds, diagnostics_block, diagnostics_from_logs, seeds_block

R, L, U, D = 0, 1, 2, 3  # G2


def hyper() -> Hyper:
    return Hyper(jnp.float32(0.1), jnp.float32(0.3), jnp.float32(0.9), jnp.float32(1.0), jnp.float32(0.1))


def test_shortest_actions_by_hand():
    """E8's best grid actions: the moves (G2, G4) one step closer to the goal by shortest path."""
    grid = parse_map("...\n.#.\n..G\n")  # cells 0..8 row by row; 4 is an obstacle, 8 the goal
    best = shortest_actions(grid)
    expected = {0: {R, D}, 1: {R}, 2: {D}, 3: {D}, 4: set(), 5: {D}, 6: {R}, 7: {R}, 8: set()}
    assert {s: set(np.flatnonzero(best[s]).tolist()) for s in range(9)} == expected
    walled = parse_map("G#.\n.#.\n")  # the right column cannot reach the goal: no best action
    assert not shortest_actions(walled)[[2, 5]].any() and shortest_actions(walled)[3].tolist() == [0, 0, 1, 0]


def test_step_route_of_each_e1_branch():
    """`select_action(route=True)`: (a) success action, (b) flags restrict, (c) plain softmax (also
    when every action is flagged); E2 learns only in (c), or always with learn_on_memory_steps."""
    cfg = algorithm("eac").resolve()
    agent = init_agent(cfg, 4, 4, 3, 5)
    failed = np.zeros((4, 4), bool)
    failed[1, [0, 1]] = True  # state 1: two of four flagged → E1(b)
    failed[2] = True  # state 2: all flagged → E1(c)
    failed[0, 0] = True  # state 0 also has a success action, which wins → E1(a)
    agent = agent.replace(memory=with_committed(agent.memory, [3, -1, -1, -1], failed))

    def route(c, state, active=True):
        return tuple(bool(x) for x in jax.tree.leaves(
            select_action(c, agent, state, 0.5, hyper(), jnp.bool_(active), route=True)[2]))

    # fields in order: taken, remembered, restricted, learns
    assert route(cfg, 0) == (True, True, False, False)
    assert route(cfg, 1) == (True, False, True, False)
    assert route(cfg, 2) == (True, False, False, True)
    assert route(cfg, 3) == (True, False, False, True)
    assert route(cfg, 0, active=False) == (False, False, False, False)
    variant = algorithm("eac_learn_on_memory").resolve()
    assert route(variant, 0) == (True, True, False, True) and route(variant, 1) == (True, False, True, True)
    ac = algorithm("ac").resolve()
    plain = init_agent(ac, 4, 4, 3, 5)
    steps = [select_action(ac, plain, s, 0.5, hyper(), jnp.bool_(True), route=True) for s in range(4)]
    assert all(tuple(bool(x) for x in jax.tree.leaves(r)) == (True, False, False, True) for _, _, r in steps)
    action, learns = select_action(cfg, agent, 1, 0.5, hyper())  # without route: two values, as before
    assert int(action) in (2, 3) and not bool(learns)


# "G.#": the only start cell is 1; left (1) enters the goal, right (0) bumps (r̃ = −1), up and down
# leave the grid (stay, r̃ = 0 before the goal is known). One chance per trial (C = 1).
LINE = parse_map("G.#\n")


def seed_where(first: tuple[float, float], second: tuple[float, float] = (0.0, 1.0)) -> int:
    """A seed of root key 0 whose E1 uniforms of trials 1 and 2 (C = 1) lie in these ranges:
    with p = 0 everywhere, the softmax picks action ⌊4u⌋."""
    for seed in range(500):
        words = seed_words(seed_key(jax.random.key(0), seed))
        u = [float(action_uniform(words, t, 0, 1)) for t in (0, 1)]
        if first[0] <= u[0] < first[1] and second[0] <= u[1] < second[1]:
            return seed
    raise AssertionError("no such seed")


def line_diagnostics(algo: str, seed: int, trials: int = 3):
    env = GridWorld(LINE, 1)
    cfg = RunConfig(trials=trials, agent=algorithm(algo))
    return diagnose_seeds(env, cfg, root_key=0, seeds=[seed], best=shortest_actions(LINE))


def test_success_memory_hits_counted_by_hand():
    """Trial 1 goes left into the goal (E1 c, learns); E4 remembers it, so trials 2 and 3 take it
    from the success memory (E1 a) without learning (E2): hit rate 2/3, learning share 1/3."""
    seed = seed_where((0.25, 0.5))
    d = line_diagnostics("eac", seed)
    assert [x.tolist() for x in jax.tree.leaves(d.routes)] == [[[3]], [[2]], [[0]], [[1]]]
    assert d.success.tolist() == [[True, True, True]] and d.flags.tolist() == [0]
    block = seeds_block(d, best_known=True)
    assert block["hit_rate_per_chance"] == [pytest.approx(2 / 3)] and block["hit_rate"] == pytest.approx(2 / 3)
    assert block["learning_share"] == pytest.approx(1 / 3) and block["restricted_share"] == 0.0
    assert block["flags"] == 0 and block["flags_on_best_share"] is None
    ac = seeds_block(line_diagnostics("ac", seed), best_known=True)  # AC: no memory, every step learns
    assert (ac["hit_rate"], ac["restricted_share"], ac["learning_share"], ac["flags"]) == (0.0, 0.0, 1.0, 0)


def test_failure_flag_and_restricted_step_counted_by_hand():
    """Trial 1 leaves the grid (r̃ 0), trial 2 bumps (r̃ −1 < 0): E6 flags (1, right), not the best
    action (left). Trial 3 at cell 1 has one of four actions flagged: E1(b), no learning."""
    seed = seed_where((0.5, 1.0), (0.0, 0.25))
    d = line_diagnostics("eac", seed)
    taken, remembered, restricted, learns = (x.tolist() for x in jax.tree.leaves(d.routes))
    assert (taken, remembered, restricted, learns) == ([[3]], [[0]], [[1]], [[2]])
    assert d.success.tolist()[0][:2] == [False, False]
    assert d.flags.tolist() == [1] and d.flags_on_best.tolist() == [0]
    block = seeds_block(d, best_known=True)
    assert block["restricted_share"] == pytest.approx(1 / 3) and block["learning_share"] == pytest.approx(2 / 3)
    assert block["flags_judged"] == 1 and block["flags_on_best_share"] == 0.0
    assert block["flags_on_best_chance"] == pytest.approx(1 / 4)  # one best action of four at cell 1


def test_diagnostics_block_pools_and_leaves_empty_shares_null():
    routes = StepRoute(np.array([[4, 2], [6, 0]]), np.array([[1, 0], [2, 0]]), np.array([[1, 1], [0, 0]]),
                       np.array([[2, 1], [4, 0]]))
    block = diagnostics_block(routes, 5, flags_judged=4, flags_on_best=1, best_at_flags=2.0)
    assert block["steps_per_chance"] == [10, 2] and block["hit_rate_per_chance"] == [0.3, 0.0]
    assert block["hit_rate"] == 0.25 and block["restricted_share"] == pytest.approx(2 / 12)
    assert block["learning_share"] == pytest.approx(7 / 12)
    assert (block["flags"], block["flags_judged"], block["flags_on_best_share"], block["flags_on_best_chance"]) \
        == (5, 4, 0.25, 0.5)
    empty = StepRoute(*(np.zeros((1, 2), int) for _ in range(4)))
    block = diagnostics_block(empty, 0)
    assert block["hit_rate_per_chance"] == [None, None] and block["hit_rate"] is None
    assert block["flags_on_best_share"] is None and block["flags_on_best_chance"] is None


VARIANTS = {name: algorithm(name) for name in ("ac", "eac", "eac_failure_only", "eac_success_only",
                                               "eac_learn_on_memory", "eac_within_trial", "q_learning")}
VARIANTS["eac_buffer_small"] = algorithm("eac", memory="buffer", capacity=3)  # FIFO eviction in use


@pytest.mark.parametrize("algo", sorted(VARIANTS))
@pytest.mark.parametrize("world", ["paper7", "random"])
def test_counts_equal_the_literal_reference(algo, world, rng):
    """Per chance index: steps, E1(a), E1(b) and learning steps of tests/reference.py (float64, so
    every step is the same), and its failure memory (E7 buffer: the pairs it still holds) against
    the best actions (on paper7, EAC's flags land on best actions and elsewhere)."""
    grid = get_map(world) if world != "random" else parse_map(random_map_text(rng))
    trials, chances, key = 30, 8, 7
    agent_cfg = VARIANTS[algo]
    with jax.enable_x64(True):
        env = GridWorld(grid, chances)
        cfg = RunConfig(trials=trials, agent=agent_cfg)
        best = shortest_actions(grid)
        d = diagnose_seeds(env, cfg, root_key=key, seeds=[0, 1], best=best)
        for i in range(2):
            ref = reference_run(grid, agent_cfg, trials=trials, chances=chances, alpha=0.1, beta=0.3,
                                gamma=0.9, tau=1.0, key=seed_key(jax.random.key(key), i))
            expected = np.zeros((4, chances), int)
            for t in ref.trials:
                for c, (branch, learned) in enumerate(zip(t.branches, t.learned, strict=True)):
                    expected[:, c] += [1, branch == "a", branch == "b", learned]
            got = np.stack([x[i] for x in jax.tree.leaves(d.routes)])
            np.testing.assert_array_equal(got, expected, err_msg=f"seed {i}: taken/a/b/learns per chance")
            assert d.success[i].tolist() == [t.success for t in ref.trials]
            flags = ref.failure_memory
            assert int(d.flags[i]) == len(flags)
            assert int(d.flags_on_best[i]) == sum(bool(best[s, a]) for s, a in flags)
            assert float(d.best_at_flags[i]) == pytest.approx(sum(best[s].mean() for s, _ in flags))
    if not agent_cfg.uses_memory:
        assert not np.asarray(d.routes.remembered).any() and not np.asarray(d.routes.restricted).any()
        np.testing.assert_array_equal(d.routes.learns, d.routes.taken)


@pytest.mark.parametrize("algo", ["ac", "eac", "eac_within_trial"])
def test_diagnosed_seeds_are_the_runs_seeds(algo):
    """The `trials` loop with diagnose re-runs exactly the run's seeds (flat loop, memory jumps
    for EAC): the same success in every trial, from any first seed (R1, R2)."""
    settings = GridSettings(seeds=6, trials=40, key=3, algos=(algo,)).resolved()
    run = run_grid(settings, first_seed=5)
    r = run.results[algo]
    d = diagnose_seeds(settings.make_env(), settings.run_config(algo), root_key=3, seeds=r.seeds)
    np.testing.assert_array_equal(d.success, r.success)
    out = memory_diagnostics(run, max_seeds=4)
    assert out["diagnostics_seeds"] == 4 and out["memory_diagnostics"][algo]["successes_match_run"] is True
    block = out["memory_diagnostics"][algo]
    assert len(block["hit_rate_per_chance"]) == settings.chances
    if algo == "ac":
        assert (block["hit_rate"], block["restricted_share"], block["learning_share"], block["flags"]) \
            == (0.0, 0.0, 1.0, 0)


@pytest.mark.parametrize(("algo", "env_name"), [("ac", None), ("q_learning", None), ("sarsa", None),
                                                ("ac", "FrozenLake-4x4-slippery-v1")])
def test_counts_without_memories_follow_from_the_run_logs(algo, env_name):
    """E8 of AC and the X3 baselines from the run's trial logs (`diagnostics_from_logs`) equals the
    `trials` loop's counts seed by seed, best actions known or not."""
    settings = GridSettings(seeds=7, trials=30, key=4, algos=(algo,), env=env_name).resolved()
    r = run_grid(settings).results[algo]
    env, grid_map = settings.make_env(), settings.grid_map()
    best = shortest_actions(grid_map) if grid_map is not None else None
    loop = diagnose_seeds(env, settings.run_config(algo), root_key=4, seeds=r.seeds, best=best)
    logs = diagnostics_from_logs(r.logs_of_first(7), env.n_chances)
    for a, b in zip(jax.tree.leaves(loop), jax.tree.leaves(logs), strict=True):
        np.testing.assert_array_equal(a, b)
        assert a.dtype == b.dtype
    assert logs.routes.taken[:, 0].tolist() == [30] * 7 and logs.routes.taken.sum() == r.agent_steps


def test_a_streamed_run_counts_only_its_memory_algorithms_again(tmp_path, monkeypatch):
    """A run written as it goes keeps its first seeds' trial logs (`CompactSeeds.first_logs`), so E8
    re-runs only EAC in the `trials` loop; AC's counts are those the loop gives."""
    import jaxeac.experiments.grid as grid

    settings = GridSettings(seeds=9, trials=20, key=1, algos=("ac", "eac"), chunk_size=4).resolved()
    asked = []
    diagnose = grid.diagnose_grid

    def counting(s, m, seeds):
        asked.append(sorted(seeds))
        return diagnose(s, m, seeds)

    monkeypatch.setattr(grid, "diagnose_grid", counting)
    run, summary = run_grid_to_folder(settings, tmp_path / "run", figures=False)
    assert asked == [["eac"]]
    whole = run_grid(settings).results["ac"]
    np.testing.assert_array_equal(run.results["ac"].logs_of_first(9), whole.logs_of_first(9))
    best = shortest_actions(settings.grid_map())
    full = seeds_block(diagnose_seeds(settings.make_env(), settings.run_config("ac"), root_key=1,
                                      seeds=np.arange(9), best=best), True)
    assert summary["memory_diagnostics"]["ac"] == full | {"successes_match_run": True}


def test_chunks_change_no_count(monkeypatch):
    """Chunking the diagnosed seeds (`CHUNK_BYTES`) gives the same counts seed by seed."""
    from jaxeac.running import diagnostics

    settings = GridSettings(seeds=5, trials=30, key=2, algos=("eac",)).resolved()
    env, cfg = settings.make_env(), settings.run_config("eac")
    whole = diagnose_seeds(env, cfg, root_key=2, seeds=np.arange(5), best=shortest_actions(settings.grid_map()))
    monkeypatch.setattr(diagnostics, "CHUNK_BYTES", 1)  # one seed per chunk
    one_by_one = diagnose_seeds(env, cfg, root_key=2, seeds=np.arange(5), best=shortest_actions(settings.grid_map()))
    for a, b in zip(jax.tree.leaves(whole), jax.tree.leaves(one_by_one), strict=True):
        np.testing.assert_array_equal(a, b)


def test_beside_an_accelerator_each_call_runs_on_one_host_device(monkeypatch):
    """E8 on a platform other than the default backend (the host's CPU beside a GPU's runs) runs each
    call on one of its devices (many calls go side by side); on the default backend it splits the
    seeds over every device. The counts are the same (R2)."""
    from jaxeac.running import diagnostics

    settings = GridSettings(seeds=6, trials=25, key=1, algos=("eac",)).resolved()
    env, cfg, best = settings.make_env(), settings.run_config("eac"), shortest_actions(settings.grid_map())
    split = diagnose_seeds(env, cfg, root_key=1, seeds=np.arange(6), best=best, platform="cpu")
    assert len(diagnostics._devices("cpu", 6)) == min(6, len(jax.local_devices(backend="cpu")))
    monkeypatch.setattr(diagnostics.jax, "default_backend", lambda: "gpu")
    assert len(diagnostics._devices("cpu", 6)) == 1 and len(diagnostics._devices(None, 6)) > 0
    alone = diagnose_seeds(env, cfg, root_key=1, seeds=np.arange(6), best=best, platform="cpu")
    for a, b in zip(jax.tree.leaves(split), jax.tree.leaves(alone), strict=True):
        np.testing.assert_array_equal(a, b)


def test_grid_cli_summary_carries_the_diagnostics(tmp_path):
    out = tmp_path / "run"
    assert main(["grid", *SMALL, "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["diagnostics_seeds"] == 4 and summary["diagnostics_seconds"] > 0
    diag = summary["memory_diagnostics"]
    assert set(diag) == {"ac", "eac"}
    for block in diag.values():
        assert block["successes_match_run"] is True
        assert len(block["hit_rate_per_chance"]) == len(block["steps_per_chance"]) == 10
        assert block["steps_per_chance"][0] == 4 * 6  # every trial takes its first chance
        assert block["steps"] == sum(block["steps_per_chance"])
    assert (diag["ac"]["hit_rate"], diag["ac"]["learning_share"], diag["ac"]["flags"]) == (0.0, 1.0, 0)
    eac = diag["eac"]
    assert eac["hit_rate"] + eac["restricted_share"] + eac["learning_share"] == pytest.approx(1.0)  # E1/E2
    assert eac["flags_judged"] == eac["flags"]


def test_bowling_counters_by_hand():
    """Bowling's `throw_routes` and `end_flags` on the hand-made memory of E4/E6's bowling test."""
    from test_bowling_agent import throw_

    from jaxeac.experiments.bowling import FULL_RACK, N_MASKS, PAPER_RULES, _diagnostic_steps

    cfg = RunConfig(trials=5, agent=algorithm("eac"), gamma=1.0).resolve(None)
    agent = init_agent(cfg.agent, N_MASKS, 3, 2, 5)
    for state, action, knocked, after, last in [
        (FULL_RACK, 0, 5, 100, False), (100, 1, 3, 7, True),  # trial 1 fails
        (FULL_RACK, 1, 4, 200, False), (200, 2, 6, 0, True),  # trial 2: a spare, remembered (E4)
        (FULL_RACK, 0, 2, 300, False), (300, 0, 1, 5, True),  # trial 3 fails: (1023, 0), (300, 0) flagged
    ]:
        agent = throw_(cfg, agent, state, action, knocked, after, last)
    routes, flags_of = _diagnostic_steps(cfg, 3, PAPER_RULES)
    agents = jax.tree.map(lambda x: jnp.stack([x] * 3), agent)  # three seeds, at three states
    words = jnp.zeros((3, 2), jnp.uint32)
    states = jnp.array([FULL_RACK, 300, 5], jnp.int32)
    route = routes(agents, words, states, hyper(), jnp.ones(3, bool))
    # full rack: success action (E1 a); 300: one of three flagged (E1 b); 5: never seen (E1 c, learns)
    assert [x.tolist() for x in jax.tree.leaves(route)] == [
        [True, True, True], [True, False, False], [False, True, False], [False, False, True]]
    flags, rack = flags_of(agents)
    assert flags.tolist() == [2, 2, 2] and rack[0].tolist() == [True, False, False]


def test_bowling_cli_summary_carries_the_diagnostics(tmp_path):
    out = tmp_path / "b"
    argv = ["bowling", "--seeds", "2", "--trials", "3", "--out", str(out), "--quiet", "--no-compare"]
    assert main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    npz = np.load(out / "bowling.npz")
    assert summary["diagnostics_seeds"] == 2 and len(summary["rack_mean_pins"]) == 21
    assert summary["best_rack_actions"]
    means = np.array([np.nan if x is None else x for x in summary["rack_mean_pins"]])
    assert np.nanmax(means) == pytest.approx(means[summary["best_rack_actions"][0]])
    for algo, block in summary["memory_diagnostics"].items():
        action = npz[f"{algo}_action"]
        assert block["steps_per_chance"] == [int((action[:, :, c] >= 0).sum()) for c in range(2)]
        assert len(block["hit_rate_per_chance"]) == 2
        assert block["hit_rate"] + block["restricted_share"] + block["learning_share"] == pytest.approx(1.0)
    ac = summary["memory_diagnostics"]["ac"]
    assert (ac["hit_rate_per_chance"], ac["learning_share"], ac["flags"]) == ([0.0, 0.0], 1.0, 0)


def test_sequential_bowling_keeps_the_counters():
    """`BowlingResult.concatenate` (sequential runs) joins the E8 counters of its batches."""
    from jaxeac.experiments.bowling import BowlingDiagnostics, BowlingResult

    def part(n):
        routes = StepRoute(*(np.full((n, 2), i, np.int32) for i in range(4)))
        return BowlingResult(np.zeros((n, 1, 2), np.int8), np.zeros((n, 1, 2), np.int8), np.zeros((n, 1), bool),
                             np.zeros(3), 0.0, 1.0, np.full((n, 1, 2), -1, np.int16),
                             BowlingDiagnostics(routes, np.arange(n), np.zeros((n, 3), bool)))

    joined = BowlingResult.concatenate([part(2), part(3)])
    assert joined.diagnostics.flags.tolist() == [0, 1, 0, 1, 2] and joined.diagnostics.routes.taken.shape == (5, 2)
    assert BowlingResult.concatenate([part(2), dataclasses.replace(part(1), diagnostics=None)]).diagnostics is None


def test_counts_beside_the_run_equal_counts_after_it(tmp_path, monkeypatch):
    """E8 on accelerators is computed while the device runs the seeds (`DIAGNOSE_BESIDE_THE_RUN`):
    forced on the CPU, the summary's diagnostics equal those computed after the run."""
    import json

    import jaxeac.experiments.grid as grid
    from jaxeac.cli import main

    def diagnostics(out):
        argv = ["grid", "--preset", "paper7", "--seeds", "12", "--trials", "20", "--out", str(out), "--quiet",
                "--no-compare"]
        assert main(argv) == 0
        summary = json.loads((out / "summary.json").read_text())
        return summary["diagnostics_seeds"], summary["memory_diagnostics"]

    after = diagnostics(tmp_path / "after")
    monkeypatch.setitem(grid.DIAGNOSE_BESIDE_THE_RUN, "cpu", True)
    calls = []
    diagnose = grid.diagnose_grid
    monkeypatch.setattr(grid, "diagnose_grid", lambda *a: calls.append(1) or diagnose(*a))
    beside = diagnostics(tmp_path / "beside")
    assert calls == [1] and beside == after and after[0] == 12
    assert all(block["successes_match_run"] for block in after[1].values())


def test_diagnostic_seed_count_bounds_the_trials_loop_work():
    """E8 re-runs at most 1000 seeds and at most 10^7 chance evaluations (T × C a seed), never fewer
    than 100 seeds nor more than the run has: 1000 on the paper grid, 100 on Four Rooms (C = 500)."""
    from jaxeac.running.diagnostics import diagnostic_seed_count

    assert diagnostic_seed_count(10_000, 200, 40) == 1000  # 10^7 // 8000 = 1250, capped at 1000
    assert diagnostic_seed_count(10_000, 200, 100) == 500
    assert diagnostic_seed_count(10_000, 200, 500) == 100
    assert diagnostic_seed_count(10_000, 2000, 5000) == 100  # the floor
    assert diagnostic_seed_count(7, 200, 500) == 7
