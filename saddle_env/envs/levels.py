"""Registered task levels: each Gymnasium id is a fixed, documented set of `EnvConfig` options.

``gym.make(ID)`` and ``gym.make_vec(ID, num_envs=n)`` build a level with no keywords;
keywords still override single options. A change to a level's meaning (its options, its
observation or its reward) gets a new version number, as Gymnasium does, never a silent edit.

Tools iterate over `LEVELS` rather than over option strings copied from the docs.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from .config import PAPER_BALL_RADII, EnvConfig

DEFAULT_EPISODE_STEPS = 500  # 10 s at the default 20 ms control period


@dataclass(frozen=True)
class Level:
    """One registered task: its id, a one-line summary, what it models and why it is hard,
    and the `EnvConfig` options that define it (everything else at its default)."""

    id: str
    summary: str
    models: str
    why_hard: str
    options: Mapping[str, Any] = field(default_factory=dict)
    max_episode_steps: int = DEFAULT_EPISODE_STEPS

    def config(self, **overrides: Any) -> EnvConfig:
        """The level's options, with ``overrides`` on top, as a validated `EnvConfig`."""
        return EnvConfig.from_kwargs(**{**self.options, **overrides})


def _level(id: str, summary: str, models: str, why_hard: str, **options: Any) -> Level:
    return Level(id, summary, models, why_hard, MappingProxyType(options))


# What a motor controller knows besides the camera: the speed it commands (exact, free of
# ripple and tachometer noise) and the saddle's angle (from the encoder). Every level after
# the calm one observes both.
_CONTROLLER_OBS = dict(observe_command=True, observe_angle=True)

LEVELS: tuple[Level, ...] = (
    _level(
        "SaddleTrap-v0",
        "calm: one ball, no disturbances, the saddle already spinning above threshold",
        "The paper's saddle and its 2.65 cm ball released within 1 cm of the centre at rest in "
        "the laboratory, the saddle at 15-25 rad/s.",
        "It is not: every constant speed from 1.1 Omega_crt to the motor's top speed keeps every "
        "ball. It is the level for checking an agent learns the basics and for benchmarks."),
)

LEVEL_IDS: tuple[str, ...] = tuple(level.id for level in LEVELS)


def get_level(env_id: str) -> Level:
    """The registered level ``env_id``; a clear error naming the known ids otherwise."""
    for level in LEVELS:
        if level.id == env_id:
            return level
    raise ValueError(f"unknown environment id {env_id!r}; registered levels: {list(LEVEL_IDS)}")


def level_config(env_id: str, **overrides: Any) -> EnvConfig:
    """The resolved options of level ``env_id`` with keyword ``overrides``."""
    return get_level(env_id).config(**overrides)


def register_levels() -> None:
    """Register every level with Gymnasium (idempotent)."""
    from gymnasium.envs.registration import register, registry

    for level in LEVELS:
        if level.id not in registry:
            register(id=level.id, entry_point="saddle_env.envs.saddle_trap:SaddleTrapEnv",
                     vector_entry_point="saddle_env.envs.vector:SaddleTrapVectorEnv",
                     max_episode_steps=level.max_episode_steps, kwargs=dict(level.options))


__all__ = ["DEFAULT_EPISODE_STEPS", "LEVELS", "LEVEL_IDS", "Level", "PAPER_BALL_RADII",
           "get_level", "level_config", "register_levels"]
