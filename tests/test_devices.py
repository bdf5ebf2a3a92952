"""Seeds split over several devices give bit-identical results (SPEC R1), incl. uneven counts.

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
    from envs.grid import GridWorld, get_map
    from jaxeac.agent import algorithm
    from jaxeac.runner import RunConfig, run_seeds
    assert len(jax.devices()) == 2, jax.devices()
    env = GridWorld(get_map("paper"), 40)
    for algo, loop in [("ac", "flat"), ("eac", "flat"), ("eac", "trials")]:
        cfg = RunConfig(trials=30, agent=algorithm(algo), loop=loop)
        one = run_seeds(env, cfg, root_key=1, n_seeds=7, chunk_size=3, devices=jax.devices()[:1])
        for chunk in (3, 4, 7):  # 7 seeds on 2 devices: padded chunks of 4, 4 and 8
            two = run_seeds(env, cfg, root_key=1, n_seeds=7, chunk_size=chunk)
            for field in ("success", "steps", "policy"):
                np.testing.assert_array_equal(getattr(one, field), getattr(two, field))
        assert len(two.seeds) == 7 and two.success.shape[0] == 7
    print("identical on 1 and 2 devices")
""")


def test_one_and_two_devices_bit_identical():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env,
                          cwd=root, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "identical on 1 and 2 devices" in proc.stdout
