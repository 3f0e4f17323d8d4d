"""The observation's layout, declared once: which column holds what, the declared box, and the
inverse a controller needs (reading the speed or the saddle angle back out of a batch).

The compiled step (`control_step.observe_one`) writes the columns at the indices this module puts
into the configuration vector, so the layout lives here only; `states_from_observations`
reads them back into physics states (the model-predictive controller's state estimate).

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

A camera (``observe_velocity=False``) sees positions only: columns 2 and 3 are left out and
every later column moves two to the left (the ball's own spin is never observed). With
``position_quantum`` q [m] the positions, noise included, are rounded to multiples of q (a
pixel's size on the saddle) before scaling.

With ``obs_history`` k > 1 the observation is the last k such frames, newest first
(k·d columns; a new episode starts with its first frame repeated): a controller that must
infer what it cannot see (a steady air current, the ball's size) gets a short memory
without a recurrent network. The indices above are those of the newest frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numba as nb
import numpy as np
from gymnasium import spaces

from .. import kernels as K
from ..scene import P_A, P_B, P_R
from .config import EnvConfig

# Bounds of the scaled observation, shared with the compiled step (it clips to them).
POS_BOUND, VEL_BOUND, OMEGA_LOW, OMEGA_HIGH = 2.0, 10.0, -0.5, 1.5
VELOCITY_SCALE = 1.0  # [m/s] observation scale of velocities (positions: / rim_radius)
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
    vx: int | None = 2         # centre velocity (None: a camera, positions only)
    vy: int | None = 3

    x, y = 0, 1

    @property
    def dim(self) -> int:
        """The observation's length: one frame's times the frames stacked."""
        return self.frame_dim * self.frames

    def speed(self, obs: np.ndarray, omega_max: float) -> np.ndarray:
        """Measured Ω [rad/s] of a batch ``(n, dim)``."""
        return np.asarray(obs)[..., self.omega] * omega_max

    def commanded(self, obs: np.ndarray, omega_max: float) -> np.ndarray | None:
        """Commanded Ω [rad/s] of a batch, or None if the layout has no such column."""
        return None if self.command is None else np.asarray(obs)[..., self.command] * omega_max

    def angle_cos_sin(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The saddle angle's (cos, sin) columns of a batch, or None if the layout has none."""
        if self.cos is None:
            return None
        obs = np.asarray(obs)
        return obs[..., self.cos], obs[..., self.cos + 1]


def layout(config: EnvConfig) -> ObsLayout:
    """The observation layout of ``config`` (see the module's table)."""
    lab = config.obs_frame == "lab"
    vel = 0 if config.observe_velocity else -2   # a camera: no columns 2, 3
    if lab:
        omega, cos, k = 6 + vel, 4 + vel, 7 + vel
    else:
        omega, cos, k = 4 + vel, None, 5 + vel
    command = None
    if config.observe_command:
        command, k = k, k + 1
    if config.observe_angle and not lab:
        cos, k = k, k + 2
    return ObsLayout(frame_dim=k, frames=config.obs_history, omega=omega, cos=cos,
                     command=command, lab_frame=lab, vx=2 if vel == 0 else None,
                     vy=3 if vel == 0 else None)


def observation_space(config: EnvConfig) -> spaces.Box:
    """Declared observation box (scaled units, float32)."""
    lay = layout(config)
    low = np.empty(lay.frame_dim, dtype=np.float32)
    high = np.empty(lay.frame_dim, dtype=np.float32)
    low[:2], high[:2] = -POS_BOUND, POS_BOUND
    if lay.vx is not None:
        low[2:4], high[2:4] = -VEL_BOUND, VEL_BOUND
    low[lay.omega], high[lay.omega] = OMEGA_LOW, OMEGA_HIGH
    if lay.cos is not None:
        low[lay.cos:lay.cos + 2], high[lay.cos:lay.cos + 2] = -1.0, 1.0
    if lay.command is not None:
        low[lay.command], high[lay.command] = 0.0, 1.0
    return spaces.Box(np.tile(low, lay.frames), np.tile(high, lay.frames), dtype=np.float32)


@nb.njit(cache=True)
def _states_from_obs(model, p, lab, L, V, omega_max, obs, cols, spin, Y, omega):
    """Physics states (rotating frame) of balls seen in ``obs``: the contact point from the
    centre (Newton on c(q) = observed centre), its velocity from the centre's
    (ċ = J q̇, horizontal rows), and for a rolling ball the spin of rolling plus ``spin[i]``
    about the normal (the component a camera cannot see). ``cols``: the columns of x, y, vx,
    vy, cos θ (sin θ after it; read in the lab frame only) and the measured Ω."""
    a, b, R = p[P_A], p[P_B], p[P_R]
    kx, ky, kvx, kvy, kcos, komega = cols
    for i in range(obs.shape[0]):
        W = obs[i, komega] * omega_max
        if lab:
            ct, st = obs[i, kcos], obs[i, kcos + 1]
            nrm = math.hypot(ct, st)
            if nrm > 0:
                ct, st = ct / nrm, st / nrm
            else:
                ct, st = 1.0, 0.0
            X, Yl = obs[i, kx] * L, obs[i, ky] * L
            UX, UY = obs[i, kvx] * V, obs[i, kvy] * V
            cx, cy = ct * X + st * Yl, -st * X + ct * Yl
            ux, uy = ct * UX + st * UY, -st * UX + ct * UY
            vcx, vcy = ux + W * cy, uy - W * cx      # ċ = u − Ω k×c
        else:
            cx, cy = obs[i, kx] * L, obs[i, ky] * L
            vcx, vcy = obs[i, kvx] * V, obs[i, kvy] * V
        omega[i] = W
        x, y = cx / (1.0 - 2.0 * R / a), cy / (1.0 + 2.0 * R / b)
        for _ in range(30):
            g = K.geometry(a, b, R, x, y)
            rx, ry = g.cx - cx, g.cy - cy
            J1x, J1y, J2x, J2y = g.J1x, g.J1y, g.J2x, g.J2y
            det = J1x * J2y - J2x * J1y
            dx = (J2y * rx - J2x * ry) / det
            dy = (-J1y * rx + J1x * ry) / det
            x -= dx
            y -= dy
            if abs(dx) + abs(dy) < 1e-15:
                break
        g = K.geometry(a, b, R, x, y)
        J1x, J1y, J2x, J2y = g.J1x, g.J1y, g.J2x, g.J2y
        det = J1x * J2y - J2x * J1y
        vx = (J2y * vcx - J2x * vcy) / det
        vy = (-J1y * vcx + J1x * vcy) / det
        K.state_from_velocity(model, p, x, y, vx, vy, spin[i], Y[i])


def states_from_observations(config: EnvConfig, model: int, params: np.ndarray,
                             obs: np.ndarray, spin: np.ndarray | None = None
                             ) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of the observation: (n, 5) physics states (rotating frame) and (n,)
    measured speeds [rad/s] of balls of contact model ``model`` with packed parameters
    ``params`` (`Scene.params()`), seen in the float64 batch ``obs`` (n, ≥ the newest frame's
    columns); a rolling ball spins by ``spin`` (n,) [rad/s] about the normal (default 0, as
    the environment places balls). A noise-free, unclipped observation gives back the state
    up to its float32 rounding."""
    lay = layout(config)
    if lay.vx is None:
        raise ValueError("states_from_observations needs velocities: this configuration "
                         "observes positions only (observe_velocity=False); estimate them "
                         "from successive positions first")
    n = len(obs)
    Y = np.zeros((n, K.STATE_WIDTH))
    omega = np.zeros(n)
    spin = np.zeros(n) if spin is None else np.ascontiguousarray(spin, float)
    cols = (lay.x, lay.y, lay.vx, lay.vy, -1 if lay.cos is None else lay.cos, lay.omega)
    _states_from_obs(model, params, lay.lab_frame, config.rim_radius, VELOCITY_SCALE,
                     config.omega_max, np.ascontiguousarray(obs), cols, spin, Y, omega)
    return Y, omega


__all__ = ["OBS_MAX", "OMEGA_HIGH", "OMEGA_LOW", "POS_BOUND", "VELOCITY_SCALE", "VEL_BOUND",
           "ObsLayout", "layout", "observation_space", "states_from_observations"]


def stack_frames(batch: np.ndarray, state: Any, episode_start: Any, k: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """A policy's input over its last ``k`` observations, as SB3's VecFrameStack builds it
    (oldest first, zeros at an episode's start): ``batch`` (n, d) the newest observations,
    ``state`` the previous stack (n, k·d) or None, ``episode_start`` which rows begin an
    episode. Returns (inputs, new state), the same array: shipped models trained with
    ``frame_stack`` and their exported folders both act on it."""
    n, d = batch.shape
    stack = np.zeros((n, k * d), np.float32) if state is None else \
        np.array(state, dtype=np.float32).reshape(n, k * d)
    start = np.ones(n, bool) if episode_start is None or state is None else \
        np.asarray(episode_start, dtype=bool).reshape(n)
    stack[start] = 0.0
    stack[:, :-d] = stack[:, d:].copy()   # drop the oldest frame
    stack[:, -d:] = batch
    return stack, stack
