"""The public face of the package: `run`, `trace`, `compare` and `load` (re-exported by `jaxeac`).

Each function checks its arguments at entry (``ValueError``/``TypeError`` naming the argument,
the value and the fix) and applies the process settings of `jaxeac.runtime` on first use, so
a notebook runs with the command line's settings and gets its numbers.
"""

from __future__ import annotations

import dataclasses
import numbers
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from jaxeac import runtime

#: Trials of a run named by its algorithm alone (the paper's grid experiment, G6).
DEFAULT_TRIALS = 200


def _check_count(name: str, value, *, allow_none: bool = False) -> None:
    if value is None and allow_none:
        return
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        raise ValueError(f"{name} must be a positive integer (got {value!r})")


def _env(env):
    """An environment object, from itself or its registered name."""
    from jaxeac.envs import make

    if isinstance(env, str):
        return make(env)
    if not all(hasattr(env, a) for a in ("n_states", "n_actions", "n_chances")):
        raise TypeError(f"env must be an environment (jaxeac.make(NAME)) or a registered name "
                        f"(jaxeac.registered() lists them), got {type(env).__name__}")
    return env


def _config(config):
    """A `RunConfig` from itself or an algorithm's name (`DEFAULT_TRIALS`, the paper's rates)."""
    from jaxeac.algorithm.config import algorithm
    from jaxeac.running.config import RunConfig

    if isinstance(config, str):
        return RunConfig(trials=DEFAULT_TRIALS, agent=algorithm(config))
    if not isinstance(config, RunConfig):
        raise TypeError(f"config must be a RunConfig or an algorithm's name such as 'eac' "
                        f"(got {type(config).__name__})")
    return config


def _configs(config) -> tuple[dict[str, Any], bool]:
    """{name: RunConfig} and whether one config was given (not a sequence or a mapping)."""
    if isinstance(config, Mapping):
        if not config:
            raise ValueError("config is an empty mapping; give at least one algorithm")
        return {str(k): _config(v) for k, v in config.items()}, False
    if isinstance(config, Sequence) and not isinstance(config, str):
        cfgs = [_config(c) for c in config]
        if not cfgs:
            raise ValueError("config is an empty sequence; give at least one algorithm")
        names = [_name(c) for c in cfgs]
        if len(set(names)) != len(names):
            raise ValueError(f"config names an algorithm twice ({names}); use a mapping {{name: RunConfig}} "
                             "to run two settings of one algorithm")
        return dict(zip(names, cfgs, strict=True)), False
    cfg = _config(config)
    return {_name(cfg): cfg}, True


def _name(cfg) -> str:
    """The registered algorithm a config runs (`jaxeac.algorithm`'s names), with any memory layout."""
    from jaxeac.algorithm.config import ALGORITHMS, BASELINES

    for name, agent in (ALGORITHMS | BASELINES).items():
        layout = {f: getattr(cfg.agent, f) for f in ("memory", "capacity", "tables")}
        if dataclasses.replace(agent, **layout) == cfg.agent:
            return name
    raise ValueError("config's agent is none of the named algorithms (jaxeac.algorithm's names); give "
                     "configs as a mapping {name: RunConfig}")


def run(env, config="eac", *, seeds: int, key=0, chunk_size: int | None = None, progress: bool = False,
        out: str | os.PathLike | None = None):
    """Run seeds 0 … seeds−1 of one algorithm or several, side by side (SPEC R1: seed i's key is
    ``fold_in(key, i)``, whatever the chunk size or device count).

    `env`: an environment (`jaxeac.make`) or its registered name. `config`: a `RunConfig`, an
    algorithm's name (``"eac"``: 200 trials at the paper's rates), or a sequence or mapping of
    these. `key`: an integer 0 … 2³²−1 or a JAX key. Returns a `SeedsResult` (success [N, T],
    steps, policy, ...) for one config, else ``{name: SeedsResult}``.

    `out`: also write the run folder that ``jaxeac run`` writes (results.parquet, summary.json,
    figures; read by `compare` and `load`). It needs `env` as a registered name and configs the
    command line can state (no schedules); the folder is the command's, byte for byte.
    """
    from jaxeac.running.batch import run_algorithms
    from jaxeac.running.outputs import SeedsResult

    _check_count("seeds", seeds)
    _check_count("chunk_size", chunk_size, allow_none=True)
    cfgs, single = _configs(config)
    if out is not None:
        results = _run_to_folder(env, cfgs, seeds=seeds, key=key, chunk_size=chunk_size, out=out)
    else:
        environment = _env(env)
        runtime.configure()
        bar = _progress(progress, seeds * len(cfgs))
        try:
            runs = run_algorithms(environment, list(cfgs.values()), root_key=key, n_seeds=seeds,
                                  chunk_size=chunk_size, progress=None if bar is None else bar.update)
        finally:
            if bar is not None:
                bar.close()
        results = dict(zip(cfgs, runs, strict=True))
    assert all(isinstance(r, SeedsResult) for r in results.values())
    return next(iter(results.values())) if single else results


def _progress(progress: bool, total: int):
    if not progress:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="seed")


def _run_to_folder(env, cfgs: dict, *, seeds: int, key, chunk_size, out) -> dict:
    """`run(..., out=)`: the command line's settings for these configs, run and written as it does."""
    from jaxeac.experiments.grid import GridRun, GridSettings, write_grid_outputs
    from jaxeac.running.batch import run_algorithms

    if not isinstance(env, str):
        raise TypeError("out= writes the folder of a command-line run, which names its environment: "
                        "pass env as a registered name (jaxeac.registered())")
    first = next(iter(cfgs.values()))
    scheduled = [f"{n}.{r}" for n, c in cfgs.items() for r in ("alpha", "beta") if callable(getattr(c, r))]
    if scheduled:
        raise ValueError(f"out= writes a folder the command line can read, which states constant rates; "
                         f"{', '.join(scheduled)} is a schedule: run without out= to keep the results "
                         "in memory")
    if any(name != _name(cfg) for name, cfg in cfgs.items()):
        raise ValueError("out= needs each config under its algorithm's name (the folder's 'algo' column)")
    from jaxeac.rng import root_key_int

    settings = GridSettings(env=env, algos=tuple(cfgs), seeds=seeds, key=root_key_int(key, "key"),
                            chunk_size=chunk_size, trials=first.trials, alpha=first.alpha, beta=first.beta,
                            gamma=first.gamma,
                            temperature=first.temperature, epsilon=first.epsilon, lanes=first.lanes,
                            memory=first.agent.memory, capacity=first.agent.capacity)
    settings = settings.resolved()
    for name, cfg in cfgs.items():
        stated = settings.run_config(name)
        if stated != cfg:
            differ = [f.name for f in dataclasses.fields(cfg)
                      if getattr(cfg, f.name) != getattr(stated, f.name)]
            raise ValueError(f"out= writes a folder the command line can read, and {name}'s config "
                             f"differs from what its flags state in {', '.join(differ)}; run without "
                             "out= to keep the results in memory")
    runtime.configure()
    environment = settings.make_env()
    runs = run_algorithms(environment, [settings.run_config(a) for a in settings.algos],
                          root_key=settings.key, n_seeds=seeds, chunk_size=chunk_size)
    results = dict(zip(settings.algos, runs, strict=True))
    write_grid_outputs(GridRun(settings, settings.grid_map(), results), out)
    return results


def trace(env, config, key=0, seed=0):
    """One seed's whole run as a pure function: ``(final agent, per-trial record)``, with each
    trial's states, actions, r̃ and outcome (the literal `trials` loop; jit and vmap it freely:
    `key` and `seed` may be traced)."""
    import jax

    from jaxeac.rng import root_key_int, seed_key
    from jaxeac.running.loops import trace_run

    environment, cfg = _env(env), _config(config)
    runtime.configure()
    if isinstance(key, numbers.Integral) and not isinstance(key, bool):
        key = jax.random.key(root_key_int(key, "key"))
    return trace_run(environment, cfg, seed_key(key, seed), cfg.hyper())


def compare(baseline, treatment=None, *, key=0, resamples: int = 10_000, level: float = 0.95,
            names: tuple[str, str] = ("ac", "eac"), paired: bool | str = "auto"):
    """Compare two methods, treatment − baseline, with the statistics engine
    (`jaxeac.stats.engine.compare`); returns its `Comparison` (``.rows``, ``.to_dict()``,
    ``.markdown()``).

    - ``compare(folder)``: a run folder (``jaxeac run``/`run(..., out=)`): writes stats.json,
      report.md and figures into it, as ``jaxeac compare FOLDER`` does; `names` are the two
      algorithms; the folder's full statistics are ``.stats`` (the content of stats.json).
    - ``compare(a, b)``: per-seed values (1-D arrays, or `SeedsResult`s, compared on successes):
      difference of means with a BCa interval, Welch's test, Hedges' g, the probability of
      improvement, the IQMs. `paired`: ``"auto"`` pairs two `SeedsResult`s of the same seeds (seed
      i of each shares its key when both came from `run` with one key) and leaves arrays
      unpaired; ``True`` pairs arrays of equal length element by element; ``False`` never pairs.

    `level`: the confidence level of every interval (0.95: 95 %). Per-seed data of several tasks
    or algorithms: `jaxeac.stats.engine.compare` directly.
    """
    _check_count("resamples", resamples)
    if isinstance(level, bool) or not isinstance(level, numbers.Real) or not 0.5 <= level < 1:
        raise ValueError(f"level is the confidence level, in [0.5, 1) (got {level!r}); "
                         "e.g. 0.95 for 95 % intervals")
    runtime.configure()
    from jaxeac.perseed import is_frame
    from jaxeac.stats.engine import compare as engine_compare

    b, t = names
    if treatment is None:
        if is_frame(baseline):  # a tidy table (a pandas DataFrame): every pair, every task
            return engine_compare(baseline, resamples=resamples, level=float(level), key=key)
        if not isinstance(baseline, str | os.PathLike):
            raise TypeError("compare(folder) takes a run folder's path; "
                            "to compare arrays give two: compare(a, b)")
        return engine_compare(baseline, baseline=b, treatment=t, resamples=resamples, level=float(level),
                              key=key)
    if paired not in ("auto", True, False):
        raise ValueError(f"paired must be 'auto', True or False (got {paired!r})")
    xb, xt = _values(baseline, "baseline"), _values(treatment, "treatment")
    from jaxeac.perseed import PerSeed

    same = [getattr(x, "seeds", None) for x in (baseline, treatment)]
    if paired is True and xb.size != xt.size:
        raise ValueError(f"paired=True needs as many values on each side (got {xb.size} and {xt.size})")
    pair = paired is True or (paired == "auto" and same[0] is not None and same[1] is not None
                              and np.array_equal(same[0], same[1]))
    seeds = {"": {b: np.arange(xb.size).astype(str), t: np.arange(xt.size).astype(str)}} if pair else None
    data = PerSeed({"": {b: xb, t: xt}}, seeds, "per-seed value: as given", "arrays")
    return engine_compare(data, baseline=b, treatment=t, resamples=resamples, level=float(level), key=key)


def _values(x, name: str):
    if hasattr(x, "successes") and hasattr(x, "success"):
        return np.asarray(x.successes, float)
    if isinstance(x, Mapping):
        raise TypeError(f"{name}: compare(a, b) takes per-seed values of one measure; for several tasks or "
                        "algorithms call jaxeac.stats.engine.compare({task: {algo: values}})")
    arr = np.asarray(x)
    if arr.ndim != 1 or arr.size < 2 or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name} must be per-seed numbers, a 1-D array of at least 2 "
                         f"(got shape {arr.shape}, dtype {arr.dtype})")
    return arr.astype(float)


@dataclasses.dataclass(frozen=True)
class Run:
    """A run folder read back (`load`): its summary.json, and per algorithm the per-seed columns
    (``per_seed[algo]["successes"]``, ...) and success per trial (``success(algo)``: bool [N, T])."""

    path: Path
    experiment: str
    algos: tuple[str, ...]
    trials: int
    summary: dict
    per_seed: dict
    _success: dict = dataclasses.field(repr=False)

    def success(self, algo: str) -> np.ndarray:
        """bool [N, T]: seed i succeeded in trial t."""
        if algo not in self._success:
            raise KeyError(f"{algo!r} is not in this run; it holds {', '.join(self.algos)}")
        value = self._success[algo]
        return value.unpack() if hasattr(value, "unpack") else np.asarray(value, bool)


def load(folder) -> Run:
    """Read a run folder written by ``jaxeac run``/``bowling`` or `run(..., out=)`: every algorithm's
    per-seed results (grid folders: seed, successes, first_success, steps_total, finite, and
    trial_steps and policy where kept; bowling: the per_seed.csv columns)."""
    from jaxeac.io import json_field, read_json_object

    path = Path(folder)
    if not (path / "summary.json").is_file():
        raise ValueError(f"{path} holds no run (no summary.json); pass a folder written by 'jaxeac run' "
                         "or jaxeac.run(..., out=FOLDER)")
    summary = read_json_object(path / "summary.json", "re-run the experiment")
    where = path / "summary.json"
    algos = tuple(json_field(summary, "algos", list, where, "re-run the experiment"))
    trials = json_field(summary, "trials", int, where, "re-run the experiment")
    if (path / "results.parquet").is_file():
        from jaxeac.results import load_grid_results

        loaded = load_grid_results(path, algos, trials)
        fields = ("seeds", "successes", "first_success", "steps_total", "finite", "trial_steps", "policy")
        per_seed = {a: {f: getattr(r, f) for f in fields if getattr(r, f) is not None}
                    for a, r in loaded.items()}
        success = {a: r.success for a, r in loaded.items()}
        return Run(path, summary.get("experiment", "grid"), algos, trials, summary, per_seed, success)
    from jaxeac.rundir import load_run_dir

    per_seed, success = {}, {}
    for other in algos[1:] or algos[:1]:
        data = load_run_dir(path, algos[0], other) if other != algos[0] else None
        if data is None:
            raise ValueError(f"{path} holds one algorithm only; a run folder holds two or more")
        per_seed |= data.per_seed
        success |= data.success
    return Run(path, summary.get("experiment", "bowling"), algos, trials, summary, per_seed, success)
