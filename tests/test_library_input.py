"""The library refuses bad input at entry, as the command line does: a `TypeError` for a value of
the wrong kind, a `ValueError` (`UsageError`) for a bad value, each naming the argument, the value
and the fix, before any JAX tracing. Root keys (R1) are 32-bit: a JAX key maps to the same root as
the integer it was made from (`jaxeac.rng.root_key_int`), and nothing aliases silently.
"""

from __future__ import annotations

import math

import jax
import numpy as np
import optax
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxeac.envs
from jaxeac.algorithm.config import algorithm
from jaxeac.errors import UsageError
from jaxeac.rng import KEY_LIMIT, as_key, root_key_int, seed_key
from jaxeac.running.batch import run_algorithms, run_entries, run_seeds, start_states
from jaxeac.running.config import RunConfig
from jaxeac.running.diagnostics import diagnose_seeds
from jaxeac.running.loops import make_run, trace_run

EAC = algorithm("eac")
ENV = jaxeac.envs.make("grid-paper7-v0", chances=12)
CFG = RunConfig(trials=4, agent=EAC)


def test_usage_error_is_a_value_error():
    assert issubclass(UsageError, ValueError)


# ------------------------------------------------------------------ RunConfig (its __post_init__)

BAD_CONFIGS = {
    "nan alpha": ({"alpha": math.nan}, ValueError, r"alpha must be a finite number \(got nan\); pass"),
    "inf beta": ({"beta": math.inf}, ValueError, r"beta must be a finite number"),
    "negative alpha": ({"alpha": -0.1}, ValueError, r"alpha must be >= 0 \(got -0.1\)"),
    "gamma 2": ({"gamma": 2.0}, ValueError, r"gamma must be in \[0, 1\] \(got 2.0\); pass the discount"),
    "epsilon 2": ({"epsilon": 2.0}, ValueError, r"epsilon must be in \[0, 1\] \(got 2.0\)"),
    "zero temperature": ({"temperature": 0.0}, ValueError, r"temperature must be > 0 \(got 0.0\)"),
    "tiny alpha": ({"alpha": 1e-40}, ValueError, r"alpha 1e-40 is outside float32's normal range"),
    "string alpha": ({"alpha": "0.1"}, TypeError, r"alpha must be a number or an optax schedule"),
    "bool gamma": ({"gamma": True}, TypeError, r"gamma must be a number \(got True"),
    "scheduled gamma": ({"gamma": optax.constant_schedule(0.9)}, TypeError, r"gamma must be a number"),
    "zero trials": ({"trials": 0}, ValueError, r"trials must be a positive integer \(got 0\); pass"),
    "negative trials": ({"trials": -3}, ValueError, r"trials must be a positive integer \(got -3\)"),
    "fractional trials": ({"trials": 2.5}, ValueError, r"trials must be a positive integer \(got 2.5\)"),
    "string trials": ({"trials": "5"}, TypeError, r"trials must be a positive integer \(got '5'"),
    "bool trials": ({"trials": True}, TypeError, r"trials must be a positive integer \(got True"),
    "huge trials": ({"trials": 2**31}, ValueError, r"trials 2147483648 is too large: trials must be at most 2,147,483,647"),
    "agent by name": ({"agent": "eac"}, TypeError,
                      r"agent must be an AgentConfig, e.g. algorithm\('eac'\) \(got 'eac'\)"),
    "zero lanes": ({"lanes": 0}, ValueError, r"lanes must be a positive integer \(got 0\)"),
    "float lanes": ({"lanes": 128.0}, ValueError, r"lanes must be a positive integer \(got 128.0\)"),
    "unknown loop": ({"loop": "fast"}, ValueError, r"unknown loop 'fast'; choose one of"),
    "loop not a string": ({"loop": 1}, TypeError, r"loop must be a string, one of"),
    "unknown kernel": ({"kernel": "cuda"}, ValueError, r"unknown kernel 'cuda'"),
    "unknown jump": ({"jump": True}, TypeError, r"jump must be a string"),
}


@pytest.mark.parametrize("case", BAD_CONFIGS, ids=list(BAD_CONFIGS))
def test_run_config_refuses_bad_fields(case):
    overrides, error, message = BAD_CONFIGS[case]
    with pytest.raises(error, match=message):
        RunConfig(**{"trials": 4, "agent": EAC, **overrides})


def test_run_config_takes_what_runs_take():
    """NumPy scalars, ints, the range's ends, optax schedules and traced rates (a `Hyper` sweep)."""
    RunConfig(trials=np.int64(3), agent=EAC, alpha=np.float32(0.5), beta=0, gamma=1,
              temperature=np.float64(2), epsilon=0.0, lanes=np.int32(128))
    RunConfig(trials=3, agent=EAC, alpha=optax.linear_schedule(0.5, 0.0, 3),
              beta=optax.constant_schedule(0.2))
    RunConfig(trials=3, agent=EAC, alpha=50.0)  # a diverging step size is the user's to try (test_outputs)
    traced = jax.jit(lambda a: RunConfig(trials=3, agent=EAC, alpha=a, gamma=a).hyper().alpha)(0.25)
    assert float(traced) == 0.25


# ------------------------------------------------------------------ environments

@pytest.mark.parametrize("name", ["grid-paper-v0", "FrozenLake-4x4-v1"])
@pytest.mark.parametrize("options, error, message", [
    ({"chances": 2.5}, ValueError,
     r"chances must be a positive integer \(got 2.5\); pass the chances per trial"),
    ({"chances": 0}, ValueError, r"chances must be a positive integer \(got 0\)"),
    ({"chances": "40"}, TypeError, r"chances must be a positive integer \(got '40'"),
    ({"slip": 1.5}, ValueError, r"slip must be in \[0, 1\] \(got 1.5\); pass e.g. 0.1"),
    ({"slip": math.nan}, ValueError, r"slip must be a finite number \(got nan\)"),
    ({"slip": None}, TypeError, r"slip must be a number \(got None"),
])
def test_make_refuses_bad_options(name, options, error, message):
    with pytest.raises(error, match=message):
        jaxeac.envs.make(name, **options)


def test_make_keeps_good_options():
    assert jaxeac.envs.make("grid-paper-v0", chances=np.int64(7)).n_chances == 7
    assert jaxeac.envs.make("FrozenLake-4x4-v1", slip=np.float32(0.25), chances=9).n_chances == 9
    with pytest.raises(TypeError, match=r"name must be a string"):
        jaxeac.envs.make(3)


# ------------------------------------------------------------------ keys (R1)

BAD_KEYS = {
    "2^40": (2**40, ValueError, r"root_key must lie in 0\.\.4294967295 \(got 1099511627776\).*key 0's run"),
    "-1": (-1, ValueError, r"root_key must lie in 0\.\.4294967295 \(got -1\).*key 4294967295's run"),
    "2^32": (2**32, ValueError, r"root_key must lie in 0\.\.4294967295"),
    "numpy -1": (np.int64(-1), ValueError, r"root_key must lie in"),
    "1.5": (1.5, ValueError, r"root_key must be an integer \(got 1.5\); pass an integer in 0\.\.4294967295"),
    "nan": (math.nan, ValueError, r"root_key must be an integer \(got nan\)"),
    "abc": ("abc", TypeError, r"root_key must be an integer or a JAX key \(got 'abc'.*pass an integer"),
    "None": (None, TypeError, r"root_key must be an integer or a JAX key \(got None"),
    "bool": (True, TypeError, r"root_key must be an integer key, not a bool"),
    "split key": (jax.random.split(jax.random.key(0))[0], ValueError,
                  r"root_key is a JAX key with data words \[\d+, \d+\].*keys from split or fold_in"),
    "key batch": (jax.random.split(jax.random.key(0)), TypeError, r"root_key must be one threefry2x32 key"),
    "rbg key": (jax.random.key(0, impl="rbg"), TypeError, r"root_key must be one threefry2x32 key.*rbg"),
    "float array": (np.zeros(2, np.float32), TypeError, r"root_key must be an integer or a JAX key"),
}


@pytest.mark.parametrize("case", BAD_KEYS, ids=list(BAD_KEYS))
def test_bad_root_keys_are_refused_at_entry(case):
    key, error, message = BAD_KEYS[case]
    with pytest.raises(error, match=message):
        root_key_int(key)
    with pytest.raises(error, match=message):
        run_seeds(ENV, CFG, root_key=key, n_seeds=2)
    if case != "split key":  # `as_key` keeps any one key as it is (a seed's key comes from fold_in)
        with pytest.raises(error, match=r"^key "):
            as_key(key)


@pytest.mark.parametrize("key", [7, np.uint32(7), np.int64(7), np.asarray(7), jax.random.key(7),
                                 jax.random.PRNGKey(7), np.asarray(jax.random.PRNGKey(7))],
                         ids=["int", "uint32", "int64", "0-d array", "key", "PRNGKey", "numpy PRNGKey"])
def test_a_jax_key_is_its_integer(key):
    assert root_key_int(key) == 7
    assert (jax.random.key_data(seed_key(key, 3)) == jax.random.key_data(seed_key(7, 3))).all()


def test_a_jax_key_runs_the_integers_run():
    """`run_seeds` with ``key(7)`` or ``PRNGKey(7)`` gives the run of root key 7, bit for bit."""
    runs = [run_seeds(ENV, CFG, root_key=key, n_seeds=3)
            for key in (7, jax.random.key(7), jax.random.PRNGKey(7))]
    other = run_seeds(ENV, CFG, root_key=8, n_seeds=3)
    for run in runs[1:]:
        np.testing.assert_array_equal(run.success, runs[0].success)
        np.testing.assert_array_equal(run.steps, runs[0].steps)
        np.testing.assert_array_equal(run.policy, runs[0].policy)
    assert not np.array_equal(other.steps, runs[0].steps)  # the key matters at all


def test_trace_run_takes_a_key_or_its_integer():
    hyper = CFG.hyper()
    run = jax.jit(lambda k: trace_run(ENV, CFG, k, hyper)[1].length)
    np.testing.assert_array_equal(run(jax.random.key(5)), run(jax.random.PRNGKey(5)))
    np.testing.assert_array_equal(trace_run(ENV, CFG, 5, hyper)[1].length, run(jax.random.key(5)))
    with pytest.raises(ValueError, match=r"key must lie in 0\.\.4294967295 \(got 1099511627776\)"):
        trace_run(ENV, CFG, 2**40, hyper)
    with pytest.raises(TypeError, match=r"cfg must be a RunConfig.*\(got 'eac'\)"):
        trace_run(ENV, "eac", 0, hyper)
    with pytest.raises(TypeError, match=r"hyper must be a Hyper"):
        trace_run(ENV, CFG, 0, {"alpha": 0.1})
    with pytest.raises(TypeError, match=r"env must be a jaxeac environment"):
        make_run("grid-paper-v0", CFG)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, KEY_LIMIT - 1))
def test_root_of_every_32_bit_key(k):
    """R1: an integer, ``key(k)`` and ``PRNGKey(k)`` name the same root, k."""
    assert root_key_int(k) == root_key_int(jax.random.key(k)) == root_key_int(jax.random.PRNGKey(k)) == k


@settings(max_examples=40, deadline=None)
@given(st.one_of(st.integers(max_value=-1), st.integers(min_value=KEY_LIMIT)))
def test_no_integer_outside_32_bits_aliases(k):
    with pytest.raises(ValueError, match=rf"root_key must lie in 0\.\.{KEY_LIMIT - 1} \(got {k}\)"):
        root_key_int(k)


def test_seed_indices_are_checked():
    with pytest.raises(ValueError, match=r"seed must lie in 0\.\.4294967295 \(got -1\)"):
        seed_key(0, -1)
    with pytest.raises(TypeError, match=r"seed must be an integer seed index \(got 1.5\)"):
        seed_key(0, 1.5)


# ------------------------------------------------------------------ run_seeds / run_algorithms / run_entries

@pytest.mark.parametrize("kwargs, error, message", [
    ({"n_seeds": 0}, ValueError, r"n_seeds must be a positive integer \(got 0\); pass how many seeds"),
    ({"n_seeds": -2}, ValueError, r"n_seeds must be a positive integer \(got -2\)"),
    ({"n_seeds": 2.5}, ValueError, r"n_seeds must be a positive integer \(got 2.5\)"),
    ({"n_seeds": "3"}, TypeError, r"n_seeds must be a positive integer \(got '3'"),
    ({"first_seed": -1}, ValueError, r"first_seed must be an integer >= 0 \(got -1\)"),
    ({"first_seed": 2**32 - 1}, ValueError, r"first_seed \+ n_seeds must be at most 2\^32"),
    ({"chunk_size": 0}, ValueError, r"chunk_size must be a positive integer \(got 0\); pass seeds per chunk"),
    ({"chunk_size": 1.5}, ValueError, r"chunk_size must be a positive integer \(got 1.5\)"),
    ({"chunk_size": "8"}, TypeError, r"chunk_size must be a positive integer \(got '8'"),
])
def test_run_seeds_refuses_bad_counts(kwargs, error, message):
    with pytest.raises(error, match=message):
        run_seeds(ENV, CFG, **{"root_key": 0, "n_seeds": 2, **kwargs})


def test_run_functions_refuse_bad_objects():
    with pytest.raises(TypeError, match=r"cfg must be a RunConfig.*\(got 'eac'\)"):
        run_seeds(ENV, "eac", root_key=0, n_seeds=2)
    with pytest.raises(TypeError, match=r"env must be a jaxeac environment"):
        run_seeds("grid-paper-v0", CFG, root_key=0, n_seeds=2)
    with pytest.raises(TypeError, match=r"cfgs must be a non-empty list of RunConfig"):
        run_algorithms(ENV, [], root_key=0, n_seeds=2)
    with pytest.raises(ValueError, match=r"hypers must have one entry per config \(2\), got 1"):
        run_algorithms(ENV, [CFG, CFG], root_key=0, n_seeds=2, hypers=[None])
    with pytest.raises(TypeError, match=r"seeds must be a 1-D sequence of integer seed indices"):
        run_entries(ENV, CFG, root_key=0, seeds=np.array([0.5, 1.0]), hyper=CFG.hyper())
    with pytest.raises(ValueError, match=r"seeds must lie in 0\.\.4294967295 \(got -1\)"):
        run_entries(ENV, CFG, root_key=0, seeds=np.array([-1, 2]), hyper=CFG.hyper())
    with pytest.raises(ValueError, match=r"root_key must lie in"):
        run_entries(ENV, CFG, root_key=2**40, seeds=np.arange(2), hyper=CFG.hyper())
    with pytest.raises(ValueError, match=r"root_key must lie in"):
        start_states(ENV, -1, np.arange(2), 3)
    with pytest.raises(ValueError, match=r"root_key must lie in"):
        diagnose_seeds(ENV, CFG, root_key=2**40, seeds=[0, 1])


def test_start_states_take_a_jax_key():
    np.testing.assert_array_equal(start_states(ENV, jax.random.PRNGKey(3), np.arange(4), 3),
                                  start_states(ENV, 3, np.arange(4), 3))
