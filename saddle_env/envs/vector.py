"""Natively vectorised SaddleTrap: one engine steps every ball through the shared kernel."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from . import DEFAULT_EPISODE_STEPS
from . import _step as S
from .config import EnvConfig
from .engine import TrapEngine
from .saddle_trap import action_space, check_actions, observation_space

if TYPE_CHECKING:
    from .rendering import SaddleRenderer


class SaddleTrapVectorEnv(VectorEnv):
    """``num_envs`` independent SaddleTrap balls stepped as one batch.

    Same options as `SaddleTrapEnv`, plus ``num_envs`` and ``max_episode_steps`` (default
    500; ``None`` for no time limit — truncation is handled here, not by a wrapper). Uses
    next-step autoreset (Gymnasium's default): the step after an episode ends resets that
    ball and returns its first observation with reward 0. Finished balls are not integrated
    until they are reset. Seeding follows ``SyncVectorEnv``: ``reset(seed=s)`` seeds ball i
    with ``s + i``, so ball i reproduces ``gym.make("SaddleTrap-v0").reset(seed=s + i)``
    step by step. Balls are stepped on all cores (numba threads) from 128 balls up.

    ``reset(options={"reset_mask": mask, ...})`` resets only the masked balls; other keys
    place them exactly, as in `SaddleTrapEnv`.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": ["rgb_array"],
                "render_fps": 50}

    def __init__(self, num_envs: int = 1, max_episode_steps: int | None = DEFAULT_EPISODE_STEPS,
                 render_mode: str | None = None, **kwargs: Any):
        self.config = EnvConfig.from_kwargs(**kwargs)
        if max_episode_steps is not None and (
                isinstance(max_episode_steps, bool) or not isinstance(max_episode_steps, (int, np.integer))
                or max_episode_steps < 1):
            raise ValueError(f"max_episode_steps must be a positive integer or None, "
                             f"got {max_episode_steps!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be 'rgb_array' or None, got {render_mode!r}")
        self.engine = TrapEngine(self.config, num_envs)
        self.num_envs = self.engine.n
        self.max_episode_steps = max_episode_steps
        self.render_mode = render_mode
        self.single_observation_space = observation_space(self.config)
        self.single_action_space = action_space()
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._rngs = [seeding.np_random()[0] for _ in range(self.num_envs)]
        self._steps = np.zeros(self.num_envs, dtype=np.int64)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._active = np.ones(self.num_envs, dtype=bool)
        self._action_buf = np.zeros(self.num_envs)
        self._renderer: SaddleRenderer | None = None
        self._started = False

    def reset(self, *, seed: int | list[int | None] | None = None,
              options: dict[str, Any] | None = None):
        if isinstance(seed, (int, np.integer)):
            seeds: list[int | None] = [int(seed) + i for i in range(self.num_envs)]
        elif seed is None:
            seeds = [None] * self.num_envs
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed must be an int, None or {self.num_envs} seeds, got {len(seeds)}")
        opts = dict(options or {})
        mask = np.asarray(opts.pop("reset_mask", np.ones(self.num_envs, dtype=bool)))
        if mask.shape != (self.num_envs,) or mask.dtype != bool:
            raise ValueError(f"reset_mask must be a bool array of shape ({self.num_envs},)")
        idx = np.flatnonzero(mask)
        for i in idx:
            if seeds[i] is not None or not self._started:
                self._rngs[i] = seeding.np_random(seeds[i])[0]
        self.engine.reset(idx, self._rngs, opts)
        self._steps[idx] = 0
        self._autoreset[idx] = False
        self._started = True
        return self.engine.obs.copy(), self._infos(np.zeros(self.num_envs, dtype=bool))

    def step(self, actions):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        a = check_actions(actions, self.num_envs, self._action_buf)
        restart = self._autoreset
        if restart.any():
            self.engine.reset(np.flatnonzero(restart), self._rngs)
            self._steps[restart] = 0
        active = np.logical_not(restart, out=self._active)
        self.engine.step(a, active, self._rngs)
        n = self.num_envs
        terminated, truncated = np.empty(n, dtype=bool), np.empty(n, dtype=bool)
        rewards = np.empty(n)
        S.episode_flags(active, self.engine.out, self._steps, self.max_episode_steps or 0,
                        terminated, truncated, rewards)
        self._autoreset = terminated | truncated
        return (self.engine.obs.copy(), rewards, terminated, truncated, self._infos(terminated))

    def _infos(self, terminated: np.ndarray) -> dict[str, Any]:
        e = self.engine
        info: dict[str, Any] = {"omega": e.balls[:, S.B_OMEGA].copy(),
                                "time": e.balls[:, S.B_TIME].copy(),
                                "N_over_mg": e.out[:, S.O_NORMAL].copy(),
                                "trapped_fraction": e.out[:, S.O_TRAPPED].copy()}
        if terminated.any():
            cause = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(terminated):
                cause[i] = e.cause(i)
            info["cause"], info["_cause"] = cause, terminated.copy()
            info["event_time"] = np.where(terminated, info["time"], np.nan)
            info["_event_time"] = terminated.copy()
        return info

    def render(self):
        """Frame of ball 0 (``rgb_array``)."""
        if self.render_mode is None:
            return None
        if self._renderer is None:
            from .rendering import SaddleRenderer
            self._renderer = SaddleRenderer(self.config, self.render_mode)
        e = self.engine
        return (self._renderer.draw(e.scenes[0], e.Y[0], e.balls[0], e.obs[0]),)

    def close_extras(self, **kwargs: Any) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
