"""The runs of a tuning (`jaxeac.experiments.tune`): every algorithm × task over its grid on the
tuning seeds, then at its selections on the evaluation seeds, each kept under the study's ``tune/``
(one npz per algorithm × task, written atomically, reused by a rerun with the same settings).

Both reuse what the study compiled: a task's evaluation runs are its algorithms' plain runs (the
preset's config, the selection's rates as inputs: `_evaluate`), one pipeline per task; tuning runs
take the study's chunk where a compile costs more than the padding (`SHARES_THE_STUDY_PROGRAM`),
and on accelerators several run at once (`TUNING_WORKERS`).
"""

from __future__ import annotations

import dataclasses
import io
import json
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from jaxeac.algorithm.config import Hyper
from jaxeac.experiments.common import plain_json

RATES = ("alpha", "beta", "gamma", "temperature", "epsilon")

#: Per platform, whether tuning runs take the study's chunk (`study_chunk`), padded, so that the
#: study's compiled programs serve them: on CPUs a compile costs more than the padding's runs.
SHARES_THE_STUDY_PROGRAM = {"cpu": True}
#: Per platform, algorithm × task tuning runs at once: on accelerators their compiles and host
#: work overlap the device's runs; on CPUs compiles and runs share the cores, one at a time.
TUNING_WORKERS = {"gpu": 8, "tpu": 8}


def _hyper(grid, points: list[dict], algo: str, per_point: int) -> Hyper:
    """Per-entry traced rates: each point's (the preset's where it leaves a key out), `per_point` times."""
    hypers = [dataclasses.replace(grid, **p).run_config(algo).hyper() for p in points]
    return Hyper(*(jnp.repeat(jnp.stack([getattr(h, r) for h in hypers]), per_point) for r in RATES))


def _run(env, grid, algo: str, points: list[dict], *, key: int, seeds: int, chunk_size,
         share: int | None = None) -> np.ndarray:
    """int32 [len(points), seeds]: successes per seed of `algo` at each point, one program for all.
    `share`: the study's chunk (`study_chunk`); the entries are padded (copies of the last, dropped)
    to a multiple of it where that adds at most half as many, so the study's program serves them."""
    from jaxeac.running.batch import run_entries

    ids = np.tile(np.arange(seeds), len(points))
    hyper = _hyper(grid, points, algo, seeds)
    n = ids.size
    if share and (m := -(-n // share) * share) <= n + n // 2:
        ids = np.pad(ids, (0, m - n), mode="edge")
        leaves = (getattr(hyper, r) for r in RATES)
        hyper = Hyper(*(jnp.concatenate([x, jnp.repeat(x[-1:], m - n)]) for x in leaves))
        chunk_size = share
    res, _, _ = run_entries(env, grid.run_config(algo), root_key=key, seeds=ids, hyper=hyper,
                            chunk_size=chunk_size)
    return np.asarray(res.success, bool)[:n].sum(axis=1).astype(np.int32).reshape(len(points), seeds)


def _evaluate(env, grid, jobs: list[tuple[str, dict]], *, key: int, seeds: int,
              chunk_size) -> list[np.ndarray]:
    """int32 [seeds] per job (algorithm, point): seeds 0 … seeds − 1 at that point, all jobs of a
    task as one pipeline (`run_algorithms`) with the preset's config and the point's rates as
    inputs: the study's own compiled programs, so nothing compiles; per seed a plain run's result."""
    from jaxeac.running.batch import run_algorithms
    from jaxeac.running.outputs import CompactCollector

    if not jobs:
        return []
    ids = np.arange(seeds, dtype=np.int64)
    collectors = [CompactCollector(ids, grid.trials, env.n_states, n_chances=env.n_chances,
                                   whole_chunks=False) for _ in jobs]
    runs = run_algorithms(env, [grid.run_config(a) for a, _ in jobs], root_key=key, n_seeds=seeds,
                          chunk_size=chunk_size, collectors=collectors,
                          hypers=[dataclasses.replace(grid, **p).run_config(a).hyper() for a, p in jobs])
    return [np.asarray(r.successes, np.int32) for r in runs]


def _is_preset(grid, algo: str, point: dict) -> bool:
    """Whether `point` gives `algo` the preset's rates (its run is then the study's own)."""
    at, preset = dataclasses.replace(grid, **point).run_config(algo).hyper(), grid.run_config(algo).hyper()
    return all(np.array_equal(np.asarray(getattr(at, r)), np.asarray(getattr(preset, r))) for r in RATES)


def study_chunk(env, grid, algo: str, seeds: int, chunk_size) -> int | None:
    """The chunk the study's runs of `seeds` seeds take (`jaxeac.running.batch`'s plan), where the
    tuning shares the study's programs (`SHARES_THE_STUDY_PROGRAM`), else None."""
    import jax

    from jaxeac.running.batch import even_chunk
    from jaxeac.running.config import auto_chunk_size

    devices = jax.local_devices()
    if not SHARES_THE_STUDY_PROGRAM.get(devices[0].platform, False):
        return None
    size = chunk_size or auto_chunk_size(env, grid.run_config(algo), seeds, devices)
    return even_chunk(seeds, size, len(devices))


def _load(path: Path | None, config: dict) -> np.ndarray | None:
    """The array kept at `path` if it was computed with `config` (else None: absent, other, damaged)."""
    if path is not None and path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                if json.loads(str(z["config"])) == plain_json(config):
                    return z["successes"]
        except (OSError, ValueError, KeyError):
            pass  # damaged: computed again and replaced
    return None


def _save(path: Path | None, config: dict, x: np.ndarray) -> None:
    """`x` and its config at `path`, atomically (npz): a killed run leaves the whole file or none."""
    if path is None:
        return
    from jaxeac.io import atomic_write_bytes

    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    np.savez(buf, successes=x, config=np.array(json.dumps(plain_json(config))))
    atomic_write_bytes(path, buf.getvalue())


def _cached(path: Path | None, config: dict, compute) -> tuple[np.ndarray, bool]:
    """`compute()` or, where `path` holds an array computed with the same `config`, that array;
    (array, reused); a computed one is kept at `path` (`_save`)."""
    if (x := _load(path, config)) is not None:
        return x, True
    x = compute()
    _save(path, config, x)
    return x, False


def _task_config(grid) -> dict:
    """What a task's runs depend on, beside the algorithm, the settings, the key and the seeds."""
    skip = {"algos", "seeds", "key", "chunk_size", "lanes"}
    return {f.name: getattr(grid, f.name) for f in dataclasses.fields(grid) if f.name not in skip}


class TuningRuns:
    """A tuning's runs for a study (`settings`, its `grids` and `envs` per task), kept in `store`."""

    def __init__(self, settings, tuning, grids: dict, envs: dict, store: Path | None, progress: bool):
        self.settings, self.tuning, self.grids, self.envs = settings, tuning, grids, envs
        self.store, self.progress = store, progress
        self.tasks, self.algos = list(grids), list(settings.algos)

    def path(self, t: str, a: str, name: str) -> Path | None:
        # the task's folder as the study names it under tasks/ (`study.folder_name`)
        return None if self.store is None else self.store / t.replace(":slip=", "-slip") / f"{a}.{name}.npz"

    def config(self, t: str, a: str, pts: list, key: int, seeds: int) -> dict:
        return {"task": _task_config(self.grids[t]), "algo": a, "points": pts, "key": key, "seeds": seeds}

    def say(self, t: str, a: str, what: str, where: Path | None = None) -> None:
        if self.progress:
            print(f"tune: {t}, {a}: {what}" + (f" (done earlier, reusing {where})" if where else ""),
                  file=sys.stderr, flush=True)

    def _tune_one(self, t: str, a: str) -> np.ndarray:
        tuning, s = self.tuning, self.settings
        pts, where = tuning.points(a), self.path(t, a, "tuning")
        share = study_chunk(self.envs[t], self.grids[t], a, s.seeds, s.chunk_size)
        x, reused = _cached(where, self.config(t, a, pts, tuning.key, tuning.seeds),
                            lambda: _run(self.envs[t], self.grids[t], a, pts, key=tuning.key,
                                         seeds=tuning.seeds, chunk_size=s.chunk_size, share=share))
        self.say(t, a, f"{len(pts)} settings x {tuning.seeds:,} tuning seeds", where if reused else None)
        return x

    def tune(self) -> dict:
        """{algo: {task: int32 [points, tuning seeds]}}: successes per tuning seed at each point."""
        import jax

        scores: dict = {a: {} for a in self.algos}
        pairs = [(t, a) for t in self.tasks for a in self.algos]
        with ThreadPoolExecutor(max_workers=TUNING_WORKERS.get(jax.default_backend(), 1)) as pool:
            for (t, a), x in zip(pairs, pool.map(lambda p: self._tune_one(*p), pairs), strict=True):
                scores[a][t] = x
        return scores

    def evaluate(self, per_algo: dict, preset: dict | None = None) -> dict:
        """{"per_task" | "cross_task": {task: {algo: int32 [N]}}}: the evaluation seeds at each
        algorithm's selections (`per_algo[a]`: its points, ``per_task`` and ``cross_task`` indices).
        A selection at the preset's rates is the study's own run: its successes `preset[task][algo]`."""
        n = self.settings.seeds
        samples: dict = {c: {t: {} for t in self.tasks} for c in ("per_task", "cross_task")}
        what = f"evaluating at its selections on {n:,} seeds"
        for t in self.tasks:
            both, want = {}, {}
            for a in self.algos:
                sel = per_algo[a]
                pts = [sel["points"][sel["per_task"][t]], sel["points"][sel["cross_task"]]]
                pts = pts[:1] if pts[0] == pts[1] else pts  # one selection for both: run once
                if (x := _load(self.path(t, a, "evaluation"), self.config(t, a, pts, self.settings.key, n))
                        ) is not None:
                    both[a] = x
                    self.say(t, a, what, self.path(t, a, "evaluation"))
                else:
                    want[a] = pts
            if want:
                jobs = [(a, p) for a, pts in want.items() for p in pts]
                known = {j: np.asarray(preset[t][a], np.int32) for j, (a, p) in enumerate(jobs)
                         if preset is not None and _is_preset(self.grids[t], a, p)}
                left = [j for i, j in enumerate(jobs) if i not in known]
                ran = iter(_evaluate(self.envs[t], self.grids[t], left, key=self.settings.key, seeds=n,
                                     chunk_size=self.settings.chunk_size))
                got = iter([known[i] if i in known else next(ran) for i in range(len(jobs))])
                for a, pts in want.items():
                    both[a] = np.stack([next(got) for _ in pts])
                    where = self.path(t, a, "evaluation")
                    _save(where, self.config(t, a, pts, self.settings.key, n), both[a])
                    self.say(t, a, what)
            for a in self.algos:
                samples["per_task"][t][a], samples["cross_task"][t][a] = both[a][0], both[a][-1]
        return samples
