"""Natively vectorised SaddleTrap: one engine steps every ball through the shared kernel."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from . import DEFAULT_EPISODE_STEPS
from . import control_step as S
from .config import EnvConfig
from .engine import TrapEngine
from .saddle_trap import action_space, check_actions, observation_space

if TYPE_CHECKING:
    from .rendering import SaddleRenderer


# The single env's per-step info entries (each a column of the engine's arrays, `_infos`)
# and their masks.
_INFO_KEYS = ("omega", "time", "N_over_mg", "trapped_fraction")
_INFO_MASKS = tuple("_" + key for key in _INFO_KEYS)


def check_autoreset_mode(value: Any) -> AutoresetMode:
    """``value`` as an `AutoresetMode` (the enum or its string value, e.g. ``"SameStep"``)."""
    if isinstance(value, AutoresetMode):
        return value
    try:
        return AutoresetMode(value)
    except (ValueError, TypeError):
        allowed = ", ".join(f"AutoresetMode.{m.name} ({m.value!r})" for m in AutoresetMode)
        raise ValueError(f"autoreset_mode must be one of {allowed}, got {value!r}") from None


class SaddleTrapVectorEnv(VectorEnv):
    """``num_envs`` independent SaddleTrap balls stepped as one batch.

    Same options as `SaddleTrapEnv`, plus ``num_envs``, ``max_episode_steps`` (default 500;
    ``None`` for no time limit — truncation is handled here, not by a wrapper, and as
    Gymnasium's ``TimeLimit`` does: a ball lost on the last step is terminated and
    truncated) and ``autoreset_mode`` (`gymnasium.vector.AutoresetMode` or its string
    value; ``metadata["autoreset_mode"]`` holds the one in use):

    * ``NEXT_STEP`` (default): the ``step`` after a ball's episode ends resets it (its action
      ignored) and returns its first observation with reward 0, neither terminated nor
      truncated, and its reset info.
    * ``SAME_STEP``: the ``step`` that ends an episode resets the ball at once and returns
      the new episode's first observation and reset info; the last observation is in
      ``info["final_obs"]``, the last step's info in ``info["final_info"]``.
    * ``DISABLED``: the ball waits for ``reset(options={"reset_mask": mask})``; a ``step``
      before that raises ``RuntimeError``.

    Every mode returns what Gymnasium's ``SyncVectorEnv`` in that mode returns over
    ``gym.make`` of the same options, bit for bit, info included (each key with its
    ``_key`` mask). Finished balls are not integrated until they are reset. Seeding follows
    ``SyncVectorEnv``: ``reset(seed=s)`` seeds ball i with ``s + i``, so ball i reproduces
    ``gym.make("SaddleTrap-v0").reset(seed=s + i)`` step by step. Balls are stepped on all
    cores (numba threads) from 128 balls up.

    ``reset(options={"reset_mask": mask, ...})`` resets only the balls where ``mask`` (a
    bool array of shape ``(num_envs,)``) is True, in any mode; other keys place them
    exactly, as in `SaddleTrapEnv`.

    Parameters
    ----------
    num_envs : int
        The number of balls.
    max_episode_steps : int or None
        The episode length in control steps (None: no time limit).
    render_mode : {"rgb_array"}, optional
        `render` draws ball 0 to an array.
    autoreset_mode : AutoresetMode or str
        What happens after a ball's episode ends (above).
    **kwargs
        `EnvConfig` options, as for ``gym.make``.

    Raises
    ------
    ValueError
        On an unknown option, a value outside its range, a bad ``max_episode_steps`` or
        ``render_mode``.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": ["rgb_array"],
                "render_fps": 50}
    # A class default, so that close() (which Gymnasium's __del__ calls) works on an
    # instance whose constructor raised before setting it.
    _renderer: SaddleRenderer | None = None

    def __init__(self, num_envs: int = 1, max_episode_steps: int | None = DEFAULT_EPISODE_STEPS,
                 render_mode: str | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, **kwargs: Any):
        self.autoreset_mode = check_autoreset_mode(autoreset_mode)
        self.metadata = dict(type(self).metadata, autoreset_mode=self.autoreset_mode)
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
        self._all = np.ones(self.num_envs, dtype=bool)  # every ball (never written)
        self._placed = np.zeros(self.num_envs, dtype=bool)  # balls reset at least once
        self._started = False  # every ball placed

    def reset(self, *, seed: int | list[int | None] | None = None,
              options: dict[str, Any] | None = None):
        """Start episodes for every ball, or the balls of ``options["reset_mask"]``.

        Parameters
        ----------
        seed : int or list of (int or None), optional
            An int ``s`` seeds ball i with ``s + i``; a list gives each ball its own seed.
        options : dict, optional
            ``reset_mask`` (a bool array of shape ``(num_envs,)``) picks the balls to reset;
            other keys place them exactly, as in `SaddleTrapEnv.reset`.

        Returns
        -------
        observations : numpy.ndarray
            Shape ``(num_envs, obs_dim)``.
        infos : dict
            Gymnasium's vector infos.

        Raises
        ------
        ValueError
            On a list of the wrong length or a malformed ``reset_mask``.
        """
        if isinstance(seed, (int, np.integer)):
            seeds: list[int | None] = [int(seed) + i for i in range(self.num_envs)]
        elif seed is None:
            seeds = [None] * self.num_envs
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed must be an int, None or {self.num_envs} seeds, got {len(seeds)}")
        opts = dict(options or {})
        if "reset_mask" in opts:
            mask = self._check_reset_mask(opts.pop("reset_mask"))
        else:
            mask = np.ones(self.num_envs, dtype=bool)
        idx = np.flatnonzero(mask)
        for i in idx:
            if seeds[i] is not None or not self._placed[i]:
                self._rngs[i] = seeding.np_random(seeds[i])[0]
        self.engine.reset(idx, self._rngs, opts)
        self._steps[idx] = 0
        self._autoreset[idx] = False
        self._placed[idx] = True
        self._started = bool(self._placed.all())
        return self.engine.obs.copy(), self._infos(mask)

    def _check_reset_mask(self, mask: Any) -> np.ndarray:
        """The ``reset_mask`` option, checked as ``SyncVectorEnv`` checks it."""
        want = f"a numpy bool array of shape ({self.num_envs},) with at least one True"
        if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_ \
                or mask.shape != (self.num_envs,):
            got = f"{type(mask).__name__}" + (f" of dtype {mask.dtype} and shape {mask.shape}"
                                              if isinstance(mask, np.ndarray) else "")
            raise ValueError(f"reset option 'reset_mask' must be {want}, got {got}")
        if not mask.any():
            raise ValueError(f"reset option 'reset_mask' must be {want}, got no True")
        return mask.copy()

    def step(self, actions):
        """Apply one action per ball for one control period.

        Parameters
        ----------
        actions : array_like
            Shape ``(num_envs,)`` or ``(num_envs, 1)``, each in [-1, 1].

        Returns
        -------
        observations : numpy.ndarray
            Shape ``(num_envs, obs_dim)``.
        rewards : numpy.ndarray
            One per ball.
        terminations : numpy.ndarray
            True where the ball detached or escaped.
        truncations : numpy.ndarray
            True where the episode reached ``max_episode_steps``.
        infos : dict
            Gymnasium's vector infos.

        Raises
        ------
        RuntimeError
            Before every ball was reset, or, with ``autoreset_mode`` DISABLED, while a finished
            ball waits for its reset.
        """
        if not self._started:
            never = np.flatnonzero(~self._placed).tolist()
            raise RuntimeError(f"call reset() before step() (balls {never} were never reset)")
        mode = self.autoreset_mode
        # np.count_nonzero, not .any(): a fifth of the cost on small arrays (numpy 2.4),
        # and a one-ball step is some 30 us
        if mode is AutoresetMode.DISABLED and np.count_nonzero(self._autoreset):
            finished = np.flatnonzero(self._autoreset).tolist()
            raise RuntimeError(
                f"balls {finished} ended their episodes and autoreset_mode is DISABLED: reset "
                f"them first with reset(options={{'reset_mask': mask}}), mask True at those balls")
        a = check_actions(actions, self.num_envs, self._action_buf)
        restart = self._autoreset  # all False unless NEXT_STEP (reset on the step after the end)
        if np.count_nonzero(restart):
            self.engine.reset(np.flatnonzero(restart), self._rngs)
            self._steps[restart] = 0
        active = np.logical_not(restart, out=self._active)
        self.engine.step(a, active, self._rngs)
        n = self.num_envs
        terminated, truncated = np.empty(n, dtype=bool), np.empty(n, dtype=bool)
        rewards = np.empty(n)
        S.episode_flags(active, self.engine.out, self._steps, self.max_episode_steps or 0,
                        terminated, truncated, rewards)
        lost = np.count_nonzero(terminated) > 0
        if lost and self.max_episode_steps is not None:
            # TimeLimit's rule: the last step truncates a ball lost in it too (episode_flags
            # leaves those terminated only)
            truncated[terminated & (self._steps >= self.max_episode_steps)] = True
        obs = self.engine.obs.copy()
        ended = terminated | truncated
        if mode is AutoresetMode.SAME_STEP and np.count_nonzero(ended):
            final_info = self._infos(ended, terminated if lost else None)
            final_obs = np.full(n, None, dtype=object)
            done = np.flatnonzero(ended)
            for i in done:
                final_obs[i] = obs[i].copy()
            self.engine.reset(done, self._rngs)
            self._steps[done] = 0
            obs[done] = self.engine.obs[done]
            info = self._infos(self._all)
            info.update(final_obs=final_obs, _final_obs=ended.copy(), final_info=final_info,
                        _final_info=ended.copy())
            self._autoreset = np.zeros(n, dtype=bool)
        else:
            info = self._infos(self._all, terminated if lost else None)
            self._autoreset = ended
        return obs, rewards, terminated, truncated, info

    def _infos(self, rows: np.ndarray, terminated: np.ndarray | None = None) -> dict[str, Any]:
        """The single env's info of the balls ``rows``, batched as ``SyncVectorEnv`` batches
        it: each key an array over all balls (0 or None where a ball has no entry) beside
        its ``_key`` mask; ``cause`` and ``event_time`` where ``terminated``."""
        e = self.engine
        # from ``out``, not ``balls`` (why: `control_step.O_OMEGA`)
        columns = (e.out[:, S.O_OMEGA], e.out[:, S.O_CLOCK], e.out[:, S.O_NORMAL],
                   e.out[:, S.O_TRAPPED])
        every = rows is self._all
        info: dict[str, Any] = {}
        for key, mask, values in zip(_INFO_KEYS, _INFO_MASKS, columns):
            info[key] = values.copy() if every else np.where(rows, values, 0.0)
            info[mask] = rows.copy()
        if terminated is not None:
            cause = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(terminated):
                cause[i] = e.cause(i)
            info["cause"], info["_cause"] = cause, terminated.copy()
            info["event_time"] = np.where(terminated, e.out[:, S.O_CLOCK], 0.0)
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
        """Close the renderer, if one is open."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
