"""Faults at random points of a run: a grid run killed (SIGKILL) or interrupted (SIGINT) at any
moment over a folder holding an earlier run leaves that folder holding one whole run, the old
or the new, never a mix and never a half-written file; the next run cleans up and finishes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

ROOT = Path(__file__).resolve().parent.parent
RUN = ["grid", "--seeds", "300", "--trials", "40", "--chances", "20", "--quiet"]


def jaxeac(argv, env, **kwargs):
    return subprocess.Popen([sys.executable, "-m", "jaxeac", *argv], env=env, cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, **kwargs)


def visible(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))


def whole_run(folder: Path, references: dict) -> int:
    """The key of the one run `folder` holds, checking that every file belongs to it."""
    summary = json.loads((folder / "summary.json").read_text())
    key = summary["key"]
    ref = references[key]
    assert pq.read_table(folder / "results.parquet").equals(pq.read_table(ref / "results.parquet"))
    assert (folder / "per_seed.csv").read_text() == (ref / "per_seed.csv").read_text()
    if (folder / "stats.json").exists():  # a report, if any, is this run's
        stats = json.loads((folder / "stats.json").read_text())
        assert stats["primary"]["n_baseline"] == summary["seeds"]
        assert stats["primary"]["mean_baseline"] == json.loads((ref / "stats.json").read_text())["primary"][
            "mean_baseline"]
    return key


@pytest.fixture(scope="module")
def references(tmp_path_factory):
    """Complete runs for keys 1 and 2 (with their reports), and how long one takes."""
    root = tmp_path_factory.mktemp("faults")
    env = dict(os.environ, JAXEAC_COMPILATION_CACHE=str(root / "cache"))  # compile once for all runs
    refs, seconds = {}, []
    for key in (1, 2):
        t0 = time.perf_counter()
        proc = jaxeac([*RUN, "--key", str(key), "--out", str(root / f"ref{key}")], env)
        assert proc.wait(timeout=600) == 0, proc.stderr.read().decode()[-2000:]
        seconds.append(time.perf_counter() - t0)
        refs[key] = root / f"ref{key}"
    return refs, env, min(seconds)


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGINT])
def test_a_run_stopped_at_random_points_leaves_one_whole_run(tmp_path, references, sig):
    refs, env, seconds = references
    out = tmp_path / "run"
    assert jaxeac([*RUN, "--key", "1", "--out", str(out)], env).wait(timeout=600) == 0
    rng = np.random.default_rng(sig)
    for at in rng.uniform(0.1, 1.1, 4) * seconds:  # from start-up to past the end
        proc = jaxeac([*RUN, "--key", "2", "--out", str(out)], env)
        time.sleep(at)
        proc.send_signal(sig)
        code = proc.wait(timeout=600)
        err = proc.stderr.read().decode()
        assert "Traceback" not in err, err[-2000:]
        if sig == signal.SIGINT:  # -SIGINT: it landed before the interpreter had a handler at all
            assert code in (0, 130, -signal.SIGINT), (code, err[-2000:])
        key = whole_run(out, refs)
        assert set(visible(out)) <= set(visible(refs[key])), visible(out)
    # the next run removes what the stopped ones left and ends with the new run, whole
    assert jaxeac([*RUN, "--key", "2", "--out", str(out)], env).wait(timeout=600) == 0
    assert whole_run(out, refs) == 2 and not list(out.glob(".staging-*"))
    assert visible(out) == visible(refs[2])


def test_ctrl_c_during_start_up_is_one_line(tmp_path):
    """Ctrl-C while `jaxeac` is still importing its modules, or early in the run (where JAX's
    garbage-collection callback used to swallow it): one line, exit 130, never a traceback,
    nothing written."""
    out = tmp_path / "run"
    for at in (1.0, 1.5, 2.0, 3.0):  # past the interpreter's own start, which may be slow
        proc = jaxeac([*RUN, "--out", str(out)], dict(os.environ))
        time.sleep(at)
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=120)
        err = proc.stderr.read().decode()
        assert "Traceback" not in err, err[-2000:]
        assert code in (130, -signal.SIGINT), (code, err)
        if code == 130:
            assert len(err.strip().splitlines()) == 1 and err.startswith("error: "), err
        assert not out.exists() or not [p for p in out.iterdir() if not p.name.startswith(".")]


def test_ctrl_c_where_python_cannot_raise_it_is_sent_again(monkeypatch, capsys):
    """A KeyboardInterrupt raised where Python can only drop it (a garbage-collection or weakref
    callback, as JAX has) is not printed as "Exception ignored" but sent again as SIGINT, to
    land in ordinary code; other dropped exceptions go to the previous hook as before."""
    import gc
    import weakref

    from jaxeac.cli import process as cli

    sent, others = [], []
    monkeypatch.setattr(cli.os, "kill", lambda pid, sig: sent.append(sig))
    monkeypatch.setattr(cli, "_previous_unraisablehook", lambda u: others.append(u.exc_type))
    monkeypatch.setattr(sys, "unraisablehook", cli._resend_dropped_ctrl_c)

    def interrupted(phase, info):
        if phase == "start":
            raise KeyboardInterrupt

    gc.callbacks.append(interrupted)
    try:
        gc.collect()
    finally:
        gc.callbacks.remove(interrupted)

    class Target:
        pass

    def fails(error):
        def callback(ref):
            raise error
        return callback

    for error in (KeyboardInterrupt, ValueError):  # weakref callbacks, one Ctrl-C, one other error
        target = Target()
        ref = weakref.ref(target, fails(error))
        del target
    deadline = time.time() + 5
    while len(sent) < 2 and time.time() < deadline:
        time.sleep(0.01)
    assert sent == [signal.SIGINT, signal.SIGINT] and others == [ValueError]
    assert ref is not None and "Exception ignored" not in capsys.readouterr().err


def test_ctrl_c_while_the_exit_handlers_run_is_ignored():
    """Once the command has finished (`jaxeac.__main__._end`), a Ctrl-C that lands in an exit
    handler (JAX's clean-up, in a run stopped at random) neither prints a traceback nor changes
    the exit code."""
    code = ("import atexit, os, signal, time; from jaxeac.__main__ import _end; "
            "atexit.register(lambda: (os.kill(os.getpid(), signal.SIGINT), time.sleep(0.2))); _end(3)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 3, proc.stderr
    assert "Traceback" not in proc.stderr and "KeyboardInterrupt" not in proc.stderr, proc.stderr


def test_the_command_ends_without_jaxs_teardown_and_runs_the_other_exit_handlers():
    """`jaxeac.__main__._end` runs the exit handlers but JAX's clean-up (`jax._src.api.clean_up`,
    freeing its client and compiled programs one by one, the process ending right after): a
    handler registered before JAX (so run after JAX's) still finds JAX's backend; the others run,
    and the exit code is the command's. With JAX's handler the backend would be gone by then."""
    code = ("import atexit, json; seen = []; atexit.register(lambda: print(json.dumps(seen + "
            "[bool(__import__('jax._src.xla_bridge', fromlist=['x'])._backends)]), flush=True)); "
            "import jax, jax.numpy as jnp; jnp.zeros(3).block_until_ready(); "
            "atexit.register(lambda: seen.append('other')); from jaxeac.__main__ import _end; _end({end})")
    for end, want in (("3", ["other", True]), ("__import__('sys').exit(3)", ["other", False])):
        proc = subprocess.run([sys.executable, "-c", code.format(end=end)], capture_output=True, text=True,
                              timeout=120, env=dict(os.environ, JAX_PLATFORMS="cpu"))
        assert proc.returncode == 3, proc.stderr
        assert json.loads(proc.stdout.splitlines()[-1]) == want, (end, proc.stdout, proc.stderr)


def test_ctrl_c_wrapped_by_an_import_is_still_an_interrupt(capsys):
    """Ctrl-C while a module's class body is set up reaches the command as a RuntimeError caused by
    it (Python 3.11's ``__set_name__``): still one line and exit code 130, never a traceback; any
    other RuntimeError is raised as it is."""
    from jaxeac.cli.process import run_command

    def interrupted_import(argv, cleanup):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise RuntimeError("Error calling __set_name__ on '_axis_method_wrapper' instance") from exc

    assert run_command([], interrupted_import) == 130
    err = capsys.readouterr().err.splitlines()
    assert err == ["error: interrupted; files already finished are kept, none is half-written"]

    def broken(argv, cleanup):
        raise RuntimeError("not an interrupt")

    with pytest.raises(RuntimeError, match="not an interrupt"):
        run_command([], broken)
