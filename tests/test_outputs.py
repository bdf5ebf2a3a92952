"""Run-folder outputs that scale: the results.parquet round trip, old folders, bad files, auto options."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from jaxeac.errors import UsageError
from jaxeac.results import (
    CSV_SEEDS,
    FULL_OUTPUT_SEEDS,
    RESULTS_FILE,
    OutputOptions,
    load_grid_results,
    unpack_success,
    write_grid_results,
)
from jaxeac.running.outputs import CompactSeeds, SeedsResult, SuccessBits, as_bool
from jaxeac.stats import cumulative
from jaxeac.stats.cumulative import count_percentile, cumulative_counts


def fake_results(rng, n, trials=13, states=7, algos=("ac", "eac")):
    out = {}
    for algo in algos:
        success = rng.random((n, trials)) < 0.4
        steps = rng.integers(1, 40, (n, trials)).astype(np.int32)
        policy = rng.integers(0, 4, (n, states)).astype(np.int32)
        out[algo] = SeedsResult(np.arange(n, dtype=np.int64), success, steps, policy, 0.0, 0.0)
    return out


@pytest.mark.parametrize("trials", [1, 8, 13, 200])
def test_round_trip_is_exact(tmp_path, rng, trials, monkeypatch):
    import jaxeac.results as results

    monkeypatch.setattr(results, "ROW_GROUP", 5)  # several row groups, one short
    res = fake_results(rng, 23, trials=trials)
    write_grid_results(tmp_path / RESULTS_FILE, res, trials, 7, OutputOptions())
    back = load_grid_results(tmp_path, ("ac", "eac"), trials)
    for algo, r in res.items():
        b = back[algo]
        np.testing.assert_array_equal(b.seeds, r.seeds)
        np.testing.assert_array_equal(b.success, r.success)
        np.testing.assert_array_equal(b.trial_steps, r.steps)
        np.testing.assert_array_equal(b.policy, r.policy)
        np.testing.assert_array_equal(b.successes, r.success.sum(1))
        np.testing.assert_array_equal(b.steps_total, r.steps.sum(1))
        first = np.where(r.success.any(1), r.success.argmax(1) + 1, -1)
        np.testing.assert_array_equal(b.first_success, first)
    assert pq.ParquetFile(tmp_path / RESULTS_FILE).metadata.num_row_groups == 10  # 5 + short, per algo
    compact = load_grid_results(tmp_path, ("ac", "eac"), trials, compact=True)  # what compare reads
    for algo, r in res.items():
        bits = compact[algo].success
        assert isinstance(bits, SuccessBits) and compact[algo].trial_steps is None
        np.testing.assert_array_equal(bits.unpack(), r.success)
        np.testing.assert_array_equal(compact[algo].successes, back[algo].successes)


@pytest.mark.parametrize("trials", [1, 7, 8, 9, 200])
def test_success_bits_match_the_bool_matrix(rng, trials, monkeypatch):
    """`SuccessBits`: rows, blocks, columns, column sums and the per-seed measures as from bools."""
    import jaxeac.stats.measures as measures

    success = rng.random((37, trials)) < rng.random((37, 1))
    bits = SuccessBits.pack(success)
    assert bits.shape == success.shape and bits.bits.shape == (37, -(-trials // 8))
    np.testing.assert_array_equal(bits.unpack(), success)
    np.testing.assert_array_equal(bits.rows(5, 11), success[5:11])
    monkeypatch.setattr(SuccessBits, "BLOCK", 10)
    assert [start for start, _ in bits.blocks()] == [0, 10, 20, 30]
    np.testing.assert_array_equal(np.concatenate([b for _, b in bits.blocks()]), success)
    for t in {0, trials // 2, trials - 1}:
        np.testing.assert_array_equal(bits.column(t), success[:, t])
    np.testing.assert_array_equal(bits.column_sums(), success.sum(0))
    np.testing.assert_array_equal(as_bool(bits), success)
    monkeypatch.setattr(measures, "_BLOCK", 6)  # several blocks on threads, one short
    from_bits = measures.per_seed_measures(bits)
    from_bools = measures.per_seed_measures(success)
    assert from_bits.keys() == from_bools.keys()
    for name in from_bits:
        np.testing.assert_array_equal(from_bits[name], from_bools[name])
    np.testing.assert_array_equal(from_bits["successes"], success.sum(1))
    np.testing.assert_array_equal(cumulative_counts(bits, chunk=8), cumulative_counts(success))


def test_streamed_run_folder_equals_the_in_memory_one(tmp_path, monkeypatch):
    """`run_grid_to_folder` (results written a chunk at a time, `CompactSeeds` kept) writes the
    same results.parquet, per_seed.csv and summary figures as `run_grid` + `write_grid_outputs`."""
    import jaxeac.results as results
    from jaxeac.experiments.grid import GridSettings, run_grid, run_grid_to_folder, write_grid_outputs

    monkeypatch.setattr(results, "ROW_GROUP", 4)
    settings = GridSettings(seeds=11, trials=9, chances=12, chunk_size=4).resolved()
    whole = run_grid(settings)
    write_grid_outputs(whole, tmp_path / "memory", figures=False)
    streamed, summary = run_grid_to_folder(settings, tmp_path / "streamed", figures=False)
    assert pq.read_table(tmp_path / "memory" / RESULTS_FILE).equals(
        pq.read_table(tmp_path / "streamed" / RESULTS_FILE))
    csv = [(tmp_path / name / "per_seed.csv").read_text() for name in ("memory", "streamed")]
    assert csv[0] == csv[1]
    memory = json.loads((tmp_path / "memory" / "summary.json").read_text())
    for algo in ("ac", "eac"):
        assert isinstance(streamed.results[algo], CompactSeeds)
        for field in ("mean_successes", "sd_successes", "ci95_successes", "agent_steps", "mean_steps"):
            assert summary["per_algo"][algo][field] == memory["per_algo"][algo][field]
        np.testing.assert_array_equal(streamed.results[algo].policy_of(3), whole.results[algo].policy[3])
    assert summary["eac_minus_ac"] == memory["eac_minus_ac"]


def test_chunks_behind_keep_their_order_and_report_a_failed_write():
    """`ChunksBehind`: calls on one thread of their own, in the order handed over (across the
    algorithms that share it), each chunk keeping only the parts asked for; `finish` raises a
    failed call's error, and a later hand-over stops at it."""
    import threading
    import time

    from jaxeac.running.outputs import BatchOutput, ChunksBehind

    seen, threads = [], set()

    def writer(name):
        def on_chunk(start, chunk, measures):
            time.sleep(0.002 * ((start + 1) % 3))
            threads.add(threading.current_thread().name)
            seen.append((name, start, chunk.log is None, chunk.policy is None, int(measures["bits"].sum())))
        return on_chunk

    chunk = BatchOutput(np.ones((2, 3), np.int8), np.zeros((2, 4), np.int8))
    with ChunksBehind(keep_log=False, keep_policy=True) as behind:
        calls = {name: behind.of(writer(name)) for name in ("ac", "eac")}
        order = [("ac", s) for s in range(5)] + [("eac", s) for s in range(5)]
        for name, start in order:
            calls[name](start, chunk, {"bits": np.full(2, start)})
        behind.finish()
    assert [(n, s) for n, s, *_ in seen] == order
    assert all(no_log and not no_policy for _, _, no_log, no_policy, _ in seen)
    assert threads == {t for t in threads if t.startswith("jaxeac-writer")} and len(threads) == 1

    def failing(start, chunk, measures):
        raise OSError("disk full")

    with ChunksBehind(keep_log=True, keep_policy=True) as behind:
        call = behind.of(failing)
        call(0, chunk, {"bits": np.zeros(2)})
        time.sleep(0.05)
        with pytest.raises(OSError, match="disk full"):
            call(2, chunk, {"bits": np.zeros(2)})
        with pytest.raises(OSError, match="disk full"):
            behind.finish()


def test_streamed_run_folder_appears_once_its_file_is_written(tmp_path, monkeypatch):
    """results.parquet is written behind the run; the folder appears with the whole file, and a
    write that fails leaves no folder."""
    import jaxeac.results as results
    from jaxeac.experiments.grid import GridSettings, run_grid_to_folder

    settings = GridSettings(seeds=9, trials=9, chances=12, chunk_size=3).resolved()
    monkeypatch.setattr(results, "ROW_GROUP", 2)
    writes = []
    original = results.ResultsWriter.write

    def slow_write(self, algo, seeds, *a, **kw):
        import time

        time.sleep(0.02)
        writes.append((algo, int(seeds[0])))
        return original(self, algo, seeds, *a, **kw)

    monkeypatch.setattr(results.ResultsWriter, "write", slow_write)
    run_grid_to_folder(settings, tmp_path / "ok", figures=False)
    assert writes == sorted(writes) and {a for a, _ in writes} == {"ac", "eac"} and len(writes) > 2, writes
    table = pq.read_table(tmp_path / "ok" / RESULTS_FILE)
    assert table.column("seed").to_pylist() == list(range(9)) * 2

    def failing(self, *a, **kw):
        raise OSError("disk full")

    monkeypatch.setattr(results.ResultsWriter, "write", failing)
    with pytest.raises(OSError, match="disk full"):
        run_grid_to_folder(settings, tmp_path / "failed", figures=False)
    assert not (tmp_path / "failed" / RESULTS_FILE).exists()


@pytest.mark.parametrize("dtype", [np.int8, np.int16, np.int32, np.int64, np.uint8, bool])
def test_arrow_arrays_built_on_numpy_buffers_equal_pyarrows_own(rng, dtype):
    """The writer builds its columns on the arrays' buffers (`_from_numpy`, `_strings`; pyarrow's
    own constructor imports pandas first): the same Arrow arrays, sliced views and odd lengths too."""
    import pyarrow as pa

    from jaxeac.results import _from_numpy, _strings

    values = rng.integers(-100, 100, size=37).astype(dtype)
    for view in (values, values[3:], values[::2], values[:0]):
        got = _from_numpy(pa, view)
        assert got.type == pa.from_numpy_dtype(view.dtype) and got.equals(pa.array(view))
    for items in (["ac"], ["ac", "eac", "", "ε-greedy"], []):
        assert _strings(pa, items).equals(pa.array(items, pa.string()))


def test_success_bits_by_hand(tmp_path):
    success = np.zeros((2, 10), bool)
    success[0, [0, 9]] = True  # bit 0 of byte 0 and bit 1 of byte 1
    success[1, 3] = True
    steps, policy = np.ones((2, 10), np.int32), np.zeros((2, 3), np.int32)
    res = {"ac": SeedsResult(np.arange(2), success, steps, policy, 0, 0)}
    write_grid_results(tmp_path / RESULTS_FILE, res, 10, 3, OutputOptions(False, False, False))
    table = pq.read_table(tmp_path / RESULTS_FILE)
    assert table.column("success_bits").to_pylist() == [b"\x01\x02", b"\x08\x00"]
    assert "policy" not in table.column_names and "trial_steps" not in table.column_names
    np.testing.assert_array_equal(unpack_success(table.column("success_bits"), 10), success)
    back = load_grid_results(tmp_path, ("ac",), 10)["ac"]
    assert back.policy is None and back.trial_steps is None


def test_auto_options_by_seed_count():
    assert OutputOptions.auto(FULL_OUTPUT_SEEDS) == OutputOptions(True, True, FULL_OUTPUT_SEEDS <= CSV_SEEDS)
    big = OutputOptions.auto(10 * max(FULL_OUTPUT_SEEDS, CSV_SEEDS))
    assert big == OutputOptions(False, False, False)
    assert OutputOptions.auto(10**7, full=True, csv=True) == OutputOptions(True, True, True)


def test_old_run_folders_still_load(tmp_path, rng):
    res = fake_results(rng, 6)
    np.savez(tmp_path / "curves.npz", **{a: r.success for a, r in res.items()},
             **{f"{a}_steps": r.steps.astype(np.int16) for a, r in res.items()})
    np.savez(tmp_path / "policies.npz", seeds=np.arange(6),
             **{a: r.policy.astype(np.int8) for a, r in res.items()})
    back = load_grid_results(tmp_path, ("ac", "eac"), 13)
    np.testing.assert_array_equal(back["eac"].success, res["eac"].success)
    np.testing.assert_array_equal(back["ac"].policy, res["ac"].policy)


def test_compare_reads_the_new_format(tmp_path, capsys):
    from jaxeac.cli import main

    out = tmp_path / "run"
    assert main(["grid", "--seeds", "6", "--trials", "8", "--chances", "12", "--quiet", "--out", str(out),
                 "--no-compare"]) == 0
    assert (out / RESULTS_FILE).is_file() and not (out / "curves.npz").exists()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outputs"] == {"trial_steps": True, "policies": True, "per_seed_csv": True}
    assert summary["per_algo"]["eac"]["run"]["chunk_size"] == 6  # auto, resolved and recorded
    assert summary["per_algo"]["eac"]["run"]["loop"] == "flat"
    assert main(["compare", str(out), "--resamples", "200"]) == 0
    stats = json.loads((out / "stats.json").read_text())["primary"]
    table = pq.read_table(out / RESULTS_FILE).to_pandas()
    assert stats["n_baseline"] == stats["n_treatment"] == 6
    assert stats["mean_treatment"] == pytest.approx(table[table.algo == "eac"].successes.mean())


@pytest.mark.parametrize("damage", ["truncate", "garbage", "drop_column", "no_rows"])
def test_damaged_results_file_is_one_clear_error(tmp_path, rng, damage):
    path = tmp_path / RESULTS_FILE
    write_grid_results(path, fake_results(rng, 9), 13, 7, OutputOptions())
    if damage == "truncate":
        path.write_bytes(path.read_bytes()[:200])
    elif damage == "garbage":
        path.write_bytes(b"PAR1" + bytes(range(256)) * 4)
    elif damage == "drop_column":
        pq.write_table(pq.read_table(path).drop_columns(["success_bits"]), path)
    algos = ("ac", "nope") if damage == "no_rows" else ("ac", "eac")
    with pytest.raises(UsageError, match=str(path)):
        load_grid_results(tmp_path, algos, 13)


def test_missing_results_names_the_fix(tmp_path):
    with pytest.raises(UsageError, match="neither results.parquet nor curves.npz"):
        load_grid_results(tmp_path, ("ac",), 5)


def test_figure_band_from_counts_matches_numpy(rng):
    for n in (1, 2, 9, 500):
        success = rng.random((n, 17)) < 0.3
        cum = np.cumsum(success, axis=1)
        counts = cumulative_counts(success, chunk=4)
        assert counts.shape == (17, 18) and (counts.sum(1) == n).all()
        for q in (5, 50, 95):
            np.testing.assert_allclose(count_percentile(counts, q), np.percentile(cum, q, axis=0), atol=1e-12)


@pytest.mark.parametrize("direct_cells", [0, 1 << 20])  # the packed bytes' path, and the direct one
def test_cumulative_counts_from_bytes_match_the_literal_count(rng, monkeypatch, direct_cells):
    """The figure's counts come from the packed bits a byte at a time (or, for few seeds, one
    histogram of running counts); each must equal the literal count of seeds per cumulative
    value, trial by trial (T not a multiple of 8, T > 255, all failures, all successes, blocks
    of one seed)."""
    monkeypatch.setattr(cumulative, "DIRECT_CELLS", direct_cells)
    for n, t, p in [(1, 1, 0.5), (9, 7, 0.5), (40, 8, 0.3), (33, 17, 0.9), (25, 300, 0.6),
                    (6, 9, 0.0), (6, 9, 1.0)]:
        success = rng.random((n, t)) < p
        cum = np.cumsum(success, axis=1)
        literal = np.array([[(cum[:, i] == v).sum() for v in range(t + 1)] for i in range(t)])
        for chunk in (1, 4, 1 << 14):
            np.testing.assert_array_equal(cumulative_counts(success, chunk=chunk), literal)
        np.testing.assert_array_equal(cumulative_counts(SuccessBits.pack(success), chunk=3), literal)


def test_numerical_blow_ups_are_reported_per_seed(tmp_path, capsys):
    """A step size far too large fills p and V with inf/NaN: each such seed is flagged in the
    results, counted in summary.json and named in the printed table."""
    from jaxeac.algorithm import algorithm
    from jaxeac.envs.grid import GridWorld, get_map
    from jaxeac.experiments.grid import GridRun, GridSettings, summary_table, write_grid_outputs
    from jaxeac.running.batch import run_seeds
    from jaxeac.running.config import RunConfig

    env = GridWorld(get_map("paper"), 40)
    wild = run_seeds(env, RunConfig(trials=40, agent=algorithm("ac"), alpha=50.0, beta=50.0), root_key=0,
                     n_seeds=3)
    tame = run_seeds(env, RunConfig(trials=40, agent=algorithm("ac")), root_key=0, n_seeds=3)
    assert not wild.finite.any() and tame.finite.all()
    np.testing.assert_array_equal(wild.non_finite_seeds, [0, 1, 2])
    settings = GridSettings(seeds=3, trials=40, algos=("ac",)).resolved()
    summary = write_grid_outputs(GridRun(settings, env.map, {"ac": wild}), tmp_path / "run", figures=False)
    assert summary["per_algo"]["ac"]["non_finite_seeds"] == {"count": 3, "first": [0, 1, 2]}
    assert "warning: ac: 3 seed(s) ended with NaN or infinite p or V" in summary_table(summary)
    assert pq.read_table(tmp_path / "run" / RESULTS_FILE).column("finite").to_pylist() == [False] * 3
