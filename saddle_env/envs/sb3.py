"""Stable-Baselines3 ``VecEnv`` over the batch engine (SB3 does not take a Gymnasium
``VectorEnv``). Requires stable-baselines3 (``pip install "saddle-env[train]"``).

SB3's convention is same-step autoreset: when a ball's episode ends, ``step_wait`` returns
the first observation of its next episode and puts the last one in
``info["terminal_observation"]`` (with ``info["TimeLimit.truncated"]`` for time limits).
Wrap with ``VecMonitor`` for episode statistics.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium.utils import seeding
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices

from . import DEFAULT_EPISODE_STEPS
from . import control_step as S
from .config import EnvConfig
from .engine import TrapEngine
from .saddle_trap import action_space, check_actions, observation_space


class SaddleTrapSB3VecEnv(VecEnv):
    """``num_envs`` SaddleTrap balls as an SB3 ``VecEnv``; options as `SaddleTrapEnv`.

    Seeding follows SB3: ``seed(s)`` then ``reset()`` seeds ball i with ``s + i``.

    Parameters
    ----------
    num_envs : int
        The number of balls.
    max_episode_steps : int or None
        The episode length in control steps (None: no limit).
    config : EnvConfig or None
        An `EnvConfig` already checked, used as given (its options are not checked again);
        not together with ``**kwargs``.
    **kwargs
        `EnvConfig` options, as for ``gym.make``.

    Raises
    ------
    ValueError
        If an option is invalid, or both ``config`` and options are given.
    """

    def __init__(self, num_envs: int = 1, max_episode_steps: int | None = DEFAULT_EPISODE_STEPS,
                 *, config: EnvConfig | None = None, **kwargs: Any):
        if config is not None and kwargs:
            raise ValueError(f"give config or the options {sorted(kwargs)}, not both")
        self.config = EnvConfig.from_kwargs(**kwargs) if config is None else config
        self.engine = TrapEngine(self.config, num_envs)
        super().__init__(self.engine.n, observation_space(self.config), action_space())
        self.max_episode_steps = max_episode_steps
        self._rngs = [seeding.np_random()[0] for _ in range(self.num_envs)]
        self._steps = np.zeros(self.num_envs, dtype=np.int64)
        self._active = np.ones(self.num_envs, dtype=bool)
        self._actions = np.zeros(self.num_envs)
        self._action_buf = np.zeros(self.num_envs)

    def reset(self):
        """Reset every ball; returns the observations (SB3's VecEnv API)."""
        for i, s in enumerate(self._seeds):
            if s is not None:
                self._rngs[i] = seeding.np_random(s)[0]
        options = self._options[0] if self._options else {}
        self.engine.reset(np.arange(self.num_envs), self._rngs, options or None)
        self._steps[:] = 0
        self._reset_seeds()
        self._reset_options()
        return self.engine.obs.copy()

    def step_async(self, actions: np.ndarray) -> None:
        """Take the actions of the next `step_wait`, checked."""
        self._actions = check_actions(actions, self.num_envs, self._action_buf).copy()

    def step_wait(self):
        """Step every ball; a finished ball restarts at once (SB3's VecEnv API)."""
        e = self.engine
        e.step(self._actions, self._active, self._rngs)
        self._steps += 1
        terminated = e.out[:, S.O_STATUS] > 0
        if self.max_episode_steps is not None:
            truncated = ~terminated & (self._steps >= self.max_episode_steps)
        else:
            truncated = np.zeros(self.num_envs, dtype=bool)
        dones = terminated | truncated
        rewards = e.out[:, S.O_REWARD].astype(np.float32)
        obs = e.obs.copy()
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        done_idx = np.flatnonzero(dones)
        if len(done_idx):
            for i in done_idx:
                infos[i] = {"terminal_observation": obs[i].copy(),
                            "TimeLimit.truncated": bool(truncated[i]),
                            "cause": e.cause(i) if terminated[i] else "time limit",
                            "event_time": float(e.out[i, S.O_CLOCK])}
            e.reset(done_idx, self._rngs)
            self._steps[done_idx] = 0
            obs[done_idx] = e.obs[done_idx]
        return obs, rewards, dones, infos

    def close(self) -> None:
        """Nothing to close: the balls hold no resources."""
        pass

    # -- the VecEnv attribute protocol: the balls share one config -------------------------
    def _indices(self, indices: VecEnvIndices) -> Sequence[int]:
        if indices is None:
            return range(self.num_envs)
        if isinstance(indices, int):
            return [indices]
        return list(indices)

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The attribute ``attr_name`` of the balls ``indices`` (they share one configuration)."""
        if attr_name == "render_mode":
            return [None for _ in self._indices(indices)]
        if attr_name == "scene":
            return [self.engine.scenes[i] for i in self._indices(indices)]
        value = getattr(self.config, attr_name)
        return [value for _ in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Not available: the options are fixed at construction.

        Raises
        ------
        AttributeError
            Always.
        """
        raise AttributeError("SaddleTrapSB3VecEnv options are fixed at construction; "
                             "build a new one to change them")

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None,
                   **method_kwargs) -> list[Any]:
        """Not available: the balls have no methods of their own.

        Raises
        ------
        AttributeError
            Always.
        """
        raise AttributeError(f"SaddleTrapSB3VecEnv has no per-ball method {method_name!r}")

    def env_is_wrapped(self, wrapper_class, indices: VecEnvIndices = None) -> list[bool]:
        """False for every ball: no ball is wrapped."""
        return [False for _ in self._indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        """None for every ball: the balls do not render."""
        return [None for _ in range(self.num_envs)]
