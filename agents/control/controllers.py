"""Controllers with Stable-Baselines3's ``predict`` signature: the base class and the
open-loop baselines (constant speeds, zero action, uniform random actions).

Every controller is built from an `EnvConfig` (the nominal scene: its ``a, b, R, g,
contact``) and works in both action modes, both observation frames and any observation
layout (`saddle_env.envs.observation`: commanded speed, saddle angle, frame history), for
one observation ``(obs_dim,)`` or a batch ``(n, obs_dim)``:

| name | what it does |
|---|---|
| ``const-K`` (K = 1.0, 1.1, 1.2, 1.5, 2.0, or any ``const-<number>``) | drive Ω to K·Ω_crt, |
| | Ω_crt = sqrt(2g/(a − 2R)) of the rigid ball (`saddle_env.linear.critical_omega`) |
| ``masspoint`` | drive Ω to sqrt(2g/a), the mass-point threshold (too low for a large ball) |
| ``zero`` | action 0 every step (acceleration mode: hold the starting speed) |
| ``random`` | uniform random actions in [-1, 1] (reproducible: seeded by the observation) |

A constant-speed controller moves Ω to its target as fast as the motor allows
(``max_accel``) and holds it there. The searched best constant lives in
`agents.control.best_constant`, the feedback controller in `agents.control.mpc`, and the registry of
names with model-file loading in `agents.evaluation.policies`.
"""

from __future__ import annotations

import hashlib
import math
import re
from collections.abc import Callable
from typing import Any

import numpy as np

from saddle_env.envs import EnvConfig
from saddle_env.envs.observation import layout, observation_space
from saddle_env.envs.saddle_trap import action_space
from saddle_env.linear import critical_omega

CONST_MULTIPLES = (1.0, 1.1, 1.2, 1.5, 2.0)
_CONST_RE = re.compile(r"^const-(\d+(?:\.\d*)?)$")


# --------------------------------------------------------------------------------------
# Base class
# --------------------------------------------------------------------------------------
class Controller:
    """A deterministic map from observations to actions (SB3's ``predict`` protocol).

    Subclasses implement ``_act(obs, omega) -> (n,) actions`` for a float64 batch ``obs``
    and the observed speed ``omega`` [rad/s]. ``row_independent``: each row's action depends
    on that row only, so a caller may pass any subset of a batch.

    Parameters
    ----------
    config : EnvConfig
        The level the controller acts on (its action mode, motor and observation layout).
    """

    name = "controller"
    row_independent = True

    def __init__(self, config: EnvConfig):
        if not isinstance(config, EnvConfig):
            raise TypeError(f"config must be an EnvConfig, got {type(config).__name__}")
        self.config = config
        # Controllers read the newest frame's camera and speed columns: the first 5, or 7 in
        # the lab frame (`observation.layout`: x, y, vx, vy, [cos θ, sin θ,] measured Ω), two
        # fewer from a camera that sees positions only (``observe_velocity=False``).
        # The observation may hold more (the commanded speed, the angle, older frames),
        # which they accept (``input_dim`` columns) and leave alone.
        self.layout = layout(config)
        self.obs_dim = (7 if config.obs_frame == "lab" else 5) - \
            (0 if config.observe_velocity else 2)
        if self.layout.omega != self.obs_dim - 1:  # the layout moved: the slice below is wrong
            raise RuntimeError(f"observation layout changed: measured speed at column "
                               f"{self.layout.omega}, controllers expect {self.obs_dim - 1}")
        self.input_dim = self.layout.dim
        self.observation_space = observation_space(config)
        self.action_space = action_space()

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """The actions for one observation or a batch (Stable-Baselines3's signature).

        Parameters
        ----------
        observation : array_like
            One observation ``(obs_dim,)`` or a batch ``(n, obs_dim)``.
        state : object, optional
            Passed through (a controller here keeps no recurrent state).
        episode_start : array_like, optional
            Unused; for SB3's signature.
        deterministic : bool
            Unused: the controllers are deterministic.

        Returns
        -------
        actions : numpy.ndarray
            float32 in [-1, 1], ``(1,)`` for one observation, ``(n, 1)`` for a batch.
        state : object
            ``state``, unchanged.
        """
        batch, single = self._batch(observation)
        omega = batch[:, -1] * self.config.omega_max
        return self._out(self._act(batch, omega), single), state

    def _batch(self, observation: Any) -> tuple[np.ndarray, bool]:
        obs = np.asarray(observation, dtype=np.float64)
        single = obs.ndim == 1
        batch = obs.reshape(1, -1) if single else obs
        if batch.ndim != 2 or batch.shape[1] != self.input_dim:
            raise ValueError(f"observation must have shape ({self.input_dim},) or "
                             f"(n, {self.input_dim}) for this configuration (obs_frame="
                             f"{self.config.obs_frame!r}, observe_command="
                             f"{self.config.observe_command}, observe_angle="
                             f"{self.config.observe_angle}, obs_history="
                             f"{self.config.obs_history}), got {obs.shape}")
        return np.ascontiguousarray(batch[:, :self.obs_dim]), single

    @staticmethod
    def _out(actions: np.ndarray, single: bool) -> np.ndarray:
        out = np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0).astype(np.float32)
        out = out.reshape(-1, 1)
        return out[0] if single else out

    def motor_rate(self, omega: np.ndarray, action: np.ndarray) -> np.ndarray:
        """Ω̇ the motor runs at for ``action`` from speed ``omega`` (the environment's rule; a
        voltage-driven motor's at this instant, (K·V − Ω)/τ)."""
        c = self.config
        dt = c.control_period
        if c.action_mode == "voltage":
            return (c.motor_gain * c.voltage_of_action(action) - omega) / c.motor_tau
        if c.action_mode == "target":
            return np.clip((0.5 * (action + 1.0) * c.omega_max - omega) / dt, -c.max_accel,
                           c.max_accel)
        end = np.clip(omega + action * c.max_accel * dt, 0.0, c.omega_max)
        return (end - omega) / dt

    def _act(self, obs: np.ndarray, omega: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def speed_action(self, omega: np.ndarray, target: np.ndarray | float) -> np.ndarray:
        """The action that moves Ω from ``omega`` toward ``target`` as fast as the motor allows
        (a voltage-driven motor: the voltage whose steady speed is ``target``)."""
        c = self.config
        target = np.clip(target, 0.0, c.omega_max)
        if c.action_mode == "target":
            return np.broadcast_to(2.0 * target / c.omega_max - 1.0, np.shape(omega)).copy()
        if c.action_mode == "voltage":
            top = c.motor_gain * c.voltage_max
            return np.broadcast_to(np.minimum(2.0 * target / top - 1.0, 1.0),
                                   np.shape(omega)).copy()
        return np.clip((target - omega) / (c.max_accel * c.control_period), -1.0, 1.0)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


# --------------------------------------------------------------------------------------
# Constant speeds
# --------------------------------------------------------------------------------------
class ConstantSpeed(Controller):
    """Drive Ω to ``omega`` [rad/s] as fast as the motor allows, then hold it.

    In ``acceleration`` mode the observed speed includes the motor's ripple and the sensor
    noise; acting on it would chase them. Given a ``state`` (SB3's recurrent-state slot;
    None at the start, then the returned one, as saddle-eval passes it), the controller
    tracks the commanded speed from its own actions (starting from the first
    observation); without one it acts on the observed speed.
    """

    def __init__(self, config: EnvConfig, omega: float, name: str | None = None):
        super().__init__(config)
        if not 0 <= omega <= config.omega_max:
            raise ValueError(f"constant speed {omega:.4g} rad/s is outside [0, omega_max = "
                             f"{config.omega_max}]")
        self.omega = float(omega)
        self.name = name or f"const-{omega:.3g}rad/s"

    def _act(self, obs: np.ndarray, omega: np.ndarray) -> np.ndarray:
        return self.speed_action(omega, self.omega)

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """The actions for ``observation`` (one or a batch); ``state`` carries the commanded speed."""
        if self.config.action_mode in ("target", "voltage"):  # a constant action holds it
            return super().predict(observation, state, episode_start, deterministic)
        batch, single = self._batch(observation)
        n = len(batch)
        command = np.full(n, np.nan) if state is None else \
            np.array(state, dtype=np.float64).reshape(n)
        if episode_start is not None:
            command[np.asarray(episode_start, dtype=bool).reshape(n)] = np.nan
        command = np.where(np.isnan(command), batch[:, -1] * self.config.omega_max, command)
        out = self._out(self.speed_action(command, self.omega), single)
        sent = out.astype(np.float64).reshape(n)  # what the environment receives
        command = command + self.motor_rate(command, sent) * self.config.control_period
        return out, command.reshape(n, 1)


def critical_speed(config: EnvConfig) -> float:
    """Ω_crt [rad/s] of the nominal scene's rigid ball."""
    return critical_omega(config.scene())


def constant_multiple(k: float) -> Callable[[EnvConfig], ConstantSpeed]:
    """Factory of the ``const-K`` baseline: Ω = K·Ω_crt (capped at ``omega_max``)."""
    name = f"const-{k:.1f}" if round(k, 1) == k else f"const-{k:g}"

    def make(config: EnvConfig) -> ConstantSpeed:
        return ConstantSpeed(config, min(k * critical_speed(config), config.omega_max), name)
    return make


def mass_point(config: EnvConfig) -> ConstantSpeed:
    """Ω = sqrt(2g/a): the mass-point threshold, below a rigid ball's Ω_crt."""
    return ConstantSpeed(config, math.sqrt(2 * config.g / config.a), "masspoint")


def parse_constant(name: str) -> Callable[[EnvConfig], ConstantSpeed] | None:
    """The factory for a ``const-<K>`` name (any K ≥ 0), or None if ``name`` is not one."""
    m = _CONST_RE.match(str(name))
    return constant_multiple(float(m.group(1))) if m else None


# --------------------------------------------------------------------------------------
# Reference points: doing nothing, and acting at random
# --------------------------------------------------------------------------------------
class ZeroAction(Controller):
    """Action 0 at every step: in acceleration mode the starting speed is held; in target
    mode the motor goes to half its top speed. The floor any learned policy must clear."""

    name = "zero"

    def _act(self, obs: np.ndarray, omega: np.ndarray) -> np.ndarray:
        return np.zeros(len(obs))


class UniformRandom(Controller):
    """Uniform random actions in [-1, 1]. Each row's action is drawn from a generator seeded
    by the bytes of its observation, so results are reproducible and do not depend on how
    balls are batched (what saddle-eval's tables rely on)."""

    name = "random"

    def _act(self, obs: np.ndarray, omega: np.ndarray) -> np.ndarray:
        out = np.empty(len(obs))
        for i, row in enumerate(obs):
            key = int.from_bytes(hashlib.blake2b(row.tobytes(), digest_size=8).digest(), "little")
            out[i] = np.random.default_rng(key).uniform(-1.0, 1.0)
        return out


__all__ = ["CONST_MULTIPLES", "ConstantSpeed", "Controller", "UniformRandom", "ZeroAction",
           "constant_multiple", "critical_speed", "mass_point", "parse_constant"]
