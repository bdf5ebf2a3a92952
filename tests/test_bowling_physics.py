"""Bowling physics as behaviour (SPEC B1-B4, B7): scene, throws, chance 2, backends, errors."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxeac.envs.bowling import (
    XML_PATH,
    BowlingConfig,
    PinState,
    SolverSettings,
    angles,
    initial_pins,
    make_mjx_throw,
    render_deck,
    throw,
    throw_command,
    throw_noise,
)
from jaxeac.envs.bowling.scene import PARK_XYZ, PIN_XY, batch_noise
from jaxeac.errors import UsageError

CFG = BowlingConfig()
EXACT = BowlingConfig(noise_angle=0.0, noise_speed=0.0)
RIGHT = [2, 5, 8, 9]  # pins 3, 6, 9, 10: y < 0, the thrower's right (B2)
LEFT = [1, 3, 6, 7]  # pins 2, 4, 7, 8


@pytest.fixture(scope="module")
def sweep():
    """Deterministic C throws at the 21 default angles from a full rack."""
    a = angles(CFG)
    return a, throw(initial_pins(len(a)), a, jnp.zeros((len(a), 2)), backend="c", cfg=CFG)


def test_scene_file_matches_python_constants():
    """B1: the MJCF has ten capsule pins at PIN_XY, the contact cap, explicit pairs only."""
    m = mujoco.MjModel.from_xml_path(str(XML_PATH))
    assert (m.nq, m.nv) == (77, 66)
    pos = np.array([m.body(f"pin{i + 1}").pos[:2] for i in range(10)])
    np.testing.assert_allclose(pos, PIN_XY, atol=1e-4)
    assert all(m.geom(f"pin{i + 1}").type == mujoco.mjtGeom.mjGEOM_CAPSULE for i in range(10))
    assert m.numeric("max_contact_points").data[0] == 32
    assert np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)
    assert m.npair == 1 + 10 + 10 + 30 + 45


def test_angles_evenly_spaced_on_symmetric_range():
    """B2: K evenly spaced angles on [-theta_max, theta_max]."""
    a = angles(BowlingConfig(n_angles=5, theta_max=0.2))
    np.testing.assert_allclose(a, [-0.2, -0.1, 0.0, 0.1, 0.2])
    assert len(angles(CFG)) == 21


def test_no_noise_repeats_exactly(sweep):
    """B3: zero noise makes throws deterministic."""
    a, first = sweep
    again = throw(initial_pins(len(a)), a, jax.random.key(7), backend="c", cfg=EXACT)
    np.testing.assert_array_equal(first.knocked, again.knocked)
    np.testing.assert_array_equal(first.standing, again.standing)
    np.testing.assert_array_equal(first.rest_qpos, again.rest_qpos)


def test_centre_throw_knocks_at_least_five(sweep):
    """B2: the centre of the deck is where the pins are."""
    a, res = sweep
    assert res.knocked[len(a) // 2] >= 5


def test_extreme_angles_knock_nothing_even_with_noise():
    """B2: +-theta_max lie in the no-pin zone, also under the default noise (B3)."""
    a = np.repeat([-CFG.theta_max, CFG.theta_max], 8)
    res = throw(initial_pins(len(a)), a, jax.random.key(3), backend="c", cfg=CFG)
    assert np.all(res.knocked == 0)
    assert np.all(res.standing)


def test_sign_of_angle_picks_the_side(sweep):
    """B2: negative angles knock more right-side pins, positive more left-side pins."""
    a, res = sweep
    down = ~np.asarray(res.standing)
    neg, pos = a < 0, a > 0
    assert down[neg][:, RIGHT].sum() > down[neg][:, LEFT].sum()
    assert down[pos][:, LEFT].sum() > down[pos][:, RIGHT].sum()


def test_knocked_counts_fallen_pins(sweep):
    """B4/B5: knocked = pins standing before and down after."""
    _, res = sweep
    np.testing.assert_array_equal(res.knocked, 10 - res.standing.sum(axis=1))


def test_chance_two_starts_without_fallen_pins(sweep):
    """B4: after chance 1 fallen pins are gone, standing pins stay at rest; a miss changes nothing."""
    a, res = sweep
    pins = res.pins_after
    # Fallen pins are parked, standing ones sit where they came to rest.
    st = np.asarray(pins.standing)
    q = np.asarray(pins.qpos)
    np.testing.assert_allclose(q[~st][:, :3], np.broadcast_to(PARK_XYZ, (len(a), 10, 3))[~st])
    np.testing.assert_allclose(q[st], np.asarray(res.rest_qpos)[st])
    # A miss in chance 2 knocks nothing and leaves every standing pin in place.
    miss = np.where(a < 0, CFG.theta_max, -CFG.theta_max)
    res2 = throw(pins, miss, jnp.zeros((len(a), 2)), backend="c", cfg=CFG)
    assert np.all(res2.knocked == 0)
    np.testing.assert_array_equal(res2.standing, st)
    moved = np.abs(np.asarray(res2.rest_qpos)[st][:, :3] - q[st][:, :3]).max()
    assert moved < 2e-3, moved
    # A hit in chance 2 knocks only pins that were still standing.
    res3 = throw(pins, -a, jnp.zeros((len(a), 2)), backend="c", cfg=CFG)
    assert np.all(res3.knocked <= st.sum(axis=1))
    assert not np.any(res3.standing & ~st)
    assert (res.knocked + res3.knocked).max() <= 10


def test_chance_two_at_opposite_side_clears_more(sweep):
    """B5: right then left knocks more in total than right alone (the paper's policy)."""
    a, res = sweep
    i = int(np.argmin(np.abs(a + 0.04)))
    assert 0 < res.knocked[i] < 10
    after = res.pins_after
    first = PinState(qpos=after.qpos[i : i + 1], standing=after.standing[i : i + 1])
    res2 = throw(first, [0.04], jnp.zeros((1, 2)), backend="c", cfg=CFG)
    assert res2.knocked[0] > 0


def test_same_key_same_noise_in_both_backends():
    """B3/B7: the noise of throw b is throw_noise(split(key, B)[b]) whatever the backend."""
    key = jax.random.key(11)
    eps = batch_noise(key, 5)
    expect = jax.vmap(throw_noise)(jax.random.split(key, 5))
    np.testing.assert_array_equal(eps, expect)
    assert float(jnp.std(eps)) > 0


def test_noise_changes_outcomes():
    """B3: default noise is non-zero: the same angle gives varied outcomes."""
    res = throw(initial_pins(24), np.full(24, -0.03), jax.random.key(0), backend="c", cfg=CFG)
    assert len({tuple(s) for s in np.asarray(res.standing)}) > 1


@pytest.mark.slow
def test_nothing_nan_over_many_random_throws():
    """Random angles and noise over two chances stay finite (C engine)."""
    key_a, key_1, key_2 = jax.random.split(jax.random.key(5), 3)
    a = np.asarray(jax.random.uniform(key_a, (160,), minval=-CFG.theta_max, maxval=CFG.theta_max))
    res = throw(initial_pins(160), a, key_1, backend="c", cfg=CFG)
    res2 = throw(res.pins_after, a[::-1], key_2, backend="c", cfg=CFG)
    for r in (res, res2):
        assert np.all(np.isfinite(r.rest_qpos))
        assert np.all(np.isfinite(r.pins_after.qpos))
    assert (res.knocked + res2.knocked).max() <= 10


@pytest.mark.slow
def test_mjx_and_c_agree_in_distribution():
    """B7: same noisy throws, both engines: mean pins per angle close, overall mean closer.

    5 angles x 12 noise draws. Tolerances: 1.5 pins per angle, 0.5 pins overall
    (measured on 256 throws over [-0.08, 0.08]: means 4.79 C vs 4.88 MJX).
    """
    base = np.array([-0.1, -0.05, 0.0, 0.03, 0.06])
    a = np.repeat(base, 12)
    keys = jax.random.split(jax.random.key(2024), len(a))
    pins = initial_pins(len(a))
    rc = throw(pins, a, keys, backend="c", cfg=CFG)
    throw_fn = make_mjx_throw(CFG)  # the pure function, jit(vmap) as an agent would
    rm = jax.jit(jax.vmap(throw_fn))(pins, jnp.asarray(a, jnp.float32), keys)
    km = np.asarray(rm.knocked).reshape(len(base), -1)
    kc = np.asarray(rc.knocked).reshape(len(base), -1)
    assert np.all(np.isfinite(np.asarray(rm.rest_qpos)))
    assert np.all(km[0] == 0) and np.all(kc[0] == 0)
    np.testing.assert_array_less(np.abs(km.mean(1) - kc.mean(1)), 1.5)
    assert abs(km.mean() - kc.mean()) < 0.5
    # The MJX result feeds chance 2 like the C one.
    assert np.all(np.asarray(rm.knocked) == 10 - np.asarray(rm.standing).sum(1))


def test_mjx_batch_and_per_throw_paths_agree():
    """B7: the batch function (api.throw, agents' runs) and the vmapped per-throw function of MJX
    give the same pins on the same noisy throws."""
    a = np.array([0.0, 0.02, -0.04, 0.1])
    keys = jax.random.split(jax.random.key(7), len(a))
    pins = initial_pins(len(a))
    batch = throw(pins, a, keys, backend="mjx", cfg=CFG)
    single = jax.jit(jax.vmap(make_mjx_throw(CFG)))(pins, jnp.asarray(a, jnp.float32), keys)
    np.testing.assert_array_equal(np.asarray(batch.knocked), np.asarray(single.knocked))
    np.testing.assert_array_equal(np.asarray(batch.standing), np.asarray(single.standing))


def test_warp_buffers_hold_every_contact_the_pair_list_allows():
    """B1/B7: Warp sizes contacts and constraint rows from WARP_CONTACTS and WARP_ROWS, which must be
    the scene's hard bounds (explicit pairs only, most contacts per pair type, pyramidal rows)."""
    import mujoco

    from jaxeac.envs.bowling.backend_c import load_model
    from jaxeac.envs.bowling.backend_mjx import WARP_CONTACTS, WARP_ROWS

    m = load_model()
    g = mujoco.mjtGeom
    assert not np.any((m.geom_contype != 0) & (m.geom_conaffinity != 0)), "only listed pairs collide"
    assert m.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL
    most = {(g.mjGEOM_PLANE, g.mjGEOM_SPHERE): 1, (g.mjGEOM_PLANE, g.mjGEOM_CAPSULE): 2,
            (g.mjGEOM_SPHERE, g.mjGEOM_CAPSULE): 1, (g.mjGEOM_CAPSULE, g.mjGEOM_CAPSULE): 2}
    contacts = rows = 0
    for i in range(m.npair):
        kinds = tuple(sorted(int(m.geom_type[j]) for j in (m.pair_geom1[i], m.pair_geom2[i])))
        n = most[kinds]
        dim = int(m.pair_dim[i])
        contacts += n
        rows += n * (1 if dim == 1 else 2 * (dim - 1))
    assert (contacts, rows) == (WARP_CONTACTS, WARP_ROWS) == (151, 514)


def test_unknown_mjx_implementation_and_missing_warp_are_usage_errors(monkeypatch):
    """The warp backend without warp-lang: one line naming the fix, before any work."""
    from jaxeac.envs.bowling import backend_mjx
    from jaxeac.experiments.bowling import BowlingSettings

    with pytest.raises(UsageError, match="implementation"):
        backend_mjx.check_impl("cuda")
    monkeypatch.setattr(backend_mjx._mjx_warp, "WARP_INSTALLED", False)
    for call in (lambda: backend_mjx.check_impl("warp"),
                 lambda: throw(initial_pins(1), 0.0, jax.random.key(0), backend="warp", cfg=CFG),
                 lambda: BowlingSettings(backend="warp").validate()):
        with pytest.raises(UsageError, match="warp-lang") as err:
            call()
        assert "\n" not in str(err.value) and "pip install" in str(err.value)


@pytest.mark.slow
def test_warp_and_c_agree_in_distribution():
    """B7: MJX's Warp implementation against the C engine on the same noisy throws (tolerances as for
    the jax implementation); needs warp-lang (skipped without it; runs on CPU or an NVIDIA GPU)."""
    pytest.importorskip("warp")
    base = np.array([-0.1, -0.05, 0.0, 0.03, 0.06])
    a = np.repeat(base, 12)
    keys = jax.random.split(jax.random.key(2024), len(a))
    pins = initial_pins(len(a))
    rc = throw(pins, a, keys, backend="c", cfg=CFG)
    rw = throw(pins, a, keys, backend="warp", cfg=CFG)
    kw = np.asarray(rw.knocked).reshape(len(base), -1)
    kc = np.asarray(rc.knocked).reshape(len(base), -1)
    assert np.all(np.isfinite(np.asarray(rw.rest_qpos)))
    assert np.all(kw[0] == 0)
    np.testing.assert_array_less(np.abs(kw.mean(1) - kc.mean(1)), 1.5)
    assert abs(kw.mean() - kc.mean()) < 0.5
    assert np.all(np.asarray(rw.knocked) == 10 - np.asarray(rw.standing).sum(1))


def test_throw_command_and_render(tmp_path):
    """CLI function: deterministic at noise 0, JSON-ready, writes a PNG."""
    png = tmp_path / "deck.png"
    out = throw_command([0.0, -CFG.theta_max], "c", str(png), CFG)
    json.dumps(out)
    assert out["theta_max"] == CFG.theta_max
    assert out["throws"][0]["knocked"] >= 5 and out["throws"][1]["knocked"] == 0
    assert len(out["throws"][0]["standing"]) == 10
    assert out == throw_command([0.0, -CFG.theta_max], "c", str(png), CFG)
    for p in out["render"]:
        assert open(p, "rb").read(8) == b"\x89PNG\r\n\x1a\n"
    res = throw(initial_pins(1), [0.0], jnp.zeros((1, 2)), cfg=CFG)
    assert render_deck(res, tmp_path / "m.png", method="matplotlib") == "matplotlib"


@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_angles": 1},
        {"theta_max": 0.0},
        {"theta_max": -0.1},
        {"noise_angle": -0.01},
        {"noise_speed": -1.0},
        {"release_speed": 0.0},
        {"n_steps": 0},
        {"tilt_down_deg": 95.0},
        {"solver": "newton"},
        {"solver": {"method": "pgs"}},
        {"solver": {"iterations": 0}},
        {"solver": {"ls_iterations": 1.5}},
        {"solver": {"contact_cap": 0}},
        {"solver": {"pair_cap": -1}},
        {"solver": {"sleep": "yes"}},
    ],
)
def test_bad_config_raises_usage_error(kwargs):
    """Bad settings name the problem and the fix in one line."""
    with pytest.raises(UsageError) as err:
        if isinstance(kwargs.get("solver"), dict):
            SolverSettings(**kwargs["solver"])
        else:
            BowlingConfig(**kwargs)
    assert "\n" not in str(err.value) and ":" in str(err.value)


def test_bad_throw_input_raises_usage_error(tmp_path):
    """Out-of-range angles, unknown backends, bad shapes and noise are UsageErrors."""
    pins = initial_pins(2)
    key = jax.random.key(0)
    with pytest.raises(UsageError, match="theta_max"):
        throw(pins, [0.0, CFG.theta_max + 0.01], key, cfg=CFG)
    with pytest.raises(UsageError, match="backend"):
        throw(pins, 0.0, key, backend="gpu")
    with pytest.raises(UsageError, match="angle"):
        throw(pins, [0.0, 0.0, 0.0], key)
    with pytest.raises(UsageError, match="noise"):
        throw(pins, 0.0, np.zeros((3, 2)))
    with pytest.raises(UsageError, match="PinState"):
        throw(np.zeros((2, 10)), 0.0, key)
    with pytest.raises(UsageError):
        throw_command([0.0], "c", None, CFG, noise_angle=-1.0)
    with pytest.raises(UsageError):
        throw_command([], "c", None, CFG)
    with pytest.raises(UsageError):
        initial_pins(0)
    with pytest.raises(UsageError):
        render_deck(initial_pins(1), tmp_path / "no" / "x.png")


def test_solver_settings_reach_both_engines():
    """B7: the config's solver settings are what the C model and the MJX model run with."""
    import mujoco

    from jaxeac.envs.bowling.backend_c import load_model

    default = load_model()
    assert (default.opt.solver, default.opt.iterations, default.opt.ls_iterations) == (
        mujoco.mjtSolver.mjSOL_NEWTON, 4, 8)
    model = load_model(SolverSettings("cg", iterations=12, ls_iterations=4, contact_cap=30, pair_cap=16))
    assert (model.opt.solver, model.opt.iterations, model.opt.ls_iterations) == (
        mujoco.mjtSolver.mjSOL_CG, 12, 4)

    def numeric(m, name):
        return m.numeric_data[m.numeric_adr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_NUMERIC, name)]]

    assert (numeric(default, "max_contact_points"), numeric(default, "max_geom_pairs")) == (32, -1)
    assert (numeric(model, "max_contact_points"), numeric(model, "max_geom_pairs")) == (30, 16)
    sleep = mujoco.mjtEnableBit.mjENBL_SLEEP
    assert default.opt.enableflags & sleep  # the C engine's default
    assert not load_model(SolverSettings(sleep=False)).opt.enableflags & sleep


def test_no_sleep_flag_reaches_the_summary(tmp_path):
    """B7: `--no-sleep` runs the engine without sleeping and says so in summary.json."""
    from jaxeac.cli import main

    out = tmp_path / "b"
    argv = ["bowling", "--seeds", "2", "--trials", "1", "--out", str(out), "--quiet", "--no-compare",
            "--no-sleep"]
    assert main(argv) == 0
    assert json.loads((out / "summary.json").read_text())["physics"]["solver"]["sleep"] is False


def test_cg_solver_throws_like_newton():
    """A measured faster setting (BENCHMARKS.md) still plays the same game on exact throws:
    the centre throw knocks >= 5 pins and a throw at theta_max knocks none."""
    cg = BowlingConfig(noise_angle=0.0, noise_speed=0.0, solver=SolverSettings("cg", 12, 4))
    res = throw(initial_pins(2), np.array([0.0, cg.theta_max]), jax.random.key(0), cfg=cg)
    assert int(res.knocked[0]) >= 5 and int(res.knocked[1]) == 0


# ---------------------------------------------------------------- the C engine's sleeping (B7)
def _start_states(n: int, seed: int, partial: bool):
    """(qpos, qvel) float64 of n noisy throws over the 21 angles, from full racks or, with
    partial, from the racks a first throw left (removed pins parked, B4)."""
    from jaxeac.envs.bowling import backend_c

    a = np.resize(angles(CFG), n)
    eps = batch_noise(jax.random.key(seed), n)
    pins = initial_pins(n)
    if partial:
        pins = throw(pins, a[::-1].copy(), jax.random.key(seed + 1), backend="c", cfg=CFG).pins_after
        pins = jax.tree.map(jnp.asarray, pins)
    qpos, qvel = backend_c._prepare_fn(CFG)(pins, jnp.asarray(a, jnp.float32), eps)
    return np.asarray(qpos, np.float64), np.asarray(qvel, np.float64)


def _in_play(final: np.ndarray, qpos: np.ndarray) -> np.ndarray:
    """Final poses (n, 10, 7) of the pins in play at the start, zero for removed ones."""
    live = (qpos[:, 9:77:7] < 10.0)[:, :, None]
    return np.where(live, final[:, 7:].reshape(-1, 10, 7), 0.0)


@pytest.mark.parametrize("partial", [False, True])
def test_settled_throws_end_where_full_length_throws_end(partial):
    """B7: a throw that stops once settled leaves every pin in play exactly where the same
    throw run for its full n_steps leaves it (nothing can wake a sleeping pin), and misses stop
    long before n_steps."""
    from jaxeac.envs.bowling.backend_c import CEngine

    qpos, qvel = _start_states(42, seed=5, partial=partial)
    eng = CEngine(2, SolverSettings())
    early, _ = eng.simulate(qpos, qvel, CFG.n_steps)
    steps_early = eng.steps_run
    full, _ = eng.simulate(qpos, qvel, CFG.n_steps, stop_when_settled=False)
    assert eng.steps_run == 42 * CFG.n_steps
    np.testing.assert_array_equal(_in_play(early, qpos), _in_play(full, qpos))
    assert steps_early < 0.95 * eng.steps_run
    eng.close()


@pytest.mark.parametrize("scene", ["default", "table1"])
def test_throws_from_a_full_rack_asleep_are_bit_identical(scene):
    """B7: a throw from a full rack starts from the rack already asleep (made once per rack and
    shared): every body ends exactly where the throw that lets the rack fall asleep itself leaves
    it, after the same steps. Partial racks (chance 2) let their pins settle themselves."""
    from jaxeac.envs.bowling import backend_c
    from jaxeac.envs.bowling.backend_c import CEngine
    from jaxeac.envs.bowling.scene import SCENES

    cfg = BowlingConfig(scene=SCENES[scene])
    n = 24
    a = np.resize(angles(cfg), n)
    eps = batch_noise(jax.random.key(4), n)
    qpos, qvel = (np.asarray(x, np.float64)
                  for x in backend_c._prepare_fn(cfg)(initial_pins(n, cfg.scene), jnp.asarray(a, jnp.float32), eps))
    eng = CEngine(2, SolverSettings(), cfg.scene)
    assert eng.rack_templates
    asleep, _ = eng.simulate(qpos, qvel, cfg.n_steps)
    steps = eng.steps_run
    assert len(eng._racks) == 1 and next(iter(eng._racks.values())) is not None  # one rack, asleep
    eng.rack_templates = False
    itself, _ = eng.simulate(qpos, qvel, cfg.n_steps)
    np.testing.assert_array_equal(asleep, itself)
    assert eng.steps_run == steps
    eng.rack_templates = True
    partial_qpos, partial_qvel = _start_states(12, seed=6, partial=True)
    eng.simulate(partial_qpos, partial_qvel, cfg.n_steps)
    assert len(eng._racks) == 1  # no template for racks with pins standing where they came to rest
    eng.close()


def test_a_ball_that_could_reach_a_settling_rack_does_not_start_from_it_asleep():
    """B7: the asleep rack is only for throws whose ball stays out of reach while the rack
    would settle; a ball started 0.6 m before the head pin lets the rack settle itself, and its
    throw ends where the engine without asleep racks leaves it."""
    from jaxeac.envs.bowling import backend_c
    from jaxeac.envs.bowling.backend_c import CEngine

    qpos, qvel = _start_states(2, seed=9, partial=False)
    eng = CEngine(1, SolverSettings())
    data = eng.datas[0]
    for near, expected in ((False, True), (True, False)):
        mujoco.mj_resetData(eng.model, data)
        data.qpos[:], data.qvel[:] = qpos[0], qvel[0]
        data.qpos[9:77:7] = backend_c.PIN_REST_Z  # as `_throw` seats a rack placed upright
        if near:
            data.qpos[0] = PIN_XY[0][0] - 0.6
        assert (eng._asleep_rack(data) is not None) == expected
    close = qpos.copy()
    close[:, 0] = PIN_XY[0][0] - 0.6
    with_racks, _ = eng.simulate(close, qvel, CFG.n_steps)
    eng.rack_templates = False
    without, _ = eng.simulate(close, qvel, CFG.n_steps)
    np.testing.assert_array_equal(with_racks, without)
    eng.close()


def test_where_removed_pins_wait_changes_no_pin_in_play():
    """B4/B7: removed pins asleep on the floor behind the thrower or falling 1000 m up: the pins
    in play move the same, bit for bit."""
    from jaxeac.envs.bowling.backend_c import CEngine

    qpos, qvel = _start_states(21, seed=8, partial=True)
    assert np.any(qpos[:, 9:77:7] > 10.0)  # some pins were removed
    eng = CEngine(2, SolverSettings())
    floor, _ = eng.simulate(qpos, qvel, CFG.n_steps, stop_when_settled=False)
    eng.floor_park = False
    air, _ = eng.simulate(qpos, qvel, CFG.n_steps, stop_when_settled=False)
    np.testing.assert_array_equal(_in_play(floor, qpos), _in_play(air, qpos))
    eng.close()


def test_throws_do_not_depend_on_thread_or_order():
    """R1/B7: each throw starts from a reset MjData, so neither the thread count nor the throws
    run before it change its result."""
    from jaxeac.envs.bowling.backend_c import CEngine

    qpos, qvel = _start_states(24, seed=3, partial=False)
    one = CEngine(1, SolverSettings())
    two = CEngine(2, SolverSettings())
    a, _ = one.simulate(qpos, qvel, CFG.n_steps)
    b, _ = two.simulate(qpos[::-1].copy(), qvel[::-1].copy(), CFG.n_steps)
    np.testing.assert_array_equal(_in_play(a, qpos), _in_play(b[::-1], qpos))
    one.close()
    two.close()


def test_sleeping_engine_knocks_the_same_pins_as_the_full_engine():
    """B7: sleeping is a physics setting measured for accuracy (BENCHMARKS.md); on these 63
    noisy throws it knocks the same number of pins as the engine without sleeping on nearly
    every throw, and the same total within a few pins."""
    a = np.resize(angles(CFG), 63)
    keys = jax.random.split(jax.random.key(11), 63)
    fast = throw(initial_pins(63), a, keys, backend="c", cfg=CFG)
    slow = throw(initial_pins(63), a, keys, backend="c",
                 cfg=BowlingConfig(solver=SolverSettings(sleep=False)))
    same = np.mean(np.asarray(fast.knocked) == np.asarray(slow.knocked))
    assert same >= 0.85, same
    assert abs(int(np.sum(fast.knocked)) - int(np.sum(slow.knocked))) <= 6


# ---------------------------------------------------------------- scenes (B1, B1a)
def test_table1_scene_model_has_its_sizes():
    """B1a: the table1 scene resizes the ball (inertia follows, mass stays) and spreads the pins."""
    from jaxeac.envs.bowling import SCENES
    from jaxeac.envs.bowling.backend_c import load_model

    scene = SCENES["table1"]
    m, d = load_model(scene=scene), load_model()
    ball = m.body("ball").id
    assert m.geom("ball").size[0] == pytest.approx(0.06)
    assert m.body_mass[ball] == pytest.approx(d.body_mass[ball]) == pytest.approx(6.0)
    assert m.body_inertia[ball][0] == pytest.approx(0.4 * 6.0 * 0.06**2)
    pos = np.array([m.body(f"pin{i + 1}").pos[:2] for i in range(10)])
    np.testing.assert_allclose(pos, scene.pin_xy(), atol=1e-9)
    assert np.linalg.norm(pos[1] - pos[2]) == pytest.approx(0.40)  # pins 2 and 3


def test_table1_scene_first_throws_knock_at_most_seven():
    """B1a: like Table I, no exact first throw at any of the 21 angles knocks more than 7 pins; the
    default scene knocks 8 or more near the centre."""
    from jaxeac.envs.bowling import SCENES

    a = angles(CFG)
    table1 = BowlingConfig(noise_angle=0.0, noise_speed=0.0, scene=SCENES["table1"])
    res = throw(initial_pins(len(a), table1.scene), a, jnp.zeros((len(a), 2)), backend="c", cfg=table1)
    assert 4 <= int(np.max(res.knocked)) <= 7
    default = throw(initial_pins(len(a)), a, jnp.zeros((len(a), 2)), backend="c", cfg=EXACT)
    assert int(np.max(default.knocked)) >= 8


def test_bad_scene_is_refused():
    """B1a: unknown scene names and impossible sizes are one-line UsageErrors."""
    from jaxeac.cli import main
    from jaxeac.envs.bowling import Scene

    with pytest.raises(UsageError, match="ball_radius"):
        Scene(ball_radius=0.5)
    with pytest.raises(UsageError, match="pins must not touch"):
        Scene(pin_spacing=0.1)
    assert main(["throw", "--angle", "0", "--scene", "wide"]) == 2


def test_pin_rest_height_is_where_the_rack_settles():
    """B7: the sleeping engine starts an upright pin at `PIN_REST_Z`, the height the rack settles to
    on its own; from there the pins fall asleep within MuJoCo's 10 quiet steps, and the rack does
    not move."""
    import mujoco

    from jaxeac.envs.bowling.backend_c import PIN_REST_Z, load_model
    from jaxeac.envs.bowling.scene import upright_qpos

    m = load_model()
    d = mujoco.MjData(m)
    rack = upright_qpos()
    d.qpos[:7] = (-5.0, 0.0, 0.11, 1.0, 0.0, 0.0, 0.0)  # the ball far from the pins
    d.qpos[7:] = rack.reshape(-1)
    mujoco.mj_step(m, d, nstep=60)
    settled = d.qpos[9::7]
    np.testing.assert_allclose(settled, PIN_REST_Z, atol=2e-6)
    d2 = mujoco.MjData(m)
    d2.qpos[:7] = (-5.0, 0.0, 0.11, 1.0, 0.0, 0.0, 0.0)
    rack[:, 2] = PIN_REST_Z
    d2.qpos[7:] = rack.reshape(-1)
    mujoco.mj_step(m, d2, nstep=12)
    assert np.all(d2.tree_asleep[1:] >= 0)
    np.testing.assert_allclose(d2.qpos[9::7], PIN_REST_Z, atol=1e-5)
