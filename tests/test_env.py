"""SaddleTrap-v0: API conformance, determinism, vector ≡ single, physics, rendering."""

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import saddle_env as se
from saddle_env.compilation.specialise import FULL_KERNELS_ENV
from saddle_env.envs import LEVEL_IDS, PAPER_BALL_RADII, SaddleTrapEnv
from saddle_env.envs.vector import SaddleTrapVectorEnv

ZERO = np.zeros(1, dtype=np.float32)
CONFIGS = [dict(), dict(obs_frame="lab", action_mode="target"),
           dict(contact="slipping", R=0.033, position_noise=1e-3, velocity_noise=1e-2,
                omega_noise=0.2, air_force=0.05, ripple_amp=0.5, ripple_freq=30.0),
           dict(ball_radii=PAPER_BALL_RADII, a_range=(0.14, 0.18),
                contact_models=("rolling", "slipping", "point"))]


@pytest.mark.parametrize("kwargs", CONFIGS)
def test_gymnasium_checker_passes_without_warnings(kwargs):
    env = gym.make("SaddleTrap-v0", render_mode="rgb_array", **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)


@pytest.mark.parametrize("kwargs", CONFIGS)
def test_sb3_checker_passes_without_warnings(kwargs):
    sb3 = pytest.importorskip("stable_baselines3.common.env_checker")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3.check_env(SaddleTrapEnv(**kwargs), warn=True)


def _rollout(env, seed, steps=300, action_seed=0):
    rng = np.random.default_rng(action_seed)
    obs, _ = env.reset(seed=seed)
    trace = [obs]
    for _ in range(steps):
        obs, r, te, tr, info = env.step(rng.uniform(-1, 1, 1).astype(np.float32))
        trace.append(np.concatenate([obs, [r, te, tr]]))
        if te or tr:
            obs, _ = env.reset()
            trace.append(obs)
    return trace


@pytest.mark.parametrize("kwargs", CONFIGS)
def test_seeded_runs_are_identical(kwargs):
    a = _rollout(gym.make("SaddleTrap-v0", **kwargs), seed=11)
    b = _rollout(gym.make("SaddleTrap-v0", **kwargs), seed=11)
    assert all(np.array_equal(x, y) for x, y in zip(a, b)) and len(a) == len(b)
    c = _rollout(gym.make("SaddleTrap-v0", **kwargs), seed=12)
    assert not np.array_equal(a[0], c[0])


@pytest.mark.parametrize("kwargs", [CONFIGS[0], CONFIGS[2], CONFIGS[3]])
def test_vector_equals_single_step_by_step_with_autoreset(kwargs):
    n, steps = 4, 250
    # harsh starts, many balls lost and autoreset (faster ones at 3 cm, up to 40 rad/s, would
    # be flung off at t = 0 on the smallest saddles, a start reset refuses)
    kw = dict(kwargs, omega0_range=(8.0, 20.0), init_offset=0.03)
    venv = gym.make_vec("SaddleTrap-v0", num_envs=n, max_episode_steps=60, **kw)
    assert isinstance(venv, SaddleTrapVectorEnv)
    singles = [gym.make("SaddleTrap-v0", max_episode_steps=60, **kw) for _ in range(n)]
    vo, _ = venv.reset(seed=5)
    so = np.array([s.reset(seed=5 + i)[0] for i, s in enumerate(singles)])
    assert np.array_equal(vo, so)
    rng = np.random.default_rng(1)
    pending = [False] * n
    resets = 0
    for _ in range(steps):
        acts = rng.uniform(-1, 1, size=(n, 1)).astype(np.float32)
        vo, vr, vt, vtr, vinfo = venv.step(acts)
        for i, s in enumerate(singles):
            if pending[i]:
                o, _ = s.reset()
                r, te, tr = 0.0, False, False
                pending[i] = False
                resets += 1
            else:
                o, r, te, tr, info = s.step(acts[i])
                pending[i] = te or tr
                if te:
                    assert vinfo["cause"][i] == info["cause"]
                    assert vinfo["event_time"][i] == info["event_time"]
            # truncated as Gymnasium's TimeLimit has it: also where the ball is lost on the
            # last step
            assert np.array_equal(o, vo[i]) and r == vr[i] and te == vt[i] and tr == vtr[i]
    assert resets >= 4  # the autoreset path was exercised


def test_finished_balls_are_not_integrated_until_reset():
    venv = SaddleTrapVectorEnv(num_envs=2, max_episode_steps=None)
    venv.reset(seed=0, options={"x": 0.005, "y": 0.005, "R": 0.033, "omega": 30.0,
                                "start": "rotating-rest"})
    for _ in range(30):
        _, _, term, _, info = venv.step(np.zeros((2, 1), np.float32))
        if term.all():
            break
    assert term.all() and list(info["cause"]) == ["detach", "detach"]
    frozen = venv.engine.Y.copy()
    venv.engine.step(np.zeros(2), np.zeros(2, dtype=bool), venv._rngs)  # nothing active
    assert np.array_equal(venv.engine.Y, frozen)
    obs, rew, term, trunc, _ = venv.step(np.zeros((2, 1), np.float32))  # the autoreset step
    assert np.all(rew == 0) and not term.any() and not trunc.any()
    assert np.all(venv.engine.balls[:, 2] == 0.0)  # clocks restarted


def test_zero_action_keeps_omega_and_reproduces_the_simulator():
    env = gym.make("SaddleTrap-v0", rtol=1e-12)
    opts = {"x": 0.004, "y": -0.002, "vx": 0.01, "vy": 0.0, "omega": 22.0}
    env.reset(seed=0, options=opts)
    scene = env.unwrapped.scene
    traj = se.simulate(scene, se.initial_state(scene, 0.004, -0.002, 0.01, 0.0), 2.0,
                       omega=22.0, dt_out=0.02, rtol=1e-12)
    for k in range(1, 101):
        _, _, te, tr, info = env.step(ZERO)
        assert info["omega"] == 22.0 and not te
        assert np.allclose(env.unwrapped.state, traj.state[k], rtol=0, atol=1e-9)
    assert info["N_over_mg"] == pytest.approx(traj.N_over_mg[-1], abs=1e-8)


def test_saddle_sim_cli_matches_the_environment(capsys):
    import json

    from saddle_env.cli import main
    main(["--format", "json", "--R", "0.0265", "--x0", "0.004", "--y0", "0.002", "--omega", "20",
          "--t-end", "1", "--dt-out", "0.02", "--rtol", "1e-12"])
    data = json.loads(capsys.readouterr().out)
    env = gym.make("SaddleTrap-v0", rtol=1e-12)
    env.reset(seed=0, options={"x": 0.004, "y": 0.002, "vx": 0.0, "vy": 0.0, "omega": 20.0})
    for k in range(1, 51):
        env.step(ZERO)
        x, y = env.unwrapped.state[:2]
        assert abs(x - data["x"][k]) < 1e-9 and abs(y - data["y"][k]) < 1e-9


def test_detaching_ball_terminates_with_the_located_time():
    env = gym.make("SaddleTrap-v0")
    opts = {"x": 0.005, "y": 0.005, "R": 0.033, "omega": 30.0, "start": "rotating-rest"}
    env.reset(seed=0, options=opts)
    total = 0.0
    for _ in range(100):
        _, r, te, tr, info = env.step(ZERO)
        total += r
        if te:
            break
    assert te and not tr and info["cause"] == "detach"
    exact = se.simulate(se.Scene(R=0.033), se.initial_state(se.Scene(R=0.033), 0.005, 0.005),
                        1.0, omega=30.0, rtol=1e-13).event.t
    assert abs(info["event_time"] - exact) < 1e-9
    assert info["N_over_mg"] == 0.0
    # reward: the trapped time in control periods, minus the loss penalty
    assert total == pytest.approx(exact / 0.02 - 10.0, abs=1e-6)
    with pytest.raises(RuntimeError, match="reset"):
        env.unwrapped.step(ZERO)


def test_escape_terminates():
    env = gym.make("SaddleTrap-v0", rim_radius=0.03)
    env.reset(seed=0, options={"x": 0.01, "y": 0.0, "omega": 5.0, "R": 0.02})
    for _ in range(200):
        _, _, te, _, info = env.step(ZERO)
        if te:
            break
    assert te and info["cause"] == "escape"
    assert np.hypot(*env.unwrapped.state[:2]) == pytest.approx(0.03, abs=1e-9)


def test_default_accuracy_over_a_whole_episode():
    """Position error < 1e-6 m over a default (500-step) episode against a tight solve of
    the same scene and action sequence, on balls that stay trapped throughout."""
    n = 16
    venvs = [SaddleTrapVectorEnv(num_envs=n), SaddleTrapVectorEnv(num_envs=n, rtol=1e-13)]
    for v in venvs:
        v.reset(seed=3)
    rng = np.random.default_rng(0)
    alive = np.ones(n, dtype=bool)
    worst = 0.0
    for _ in range(500):
        a = rng.uniform(-1, 1, (n, 1)).astype(np.float32)
        outs = [v.step(a) for v in venvs]
        alive &= ~(outs[0][2] | outs[1][2])  # drop balls lost in either run
        diff = np.abs(venvs[0].engine.Y[alive, :2] - venvs[1].engine.Y[alive, :2])
        worst = max(worst, diff.max(initial=0.0))
    assert alive.sum() >= n // 2
    assert worst < 1e-6, worst


def test_target_mode_reaches_the_target_at_the_motor_limit():
    env = gym.make("SaddleTrap-v0", action_mode="target", max_accel=20.0)
    env.reset(seed=0, options={"omega": 20.0})
    _, _, _, _, info = env.step(np.array([0.0], np.float32))  # target 22.5
    assert info["omega"] == pytest.approx(20.4)  # 20 rad/s² for 20 ms
    for _ in range(10):
        _, _, _, _, info = env.step(np.array([0.0], np.float32))
    assert info["omega"] == pytest.approx(22.5)


def test_acceleration_mode_clips_omega_to_the_motor_range():
    env = gym.make("SaddleTrap-v0", omega_max=30.0, omega0_range=(29.9, 29.9))
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([1.0], np.float32))
    assert info["omega"] == pytest.approx(30.0)
    env.reset(seed=0, options={"omega": 0.1})
    _, _, _, _, info = env.step(np.array([-1.0], np.float32))
    assert info["omega"] == 0.0


def test_lab_frame_observation_is_the_rotated_rotating_one():
    rot = gym.make("SaddleTrap-v0")
    lab = gym.make("SaddleTrap-v0", obs_frame="lab")
    o_r, _ = rot.reset(seed=4)
    o_l, _ = lab.reset(seed=4)
    for _ in range(20):
        o_r, *_ = rot.step(np.array([0.5], np.float32))
        o_l, *_ = lab.step(np.array([0.5], np.float32))
    c, s = o_l[4], o_l[5]
    omega = o_r[4] * 45.0
    # positions rotate by θ; velocities also gain Ω k×c (scaled: rim 0.1 m, 1 m/s)
    assert np.allclose(o_l[:2], [c * o_r[0] - s * o_r[1], s * o_r[0] + c * o_r[1]], atol=1e-6)
    ux = o_r[2] - omega * 0.1 * o_r[1]
    uy = o_r[3] + omega * 0.1 * o_r[0]
    assert np.allclose(o_l[2:4], [c * ux - s * uy, s * ux + c * uy], atol=1e-5)
    assert o_l[6] == o_r[4]


def test_disturbances_change_the_run_and_default_is_undisturbed():
    calm = _rollout(gym.make("SaddleTrap-v0"), seed=2, steps=50)
    windy = _rollout(gym.make("SaddleTrap-v0", air_force=0.2), seed=2, steps=50)
    assert np.array_equal(calm[0], windy[0]) is False or True  # same start draws aside
    assert not np.allclose(calm[-1][:4], windy[-1][:4])
    env = gym.make("SaddleTrap-v0", ripple_amp=1.0, ripple_freq=40.0)
    env.reset(seed=0, options={"omega": 20.0})
    seen = {round(float(env.step(ZERO)[0][4]) * 45.0, 6) for _ in range(20)}
    assert max(seen) - min(seen) > 1.0  # the tachometer sees the ripple


def test_domain_randomisation_draws_the_papers_balls():
    env = gym.make("SaddleTrap-v0", ball_radii=PAPER_BALL_RADII, contact_models=("rolling", "point"))
    seen_R, seen_c = set(), set()
    env.reset(seed=0)
    for _ in range(40):
        env.reset()
        seen_R.add(env.unwrapped.scene.R)
        seen_c.add(env.unwrapped.scene.contact)
    assert seen_R == set(PAPER_BALL_RADII) and seen_c == {"rolling", "point"}


@pytest.mark.parametrize("action, message", [
    (np.array([np.nan], np.float32), "finite"),
    (np.array([0.1, 0.2], np.float32), "shape"),
    (np.zeros((2, 2)), "shape"),
    ("fast", "numeric"),
    (None, "numeric|shape|finite"),
])
def test_bad_actions(action, message):
    env = gym.make("SaddleTrap-v0").unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match=message):
        env.step(action)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(6,), (6, 1)])
def test_vector_actions_fast_path_checks_and_clips_like_the_general_one(dtype, shape):
    """Float arrays of shape (n,) or (n, 1) take a compiled check; the result must equal
    the general path's (here fed a list) and a NaN anywhere must be refused."""
    values = np.array([0.3, -7.0, 2.5, -0.0, 1.0, -1.0])
    envs = [SaddleTrapVectorEnv(num_envs=6) for _ in range(2)]
    for e in envs:
        e.reset(seed=5)
    fast = envs[0].step(values.astype(dtype).reshape(shape))
    general = envs[1].step(values.astype(dtype).reshape(shape).tolist())
    assert np.array_equal(fast[0], general[0]) and np.array_equal(fast[4]["omega"],
                                                                  general[4]["omega"])
    bad = values.astype(dtype).reshape(shape).copy()
    bad.flat[4] = np.nan
    with pytest.raises(ValueError, match="finite"):
        envs[0].step(bad)


def test_out_of_range_actions_are_clipped():
    a, b = gym.make("SaddleTrap-v0"), gym.make("SaddleTrap-v0")
    a.reset(seed=0)
    b.reset(seed=0)
    assert a.step(np.array([5.0], np.float32))[4]["omega"] == b.step(np.array([1.0], np.float32))[4]["omega"]


@pytest.mark.parametrize("kwargs, message", [
    (dict(R=0.1), "R must satisfy"),
    (dict(control_period=0.0), "control_period must be > 0"),
    (dict(omega_max=-1.0), "omega_max must be > 0"),
    (dict(action_mode="torque"), "action_mode"),
    (dict(obs_frame="polar"), "obs_frame"),
    (dict(omega0_range=(10.0, 50.0)), "omega0_range must lie"),
    (dict(ball_radii=(0.02, 0.09)), "invalid"),
    (dict(contact_models=("rolling", "gliding")), "contact_models"),
    (dict(method="euler"), "method must be one of"),
    (dict(method="rk4"), "fixed-step"),
    # a substep that no control step could finish within the step limit (hypothesis found
    # 9e-98 s failing mid-step with "non-finite")
    (dict(substep=8.97e-98), "substep must be >= control_period / 100,000"),
    (dict(drilling_friction=1e308), "drilling_friction must satisfy"),  # overflowed mid-step
    (dict(drag_quadratic=1e7), "drag_quadratic must satisfy"),
    # each of these used to overflow in the first step instead (a sweep of every option at 1e30)
    (dict(g=1e30), "g must satisfy"),
    (dict(rolling_resistance=2.0), "rolling_resistance must satisfy"),
    (dict(omega_max=1e30), "omega_max must be <= 1000"),
    (dict(air_force=1e30), "air_force must be <= 1000"),
    (dict(ripple_amp=1e30), "ripple_amp must be <= omega_max"),
    (dict(init_offset=0.2), "init_offset"),
    (dict(init_speed=10.0), "init_speed must be <= omega_max"),
    (dict(wind=1.0), "unknown SaddleTrap option"),
    (dict(render_mode="ascii"), "render_mode"),
])
def test_bad_options(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make("SaddleTrap-v0", **kwargs)


@pytest.mark.parametrize("options, message", [
    ({"x": np.nan}, "finite"),
    ({"speed": 1.0}, "unknown reset option"),
    ({"omega": 99.0}, "omega"),
    ({"start": "thrown"}, "start"),
    ({"R": 0.2}, "R must satisfy"),
    ({"x": 1.0}, "inside the rim"),            # ten times the rim
    ({"y": -0.5}, "inside the rim"),
    ({"x": 0.08, "y": 0.07}, "inside the rim"),  # each inside, together outside
    ({"vx": 1e9}, r"speed sqrt\(vx² \+ vy²\) <= omega_max \* rim_radius"),
    ({"vx": 3.0, "vy": 3.5}, "omega_max"),       # 4.6 m/s > 45 rad/s x 0.1 m
    ({"spin_normal": 1e4}, "spin_normal"),
    ({"x": 0.05, "omega": 45.0}, r"N/mg = -\d"),  # flung off at once
])
def test_bad_reset_options(options, message):
    env = gym.make("SaddleTrap-v0")
    with pytest.raises(ValueError, match=message):
        env.reset(seed=0, options=options)


def test_rgb_rendering_shows_the_ball_moving():
    env = gym.make("SaddleTrap-v0", render_mode="rgb_array")
    env.reset(seed=0, options={"x": 0.02, "y": 0.0, "omega": 20.0})
    first = env.render()
    assert first.shape == (400, 600, 3) and first.dtype == np.uint8
    assert first.std() > 10  # not blank
    for _ in range(10):
        env.step(ZERO)
    later = env.render()
    assert (first != later).any(axis=2).mean() > 0.005
    env.close()


def test_record_video_writes_a_file(tmp_path):
    pytest.importorskip("moviepy")
    from gymnasium.wrappers import RecordVideo
    env = RecordVideo(gym.make("SaddleTrap-v0", render_mode="rgb_array"), str(tmp_path / "v"),
                      episode_trigger=lambda e: True, disable_logger=True)
    env.reset(seed=0)
    for _ in range(30):
        env.step(ZERO)
    env.close()
    videos = list((tmp_path / "v").glob("*.mp4"))
    assert videos and videos[0].stat().st_size > 1000


def test_pickle_round_trip_continues_identically():
    env = gym.make("SaddleTrap-v0")
    env.reset(seed=9)
    for _ in range(5):
        env.step(ZERO)
    clone = pickle.loads(pickle.dumps(env))
    for _ in range(20):
        a, b = env.step(ZERO), clone.step(ZERO)
        assert np.array_equal(a[0], b[0]) and a[1] == b[1]


def test_sb3_adapter_matches_single_envs_and_reports_terminal_observation():
    pytest.importorskip("stable_baselines3")
    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv
    kw = dict(omega0_range=(8.0, 40.0), init_offset=0.03)
    n = 3
    vec = SaddleTrapSB3VecEnv(num_envs=n, max_episode_steps=40, **kw)
    vec.seed(21)
    obs = vec.reset()
    singles = [gym.make("SaddleTrap-v0", max_episode_steps=40, **kw) for _ in range(n)]
    so = [s.reset(seed=21 + i)[0] for i, s in enumerate(singles)]
    assert np.array_equal(obs, np.array(so))
    rng = np.random.default_rng(0)
    dones_seen = 0
    for _ in range(120):
        acts = rng.uniform(-1, 1, (n, 1)).astype(np.float32)
        obs, rew, done, infos = vec.step(acts)
        for i, s in enumerate(singles):
            o, r, te, tr, _ = s.step(acts[i])
            assert r == pytest.approx(rew[i], rel=1e-6) and done[i] == (te or tr)
            if done[i]:
                dones_seen += 1
                assert np.array_equal(infos[i]["terminal_observation"], o)
                assert infos[i]["TimeLimit.truncated"] == (tr and not te)
                o, _ = s.reset()
            assert np.array_equal(obs[i], o)
    assert dones_seen >= 3


def _forked_child(queue):
    from saddle_env import simulate_batch
    from saddle_env.scene import Scene
    env = gym.make_vec("SaddleTrap-v0", num_envs=128)
    env.reset(seed=1)
    obs, *_ = env.step(np.zeros((128, 1), np.float32))
    batch = simulate_batch(Scene(a=0.2), np.full((40, 5), 0.001), 0.1, omega=20.0)
    queue.put((float(obs.sum()), float(np.nansum(batch.state))))


def test_vector_env_and_batch_run_in_a_child_forked_after_threads_were_used():
    """GNU OpenMP cannot run again in a forked child (numba would terminate it): the child's
    vector env falls back to one thread, and `simulate_batch` makes its Python threads
    again (the parent's do not survive the fork); the same numbers."""
    import multiprocessing as mp

    from saddle_env import simulate_batch
    from saddle_env.scene import Scene
    env = gym.make_vec("SaddleTrap-v0", num_envs=128)
    env.reset(seed=1)
    assert env.unwrapped.engine.parallel
    obs, *_ = env.step(np.zeros((128, 1), np.float32))  # parallel kernels have run here
    batch = simulate_batch(Scene(a=0.2), np.full((40, 5), 0.001), 0.1, omega=20.0)
    queue = mp.get_context("fork").Queue()
    child = mp.get_context("fork").Process(target=_forked_child, args=(queue,))
    child.start()
    child.join(300)
    assert child.exitcode == 0
    assert queue.get(timeout=5) == (float(obs.sum()), float(np.nansum(batch.state)))



def _seeded_steps(env_id: str, options: dict | None = None) -> tuple[object, list[tuple]]:
    """Seeded episodes of ``env_id`` under a fixed action pattern: the engine and, per reset
    and step, its outputs."""
    env = gym.make(env_id)
    rows = [(env.reset(seed=7, options=options)[0],)]
    for t in range(60):
        obs, reward, term, trunc, _ = env.step(np.array([np.sin(0.3 * t)], np.float32))
        rows.append((obs, reward, term, trunc))
        if term or trunc:
            rows.append((env.reset(seed=8 + t, options=options)[0],))
    return env.unwrapped.engine, rows


def _assert_identical(own: list[tuple], full: list[tuple]) -> None:
    for a, b in zip(own, full, strict=True):
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("env_id", LEVEL_IDS)
def test_each_levels_own_compiled_step_matches_the_full_kernels(env_id, monkeypatch):
    """A level compiles its step for the contact models it draws (`compilation.specialise`);
    seeded episodes through that copy are the full kernels' to the last bit."""
    from saddle_env.envs import control_step

    monkeypatch.delenv(FULL_KERNELS_ENV)           # the copies (the suite's default)
    engine, own = _seeded_steps(env_id)
    assert engine._S is not control_step                    # a copy, without the other models
    monkeypatch.setenv(FULL_KERNELS_ENV, "1")
    engine, full = _seeded_steps(env_id)
    assert engine._S is control_step
    _assert_identical(own, full)


def test_a_reset_that_brings_another_contact_model_widens_the_compiled_step(monkeypatch):
    """A rolling level's copy has no slipping code: a reset with ``contact="slipping"``
    recompiles the step for both models, and the episodes are the full kernels'."""
    from saddle_env.scene import ROLLING, SLIPPING

    monkeypatch.delenv(FULL_KERNELS_ENV)
    options = {"contact": "slipping"}
    engine, own = _seeded_steps("SaddleTrap-v0", options)
    assert engine._uses == ({ROLLING, SLIPPING}, False)    # no resistance was drawn
    monkeypatch.setenv(FULL_KERNELS_ENV, "1")
    _assert_identical(own, _seeded_steps("SaddleTrap-v0", options)[1])


def test_gym_make_wraps_in_the_time_limit_alone_and_the_env_enforces_the_order():
    """The env checks what OrderEnforcing would (a step or render before reset), so
    gym.make adds TimeLimit only; the passive checker can still be asked for."""
    env = gym.make("SaddleTrap-v0", render_mode="rgb_array")
    assert str(env) == "<TimeLimit<SaddleTrapEnv<SaddleTrap-v0>>>"
    with pytest.raises(RuntimeError, match=r"reset\(\) before step"):
        env.step(ZERO)
    with pytest.raises(RuntimeError, match=r"reset\(\) before render"):
        env.render()
    env.reset(seed=0)
    assert env.render().ndim == 3
    checked = gym.make("SaddleTrap-v0", disable_env_checker=False)
    assert "PassiveEnvChecker" in str(checked)
    checked.reset(seed=0)
    checked.step(ZERO)


def test_a_step_with_the_envs_own_buffers_equals_one_with_fresh_arrays():
    """The engine keeps the last call's arguments when the same arrays come again (the
    single env's step): the run is the one of fresh arrays each step, through a lockstep
    switch and a reset that widens the compiled step in between."""
    def run(fresh: bool):
        env = SaddleTrapEnv()
        env.reset(seed=5)
        engine = env.unwrapped.engine
        rows = []
        for k in range(60):
            if k == 20:
                engine.lockstep = False
            if k == 40:
                env.reset(seed=6, options={"contact": "slipping"})
            if fresh:
                env._action = np.zeros(1)       # a new buffer: the general path
                env._active = np.ones(1, dtype=bool)
            obs, r, te, tr, info = env.step(np.array([0.3 * np.sin(k)], np.float32))
            rows.append((obs, r, te, info, engine.Y[0].copy()))
            if te:
                env.reset(seed=k)
        return rows

    kept, fresh = run(False), run(True)
    for (o1, r1, t1, i1, y1), (o2, r2, t2, i2, y2) in zip(kept, fresh):
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(y1, y2)
        assert (r1, t1, i1) == (r2, t2, i2)


def test_the_steps_info_holds_python_floats_of_the_engines_rows():
    env = gym.make("SaddleTrap-v0")
    env.reset(seed=2)
    _, reward, terminated, _, info = env.step(ZERO)
    e = env.unwrapped.engine
    assert type(reward) is float and type(terminated) is bool
    assert info == {"omega": e.balls[0, 0], "time": pytest.approx(0.02, abs=1e-15),
                    "N_over_mg": e.out[0, 2], "trapped_fraction": 1.0}
    assert all(type(v) is float for v in info.values())
