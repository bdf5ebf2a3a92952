"""`jaxeac.running.helper`: jobs in a process of its own (JAX on the CPU, one host device)."""

from __future__ import annotations

import os
import signal
import time

import pytest

from jaxeac.running.helper import Helper, HelperError, helper_environment


def _jax_as_seen() -> tuple:
    import jax

    return jax.default_backend(), len(jax.devices()), os.getpid(), os.getpriority(os.PRIO_PROCESS, 0)


def _sleep_then(seconds: float, value):
    time.sleep(seconds)
    return value


def _unpicklable():
    return lambda: None


@pytest.fixture(scope="module")
def helper():
    with Helper() as h:
        yield h


def test_a_job_runs_in_another_process_with_jax_on_one_cpu_device_at_a_lower_priority(helper):
    backend, devices, pid, nice = helper.submit(_jax_as_seen).result(timeout=60)
    assert (backend, devices) == ("cpu", 1)
    assert pid != os.getpid()
    assert nice >= os.getpriority(os.PRIO_PROCESS, 0) + 1


def test_jobs_run_side_by_side_and_keep_their_own_results(helper):
    t0 = time.perf_counter()
    futures = [helper.submit(_sleep_then, 0.5, i) for i in range(4)]
    assert [f.result(timeout=30) for f in futures] == [0, 1, 2, 3]
    assert time.perf_counter() - t0 < 1.5  # four half-second jobs at once, not one after another
    assert helper.submit(divmod, 7, b=2).exception(timeout=30) is not None  # divmod takes no keywords
    assert helper.submit(divmod, 7, 2).result(timeout=30) == (3, 1)


def test_a_jobs_error_comes_back_as_itself(helper):
    with pytest.raises(ValueError, match="invalid literal for int"):
        helper.submit(int, "x").result(timeout=30)


def test_a_result_that_cannot_come_back_is_an_error_naming_it(helper):
    with pytest.raises(HelperError, match="result of _unpicklable cannot come back"):
        helper.submit(_unpicklable).result(timeout=30)
    assert helper.submit(abs, -3).result(timeout=30) == 3  # the helper goes on


def test_the_environment_keeps_the_users_xla_flags_but_one_host_device():
    env = helper_environment({"XLA_FLAGS": "--xla_force_host_platform_device_count=16 --xla_cpu_foo=1"})
    assert env == {"JAX_PLATFORMS": "cpu", "XLA_FLAGS": "--xla_cpu_foo=1 --xla_force_host_platform_device_count=1"}


def test_close_waits_for_the_jobs_and_reports_the_helpers_peak_memory():
    h = Helper()
    late = h.submit(_sleep_then, 0.3, "done")
    h.close()
    assert late.result(timeout=0) == "done"
    assert 10 * 2**20 < h.peak_rss_bytes < 8 * 2**30
    with pytest.raises(HelperError, match="has ended"):
        h.submit(abs, 1)


def test_a_helper_that_dies_fails_its_jobs_and_one_killed_leaves_no_process():
    h = Helper()
    pid = h.submit(os.getpid).result(timeout=30)
    stuck = h.submit(_sleep_then, 60, None)
    os.kill(pid, signal.SIGKILL)
    with pytest.raises(HelperError, match="ended before this job finished"):
        stuck.result(timeout=30)
    with pytest.raises(HelperError, match="has ended"):
        h.submit(abs, 1)
    h.kill()
    assert h.peak_rss_bytes is None

    h = Helper()
    pid = h.submit(os.getpid).result(timeout=30)
    stuck = h.submit(_sleep_then, 60, None)
    h.kill()
    with pytest.raises(HelperError):
        stuck.result(timeout=30)
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)


def test_the_helper_ignores_ctrl_c_its_parent_handles():
    with Helper() as h:
        pid = h.submit(os.getpid).result(timeout=30)
        os.kill(pid, signal.SIGINT)
        assert h.submit(_sleep_then, 0.2, "alive").result(timeout=30) == "alive"
