"""The registered task levels: each id builds with no keywords, passes both checkers, keeps
vector ≡ single, and keywords still override its options."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import saddle_env as se
from saddle_env.envs import LEVEL_IDS, LEVELS, EnvConfig, SaddleTrapEnv, get_level, level_config
from saddle_env.envs.vector import SaddleTrapVectorEnv

IDS = [level.id for level in LEVELS]
# Registered, but the leaderboard (1,000 frozen test episodes per policy) has not been run on
# it yet: its reward threshold is mpc's mean return on design episodes (docs/levels.md). Every
# level is on the board now.
NOT_YET_ON_THE_LEADERBOARD: set[str] = set()


def test_levels_are_registered_unique_and_documented():
    assert IDS[0] == "SaddleTrap-v0"  # the calm level stays first and unchanged
    assert len(set(IDS)) == len(IDS) == len(LEVEL_IDS) >= 4
    assert se.LEVELS is LEVELS
    for level in LEVELS:
        assert level.id in gym.registry
        spec = gym.spec(level.id)
        assert spec.max_episode_steps == level.max_episode_steps
        assert dict(spec.kwargs) == dict(level.options)
        # one line to list, and a physical description and a reason it is hard for the docs
        assert level.summary and "\n" not in level.summary
        assert len(level.models) > 40 and len(level.why_hard) > 40


def test_calm_level_is_the_default_configuration():
    assert level_config("SaddleTrap-v0") == EnvConfig()
    assert get_level("SaddleTrap-v0").options == {}


@pytest.mark.parametrize("env_id", IDS[1:])
def test_non_calm_levels_differ_from_calm_and_observe_the_motor(env_id):
    config = level_config(env_id)
    assert config != EnvConfig()
    # A controller needs what the motor controller knows: its set-point and the angle. A
    # voltage-driven motor (the Lab level) has no set-point but the voltage the controller
    # gave, and its camera sees positions only: x, y, the tachometer, cos θ, sin θ.
    assert config.observe_angle
    if config.action_mode == "voltage":
        assert not config.observe_command and not config.observe_velocity
        width = 5
    else:
        assert config.observe_command
        width = 8
    env = gym.make(env_id)
    assert env.observation_space.shape == (width * config.obs_history,)


@pytest.mark.parametrize("env_id", IDS)
def test_make_without_keywords_passes_both_checkers(env_id):
    env = gym.make(env_id)
    assert env.unwrapped.config == level_config(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    sb3 = pytest.importorskip("stable_baselines3.common.env_checker")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3.check_env(SaddleTrapEnv(**get_level(env_id).options), warn=True)


@pytest.mark.parametrize("env_id", IDS)
def test_keywords_override_one_option_and_keep_the_rest(env_id):
    env = gym.make(env_id, air_force=0.0, max_episode_steps=7)
    config = env.unwrapped.config
    assert config.air_force == 0.0
    assert config == level_config(env_id, air_force=0.0)
    env.reset(seed=0)
    steps = 0
    while True:
        _, _, te, tr, _ = env.step(np.zeros(1, dtype=np.float32))
        steps += 1
        if te or tr:
            break
    assert steps <= 7


@pytest.mark.parametrize("env_id", IDS)
def test_vector_equals_single_per_level(env_id):
    n, steps = 3, 120
    venv = gym.make_vec(env_id, num_envs=n)
    assert isinstance(venv, SaddleTrapVectorEnv)
    assert venv.unwrapped.config == level_config(env_id)
    singles = [gym.make(env_id) for _ in range(n)]
    vo, _ = venv.reset(seed=40)
    so = np.array([s.reset(seed=40 + i)[0] for i, s in enumerate(singles)])
    assert np.array_equal(vo, so)
    rng = np.random.default_rng(3)
    done = np.zeros(n, dtype=bool)
    for _ in range(steps):
        acts = rng.uniform(-1, 1, size=(n, 1)).astype(np.float32)
        vo, vr, vt, vtr, _ = venv.step(acts)
        for i, s in enumerate(singles):
            if done[i]:
                continue  # the vector env autoresets; compare first episodes only
            o, r, te, tr, _ = s.step(acts[i])
            assert np.array_equal(o, vo[i]) and r == vr[i] and te == vt[i] and tr == vtr[i]
            done[i] = te or tr


def test_unknown_level_names_the_registered_ones():
    with pytest.raises(ValueError, match="registered levels.*SaddleTrap-v0"):
        get_level("SaddleTrap-v9")


def test_a_bad_override_names_the_option():
    with pytest.raises(ValueError, match="air_force"):
        level_config(IDS[-1], air_force=-1.0)
    with pytest.raises(ValueError, match="observe_command"):
        level_config(IDS[0], observe_command="yes")


def test_history_holds_the_last_frames_newest_first_in_every_env_kind():
    kw = dict(observe_command=True, observe_angle=True, obs_history=3)
    frame = gym.make("SaddleTrap-v0", observe_command=True, observe_angle=True)
    stacked = gym.make("SaddleTrap-v0", **kw)
    assert stacked.observation_space.shape == (3 * frame.observation_space.shape[0],)
    f0, _ = frame.reset(seed=2)
    s0, _ = stacked.reset(seed=2)
    d = f0.size
    assert np.array_equal(s0, np.tile(f0, 3))  # a new episode: its first frame, three times
    frames = [f0]
    for k in range(4):
        a = np.array([0.3 * (-1) ** k], dtype=np.float32)
        f, *_ = frame.step(a)
        s, *_ = stacked.step(a)
        frames.insert(0, f)
        want = np.concatenate((frames + [frames[-1]] * 3)[:3])
        assert np.array_equal(s, want) and stacked.observation_space.contains(s)
    venv = gym.make_vec("SaddleTrap-v0", num_envs=2, **kw)
    vo, _ = venv.reset(seed=2)
    assert np.array_equal(vo[0], s0) and vo.shape == (2, 3 * d)


def test_commanded_speed_and_angle_columns():
    env = gym.make("SaddleTrap-v0", observe_command=True, observe_angle=True, ripple_amp=2.0,
                   ripple_freq=20.0, omega_noise=0.5, action_mode="target")
    obs, info = env.reset(seed=0)
    for _ in range(10):
        obs, _, _, _, info = env.step(np.array([0.2], dtype=np.float32))
    wmax = env.unwrapped.config.omega_max
    assert obs[5] == pytest.approx(info["omega"] / wmax, rel=1e-6)  # exact set-point
    assert abs(obs[4] * wmax - info["omega"]) > 1e-3                 # measured: ripple + noise
    assert obs[6] ** 2 + obs[7] ** 2 == pytest.approx(1.0, abs=1e-6)


def test_every_scene_parameter_is_an_env_option_with_the_scenes_default_and_check():
    from dataclasses import fields

    from saddle_env.envs.config import PAPER_BALL_RADII, SCENE_FIELDS

    options = {f.name: f.default for f in fields(EnvConfig)}
    scene_defaults = {f.name: f.default for f in fields(se.Scene)}
    assert set(SCENE_FIELDS) == set(scene_defaults) and set(SCENE_FIELDS) <= set(options)
    for name in SCENE_FIELDS:
        want = PAPER_BALL_RADII[1] if name == "R" else scene_defaults[name]
        assert options[name] == want, name
    # the check is the scene's: the same message for the same bad value
    for name, bad in (("alpha", 1.5), ("a", -1.0), ("contact", "sticky")):
        with pytest.raises(ValueError) as env_err:
            EnvConfig(**{name: bad})
        with pytest.raises(ValueError) as scene_err:
            se.Scene(**{name: bad})
        assert str(env_err.value) == str(scene_err.value)


def test_slippery_level_draws_coulomb_balls_whose_low_friction_makes_them_slip():
    level = get_level("SaddleTrap-Slippery-v0")
    lo, hi = level.options["mu_range"]
    env = gym.make(level.id)
    mus = []
    for seed in range(40):
        env.reset(seed=seed)
        scene = env.unwrapped.engine.scenes[0]
        assert scene.contact == "coulomb" and scene.drag_quadratic == 0.2
        assert lo <= scene.mu <= hi and scene.mu_static in (None, scene.mu)
        assert scene.R in level.options["ball_radii"]
        mus.append(scene.mu)
    assert min(mus) < lo + 0.2 * (hi - lo) and max(mus) > hi - 0.2 * (hi - lo)  # uniform-ish

    # The same start as a rolling ball: at the range's top the ball sticks all the way
    # (stick is the rolling model), at its bottom it slips and goes its own way.
    start = {"x": 0.008, "y": 0.004, "omega": 20.0, "R": 0.0265}

    def position_after(steps, **kw):
        e = gym.make(level.id, **kw)
        obs, _ = e.reset(seed=3, options=start)
        for _ in range(steps):
            obs, _, te, tr, _ = e.step(np.zeros(1, dtype=np.float32))
            assert not (te or tr)
        return obs[:2]

    rolling = position_after(100, contact="rolling", mu_range=None)
    assert np.abs(position_after(100, mu_range=[hi, hi]) - rolling).max() < 1e-5
    assert np.abs(position_after(100, mu_range=[lo, lo]) - rolling).max() > 0.05


def test_every_level_has_a_reward_threshold_at_mpcs_test_return():
    """gym.spec(ID).reward_threshold is mpc's mean return on the level's frozen test set
    (docs/leaderboard.json), rounded down to 0.1."""
    import json
    import math
    from pathlib import Path

    board = json.loads((Path(__file__).resolve().parents[1] / "docs" / "leaderboard.json")
                       .read_text())
    for level in LEVELS:
        if level.id in NOT_YET_ON_THE_LEADERBOARD:
            assert level.id not in board["levels"], "on the leaderboard now: check its threshold"
            assert gym.spec(level.id).reward_threshold == level.reward_threshold is not None
            continue
        threshold = gym.spec(level.id).reward_threshold
        assert threshold is not None and threshold == level.reward_threshold
        mpc = next(r for r in board["levels"][level.id]["policies"] if r["policy"] == "mpc")
        assert threshold == math.floor(mpc["return"]["mean"] * 10) / 10, level.id
