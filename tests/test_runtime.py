"""The process settings (`jaxeac.runtime`): applied alike by the command line and by the
library, each leaving what the user set; each case in a fresh interpreter, since the settings
only take effect before NumPy and JAX start."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

VARIABLES = ("XLA_FLAGS", "XLA_PYTHON_CLIENT_PREALLOCATE", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
             "JAXEAC_RUNTIME")
CLEAN = {k: v for k, v in os.environ.items() if k not in VARIABLES}
SHOW = ("import json, os; print(json.dumps({k: os.environ.get(k) for k in "
        "('XLA_FLAGS', 'XLA_PYTHON_CLIENT_PREALLOCATE', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS')}))")


def _python(code: str, env: dict | None = None) -> dict:
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=CLEAN | (env or {}), timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.splitlines()[-1])


def test_import_applies_the_settings_that_precede_numpy_and_jax():
    seen = _python("import jaxeac; " + SHOW)
    flags = seen["XLA_FLAGS"].split()
    assert f"--xla_force_host_platform_device_count={len(os.sched_getaffinity(0))}" in flags
    assert "--xla_gpu_autotune_level=0" in flags and "--xla_gpu_enable_triton_gemm=false" in flags
    assert any(f.startswith("--xla_gpu_enable_command_buffer=") for f in flags)
    assert seen["XLA_PYTHON_CLIENT_PREALLOCATE"] == "false"
    assert seen["OPENBLAS_NUM_THREADS"] == seen["MKL_NUM_THREADS"] == "1"


def test_every_setting_the_user_made_is_kept():
    user = {"XLA_FLAGS": "--xla_gpu_enable_triton_gemm=true --xla_force_host_platform_device_count=3",
            "XLA_PYTHON_CLIENT_PREALLOCATE": "true", "MKL_NUM_THREADS": "4"}
    seen = _python("import jaxeac; " + SHOW, user)
    flags = seen["XLA_FLAGS"].split()
    assert flags.count("--xla_gpu_enable_triton_gemm=true") == 1 and "--xla_gpu_enable_triton_gemm=false" not in flags
    assert flags.count("--xla_force_host_platform_device_count=3") == 1
    assert seen["XLA_PYTHON_CLIENT_PREALLOCATE"] == "true"
    assert (seen["MKL_NUM_THREADS"], seen["OPENBLAS_NUM_THREADS"]) == ("4", "1")


def test_opting_out_leaves_a_library_process_alone():
    seen = _python("import jaxeac; import jaxeac.runtime as r; assert r.configure() == {}; " + SHOW,
                   {"JAXEAC_RUNTIME": "off"})
    assert seen == {k: None for k in seen}


def test_later_work_replaces_the_compile_flags_until_jax_starts():
    """`import jaxeac` chooses grid-like flags; bowling (MJX physics, slower with them) then drops
    them, as long as JAX has not been imported; once it has, XLA's flags are left alone."""
    seen = _python("import jaxeac.runtime as r; r.configure('bowling', start_jax=False); " + SHOW)
    flags = seen["XLA_FLAGS"]
    assert "autotune" not in flags and "triton_gemm" not in flags and "command_buffer" in flags
    late = _python("import jax, jaxeac.runtime as r; r.configure('bowling', start_jax=False); " + SHOW)
    assert late["XLA_FLAGS"] is None  # JAX keeps the flags it was imported with: none are set


def test_command_line_applies_them_even_when_a_library_process_would_not():
    code = ("import atexit, sys; import jaxeac.__main__ as m; sys.argv = ['jaxeac', 'bowling', '--help']; "
            "atexit.register(lambda: print(__import__('json').dumps({k: __import__('os').environ.get(k) for k in "
            "('XLA_FLAGS', 'OPENBLAS_NUM_THREADS')}))); m.run()")
    seen = _python(code, {"JAXEAC_RUNTIME": "off"})
    assert seen["OPENBLAS_NUM_THREADS"] == "1"
    assert "command_buffer" in seen["XLA_FLAGS"] and "autotune" not in seen["XLA_FLAGS"]


def test_numpy_loaded_first_gets_one_blas_thread_through_openblas():
    code = ("import numpy, jaxeac.runtime as r; out = r.configure(start_jax=False); "
            "import json; print(json.dumps({'blas': out.get('blas')}))")
    seen = _python(code)
    pytest.importorskip("numpy")
    uses_openblas = "openblas" in json.dumps(__import__("numpy").show_config(mode="dicts")).lower()
    assert seen["blas"] == (1 if uses_openblas else None)


def test_compilation_cache_in_the_folder_chosen(tmp_path):
    folder = tmp_path / "xla"
    code = ("import jaxeac.runtime as r; import jax, json; "
            "print(json.dumps({'folder': r.configure()['compilation_cache'], "
            "'jax': jax.config.jax_compilation_cache_dir}))")
    seen = _python(code, {"JAXEAC_COMPILATION_CACHE": str(folder)})
    assert seen == {"folder": str(folder), "jax": str(folder)} and folder.is_dir()
    off = _python(code.replace("'jax': jax.config.jax_compilation_cache_dir", "'jax': None"),
                  {"JAXEAC_COMPILATION_CACHE": "off"})
    assert off["folder"] is None


def test_versions_states_each_package_and_marks_missing_ones():
    from jaxeac import runtime

    found = runtime.versions(("jaxeac", "numpy", "no-such-package-xyz"), optional=("another-missing",))
    assert found["jaxeac"] == __import__("jaxeac").__version__
    assert found["numpy"] == __import__("numpy").__version__
    assert found["no_such_package_xyz"] == "unknown" and "another_missing" not in found


def test_commands_start_without_scipy_stats_and_optimize():
    """scipy.stats and scipy.optimize (about 0.6 s and 0.3 s to import) load where the statistics
    first need them, not when a command's modules are imported before its checks and runs."""
    seen = _python("import json, sys, jaxeac.cli, jaxeac.cli.run, jaxeac.experiments.grid, "
                   "jaxeac.experiments.study, jaxeac.experiments.pipeline, jaxeac.stats; "
                   "print(json.dumps(sorted(m for m in ('scipy.stats', 'scipy.optimize') if m in sys.modules)))")
    assert seen == []


def test_the_reports_closed_forms_do_not_import_scipy_stats():
    """Welch, Brunner-Munzel, power, log-rank and Wilson (every grid and study report computes
    them) take their distributions from scipy.special, so scipy.stats is never imported on the
    way: its import held the interpreter 0.6-0.8 s while a GPU report's statistics waited."""
    seen = _python(
        "import json, sys, numpy as np; from jaxeac.stats import closed_form as cf, events as ev; "
        "cf.welch_from_moments(10, 5.0, 2.0, 12, 9.0, 3.0); "
        "cf.brunner_munzel_counts(np.array([3.0, 2, 1]), np.array([1.0, 2, 3])); "
        "cf.seeds_for_power(0.5); ev.logrank_counts(np.array([1.0, 2, 0, 3]), np.array([[0.0, 1, 0, 2]])); "
        "ev.wilson_ci(3, 10); print(json.dumps('scipy.stats' in sys.modules))")
    assert seen is False


def test_malloc_arenas_are_capped_unless_the_user_set_them():
    """glibc's arenas are capped (`MALLOC_ARENAS`: threads share what they free instead of each
    keeping it); a ``MALLOC_ARENA_MAX`` the user set is left as glibc read it."""
    from jaxeac import runtime

    code = "import json, jaxeac.runtime as r; print(json.dumps(r.configure(start_jax=False)['malloc_arenas']))"
    assert _python(code) == runtime.MALLOC_ARENAS == 8
    assert _python(code, {"MALLOC_ARENA_MAX": "3"}) is None
