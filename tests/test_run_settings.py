"""A run's settings are resolved once and frozen (`TrainSettings.validate`, then
`TrainSettings.with_recipe` gives the `RunSettings` a back end trains with), and the SB3
batch environment takes the config the settings checked instead of checking it again."""

from __future__ import annotations

import dataclasses

import pytest

pytest.importorskip("stable_baselines3")

from agents.training.runs import (  # noqa: E402
    DEFAULT_EVAL_EPISODES,
    DEFAULT_N_ENVS,
    RunSettings,
    TrainSettings,
)


def test_settings_are_frozen_and_validate_returns_a_filled_copy():
    asked = TrainSettings(env_id="SaddleTrap-v0")
    with pytest.raises(dataclasses.FrozenInstanceError):
        asked.n_envs = 3  # type: ignore[misc]
    checked = asked.validate()
    assert asked.max_episode_steps is None       # the request is left as it was
    assert isinstance(checked.max_episode_steps, int) and checked.max_episode_steps > 0


def test_the_recipe_resolves_every_count_once():
    checked = TrainSettings(env_id="SaddleTrap-v0", total_timesteps=4000).validate()
    run = checked.with_recipe({"n_timesteps": 1e6})
    assert isinstance(run, RunSettings) and isinstance(run, TrainSettings)
    assert (run.n_envs, run.total_timesteps, run.eval_freq, run.eval_episodes) == (
        DEFAULT_N_ENVS["sb3"], 4000, 20_000, DEFAULT_EVAL_EPISODES)   # the flag's budget wins
    assert run.max_episode_steps == checked.max_episode_steps
    assert run.hyperparams_used == {"n_timesteps": 1e6}
    with pytest.raises(dataclasses.FrozenInstanceError):
        run.eval_freq = 1  # type: ignore[misc]
    # config.json keeps the same keys as before: one per TrainSettings field
    assert [f.name for f in dataclasses.fields(run)] == [
        f.name for f in dataclasses.fields(TrainSettings)]


def test_a_run_checks_its_environment_once(monkeypatch):
    from saddle_env.envs import EnvConfig

    run = TrainSettings(env_id="SaddleTrap-v0", env_kwargs={"R": 0.03}).validate().with_recipe({})
    checks = []
    original = EnvConfig.__post_init__
    monkeypatch.setattr(EnvConfig, "__post_init__",
                        lambda self: (checks.append(1), original(self))[1])
    first = run.environment()
    assert run.environment() is first and first[1].R == 0.03
    assert len(checks) == 1


def test_the_recipe_needs_validated_settings():
    with pytest.raises(ValueError, match="call validate"):
        TrainSettings(env_id="SaddleTrap-v0").with_recipe({})


def test_the_rllib_runner_count_is_resolved():
    run = TrainSettings(backend="rllib", env_id="SaddleTrap-v0").validate().with_recipe({})
    assert run.env_runners == run.num_env_runners == 2


def test_the_sb3_batch_env_takes_the_checked_config_without_checking_it_again(monkeypatch):
    from agents.training.backends.sb3 import make_vec_env
    from saddle_env.envs import EnvConfig, get_level
    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    config = get_level("SaddleTrap-v0").config(R=0.03)
    checks = []
    original = EnvConfig.__post_init__
    monkeypatch.setattr(EnvConfig, "__post_init__",
                        lambda self: (checks.append(1), original(self))[1])
    env = make_vec_env(2, 0, config, 5)
    assert checks == []
    assert env.venv.config is config
    env.close()
    with pytest.raises(ValueError, match=r"give config or the options \['R'\], not both"):
        SaddleTrapSB3VecEnv(num_envs=1, config=config, R=0.02)
    # options alone are still checked, with the config's own message
    with pytest.raises(ValueError, match="obs_frame"):
        SaddleTrapSB3VecEnv(num_envs=1, obs_frame="sideways")


def test_a_checkpoints_recorded_settings_carry_the_recipe_it_trained_with(tmp_path):
    from agents.training.runs import recorded_settings

    run = TrainSettings(env_id="SaddleTrap-v0", log_dir=str(tmp_path), run_name="r",
                        total_timesteps=4000).validate().with_recipe({"learning_rate": 1e-3,
                                                                     "n_envs": 8})
    folder = run.open_run_folder()
    (folder / "final_model.zip").write_bytes(b"")
    recorded = recorded_settings(folder / "final_model.zip")
    assert recorded.hyperparams_used == {"learning_rate": 1e-3, "n_envs": 8}
    assert (recorded.n_envs, recorded.total_timesteps) == (8, 4000)
    # a config.json from elsewhere whose recipe is not a mapping is refused by name
    (folder / "config.json").write_text((folder / "config.json").read_text().replace(
        '"hyperparams_used": {', '"hyperparams_used": [{').replace('"n_envs": 8\n  }',
                                                                    '"n_envs": 8\n  }]'))
    with pytest.raises(ValueError, match="hyperparams_used"):
        recorded_settings(folder / "final_model.zip")
