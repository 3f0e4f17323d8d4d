"""Reward shaping for training only: ``reward_shaping`` in a recipe.

The environment's reward is the fraction of the step the ball stayed on, minus
``loss_penalty`` when it is lost: aligned with the trapping time, but a loss is the only
signal, and on the harder levels it comes seconds after the decision that caused it. What
predicts a loss is the size of the orbit (``mpc`` chooses the speed that makes it
smallest). ``reward_shaping: {distance: c}`` subtracts ``c``·(r/rim)² per step from the
*training* rewards (r: the ball centre's distance from the axis in the newest frame, the
observation's own columns), so an action that widens the orbit is penalised at once.

Only the training environment is wrapped: model selection, the comparison, the leaderboard
and every evaluation score the environment's own reward and trapping time, and the level's
options (and so best-const's search and cache) are unchanged.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from saddle_env.envs import EnvConfig
from saddle_env.envs.observation import layout

SHAPING_KEYS = ("distance",)


def check_shaping(value: Any) -> dict[str, float] | None:
    """The validated ``reward_shaping`` mapping (None: none); ValueError otherwise."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise ValueError(f"reward_shaping must be a mapping of {list(SHAPING_KEYS)}, "
                         f"got {value!r}")
    bad = set(value) - set(SHAPING_KEYS)
    if bad:
        raise ValueError(f"reward_shaping: unknown keys {sorted(bad)}; allowed: "
                         f"{list(SHAPING_KEYS)}")
    out = {}
    for key, v in value.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                or v < 0:
            raise ValueError(f"reward_shaping.{key} must be a number >= 0, got {v!r}")
        out[key] = float(v)
    return out


def shape(env: Any, value: Any, config: EnvConfig, training: bool = True) -> Any:
    """``env`` (an SB3 VecEnv of ``config``'s observations) with shaped rewards, or
    ``env`` itself when there is no shaping. ``training=False`` (the evaluation env of a
    shaped run) wraps it in a pass-through instead, so that its wrappers stack as the
    training env's do (SB3 syncs VecNormalize statistics wrapper by wrapper)."""
    settings = check_shaping(value)
    if not settings or settings.get("distance", 0.0) == 0.0:
        return env
    from stable_baselines3.common.vec_env import VecEnvWrapper

    lay = layout(config)
    cost = settings["distance"] if training else 0.0

    class DistanceCost(VecEnvWrapper):
        """Training rewards minus ``cost``·(r/rim)² of the state each step ends in (an
        ended episode's: its last observation)."""

        def reset(self):
            return self.venv.reset()

        def step_wait(self):
            obs, rewards, dones, infos = self.venv.step_wait()
            if cost == 0.0:
                return obs, rewards, dones, infos
            assert isinstance(obs, np.ndarray)  # SaddleTrap's observations: one Box
            last = obs
            if dones.any():
                last = obs.copy()
                for i in np.flatnonzero(dones):
                    last[i] = infos[i]["terminal_observation"]
            r2 = last[:, lay.x] ** 2 + last[:, lay.y] ** 2
            return obs, rewards - np.float32(cost) * r2.astype(np.float32), dones, infos

    return DistanceCost(env)


__all__ = ["SHAPING_KEYS", "check_shaping", "shape"]
