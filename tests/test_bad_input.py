"""Hostile input and faults: one line ``error: ...`` on stderr, exit code 2, nothing written.

Bad values of every numeric flag (generated with hypothesis), sizes that cannot fit in
memory or finish, bad paths and files, two runs into one folder, a full disk, Ctrl-C and
running out of memory: never a traceback, never a silent acceptance, nothing half-written.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxeac.cli import build_parser, main
from jaxeac.envs.grid import load_map, paper_like_map

TINY = ["--seeds", "2", "--trials", "2", "--chances", "5", "--quiet", "--no-compare"]
INT32_MAX = 2**31 - 1
F32_TINY, F32_MAX = float(np.finfo(np.float32).tiny), float(np.finfo(np.float32).max)
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")  # a warning is a second stderr line
FUZZ = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def snapshot(root):
    """Every path under `root` (hidden ones too), to check that nothing was created or changed."""
    return sorted((str(p.relative_to(root)), p.is_dir(), p.is_file() and p.stat().st_size)
                  for p in root.rglob("*"))


def refused(capsys, argv, root, match=None, code=2) -> str:
    """main(argv) fails with one `error:` line and exit `code`, and nothing under `root` changes."""
    before = snapshot(root)
    capsys.readouterr()
    assert main(argv) == code, argv
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    if match:
        assert re.search(match, err), err
    assert snapshot(root) == before, argv
    return err


def bad_count(text: str, limit: int = INT32_MAX, low: int = 1) -> bool:
    """Whether `text` is not a count the CLI accepts (an integer in low..limit)."""
    try:
        value = int(text)
    except ValueError:
        return True
    return not low <= value <= limit


def bad_number(text: str, low: float, high: float, *, positive: bool = False) -> bool:
    """Whether `text` is not a rate the CLI accepts (finite, in [low, high], float32-normal)."""
    try:
        value = float(text)
    except ValueError:
        return True
    if not np.isfinite(value) or not low <= value <= high or (positive and value == 0):
        return True
    return value != 0 and not F32_TINY <= abs(value) <= F32_MAX


texts = st.text(max_size=30)
counts = st.one_of(st.integers(max_value=0).map(str), st.integers(min_value=INT32_MAX + 1).map(str),
                   st.floats(allow_nan=True).map(repr), texts).filter(bad_count)


# ------------------------------------------------------------------ generated bad values


@FUZZ
@given(flag=st.sampled_from(["--seeds", "--trials", "--chances"]), value=counts)
def test_bad_counts(flag, value, tmp_path, capsys):
    refused(capsys, ["grid", *TINY, "--out", str(tmp_path / "out"), f"{flag}={value}"], tmp_path)


@FUZZ
@given(value=st.one_of(st.integers(max_value=-1), st.integers(min_value=2**32)).map(str)
       | texts.filter(lambda t: bad_count(t, 2**32 - 1, low=0)))  # keys are 0..2^32 - 1, 0 included
def test_bad_keys(value, tmp_path, capsys):
    refused(capsys, ["grid", *TINY, "--out", str(tmp_path / "out"), f"--key={value}"], tmp_path)


@pytest.mark.parametrize("value", ["0", " 0", "+0", "-0", "00", "4294967295"])
def test_keys_at_the_ends_of_their_range_are_accepted(value):
    """Keys are 0..2^32 - 1 (R1): the ends of the range, as a user may type them, parse."""
    from jaxeac.cli.flags import prng_key

    assert prng_key(value) == int(value)


@FUZZ
@given(flag=st.sampled_from(["--alpha", "--beta"]),
       value=st.one_of(st.floats().map(repr), texts, st.floats(1e-300, 1e-39).map(repr))
       .filter(lambda t: bad_number(t, 0.0, 1.0)))
def test_bad_rates(flag, value, tmp_path, capsys):
    refused(capsys, ["grid", *TINY, "--out", str(tmp_path / "out"), f"{flag}={value}"], tmp_path)


@FUZZ
@given(value=st.one_of(st.floats().map(repr), texts, st.sampled_from(["5e-324", "1e-40", "1e39", "0", "-0"]))
       .filter(lambda t: bad_number(t, 0.0, float("inf"), positive=True)))
def test_bad_temperatures(value, tmp_path, capsys):
    refused(capsys, ["grid", *TINY, "--out", str(tmp_path / "out"), f"--temperature={value}"], tmp_path)


hosts = st.sampled_from(["host0", "10.0.0.1", "[::1]", "a.b-c_d"])
bad_ports = st.one_of(st.integers(max_value=0), st.integers(min_value=65536)).map(str) | texts.filter(
    lambda t: not (t.strip().isascii() and t.strip().isdigit() and 1 <= int(t.strip()) <= 65535))
bad_hosts = st.sampled_from(["", "two words", "a/b", "::1", "user@host", "h\u00e9", "[zz::1]", "[]"])
coordinators = st.one_of(
    texts.filter(lambda t: ":" not in t),  # no port at all
    st.builds(lambda h, p: f"{h}:{p}", hosts, bad_ports),
    st.builds(lambda h, p: f"{h}:{p}", bad_hosts, st.integers(1, 65535)),
)


@FUZZ
@given(value=coordinators)
def test_bad_coordinators(value, tmp_path, capsys):
    argv = ["grid", *TINY, "--out", str(tmp_path / "out"), "--num-processes", "2", "--process-id", "0",
            f"--coordinator={value}"]
    refused(capsys, argv, tmp_path)


def test_coordinator_needs_several_processes(tmp_path, capsys):
    refused(capsys, ["grid", *TINY, "--out", str(tmp_path / "o"), "--coordinator", "host0:1234"], tmp_path,
            "multi-process")


def test_good_values_parse():
    """The edges of every range still parse (nothing valid is refused by the checks above)."""
    args = build_parser().parse_args(["grid", "--key", str(2**32 - 1), "--coordinator", "[::1]:65535",
                                      "--alpha", "1", "--temperature", "1e-30"])
    assert args.key == 2**32 - 1 and args.coordinator == "[::1]:65535"
    assert build_parser().parse_args(["grid", "--coordinator", "host0:1234"]).coordinator == "host0:1234"


def test_key_beyond_32_bits_is_refused_not_wrapped(tmp_path, capsys):
    """jax.random.key keeps key mod 2^32: 2^32 would silently rerun key 0 under another name."""
    for command in (["grid", *TINY, "--out", str(tmp_path / "o")], ["throw", "--angle", "0"],
                    ["bowling", "--seeds", "2", "--out", str(tmp_path / "o")]):
        for key in (2**32, 2**64):
            refused(capsys, [*command, "--key", str(key)], tmp_path, r"0\.\.4294967295")


# ------------------------------------------------------------------ sizes that cannot run


@pytest.mark.parametrize("flags", [
    ["--seeds", str(INT32_MAX + 1)],  # seed indices are int32
    ["--seeds", str(INT32_MAX)],  # TBs of results
    ["--seeds", "1000000000000"],
    ["--trials", "1000000000", "--seeds", "1000"],
    ["--chances", "1000000000000"],
    ["--chances", "2000000000", "--seeds", "1000"],
    ["--chances", "100000000"],  # fits, but each step moves the r̃ of 10^8 chances: years
    ["--memory", "buffer", "--capacity", "1000000000000"],
    ["--chunk-size", "1", "--capacity", "1000000000000", "--memory", "buffer"],
    ["--memory", "buffer", "--capacity", str(2**64)],  # past int64: was an OverflowError traceback
])
def test_grid_sizes_that_cannot_fit_or_finish(flags, tmp_path, capsys):
    err = refused(capsys, ["grid", *TINY, "--out", str(tmp_path / "out"), *flags], tmp_path)
    assert re.search(r"too large|cannot fit|far too long", err), err
    assert re.search(r"\d", err)  # the numbers are in the message


def test_huge_map_and_device_map_files(tmp_path, capsys):
    big = tmp_path / "big.txt"
    big.write_text(paper_like_map(2000))  # 4 million cells
    refused(capsys, ["grid", *TINY, "--seeds", "100000", "--map", str(big), "--out", str(tmp_path / "o")],
            tmp_path, "cannot fit in memory")
    line = tmp_path / "line.txt"
    line.write_text("G" + "." * (1 << 22) + "\n")  # one row past the cell limit
    refused(capsys, ["grid", *TINY, "--map", str(line), "--out", str(tmp_path / "o")], tmp_path,
            "4,194,305 cells, more than the 4,194,304")
    refused(capsys, ["grid", *TINY, "--map", "/dev/zero", "--out", str(tmp_path / "o")], tmp_path,
            "is a device")
    refused(capsys, ["grid", *TINY, "--map", str(tmp_path), "--out", str(tmp_path / "o")], tmp_path,
            "is a folder")


@pytest.mark.parametrize(("flags", "match"), [
    (["--seeds", "1000000000000"], "too large"),
    (["--seeds", "2000000000"], "cannot fit|far too long"),
    (["--angles", "1000000000", "--algos", "ac"], "cannot fit in memory"),
    (["--angles", "1000000000"], "at most 24 angles"),
    (["--trials", "5000"], "at most 1,023 trials"),
    (["--contact-cap", "1"], "below 30"),
    (["--contact-cap", "29"], "below 30"),
])
def test_bowling_sizes_and_caps(flags, match, tmp_path, capsys):
    refused(capsys, ["bowling", "--seeds", "2", "--out", str(tmp_path / "out"), *flags], tmp_path, match)


def test_bowling_settings_check_what_eacs_memories_hold():
    """`BowlingSettings.validate` (the CLI, reproduce and library callers alike) refuses K and T beyond
    EAC's dense memories, naming the setting and the limit; AC alone has no such limit."""
    from jaxeac.errors import UsageError
    from jaxeac.experiments.bowling import BowlingSettings

    with pytest.raises(UsageError, match=r"^angles 25: EAC's memories hold at most 24 angles; use 24 angles or fewer"):
        BowlingSettings(angles=25).validate()
    with pytest.raises(UsageError, match=r"^trials 1024: with 21 angles EAC's memories hold at most 1,023 trials"):
        BowlingSettings(trials=1024).validate()
    BowlingSettings(angles=25, trials=1024, algos=("ac",)).validate()
    BowlingSettings(trials=1023).validate()


def test_compare_resamples_that_cannot_fit(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "summary.json").write_text(json.dumps({"trials": 200}))
    refused(capsys, ["compare", str(run), "--resamples", "1000000000000"], tmp_path, "cannot fit in memory")


# ------------------------------------------------------------------ paths and files


def test_empty_out_and_bad_render_paths(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for command in (["grid", *TINY], ["bowling", "--seeds", "2"], ["sweep", "--set", "alpha=0.1,0.2"],
                    ["reproduce"]):
        refused(capsys, [*command, "--out", ""], tmp_path, "empty name")
        refused(capsys, [*command, "--out=  "], tmp_path, "empty name")
    refused(capsys, ["compare", ""], tmp_path, "empty name")
    (tmp_path / "folder").mkdir()
    throw = ["throw", "--angle", "0", "--render"]
    refused(capsys, [*throw, str(tmp_path / "missing" / "deck.png")], tmp_path, "does not exist")
    refused(capsys, [*throw, str(tmp_path / "folder")], tmp_path, "is a folder")
    refused(capsys, [*throw, ""], tmp_path, "not a file name")
    refused(capsys, [*throw, str(tmp_path / "deck.jpg")], tmp_path, "PNG")
    refused(capsys, ["grid", *TINY, "--out", "x" * 5000], tmp_path, "too long")


def test_a_folder_holding_another_kind_of_output_is_refused(tmp_path, capsys):
    """A run, a sweep and a reproduction never share a folder: their files would mix (a run
    replaces only a run's files; a sweep or a reproduction resumes its own)."""
    kinds = {"run": "summary.json", "sweep": "sweep.json", "reproduce": "grid/reproduce.json"}
    for kind, marker in kinds.items():
        (tmp_path / kind / marker).parent.mkdir(parents=True)
        (tmp_path / kind / marker).write_text("{}")
    run, sweep, repro = (str(tmp_path / k) for k in kinds)
    refused(capsys, ["grid", *TINY, "--out", sweep], tmp_path, r"holds a sweep .*sweep\.json")
    refused(capsys, ["bowling", "--seeds", "2", "--out", repro], tmp_path, "holds a reproduction")
    refused(capsys, ["sweep", "--set", "alpha=0.1,0.2", *TINY[:6], "--out", run], tmp_path,
            "holds a grid or bowling run")
    refused(capsys, ["reproduce", "--quick", "--out", sweep], tmp_path, "holds a sweep")
    refused(capsys, ["grid", *TINY, "--out", str(tmp_path / "reproduce" / "grid")], tmp_path,
            "holds a reproduction")  # a reproduction's step folder is the reproduction's
    refused(capsys, ["merge", sweep], tmp_path, "holds a sweep .*; pass a folder holding a grid or bowling run")
    refused(capsys, ["compare", sweep], tmp_path, "holds a sweep .*; pass a folder holding a grid or bowling run")
    err = refused(capsys, ["grid", *TINY, "--out", sweep], tmp_path, "choose another --out")
    assert "remove" not in err  # never advice that deletes the user's sweep


@pytest.mark.parametrize("key", [1, 2])
def test_two_seeds_compare_without_warnings(tmp_path, capsys, key):
    """Two seeds per method: resamples and leave-one-out samples without spread make g and
    max-T infinite or undefined; the report says so, and numpy prints nothing (module mark:
    a RuntimeWarning fails the test)."""
    argv = ["grid", "--seeds", "2", "--trials", "20", "--chances", "20", "--key", str(key), "--quiet",
            "--out", str(tmp_path / "run")]
    assert main(argv) == 0
    assert capsys.readouterr().err == ""


def test_throw_noise_that_underflows_is_refused(tmp_path, capsys):
    throw = ["throw", "--angle", "0"]
    refused(capsys, [*throw, "--noise-angle=5e-324"], tmp_path, "noise_angle.*smallest normal")
    refused(capsys, [*throw, "--noise-speed=1e-40"], tmp_path, "noise_speed.*smallest normal")


def test_render_reports_the_file_it_wrote(tmp_path, capsys):
    assert main(["throw", "--angle", "0", "--render", str(tmp_path / "deck")]) == 0
    reported = json.loads(capsys.readouterr().out)["render"]
    assert reported == [str(tmp_path / "deck.png")] and (tmp_path / "deck.png").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["deck.png"]


def test_map_with_a_byte_order_mark_loads(tmp_path):
    path = tmp_path / "bom.txt"
    path.write_text(paper_like_map(11), encoding="utf-8-sig")
    assert load_map(path).text == paper_like_map(11)


# ------------------------------------------------------------------ faults


def test_interrupt_and_out_of_memory_are_one_line(tmp_path, capsys, monkeypatch):
    from jaxeac.experiments import grid

    out = tmp_path / "out"
    for fault, code, match in ((KeyboardInterrupt, 130, "interrupted"), (MemoryError, 2, "out of memory")):
        def boom(*args, fault=fault, **kwargs):
            raise fault()

        monkeypatch.setattr(grid, "run_algorithms", boom)  # mid-run, with results.parquet being written
        refused(capsys, ["grid", *TINY, "--out", str(out)], tmp_path, match, code)
        refused(capsys, ["grid", *TINY, "--sequential", "--effect", "1", "--seeds", "20", "--looks", "2",
                         "--out", str(out)], tmp_path, match, code)


def test_closed_stdout_is_quiet(monkeypatch, capfd):
    """`jaxeac throw ... | head`: the reader went away; exit 141 as a shell would, no traceback."""

    class Closed:
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self):
            pass

    monkeypatch.setattr(sys, "stdout", Closed())
    assert main(["throw", "--angle", "0"]) == 141
    assert capfd.readouterr().err == ""


def _jaxeac(*argv, **kwargs):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, "-m", "jaxeac", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, **kwargs)


def _wait_for(proc, text: str, timeout: float = 120) -> str:
    """Read proc's stderr until `text` appears (the run is past its checks, holding its folder)."""
    seen, deadline = "", time.monotonic() + timeout
    while text not in seen:
        char = proc.stderr.read(1)
        assert char and time.monotonic() < deadline, seen
        seen += char
    return seen


def test_ctrl_c_exits_130_with_one_line(tmp_path):
    out = tmp_path / "out"
    proc = _jaxeac("grid", "--seeds", "100000", "--trials", "200", "--out", str(out), "--no-compare")
    _wait_for(proc, "grid: ")  # the progress bar: running
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and err.rstrip().splitlines()[-1].startswith("error: interrupted")
    left = sorted(str(f.relative_to(out)) for f in out.rglob("*")) if out.exists() else None
    assert left is None, left  # the folder it created is removed again: nothing written


def test_concurrent_writers_to_one_folder(tmp_path, capsys):
    """While one run holds --out, a second is refused at once; the first's result is intact."""
    out = tmp_path / "out"
    first = _jaxeac("grid", *TINY[:-2], "--out", str(out), "--no-compare")
    try:
        _wait_for(first, "grid: ")
        first.send_signal(signal.SIGSTOP)  # hold it mid-run, the folder locked
        err = refused(capsys, ["grid", *TINY, "--out", str(out)], tmp_path, "being written by another")
        assert str(first.pid) in err
    finally:
        first.send_signal(signal.SIGCONT)
    _, err = first.communicate(timeout=120)
    assert first.returncode == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seeds"] == 2 and summary["trials"] == 2
    assert not any(p.name.startswith(".") for p in out.iterdir())  # no lock file, no staging left


@pytest.fixture
def full_disk(tmp_path):
    """A 64 KiB tmpfs (needs root and mount); skipped where it cannot be mounted."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a small tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode(errors='replace').strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], check=False)


def test_full_disk_is_one_line_and_leaves_nothing(full_disk, capsys):
    refused(capsys, ["grid", *TINY, "--out", str(full_disk / "run")], full_disk, "disk is full")
    refused(capsys, ["throw", "--angle", "0", "--angle", "0.05", "--render", str(full_disk / "deck.png")],
            full_disk, "disk is full")  # two pictures do not fit: neither is left half-drawn
    assert list(full_disk.iterdir()) == []


# ------------------------------------------------------------------ found by a hostile-input campaign


@pytest.mark.parametrize(("argv", "match"), [
    (["compare", "run", "--level", "0.99999999999999"], "--level .* beyond double precision"),  # α/2 ~ 0
    (["compare", "run", "--level", "1"], r"--level must lie in \(0, 1\)"),
    (["sweep", "--seeds", "2", "--set", "alpha=0.1,,0.2"], "empty"),  # was run with the empty value dropped
    (["sweep", "--seeds", "2", "--set", "alpha=0.1,"], "empty"),
    (["grid", *TINY, "--map", ""], "empty name is not a map file"),  # was the preset's map
    (["grid", *TINY, "--map", "  "], "empty name is not a map file"),
    (["bowling", "--seeds", "2", "--noise-speed", "1e12"], "noise_speed"),  # the simulation blew up
    (["bowling", "--seeds", "2", "--noise-angle", "1e12"], "noise_angle"),
    (["bowling", "--seeds", "2", "--theta-max", "1e-40"], "theta_max"),  # every angle 0 in float32
    (["bowling", "--seeds", "2", "--noise-angle", "5e-324"], "noise_angle"),
    (["throw", "--angle", "0", "--noise-speed", "1e308"], "--noise-speed.*noise_speed"),
    (["throw", "--angle", "0", "--theta-max", "5e-324"], "theta_max"),
])
def test_extreme_values_found_by_the_campaign(argv, match, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    out = [] if argv[0] in ("compare", "throw") else ["--out", str(tmp_path / "out")]
    refused(capsys, [*argv, *out], tmp_path, match)


def test_smallest_compare_alpha_is_accepted():
    """The check above refuses what double precision cannot resolve, not small levels as such."""
    from jaxeac.cli.flags import MIN_TEST_ALPHA
    from jaxeac.stats.closed_form import seeds_for_power

    assert seeds_for_power(0.5, 0.8, MIN_TEST_ALPHA) is not None


def test_reproduce_analysis_keys_differ_for_every_root_key():
    """Keys k and k + 2^31 used to share every analysis key (mod 2^31); keys below 2^31 keep theirs."""
    from jaxeac.experiments.reproduce.measures import sub_key

    assert sub_key(0, "grid/reach") == 50674734  # unchanged for the keys that were distinct
    for k in (0, 1, 12345, 2**31 - 1):
        assert sub_key(k, "grid/reach") != sub_key(k + 2**31, "grid/reach")
        assert sub_key(k + 2**31, "grid/reach") < 2**32
    assert len({sub_key(k, "x") for k in range(0, 2**32, 2**28)}) == 16


def test_policy_figure_of_a_large_map_draws_no_arrow_per_cell(tmp_path, monkeypatch):
    """A 10,000-cell map took minutes (10^7 cells: hours) to draw an arrow and a tick per cell."""
    import matplotlib.axes

    from jaxeac import plots
    from jaxeac.envs.grid import parse_map

    calls = []
    real = matplotlib.axes.Axes.quiver
    monkeypatch.setattr(matplotlib.axes.Axes, "quiver",
                        lambda self, *a, **k: calls.append(1) or real(self, *a, **k))
    wide = parse_map("." * (plots.POLICY_ARROW_SIDE + 1) + "G\n")
    plots.policy_figure(wide, {"ac": np.zeros(wide.n_cells, int)}, tmp_path / "wide.png", seed=0, max_steps=5)
    assert calls == [] and (tmp_path / "wide.png").is_file()
    small = parse_map(paper_like_map(11))
    plots.policy_figure(small, {"ac": np.zeros(small.n_cells, int)}, tmp_path / "small.png", seed=0,
                        max_steps=5)
    assert calls == [1]


# --- environments, baselines and the study (X1–X4) ---------------------------------------------

@pytest.mark.parametrize("argv, match", [
    (["run", "--env", "Nowhere-v9"], r"unknown environment 'Nowhere-v9'; choose one of .*CliffWalking-v1.*"
                                     r"FrozenLake-4x4-v1"),
    (["grid", "--env", "FrozenLake-4x4-v1", "--map", "m.txt"], "--env and --map both name the world"),
    (["run", "--env", "FrozenLake-4x4-v1", "--slip", "1.5"], r"slip must lie in \[0, 1\]"),
    (["run", "--env", "FrozenLake-4x4-v1", "--slip", "-0.1"], "slip must be non-negative"),
    (["run", "--env", "FrozenLake-4x4-v1", "--epsilon", "2"], r"epsilon must lie in \[0, 1\]"),
    (["run", "--env", "FrozenLake-4x4-v1", "--algos", "ac", "dqn"], "unknown algorithm 'dqn'; choose from .*sarsa"),
    (["study", "--tasks", "Nowhere-v9"], "unknown environment 'Nowhere-v9'"),
    (["study", "--tasks", "FrozenLake-4x4-v1:slip=2"], r"slip must lie in \[0, 1\]"),
    (["study", "--tasks", "FrozenLake-4x4-v1:wind=2"], "write NAME or NAME:slip=P"),
    (["study", "--algos", "eac", "sarsa"], "--algos must include ac"),
    # refused before anything runs or is written (issue 40): no comparison could come of these
    (["study", "--algos", "ac"], "--algos ac: a study compares algorithms with ac"),
    (["study", "--seeds", "1"], "--seeds 1: a comparison needs at least 2 seeds"),
    (["study", "--tasks", "FrozenLake-4x4-v1", "FrozenLake-4x4-v1:slip=0"], "--tasks names one task twice"),
    (["study", "--tasks", "CliffWalking-v1:slip=0.1", "CliffWalking-v1:slip=0.10"], "names one task twice"),
    (["study", "--tasks", "FrozenLake-4x4-v1", "FrozenLake-4x4-v1"], "--tasks names one task twice"),
    (["study", "--tasks", "FrozenLake-4x4-v1:"], "--tasks: task 'FrozenLake-4x4-v1:': nothing after ':'"),
    (["study", "--resamples", "100"], "--resamples 100 is too few"),
    (["run", "--seeds", "1"], "--seeds 1: a run reports each algorithm's mean with a 95% CI"),
    (["study", "--tasks", "FourRooms-v0", "--seeds", "2000000000"], "this run (cannot fit in memory|could take far too long)"),
])
def test_bad_environment_input_is_refused(capsys, tmp_path, monkeypatch, argv, match):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "m.txt").write_text("G.\n..\n")
    refused(capsys, [*argv, "--out", str(tmp_path / "out")], tmp_path, match)
