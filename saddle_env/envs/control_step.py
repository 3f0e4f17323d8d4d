"""Compiled control step of the environment: one call advances every active ball by one
control period through the shared integrator and writes observations and rewards. The
single environment and the vector environment both call it; nothing here re-implements
the physics.

Within a control step the motor ramps Ω linearly (finite Ω̇, so the Euler force is
defined) or, driven by a voltage, relaxes exponentially to K·V (`kernels.omega_at`),
optionally with a sinusoidal ripple, and an optional lab-fixed force acts. The engine may
split a control period into segments (delays, `engine.DelayPlan`): it then calls the step
once per segment with ``C_DT`` the segment's length and ``C_GIVEN`` set, the actions being
the motor's Ω̇ (or the voltage command) in force during the segment.

Two paths, one result: a ball whose adaptive integrator will cover the control period in a
single step (nearly every step after an episode's first) is gathered with others of its
contact model into a block and stepped in SIMD lanes (`saddle_env.lockstep`), and the lanes
whose step `integrate_h` would accept as it stands are booked together (`_finish_lanes`);
any other ball, and any lane whose step `integrate_h` would reject or end with an event,
goes through `integrators.integrate_h` and is booked on its own (`_finish`). Both give
bit-identical results (tests/test_lockstep.py).

The engine keeps each ball in rows of float arrays, read and written only through the slot
names below (the physics state ``Y`` is `kernels`'s, the method and the step settings
travel as the records `integrators.Tableau` and `integrators.StepControl`):

| array | slot | holds |
|---|---|---|
| ``balls`` (n, BALL_WIDTH) | ``B_OMEGA`` | the motor's commanded speed Ω now (no ripple) [rad/s] |
| | ``B_THETA`` | saddle angle θ [rad] |
| | ``B_TIME`` | episode clock [s] |
| | ``B_PHASE`` | phase of the motor's ripple [rad] |
| | ``B_FX``, ``B_FY`` | lab-fixed force per unit mass (air current) [m/s²] |
| | ``B_H`` | the step the integrator continues with (`Outcome.h_next`) [s]; 0: it chooses |
| ``out`` (n, OUT_WIDTH) | ``O_STATUS`` | the step's STATUS_* code (> 0 an event, < 0 a failure) |
| | ``O_TIME`` | time the step covered (the event time if one fired) [s] |
| | ``O_NORMAL`` | N/(mg) at the step's end (0 at a detachment; NaN with detachment off) |
| | ``O_REWARD`` | the step's reward |
| | ``O_TRAPPED`` | fraction of the control period the ball stayed on |
| | ``O_OMEGA``, ``O_CLOCK`` | ``B_OMEGA`` and ``B_TIME`` at the step's end (what the info reports) |
| ``cfg`` (CFG_WIDTH,) | ``C_DT`` | control period [s] |
| | ``C_MAX_ACCEL``, ``C_OMEGA_MAX`` | motor limits [rad/s², rad/s] |
| | ``C_TARGET_MODE`` | 1: the action is a target speed; 0: an acceleration |
| | ``C_VOLTAGE_MODE`` | 1: the action is a voltage; Ω relaxes to K·V with time constant τ |
| | ``C_MOTOR_TOP``, ``C_MOTOR_RATE`` | K·V_max [rad/s] and 1/τ [1/s] (voltage mode) |
| | ``C_GIVEN`` | 1: the actions are Ω̇ [rad/s²] as given (voltage: the command); see above |
| | ``C_LAB_FRAME`` | 1: observe in the laboratory frame |
| | ``C_POS_SCALE``, ``C_VEL_SCALE`` | observation scales [m, m/s] |
| | ``C_RIPPLE_AMP``, ``C_RIPPLE_FREQ`` | the motor's ripple [rad/s, rad/s] |
| | ``C_LOSS``, ``C_DIST_COST``, ``C_EFFORT_COST`` | reward terms |
| | ``C_LOCKSTEP`` | 1: step balls in SIMD blocks where they fit |
| | ``C_OBS_OMEGA``, ``C_OBS_COMMAND``, ``C_OBS_COS`` | `observation.layout` columns (-1: none) |
| | ``C_OBS_VEL`` | 1: velocities in columns 2, 3; 0: a camera, positions only |
| | ``C_POS_QUANTUM`` | positions rounded to multiples of it / ``C_POS_SCALE`` (0: not) |
"""

from __future__ import annotations

import math
from collections import namedtuple

import numba as nb
import numpy as np

from ..compilation.jit import inline, ir_inline, jit, jit_per_constant, python_entry, unmanaged
from ..compilation.specialise import COULOMB_ON, ROLLING_ON, SLIPPING_ON, specialisable
from ..integrators import (
    EVENT_DETACH,
    STATUS_DETACH,
    StepControl,
    Tableau,
    integrate_h,
    reaches,
    unmanaged_tableau,
)
from ..kernels import (
    DRIVE_AMP,
    DRIVE_DECAY,
    DRIVE_DECAY_RATE,
    DRIVE_FREQ,
    DRIVE_FX,
    DRIVE_FY,
    DRIVE_PHASE,
    DRIVE_RATE,
    DRIVE_THETA0,
    DRIVE_W0,
    DRIVE_WIDTH,
    ROW_WIDTH,
    STATE_WIDTH,
    angle_at,
    contact_velocity,
    geometry,
    lab_rest_velocity,
    rhs,
    rolling_contact_velocity,
    state_from_velocity,
)
from ..lockstep import (
    BLOCK_WIDTH,
    LANES,
    PARAM_WIDTH,
    accept_lanes,
    block_size,
    carve_block,
    next_step,
    rk_step_block,
    take,
)
from ..scene import (
    COULOMB,
    P_A,
    P_B,
    P_G,
    P_R,
    P_RESIST,
    P_RIM,
    P_TILT_FORCE,
    ROLLING,
    SLIPPING,
)
from .observation import OBS_MAX, OMEGA_HIGH, OMEGA_LOW, POS_BOUND, VEL_BOUND

# The slots of the module's table: the only way into the engine's per-ball rows. The rows are
# plain float arrays so that a ball is copied into thread-local scratch by a loop (`_load`)
# and the block path gathers lanes from them.
B_OMEGA, B_THETA, B_TIME, B_PHASE, B_FX, B_FY, B_H = range(7)
BALL_WIDTH = 7
# O_OMEGA and O_CLOCK repeat two of the ball's slots for the environments' info. Reading
# them from ``balls``, which the step reads before it writes, cost the vector environment a
# third of its step: the other thread's rows were left shared with the main thread's cache
# and each one's first write of the next step waited for them (measured at 1,024 balls, two
# threads); ``out`` is only written by the step.
O_STATUS, O_TIME, O_NORMAL, O_REWARD, O_TRAPPED, O_OMEGA, O_CLOCK = range(7)
OUT_WIDTH = 7
(C_DT, C_MAX_ACCEL, C_OMEGA_MAX, C_TARGET_MODE, C_LAB_FRAME, C_POS_SCALE, C_VEL_SCALE,
 C_RIPPLE_AMP, C_RIPPLE_FREQ, C_LOSS, C_DIST_COST, C_EFFORT_COST, C_LOCKSTEP, C_OBS_OMEGA,
 C_OBS_COMMAND, C_OBS_COS, C_VOLTAGE_MODE, C_MOTOR_TOP, C_MOTOR_RATE, C_GIVEN, C_OBS_VEL,
 C_POS_QUANTUM) = range(22)
CFG_WIDTH = 22

MIN_BLOCK = 4  # fewest balls worth a SIMD block (measured crossover: 4-8 balls)

# The scalar path's scratch (`_carve`): its one output time (the control period) and state
# row, the integrator's counters, a derivative, the integrator's workspace and a drive row.
ScalarScratch = namedtuple("ScalarScratch", "t_out Y_out stats dy work drive")


@jit
def omega_rate(cfg, omega, action):
    """Ω̇ for this step: the motor's response to the action, keeping Ω in [0, omega_max]
    (with ``C_GIVEN`` the action is Ω̇ itself, worked out by `command_rates` when the
    command took effect)."""
    if cfg[C_GIVEN] != 0.0:
        return action
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


# What the observation reads from ``cfg``, read once into scalars: a loop over a block's
# lanes then keeps them in registers (a read of ``cfg`` inside the loop might alias its
# stores, and the compiler would not vectorise it). The k_* are `observation.layout`'s
# columns (-1: none).
ObsSettings = namedtuple("ObsSettings", "lab pos_scale vel_scale quantum omega_max "
                                        "velocities k_omega k_cos k_cmd")


@inline
def _obs_settings(cfg):
    """The `ObsSettings` of ``cfg``."""
    return ObsSettings(cfg[C_LAB_FRAME] != 0.0, cfg[C_POS_SCALE], cfg[C_VEL_SCALE],
                       cfg[C_POS_QUANTUM], cfg[C_OMEGA_MAX], cfg[C_OBS_VEL] != 0.0,
                       int(cfg[C_OBS_OMEGA]), int(cfg[C_OBS_COS]), int(cfg[C_OBS_COMMAND]))


@inline
def _measured(ball, cfg):
    """The drive as its sensors read it: Ω with the motor's ripple (the tachometer), and
    cos θ, sin θ (the encoder; 1, 0 where the angle is not observed, sparing the trig)."""
    omega = ball[B_OMEGA]
    if cfg[C_RIPPLE_AMP] != 0.0:
        omega += cfg[C_RIPPLE_AMP] * math.sin(ball[B_PHASE])
    ct, st = 1.0, 0.0
    if int(cfg[C_OBS_COS]) >= 0:  # the angle is observed (always in the lab frame)
        th = ball[B_THETA]
        ct, st = math.cos(th), math.sin(th)
    return omega, ct, st


@inline
def _noise_of(s, noise):
    """The sensor noise of the columns `_columns` makes, in its order, from a noise row laid
    out as the observation (0 for a column the layout ``s`` lacks)."""
    nvx, nvy = (noise[2], noise[3]) if s.velocities else (0.0, 0.0)
    ncos, nsin = (noise[s.k_cos], noise[s.k_cos + 1]) if s.k_cos >= 0 else (0.0, 0.0)
    return noise[0], noise[1], nvx, nvy, noise[s.k_omega], ncos, nsin


@inline
def _columns(s, g, vx, vy, omega, ct, st, command, noise):
    """Every column the observation may have, scaled, noisy and clipped, in the order (x, y,
    vx, vy, Ω, cos θ, sin θ, commanded Ω): the centre of `Geometry` ``g`` moving at
    contact-point velocity (vx, vy) (rotating frame, or the lab frame turned by θ), the
    measured Ω ``omega``, the encoder's ``ct``, ``st`` and the ``command``ed Ω; ``noise``
    from `_noise_of`. `_put` stores the ones the layout ``s`` has."""
    cx, cy = g.cx, g.cy
    vcx = g.J1x * vx + g.J2x * vy
    vcy = g.J1y * vx + g.J2y * vy
    if s.lab:  # lab velocity of the centre: ċ + Ω k×c, turned by θ
        ux = vcx - omega * cy
        uy = vcy + omega * cx
        px, py, pu, pv = ct * cx - st * cy, st * cx + ct * cy, ct * ux - st * uy, st * ux + ct * uy
    else:
        px, py, pu, pv = cx, cy, vcx, vcy
    L, V, q = s.pos_scale, s.vel_scale, s.quantum
    px, py = px / L + noise[0], py / L + noise[1]
    if q > 0.0:  # a camera's pixels (q in units of C_POS_SCALE)
        px, py = round(px / q) * q, round(py / q) * q
    return (min(POS_BOUND, max(-POS_BOUND, px)), min(POS_BOUND, max(-POS_BOUND, py)),
            min(VEL_BOUND, max(-VEL_BOUND, pu / V + noise[2])),
            min(VEL_BOUND, max(-VEL_BOUND, pv / V + noise[3])),
            min(OMEGA_HIGH, max(OMEGA_LOW, omega / s.omega_max + noise[4])),
            min(1.0, max(-1.0, ct + noise[5])), min(1.0, max(-1.0, st + noise[6])),
            # the commanded speed: known to the motor controller exactly
            min(1.0, max(0.0, command / s.omega_max)))


@inline
def _put(s, cols, obs):
    """Store the columns `_columns` made where the layout ``s`` has them in ``obs``."""
    obs[0], obs[1] = cols[0], cols[1]
    if s.velocities:
        obs[2], obs[3] = cols[2], cols[3]
    obs[s.k_omega] = cols[4]
    if s.k_cos >= 0:
        obs[s.k_cos], obs[s.k_cos + 1] = cols[5], cols[6]
    if s.k_cmd >= 0:
        obs[s.k_cmd] = cols[7]


@jit
def observe_one(model, p, y, ball, cfg, noise, obs):
    """Scaled, clipped observation of one ball (rotating or lab frame; the columns are
    `observation.layout`'s, passed in ``cfg``)."""
    s = _obs_settings(cfg)
    g = geometry(p[P_A], p[P_B], p[P_R], y[0], y[1])
    vx, vy = contact_velocity(model, p, y)
    omega, ct, st = _measured(ball, cfg)
    _put(s, _columns(s, g, vx, vy, omega, ct, st, ball[B_OMEGA], _noise_of(s, noise)), obs)


@jit
def _drive(ball, cfg, action, drive):
    """Fill this control step's drive row (Ω ramping at the motor's response to the action,
    ripple, saddle angle, air force) and return the ramp rate Ω̇ (0 for a voltage, whose
    exponential approach to K·V the row carries)."""
    if cfg[C_VOLTAGE_MODE] != 0.0:
        steady = 0.5 * (action + 1.0) * cfg[C_MOTOR_TOP]   # K·V, V = (action + 1)/2 · V_max
        rate = 0.0
        drive[DRIVE_W0] = steady
        drive[DRIVE_DECAY] = ball[B_OMEGA] - steady
        drive[DRIVE_DECAY_RATE] = cfg[C_MOTOR_RATE]
    else:
        rate = omega_rate(cfg, ball[B_OMEGA], action)
        drive[DRIVE_W0] = ball[B_OMEGA]
        drive[DRIVE_DECAY] = 0.0
        drive[DRIVE_DECAY_RATE] = 0.0
    drive[DRIVE_RATE] = rate
    drive[DRIVE_AMP] = cfg[C_RIPPLE_AMP]
    drive[DRIVE_FREQ] = cfg[C_RIPPLE_FREQ]
    drive[DRIVE_PHASE] = ball[B_PHASE]
    drive[DRIVE_THETA0] = ball[B_THETA]
    drive[DRIVE_FX] = ball[B_FX]
    drive[DRIVE_FY] = ball[B_FY]
    return rate


@inline
def _advance_drive(ball, cfg, drive, rate, t_end):
    """Move a ball's Ω, angle, ripple phase and clock on by ``t_end`` along its ``drive``
    row, which ramps Ω at ``rate``."""
    if drive[DRIVE_DECAY] != 0.0:  # the voltage-driven motor: closed form, as the ODE saw it
        ball[B_OMEGA] = drive[DRIVE_W0] + drive[DRIVE_DECAY] * math.exp(
            -drive[DRIVE_DECAY_RATE] * t_end)
    else:
        ball[B_OMEGA] += rate * t_end
    ball[B_THETA] = angle_at(drive, t_end)
    ball[B_PHASE] += cfg[C_RIPPLE_FREQ] * t_end
    ball[B_TIME] += t_end


@inline
def _per_weight(n, g):
    """N/m ``n`` in units of the weight per unit mass ``g`` (`weight`; as N/m if g is 0)."""
    return n / g if g > 0 else n


@inline
def _reward(trapped, x, y, rim, action, dist_cost, effort_cost):
    """The step's reward before any loss penalty: the ``trapped`` fraction, less the costs of
    the distance from the centre (contact point (x, y), saddle of radius ``rim``) and of the
    ``action``."""
    r2 = (x * x + y * y) / (rim * rim)
    return trapped - dist_cost * min(r2, 1.0) - effort_cost * action * action


@jit
def _finish(model, p, y, ball, cfg, events, action, drive, rate, status, t_end, normal, noise,
            obs, out, dy):
    """Book the step that ended at ``t_end`` with ``status``: Ω, angle, clock, outputs,
    reward and observation. ``normal``: N/m at the final state as the integrator left it
    (used when the step completed with detachment ``events`` on)."""
    dt = cfg[C_DT]
    _advance_drive(ball, cfg, drive, rate, t_end)
    out[O_STATUS] = status
    out[O_TIME] = t_end
    g = weight(p)
    if not events & EVENT_DETACH:
        out[O_NORMAL] = np.nan
    elif status == STATUS_DETACH:
        out[O_NORMAL] = 0.0  # the step ended at the located crossing
    elif status != 0:
        n = rhs(model, p, drive, t_end, y, dy, True)  # rare: the state at an escape
        out[O_NORMAL] = _per_weight(n, g)
    else:
        out[O_NORMAL] = _per_weight(normal, g)
    lost = status != 0
    trapped = t_end / dt if lost else 1.0
    out[O_TRAPPED] = trapped
    reward = _reward(trapped, y[0], y[1], p[P_RIM], action, cfg[C_DIST_COST],
                     cfg[C_EFFORT_COST])
    if lost and status > 0:
        reward -= cfg[C_LOSS]
    out[O_REWARD] = reward
    out[O_OMEGA], out[O_CLOCK] = ball[B_OMEGA], ball[B_TIME]
    observe_one(model, p, y, ball, cfg, noise, obs)


@ir_inline
def _integrate(model, p, scale, y, ball, drive, tab, ctl, sc):
    """The scalar path: `integrate_h` over one control period; returns the status, the end
    time and N/m at the final state. The step size carries over from the last control step
    in ball[B_H]."""
    res = integrate_h(model, p, drive, y, 0.0, sc.t_out, tab, ctl, scale, sc.Y_out, sc.stats,
                      ball[B_H], sc.work)
    ball[B_H] = res.h_next
    return res.status, res.t_final, res.normal


@jit
def _first_step(ball, ctl):
    """The first step `integrate_h` will try this control period (0: it will choose one)."""
    if ctl.dt > 0.0:
        return min(ctl.dt, ctl.max_step)
    if ball[B_H] > 0.0:
        return min(ball[B_H], ctl.max_step)
    return 0.0  # a fresh episode: the starting-step heuristic decides


# Private copy of one ball's rows while it is stepped ("record"): parameters, state
# scales, state, ball columns, noise, observation (float64, stored as float32) and outputs.
REC_WIDTH = PARAM_WIDTH + 2 * STATE_WIDTH + BALL_WIDTH + 2 * OBS_MAX + OUT_WIDTH

# A block's accepted lanes as `_finish_lanes` books them, in a flat book of LANE_ROWS rows
# of LANES (lane q of row r at `_at`): what the pass over their balls reads for the pass over
# the lanes (the action, the weight, the sensors' Ω, cos θ, sin θ, the commanded Ω, then
# from L_NOISE the noise of `_columns`' noisy columns) and what that pass makes (from
# L_COLUMNS the observation's columns in `_columns`' order, the reward, N/mg).
COLUMNS = 8        # `_columns`' columns
NOISY_COLUMNS = 7  # those with sensor noise (`_noise_of`): all but the commanded Ω
L_ACTION, L_WEIGHT, L_OMEGA, L_COS, L_SIN, L_COMMAND, L_NOISE = range(7)
L_COLUMNS = L_NOISE + NOISY_COLUMNS
L_REWARD = L_COLUMNS + COLUMNS
L_NORMAL = L_REWARD + 1
LANE_ROWS = L_NORMAL + 1


@inline
def _at(row, q):
    """Where lane q of ``row`` sits in the flat lane book. Flat, so that the compiler sees
    the rows' distances (of a 2-D view's row length it knows nothing: it would have to
    check every pair of rows for overlap at run time, and gave up vectorising)."""
    return row * LANES + q


@jit
def scratch_size(stages):
    """Floats of scratch memory one `_step_range` call needs (method of ``stages`` stages)."""
    return (1 + 2 * STATE_WIDTH + DRIVE_WIDTH + (stages + 5) * STATE_WIDTH + LANES + REC_WIDTH
            + LANE_ROWS * LANES + block_size(stages))


@ir_inline
def _carve_scalar(buf, ibuf, stages, dt):
    """The scalar path's views into the caller's scratch buffers (see `_carve`): its
    `ScalarScratch`, the ball record (see `_load`), the lanes' Ω̇ and the offset where the
    lane block starts."""
    t_out, o = take(buf, 0, 1)
    t_out[0] = dt
    Y_out, o = take(buf, o, STATE_WIDTH)
    dy, o = take(buf, o, STATE_WIDTH)
    drive, o = take(buf, o, DRIVE_WIDTH)
    work, o = take(buf, o, (stages + 5) * STATE_WIDTH)
    rates, o = take(buf, o, LANES)
    p, o = take(buf, o, PARAM_WIDTH)
    scale, o = take(buf, o, STATE_WIDTH)
    y, o = take(buf, o, STATE_WIDTH)
    ball, o = take(buf, o, BALL_WIDTH)
    noise, o = take(buf, o, OBS_MAX)
    obs, o = take(buf, o, OBS_MAX)
    out, o = take(buf, o, OUT_WIDTH)
    Y_out = Y_out.reshape((1, STATE_WIDTH))
    work = work.reshape((stages + 5, STATE_WIDTH))
    record = (p, scale, y, ball, noise, obs, out)
    sc = ScalarScratch(t_out, Y_out, ibuf[:4], dy, work, drive)
    return sc, record, rates, o


@jit
def _carve(buf, ibuf, stages, dt):
    """Views into the caller's scratch buffers (floats: `scratch_size`; ints: 4 + LANES):
    the scalar path's `ScalarScratch`, the ball record (see `_load`), the lane block, the
    lane book (`L_*`), the lanes' Ω̇ and their ball indices."""
    sc, record, rates, o = _carve_scalar(buf, ibuf, stages, dt)
    book, o = take(buf, o, LANE_ROWS * LANES)
    ws = carve_block(buf[o:], stages)
    return sc, record, ws, book, rates, ibuf[4:4 + LANES]


@jit_per_constant
def _load(i, width, P, scales, Y, balls, noise, record):
    """Copy ball i's rows into the thread's private record, so the per-ball work touches
    only the thread's own memory (the shared arrays are read and written once per ball).
    ``width``: the state slots copied, a constant at every call (`kernels.ROW_WIDTH`, or
    STATE_WIDTH for a coulomb ball)."""
    p, scale, y, ball, nz, ob, o = record
    for k in range(PARAM_WIDTH):
        p[k] = P[i, k]
    for j in range(width):
        scale[j] = scales[i, j]
        y[j] = Y[i, j]
    for k in range(BALL_WIDTH):
        ball[k] = balls[i, k]
    for k in range(noise.shape[1]):
        nz[k] = noise[i, k]


@jit_per_constant
def _store(i, width, Y, balls, obs, out, record):
    """Write the record back: state (``width`` slots, as `_load`), ball columns,
    observation and outputs."""
    p, scale, y, ball, nz, ob, o = record
    for j in range(width):
        Y[i, j] = y[j]
    for k in range(BALL_WIDTH):
        balls[i, k] = ball[k]
    for k in range(obs.shape[1]):
        obs[i, k] = ob[k]
    for k in range(OUT_WIDTH):
        out[i, k] = o[k]


@ir_inline
def _scalar_ball(i, model, width, Y, balls, cfg, actions, tab, ctl, obs, out, sc, record):
    """The scalar path for ball i, already loaded into ``record`` (``width`` state slots, as
    `_load`): its drive, `integrate_h` over the control period, the booking, the store.
    Returns 1 if it failed, else 0."""
    p, scale, y, ball, nz, ob, o = record
    drive = sc.drive
    rate = _drive(ball, cfg, actions[i], drive)
    status, t_end, normal = _integrate(model, p, scale, y, ball, drive, tab, ctl, sc)
    _finish(model, p, y, ball, cfg, ctl.events, actions[i], drive, rate, status, t_end, normal,
            nz, ob, o, sc.dy)
    _store(i, width, Y, balls, obs, out, record)
    return 1 if status < 0 else 0


@ir_inline
def _coulomb_balls(lo, hi, models, P, scales, Y, balls, cfg, actions, active, tab, ctl, noise,
                   obs, out, sc, record):
    """Step the active coulomb balls lo..hi-1 on the scalar path (a phase may change inside a
    step), whole state rows; return how many failed. A loop of their own: handling them in
    the loop over the other balls, with a longer row copy behind a branch, made the
    environment's step slower for the other balls."""
    failed = 0
    for i in range(lo, hi):
        if not COULOMB_ON or not active[i] or models[i] != COULOMB:  # `compilation.specialise`
            continue
        _load(i, STATE_WIDTH, P, scales, Y, balls, noise, record)
        failed += _scalar_ball(i, COULOMB, STATE_WIDTH, Y, balls, cfg, actions, tab, ctl, obs,
                               out, sc, record)
    return failed


@ir_inline
def _step_block(model, m, lanes, rates, ws, book, sc, record, P, scales, Y, balls, cfg,
                actions, tab, ctl, noise, obs, out):
    """Finish lanes 0..m-1 (balls ``lanes``), gathered into ``ws``: one SIMD step for all;
    the lanes whose result is exactly what `integrate_h` would return are booked together
    (`_finish_lanes`), the others' balls are redone by the scalar path (error too large, an
    event, a dip of N). Returns how many failed."""
    # A block of a few balls costs more than it saves (loop overhead of ~2 µs): step them
    # one by one.
    use_block = m >= MIN_BLOCK
    if use_block:
        adaptive = ctl.dt <= 0.0
        d = rk_step_block(model, m, cfg[C_DT], tab, ctl, ws)
        accept_lanes(model, m, d, adaptive, ctl.events, ws)
        _finish_lanes(model, m, lanes, rates, ws, book, P, Y, balls, cfg, actions, ctl,
                      tab.err_order, noise, obs, out)
    failed = 0
    for q in range(m):
        if use_block and ws.ok[q] != 0.0:
            continue
        i = lanes[q]
        _load(i, ROW_WIDTH, P, scales, Y, balls, noise, record)
        failed += _scalar_ball(i, model, ROW_WIDTH, Y, balls, cfg, actions, tab, ctl, obs, out,
                               sc, record)
    return failed


@jit
def _finish_lanes(model, m, lanes, rates, ws, book, P, Y, balls, cfg, actions, ctl, err_order,
                  noise, obs, out):
    """Book the accepted lanes (``ws.ok``, `accept_lanes`) of a block whose step covered the
    control period, as `_finish` books a ball (same operations, same order: bit-identical),
    writing to the shared arrays straight. Done ball by ball, with each ball's rows copied
    into a record and back, this booking was about half of the vector environment's step
    (profile at 1,024 balls); here the geometry, observation and reward of the whole block are one loop
    over the lanes, which the compiler vectorises. Three passes: over the lanes' balls for
    what needs a ball's row or a library call (`_read_lanes`), over the lanes
    (`_observe_lanes`), over the balls again to store (`_store_lanes`)."""
    _read_lanes(m, lanes, rates, ws, book, P, balls, cfg, actions, ctl, err_order, noise)
    _observe_lanes(model, m, ws, book, cfg, (ctl.events & EVENT_DETACH) != 0)
    _store_lanes(m, lanes, ws, book, Y, balls, cfg, obs, out)


@jit
def _read_lanes(m, lanes, rates, ws, book, P, balls, cfg, actions, ctl, err_order, noise):
    """The accepted lanes' balls: move each one's drive on by the control period and leave
    its step-size hint (as `integrate_h` does), and put what the observation and reward need
    of its rows, and what the sensors read (`_measured`: trigonometry, a call per ball),
    into the lane ``book``."""
    dt = cfg[C_DT]
    s = _obs_settings(cfg)
    adaptive = ctl.dt <= 0.0
    D, Err, ok = ws.D, ws.Err, ws.ok
    for q in range(m):
        if ok[q] == 0.0:
            continue
        i = lanes[q]
        ball = balls[i]
        h_first = _first_step(ball, ctl)
        _advance_drive(ball, cfg, D[q], rates[q], dt)
        ball[B_H] = next_step(Err[q], dt, h_first, err_order, ctl.max_step) if adaptive \
            else h_first
        book[_at(L_OMEGA, q)], book[_at(L_COS, q)], book[_at(L_SIN, q)] = _measured(ball, cfg)
        book[_at(L_COMMAND, q)] = ball[B_OMEGA]
        book[_at(L_ACTION, q)] = actions[i]
        book[_at(L_WEIGHT, q)] = weight(P[i])
        nz = _noise_of(s, noise[i])
        for k in range(NOISY_COLUMNS):
            book[_at(L_NOISE + k, q)] = nz[k]


@jit
def _observe_lanes(model, m, ws, book, cfg, detach):
    """Observation columns, reward and N/mg (NaN without ``detach``ment events) of lanes
    0..m-1 at the end of their step (`ws.Ynew`), from what `_read_lanes` left in the lane
    ``book``: a loop over the lanes with no call in it, which the compiler vectorises (the
    lanes not accepted are computed too, and not stored)."""
    s = _obs_settings(cfg)
    dist_cost, effort_cost = cfg[C_DIST_COST], cfg[C_EFFORT_COST]
    P, Y, N = ws.P, ws.Ynew, ws.Nend
    for q in range(m):
        R = P[P_R, q]
        g = geometry(P[P_A, q], P[P_B, q], R, Y[0, q], Y[1, q])
        if model == ROLLING:
            vx, vy = rolling_contact_velocity(R, g, Y[2, q], Y[3, q], Y[4, q])
        else:
            vx, vy = Y[2, q], Y[3, q]
        nz = (book[_at(L_NOISE, q)], book[_at(L_NOISE + 1, q)], book[_at(L_NOISE + 2, q)],
              book[_at(L_NOISE + 3, q)], book[_at(L_NOISE + 4, q)], book[_at(L_NOISE + 5, q)],
              book[_at(L_NOISE + 6, q)])
        cols = _columns(s, g, vx, vy, book[_at(L_OMEGA, q)], book[_at(L_COS, q)],
                        book[_at(L_SIN, q)], book[_at(L_COMMAND, q)], nz)
        for k in range(COLUMNS):
            book[_at(L_COLUMNS + k, q)] = cols[k]
        book[_at(L_REWARD, q)] = _reward(1.0, Y[0, q], Y[1, q], P[P_RIM, q],
                                         book[_at(L_ACTION, q)], dist_cost, effort_cost)
        book[_at(L_NORMAL, q)] = _per_weight(N[q], book[_at(L_WEIGHT, q)]) if detach \
            else np.nan


@jit
def _store_lanes(m, lanes, ws, book, Y, balls, cfg, obs, out):
    """Store the accepted lanes' states, observations and outputs in their balls' rows
    (``balls``, already moved on by `_read_lanes`, is only read: for the clock)."""
    s = _obs_settings(cfg)
    dt = cfg[C_DT]
    Ynew, ok = ws.Ynew, ws.ok
    for q in range(m):
        if ok[q] == 0.0:
            continue
        i = lanes[q]
        for j in range(BLOCK_WIDTH):
            Y[i, j] = Ynew[j, q]
        c = L_COLUMNS
        _put(s, (book[_at(c, q)], book[_at(c + 1, q)], book[_at(c + 2, q)],
                 book[_at(c + 3, q)], book[_at(c + 4, q)], book[_at(c + 5, q)],
                 book[_at(c + 6, q)], book[_at(c + 7, q)]), obs[i])
        out[i, O_STATUS] = 0.0
        out[i, O_TIME] = dt
        out[i, O_NORMAL] = book[_at(L_NORMAL, q)]
        out[i, O_REWARD] = book[_at(L_REWARD, q)]
        out[i, O_TRAPPED] = 1.0
        out[i, O_OMEGA] = book[_at(L_COMMAND, q)]
        out[i, O_CLOCK] = balls[i, B_TIME]


@jit
def _step_range(lo, hi, models, P, scales, Y, balls, cfg, actions, active, tab, ctl, noise, obs,
                out, buf, ibuf):
    """Step the active balls lo..hi-1; return how many failed (status < 0).

    Balls whose integrator will cover the control period in one step (nearly always after
    the first step of an episode) are gathered by contact model into blocks of `LANES` and
    stepped together (`saddle_env.lockstep`); the rest take the scalar path."""
    stages = tab.B.shape[0]
    dt = cfg[C_DT]
    sc, record, ws, book, rates, lanes = _carve(buf, ibuf, stages, dt)
    Pl, D, Y0, Sc = ws.P, ws.D, ws.Y0, ws.Sc
    lockstep = cfg[C_LOCKSTEP] != 0.0
    failed = 0
    for model in (ROLLING, SLIPPING):
        m = 0
        for i in range(lo, hi):
            if not (ROLLING_ON or SLIPPING_ON) or not active[i] or models[i] != model:
                continue
            # A ball with rolling resistance takes the scalar path: its loop may cut a step at
            # a rolling spin's stop (`integrators`, roll stop), which a block's lanes do not.
            # A lane is gathered from the shared rows straight (the ball's record is loaded
            # when the block is finished, `_step_block`).
            row = balls[i]
            if lockstep and P[i, P_RESIST] == 0.0 and reaches(0.0, _first_step(row, ctl), dt):
                lanes[m] = i
                rates[m] = _drive(row, cfg, actions[i], D[m])
                for k in range(PARAM_WIDTH):
                    Pl[k, m] = P[i, k]
                for j in range(BLOCK_WIDTH):
                    Y0[j, m] = Y[i, j]
                    Sc[j, m] = scales[i, j]
                m += 1
                if m == LANES:
                    failed += _step_block(model, m, lanes, rates, ws, book, sc, record, P,
                                          scales, Y, balls, cfg, actions, tab, ctl, noise, obs,
                                          out)
                    m = 0
            else:
                _load(i, ROW_WIDTH, P, scales, Y, balls, noise, record)
                failed += _scalar_ball(i, model, ROW_WIDTH, Y, balls, cfg, actions, tab, ctl,
                                       obs, out, sc, record)
        if m > 0:
            failed += _step_block(model, m, lanes, rates, ws, book, sc, record, P, scales, Y,
                                  balls, cfg, actions, tab, ctl, noise, obs, out)
    return failed + _coulomb_balls(lo, hi, models, P, scales, Y, balls, cfg, actions, active,
                                   tab, ctl, noise, obs, out, sc, record)


@ir_inline
def _step_range_scalar(lo, hi, models, P, scales, Y, balls, cfg, actions, active, tab, ctl,
                       noise, obs, out, buf, ibuf):
    """`_step_range` where no block can form (fewer than `MIN_BLOCK` balls, or SIMD blocks
    off): every ball on the scalar path, as `_step_range` then steps it. Compiles without
    `saddle_env.lockstep` (a fifth of the environment's compile, docs/coldstart.md), so a
    single environment's first step compiles less."""
    sc, record, rates, o = _carve_scalar(buf, ibuf, tab.B.shape[0], cfg[C_DT])
    failed = 0
    for model in (ROLLING, SLIPPING):
        for i in range(lo, hi):
            if not (ROLLING_ON or SLIPPING_ON) or not active[i] or models[i] != model:
                continue
            _load(i, ROW_WIDTH, P, scales, Y, balls, noise, record)
            failed += _scalar_ball(i, model, ROW_WIDTH, Y, balls, cfg, actions, tab, ctl, obs,
                                   out, sc, record)
    return failed + _coulomb_balls(lo, hi, models, P, scales, Y, balls, cfg, actions, active,
                                   tab, ctl, noise, obs, out, sc, record)


@ir_inline
def _unmanaged_tableau(tab_fields):
    """`Tableau` of ``tab_fields`` with its arrays `unmanaged`: the compiled step entry points
    work on their arguments without reference counts (`compilation.jit.unmanaged`; Python
    holds them for the call), so the integrator's views of its scratch rows cost no atomic
    increments."""
    return unmanaged_tableau(Tableau(*tab_fields))


# `_step_range`, `_step_block` and `_integrate` are typed into `step_serial`
# (`kernels.ir_inline`): compiled on their own, each was one more module holding all of the
# integrator's code, optimised and turned into machine code again (docs/coldstart.md).
# `step_parallel` calls `_step_range` compiled on its own: numba's analysis of the reduction
# in its parallel loop fails on the inlined body ("unexpected cycle in lookup()").
_step_range_inlined = ir_inline(_step_range.py_func)

# The entry points take the method and the step settings as the plain tuples of their
# records' fields and rebuild the records inside: numba's dispatcher types a namedtuple
# argument in Python, ~0.5 µs a call (measured), a tenth of a single ball's control step.
@python_entry
@jit
def step_serial(models, P, scales, Y, balls, cfg, actions, active, tab_fields, ctl_fields,
                noise, obs, out, buf, ibuf):
    """Step the active balls on this thread with the caller's scratch buffers (see `_carve`);
    return how many failed (status < 0). ``tab_fields``, ``ctl_fields``: the fields of the
    method's `Tableau` and of the `StepControl`."""
    U = unmanaged
    return _step_range_inlined(0, Y.shape[0], U(models), U(P), U(scales), U(Y), U(balls), U(cfg),
                               U(actions), U(active), _unmanaged_tableau(tab_fields),
                               StepControl(*ctl_fields), U(noise), U(obs), U(out), U(buf),
                               U(ibuf))


@python_entry
@jit
def step_scalar(models, P, scales, Y, balls, cfg, actions, active, tab_fields, ctl_fields,
                noise, obs, out, buf, ibuf):
    """`step_serial` for engines where no SIMD block can form (`_step_range_scalar`): the
    same results, less to compile. Same arguments."""
    U = unmanaged
    return _step_range_scalar(0, Y.shape[0], U(models), U(P), U(scales), U(Y), U(balls), U(cfg),
                              U(actions), U(active), _unmanaged_tableau(tab_fields),
                              StepControl(*ctl_fields), U(noise), U(obs), U(out), U(buf),
                              U(ibuf))


@python_entry
@nb.njit(cache=True, parallel=True)
def step_parallel(models, P, scales, Y, balls, cfg, actions, active, tab_fields, ctl_fields,
                  noise, obs, out, bufs, ibufs):
    """Step the active balls on all threads in ``len(bufs)`` contiguous chunks, each with its
    own rows of the caller's scratch buffers (a few chunks per thread balance the load);
    return how many failed. The records' fields as in `step_serial`."""
    tab, ctl = _unmanaged_tableau(tab_fields), StepControl(*ctl_fields)
    U = unmanaged
    models, P, scales, Y, balls, cfg = U(models), U(P), U(scales), U(Y), U(balls), U(cfg)
    actions, active, noise, obs, out = U(actions), U(active), U(noise), U(obs), U(out)
    bufs, ibufs = U(bufs), U(ibufs)
    n = Y.shape[0]
    chunks = bufs.shape[0]
    failed = 0
    for c in nb.prange(chunks):
        failed += _step_range(c * n // chunks, (c + 1) * n // chunks, models, P, scales, Y,
                              balls, cfg, actions, active, tab, ctl, noise, obs, out, bufs[c],
                              ibufs[c])
    return failed


@jit
def _observe_into(model, p, y, ball, cfg, noise, obs, row):
    """`observe_one` into the float32 observation row ``obs`` through the float64 ``row``,
    as the step observes into its float64 record (`_finish`): one compiled `observe_one`
    for both (a float32 row was a second specialisation, adding to the environment's compile
    time; the values are the same, rounded to float32 on the copy instead of the store)."""
    observe_one(model, p, y, ball, cfg, noise, row)
    for k in range(obs.shape[0]):
        obs[k] = row[k]


@python_entry
@jit
def place(idx, models, P, Y, balls, cfg, x, y, vx, vy, lab_rest, spin_normal, noise, obs, out):
    """Start balls ``idx[j]`` at contact point (x[j], y[j]) with rotating-frame velocity
    (vx[j], vy[j]), plus the velocity of rest in the laboratory where ``lab_rest[j]``; Ω,
    phase and force are already in ``balls``. Writes the state, observation and outputs
    (N/mg at rest in time)."""
    row = np.zeros(OBS_MAX)
    for j in range(idx.shape[0]):
        i = idx[j]
        p = P[i]
        u, v = vx[j], vy[j]
        if lab_rest[j]:
            lu, lv = lab_rest_velocity(p, balls[i, B_OMEGA], x[j], y[j])
            u, v = lu + u, lv + v
        Y[i, :] = 0.0
        state_from_velocity(models[i], p, x[j], y[j], u, v, spin_normal, Y[i])
        out[i, :] = 0.0
        out[i, O_TRAPPED] = 1.0
        out[i, O_OMEGA], out[i, O_CLOCK] = balls[i, B_OMEGA], balls[i, B_TIME]
        out[i, O_NORMAL] = normal_over_mg(models[i], p, Y[i], balls[i], cfg)
        _observe_into(models[i], p, Y[i], balls[i], cfg, noise[i], obs[i], row)


@jit
def clip_actions(actions, out):
    """out = actions clipped to [-1, 1]; False (out unusable) if any action is not finite."""
    for i in range(actions.shape[0]):
        v = float(actions[i])
        if not math.isfinite(v):
            return False
        out[i] = min(1.0, max(-1.0, v))
    return True


@jit
def episode_flags(active, out, steps, max_steps, terminated, truncated, rewards):
    """After a step: count the active balls' steps; fill terminated (an event), truncated
    (the time limit, ``max_steps`` <= 0 for none) and rewards (0 for balls not stepped)."""
    for i in range(active.shape[0]):
        if active[i]:
            steps[i] += 1
            terminated[i] = out[i, O_STATUS] > 0
            truncated[i] = not terminated[i] and 0 < max_steps <= steps[i]
            rewards[i] = out[i, O_REWARD]
        else:
            terminated[i] = False
            truncated[i] = False
            rewards[i] = 0.0


@jit
def command_rates(cfg, balls, commands, active, rates):
    """When commands take effect (delays: `engine.DelayPlan`): ``rates[i]`` is what the
    segments of a split control period pass the step with ``C_GIVEN`` until the next command:
    Ω̇ for the whole control period from Ω now (`omega_rate` with ``cfg``, the undelayed
    configuration), 0 for a NaN command (before the first command arrives the motor holds its
    speed); in voltage mode the command itself."""
    for i in range(balls.shape[0]):
        if active[i]:
            a = commands[i]
            if cfg[C_VOLTAGE_MODE] != 0.0:
                rates[i] = a
            elif math.isnan(a):
                rates[i] = 0.0
            else:
                rates[i] = omega_rate(cfg, balls[i, B_OMEGA], a)


@jit
def normal_over_mg(model, p, y, ball, cfg):
    """N/(mg) of a ball at rest in time (reset observation info)."""
    drive = np.zeros(DRIVE_WIDTH)
    drive[DRIVE_W0] = ball[B_OMEGA]
    drive[DRIVE_AMP] = cfg[C_RIPPLE_AMP]
    drive[DRIVE_PHASE] = ball[B_PHASE]
    dy = np.empty(STATE_WIDTH)
    n = rhs(model, p, drive, 0.0, y, dy, True)
    g = weight(p)
    return n / g if g > 0 else n


@jit
def weight(p):
    """Gravity per unit mass [m/s²], the unit of N/mg: the whole of it on a tilted saddle,
    whose packed row splits it into g·cos(tilt) along the axis and g·sin(tilt) across
    (`Scene.params`; hypot(g, 0) is g exactly on a level one)."""
    g, tilt = p[P_G], p[P_TILT_FORCE]
    if tilt == 0.0 and math.isfinite(g):
        return abs(g)  # what hypot gives (IEEE 754 / C99 Annex F: hypot(x, ±0) = |x|), sooner
    return math.hypot(g, tilt)


specialisable(__name__)
