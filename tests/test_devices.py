"""Seeds split over several devices give bit-identical results (SPEC R1), incl. uneven counts,
with XLA ops and with the fused kernel (run by Pallas's interpreter).

Runs in a subprocess with two virtual CPU devices
(``XLA_FLAGS=--xla_force_host_platform_device_count=2``), since the device count is
fixed when JAX starts.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

SCRIPT = textwrap.dedent("""
    import jax, numpy as np
    from jaxeac.envs.grid import GridWorld, get_map
    from jaxeac.algorithm.config import algorithm
    from jaxeac.running.batch import run_seeds
    from jaxeac.running.config import RunConfig
    assert len(jax.devices()) == 2, jax.devices()
    env = GridWorld(get_map("paper"), 40)
    configs = [RunConfig(trials=30, agent=algorithm(algo), loop=loop)
               for algo, loop in [("ac", "flat"), ("eac", "flat"), ("eac", "trials")]]
    configs.append(RunConfig(trials=30, agent=algorithm("eac", tables="rows"), kernel="pallas"))
    for cfg in configs:
        one = run_seeds(env, cfg, root_key=1, n_seeds=7, chunk_size=3, devices=jax.devices()[:1])
        for chunk in (3, 4, 7):  # 7 seeds on 2 devices: padded chunks of 4, 4 and 8
            two = run_seeds(env, cfg, root_key=1, n_seeds=7, chunk_size=chunk)
            for field in ("success", "steps", "policy"):
                np.testing.assert_array_equal(getattr(one, field), getattr(two, field))
        assert len(two.seeds) == 7 and two.success.shape[0] == 7
    # the fused kernel (Pallas's interpreter here) with a queue: 150 seeds per device on 128 lanes
    cfg = RunConfig(trials=15, agent=algorithm("eac", tables="rows"), kernel="pallas", lanes=128)
    one = run_seeds(env, cfg, root_key=2, n_seeds=300, chunk_size=300, devices=jax.devices()[:1])
    two = run_seeds(env, cfg, root_key=2, n_seeds=300, chunk_size=300)
    for field in ("success", "steps", "policy"):
        np.testing.assert_array_equal(getattr(one, field), getattr(two, field))
    print("identical on 1 and 2 devices")
""")


def _on_cpu_devices(script: str, devices: int, timeout: int) -> str:
    """`script` in a fresh interpreter with `devices` virtual CPU devices; its stdout."""
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}", JAX_PLATFORMS="cpu")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env,
                          cwd=Path(__file__).resolve().parents[1], timeout=timeout)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_one_and_two_devices_bit_identical():
    assert "identical on 1 and 2 devices" in _on_cpu_devices(SCRIPT, 2, timeout=600)


def test_processes_write_parts_and_merge_to_the_single_run(tmp_path, capsys):
    """Multi-host layout: each process writes only its seeds; the merge equals one process's run."""
    import shutil

    from jaxeac.cli import main

    small = ["--seeds", "7", "--trials", "12", "--chances", "15", "--quiet"]
    for i in range(3):
        assert main(["grid", *small, "--num-processes", "3", "--process-id", str(i),
                     "--out", str(tmp_path / "multi")]) == 0
    parts = sorted(p.name for p in (tmp_path / "multi").iterdir())
    assert parts == ["part-0000-of-0003", "part-0001-of-0003", "part-0002-of-0003"]
    rows = [(tmp_path / "multi" / p / "per_seed.csv").read_text().splitlines()[1:] for p in parts]
    assert [len(r) for r in rows] == [4, 4, 6]  # 2 algorithms × seeds {0,1}, {2,3}, {4,5,6}
    assert main(["merge", str(tmp_path / "multi"), "--no-compare", "--quiet"]) == 0
    assert main(["grid", *small, "--no-compare", "--out", str(tmp_path / "single")]) == 0
    merged, single = tmp_path / "multi", tmp_path / "single"
    assert (merged / "per_seed.csv").read_text() == (single / "per_seed.csv").read_text()
    import pyarrow.parquet as pq

    assert pq.read_table(merged / "results.parquet").equals(pq.read_table(single / "results.parquet"))
    # a missing part is refused with a clear message
    shutil.rmtree(merged / "part-0001-of-0003")
    capsys.readouterr()
    assert main(["merge", str(merged), "--no-compare"]) == 2
    assert "part-0001-of-0003" in capsys.readouterr().err


APART = textwrap.dedent("""
    import jax, numpy as np
    from jaxeac.envs.grid import GridWorld, get_map
    from jaxeac.algorithm.config import algorithm
    from jaxeac.running import batch
    from jaxeac.running.batch import run_seeds
    from jaxeac.running.config import RunConfig
    from jaxeac.running.outputs import CompactCollector
    assert len(jax.devices()) == 3, jax.devices()
    batch.DEVICES_APART["cpu"] = True  # a program per device, as on GPUs
    env = GridWorld(get_map("paper"), 40)
    configs = [RunConfig(trials=30, agent=algorithm(algo), loop=loop)
               for algo, loop in [("ac", "flat"), ("eac", "flat"), ("eac", "trials")]]
    configs.append(RunConfig(trials=15, agent=algorithm("eac", tables="rows"), kernel="pallas", lanes=128))
    for i, cfg in enumerate(configs):
        one = run_seeds(env, cfg, root_key=1, n_seeds=40, chunk_size=40, devices=jax.devices()[:1])
        # chunks of 1, 3 and 14 seeds per device, the last ones padded; every loop at chunks of 3
        for chunk in (3, 7, 40) if i == 0 else (7,):
            for again in (False, True):  # the first run: devices join as their programs come in
                with batch.record_timeline() as events:
                    three = run_seeds(env, cfg, root_key=1, n_seeds=40, chunk_size=chunk)
                for field in ("success", "steps", "policy", "finite"):
                    np.testing.assert_array_equal(getattr(one, field), getattr(three, field))
            ran = [e for e in events if e["event"] == "chunk"]
            assert chunk == 40 or len({e["group"] for e in ran}) > 1, ran  # each device takes chunks
            assert sorted(e["start"] for e in ran) == [e["start"] for e in ran]  # collected in seed order
            assert all(e["dispatch"] <= e["ready"] <= e["fetched"] <= e["collect"] for e in ran)
            assert three.settings["devices"] == 3
    # a streamed run: every chunk reaches the writer once, in seed order
    seen = []
    collector = CompactCollector(np.arange(40), 30, env.n_states,
                                 on_chunk=lambda start, chunk, m: seen.append(start))
    compact = run_seeds(env, configs[1], root_key=1, n_seeds=40, chunk_size=6, collector=collector)
    assert seen == list(range(0, 40, 2)), seen  # chunks of 6: 2 seeds a device
    np.testing.assert_array_equal(compact.successes, one_eac := run_seeds(
        env, configs[1], root_key=1, n_seeds=40, devices=jax.devices()[:1]).successes)
    # measured on each device (`device_measures`): the same bits and measures
    measured = run_seeds(env, configs[1], root_key=1, n_seeds=40, chunk_size=6, collector=CompactCollector(
        np.arange(40), 30, env.n_states, whole_chunks=False))
    for field in ("successes", "first_success", "steps_total", "finite", "first_policies", "first_logs"):
        np.testing.assert_array_equal(getattr(measured, field), getattr(compact, field))
    np.testing.assert_array_equal(measured.success.bits, compact.success.bits)
    # one compile per device, side by side without a persistent cache
    assert batch._persistent_cache_shared("cpu") is False
    print("identical on 1 and 3 devices apart")
""")


def test_devices_apart_bit_identical():
    """A program per device, each taking chunks from the shared queue (`DEVICES_APART`, the GPU
    path), on three virtual CPU devices: the same per-seed results as one device (R1), devices
    sharing the chunks, collected in seed order."""
    assert "identical on 1 and 3 devices apart" in _on_cpu_devices(APART, 3, timeout=900)
