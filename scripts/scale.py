"""Scale-out evidence (SPEC R1, §5): seeds over 1 and all local devices — time, scaling, identity.

For AC and EAC on the paper preset: the run of N seeds on all local devices and on
one device (compile timed apart), the scaling efficiency t₁ / (n · tₙ), and a check
that the per-seed results of the first K seeds are bit-identical on 1 and n devices.

``--timeline`` instead records where a run's time goes, per chunk and per device: when each
chunk was dispatched, ready on its device, copied to the host and collected, for the kernel
alone (host arrays, as bench.py) and for the `jaxeac run` command's run phase (results
streamed to results.parquet, `--mode command`); it prints, per device, kernel seconds and idle
gaps, and per run the host's copy and collect seconds. It reads the jaxeac on PYTHONPATH,
so an older build is timed too (its chunks spanning every device: ready times per shard).

    python scripts/scale.py --seeds 1000000 --chunk 1000000 --subset 100000 --out scale.json
    python scripts/scale.py --timeline --seeds 4194304 --mode kernel command --out timeline.json

``--commands`` times the `jaxeac grid` command itself, each run in a fresh process, for source
trees taking turns and sets of visible GPUs: wall seconds, its summary's compile and run seconds,
the report's, and digests of its results.parquet's bytes and of its rows (equal rows: the same
per-seed results, whatever the row groups);
``--cold N`` runs each first with an empty compilation cache, then warm.

    python scripts/scale.py --commands --builds OLD NEW --visible 0 0,1 --seeds-list 4194304 8388608
    python scripts/scale.py --commands --cold 1000000 --report on --visible 0

``--record`` makes the whole scaling record of the command in one call (`scaling_record`): one and
two GPUs at each seed count with and without the report, the per-device timelines, the multi-host
recipe against one process, the 10^6-seed command cold and warm with where its seconds go, and
bench.py on one and two GPUs; `bench.py --render` turns it into tables.

    python scripts/scale.py --record --builds OLD NEW --seeds-list 4194304 8388608 --out record.json

(Over 400 lines: the scaling evidence of both the kernel and the command, each with its record.)
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from jaxeac.runtime import configure

configure("grid", start_jax=False)  # before JAX starts, as `jaxeac` does

import jax  # noqa: E402


def _paper(algo: str):
    from jaxeac.algorithm.config import algorithm
    from jaxeac.envs.grid import GridWorld, get_map
    from jaxeac.running.config import RunConfig

    return GridWorld(get_map("paper"), 40), RunConfig(trials=200, agent=algorithm(algo), alpha=0.1, beta=0.3,
                                                      gamma=0.9)


def scaling(args) -> dict:
    """One device against all local devices, with the per-seed check (the default)."""
    from jaxeac.running.batch import run_seeds

    devices = jax.local_devices()
    rows = []
    for algo in args.algos:
        env, cfg = _paper(algo)
        row = {"algo": algo, "seeds": args.seeds, "chunk": args.chunk, "devices": len(devices)}
        for label, devs in [("all", devices)] + ([("one", devices[:1])] if args.single else []):
            first = run_seeds(env, cfg, root_key=0, n_seeds=args.seeds, chunk_size=args.chunk, devices=devs)
            r = run_seeds(env, cfg, root_key=0, n_seeds=args.seeds, chunk_size=args.chunk, devices=devs)
            row[f"{label}_first_run_s"] = first.run_seconds  # includes CUDA-graph capture on GPUs
            row[f"{label}_compile_s"] = first.compile_seconds
            row[f"{label}_run_s"] = r.run_seconds
            row[f"{label}_steps_per_s"] = r.agent_steps / r.run_seconds
            row["mean_successes"] = float(r.successes.mean())
        if args.single and len(devices) > 1:
            row["scaling_efficiency"] = row["one_run_s"] / (len(devices) * row["all_run_s"])
        k = min(args.subset, args.seeds)
        one = run_seeds(env, cfg, root_key=0, n_seeds=k, chunk_size=k, devices=devices[:1])
        many = run_seeds(env, cfg, root_key=0, n_seeds=k, chunk_size=k, devices=devices)
        row["subset"] = k
        row["subset_identical"] = bool(all(np.array_equal(getattr(one, f), getattr(many, f))
                                           for f in ("success", "steps", "policy")))
        print(json.dumps(row), flush=True)
        rows.append(row)
    return {"rows": rows}


class _Recorder:
    """Chunk events of a build without `record_timeline` (chunks split over every device with
    `shard_map`): its dispatches and collections wrapped, each shard's ready time from a thread."""

    def __init__(self, batch):
        self.events: list[dict] = []
        self.lock = threading.Lock()
        entries = batch._Entries
        dispatch, collect = entries.dispatch, entries.collect
        recorder = self

        def timed_dispatch(job, start):
            t = time.perf_counter()
            got = dispatch(job, start)
            out = got[2]
            for i, shard in enumerate(out.log.addressable_shards):
                threading.Thread(target=recorder._wait, args=(job, start, i, shard.data, t), daemon=True).start()
            return got

        def timed_collect(job, start, size, out, pool, progress):
            t = time.perf_counter()
            collect(job, start, size, out, pool, progress)
            recorder._add({"event": "collect", "job": str(id(job)), "start": start, "size": size, "collect": t,
                           "collected": time.perf_counter()})

        entries.dispatch, entries.collect = timed_dispatch, timed_collect

    def _wait(self, job, start, group, data, dispatched):
        data.block_until_ready()
        self._add({"event": "shard", "job": str(id(job)), "start": start, "group": group, "dispatch": dispatched,
                   "ready": time.perf_counter()})

    def _add(self, event):
        with self.lock:
            self.events.append(event)


def _merged(events: list[dict]) -> list[dict]:
    """An older build's shard and collect events as chunk events (one per shard)."""
    collects = {(e["job"], e["start"]): e for e in events if e["event"] == "collect"}
    last = {}  # the chunk's last shard: its collection waits for every shard
    for e in events:
        if e["event"] == "shard":
            key = (e["job"], e["start"])
            last[key] = max(last.get(key, 0.0), e["ready"])
    out = []
    for e in events:
        if e["event"] == "shard":
            key = (e["job"], e["start"])
            c = collects.get(key, {})
            begin = max(c.get("collect", e["ready"]), last[key])
            out.append({**e, "event": "chunk", "size": c.get("size", 0), "fetched": begin, "collect": begin,
                        "collected": c.get("collected", begin)})
    return out


def summarize(chunks: list[dict]) -> dict:
    """Per device group: chunks, kernel seconds (ready − the later of its dispatch and the group's
    previous ready), idle seconds between its chunks; per run: wall, the host's copy and collect
    seconds, and the seconds the last chunk's collection took after the devices were done."""
    if not chunks:
        return {}
    t0 = min(c["dispatch"] for c in chunks)
    end = max(c["collected"] for c in chunks)
    groups = {}
    for g in sorted({c["group"] for c in chunks}):
        mine = sorted((c for c in chunks if c["group"] == g), key=lambda c: c["ready"])
        busy, prev = 0.0, t0
        for c in mine:
            busy += c["ready"] - max(c["dispatch"], prev)
            prev = c["ready"]
        groups[str(g)] = {"chunks": len(mine), "kernel_s": busy, "idle_s": max(c["ready"] for c in mine) - t0 - busy,
                          "done_s": max(c["ready"] for c in mine) - t0}
    collects = {(c["job"], c["start"]): c for c in chunks}.values()  # one per chunk, whichever shard
    return {"wall_s": end - t0, "devices": groups,
            "copy_s": sum(c["fetched"] - c["ready"] for c in chunks),
            "prepare_s": sum(c.get("prepared", c["fetched"]) - c["fetched"] for c in chunks),
            "collect_s": sum(c["collected"] - c["collect"] for c in collects),
            "tail_s": end - max(c["ready"] for c in chunks)}


def dispatches(events: list[dict]) -> dict:
    """Per device group, the host's seconds in each step of its dispatches (a build that records
    them): chunk inputs, their copy to the device, the program's launch, the copies back queued."""
    out: dict = {}
    for e in events:
        if e["event"] == "dispatch":
            zero = {"chunks": 0, "inputs_s": 0.0, "put_s": 0.0, "launch_s": 0.0, "copy_s": 0.0}
            mine = out.setdefault(str(e["group"]), zero)
            mine["chunks"] += 1
            for k in ("inputs_s", "put_s", "launch_s", "copy_s"):
                mine[k] += e[k]
    return out


def _digest(r) -> str:
    """A hash of every seed's successes, steps and policy: equal digests, identical results."""
    import hashlib

    h = hashlib.blake2b(digest_size=16)
    h.update(np.packbits(r.success, axis=1).tobytes())
    h.update(r.steps.astype(np.uint16).tobytes())
    h.update(r.policy.astype(np.uint8).tobytes())
    return h.hexdigest()


def timeline(args) -> dict:
    """`--timeline`: per mode and algorithm, the second run's chunk events and their summary (and
    the first run's, which compiles: with `--cache`, loads its programs from the compilation cache
    as the `jaxeac` command does)."""
    if args.cache:
        configure("grid")  # every setting of the command, its compilation cache included
    from jaxeac.running import batch

    own = hasattr(batch, "record_timeline")
    recorder = None if own else _Recorder(batch)
    runs, digests = [], {}

    def record(mode: str, algo: str, go) -> None:
        t = time.perf_counter()
        with batch.record_timeline() if own else contextlib.nullcontext([]) as first:
            go()  # compiles, and captures the CUDA graphs: not timed
        first_chunks = [e for e in first if e["event"] == "chunk"]
        first = {"first_call_s": time.perf_counter() - t,
                 "first_compiles": [e for e in first if e["event"] in ("compile", "lowered")],
                 "first": summarize(first_chunks), "first_chunks": first_chunks,
                 "first_dispatches": [e for e in first if e["event"] == "dispatch"]}
        t = time.perf_counter()
        if own:
            with batch.record_timeline() as events:
                got = go()
            chunks = [e for e in events if e["event"] == "chunk"]
            extra = {"dispatch": dispatches(events),
                     "compiles": [e for e in events if e["event"] in ("compile", "lowered")],
                     "dispatches": [e for e in events if e["event"] == "dispatch"]}
        else:
            extra = {}
            recorder.events.clear()
            got = go()
            chunks = _merged(recorder.events)
        wall = time.perf_counter() - t
        if mode == "kernel":
            digests[algo] = _digest(got)
        row = {"mode": mode, "algo": algo, "seeds": args.seeds, "devices": len(jax.local_devices()),
               "call_s": wall, **summarize(chunks), **extra, **first, "digest": digests.get(algo),
               "chunks": chunks}
        print(json.dumps({k: v for k, v in row.items() if k != "chunks"}), flush=True)
        runs.append(row)

    for mode in args.mode:
        if mode == "kernel":
            from jaxeac.running.batch import run_seeds

            for algo in args.algos:
                env, cfg = _paper(algo)
                record(mode, algo, lambda env=env, cfg=cfg: run_seeds(env, cfg, root_key=0, n_seeds=args.seeds,
                                                                     chunk_size=args.chunk))
        else:
            from jaxeac.experiments import grid
            from jaxeac.experiments.grid import GridSettings, run_grid_to_folder

            if args.diagnose == "start" and hasattr(grid, "DIAGNOSE_ONCE_DISPATCHED"):
                grid.DIAGNOSE_ONCE_DISPATCHED = {}

            settings = GridSettings(seeds=args.seeds, algos=tuple(args.algos), chunk_size=args.chunk).resolved()
            with tempfile.TemporaryDirectory() as tmp:
                record(mode, "+".join(args.algos), lambda: run_grid_to_folder(settings, Path(tmp) / "run"))
    return {"rows": runs, "build": "record_timeline" if own else "wrapped"}


def _file_digest(path: Path) -> str:
    import hashlib

    h = hashlib.blake2b(digest_size=16)
    with open(path, "rb") as f:
        while block := f.read(1 << 24):
            h.update(block)
    return h.hexdigest()


def _rows_digest(path: Path) -> str:
    """A hash of results.parquet's rows, column by column, whatever its row groups (a run cut into
    other chunks writes other row groups: other bytes, the same rows)."""
    import hashlib

    import pyarrow.parquet as pq

    h = hashlib.blake2b(digest_size=16)
    table = pq.read_table(path)
    for name in table.column_names:
        h.update(name.encode())
        column = table.column(name).combine_chunks()
        if name == "algo":
            column = column.cast("string")
        for buffer in column.buffers():
            if buffer is not None:
                h.update(buffer)
    return h.hexdigest()


def _build_env(build: Path | None, visible: str, cache: str, tmp: Path, extra: dict | None = None) -> dict:
    """The environment of a fresh process of `build` (first on PYTHONPATH) on GPUs `visible`."""
    import os

    name = build.name if build else "installed"
    extra = dict(extra or {})
    if "XLA_FLAGS" in extra:  # after the flags this process was started with
        extra["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {extra['XLA_FLAGS']}".strip()
    env = dict(os.environ, CUDA_VISIBLE_DEVICES=visible, **extra)
    if build:
        paths = [str(build.resolve()), *filter(None, [os.environ.get("PYTHONPATH")])]
        env["PYTHONPATH"] = os.pathsep.join(paths)
    if cache != "shared":
        env["JAXEAC_COMPILATION_CACHE"] = str(tmp / f"cache-{name}-{visible}")
    return env


#: Seconds a command of `--commands` / `--record` may take before it is stopped and recorded as such.
COMMAND_TIMEOUT = 180


def _phases(launched: float, ended: float, out: Path, summary: dict) -> dict:
    """Where a command's wall seconds went (a build whose summary.json has a ``timeline``): process
    start to the run's start (imports, JAX's start, settings), the run (compile and chunks), the
    summary's statistics and the figures, E8's counts still running after them, the rest of the
    folder (E8's blocks, summary.json), the report after the folder (stats.json, report.md), and
    the process's exit (results.parquet's last rows, the folder's move, the end of the process)."""
    tl = summary.get("timeline")
    if not tl:
        return {}
    folder = (out / "summary.json").stat().st_mtime
    stats = out / "stats.json"
    report = max(folder, (out / "report.md").stat().st_mtime if (out / "report.md").is_file() else
                 stats.stat().st_mtime if stats.is_file() else folder)
    drawn = tl.get("figures", tl["results"])  # a build that drew the figures after E8's counts: none
    return {"startup_s": tl["started"] - launched, "run_s": tl["results"] - tl["started"],
            "figures_s": drawn - tl["results"], "diagnostics_wait_s": tl["diagnosed"] - drawn,
            "folder_s": folder - tl["diagnosed"], "report_s": report - folder, "exit_s": ended - report}


def _command(build: Path | None, visible: str, n: int, report: bool, cache: str, tmp: Path,
             extra: dict | None = None) -> dict:
    """One `jaxeac grid` command in a fresh process (see `command_runs`); `extra`: more environment
    variables (e.g. XLA_FLAGS)."""
    import shutil
    import subprocess

    name = build.name if build else "installed"
    env = _build_env(build, visible, cache, tmp, extra)
    out = tmp / "run"
    argv = [sys.executable, "-P", "-m", "jaxeac", "grid", "--preset", "paper", "--seeds", str(n), "--quiet",
            "--out", str(out), *([] if report else ["--no-compare"])]
    t0, launched = time.perf_counter(), time.time()
    try:
        proc = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=COMMAND_TIMEOUT)
    except subprocess.TimeoutExpired as e:
        return {"build": name, "visible": visible, "seeds": n, "report": report, "cache": cache,
                "wall_s": time.perf_counter() - t0, "rc": "timeout", "stderr": str(e.stderr)[-2000:]}
    row = {"build": name, "visible": visible, "seeds": n, "report": report, "cache": cache,
           "wall_s": time.perf_counter() - t0, "rc": proc.returncode, **({"env": extra} if extra else {})}
    ended = time.time()
    if proc.returncode != 0:
        return row | {"stderr": proc.stderr[-2000:]}
    summary = json.loads((out / "summary.json").read_text())
    row["phases"] = _phases(launched, ended, out, summary)
    per_algo = {a: {"compile_s": v["compile_seconds"], "run_s": v["run_seconds"], "settings": v.get("run")}
                for a, v in summary["per_algo"].items()}
    row |= {"compile_s": summary["compile_seconds"], "run_s": summary["run_seconds"], "per_algo": per_algo,
            "results_digest": _file_digest(out / "results.parquet"),
            "rows_digest": _rows_digest(out / "results.parquet")}
    if (out / "stats.json").is_file():
        row["report_timing"] = json.loads((out / "stats.json").read_text()).get("timing")
    shutil.rmtree(out, ignore_errors=True)
    return row


def _parts(build: Path | None, n: int, report: bool, tmp: Path, port: int,
           timeout: float = COMMAND_TIMEOUT) -> dict:
    """The multi-host recipe (docs/USAGE.md, "Several hosts") on one host: two `jaxeac grid`
    processes of one GPU each with a coordinator, then `jaxeac merge`, stopped after `timeout`
    seconds in all; wall seconds of the parts (both done) and of the merge, and the merged
    results' digest."""
    import shutil
    import subprocess

    name = build.name if build else "installed"
    out = tmp / "run"
    procs, t0 = [], time.perf_counter()
    for i in range(2):
        argv = [sys.executable, "-P", "-m", "jaxeac", "grid", "--preset", "paper", "--seeds", str(n),
                "--quiet", "--out", str(out), "--num-processes", "2", "--process-id", str(i),
                "--coordinator", f"localhost:{port}"]
        procs.append(subprocess.Popen(argv, env=_build_env(build, str(i), "shared", tmp),
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    ends, errs = [], []
    for p in procs:
        try:
            _, err = p.communicate(timeout=max(1.0, timeout - (time.perf_counter() - t0)))
        except subprocess.TimeoutExpired:
            p.kill()
            _, err = p.communicate()
        ends.append(time.perf_counter() - t0)
        errs.append(err[-1000:] if p.returncode else "")
    row = {"build": f"{name} 2 processes", "visible": "0,1", "seeds": n, "report": report, "cache": "shared",
           "parts_s": ends, "rc": max(p.returncode for p in procs)}
    if row["rc"]:
        return row | {"wall_s": max(ends), "stderr": errs}
    t1 = time.perf_counter()
    try:
        merge = subprocess.run([sys.executable, "-P", "-m", "jaxeac", "merge", str(out), "--quiet",
                                *([] if report else ["--no-compare"])],
                               env=_build_env(build, "0", "shared", tmp), capture_output=True, text=True,
                               timeout=max(1.0, timeout - (time.perf_counter() - t0)))
    except subprocess.TimeoutExpired:
        return row | {"wall_s": time.perf_counter() - t0, "rc": "timeout (merge)"}
    row |= {"merge_s": time.perf_counter() - t1, "wall_s": time.perf_counter() - t0, "rc": merge.returncode}
    if merge.returncode:
        return row | {"stderr": merge.stderr[-2000:]}
    summary = json.loads((out / "summary.json").read_text())
    row |= {"compile_s": summary["compile_seconds"], "run_s": summary["run_seconds"],
            "per_algo": {a: {"compile_s": v["compile_seconds"], "run_s": v["run_seconds"]}
                         for a, v in summary["per_algo"].items()},
            "rows_digest": _rows_digest(out / "results.parquet")}
    shutil.rmtree(out, ignore_errors=True)
    return row


def command_runs(args) -> dict:
    """`--commands`: the `jaxeac grid` command as a user runs it, in a fresh process each time, for
    every build (`--builds`, source trees put first on PYTHONPATH), set of visible GPUs
    (`--visible`, as CUDA_VISIBLE_DEVICES), seed count and with or without the report (`--report`),
    the builds taking turns; per run its wall seconds, what its summary.json and stats.json say of
    compile, run and report seconds (per algorithm too), and a digest of its results.parquet.
    `--cold` first runs each build and GPU set once with an empty compilation cache of its own
    (what a first run pays), then once more with it warm."""
    record: dict = {"runs": []}
    if args.cold:
        plan = [(n, report, cache) for n in args.cold for report in args.report for cache in ("cold", "warm")]
    else:
        plan = [(n, report, "shared") for n in args.seeds for report in args.report]
    with tempfile.TemporaryDirectory() as tmp:
        for rnd in range(args.rounds):
            for n, report, cache in plan:
                for visible in args.visible:
                    for build in args.builds or [None]:
                        row = {"round": rnd, **_command(build, visible, n, report, cache, Path(tmp))}
                        print(json.dumps({k: v for k, v in row.items() if k != "per_algo"}), flush=True)
                        record["runs"].append(row)
                        if args.out:
                            args.out.write_text(json.dumps(record, indent=2) + "\n")
    return record


def _timeline_run(build: Path | None, visible: str, n: int, tmp: Path, extra: dict | None = None,
                  flags: tuple = ()) -> dict:
    """`--timeline --mode command` of `build` in a fresh process on GPUs `visible`: its row."""
    import subprocess

    out = tmp / "timeline.json"
    argv = [sys.executable, __file__, "--timeline", "--mode", "command", "--cache", "--seeds", str(n),
            "--out", str(out), *flags]
    try:
        proc = subprocess.run(argv, env=_build_env(build, visible, "shared", tmp, extra), capture_output=True,
                              text=True, timeout=COMMAND_TIMEOUT)
    except subprocess.TimeoutExpired:
        return {"visible": visible, "rc": "timeout"}
    if proc.returncode:
        return {"visible": visible, "rc": proc.returncode, "stderr": proc.stderr[-2000:]}
    row = json.loads(out.read_text())["rows"][0]
    return {"build": build.name if build else "installed", "visible": visible,
            **({"env": extra} if extra else {}), **({"flags": list(flags)} if flags else {}), **row}


def scaling_record(args) -> dict:
    """`--record`: the scaling record of the `jaxeac grid` command on one and two GPUs of one host,
    in one call, within `--budget` seconds (a step is skipped once they are spent), the builds
    (`--builds`: old, new) taking turns, each command a fresh process:

    * ``cmd_warmup``: each build once at 2^20 seeds (fills the shared compilation cache);
    * ``timeline``: the newest build's per-device timeline (`--timeline --mode command`) at
      `--seeds` on one and on two GPUs (with `--experiments`, on two GPUs: XLA's command buffers
      off, and CUDA's modules loaded when a program loads rather than at its first launch);
    * ``cmd_main``: `--seeds-list` without the report, on one and two GPUs;
    * ``cmd_hosts``: the multi-host recipe as two processes of one GPU each with a coordinator,
      and `jaxeac merge` (the newest build), against one process with two GPUs, at `--hosts-seeds`
      (each part keeps every trial's steps and policy for the merge: slow to write at 4M seeds);
    * ``cmd_report``: the first seed count with the report;
    * ``cmd_cold``: `--cold` (10^6) seeds with the report on one GPU, a cache of its own empty,
      then warm, with each command's phases (where its seconds go);
    * ``bench``: scripts/bench.py on one and two GPUs (the kernel with host arrays).

    Written to `--out` after every step; `bench.py --render` makes its tables."""
    import os
    import subprocess

    from bench import command_line

    t_start = time.perf_counter()
    builds = args.builds or [None]
    new = builds[-1]
    seeds = args.seeds_list or [args.seeds]
    rec: dict = {"what": "scripts/scale.py --record", "command": command_line(), "environment": {},
                 "runs": {}, "skipped": []}

    def save() -> None:
        rec["wall_s"] = time.perf_counter() - t_start
        if args.out:
            args.out.write_text(json.dumps(rec, indent=2) + "\n")

    def step(name: str, cost: float, work) -> None:
        if name in (args.skip or []) or time.perf_counter() - t_start + cost > args.budget:
            rec["skipped"].append(name)
            print(json.dumps({"skipped": name}), flush=True)
            return save()
        rows = rec["runs"].setdefault(name, [])
        for row in work():
            print(json.dumps({k: v for k, v in row.items() if k not in ("per_algo", "chunks", "first_chunks",
                                                                           "compiles", "first_compiles")}),
                  flush=True)
            rows.append(row)
            save()

    try:  # JAX is not started here: the commands get the GPUs to themselves
        names = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                               capture_output=True, text=True, check=True).stdout.split("\n")
        cards = f"{len([n for n in names if n])}x {names[0]}"
    except (OSError, subprocess.CalledProcessError):
        cards = "no GPU"
    rec["environment"] = {"cards": cards, "cpus": os.cpu_count(), "date": time.strftime("%Y-%m-%d")}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)

        def cmd(build, visible, n, report, cache="shared", extra=None):
            return {"round": 0, **_command(build, visible, n, report, cache, tmp, extra)}

        step("cmd_warmup", 15 * len(builds), lambda: (cmd(b, "0", args.warmup, False) for b in builds))
        big = seeds[0]
        step("timeline", 45, lambda: (_timeline_run(new, v, big, tmp) for v in ("0", "0,1")))
        if args.experiments:  # what the first launch of a program on a GPU waits for
            no_graphs = {"XLA_FLAGS": "--xla_gpu_enable_command_buffer="}
            for extra in (no_graphs, {"CUDA_MODULE_LOADING": "EAGER"}):
                step("timeline", 30, lambda extra=extra: [_timeline_run(new, "0,1", big, tmp, extra=extra)])
        for n in seeds:
            step("cmd_main", 2 * len(builds) * (4 + n / 4e5),
                 lambda n=n: (cmd(b, v, n, False) for v in ("0", "0,1") for b in builds))
        hosts = args.hosts_seeds
        step("cmd_hosts", 30 + hosts / 4e4, lambda: [cmd(new, "0,1", hosts, False),
                                                    {"round": 0, **_parts(new, hosts, False, tmp,
                                                                          12357 + os.getpid() % 1000, 100)}])
        step("cmd_report", 2 * len(builds) * (8 + big / 4e5),
             lambda: (cmd(b, v, big, True) for v in ("0", "0,1") for b in builds))
        cold = (args.cold or [1_000_000])[0]
        step("cmd_cold", 30, lambda: (cmd(new, "0", cold, True, c) for c in ("cold", "warm")))

        def bench():
            for visible, chunk in (("0", 1 << 20), ("0,1", 1 << 21)):
                out = tmp / "bench.json"
                argv = [sys.executable, str(Path(__file__).with_name("bench.py")), "--builds",
                        *map(str, builds), "--rounds", "1", "--seeds", str(big), "--chunk", str(chunk),
                        "--repeats", "2", "--out", str(out)]
                try:
                    proc = subprocess.run(argv, env=_build_env(None, visible, "shared", tmp),
                                          capture_output=True, text=True, timeout=COMMAND_TIMEOUT)
                except subprocess.TimeoutExpired:
                    yield {"visible": visible, "rc": "timeout"}
                    continue
                if proc.returncode:
                    yield {"visible": visible, "rc": proc.returncode, "stderr": proc.stderr[-2000:]}
                    continue
                for row in json.loads(out.read_text())["rows"]:
                    yield {"visible": visible, **row}

        step("bench", 30 * len(builds), bench)
    save()
    return rec


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=1_000_000)
    p.add_argument("--chunk", type=int, default=None, help="seeds per chunk, split over the devices "
                   "(default: automatic, 2^20 per GPU)")
    p.add_argument("--subset", type=int, default=100_000, help="seeds compared across device counts")
    p.add_argument("--single", action="store_true", help="also time the whole run on one device")
    p.add_argument("--algos", nargs="+", choices=["ac", "eac"], default=["ac", "eac"])
    p.add_argument("--timeline", action="store_true",
                   help="record per chunk and device where the time goes (see the description)")
    p.add_argument("--mode", nargs="+", choices=["kernel", "command"], default=["kernel"],
                   help="--timeline: the kernel with host arrays (as bench.py), the command's run phase, "
                        "or both")
    p.add_argument("--diagnose", choices=["start", "drained"], default="drained",
                   help="--timeline --mode command: E8's counts start with the run, or once every chunk is "
                        "handed out (the default of a build that has it)")
    p.add_argument("--cache", action="store_true",
                   help="--timeline: JAX's persistent compilation cache on, as the `jaxeac` command has it")
    p.add_argument("--record", action="store_true",
                   help="the whole scaling record in one call (see `scaling_record`)")
    p.add_argument("--budget", type=float, default=540.0,
                   help="--record: seconds; a step that would start later is skipped")
    p.add_argument("--skip", nargs="+", metavar="STEP", help="--record: steps left out (e.g. bench)")
    p.add_argument("--hosts-seeds", dest="hosts_seeds", type=int, default=1 << 20,
                   help="--record: seeds of the multi-host recipe's runs")
    p.add_argument("--warmup", type=int, default=1 << 20, help="--record: seeds of the warm-up commands")
    p.add_argument("--experiments", action="store_true",
                   help="--record: also two-GPU timelines with XLA's command buffers off and with CUDA's "
                        "modules loaded eagerly")
    p.add_argument("--commands", action="store_true",
                   help="time the `jaxeac grid` command in fresh processes (see `command_runs`)")
    p.add_argument("--builds", type=Path, nargs="+", metavar="DIR",
                   help="--commands: source trees to compare")
    p.add_argument("--visible", nargs="+", default=["0"], metavar="IDS",
                   help="--commands: CUDA_VISIBLE_DEVICES of each run, e.g. 0 0,1")
    p.add_argument("--seeds-list", dest="seeds_list", type=int, nargs="+", metavar="N",
                   help="--commands: seed counts (default --seeds)")
    p.add_argument("--report", type=lambda v: v == "on", nargs="+", default=[False], metavar="on|off",
                   help="--commands: with the statistics report (on) or --no-compare (off)")
    p.add_argument("--cold", type=int, nargs="+", metavar="N",
                   help="--commands: instead, each seed count with an empty compilation cache, then warm")
    p.add_argument("--rounds", type=int, default=1, help="--commands: rounds of the builds taking turns")
    p.add_argument("--out", type=Path)
    args = p.parse_args()
    if args.record:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        scaling_record(args)
        return
    if args.commands:
        args.seeds = args.seeds_list or [args.seeds]
        rec = command_runs(args)
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from bench import command_line

        rec |= {"command": command_line()}
        if args.out:
            args.out.write_text(json.dumps(rec, indent=2) + "\n")
        return

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench import command_line, environment

    record = {"environment": environment(), "command": command_line(),
              **(timeline(args) if args.timeline else scaling(args))}
    if args.out:
        args.out.write_text(json.dumps(record, indent=2) + "\n")


if __name__ == "__main__":
    main()
