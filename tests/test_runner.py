"""Reproducibility of the vectorised runner (SPEC R1, R2): chunks, reruns, vmap vs single runs."""

from __future__ import annotations

import dataclasses
import time

import jax
import numpy as np
import optax
import pytest

from jaxeac.algorithm.config import algorithm
from jaxeac.envs.grid import GridWorld, get_map, parse_map
from jaxeac.errors import UsageError
from jaxeac.rng import seed_key
from jaxeac.running.batch import run_seeds
from jaxeac.running.config import RunConfig
from jaxeac.running.loops import make_run
from jaxeac.running.outputs import BatchOutput, empty_results, narrow_int, unpack_output

ENV = GridWorld(get_map("paper"), 40)


def run(algo="eac", **kw):
    cfg = RunConfig(trials=40, agent=algorithm(algo))
    return run_seeds(ENV, cfg, root_key=kw.pop("root_key", 11), **kw)


@pytest.mark.parametrize("algo", ["ac", "eac"])
def test_chunk_size_does_not_change_results_r1(algo):
    whole = run(algo, n_seeds=10, chunk_size=10)
    for chunk in (1, 3, 4, 7):
        parts = run(algo, n_seeds=10, chunk_size=chunk)
        np.testing.assert_array_equal(whole.success, parts.success)
        np.testing.assert_array_equal(whole.steps, parts.steps)
        np.testing.assert_array_equal(whole.policy, parts.policy)


def test_seed_results_do_not_depend_on_seed_count_r1():
    few, many = run(n_seeds=3, chunk_size=3), run(n_seeds=9, chunk_size=4)
    np.testing.assert_array_equal(few.steps, many.steps[:3])


def test_rerun_bit_identical_and_key_matters_r2():
    a, b = run(n_seeds=6, chunk_size=6), run(n_seeds=6, chunk_size=6)
    np.testing.assert_array_equal(a.steps, b.steps)
    c = run(n_seeds=6, chunk_size=6, root_key=12)
    assert not np.array_equal(a.steps, c.steps)


def test_vmapped_seeds_equal_separate_runs():
    cfg = RunConfig(trials=40, agent=algorithm("eac"))
    batch = run(n_seeds=5, chunk_size=5)
    single = jax.jit(make_run(ENV, cfg))
    root = jax.random.key(11)
    for i in range(5):
        r = single(seed_key(root, i), cfg.hyper())
        np.testing.assert_array_equal(np.asarray(r.steps), batch.steps[i])
        np.testing.assert_array_equal(np.asarray(r.success), batch.success[i])


def test_narrow_int_bounds():
    assert [narrow_int(n) for n in (1, 127, 128, 32767, 32768)] == [np.int8, np.int8, np.int16, np.int16,
                                                                      np.int32]


def test_unpack_output_by_hand():
    """Signed log → success and steps; policy widened; chunks written in place at their rows."""
    chunk = BatchOutput(log=np.array([[3, -40], [-1, 127]], np.int8), policy=np.array([[0, 3, 1]], np.int8))
    alone = unpack_output(BatchOutput(chunk.log[:1], chunk.policy))
    assert alone.success.tolist() == [[True, False]] and alone.steps.tolist() == [[3, 40]]
    assert alone.policy.dtype == np.int32 and alone.policy.tolist() == [[0, 3, 1]]
    whole = empty_results(3, 2, 3)
    whole.steps[0], whole.success[0], whole.policy[0] = 9, True, 2  # row 0 is not touched
    got = unpack_output(BatchOutput(chunk.log, np.array([[1, 1, 0], [2, 0, 0]], np.int8)), whole, start=1)
    assert got is whole
    assert whole.steps.tolist() == [[9, 9], [3, 40], [1, 127]] and whole.steps.dtype == np.int32
    assert whole.success.tolist() == [[True, True], [True, False], [False, True]]
    assert whole.policy.tolist() == [[2, 2, 2], [1, 1, 0], [2, 0, 0]]


def test_chunks_unpacked_in_row_blocks_equal_whole_chunks(monkeypatch):
    """Host threads unpack a chunk in row blocks (`UNPACK_ROWS`); blocks that split chunks unevenly."""
    import jaxeac.running.outputs as outputs

    cfg = RunConfig(trials=10, agent=algorithm("eac"))
    whole = run_seeds(ENV, cfg, root_key=4, n_seeds=11, chunk_size=8)
    monkeypatch.setattr(outputs, "UNPACK_ROWS", 3)
    blocks = run_seeds(ENV, cfg, root_key=4, n_seeds=11, chunk_size=8)
    for field in ("success", "steps", "policy"):
        np.testing.assert_array_equal(getattr(whole, field), getattr(blocks, field))


@pytest.mark.parametrize("whole_chunks", [True, False])  # measured on the host, or on the device
def test_compact_collector_keeps_the_same_measures_and_hands_on_every_chunk(monkeypatch, whole_chunks):
    """`CompactCollector` (streamed runs): success bits, per-seed measures, the first policies
    and logs equal the full host arrays', and every chunk reaches `on_chunk` once, in order; measured
    on the device (`device_measures`), only the chunks that keep rows bring their logs back, and
    only those rows."""
    import jaxeac.running.outputs as outputs

    cfg = RunConfig(trials=13, agent=algorithm("eac"))
    full = run_seeds(ENV, cfg, root_key=4, n_seeds=21, chunk_size=8)
    monkeypatch.setattr(outputs, "UNPACK_ROWS", 3)
    monkeypatch.setattr(outputs, "KEEP_POLICIES", 10)
    monkeypatch.setattr(outputs, "KEEP_LOGS", 9)
    seen, logs_back = [], []

    def on_chunk(start, chunk, m):
        seen.append((start, m["successes"].copy()))
        logs_back.append(None if chunk.log is None else (chunk.log.shape[0], chunk.policy.shape[0]))

    seeds = np.arange(21)
    collector = outputs.CompactCollector(seeds, 13, ENV.n_states, on_chunk=on_chunk, whole_chunks=whole_chunks)
    compact = run_seeds(ENV, cfg, root_key=4, n_seeds=21, chunk_size=8, collector=collector)
    # the chunk is balanced over the chunks and devices (21 = 3 × 7 on one device), as the full run's
    assert isinstance(compact, outputs.CompactSeeds)
    chunk = compact.settings["chunk_size"]
    assert chunk == full.settings["chunk_size"] in (7, 8)
    np.testing.assert_array_equal(compact.success.unpack(), full.success)
    np.testing.assert_array_equal(compact.success.bits,
                                  np.packbits(full.success, axis=1, bitorder="little"))
    np.testing.assert_array_equal(compact.successes, full.successes)
    np.testing.assert_array_equal(compact.first_success, full.first_success)
    np.testing.assert_array_equal(compact.steps_total, full.steps.sum(1))
    np.testing.assert_array_equal(compact.finite, full.finite)
    assert compact.agent_steps == full.agent_steps
    np.testing.assert_array_equal(compact.first_policies, full.policy[:10])
    np.testing.assert_array_equal(compact.first_logs, full.logs_of_first(9))
    assert [s for s, _ in seen] == list(range(0, 21, chunk))  # 3 chunks, rows kept in the first 2
    sizes = [min(chunk, 21 - s) for s in range(0, 21, chunk)]
    kept = [min(size, 10 - s) if s < 10 else None for s, size in zip(range(0, 21, chunk), sizes, strict=True)]
    assert logs_back == ([(n, n) for n in sizes] if whole_chunks else [k and (k, k) for k in kept])
    np.testing.assert_array_equal(np.concatenate([m for _, m in seen]), full.successes)


@pytest.mark.parametrize("chances", [127, 128])  # the chunk's log travels as int8, then as int16
def test_narrow_chunk_outputs_are_exact(chances):
    env = GridWorld(get_map("paper"), chances)
    cfg = RunConfig(trials=12, agent=algorithm("ac"), alpha=0.0, beta=0.0)  # no learning: long trials
    batch = run_seeds(env, cfg, root_key=3, n_seeds=4, chunk_size=4)
    single = jax.jit(make_run(env, cfg))
    for i in range(4):
        r = single(seed_key(jax.random.key(3), i), cfg.hyper())
        np.testing.assert_array_equal(np.asarray(r.steps), batch.steps[i])
        np.testing.assert_array_equal(np.asarray(r.success), batch.success[i])
        np.testing.assert_array_equal(np.asarray(r.policy), batch.policy[i])
    assert batch.steps.dtype == np.int32 and (batch.steps[~batch.success] == chances).all()
    assert (~batch.success).any()  # failed trials carry the full C, the value the narrow type must hold


def test_derived_per_seed_fields():
    r = run(n_seeds=8, chunk_size=8)
    assert r.success.shape == (8, 40) and r.steps.shape == (8, 40) and r.policy.shape == (8, 121)
    assert ((r.steps >= 1) & (r.steps <= 40)).all()
    assert (r.steps[~r.success] == 40).all()  # failed trials use all C chances
    first = r.first_success
    for i in range(8):
        hits = np.flatnonzero(r.success[i])
        assert first[i] == (hits[0] + 1 if hits.size else -1)
    assert r.agent_steps == r.steps.sum()


def test_optax_schedule_for_step_sizes():
    frozen = RunConfig(trials=30, agent=algorithm("ac"), alpha=optax.constant_schedule(0.0),
                       beta=optax.constant_schedule(0.0))
    learn = RunConfig(trials=30, agent=algorithm("ac"), alpha=optax.linear_schedule(0.5, 0.0, 30),
                      beta=optax.linear_schedule(0.5, 0.0, 30))
    a = run_seeds(ENV, frozen, root_key=0, n_seeds=4, chunk_size=4)
    b = run_seeds(ENV, learn, root_key=0, n_seeds=4, chunk_size=4)
    assert (a.policy == 0).all()  # no learning → argmax of zeros everywhere
    assert not np.array_equal(a.steps, b.steps)


def test_bad_counts():
    cfg = RunConfig(trials=5, agent=algorithm("ac"))
    with pytest.raises(UsageError, match="seeds must be a positive integer"):
        run_seeds(ENV, cfg, root_key=0, n_seeds=0)
    with pytest.raises(UsageError, match="chunk_size must be a positive integer"):
        run_seeds(ENV, cfg, root_key=0, n_seeds=2, chunk_size=0)


LOOP_CASES = [  # (algorithm, variant, map seed: 0 = paper map, else a random small map)
    ("ac", {}, 0),
    ("eac", {}, 0),
    ("eac", {"learn_on_memory_steps": True}, 1),
    ("eac", {"failure_rule": "within_trial"}, 2),
    ("eac_success_only", {}, 3),
    ("eac_failure_only", {}, 4),
    ("eac", {"tables": "rows"}, 5),
]


@pytest.mark.parametrize("lanes", [3, 64])  # fewer lanes than entries (a queue); a lane for each
@pytest.mark.parametrize(("algo", "variant", "map_seed"), LOOP_CASES)
def test_flat_loop_equals_trials_loop(algo, variant, map_seed, lanes):
    """The fast flat loop and the literal trials loop give bit-identical runs."""
    from conftest import random_map_text

    from jaxeac.envs.grid import parse_map

    rng = np.random.default_rng(map_seed)
    env = ENV if map_seed == 0 else GridWorld(parse_map(random_map_text(rng)), int(rng.integers(1, 12)))
    agent = algorithm(algo, **variant)
    results = [
        run_seeds(env, RunConfig(trials=30, agent=agent, loop=loop, lanes=lanes), root_key=map_seed,
                  n_seeds=24, chunk_size=8)
        for loop in ("flat", "trials")
    ]
    np.testing.assert_array_equal(results[0].success, results[1].success)
    np.testing.assert_array_equal(results[0].steps, results[1].steps)
    np.testing.assert_array_equal(results[0].policy, results[1].policy)


def test_step_uniform_is_uniform_and_decorrelated():
    from scipy import stats

    from jaxeac.rng import action_counter, seed_words, step_uniform

    words = jax.vmap(seed_words)(jax.vmap(lambda i: seed_key(jax.random.key(0), i))(np.arange(64)))
    counters = action_counter(np.arange(200)[:, None], np.arange(41)[None, :], 40).reshape(-1)
    u = np.asarray(jax.vmap(lambda w: jax.vmap(lambda c: step_uniform(w, c))(counters))(words))
    assert u.min() >= 0 and u.max() < 1
    assert stats.kstest(u.reshape(-1), "uniform").pvalue > 1e-3
    # neighbouring counters and neighbouring seeds are uncorrelated
    assert abs(np.corrcoef(u[:, :-1].reshape(-1), u[:, 1:].reshape(-1))[0, 1]) < 0.01
    assert abs(np.corrcoef(u[:-1].reshape(-1), u[1:].reshape(-1))[0, 1]) < 0.01


def test_default_lanes_per_backend_and_algorithm():
    """CPU: 256 lanes fed from a queue; accelerators: a lane per seed for AC, at most 2^18 for EAC
    (2^15 with the fused kernel)."""
    from jaxeac.running.config import default_lanes

    ac, eac = algorithm("ac"), algorithm("eac")
    assert default_lanes(ac, 10_000, "cpu") == default_lanes(eac, 10_000, "cpu") == 256
    assert default_lanes(ac, 4_000_000, "gpu") == 4_000_000
    assert default_lanes(eac, 4_000_000, "gpu") == 1 << 18
    assert default_lanes(eac, 1000, "gpu") == 1000  # fewer seeds than that: a lane each, no queue
    assert default_lanes(eac, 4_000_000, "gpu", kernel="pallas") == 1 << 15
    assert default_lanes(ac, 4_000_000, "gpu", kernel="pallas") == 4_000_000


def test_algorithms_in_one_pipeline_equal_separate_runs():
    """`run_algorithms`: programs compiled side by side, the next algorithm's chunks dispatched
    while the last one's come back; every seed's results are those of its own run (R1)."""
    from jaxeac.running.batch import run_algorithms

    cfgs = [RunConfig(trials=7, agent=algorithm(a)) for a in ("ac", "eac", "eac_within_trial")]
    together = run_algorithms(ENV, cfgs, root_key=9, n_seeds=10, chunk_size=4)
    for cfg, got in zip(cfgs, together, strict=True):
        alone = run_seeds(ENV, cfg, root_key=9, n_seeds=10, chunk_size=5)
        for field in ("success", "steps", "policy", "finite"):
            np.testing.assert_array_equal(getattr(got, field), getattr(alone, field))
        assert got.settings["chunk_size"] == 4 and got.compile_seconds >= 0


class _LoggedJob:
    """A stand-in for a compiled program in `run_chunks`: logs its dispatches and collections;
    group 0 of `groups` takes `slow` seconds a chunk, the others none."""

    def __init__(self, name: str, log: list, chunks: int, on_collect=None, groups: int = 1, slow: float = 0.0):
        self.name, self.log, self.chunks, self.on_collect = name, log, chunks, on_collect
        self.groups, self.slow, self.ran = [(None,)] * groups, slow, []
        self.first_dispatch = self.last_collect = self.started_after = 0.0

    def starts(self):
        return range(self.chunks)

    def dispatch(self, start, group):
        self.log.append(f"dispatch {self.name}{start}")
        self.ran.append(group)
        return 1, group

    def ready(self, out):
        if out == 0:
            time.sleep(self.slow)

    @staticmethod
    def fetch(size, out):
        return out

    def collect(self, start, host, pool):
        self.log.append(f"collect {self.name}{start}")
        if self.on_collect is not None:
            self.on_collect()


def test_a_program_runs_while_the_next_one_compiles():
    """`run_chunks`: a device keeps two chunks dispatched while the host collects, in order; a
    job still compiling (a pending future) lets the chunks in flight come back meanwhile instead
    of waiting with them."""
    from concurrent.futures import Future

    from jaxeac.running.schedule import run_chunks as _run_chunks

    log: list[str] = []
    ready = Future()
    ready.set_result(_LoggedJob("b", log, 1))
    _run_chunks([_LoggedJob("a", log, 2), ready], None)
    assert [x for x in log if x.startswith("dispatch")] == ["dispatch a0", "dispatch a1", "dispatch b0"]
    assert [x for x in log if x.startswith("collect")] == ["collect a0", "collect a1", "collect b0"]
    assert log.index("dispatch a1") < log.index("collect a0")  # two in flight
    log.clear()
    compiling = Future()  # compiles until a's last chunk is back
    first = _LoggedJob("a", log, 2, on_collect=lambda: log[-1] == "collect a1" and compiling.set_result(
        _LoggedJob("b", log, 1)))
    _run_chunks([first, compiling], None)
    assert log == ["dispatch a0", "dispatch a1", "collect a0", "collect a1", "dispatch b0", "collect b0"]


def test_devices_take_chunks_at_their_own_pace():
    """`run_chunks` with several device groups: each takes the next chunk from the shared queue
    when it has room (at most `CHUNKS_IN_FLIGHT` + 1 ahead of the host's collection), so a slow
    device runs fewer chunks; the host still collects them in seed order."""
    from jaxeac.running.schedule import run_chunks as _run_chunks

    log: list[str] = []
    job = _LoggedJob("a", log, 24, groups=2, slow=0.05)
    _run_chunks([job], None)
    assert [x for x in log if x.startswith("collect")] == [f"collect a{i}" for i in range(24)]
    assert job.ran.count(1) > job.ran.count(0) > 0, job.ran


def test_on_drained_is_called_once_when_every_chunk_is_handed_out():
    """`run_chunks(on_drained=...)`: called once, on a thread of its own, after the last chunk's
    dispatch (E8's counts start there in `jaxeac grid`), whatever the device groups."""
    import threading

    from jaxeac.running.schedule import run_chunks as _run_chunks

    for groups in (1, 2):
        log: list[str] = []
        called = threading.Event()
        seen: list = []

        def drained(log=log, seen=seen, called=called) -> None:
            seen.append((threading.current_thread() is threading.main_thread(),
                         [x for x in log if x.startswith("dispatch")]))
            called.set()

        _run_chunks([_LoggedJob("a", log, 5, groups=groups)], None, drained)
        assert called.wait(5)
        assert len(seen) == 1 and not seen[0][0]
        assert seen[0][1] == [f"dispatch a{i}" for i in range(5)]


def test_a_device_joins_when_its_own_program_is_in():
    """Each device takes chunks once its own program is in (`program_pending`): the first
    device's runs while the second's is still loading; the second then joins, and the host
    still collects every chunk once, in seed order."""
    import threading
    from concurrent.futures import Future

    from jaxeac.running.schedule import run_chunks as _run_chunks

    loading: Future = Future()

    class Loading(_LoggedJob):
        def program_pending(self, group):
            return loading if group == 1 and not loading.done() else None

        def dispatch(self, start, group):
            assert group == 0 or loading.done()
            if start == 3:  # the second device's program comes in while the first runs
                threading.Timer(0.01, loading.set_result, args=("program",)).start()
            return super().dispatch(start, group)

        def ready(self, out):
            time.sleep(0.005)

    log: list[str] = []
    job = Loading("a", log, 40, groups=2)
    _run_chunks([job], None)
    assert [x for x in log if x.startswith("collect")] == [f"collect a{i}" for i in range(40)]
    assert job.ran[:4] == [0, 0, 0, 0] and 1 in job.ran, job.ran


def test_chunks_are_prepared_on_the_device_threads_and_collected_in_order():
    """`prepare` (a chunk's own rows) runs on the device groups' threads, several chunks at
    once and in any order; `collect` gets every prepared chunk once, in seed order, on the
    calling thread."""
    import threading

    from jaxeac.running.schedule import run_chunks as _run_chunks

    class Prepared(_LoggedJob):
        def __init__(self, *a, **kw):
            super().__init__(*a, **kw)
            self.prepared, self.threads = {}, set()

        def prepare(self, start, host, pool):
            self.threads.add(threading.current_thread().name)
            time.sleep(0.002 * (start % 3))  # out of order
            self.prepared[start] = host
            return ("prepared", start)

        def collect(self, start, host, pool):
            assert host == ("prepared", start) and threading.current_thread() is threading.main_thread()
            super().collect(start, host, pool)

    log: list[str] = []
    job = Prepared("a", log, 30, groups=3)
    _run_chunks([job], None)
    assert [x for x in log if x.startswith("collect")] == [f"collect a{i}" for i in range(30)]
    assert sorted(job.prepared) == list(range(30))
    assert job.threads <= {f"jaxeac-device-{g}" for g in range(3)} and len(job.threads) > 1, job.threads


def test_a_failing_device_stops_the_run():
    """An error on a device's thread reaches the caller, and the run stops."""
    from jaxeac.running.schedule import run_chunks as _run_chunks

    class Failing(_LoggedJob):
        def ready(self, out):
            raise RuntimeError("device lost")

    with pytest.raises(RuntimeError, match="device lost"):
        _run_chunks([Failing("a", [], 5, groups=2)], None)


@pytest.mark.parametrize(("platform", "most_at_once"), [("cpu", 1), ("gpu", 3)])
def test_programs_compile_side_by_side_on_accelerators_only(platform, most_at_once):
    """`_prepare_all`: on CPUs one compile at a time, in order (they share the cores with the runs);
    on accelerators all side by side (`COMPILES_SIDE_BY_SIDE`)."""
    import threading

    from jaxeac.running.batch import _prepare_all

    log, active, most = [], [0], [0]
    lock = threading.Lock()

    def make(i):
        with lock:
            active[0] += 1
            most[0] = max(most[0], active[0])
        time.sleep(0.3)
        with lock:
            active[0] -= 1
        return _LoggedJob("abc"[i], log, 1)

    jobs = _prepare_all(make, 3, None, platform)
    assert [j.name for j in jobs] == ["a", "b", "c"] and most[0] == most_at_once
    assert sorted(log) == ["collect a0", "collect b0", "collect c0",
                           "dispatch a0", "dispatch b0", "dispatch c0"]


def _iterations_until_done(env, cfg, n_seeds=16):
    """Run the flat loop one chance per call with a lane per seed; (lane iterations until each
    seed was done, final agents)."""
    from jaxeac.rng import seed_words
    from jaxeac.running.loops import flat_init, flat_slot

    cfg = cfg.resolve(env, n_seeds)
    words = jax.vmap(lambda i: seed_words(seed_key(jax.random.key(2), i)))(np.arange(n_seeds))
    hyper = jax.tree.map(lambda x: np.broadcast_to(x, (n_seeds,)), cfg.hyper())
    step = jax.jit(jax.vmap(lambda c, w, h: flat_slot(env, cfg, c, w, h)))
    run = jax.vmap(lambda w: flat_init(env, cfg, w))(words)
    iterations = 0
    while (live := int((run.agent.trial < cfg.trials).sum())):
        run, iterations = step(run, words, hyper), iterations + live
    return iterations, run.agent


@pytest.mark.parametrize(("algo", "variant", "chances", "at_most"), [
    ("eac", {}, 40, 0.6),  # paper: E6 compares with trial t−1's r̃ along its skipped path
    ("eac", {}, 9, 0.95),  # short trials: jumps onto paths longer than the chances left fail (G5)
    ("eac", {"failure_rule": "within_trial"}, 40, 0.6),
    ("eac_success_only", {}, 40, 0.6),
])
def test_memory_jumps_skip_steps_and_keep_every_result(algo, variant, chances, at_most):
    """A trial on a state whose success-memory path has a known length ends at once: far fewer
    iterations, and the same trial log (successes and chances used) and policy as taking every
    step, as the literal trials loop does."""
    from jaxeac.algorithm.agent import greedy_policy

    env = GridWorld(get_map("paper"), chances)
    agent = algorithm(algo, **variant)
    runs = {jump: _iterations_until_done(env, RunConfig(trials=120, agent=agent, jump=jump))
            for jump in ("off", "on")}
    (slow, every), (fast, jumped) = runs["off"], runs["on"]
    assert fast < at_most * slow, (fast, slow)
    np.testing.assert_array_equal(jumped.log, every.log)
    cfg = RunConfig(trials=120, agent=agent).resolve(env)
    policy = jax.vmap(lambda a: greedy_policy(cfg.agent, a))
    np.testing.assert_array_equal(policy(jumped), policy(every))
    literal = run_seeds(env, RunConfig(trials=120, agent=agent, loop="trials"), root_key=2, n_seeds=16)
    np.testing.assert_array_equal(np.abs(np.asarray(jumped.log)), literal.steps)
    if chances == 9:
        assert (np.asarray(every.log) < 0).any()  # failures happen, jumps among them


def test_memory_jumps_resolve_where_exact_only():
    """`auto` jumps for a deterministic world with a success memory and no learning on memory
    steps, in the flat loop (XLA ops or the fused kernel); `on` elsewhere is refused, naming why."""
    env = GridWorld(get_map("paper"), 40)

    def resolved(algo, **kw):
        return RunConfig(trials=10, agent=algorithm(algo), **kw).resolve(env, 64, "cpu").jump

    assert resolved("eac") == "on" and resolved("eac_success_only") == "on"
    assert resolved("ac") == "off" and resolved("eac_failure_only") == "off"
    assert resolved("eac_learn_on_memory") == "off" and resolved("eac", loop="trials") == "off"
    assert resolved("eac", jump="off") == "off"
    assert RunConfig(trials=10, agent=algorithm("eac")).resolve(None, 64, "cpu").jump == "off"  # bowling
    with pytest.raises(UsageError, match="deterministic environment"):
        RunConfig(trials=10, agent=algorithm("eac"), jump="on").resolve(None, 64, "cpu")
    with pytest.raises(UsageError, match="learn_on_memory_steps"):
        RunConfig(trials=10, agent=algorithm("eac_learn_on_memory"), jump="on").resolve(env, 64, "cpu")
    with pytest.raises(UsageError, match="unknown jump setting"):
        RunConfig(trials=10, agent=algorithm("eac"), jump="sometimes")


def test_memory_jumps_with_the_three_word_dense_memory(monkeypatch):
    """Where one word per state cannot hold both memories (many trials), the three-word dense
    layout runs; its pending success action is the path action too, so jumps stay exact."""
    import jaxeac.algorithm.memory as mem

    monkeypatch.setattr(mem, "packed_fits", lambda n_actions, n_trials: False)
    agent = algorithm("eac")
    assert isinstance(mem.init_memory("dense", 4, 4, 8, 10), mem.DenseMemory)
    runs = [run_seeds(ENV, RunConfig(trials=80, agent=agent, loop=loop, jump=jump), root_key=4, n_seeds=24)
            for loop, jump in (("flat", "on"), ("trials", "auto"))]
    for field in ("success", "steps", "policy"):
        np.testing.assert_array_equal(getattr(runs[0], field), getattr(runs[1], field))


@pytest.mark.parametrize("algo", ["eac", "eac_failure_only", "ac"])
def test_tail_on_fewer_lanes_keeps_every_result(algo, monkeypatch):
    """The flat loop's tail phase (the last seeds moved to 1/16 of the lanes) changes no result,
    with a queue (lanes < seeds) and without one (a lane per seed, memories only)."""
    from jaxeac.running import loops

    env = GridWorld(parse_map("....\n.#..\n...G\n"), 12)
    cfg = RunConfig(trials=25, agent=algorithm(algo), lanes=64)
    plain = run_seeds(env, cfg, root_key=2, n_seeds=80)
    monkeypatch.setattr(loops, "TAIL_MIN_LANES", 2)
    assert loops.tail_lanes(64, "xla") == [4] and loops.tail_lanes(4000, "pallas") == [128]
    for lanes in (64, 80):
        fresh = GridWorld(env.map, 12)  # programs are cached per env object: compile anew
        tail = run_seeds(fresh, dataclasses.replace(cfg, lanes=lanes), root_key=2, n_seeds=80)
        np.testing.assert_array_equal(tail.success, plain.success)
        np.testing.assert_array_equal(tail.steps, plain.steps)
        np.testing.assert_array_equal(tail.policy, plain.policy)


@pytest.mark.parametrize("algo", ["ac", "eac"])
def test_queue_blocks_update_lanes_in_place(algo):
    """A queue-fed chunk's compiled program copies no lane's tables, memory or trial log: each
    block's writes into the lanes depend on its reads of the finished lanes (`loops._read`), so
    XLA updates the lanes in place (BENCHMARKS.md, *Queue blocks that update their lanes in
    place*). Without that dependency the program copied them twice a block. (With 8 lanes or
    fewer, one finished lane a block, XLA fuses its log read into the write of the results and
    keeps one copy of the log: not tested.)"""
    import re

    from jaxeac.algorithm.config import algorithm
    from jaxeac.envs.grid import GridWorld, get_map
    from jaxeac.running.batch import make_batch_run

    env = GridWorld(get_map("paper"), 40)
    lanes, m = 16, 64
    cfg = RunConfig(trials=20, agent=algorithm(algo), lanes=lanes).resolve(env, m)
    hyper = jax.tree.map(lambda x: np.broadcast_to(np.asarray(x), (m,)), cfg.hyper())
    program = make_batch_run(env, cfg).lower(jax.random.key(0), np.arange(m, dtype=np.int32), hyper, {})
    text = program.compile().as_text()
    per_lane = {f"[{lanes},{env.n_states},{env.n_actions}]", f"[{lanes},{env.n_states}]",
                f"[{lanes},{cfg.trials}]"}
    loops = [c for c in re.split(r"\n(?=\S)", text) if not c.startswith("ENTRY")]  # not the one-off start
    copied = {shape for c in loops for shape in re.findall(r"= \w+(\[[\d,]+\])\{[\d,]*\} copy\(", c)}
    assert "while(" in text and not copied & per_lane, sorted(copied)


@pytest.mark.parametrize("once_dispatched", [False, True])
def test_diagnostics_beside_the_run_give_the_same_folder(monkeypatch, tmp_path, once_dispatched):
    """E8's counts computed beside the run, from its start or once every chunk is handed out
    (`DIAGNOSE_ONCE_DISPATCHED`), are those computed after it; summary.json's timeline is in order."""
    from jaxeac.experiments import grid
    from jaxeac.experiments.grid import GridSettings, run_grid_to_folder

    settings = GridSettings(seeds=9, trials=20, key=1, algos=("ac", "eac"), chunk_size=4).resolved()
    _, after = run_grid_to_folder(settings, tmp_path / "after", figures=False)
    backend = jax.default_backend()
    monkeypatch.setattr(grid, "DIAGNOSE_BESIDE_THE_RUN", {backend: True})
    monkeypatch.setattr(grid, "DIAGNOSE_ONCE_DISPATCHED", {backend: once_dispatched})
    _, beside = run_grid_to_folder(settings, tmp_path / "beside", figures=False)
    assert beside["memory_diagnostics"] == after["memory_diagnostics"]
    files = [(tmp_path / d / "results.parquet").read_bytes() for d in ("beside", "after")]
    assert files[0] == files[1]
    tl = beside["timeline"]
    assert tl["started"] <= tl["results"] <= tl["figures"] <= tl["diagnosed"]
