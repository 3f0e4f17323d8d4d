"""Shared test helpers (not physics: only evaluation of the shared kernels)."""

from __future__ import annotations

import numpy as np

from saddle_env import _kernels as K
from saddle_env.scene import Scene


def padded(state: np.ndarray) -> np.ndarray:
    out = np.zeros(K.STATE_WIDTH)
    out[: len(state)] = state
    return out


def centre_state(scene: Scene, state: np.ndarray) -> np.ndarray:
    """(c_x, c_y, ċ_x, ċ_y) of the exact model for a state vector."""
    y = padded(state)
    p = scene.params()
    geo = K.geometry(p[0], p[1], p[2], y[0], y[1])
    vx, vy = K.contact_velocity(scene.model_code, p, y)
    J1x, J1y, J2x, J2y = geo[7], geo[8], geo[10], geo[11]
    return np.array([geo[4], geo[5], J1x * vx + J2x * vy, J1y * vx + J2y * vy])


def rhs(scene: Scene, state: np.ndarray, omega: float | np.ndarray = 0.0, t: float = 0.0) -> np.ndarray:
    prof = np.zeros(K.DRIVE_WIDTH)
    if np.isscalar(omega):
        prof[0] = omega
    else:
        prof[: len(omega)] = omega
    dy = np.zeros(K.STATE_WIDTH)
    K.rhs(scene.model_code, scene.params(), prof, t, padded(state), dy, False)
    return dy[: scene.state_size]


def fd_linearisation(scene: Scene, omega: float, spin_z: float = 0.0, eps: float = 1e-7) -> np.ndarray:
    """4x4 matrix of the exact model linearised at the saddle point, in centre coordinates
    (x_c, y_c, ẋ_c, ẏ_c), by central differences of the right-hand side."""
    n = scene.state_size
    eq = np.zeros(n)
    if scene.rolling:
        eq[4] = spin_z
    idx = [0, 1, 2, 3]  # the spin about the vertical is a constant of the linear motion
    F = np.zeros((4, 4))
    T = np.zeros((4, 4))
    for col, i in enumerate(idx):
        step = eps * (scene.a if i < 2 else (1.0 if not scene.rolling else 1.0))
        yp, ym = eq.copy(), eq.copy()
        yp[i] += step
        ym[i] -= step
        F[:, col] = (rhs(scene, yp, omega)[idx] - rhs(scene, ym, omega)[idx]) / (2 * step)
        T[:, col] = (centre_state(scene, yp) - centre_state(scene, ym)) / (2 * step)
    return T @ F @ np.linalg.inv(T)


def assert_matches_lab_frame(traj, ref: dict, rolling: bool) -> None:
    """A trajectory equals the laboratory-frame reference's (tests/reference_lab_frame.py):
    positions to 1e-9 m, velocities and N/mg to 1e-8, a rolling ball's spin to 1e-7 rad/s."""
    assert np.max(np.abs(traj.x - ref["x"])) < 1e-9
    assert np.max(np.abs(traj.y - ref["y"])) < 1e-9
    assert np.max(np.abs(traj.vx - ref["vx"])) < 1e-8
    assert np.max(np.abs(traj.vy - ref["vy"])) < 1e-8
    assert np.max(np.abs(traj.N_over_mg - ref["N_over_mg"])) < 1e-8
    if rolling:
        assert np.max(np.abs(traj.state[:, 2:] - ref["w"])) < 1e-7


def batch_and_singles(scenes: list[Scene], t_end: float = 1.0, omega: float = 25.0):
    """The same balls (each released at (3, 1) mm) run as one `simulate_batch` and one by one
    with `simulate`: (batch result, single trajectories)."""
    from saddle_env import initial_state, simulate, simulate_batch

    states = np.zeros((len(scenes), 5))
    for i, sc in enumerate(scenes):
        states[i, : sc.state_size] = initial_state(sc, 0.003, 0.001)
    batch = simulate_batch(scenes, states, t_end, omega=omega)
    return batch, [simulate(sc, states[i, : sc.state_size], t_end, omega=omega)
                   for i, sc in enumerate(scenes)]
