"""Baselines (agents.control.controllers, agents.control.best_constant, agents.control.mpc,
agents.evaluation.policies) and the
evaluation tool (agents.evaluation.evaluate, saddle-eval)."""

import json
import math

import gymnasium as gym
import numpy as np
import pytest

from agents.control import best_constant as BC
from agents.control import controllers as C
from agents.control import mpc as M
from agents.control import rollout as R
from agents.evaluation import evaluate as E
from agents.evaluation import policies as P
from saddle_env.envs import PAPER_BALL_RADII, EnvConfig
from saddle_env.linear import critical_omega

MODES = [dict(), dict(action_mode="target"), dict(obs_frame="lab"),
         dict(obs_frame="lab", action_mode="target")]
HARD = dict(ball_radii=PAPER_BALL_RADII, air_force=0.2)


def _mpc(config, **kw):
    """The feedback baseline with an explicit reference speed (no best-const search)."""
    return M.ModelPredictiveController(config, omega_ref=kw.pop("omega_ref", 20.0), **kw)


def _run(config, policy, seeds, **kw):
    act, row_independent = E.policy_actor(policy)
    return E.run_episodes(config, act, seeds, row_independent=row_independent, **kw)


# -- the controllers -------------------------------------------------------------------
@pytest.mark.parametrize("kwargs", MODES)
def test_predict_accepts_single_and_batched_observations(kwargs):
    config = EnvConfig(**kwargs)
    env = gym.make("SaddleTrap-v0", **kwargs)
    obs, _ = env.reset(seed=1)
    for policy in (P.load_policy("const-1.2", config), P.load_policy("masspoint", config),
                   _mpc(config)):
        a, _ = policy.predict(obs)
        assert a.shape == (1,) and a.dtype == np.float32 and -1 <= a[0] <= 1
        batch, _ = policy.predict(np.stack([obs, obs, obs]))
        assert batch.shape == (3, 1) and batch.dtype == np.float32
        assert np.all(batch == a[0])  # rows are independent
        assert env.action_space.contains(a)
        with pytest.raises(ValueError, match="observation must have shape"):
            policy.predict(np.zeros(obs.shape[0] + 1))


@pytest.mark.parametrize("kwargs", MODES[:2])
def test_constant_speed_reaches_its_target_at_full_motor_rate_and_holds_it(kwargs):
    config = EnvConfig(**kwargs)
    policy = P.load_policy("const-1.5", config)
    target = 1.5 * critical_omega(config.scene())
    assert policy.omega == pytest.approx(target)
    env = gym.make("SaddleTrap-v0", **kwargs)
    obs, info = env.reset(seed=0, options={"omega": 30.0})
    speeds = []
    for _ in range(150):
        obs, _, _, _, info = env.step(policy.predict(obs)[0])
        speeds.append(info["omega"])
    speeds = np.array(speeds)
    ramp = (30.0 - target) / (config.max_accel * config.control_period)
    n_ramp = math.ceil(ramp - 1e-6)
    # Full deceleration while far from the target, then the target held.
    assert np.allclose(np.diff(speeds[: n_ramp - 1]), -config.max_accel * config.control_period)
    assert np.allclose(speeds[n_ramp:], target, rtol=1e-5)


def test_constant_speed_holds_the_commanded_speed_despite_ripple_and_noise():
    """The observed speed carries the motor's ripple and sensor noise; with its state the
    controller holds the commanded speed (info["omega"]) instead of chasing them."""
    kwargs = dict(ripple_amp=0.5, ripple_freq=20.0, omega_noise=0.2)
    config = EnvConfig(**kwargs)
    policy = P.load_policy("const-1.2", config)
    env = gym.make("SaddleTrap-v0", **kwargs)
    for use_state in (True, False):
        obs, _ = env.reset(seed=3, options={"omega": 16.0})
        state, speeds = None, []
        for _ in range(60):
            action, new_state = policy.predict(obs, state)
            state = new_state if use_state else None
            obs, _, _, _, info = env.step(action)
            speeds.append(info["omega"])
        spread = np.ptp(speeds[10:])
        if use_state:
            assert spread < 1e-9 and abs(speeds[-1] - policy.omega) < 0.5 + 4 * 0.2
        else:
            assert spread > 0.5


def test_thresholds_are_the_papers():
    config = EnvConfig()
    wc = math.sqrt(2 * config.g / (config.a - 2 * config.R))
    assert C.critical_speed(config) == pytest.approx(wc)
    assert P.load_policy("const-1.0", config).omega == pytest.approx(wc)
    assert P.load_policy("masspoint", config).omega == pytest.approx(math.sqrt(2 * config.g / config.a))
    assert P.load_policy("const-2.5", config).omega == pytest.approx(2.5 * wc)
    assert P.load_policy("const-9", config).omega == config.omega_max  # capped


def test_const_1_2_keeps_a_small_offset_ball_in_the_default_task():
    config = EnvConfig()
    res = _run(config, P.load_policy("const-1.2", config), np.arange(20))
    assert res["kept"].mean() >= 0.9
    assert np.all(res["time"] <= 10.0 + 1e-9)


def test_mass_point_threshold_loses_a_large_ball():
    """sqrt(2g/a) is below a 3.3 cm ball's Ω_crt = sqrt(2g/(a − 2R)): the ball escapes."""
    config = EnvConfig(R=0.033)
    policy = P.load_policy("masspoint", config)
    assert policy.omega < 0.8 * critical_omega(config.scene())
    res = _run(config, policy, np.arange(20))
    assert res["kept"].mean() <= 0.1
    assert np.all(res["cause"][~res["kept"]] == "escape")
    # ... while its own threshold (with margin) keeps it.
    res = _run(config, P.load_policy("const-1.2", config), np.arange(20))
    assert res["kept"].mean() >= 0.9


def test_state_estimate_inverts_the_observation():
    """The controller's physics state from an observation is the environment's state
    (position, velocity, spin; the spin about the normal is 0 at a reset)."""
    for kwargs in (dict(), dict(obs_frame="lab"), dict(contact="slipping", R=0.03)):
        config = EnvConfig(**kwargs)
        env = gym.make("SaddleTrap-v0", **kwargs)
        obs, _ = env.reset(seed=4, options={"x": 0.02, "y": -0.01, "vx": 0.1, "vy": 0.05})
        Y, omega = _mpc(config).states(obs[None].astype(float))
        n = env.unwrapped.scene.state_size
        assert np.allclose(Y[0, :n], env.unwrapped.state, rtol=1e-5, atol=1e-6)
        assert omega[0] == pytest.approx(env.unwrapped.omega, rel=1e-6)


def test_mpc_keeps_the_ball_and_damps_the_orbit_in_the_default_task():
    config = EnvConfig()
    seeds = np.arange(4)
    mpc = _run(config, _mpc(config, omega_ref=20.0), seeds, max_episode_steps=300)
    const = _run(config, C.ConstantSpeed(config, 20.0), seeds, max_episode_steps=300)
    assert mpc["kept"].all() and const["kept"].all()
    # Feedback around 20 rad/s keeps the ball closer than holding 20 rad/s.
    assert mpc["mean_r"].mean() < 0.9 * const["mean_r"].mean()


@pytest.mark.slow
def test_mpc_beats_the_best_constant_with_air_currents_and_random_balls():
    config = EnvConfig(**HARD)
    seeds = 1000 + np.arange(40)
    best = BC.best_constant(config)  # shipped in agents/control/best_const.json
    mpc = _run(config, P.load_policy("mpc", config), seeds)
    const = _run(config, C.ConstantSpeed(config, best["omega"]), seeds)
    assert mpc["time"].mean() > const["time"].mean()
    assert mpc["kept"].mean() > const["kept"].mean()


@pytest.mark.slow
def test_mpc_identifies_the_ball_radius():
    config = EnvConfig(**HARD)
    policy = P.load_policy("mpc", config)
    env = gym.make("SaddleTrap-v0", **HARD)
    right = 0
    for seed in range(12):
        obs, _ = env.reset(seed=seed)
        state = None
        for _ in range(50):
            a, state = policy.predict(obs, state)
            obs, _, terminated, _, _ = env.step(a)
            if terminated:
                break
        blocks = state[0, 2 + policy.obs_dim:].reshape(len(policy.radii), 4)
        right += policy.radii[int(np.argmin(blocks[:, 2]))] == env.unwrapped.scene.R
    assert right >= 10


def test_best_constant_search_is_cached(tmp_path, monkeypatch):
    monkeypatch.setattr(BC, "CACHE_FILE", tmp_path / "best.json")
    monkeypatch.setattr(BC, "USER_CACHE_FILE", tmp_path / "user.json")
    monkeypatch.delenv(BC.CACHE_ENV_VAR)       # the default: the first writable file
    config = EnvConfig(R=0.033)
    # 3 episodes x 33 speeds: 99 balls, below the threaded step's 128 (which no build holds
    # and a cold run would compile here, at the start of the suite; test_lockstep.py and
    # test_env.py test it)
    first = BC.best_constant(config, episodes=3, max_episode_steps=100)
    wc = critical_omega(config.scene())
    assert wc < first["omega"] <= config.omega_max and first["kept"] == 1.0
    calls = []
    monkeypatch.setattr(BC, "search_best_constant", lambda *a, **k: calls.append(1))
    again = BC.best_constant(EnvConfig(R=0.033, action_mode="target", loss_penalty=1.0),
                            episodes=3, max_episode_steps=100)
    assert again == first and not calls
    assert json.loads((tmp_path / "best.json").read_text())


def test_the_paired_comparison_keeps_the_grid_choice_unless_beaten_beyond_its_error():
    """Speeds far apart are told apart on common episodes; a speed against itself ties;
    the incumbent is replaced only by a speed that beats it by more than two standard
    errors (issue 44)."""
    config = EnvConfig(R=0.033)
    wc = critical_omega(config.scene())
    slow, good = round(0.5 * wc, 3), round(1.3 * wc, 3)   # below critical: the ball is lost
    res = BC.paired_comparison(config, [slow, good, good], episodes=12, seed=5,
                               max_episode_steps=100, incumbent=slow)
    assert res["omega"] == good and res["ties"] == [good, good]
    rows = {(r["omega"], i): r for i, r in enumerate(res["speeds"])}
    assert rows[(slow, 0)]["difference"] < -2 * rows[(slow, 0)]["se"]
    assert rows[(good, 2)]["difference"] == 0.0
    same = BC.paired_comparison(config, [good, good + 0.001], episodes=12, seed=5,
                                max_episode_steps=100, incumbent=good + 0.001)
    assert same["omega"] == good + 0.001          # not beaten beyond its error: kept
    with pytest.raises(ValueError, match="incumbent must be one of"):
        BC.paired_comparison(config, [good], episodes=4, incumbent=slow)
    with pytest.raises(ValueError, match="episodes must be an integer >= 2"):
        BC.paired_comparison(config, [good], episodes=1)


def test_a_paired_search_is_cached_apart_and_records_its_candidates(tmp_path, monkeypatch):
    monkeypatch.setattr(BC, "CACHE_FILE", tmp_path / "best.json")
    monkeypatch.setattr(BC, "USER_CACHE_FILE", tmp_path / "user.json")
    monkeypatch.delenv(BC.CACHE_ENV_VAR)
    config = EnvConfig(R=0.033)
    grid = BC.best_constant(config, episodes=3, max_episode_steps=100)
    both = BC.best_constant(config, episodes=3, max_episode_steps=100, paired=8)
    assert "paired" not in grid and both["paired"]["episodes"] == 8
    speeds = [r["omega"] for r in both["paired"]["speeds"]]
    assert speeds[0] == grid["omega"] == both["paired"]["incumbent"]
    assert len(speeds) == BC.PAIRED_TOP and both["omega"] in speeds
    assert both["omega"] in both["paired"]["ties"] and both["paired"]["seed"] == BC.SEARCH_SEED + 3
    assert len(json.loads((tmp_path / "best.json").read_text())) == 2   # two keys


def test_the_shipped_cache_holds_every_level_s_paired_best_const():
    """The best-const baseline of each of the five first levels is the paired search's,
    shipped in agents/control/best_const.json (no search at the leaderboard's first use),
    and its recorded comparison says which speeds it could not tell apart."""
    from saddle_env.envs import get_level

    for lid in ("SaddleTrap-v0", "SaddleTrap-Gusty-v0", "SaddleTrap-Capture-v0",
                "SaddleTrap-Storm-v0", "SaddleTrap-Slippery-v0"):
        level = get_level(lid)
        hit = BC.cached_best_constant(level.config(), max_episode_steps=level.max_episode_steps,
                                      paired=BC.PAIRED_EPISODES)
        assert hit is not None, lid
        winner = next(r for r in hit["paired"]["speeds"] if r["omega"] == hit["omega"])
        assert all(r["difference"] <= 2 * r["se"] for r in hit["paired"]["speeds"]), lid
        assert winner["difference"] == 0.0 and hit["omega"] in hit["paired"]["ties"]


def test_load_policy_rejects_unknown_names(tmp_path):
    with pytest.raises(ValueError, match="unknown policy"):
        P.load_policy("nope", EnvConfig())
    bad = tmp_path / "bad.zip"
    bad.write_text("not a zip")
    with pytest.raises(ValueError, match="not a Stable-Baselines3 model"):
        P.load_policy(str(bad), EnvConfig())


@pytest.mark.parametrize("algo", ["PPO", "A2C", "SAC", "TD3", "DDPG"])
def test_sb3_model_files_are_detected_and_evaluated(tmp_path, algo):
    sb3 = pytest.importorskip("stable_baselines3")
    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    env = SaddleTrapSB3VecEnv(num_envs=2)
    kw = {} if algo in ("PPO", "A2C") else dict(buffer_size=100)
    model = getattr(sb3, algo)("MlpPolicy", env, seed=0, **kw)
    path = tmp_path / "model.zip"
    model.save(path)
    assert P.sb3_algorithm(path) == algo
    policy = P.load_policy(str(path), EnvConfig())
    table, _ = E.evaluate([str(path)], EnvConfig(), episodes=3, seed=0, max_episode_steps=20)
    assert table["policies"][0]["kind"] == algo
    assert policy.predict(np.zeros(5, np.float32))[0].shape == (1,)


# -- evaluation ------------------------------------------------------------------------
def test_evaluation_is_deterministic_and_independent_of_batching():
    config = EnvConfig(air_force=0.2)
    specs = ["const-1.2", ("mpc", _mpc(config, omega_ref=15.0))]
    t1, d1 = E.evaluate(specs, config, episodes=4, seed=7, max_episode_steps=100)
    t2, _ = E.evaluate(specs, config, episodes=4, seed=7, max_episode_steps=100)
    assert json.dumps(t1) == json.dumps(t2)
    # Episodes 9 and 10 alone give what they gave in the batch of four.
    for label, policy in (("const-1.2", P.load_policy("const-1.2", config)),
                          ("mpc", _mpc(config, omega_ref=15.0))):
        alone = _run(config, policy, [9, 10], max_episode_steps=100)
        assert np.array_equal(alone["time"], d1[label]["time"][2:])
        assert np.array_equal(alone["mean_r"], d1[label]["mean_r"][2:])


def test_model_files_act_on_fixed_size_chunks(monkeypatch):
    """A batch policy (not row-independent) always sees CHUNK rows, padded."""
    seen = []

    class Batch:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            seen.append(len(obs))
            return np.zeros((len(obs), 1), np.float32), None

    monkeypatch.setattr(R, "CHUNK", 8)
    act, row_independent = E.policy_actor(Batch())
    assert not row_independent
    res = E.run_episodes(EnvConfig(), act, np.arange(11), max_episode_steps=5,
                         row_independent=False)
    assert set(seen) == {8} and len(res["time"]) == 11


def test_intervals():
    w = E.wilson_interval(20, 20)
    assert w["mean"] == 1.0 and w["high"] == 1.0 and 0.8 < w["low"] < 0.85
    times = np.r_[np.full(95, 10.0), np.linspace(1, 5, 5)]
    b = E.bootstrap_interval(times)
    assert b["low"] < b["mean"] < b["high"] <= 10.0  # within the data's range
    assert b == E.bootstrap_interval(times)
    assert E.bootstrap_interval(np.full(7, 10.0)) == {"mean": 10.0, "low": 10.0, "high": 10.0}


def test_saddle_eval_json_output(tmp_path, capsys):
    out = tmp_path / "ev"
    argv = ["--policy", "const-1.2", "--policy", "masspoint", "--episodes", "3", "--seed", "5",
            "--max-episode-steps", "60", "--out", str(out), "--env-kwargs", "R=0.033",
            "omega0_range=[14, 16]", "--no-progress"]
    code = E.main(argv + ["--json"])
    assert code == 0
    captured = capsys.readouterr()
    table = json.loads(captured.out)
    assert table["env_kwargs"] == {"R": 0.033, "omega0_range": [14.0, 16.0]}
    assert table["env_id"] == "SaddleTrap-v0"
    assert table["options"]["R"] == 0.033 and table["options"]["omega0_range"] == [14.0, 16.0]
    assert [p["policy"] for p in table["policies"]] == ["const-1.2", "masspoint"]
    for row in table["policies"]:
        for key in E.METRICS:
            assert set(row[key]) == {"mean", "low", "high"}
            assert row[key]["low"] <= row[key]["mean"] <= row[key]["high"]
    # --json: the table on stdout only; nothing is written (no folder, no plots).
    assert not out.exists()
    # Without --json the same table goes to files, with the plots.
    assert E.main(argv) == 0
    capsys.readouterr()
    assert json.loads((out / "results.json").read_text()) == table
    md = (out / "results.md").read_text()
    assert md.startswith("| policy |") and "masspoint" in md
    for name in ("trapping_time.png", "examples.png", "episodes.json"):
        assert (out / name).stat().st_size > 0


def test_saddle_eval_json_writes_nothing_in_the_working_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert E.main(["--policy", "const-1.2", "--episodes", "2", "--max-episode-steps", "10",
                   "--json", "--no-progress"]) == 0
    assert json.loads(capsys.readouterr().out)["policies"][0]["policy"] == "const-1.2"
    assert list(tmp_path.iterdir()) == []


def test_saddle_eval_env_kwargs_as_json(tmp_path, capsys):
    E.main(["--policy", "const-1.1", "--episodes", "2", "--max-episode-steps", "10", "--json",
            "--no-plots", "--out", str(tmp_path), "--no-progress",
            "--env-kwargs", '{"action_mode": "target", "ball_radii": [0.0223, 0.033]}'])
    table = json.loads(capsys.readouterr().out)
    assert table["env_kwargs"] == {"action_mode": "target", "ball_radii": [0.0223, 0.033]}


@pytest.mark.parametrize("argv, message", [
    (["--policy", "nope"], "unknown policy"),
    (["--policy", "const-1.2", "--episodes", "0"], "--episodes"),
    (["--policy", "const-1.2", "--env-kwargs", "R=-1"], "--env-kwargs"),
    (["--policy", "const-1.2", "--env-kwargs", "bogus=1"], "unknown SaddleTrap option"),
    (["--policy", "const-1.2", "--env-kwargs", "R"], "key=value"),
    (["--policy", "const-1.2", "--env-kwargs", "{bad json"], "JSON"),
    ([], "--policy"),
])
def test_saddle_eval_bad_arguments_exit_2(tmp_path, capsys, argv, message):
    with pytest.raises(SystemExit) as exc:
        E.main(argv + ["--out", str(tmp_path)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_mpc_ramps_the_motor_from_its_set_point_when_the_set_point_is_observed():
    """With ripple, the measured speed is off the motor's set-point; in target mode the motor
    ramps from the set-point, so the mpc's target must lie within one step's ramp of it."""
    import saddle_env  # noqa: F401
    from saddle_env.envs import level_config

    config = level_config("SaddleTrap-Gusty-v0", ball_radii=None)
    policy = _mpc(config, omega_ref=15.0)   # a reference speed without the search
    env = gym.make("SaddleTrap-Gusty-v0", ball_radii=None)
    lay = policy.layout
    step = config.max_accel * config.control_period
    for seed in range(4):
        obs, info = env.reset(seed=seed, options={"omega": float(policy._ref[0])})
        obs = obs.copy()
        for offset in (-1.0, 1.0):   # a ripple of ±1 rad/s on the measured speed
            obs[lay.omega] = (info["omega"] + offset) / config.omega_max
            action, _ = policy.predict(obs)
            target = (float(action[0]) + 1.0) / 2.0 * config.omega_max
            assert abs(target - info["omega"]) <= step + 1e-4, (seed, offset, target)
