"""Warm start: the untrained policy's mean action is the level's best constant speed."""

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from agents.training import warm_start as ws  # noqa: E402
from saddle_env.envs import level_config  # noqa: E402


def test_untrained_policy_starts_at_the_best_constant_speed(monkeypatch):
    from stable_baselines3 import PPO

    from agents.control import best_constant
    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    config = level_config("SaddleTrap-Capture-v0")
    monkeypatch.setattr(best_constant, "best_constant", lambda c, **kw: {"omega": 18.0})
    action = ws.warm_start_action(config, "best-const", 500)
    assert action == pytest.approx(2 * 18.0 / config.omega_max - 1)
    env = SaddleTrapSB3VecEnv(4, **config.as_dict())
    model = PPO("MlpPolicy", env, n_steps=8, batch_size=8, seed=0, device="cpu")
    obs = env.reset()
    before, _ = model.predict(obs, deterministic=True)
    assert np.abs(before - action).max() > 0.05  # the untrained network is elsewhere
    ws.apply_warm_start(model, action)
    after, _ = model.predict(obs, deterministic=True)
    # the head's weights are tiny at initialisation: the mean is the bias, to ~1e-2
    assert np.abs(after - action).max() < 0.02


def test_a_voltage_driven_motor_starts_at_the_voltage_of_the_best_constant_speed(monkeypatch):
    """In voltage mode a constant action holds the steady speed K·V: the warm start's action
    is the voltage whose steady speed is the best constant, not the target-speed action."""
    from agents.control import best_constant

    # a motor whose top steady speed (30 rad/s) is below omega_max: the two modes differ
    config = level_config("SaddleTrap-Lab-v0", motor_gain=1.25)
    monkeypatch.setattr(best_constant, "best_constant", lambda c, **kw: {"omega": 18.0})
    action = ws.warm_start_action(config, "best-const", 500)
    top = config.motor_gain * config.voltage_max
    assert top < config.omega_max
    assert action == pytest.approx(2 * 18.0 / top - 1)


def test_warm_start_refuses_what_it_cannot_do():
    with pytest.raises(ValueError, match="warm_start must be one of"):
        ws.warm_start_action(level_config("SaddleTrap-Capture-v0"), "imitate", 500)
    with pytest.raises(ValueError, match="does not set a constant action"):
        ws.warm_start_action(level_config("SaddleTrap-Capture-v0"), "mpc", 500)
    with pytest.raises(ValueError, match="action_mode='target'"):
        ws.warm_start_action(level_config("SaddleTrap-v0"), "best-const", 500)

    class NotOnPolicy:
        policy = object()

    with pytest.raises(ValueError, match="PPO and A2C"):
        ws.apply_warm_start(NotOnPolicy(), 0.0)
    with pytest.raises(ValueError, match=r"\[-1, 1\]"):
        from types import SimpleNamespace

        import torch
        ws.apply_warm_start(SimpleNamespace(policy=SimpleNamespace(
            action_net=torch.nn.Linear(2, 1))), 1.5)


def test_every_level_has_its_best_constant_cached_in_the_repository():
    """No user (nor the main job's warm start) pays the search for a registered level."""
    import json

    from agents.control import best_constant as bc
    from saddle_env.envs import LEVELS

    cached = json.loads(bc.CACHE_FILE.read_text())
    for level in LEVELS:
        key = bc._search_key(level.config(), bc.SEARCH_EPISODES, bc.SEARCH_SEED,
                             level.max_episode_steps)
        assert key in cached, level.id


def test_the_cache_key_ignores_options_at_their_defaults():
    from agents.control import best_constant as bc
    from saddle_env.envs import EnvConfig

    def key(**kw):
        return bc._search_key(EnvConfig(**kw), 64, 1, 500)

    assert key() == key(observe_command=False, obs_history=1)   # defaults spelled out
    assert key() != key(air_force=0.1)
    assert key(action_mode="target") == key()                  # irrelevant to a constant


def test_new_searches_go_to_the_cache_the_environment_names(tmp_path, monkeypatch):
    from agents.control import best_constant as bc
    from saddle_env.envs import EnvConfig

    shipped = bc.CACHE_FILE.read_bytes()
    target = tmp_path / "cache.json"
    monkeypatch.setenv(bc.CACHE_ENV_VAR, str(target))
    monkeypatch.setattr(bc, "search_best_constant",
                        lambda c, e, s, m, paired=0: {"omega": 17.0, "grid": [],
                                                      "mean_time": 1.0})
    config = EnvConfig(R=0.0201)                 # a task no cache has
    assert bc.best_constant(config, max_episode_steps=7)["omega"] == 17.0
    assert bc.CACHE_FILE.read_bytes() == shipped
    monkeypatch.setattr(bc, "search_best_constant", None)   # now it must come from the file
    assert bc.best_constant(config, max_episode_steps=7)["omega"] == 17.0
