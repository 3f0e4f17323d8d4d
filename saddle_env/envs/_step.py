"""Compiled control step of the environment: one call advances every active ball by one
control period through the shared integrator (`saddle_env.integrators.integrate`) and
writes observations and rewards. The single environment and the vector environment both
call it; nothing here re-implements the physics.

Within a control step the motor ramps Ω linearly (finite Ω̇, so the Euler force is
defined), optionally with a sinusoidal ripple, and an optional lab-fixed force acts.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .._kernels import DRIVE_WIDTH, STATE_WIDTH, angle_at, contact_velocity, geometry, jit, rhs
from ..integrators import EVENT_DETACH, STATUS_DETACH, integrate_h
from ..scene import P_A, P_B, P_G, P_R, P_RIM

# Per-ball float state besides the physics state Y.
B_OMEGA, B_THETA, B_TIME, B_PHASE, B_FX, B_FY, B_H, B_NORMAL = range(8)
BALL_WIDTH = 8

# Per-ball outputs of a step.
O_STATUS, O_TIME, O_NORMAL, O_REWARD, O_TRAPPED = range(5)
OUT_WIDTH = 5

# Configuration vector.
(C_DT, C_MAX_ACCEL, C_OMEGA_MAX, C_TARGET_MODE, C_LAB_FRAME, C_POS_SCALE, C_VEL_SCALE,
 C_RIPPLE_AMP, C_RIPPLE_FREQ, C_SUBSTEP, C_RTOL, C_ATOL, C_MAX_STEP, C_LOSS, C_DIST_COST,
 C_EFFORT_COST, C_EVENTS) = range(17)
CFG_WIDTH = 17

# Observation bounds (scaled units), shared with the declared observation space.
POS_BOUND, VEL_BOUND, OMEGA_LOW, OMEGA_HIGH = 2.0, 10.0, -0.5, 1.5


@jit
def omega_rate(cfg, omega, action):
    """Ω̇ for this step: the motor's response to the action, keeping Ω in [0, omega_max]."""
    dt = cfg[C_DT]
    amax = cfg[C_MAX_ACCEL]
    wmax = cfg[C_OMEGA_MAX]
    if cfg[C_TARGET_MODE] != 0.0:
        target = 0.5 * (action + 1.0) * wmax
        rate = (target - omega) / dt
        return min(amax, max(-amax, rate))
    end = omega + action * amax * dt
    end = min(wmax, max(0.0, end))
    return (end - omega) / dt


@jit
def observe_one(model, p, y, ball, cfg, noise, obs):
    """Scaled, clipped observation of one ball (rotating or lab frame)."""
    s, nx, ny, nz, cx, cy, cz, J1x, J1y, J1z, J2x, J2y, J2z = geometry(p[P_A], p[P_B], p[P_R],
                                                                       y[0], y[1])
    vx, vy = contact_velocity(model, p, y)
    vcx = J1x * vx + J2x * vy
    vcy = J1y * vx + J2y * vy
    omega = ball[B_OMEGA]
    if cfg[C_RIPPLE_AMP] != 0.0:
        omega += cfg[C_RIPPLE_AMP] * math.sin(ball[B_PHASE])
    L = cfg[C_POS_SCALE]
    V = cfg[C_VEL_SCALE]
    if cfg[C_LAB_FRAME] != 0.0:
        th = ball[B_THETA]
        ct, st = math.cos(th), math.sin(th)
        # lab velocity of the centre: ċ + Ω k×c, turned by θ
        ux = vcx - omega * cy
        uy = vcy + omega * cx
        vals = (ct * cx - st * cy, st * cx + ct * cy, ct * ux - st * uy, st * ux + ct * uy)
        obs[4] = min(1.0, max(-1.0, ct + noise[4]))
        obs[5] = min(1.0, max(-1.0, st + noise[5]))
        k_omega = 6
    else:
        vals = (cx, cy, vcx, vcy)
        k_omega = 4
    obs[0] = min(POS_BOUND, max(-POS_BOUND, vals[0] / L + noise[0]))
    obs[1] = min(POS_BOUND, max(-POS_BOUND, vals[1] / L + noise[1]))
    obs[2] = min(VEL_BOUND, max(-VEL_BOUND, vals[2] / V + noise[2]))
    obs[3] = min(VEL_BOUND, max(-VEL_BOUND, vals[3] / V + noise[3]))
    obs[k_omega] = min(OMEGA_HIGH, max(OMEGA_LOW, omega / cfg[C_OMEGA_MAX] + noise[k_omega]))


@jit
def step_one(model, p, scale, y, ball, cfg, action, C, A, B, E, E3, err_kind, err_order,
             noise, obs, out, t_out, Y_out, stats, drive, dy):
    """Advance one ball by one control period; fill its observation and outputs."""
    dt = cfg[C_DT]
    rate = omega_rate(cfg, ball[B_OMEGA], action)
    drive[0] = ball[B_OMEGA]
    drive[1] = rate
    drive[2] = cfg[C_RIPPLE_AMP]
    drive[3] = cfg[C_RIPPLE_FREQ]
    drive[4] = ball[B_PHASE]
    drive[5] = ball[B_THETA]
    drive[6] = ball[B_FX]
    drive[7] = ball[B_FY]
    events = int(cfg[C_EVENTS])
    # The step size carries over from the last control step (no restart heuristic).
    hio = ball[B_H:B_NORMAL + 1]
    status, t_end = integrate_h(model, p, drive, y, 0.0, t_out, C, A, B, E, E3, err_kind,
                                err_order, cfg[C_SUBSTEP], cfg[C_RTOL], cfg[C_ATOL], scale,
                                cfg[C_MAX_STEP], events, 100_000, Y_out, stats, hio)
    ball[B_OMEGA] += rate * t_end
    ball[B_THETA] = angle_at(drive, t_end)
    ball[B_PHASE] += cfg[C_RIPPLE_FREQ] * t_end
    ball[B_TIME] += t_end
    out[O_STATUS] = status
    out[O_TIME] = t_end
    g = p[P_G]
    if not events & EVENT_DETACH:
        out[O_NORMAL] = np.nan
    elif status == STATUS_DETACH:
        out[O_NORMAL] = 0.0  # the step ended at the located crossing
    elif status != 0:
        n = rhs(model, p, drive, t_end, y, dy, True)  # rare: the state at an escape
        out[O_NORMAL] = n / g if g > 0 else n
    else:
        n = hio[1]  # computed by the integrator at the final state
        out[O_NORMAL] = n / g if g > 0 else n
    lost = status != 0
    trapped = t_end / dt if lost else 1.0
    out[O_TRAPPED] = trapped
    r2 = (y[0] * y[0] + y[1] * y[1]) / (p[P_RIM] * p[P_RIM])
    reward = trapped - cfg[C_DIST_COST] * min(r2, 1.0) - cfg[C_EFFORT_COST] * action * action
    if lost and status > 0:
        reward -= cfg[C_LOSS]
    out[O_REWARD] = reward
    observe_one(model, p, y, ball, cfg, noise, obs)


@jit
def _workspace(dt):
    """Scratch arrays for one ball's control step (output time dt)."""
    t_out = np.empty(1)
    t_out[0] = dt
    return (t_out, np.empty((1, STATE_WIDTH)), np.zeros(4, dtype=np.int64),
            np.empty(DRIVE_WIDTH), np.empty(STATE_WIDTH))


@jit
def _step_ball(i, models, P, scales, Y, balls, cfg, actions, C, A, B, E, E3, err_kind,
               err_order, noise, obs, out, work):
    """Step ball i with the given scratch arrays; 1 if its integration failed, else 0."""
    t_out, Y_out, stats, drive, dy = work
    step_one(models[i], P[i], scales[i], Y[i], balls[i], cfg, actions[i], C, A, B, E, E3,
             err_kind, err_order, noise[i], obs[i], out[i], t_out, Y_out, stats, drive, dy)
    return 1 if out[i, O_STATUS] < 0 else 0


@jit
def step_serial(models, P, scales, Y, balls, cfg, actions, active, C, A, B, E, E3, err_kind,
                err_order, noise, obs, out):
    """Step the active balls one after another; return how many failed (status < 0)."""
    work = _workspace(cfg[C_DT])
    failed = 0
    for i in range(Y.shape[0]):
        if active[i]:
            failed += _step_ball(i, models, P, scales, Y, balls, cfg, actions, C, A, B, E, E3,
                                 err_kind, err_order, noise, obs, out, work)
    return failed


@nb.njit(cache=True, parallel=True)
def step_parallel(models, P, scales, Y, balls, cfg, actions, active, C, A, B, E, E3, err_kind,
                  err_order, noise, obs, out):
    """Step the active balls on all threads (scratch arrays per ball); return how many failed."""
    failed = 0
    for i in nb.prange(Y.shape[0]):
        if active[i]:
            failed += _step_ball(i, models, P, scales, Y, balls, cfg, actions, C, A, B, E, E3,
                                 err_kind, err_order, noise, obs, out, _workspace(cfg[C_DT]))
    return failed


@jit
def observe_all(models, P, Y, balls, cfg, active, noise, obs):
    for i in range(Y.shape[0]):
        if active[i]:
            observe_one(models[i], P[i], Y[i], balls[i], cfg, noise[i], obs[i])


@jit
def normal_over_mg(model, p, y, ball, cfg):
    """N/(mg) of a ball at rest in time (reset observation info)."""
    drive = np.zeros(DRIVE_WIDTH)
    drive[0] = ball[B_OMEGA]
    drive[2] = cfg[C_RIPPLE_AMP]
    drive[4] = ball[B_PHASE]
    dy = np.empty(STATE_WIDTH)
    n = rhs(model, p, drive, 0.0, y, dy, True)
    g = p[P_G]
    return n / g if g > 0 else n

