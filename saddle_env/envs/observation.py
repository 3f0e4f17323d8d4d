"""The observation's layout, declared once: which column holds what, the declared box, and the
inverse a controller needs (reading the speed or the saddle angle back out of a batch).

The compiled step (`_step.observe_one`) writes the columns at the indices this module puts
into the configuration vector, so the layout lives here only.

| column | rotating frame (default) | lab frame (``obs_frame="lab"``) | scale |
|---|---|---|---|
| 0, 1 | ball centre x, y | X, Y | / ``rim_radius``, box ±2 |
| 2, 3 | centre velocity | lab velocity | / 1 m/s, box ±10 |
| 4 (5) | Ω, measured | cos θ, sin θ | Ω / ``omega_max``, box [−0.5, 1.5] |
| — (6) | | Ω, measured | |
| next | commanded Ω (``observe_command``) | the same | / ``omega_max``, box [0, 1] |
| next two | cos θ, sin θ (``observe_angle``) | — (already there) | box ±1 |

"Measured" Ω carries the motor's ripple and the tachometer's noise; the commanded speed is
what the motor controller asked for, which it knows exactly.

With ``obs_history`` k > 1 the observation is the last k such frames, newest first
(k·d columns; a new episode starts with its first frame repeated): a controller that must
infer what it cannot see (a steady air current, the ball's size) gets a short memory
without a recurrent network. The indices above are those of the newest frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from gymnasium import spaces

from .config import EnvConfig

# Bounds of the scaled observation, shared with the compiled step (it clips to them).
POS_BOUND, VEL_BOUND, OMEGA_LOW, OMEGA_HIGH = 2.0, 10.0, -0.5, 1.5
OBS_MAX = 8  # the widest layout: lab frame + command, or rotating frame + command + angle


@dataclass(frozen=True)
class ObsLayout:
    """Column indices of one configuration's observation, in its newest frame (None: not
    observed); ``dim`` is the width of one frame times ``frames``."""

    frame_dim: int
    frames: int
    omega: int                 # measured speed / omega_max
    cos: int | None            # saddle angle θ: cos θ at ``cos``, sin θ at ``cos + 1``
    command: int | None        # commanded speed / omega_max
    lab_frame: bool

    x, y, vx, vy = 0, 1, 2, 3

    @property
    def dim(self) -> int:
        return self.frame_dim * self.frames

    def speed(self, obs: np.ndarray, omega_max: float) -> np.ndarray:
        """Measured Ω [rad/s] of a batch ``(n, dim)``."""
        return np.asarray(obs)[..., self.omega] * omega_max

    def commanded(self, obs: np.ndarray, omega_max: float) -> np.ndarray | None:
        """Commanded Ω [rad/s] of a batch, or None if the layout has no such column."""
        return None if self.command is None else np.asarray(obs)[..., self.command] * omega_max

    def angle_cos_sin(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        if self.cos is None:
            return None
        obs = np.asarray(obs)
        return obs[..., self.cos], obs[..., self.cos + 1]


def layout(config: EnvConfig) -> ObsLayout:
    """The observation layout of ``config`` (see the module's table)."""
    lab = config.obs_frame == "lab"
    if lab:
        omega, cos, k = 6, 4, 7
    else:
        omega, cos, k = 4, None, 5
    command = None
    if config.observe_command:
        command, k = k, k + 1
    if config.observe_angle and not lab:
        cos, k = k, k + 2
    return ObsLayout(frame_dim=k, frames=config.obs_history, omega=omega, cos=cos,
                     command=command, lab_frame=lab)


def observation_space(config: EnvConfig) -> spaces.Box:
    """Declared observation box (scaled units, float32)."""
    lay = layout(config)
    low = np.empty(lay.frame_dim, dtype=np.float32)
    high = np.empty(lay.frame_dim, dtype=np.float32)
    low[:2], high[:2] = -POS_BOUND, POS_BOUND
    low[2:4], high[2:4] = -VEL_BOUND, VEL_BOUND
    low[lay.omega], high[lay.omega] = OMEGA_LOW, OMEGA_HIGH
    if lay.cos is not None:
        low[lay.cos:lay.cos + 2], high[lay.cos:lay.cos + 2] = -1.0, 1.0
    if lay.command is not None:
        low[lay.command], high[lay.command] = 0.0, 1.0
    return spaces.Box(np.tile(low, lay.frames), np.tile(high, lay.frames), dtype=np.float32)


__all__ = ["OBS_MAX", "OMEGA_HIGH", "OMEGA_LOW", "POS_BOUND", "VEL_BOUND", "ObsLayout", "layout",
           "observation_space"]
