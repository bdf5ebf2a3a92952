"""`jaxeac.running.helper`: jobs in a process of its own (JAX on the CPU, one host device)."""

from __future__ import annotations

import os
import signal
import time

import pytest

from jaxeac.running.helper import Helper, HelperError, helper_environment, in_helper


def _jax_as_seen() -> tuple:
    import jax

    return (jax.config.jax_platforms, jax.default_backend(), len(jax.devices()), os.getpid(),
            os.getpriority(os.PRIO_PROCESS, 0))


def _sleep_then(seconds: float, value):
    time.sleep(seconds)
    return value


def _unpicklable():
    return lambda: None


def _refuse():
    raise RuntimeError("this class is read in the helper only")


class _ReadThereOnly:
    def __reduce__(self):
        return _refuse, ()


def _unreadable_here():
    return _ReadThereOnly()


@pytest.fixture(scope="module")
def helper():
    with Helper() as h:
        yield h


def test_a_job_runs_in_another_process_with_jax_on_one_cpu_device_at_a_lower_priority(helper):
    platforms, backend, devices, pid, nice = helper.submit(_jax_as_seen).result(timeout=60)
    assert (platforms, backend, devices) == ("cpu", "cpu", 1)
    assert pid != os.getpid()
    assert nice >= os.getpriority(os.PRIO_PROCESS, 0) + 1


def test_jobs_run_side_by_side_and_keep_their_own_results(helper):
    helper.submit(abs, 0).result(timeout=60)  # started
    t0 = time.perf_counter()
    futures = [helper.submit(_sleep_then, 0.5, i) for i in range(4)]
    assert [f.result(timeout=30) for f in futures] == [0, 1, 2, 3]
    assert time.perf_counter() - t0 < 1.9  # four half-second jobs at once, not one after another (2 s)
    assert not futures[0].cancel()  # a job sent is not called back
    assert helper.submit(divmod, 7, b=2).exception(timeout=30) is not None  # divmod takes no keywords
    assert helper.submit(divmod, 7, 2).result(timeout=30) == (3, 1)


def test_a_jobs_error_comes_back_as_itself(helper):
    with pytest.raises(ValueError, match="invalid literal for int"):
        helper.submit(int, "x").result(timeout=30)


def test_a_result_that_cannot_come_back_is_an_error_naming_it(helper):
    with pytest.raises(HelperError, match="result of _unpicklable cannot come back"):
        helper.submit(_unpicklable).result(timeout=30)
    with pytest.raises(HelperError, match="result could not be read here .*read in the helper only"):
        helper.submit(_unreadable_here).result(timeout=30)
    with pytest.raises(Exception, match="Can't pickle|can't pickle|cannot pickle"):
        helper.submit(lambda: None)  # the caller's own error, before anything is sent
    assert helper.submit(abs, -3).result(timeout=30) == 3  # the helper goes on


def test_a_job_the_helper_cannot_import_fails_alone(tmp_path, helper, monkeypatch):
    (tmp_path / "only_here.py").write_text("def seven():\n    return 7\n")
    monkeypatch.syspath_prepend(str(tmp_path))  # after the helper started: not on its path
    import only_here

    with pytest.raises(ModuleNotFoundError, match="only_here"):
        helper.submit(only_here.seven).result(timeout=30)
    assert helper.submit(abs, -4).result(timeout=30) == 4


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


def test_sending_to_a_helper_that_has_gone_is_a_helper_error_and_kill_ends_a_stopped_one():

    h = Helper()
    os.kill(h.submit(os.getpid).result(timeout=30), signal.SIGKILL)
    with pytest.raises(HelperError, match="has ended"):
        for _ in range(200):  # the pipe breaks, or the reader sees the end first: either way
            h.submit(abs, 1)
            time.sleep(0.01)
    h.kill()

    h = Helper()
    os.kill(h.submit(os.getpid).result(timeout=30), signal.SIGSTOP)  # reads nothing more
    t0 = time.perf_counter()
    jobs = [h.submit(len, b"x" * 2**26) for _ in range(2)]  # 128 MiB: the pipe is full, the caller goes on
    assert time.perf_counter() - t0 < 5 and h._writer.is_alive()  # still sending, on the writer thread
    h.kill()
    assert time.perf_counter() - t0 < 10 and not h._writer.is_alive()
    for job in jobs:
        with pytest.raises(HelperError, match="ended"):
            job.result(timeout=10)


def test_jobs_go_out_in_order_without_the_caller_waiting_for_the_helper_to_start():
    """Sending never waits for the helper's process (whose start, a Python with JAX, takes seconds):
    the jobs go out in order from a thread of their own, and their results come back."""
    t0 = time.perf_counter()
    with Helper(threads=1) as h:
        jobs = [h.submit(len, b"x" * (2**20 + i)) for i in range(16)]  # 16 MiB: far over the pipe's 64 KiB
        sent = time.perf_counter() - t0
        order = h.submit(_sleep_then, 0.0, "last")
        assert [j.result(timeout=60) for j in jobs] == [2**20 + i for i in range(16)]
        assert order.result(timeout=60) == "last"
        started = time.perf_counter() - t0
    assert sent < 0.5 * started  # the caller was back long before the helper had read them


def test_the_helper_ignores_ctrl_c_its_parent_handles():
    with Helper() as h:
        pid = h.submit(os.getpid).result(timeout=30)
        os.kill(pid, signal.SIGINT)
        assert h.submit(_sleep_then, 0.2, "alive").result(timeout=30) == "alive"


def test_a_script_without_a_main_guard_runs_once(tmp_path):
    """The helper does not import the caller's main module again (what spawning does by default):
    a script that starts one at its top level, with no ``if __name__ == "__main__":``, runs once,
    and its job runs."""
    import subprocess
    import sys

    script, marker = tmp_path / "unguarded.py", tmp_path / "ran.txt"
    script.write_text(
        "import operator, sys\n"
        "from pathlib import Path\n"
        "with Path(sys.argv[1]).open('a') as f:\n"
        "    f.write('ran\\n')\n"
        "from jaxeac.running.helper import Helper\n"
        "with Helper(threads=1) as helper:\n"
        "    print(helper.submit(operator.add, 2, 3).result())\n")
    done = subprocess.run([sys.executable, str(script), str(marker)], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["5"]
    assert marker.read_text() == "ran\n"


def _pid_plus(x: int) -> tuple:
    return os.getpid(), x + 1


def _pid_after(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


def test_in_helper_runs_there_and_here_once_the_helper_has_gone():
    """`in_helper`: the job's value from the helper; without a helper, or once it has ended (before
    the job is sent, or while it runs), computed here; what the job raises is raised."""
    with Helper(threads=1) as h:
        pid, value = in_helper(h, _pid_plus, 1)()
        assert pid != os.getpid() and value == 2
        with pytest.raises(ValueError):
            in_helper(h, int, "not a number")()
        running = in_helper(h, _pid_after, 1.0)
        time.sleep(0.3)  # sent and under way
        h.kill()
        assert running() == os.getpid()  # its value never came back: computed here
        assert in_helper(h, _pid_plus, 2)() == (os.getpid(), 3)
    assert in_helper(None, _pid_plus, 3)() == (os.getpid(), 4)


def test_a_lanes_jobs_run_beside_the_helpers_own_and_an_unknown_lane_is_refused():
    with Helper(threads=1, lanes={"figure": 1}) as h:
        busy = h.submit(_sleep_then, 20, None)  # the one thread of `submit`'s jobs is taken
        assert h.submit_to("figure", _pid_plus, 1).result(timeout=60)[1] == 2 and not busy.done()
        with pytest.raises(ValueError, match="no lane 'drawing' in this helper"):
            h.submit_to("drawing", abs, -1)
        h.kill()


def test_the_peak_memory_is_the_helpers_own_not_its_parents():
    """`peak_rss_bytes` is the helper's own high-water mark: a parent holding 1.5 GiB when it starts
    the helper (the rusage maximum keeps it across the start's fork and exec) does not count."""
    import numpy as np

    held = np.ones(3 * 2**27, np.float32)  # 1.5 GiB, resident
    with Helper(threads=1) as h:
        assert h.submit(abs, -1).result(timeout=60) == 1
    del held
    assert 0 < h.peak_rss_bytes < 2**30



_PRELOADED: list[str] = []


def _preload_slowly() -> None:
    time.sleep(1.0)  # a job sent meanwhile waits in the pipe
    _PRELOADED.append("preloaded")


def _preloaded() -> list[str]:
    return list(_PRELOADED)


def test_a_helpers_preload_ends_before_it_reads_a_job():
    """`preload` runs in the helper before its first job is read (two jobs importing one package at
    once saw it half made), and a job sent while it runs finds it done."""
    with Helper(threads=2, preload=_preload_slowly) as h:
        first = h.submit(_preloaded)
        assert first.result(timeout=60) == ["preloaded"]
    assert _PRELOADED == []  # it ran there, not here
