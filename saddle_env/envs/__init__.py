"""Gymnasium environments. Importing `saddle_env` registers ``SaddleTrap-v0``."""

from .config import PAPER_BALL_RADII, EnvConfig
from .saddle_trap import SaddleTrapEnv

ENV_ID = "SaddleTrap-v0"
DEFAULT_EPISODE_STEPS = 500  # 10 s at the default 20 ms control period


def register() -> None:
    from gymnasium.envs.registration import register as gym_register
    from gymnasium.envs.registration import registry

    if ENV_ID not in registry:
        gym_register(id=ENV_ID, entry_point="saddle_env.envs.saddle_trap:SaddleTrapEnv",
                     vector_entry_point="saddle_env.envs.vector:SaddleTrapVectorEnv",
                     max_episode_steps=DEFAULT_EPISODE_STEPS)


__all__ = ["ENV_ID", "PAPER_BALL_RADII", "EnvConfig", "SaddleTrapEnv", "register"]
