"""From a rig's frames to what a controller sees, and from its action to a voltage.

`Observer` turns the frames the loop reads into the observation the level's environment
gives (`saddle_env.envs.observation`): positions in the level's frame (the rotating frame
turned back by the encoder's angle θ, or the laboratory's) scaled by ``rim_radius``, the
tachometer's speed by ``omega_max``, cos θ and sin θ, clipped to the declared box, the last
``obs_history`` frames newest first with a release's first frame repeated, as the
environment's reset repeats it. The camera's latency, pixels and noise are in the frames
already; nothing is added. A frame where tracking lost the ball repeats the last position
seen. On a level that observes velocities (not the Lab level) they are estimated as the
difference of the last two positions over their times: an approximation the environment
does not make.

`as_policy` gives one call signature to the three kinds of controller the loop accepts, and
`EnvConfig.voltage_of_action` turns an action into the voltage, as the level's voltage mode
does.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ..envs import EnvConfig
from ..envs.observation import OMEGA_HIGH, OMEGA_LOW, POS_BOUND, VEL_BOUND, VELOCITY_SCALE, layout
from .interface import Frame


class Observer:
    """The level's observation from a rig's frames (see the module). `reset` at each
    release; `push` each frame read; `observation` is then what the environment would give."""

    def __init__(self, config: EnvConfig):
        self.config = config
        self.layout = layout(config)
        lay = self.layout
        self.needs_theta = not lay.lab_frame or lay.cos is not None
        self._frames: np.ndarray | None = None   # (k, frame_dim) newest first
        self._last: tuple[float, float, float] | None = None   # t, position in the level's frame
        self._velocity = (0.0, 0.0)

    def reset(self) -> None:
        """A new release: no frames yet."""
        self._frames = None
        self._last = None
        self._velocity = (0.0, 0.0)

    @property
    def ready(self) -> bool:
        """Whether a frame with the ball's position has been pushed since the reset."""
        return self._frames is not None

    def push(self, frame: Frame) -> None:
        """Take in one new frame (a frame without a position before the first one that has
        one is ignored: the controller has nothing to act on yet)."""
        c, lay = self.config, self.layout
        theta = frame.theta
        if self.needs_theta and (theta is None or not math.isfinite(theta)):
            raise ValueError("this level observes in the rotating frame or observes the "
                             "saddle's angle: the rig's frames need theta (an encoder's angle)")
        if not math.isfinite(frame.omega):
            raise ValueError(f"the frame at t = {frame.t!r} s has no speed (omega = "
                             f"{frame.omega!r}); the tachometer must give one in every frame")
        tracked = math.isfinite(frame.x) and math.isfinite(frame.y)
        if tracked:
            if lay.lab_frame:
                px, py = frame.x, frame.y
            else:
                assert theta is not None
                ct, st = math.cos(theta), math.sin(theta)
                px, py = ct * frame.x + st * frame.y, -st * frame.x + ct * frame.y
            if self._last is not None and frame.t > self._last[0]:
                dt = frame.t - self._last[0]
                self._velocity = ((px - self._last[1]) / dt, (py - self._last[2]) / dt)
            self._last = (frame.t, px, py)
        elif self._last is None:
            return
        assert self._last is not None
        row = np.empty(lay.frame_dim, dtype=np.float32)
        L = c.rim_radius
        row[0] = min(POS_BOUND, max(-POS_BOUND, self._last[1] / L))
        row[1] = min(POS_BOUND, max(-POS_BOUND, self._last[2] / L))
        if lay.vx is not None:
            vx, vy = self._velocity
            row[2] = min(VEL_BOUND, max(-VEL_BOUND, vx / VELOCITY_SCALE))
            row[3] = min(VEL_BOUND, max(-VEL_BOUND, vy / VELOCITY_SCALE))
        row[lay.omega] = min(OMEGA_HIGH, max(OMEGA_LOW, frame.omega / c.omega_max))
        if lay.cos is not None:
            assert theta is not None
            row[lay.cos], row[lay.cos + 1] = math.cos(theta), math.sin(theta)
        if self._frames is None:
            self._frames = np.tile(row, (lay.frames, 1))
        else:
            self._frames[1:] = self._frames[:-1].copy()
            self._frames[0] = row

    @property
    def observation(self) -> np.ndarray:
        """The environment's observation (float32, ``layout.dim``) after the frames pushed."""
        if self._frames is None:
            raise RuntimeError("no frame with the ball's position yet since the release")
        return self._frames.reshape(-1).copy()


Policy = Callable[[np.ndarray, bool], float]


def as_policy(controller: Any) -> Policy:
    """One signature, ``policy(observation, first) -> action``, for the controllers `run`
    accepts, tried in this order:

    * an object with ``act(observation)`` (`saddle_env.deploy.Controller`); its ``reset()``,
      if it has one, is called at each release's first observation;
    * an object with Stable-Baselines3's ``predict(observation, state=, episode_start=,
      deterministic=True) -> (action, state)`` (an SB3 model, `agents`' ``mpc`` and the
      other controllers of `agents.control`); the state is carried from call to call and
      ``episode_start`` is true at a release's first observation;
    * a plain callable ``f(observation) -> action``.

    The action is a number or an array of one number in [-1, 1] (clipped, as the
    environment clips it); anything else, or NaN, is a ValueError.
    """
    if hasattr(controller, "act"):
        reset = getattr(controller, "reset", None)

        def act(obs: np.ndarray, first: bool) -> float:
            if first and callable(reset):
                reset()
            return _one_action(controller.act(obs))
        return act
    if hasattr(controller, "predict"):
        memory: list[Any] = [None]

        def predict(obs: np.ndarray, first: bool) -> float:
            action, memory[0] = controller.predict(
                obs, state=None if first else memory[0], episode_start=np.array([first]),
                deterministic=True)
            return _one_action(action)
        return predict
    if callable(controller):
        return lambda obs, first: _one_action(controller(obs))
    raise TypeError(f"controller must have act(observation), SB3's predict(observation, ...) "
                    f"or be callable, got {type(controller).__name__}")


def _one_action(action: Any) -> float:
    try:
        arr = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"the controller's action must be a number in [-1, 1], got "
                         f"{action!r}") from None
    if arr.size != 1 or not math.isfinite(float(arr.reshape(-1)[0])):
        raise ValueError(f"the controller's action must be one finite number in [-1, 1], "
                         f"got {action!r}")
    return float(np.clip(np.float32(arr.reshape(-1)[0]), -1.0, 1.0))   # float32, as the env


def constant_voltage(config: EnvConfig, voltage: float) -> Callable[[np.ndarray], float]:
    """A controller that always asks for ``voltage`` [V]: the action of that voltage."""
    action = config.action_of_voltage(voltage)
    return lambda obs: action


__all__ = ["Observer", "Policy", "as_policy", "constant_voltage"]
