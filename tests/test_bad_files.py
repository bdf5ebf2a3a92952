"""Damaged files a command reads: one `error:` line naming the file, exit 2, nothing written or changed.

`compare` on a run folder, `merge` on a multi-process run and a resumed `sweep` each get
the same damages: truncated, binary garbage, valid JSON of the wrong shape or type,
missing files.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from jaxeac.cli import main
from jaxeac.errors import UsageError

SMALL = ["--seeds", "4", "--trials", "5", "--chances", "10", "--quiet"]


def snapshot(folder):
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def assert_refused(argv, folder, capsys, names):
    before = snapshot(folder)
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    assert any(n in err for n in names), err
    assert snapshot(folder) == before  # nothing written, nothing changed


@pytest.fixture(scope="module")
def grid_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "grid"
    assert main(["grid", *SMALL, "--no-compare", "--out", str(out)]) == 0
    return out


def summary_of(run):
    return json.loads((run / "summary.json").read_text())


DAMAGES = {
    "summary is a list": ("summary.json", lambda p, s: p.write_text("[]")),
    "summary is binary": ("summary.json", lambda p, s: p.write_bytes(bytes(range(256)))),
    "summary truncated": ("summary.json", lambda p, s: p.write_text(p.read_text()[:40])),
    "trials is text": ("summary.json", lambda p, s: p.write_text(json.dumps({**s, "trials": "many"}))),
    "algos missing": ("summary.json", lambda p, s: p.write_text(json.dumps({k: v for k, v in s.items()
                                                                            if k != "algos"}))),
    "algos repeated": ("summary.json", lambda p, s: p.write_text(json.dumps({**s, "algos": ["ac", "ac", "eac"]}))),
    "summary missing": ("summary.json", lambda p, s: p.unlink()),
    "results truncated": ("results.parquet", lambda p, s: p.write_bytes(p.read_bytes()[:100])),
    "results garbage": ("results.parquet", lambda p, s: p.write_bytes(b"PAR1" + bytes(1000) + b"PAR1")),
    "results missing": ("results.parquet", lambda p, s: p.unlink()),
}


def test_compare_refuses_a_non_numeric_per_seed_csv(tmp_path, capsys):
    """A legacy folder whose per_seed.csv has a non-numeric value is refused, not silently used."""
    import numpy as np

    run = tmp_path / "legacy"
    run.mkdir()
    rng = np.random.default_rng(0)
    curves = {a: rng.random((4, 5)) < 0.5 for a in ("ac", "eac")}
    np.savez(run / "curves.npz", **curves)
    rows = [f"{a},{i},{int(c[i].sum()) if (a, i) != ('eac', 2) else 'x'},9,-1"
            for a, c in curves.items() for i in range(4)]
    (run / "per_seed.csv").write_text("algo,seed,successes,steps,first_success\n" + "\n".join(rows) + "\n")
    (run / "summary.json").write_text(json.dumps({"experiment": "grid", "trials": 5, "algos": ["ac", "eac"]}))
    assert_refused(["compare", str(run), "--resamples", "200"], run, capsys, ("per_seed.csv",))


@pytest.fixture(scope="module")
def parts_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("multi") / "run"
    for i in range(2):
        assert main(["grid", *SMALL, "--num-processes", "2", "--process-id", str(i), "--out", str(out)]) == 0
    return out


def spoil_config(path, summary):
    path.write_text(json.dumps({**summary, "config": {**summary["config"], "trials": "many"}}))


@pytest.mark.parametrize("damage", ["summary is a list", "summary missing", "config trials is text",
                                    "results truncated", "results missing"])
def test_merge_refuses_damaged_parts(parts_run, tmp_path, capsys, damage):
    run = tmp_path / "run"
    shutil.copytree(parts_run, run)
    name, spoil = DAMAGES.get(damage, ("summary.json", spoil_config))
    parts = ["part-0000-of-0002", "part-0001-of-0002"] if damage == "config trials is text" else [
        "part-0001-of-0002"]  # both parts agree on the bad config, so it reaches the settings check
    for part in parts:
        spoil(run / part / name, summary_of(run / part))
    assert_refused(["merge", str(run), "--no-compare"], run, capsys, (name, "config", "trials"))


def test_merge_refuses_parts_of_mixed_counts(parts_run, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(parts_run, run)
    (run / "part-0001-of-0003").mkdir()
    assert_refused(["merge", str(run), "--no-compare"], run, capsys, ("counts",))


@pytest.fixture(scope="module")
def sweep_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "s"
    assert main(["sweep", *SMALL, "--set", "alpha=0.1,0.2", "--out", str(out)]) == 0
    return out


@pytest.mark.parametrize("damage", ["manifest garbage", "manifest list", "part truncated", "part garbage"])
def test_resumed_sweep_refuses_damaged_files(sweep_run, tmp_path, capsys, damage):
    out = tmp_path / "s"
    shutil.copytree(sweep_run, out)
    (out / "results.csv").unlink()  # as if killed before the end: the rerun reads every part
    part = sorted((out / "parts").glob("*.npz"))[0]
    target = {"manifest garbage": (out / "sweep.json", b"\xff\xfe{"),
              "manifest list": (out / "sweep.json", b"[1]"),
              "part truncated": (part, part.read_bytes()[:30]), "part garbage": (part, bytes(200))}[damage]
    target[0].write_bytes(target[1])
    assert_refused(["sweep", *SMALL, "--set", "alpha=0.1,0.2", "--out", str(out)], out, capsys,
                   (target[0].name,))


def test_a_killed_runs_staging_folder_is_removed_by_the_next_run(tmp_path):
    out = tmp_path / "run"
    stale = out / ".staging-abc123"
    stale.mkdir(parents=True)
    (stale / "results.parquet").write_bytes(b"half")  # what a SIGKILL mid-write leaves
    assert main(["grid", *SMALL, "--no-compare", "--out", str(out)]) == 0
    assert not stale.exists() and not list(out.glob(".staging-*"))
    assert (out / "results.parquet").is_file()


def test_a_stage_interrupted_before_it_has_a_name_is_removed(tmp_path, monkeypatch):
    """Ctrl-C right after the staging folder is made, before staged_dir knows its name: nothing
    is left; an enclosing stage of the same folder survives an inner one."""
    import tempfile

    from jaxeac.io import staged_dir

    out = tmp_path / "run"
    made = tempfile.mkdtemp

    def interrupted(**kw):
        made(**kw)
        raise KeyboardInterrupt

    with staged_dir(out) as outer:
        (outer / "a.txt").write_text("outer")
        with monkeypatch.context() as m:
            m.setattr(tempfile, "mkdtemp", interrupted)
            with pytest.raises(KeyboardInterrupt), staged_dir(out):
                pass
        assert list(out.glob(".staging-*")) == [outer]
    assert not list(out.glob(".staging-*")) and (out / "a.txt").read_text() == "outer"


def test_a_stage_a_writer_refilled_is_removed_with_the_folder_it_was_made_in(tmp_path, monkeypatch):
    """A run stopped while a thread still writes into its stage: the stage's removal misses a file
    written meanwhile (as `shutil.rmtree` racing a writer does). Releasing the folder removes the
    stage, and the folder the command created is gone again: nothing is left of the run."""
    from jaxeac import io
    from jaxeac.io import folder_lock, staged_dir

    out = tmp_path / "new" / "run"
    real_rmtree = shutil.rmtree

    def racing(path, ignore_errors=False):
        real_rmtree(path, ignore_errors=ignore_errors)
        Path(path).mkdir()
        (Path(path) / "fig.png").write_bytes(b"late")  # the writer's file, after the removal

    with folder_lock(out):
        with monkeypatch.context() as m:
            m.setattr(io.shutil, "rmtree", racing)
            with pytest.raises(KeyboardInterrupt), staged_dir(out) as stage:
                (stage / "results.parquet").write_bytes(b"half")
                raise KeyboardInterrupt
        assert [p.name for p in out.glob(".staging-*/*")] == ["fig.png"]  # left by the race
        (out / ".probe-x").write_bytes(b"")  # a write probe a Ctrl-C cut short
    assert not (tmp_path / "new").exists()


def test_a_new_run_replaces_the_old_folder_as_a_whole(tmp_path):
    """A run into a folder of another run (its report, its figures, bowling's files) leaves no
    file of the old run beside the new results."""
    out = tmp_path / "run"
    assert main(["grid", *SMALL, "--out", str(out)]) == 0  # results, report, compare figures
    (out / "table1.md").write_text("a bowling run's table")
    (out / "notes.txt").write_text("the user's own file")
    assert main(["grid", "--seeds", "3", "--trials", "4", "--chances", "10", "--quiet", "--no-compare",
                 "--out", str(out)]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert "stats.json" not in names and "report.md" not in names and "table1.md" not in names
    assert not [n for n in names if n.startswith("compare_")]
    assert "notes.txt" in names and json.loads((out / "summary.json").read_text())["trials"] == 4


@pytest.mark.parametrize("damage", ["binary", "list", "truncated", "no result", "empty"])
def test_reproduce_treats_a_damaged_step_record_as_unfinished(tmp_path, damage):
    """`jaxeac reproduce` resumes finished steps from their records; a damaged record or run
    summary means "run that step again" (its folder is then replaced whole), never a traceback;
    a damaged results file of a finished step is one error naming it."""
    from jaxeac.experiments.common import finished_run
    from jaxeac.experiments.reproduce.runs import _marker, _npz_arrays

    content = {"binary": bytes(range(256)), "list": b"[1, 2]", "truncated": b'{"fingerprint": {"st',
               "no result": b'{"fingerprint": {}, "seconds": 3}', "empty": b""}[damage]
    (tmp_path / "reproduce.json").write_bytes(content)
    (tmp_path / "summary.json").write_bytes(content)
    assert _marker(tmp_path) is None
    assert finished_run(tmp_path, {"seeds": 10}) is False
    (tmp_path / "curves.npz").write_bytes(content[:40])
    with pytest.raises(UsageError, match="curves.npz is not a readable .npz file"):
        _npz_arrays(tmp_path / "curves.npz", ["ac_return"], ["ac"])


def _rewrite_results(p, change):
    import pyarrow.parquet as pq

    table = change(pq.read_table(p))
    pq.write_table(table, p)


def _seeds_all_zero(table):
    import pyarrow as pa

    return table.set_column(table.schema.get_field_index("seed"), "seed", pa.array([0] * table.num_rows))


def _seed_column(values):
    def change(table):
        import pyarrow as pa

        n = table.num_rows
        return table.set_column(table.schema.get_field_index("seed"), "seed", pa.array(values(n)))
    return change


def _sequential(seq):
    return lambda p, s: p.write_text(json.dumps({**s, "sequential": seq}))


MORE_DAMAGES = {  # found by a hostile-input campaign on the streaming and sequential build
    "summary nested too deeply": ("summary.json", lambda p, s: p.write_text("[" * 200_000)),
    "trials disagree with results": ("summary.json",
                                     lambda p, s: p.write_text(json.dumps({**s, "trials": 8}))),
    "seeds not distinct": ("results.parquet", lambda p, s: _rewrite_results(p, _seeds_all_zero)),
    "sequential garbage": ("summary.json", _sequential("garbage")),
    "sequential missing looks": ("summary.json", _sequential({"x": 1})),
    "sequential looks of text": ("summary.json", _sequential({"looks_taken": "abc"})),
    "seeds missing": ("results.parquet",
                      lambda p, s: _rewrite_results(p, _seed_column(lambda n: [None] * n))),
    "seeds of text": ("results.parquet", lambda p, s: _rewrite_results(  # was a TypeError traceback
        p, _seed_column(lambda n: [str(i % (n // 2)) for i in range(n)]))),
    "seeds fractional": ("results.parquet", lambda p, s: _rewrite_results(
        p, _seed_column(lambda n: [i % (n // 2) + 0.5 for i in range(n)]))),
    "seeds negative": ("results.parquet", lambda p, s: _rewrite_results(
        p, _seed_column(lambda n: [i % (n // 2) - n for i in range(n)]))),
    "trials metadata of control bytes": ("results.parquet", lambda p, s: _rewrite_results(  # six lines
        p, lambda t: t.replace_schema_metadata({**t.schema.metadata, b"jaxeac.trials": bytes(range(256))}))),
    "trials 1e308": ("summary.json", lambda p, s: p.write_text(json.dumps({**s, "trials": 1e308}))),
}


@pytest.mark.parametrize("damage", sorted(DAMAGES) + sorted(MORE_DAMAGES))
def test_compare_refuses_damaged_run_folders(grid_run, tmp_path, capsys, damage):
    run = tmp_path / "run"
    shutil.copytree(grid_run, run)
    name, spoil = {**DAMAGES, **MORE_DAMAGES}[damage]
    spoil(run / name, summary_of(grid_run))
    names = (name, "curves.npz") if damage in DAMAGES else (name,)
    assert_refused(["compare", str(run), "--resamples", "200"], run, capsys, names)


@pytest.mark.parametrize("damage", ["curves truncated", "curves zeros", "per_seed binary",
                                    "return not a number", "seed NaN", "seed 1e308", "seed inf"])
def test_compare_refuses_damaged_bowling_style_folders(tmp_path, capsys, rng, damage):
    """Folders of curves.npz and per_seed.csv (bowling, older grid runs): damaged files are one line."""
    import numpy as np

    success = {a: rng.random((6, 4)) < 0.5 for a in ("ac", "eac")}
    returns = {f"{a}_return": rng.integers(0, 11, (6, 4)) for a in success}
    np.savez(tmp_path / "curves.npz", **success, **returns)
    rows = ["algo,seed,return,successes,first_success"]
    for a, s in success.items():
        first = np.where(s.any(1), s.argmax(1) + 1, -1)
        rows += [f"{a},{i},{returns[f'{a}_return'][i].sum()},{s[i].sum()},{first[i]}" for i in range(6)]
    (tmp_path / "per_seed.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "summary.json").write_text(json.dumps({"experiment": "bowling", "primary_measure": "return",
                                                       "algos": ["ac", "eac"], "trials": 4}))
    assert main(["compare", str(tmp_path), "--resamples", "200"]) == 0  # the intact folder compares
    curves, csv = tmp_path / "curves.npz", tmp_path / "per_seed.csv"
    if damage == "curves truncated":
        curves.write_bytes(curves.read_bytes()[:50])
    elif damage == "curves zeros":
        curves.write_bytes(bytes(len(curves.read_bytes())))
    elif damage == "per_seed binary":
        csv.write_bytes(bytes(range(256)) * 4)
    elif damage.startswith("seed "):  # was read, and the seeds then differed: silently unpaired
        csv.write_text(csv.read_text().replace("\neac,3,", f"\neac,{damage[5:]},", 1))
    else:
        csv.write_text(csv.read_text().replace("ac,0,", "ac,0,lots", 1))
    assert_refused(["compare", str(tmp_path), "--resamples", "200"], tmp_path, capsys,
                   ("curves.npz" if "curves" in damage else "per_seed.csv",))


def test_aggregate_only_with_a_table(grid_run, capsys):
    assert_refused(["compare", str(grid_run), "--aggregate", "mean"], grid_run, capsys, ("--aggregate",))


@pytest.mark.parametrize("kind", ["datetime", "complex"])
def test_table_values_must_be_real_numbers(tmp_path, capsys, kind):
    import numpy as np

    if kind == "datetime":
        import pandas as pd

        path = tmp_path / "t.parquet"
        pd.DataFrame({"algo": ["a", "a", "b", "b"], "seed": [0, 1, 0, 1],
                      "value": pd.to_datetime(["2024-01-01"] * 4)}).to_parquet(path)
    else:
        path = tmp_path / "t.npz"
        np.savez(path, a=np.ones((3, 2), complex), b=np.ones((3, 2), complex))
    assert_refused(["compare", "--table", str(path)], tmp_path, capsys, (path.name,))


@pytest.mark.parametrize("kind", ["csv 1e308", "csv -1e200", "parquet 1e308", "npz 1e308", "sums beyond",
                                  "tiny spread", "monitor 1e308"])
def test_table_values_the_statistics_cannot_take(tmp_path, capsys, kind):
    """Huge values overflowed (NaN intervals, RuntimeWarnings) and values differing by ~1e-300 gave
    a zero-width interval with p < 1e-16: refused, naming the file (and the column where it is one)."""
    import numpy as np
    import pandas as pd

    values = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]
    frame = pd.DataFrame({"algo": ["a"] * 4 + ["b"] * 4, "seed": [0, 1, 2, 3] * 2, "value": values})
    if kind in ("csv 1e308", "parquet 1e308"):
        frame.loc[2, "value"] = 1e308
    elif kind == "csv -1e200":
        frame.loc[5, "value"] = -1e200
    elif kind == "tiny spread":
        frame["value"] = np.array(values) * 1e-300
    path = tmp_path / ("t.parquet" if kind.startswith("parquet") else "t.csv")
    if kind == "sums beyond":  # every row within the bound, a seed's sum over trials beyond it
        frame = pd.DataFrame({"algo": ["a"] * 4 + ["b"] * 4, "seed": [0, 0, 1, 1] * 2, "trial": [0, 1] * 4,
                              "value": [9e14, 9e14, 1, 1, 1, 2, 3, 4]})
    if kind == "npz 1e308":
        path = tmp_path / "t.npz"
        np.savez(path, a=np.array([[1.0], [2.0], [1e308]]), b=np.ones((3, 1)))
    elif kind == "monitor 1e308":
        path = tmp_path / "sb3"
        for algo in ("a", "b"):
            for seed in range(2):
                folder = path / algo / str(seed)
                folder.mkdir(parents=True)
                r = "1e308" if (algo, seed) == ("a", 1) else str(seed + 1)
                (folder / "monitor.csv").write_text(f'#{{"t_start": 0}}\nr,l,t\n{r},10,0.1\n')
    elif kind.startswith("parquet"):
        frame.to_parquet(path)
    else:
        frame.to_csv(path, index=False)
    names = ("monitor.csv",) if kind.startswith("monitor") else (path.name,)
    assert_refused(["compare", "--table", str(path), "--resamples", "200"], tmp_path, capsys, names)


def test_a_damaged_folder_waits_for_the_device_start(grid_run, tmp_path, monkeypatch):
    """compare starts the device on a thread while it reads the folder; a damaged folder ends the
    command at once, and exiting while that thread is inside JAX's start-up aborted the
    interpreter ("terminate called ...", exit -6) after the error line: the thread is joined."""
    from jaxeac.stats import run as stats_run

    class Starter:
        joined = False

        def join(self):
            Starter.joined = True

    monkeypatch.setattr(stats_run, "start_device", lambda: Starter())
    run = tmp_path / "run"
    shutil.copytree(grid_run, run)
    (run / "results.parquet").write_bytes(b"")
    with pytest.raises(UsageError, match="results.parquet"):
        stats_run.compare_run_dir(run, resamples=200, progress=False)
    assert Starter.joined


def _edit_summary(part, **fields):
    path = part / "summary.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), **fields}))


def _edit_results(part, name, fill):
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pq.read_table(part / "results.parquet")
    width = table.schema.field(name).type.list_size
    dtype = table.schema.field(name).type.value_type.to_pandas_dtype()
    values = pa.array(np.full(table.num_rows * width, fill, dtype))
    column = pa.FixedSizeListArray.from_arrays(values, width)
    table = table.set_column(table.schema.get_field_index(name), name, column)
    pq.write_table(table, part / "results.parquet")


@pytest.mark.parametrize("damage", ["per_algo list", "timing text", "seeds 2^70", "map of another size",
                                    "policy not an action", "negative steps"])
def test_merge_refuses_damage_found_by_the_campaign(parts_run, tmp_path, capsys, damage):
    """Tracebacks (AttributeError, ValueError, ArrowTypeError) or parts merged as they were."""
    run = tmp_path / "run"
    shutil.copytree(parts_run, run)
    parts = sorted(run.glob("part-*"))
    config = summary_of(parts[0])["config"]
    if damage == "per_algo list":
        _edit_summary(parts[1], per_algo=[1])
    elif damage == "timing text":
        _edit_summary(parts[1], per_algo={"ac": {"compile_seconds": "abc"}, "eac": {}})
    elif damage in ("seeds 2^70", "map of another size"):
        for part in parts:
            _edit_summary(part, config={**config, **({"seeds": 2**70} if damage == "seeds 2^70" else
                                                      {"map": "..G\n"})})
    else:
        change = ("policy", 100) if damage == "policy not an action" else ("trial_steps", -3)
        _edit_results(parts[1], *change)
    assert_refused(["merge", str(run), "--no-compare"], run, capsys,
                   ("summary.json", "results.parquet", "seeds"))


@pytest.mark.parametrize("damage", ["part of NaN", "part of another shape", "parts a file"])
def test_resumed_sweep_refuses_damage_found_by_the_campaign(sweep_run, tmp_path, capsys, damage):
    import numpy as np

    out = tmp_path / "s"
    shutil.copytree(sweep_run, out)
    (out / "results.csv").unlink()
    part = sorted((out / "parts").glob("*.npz"))[0]
    if damage == "parts a file":
        shutil.rmtree(out / "parts")
        (out / "parts").write_text("x")
    else:
        with np.load(part) as npz:
            arrays = dict(npz)
        arrays = ({k: v.astype(float) * np.nan for k, v in arrays.items()} if damage == "part of NaN"
                  else {k: v[None] for k, v in arrays.items()})
        np.savez(part, **arrays)
    assert_refused(["sweep", *SMALL, "--set", "alpha=0.1,0.2", "--out", str(out)], out, capsys,
                   ("parts", part.name))
