"""Warm start by imitating mpc (DAgger): returns, settings, the expert told what the motor
did, and a small run in which the network learns mpc's actions."""

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from agents.training import imitation as im  # noqa: E402
from saddle_env.envs import level_config  # noqa: E402


def test_returns_discount_and_continue_kept_episodes():
    gamma = 0.5
    rewards = np.array([[1.0, 1.0], [1.0, -10.0], [2.0, 0.0]])
    alive = np.array([[True, True], [True, True], [True, False]])
    kept = np.array([True, False])          # ball 0 ran into the time limit, ball 1 was lost
    ret = im.discounted_returns(rewards, alive, kept, gamma)
    tail = 2.0 / (1 - gamma)                # the kept ball's last reward, forever
    assert ret[2, 0] == pytest.approx(2.0 + gamma * tail)
    assert ret[0, 0] == pytest.approx(1.0 + gamma * (1.0 + gamma * ret[2, 0]))
    assert ret[1, 1] == pytest.approx(-10.0)             # no tail after a loss
    assert ret[0, 1] == pytest.approx(1.0 + gamma * -10.0)


def test_settings_are_checked():
    assert im.ImitationSettings.from_hyper(None) == im.ImitationSettings()
    assert im.ImitationSettings.from_hyper({"rounds": 2}).rounds == 2
    with pytest.raises(ValueError, match="unknown keys"):
        im.ImitationSettings.from_hyper({"round": 2})
    with pytest.raises(ValueError, match="imitation.episodes"):
        im.ImitationSettings.from_hyper({"episodes": 0})
    with pytest.raises(ValueError, match="imitation.learning_rate"):
        im.ImitationSettings.from_hyper({"learning_rate": float("nan")})
    with pytest.raises(ValueError, match="mapping"):
        im.ImitationSettings.from_hyper(3)


def test_imitation_without_mpc_warm_start_is_an_error(tmp_path):
    from agents.training.recipes import load_hyperparams

    f = tmp_path / "ppo.yml"
    f.write_text("SaddleTrap-Storm-v0:\n  warm_start: best-const\n  imitation: {rounds: 2}\n")
    with pytest.raises(ValueError, match="only used with warm_start: mpc"):
        load_hyperparams("ppo", "SaddleTrap-Storm-v0", f)


def test_the_watching_expert_predicts_the_step_the_motor_took():
    from agents.control.mpc import ModelPredictiveController
    from saddle_env.envs.vector import SaddleTrapVectorEnv

    config = level_config("SaddleTrap-Storm-v0")
    expert = ModelPredictiveController(config)
    env = SaddleTrapVectorEnv(num_envs=3, **config.as_dict())
    obs, _ = env.reset(seed=[7, 8, 9])
    _, state = expert.predict(obs, None, episode_start=np.ones(3, bool))
    taken = np.array([-1.0, 0.0, 1.0])
    told = expert.executed(state, taken)
    assert not np.array_equal(told, state)
    # Only the action column changed, and it holds what the motor was told.
    changed = np.flatnonzero((told != state).any(axis=0))
    assert len(changed) == 1 and np.array_equal(told[:, changed[0]], taken)


def test_a_short_imitation_brings_the_network_to_mpc():
    import torch
    from stable_baselines3 import PPO

    from agents.control.mpc import ModelPredictiveController
    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    torch.manual_seed(0)
    config = level_config("SaddleTrap-Storm-v0")
    env = SaddleTrapSB3VecEnv(4, **config.as_dict())
    model = PPO("MlpPolicy", env, n_steps=8, batch_size=8, seed=0, device="cpu",
                policy_kwargs={"log_std_init": -2.0})
    log_std = model.policy.log_std.detach().clone()
    # Held-out observations (seeds outside the imitation range) labelled by mpc.
    probe = im.record_round(config, ModelPredictiveController(config), None,
                            np.arange(50, 58), 60, 0.99)
    before = np.mean((im.network_actions(model.policy, probe["obs"]) - probe["action"]) ** 2)
    history = im.imitate(model, config, 60, 0,
                         im.ImitationSettings(rounds=2, episodes=8, epochs=20, batch_size=128),
                         log=lambda *_: None)
    after = np.mean((im.network_actions(model.policy, probe["obs"]) - probe["action"]) ** 2)
    assert [h["driver"] for h in history] == ["mpc", "network"]
    assert history[1]["labels"] > history[0]["labels"]
    assert after < 0.25 * before, (before, after)
    assert torch.equal(model.policy.log_std, log_std)   # exploration noise left alone


def test_with_normalised_observations_the_network_imitates_through_the_normaliser():
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from agents.control.mpc import ModelPredictiveController
    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    torch.manual_seed(0)
    config = level_config("SaddleTrap-Storm-v0")
    env = VecNormalize(SaddleTrapSB3VecEnv(4, **config.as_dict()), norm_reward=False)
    model = PPO("MlpPolicy", env, n_steps=8, batch_size=8, seed=0, device="cpu",
                policy_kwargs={"log_std_init": -2.0})
    assert im.observation_normaliser(model) is env
    probe = im.record_round(config, ModelPredictiveController(config), None,
                            np.arange(50, 58), 60, 0.99)
    im.imitate(model, config, 60, 0,
               im.ImitationSettings(rounds=2, episodes=8, epochs=20, batch_size=128),
               log=lambda *_: None)
    # The statistics are those of mpc's observations, not the untouched (0, 1).
    assert env.obs_rms.count > 100
    assert not np.allclose(env.obs_rms.var, 1.0)
    # The network follows mpc on what RL will feed it: normalised observations.
    seen = np.mean((im.network_actions(model.policy, env.normalize_obs(probe["obs"]))
                    - probe["action"]) ** 2)
    raw = np.mean((im.network_actions(model.policy, probe["obs"]) - probe["action"]) ** 2)
    assert seen < raw, (seen, raw)
    assert seen < 0.1 * np.var(probe["action"]) + 0.05, seen


def test_normaliser_statistics_are_checked():
    class Rms:
        mean, var, count = np.zeros(3), np.ones(3), 1e-4

    class Norm:
        obs_rms = Rms()

    with pytest.raises(ValueError, match="statistics"):
        im.set_statistics(Norm(), np.zeros((5, 4)))
    with pytest.raises(ValueError, match="finite"):
        im.set_statistics(Norm(), np.full((5, 3), np.nan))
    obs = np.arange(15.0).reshape(5, 3)
    im.set_statistics(Norm(), obs)
    assert np.allclose(Norm.obs_rms.mean, obs.mean(axis=0)) and Norm.obs_rms.count == 5
