"""Gymnasium environments. Importing `saddle_env` registers every task level (`LEVELS`),
``SaddleTrap-v0`` (the calm level) first."""

from .config import PAPER_BALL_RADII, EnvConfig
from .levels import DEFAULT_EPISODE_STEPS, LEVEL_IDS, LEVELS, Level, get_level, level_config
from .saddle_trap import SaddleTrapEnv

ENV_ID = "SaddleTrap-v0"  # the calm level, the default of every tool


def register() -> None:
    """Register the task levels with Gymnasium (``import saddle_env`` does it)."""
    from .levels import register_levels

    register_levels()


__all__ = ["DEFAULT_EPISODE_STEPS", "ENV_ID", "LEVELS", "LEVEL_IDS", "PAPER_BALL_RADII",
           "EnvConfig", "Level", "SaddleTrapEnv", "get_level", "level_config", "register"]
