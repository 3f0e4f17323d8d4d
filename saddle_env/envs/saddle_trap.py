"""SaddleTrap-v0: keep a ball trapped on a rotating saddle by modulating its speed."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from . import control_step as S
from .config import EnvConfig
from .engine import TrapEngine
from .observation import observation_space

if TYPE_CHECKING:
    from .rendering import SaddleRenderer


# The slots `step` reads, as module constants (a module attribute costs a lookup per step)
_O_STATUS, _O_REWARD, _O_NORMAL, _O_TRAPPED = S.O_STATUS, S.O_REWARD, S.O_NORMAL, S.O_TRAPPED
_O_OMEGA, _O_CLOCK = S.O_OMEGA, S.O_CLOCK


def action_space() -> spaces.Box:
    """The action space of every level: one number in [-1, 1]."""
    return spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)


def check_actions(actions: Any, n: int, out: np.ndarray | None = None) -> np.ndarray:
    """Actions as a float64 (n,) array clipped to [-1, 1]; a clear error for bad input.

    ``out`` (shape (n,), owned by the caller) enables a fast path for the common call (a
    float array of shape (n,) or (n, 1)), which runs every step; the result is then ``out``."""
    if out is not None and type(actions) is np.ndarray and actions.dtype.kind == "f" and \
            (actions.shape == (n,) or actions.shape == (n, 1)):
        if n == 1:  # a plain float is cheaper than a compiled call for one ball
            v = actions.item(0)
            if not math.isfinite(v):
                raise ValueError(f"action must be finite (in [-1, 1]), got {actions!r}")
            out[0] = -1.0 if v < -1.0 else (1.0 if v > 1.0 else v)
            return out
        if not S.clip_actions(actions.reshape(n), out):
            raise ValueError(f"action must be finite (in [-1, 1]), got {actions!r}")
        return out
    try:
        arr = np.asarray(actions, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"action must be numeric with shape {(n, 1) if n > 1 else (1,)}, "
                         f"got {actions!r}") from None
    if arr.size != n or arr.ndim > 2 or (arr.ndim == 2 and arr.shape != (n, 1)) or \
            (arr.ndim == 1 and n > 1 and arr.shape != (n,)):
        want = "(1,)" if n == 1 else f"({n}, 1)"
        raise ValueError(f"action must have shape {want}, got shape {arr.shape}")
    arr = arr.reshape(n)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"action must be finite (in [-1, 1]), got {actions!r}")
    return np.clip(arr, -1.0, 1.0)


class SaddleTrapEnv(gym.Env):
    """A rigid ball on a saddle ``z = x²/a − y²/b`` spinning at Ω(t); the agent sets the motor's
    acceleration (or target speed) to keep the ball near the centre without it jumping off.

    ## Action space
    ``Box(-1, 1, (1,), float32)``. In ``"acceleration"`` mode (default) Ω̇ = action ×
    ``max_accel`` during the next control period, reduced so that Ω stays in
    [0, ``omega_max``]. In ``"target"`` mode the action picks a target speed
    (action + 1)/2 × ``omega_max``, approached at up to ``max_accel``. Ω is piecewise linear
    in time (a motor with a torque limit), so the Euler force is finite and is in the
    dynamics. Out-of-range actions are clipped; NaN or a wrong shape raises ``ValueError``.

    ## Observation space
    float32, what a camera above the saddle and a tachometer report, scaled to order one
    and clipped to the box:

    | index | rotating frame (default) | lab frame (``obs_frame="lab"``) | unit / scale |
    |---|---|---|---|
    | 0, 1 | ball centre x, y | ball centre X, Y | m / ``rim_radius``, box ±2 |
    | 2, 3 | centre velocity vx, vy | centre velocity VX, VY | m/s / 1 m/s, box ±10 |
    | 4, 5 | Ω | cos θ, sin θ (saddle angle) | Ω / ``omega_max``, box [−0.5, 1.5] |
    | 6 | — | Ω | Ω / ``omega_max`` |

    Optional Gaussian sensor noise: ``position_noise`` [m], ``velocity_noise`` [m/s],
    ``omega_noise`` [rad/s].

    ## Rewards
    Per step: the fraction of the control period the ball stayed trapped (1 until it is
    lost), − ``distance_cost``·(r/rim)² (r: contact point's distance from the axis),
    − ``effort_cost``·action², and − ``loss_penalty`` (default 10) in the step the ball is lost.

    ## Starting state
    The ball is placed by hand: contact point uniform in a disc of radius ``init_offset``
    (1 cm), "at rest in the laboratory" by default (``init_start``), plus a random velocity up
    to ``init_speed``; Ω₀ uniform in ``omega0_range`` (15–25 s⁻¹). Domain randomisation
    (off by default): ``ball_radii`` (e.g. the paper's 2.23, 2.65, 3.30 cm), ``a_range``,
    ``contact_models``. ``reset(options={...})`` places the ball exactly: keys ``x, y``
    [m], ``vx, vy`` [m/s] (rotating frame), ``omega``, ``R``, ``a``, ``contact``, ``start``,
    ``spin_normal``.

    ## Episode end
    ``terminated`` when the ball detaches (the normal force crosses 0, located inside the
    step) or its contact point leaves ``rim_radius``; ``truncated`` only by the time limit
    (``max_episode_steps``, 500 steps = 10 s by default, from ``TimeLimit``).

    ## Info
    ``omega`` (commanded speed, rad/s), ``time`` (s), ``N_over_mg`` (normal force / weight
    at the end of the step), ``trapped_fraction``; when terminated, ``cause``
    ("detach" | "escape") and ``event_time`` (s since the episode started, located to 1e-12 s).

    Parameters
    ----------
    render_mode : {"rgb_array", "human"}, optional
        How `render` draws: to an array, or to a window.
    **kwargs
        Every field of `saddle_env.envs.EnvConfig` is a keyword, e.g.
        ``gym.make("SaddleTrap-v0", R=0.033, contact="slipping", action_mode="target")``.

    Raises
    ------
    ValueError
        On an unknown option, a value outside its range, or an unknown render mode.
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 50}

    def __init__(self, render_mode: str | None = None, **kwargs: Any):
        self.config = EnvConfig.from_kwargs(**kwargs)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, "
                             f"got {render_mode!r}")
        self.render_mode = render_mode
        self.metadata = dict(self.metadata, render_fps=round(1.0 / self.config.control_period))
        self.engine = TrapEngine(self.config, 1, parallel=False)
        self.observation_space = observation_space(self.config)
        self.action_space = action_space()
        self._active = np.ones(1, dtype=bool)
        self._action = np.zeros(1)
        self._renderer: SaddleRenderer | None = None
        self._needs_reset = True
        self._was_reset = False  # render needs an episode (`levels.register_levels`)

    @property
    def scene(self):
        """The scene of the current episode (randomised parameters included)."""
        return self.engine.scenes[0]

    @property
    def state(self) -> np.ndarray:
        """Physics state of the ball (see `saddle_env.initial_state`)."""
        return self.engine.Y[0, : self.scene.state_size].copy()

    @property
    def omega(self) -> float:
        """The saddle's speed Ω [rad/s] now."""
        return float(self.engine.balls[0, S.B_OMEGA])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start an episode.

        Parameters
        ----------
        seed : int, optional
            Seeds the episode's random draws (release, randomised parameters, noise).
        options : dict, optional
            Places the ball exactly instead of at random (keys as in the class's "Starting
            state" above).

        Returns
        -------
        observation : numpy.ndarray
            The first observation.
        info : dict
            As described under "Info" above.
        """
        super().reset(seed=seed)
        self.engine.reset(np.array([0]), [self.np_random], options)
        self._needs_reset = False
        self._was_reset = True
        if self._renderer is not None:
            self._renderer.clear()
        if self.render_mode == "human":
            self.render()
        return self.engine.obs[0].copy(), self._info(False)

    def step(self, action):
        """Apply ``action`` for one control period.

        Parameters
        ----------
        action : array_like
            One number in [-1, 1] (its meaning depends on ``action_mode``).

        Returns
        -------
        observation : numpy.ndarray
            The observation at the end of the period.
        reward : float
            The period's reward.
        terminated : bool
            True if the ball detached or escaped.
        truncated : bool
            Always False; ``gym.make``'s time limit truncates.
        info : dict
            As described under "Info" above.

        Raises
        ------
        RuntimeError
            If the episode has ended or not begun (call `reset`).
        """
        if self._needs_reset:
            raise RuntimeError("call reset() before step() (the episode has ended or not begun)")
        a = check_actions(action, 1, self._action)
        e = self.engine
        e.step(a, self._active, [self.np_random])
        # The rows' numbers as Python floats, one call per row (indexing them one by one was
        # a tenth of the step)
        out = e.out[0].tolist()
        terminated = out[_O_STATUS] > 0
        self._needs_reset = terminated
        if self.render_mode == "human":
            self.render()
        return e.obs[0].copy(), out[_O_REWARD], terminated, False, self._info(terminated, out)

    def _info(self, terminated: bool, out: list[float] | None = None) -> dict[str, Any]:
        """The info of the step whose outputs (``engine.out``'s row) are ``out``."""
        e = self.engine
        if out is None:
            out = e.out[0].tolist()
        info: dict[str, Any] = {"omega": out[_O_OMEGA], "time": out[_O_CLOCK],
                                "N_over_mg": out[_O_NORMAL], "trapped_fraction": out[_O_TRAPPED]}
        if terminated:
            info["cause"] = e.cause(0)
            info["event_time"] = info["time"]
        return info

    def render(self):
        """Draw the current frame.

        Returns
        -------
        numpy.ndarray or None
            An RGB array in "rgb_array" mode; None in "human" mode (it draws to a window) or
            without a render mode.

        Raises
        ------
        RuntimeError
            Before the first `reset` (no episode to draw).
        """
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' "
                            "or 'human' to gym.make")
            return None
        if not self._was_reset:
            raise RuntimeError("call reset() before render() (there is no episode to draw)")
        if self._renderer is None:
            from .rendering import SaddleRenderer
            self._renderer = SaddleRenderer(self.config, self.render_mode)
        return self._renderer.draw(self.scene, self.engine.Y[0], self.engine.balls[0],
                                   self.engine.obs[0])

    def close(self):
        """Close the render window, if one is open."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
