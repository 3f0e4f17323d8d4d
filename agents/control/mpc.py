"""``mpc``: model-predictive feedback on the saddle speed with the exact model.

Every control step, `ModelPredictiveController` estimates the ball's state from the
observation (`saddle_env.envs.observation` gives the columns), predicts each candidate
speed change with the compiled integrator the simulator and the environment use, and picks
the candidate that shrinks the orbit without a predicted loss. See the class docstring.
"""

from __future__ import annotations

import math
from typing import Any

import numba as nb
import numpy as np

from saddle_env import kernels as Kn
from saddle_env.envs import EnvConfig
from saddle_env.envs.observation import VELOCITY_SCALE, states_from_observations
from saddle_env.integrators import state_scale
from saddle_env.linear import abcd, critical_omega, is_stable
from saddle_env.prediction import predict_batch
from saddle_env.scene import P_A, P_B, P_G, P_R, ROLLING

from .best_constant import best_constant
from .controllers import Controller

RAMP, BACK, HOLD = range(3)  # the segments of a candidate's prediction
METHOD = "dop853"            # the integrator of every prediction


@nb.njit(cache=True)
def _centre_velocity(model, p, y):
    """Horizontal velocity of the ball's centre (rotating frame) [m/s]."""
    g = Kn.geometry(p[P_A], p[P_B], p[P_R], y[0], y[1])
    vx, vy = Kn.contact_velocity(model, p, y)
    return g.J1x * vx + g.J2x * vy, g.J1y * vx + g.J2y * vy


@nb.njit(cache=True)
def _centre_velocities(model, p, Y, out, spin):
    """Centre velocities (n, 2) and, rolling, the spins about the normal w·n (n,)."""
    for i in range(Y.shape[0]):
        out[i, 0], out[i, 1] = _centre_velocity(model, p, Y[i])
        if model == ROLLING:
            g = Kn.geometry(p[P_A], p[P_B], p[P_R], Y[i, 0], Y[i, 1])
            spin[i] = g.nx * Y[i, 2] + g.ny * Y[i, 3] + g.nz * Y[i, 4]
        else:
            spin[i] = 0.0


@nb.njit(cache=True)
def _orbit_size(model, p, y, w, grid_lo, grid_step, modes):
    """Upper bound of the future orbit radius [m] of the linearised motion at constant
    speed ``w`` from state ``y``: Σ_modes |amplitude|·|position part of the eigenvector|
    (the two modal amplitudes are conserved at constant speed); inf where ``w`` is not
    stabilising. ``modes``: the table of `_mode_table` for this ball."""
    j = int(round((w - grid_lo) / grid_step))
    if j < 0 or j >= modes.shape[0] or not math.isfinite(modes[j, 0, 0]):
        return np.inf
    g = Kn.geometry(p[P_A], p[P_B], p[P_R], y[0], y[1])
    z0, z1 = g.cx, g.cy
    z2, z3 = _centre_velocity(model, p, y)
    size = 0.0
    for m in range(2):
        re = modes[j, m, 0] * z0 + modes[j, m, 1] * z1 + modes[j, m, 2] * z2 + modes[j, m, 3] * z3
        im = modes[j, m, 4] * z0 + modes[j, m, 5] * z1 + modes[j, m, 6] * z2 + modes[j, m, 7] * z3
        size += math.hypot(re, im)
    return size


@nb.njit(cache=True)
def _candidate_drives(omega0, force, omega_ref, low, high, rates, ramps, amax, t_hold, drives,
                      durations):
    """The three drive segments of ball i's candidate k (run i·K + k): ramp Ω at ``rates[k]``
    for ``ramps[k]`` s (kept within [``low[i]``, ``high[i]``]), then back to ``omega_ref[i]``
    at ``amax``, then hold it for ``t_hold``; the lab-fixed force ``force[i]`` (saddle axes
    now) throughout. Fills ``drives`` (n·K, 3, DRIVE_WIDTH) and ``durations`` (n·K, 3)."""
    n, K = omega0.shape[0], rates.shape[0]
    for q in range(n * K):
        i, k = q // K, q % K
        w_ref = omega_ref[i]
        t_ramp = ramps[k]
        w1 = min(high[i], max(low[i], omega0[i] + rates[k] * t_ramp))
        t_back = abs(w_ref - w1) / amax
        for seg in range(3):
            drives[q, seg, :] = 0.0
            drives[q, seg, Kn.DRIVE_FX], drives[q, seg, Kn.DRIVE_FY] = force[i, 0], force[i, 1]
        drives[q, RAMP, Kn.DRIVE_W0] = omega0[i]
        drives[q, RAMP, Kn.DRIVE_RATE] = (w1 - omega0[i]) / t_ramp
        drives[q, BACK, Kn.DRIVE_W0] = w1
        drives[q, BACK, Kn.DRIVE_RATE] = (w_ref - w1) / t_back if t_back > 0 else 0.0
        drives[q, HOLD, Kn.DRIVE_W0] = w_ref
        durations[q, RAMP], durations[q, BACK], durations[q, HOLD] = t_ramp, t_back, t_hold


@nb.njit(cache=True)
def _candidate_drives_voltage(omega0, force, targets, omega_ref, ramps, tau, t_hold, drives,
                              durations):
    """`_candidate_drives` for a voltage-driven motor: candidate k of ball i holds the voltage
    whose steady speed is ``targets[i, k]`` for ``ramps[k]`` s, then the reference's voltage
    for ``t_hold`` s (a motor relaxing with time constant ``tau``: the drive rows' exponential
    term carries it exactly; the back segment is empty)."""
    n, K = omega0.shape[0], ramps.shape[0]
    for q in range(n * K):
        i, k = q // K, q % K
        w_ref, w_k = omega_ref[i], targets[i, k]
        t_ramp = ramps[k]
        w1 = w_k + (omega0[i] - w_k) * math.exp(-t_ramp / tau)
        for seg in range(3):
            drives[q, seg, :] = 0.0
            drives[q, seg, Kn.DRIVE_FX], drives[q, seg, Kn.DRIVE_FY] = force[i, 0], force[i, 1]
            drives[q, seg, Kn.DRIVE_DECAY_RATE] = 1.0 / tau
        drives[q, RAMP, Kn.DRIVE_W0] = w_k
        drives[q, RAMP, Kn.DRIVE_DECAY] = omega0[i] - w_k
        for seg in (BACK, HOLD):
            drives[q, seg, Kn.DRIVE_W0] = w_ref
            drives[q, seg, Kn.DRIVE_DECAY] = w1 - w_ref
        durations[q, RAMP], durations[q, BACK], durations[q, HOLD] = t_ramp, 0.0, t_hold


@nb.njit(cache=True)
def _centre_states(model, p, Y, out):
    """Centre position and velocity (n, 4) [m, m/s] in the saddle's axes of states ``Y``."""
    for i in range(Y.shape[0]):
        g = Kn.geometry(p[P_A], p[P_B], p[P_R], Y[i, 0], Y[i, 1])
        out[i, 0], out[i, 1] = g.cx, g.cy
        out[i, 2], out[i, 3] = _centre_velocity(model, p, Y[i])


@nb.njit(cache=True)
def _score(model, P, table, omega_ref, grid_lo, grid_step, modes, state, normal, status, cost,
           min_normal):
    """Cost and smallest N/mg of every run of a plan (run q = i·K + k, K = ``cost.shape[1]``)
    from its samples: the orbit size at ``omega_ref[i]`` averaged over the hold samples
    (inf after a predicted loss) and the smallest N/mg over all samples (0 after a loss)."""
    K = cost.shape[1]
    for q in range(state.shape[0]):
        i, k = q // K, q % K
        p = P[i]
        g = p[P_G]
        lowest = np.inf
        acc = 0.0
        count = 0
        for seg in range(state.shape[1]):
            for r in range(state.shape[2]):
                if not math.isfinite(state[q, seg, r, 0]):
                    break
                lowest = min(lowest, normal[q, seg, r] / g)
                if seg == HOLD:
                    acc += _orbit_size(model, p, state[q, seg, r], omega_ref[i], grid_lo,
                                       grid_step, modes[table[i]])
                    count += 1
        if status[q] != 0:
            lowest = min(lowest, 0.0)
        min_normal[i, k] = lowest
        cost[i, k] = acc / count if count > 0 and status[q] == 0 else np.inf


def _mode_table(scene, lo: float, hi: float, step: float) -> np.ndarray:
    """Per speed on a grid: for the two modes, 2·||v_pos||·(row of V⁻¹) as (re[4], im[4]).

    Linearised centre dynamics (Table I), z = (x_c, y_c, ẋ_c, ẏ_c); z(t) = Σ c_k v_k e^{λ_k t}
    with c = V⁻¹ z; a mode's position traces an ellipse of radius at most 2|c_k|·||v_k,pos||.
    """
    speeds = np.arange(lo, hi + step / 2, step)
    table = np.full((len(speeds), 2, 8), np.nan)
    for j, w in enumerate(speeds):
        if not is_stable(scene, w):
            continue
        lam, V = np.linalg.eig(abcd(scene, w).matrix())
        Vinv = np.linalg.inv(V)
        pick = np.flatnonzero(lam.imag > 0)
        if len(pick) != 2:
            continue
        for m, kidx in enumerate(pick):
            row = 2.0 * np.linalg.norm(V[:2, kidx]) * Vinv[kidx]
            table[j, m, :4], table[j, m, 4:] = row.real, row.imag
    return table


def _rotate(v: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotate rows (x, y) of ``v`` by ``angle`` [rad] (per row)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]])


class ModelPredictiveController(Controller):
    """Model-predictive control of the saddle speed with the exact model: a one-step
    policy improvement, every control step, over holding the reference speed ``omega_ref``.

    For each ball:

    1. **State estimate** from the observation: the centre's position and velocity are
       inverted to the contact point and its velocity (Newton on c(q) = observed centre);
       a rolling ball's spin is that of rolling plus a spin about the normal, which the
       camera cannot see: 0 at a reset (as the environment places balls), afterwards
       carried over from the previous step's prediction.
    2. **Prediction** with the exact model (`saddle_env.prediction.predict_batch`, the
       integrator `simulate` and the environment use), for each candidate: Ω̇ = level ×
       ``max_accel`` for ``ramps`` control periods (the level is the coming step's
       action; Ω kept within ``band`` of the reference), then back to the reference as
       fast as the motor allows, then ``hold`` seconds there; detachment and escape events
       on, N/mg sampled every ``sample`` seconds.
    3. **Cost**: the orbit size at the reference speed — the bound on the future orbit
       radius of the linearised motion (Table I), from its two modal amplitudes, which
       are conserved at constant speed — averaged over the hold.
    4. **Choice**: the smallest cost among candidates with no predicted loss and N/mg ≥
       ``margin`` at every sample; if none qualifies, the candidate with no predicted loss
       and the largest N/mg (backing off before detachment).

    Farther than ``band`` from the reference (at the start of an episode) it approaches
    the reference as fast as the motor allows, as the constant-speed baselines do.

    What varies between episodes is estimated when the config says it varies, in the
    ``state`` of `predict` (SB3's recurrent-state slot; pass the returned one back):

    * **air force** (``air_force > 0``): the lab-fixed force is corrected each step from
      the error of the predicted centre velocity (gain ``observer_gain``), turned with
      the saddle, and included in the predictions;
    * **ball radius** (``ball_radii``): one estimator per candidate radius runs in
      parallel; the radius whose one-step predictions fit best (errors weighted over
      ``id_time`` seconds) is used. Randomised ``a`` and contact models are not
      identified (the nominal values are used); sensor noise and the motor's ripple are
      not modelled.

    ``omega_ref`` defaults to the ``best-const`` speed of the config (searched and cached
    on first use), kept ≥ 1.05·Ω_crt of the estimated ball and ≤ ``omega_max − band``
    (room to modulate both ways).

    **The rig** (a voltage-driven motor, ``obs_delay`` / ``action_delay``, a camera without
    velocities; `_predict_rig`): the estimate is of the state the observation shows, carried
    from step to step by the exact model through the commands then in force (the controller
    keeps its last commands) and corrected by each observation; velocities the camera does
    not give are estimated from the positions' prediction errors (``position_gain``,
    ``velocity_gain``), the motor's speed from its model and the tachometer
    (``speed_gain``). With ``delay_aware`` (default) the estimate is then carried through
    the camera's and the command's delays, so the plan starts where the coming command will
    act; ``delay_aware=False`` (the ``mpc-blind`` baseline) plans from the estimate as if it
    were now. In voltage mode a candidate holds the voltage of the steady speed
    ``omega_ref`` + level × ``voltage_span`` for its ramp, then the reference's voltage.
    Configurations without these parts take the path above unchanged.
    """

    name = "mpc"

    def __init__(self, config: EnvConfig, omega_ref: float | None = None,
                 levels: tuple[float, ...] = (-1.0, -0.5, 0.5, 1.0, 0.0),
                 ramps: tuple[int, ...] = (1, 5, 10), hold: float = 0.2, sample: float = 0.025,
                 margin: float = 0.3, band: float = 3.0, observer_gain: float = 0.2,
                 id_time: float = 0.5, rtol: float = 1e-6, name: str = "mpc",
                 delay_aware: bool = True, position_gain: float = 0.5,
                 velocity_gain: float = 0.3, speed_gain: float = 0.2,
                 voltage_span: float = 10.0):
        super().__init__(config)
        c = config
        self.name = name
        # Candidates: every nonzero level for every ramp length, and "hold" (level 0).
        self.levels = np.array([lv for r in ramps for lv in levels if lv != 0] + [0.0])
        self.ramps = np.array([r for r in ramps for lv in levels if lv != 0]
                              + [1]) * c.control_period
        self.hold, self.sample, self.margin, self.rtol = hold, sample, margin, rtol
        self.band = band
        self.observer_gain, self.id_time = observer_gain, id_time
        self.radii = tuple(c.ball_radii) if c.ball_radii else (c.R,)
        self.scenes = [c.scene(R=R) for R in self.radii]
        self.nominal = int(np.argmin([abs(R - c.R) for R in self.radii]))
        self.estimate_force = c.air_force > 0
        self._model = self.scenes[0].model_code
        self._P = np.array([s.params() for s in self.scenes])
        self._scales = np.array([state_scale(p, self._model) for p in self._P])
        self._alpha = c.alpha if self.scenes[0].rolling else 0.0
        self._max_step = math.pi / (2.0 * c.omega_max)
        self.omega_crt = np.array([critical_omega(s) for s in self.scenes])
        self._grid_step = 0.01
        self._grid_lo = 0.5 * float(np.nanmin(self.omega_crt))
        self._modes = np.array([_mode_table(s, self._grid_lo, c.omega_max + 1.0, self._grid_step)
                                for s in self.scenes])
        if omega_ref is None:
            omega_ref = best_constant(c)["omega"]
        self.omega_ref = float(omega_ref)
        # Per candidate radius: the reference speed (at least 1.05·Ω_crt, with room to
        # modulate below omega_max) and the window the candidates stay in.
        floor = 1.05 * self.omega_crt
        self._ref = np.maximum(np.minimum(self.omega_ref, c.omega_max - band), floor)
        self._ref = np.minimum(self._ref, c.omega_max)
        self._low = np.maximum(self._ref - band, 0.0)
        self._high = np.minimum(self._ref + band, c.omega_max)
        # Recurrent state per ball: [has previous, previous observation, previous action],
        # then per candidate radius a block (force x, force y, fit score, spin about normal).
        # With the commanded speed in the observation the estimators and the plan ramp the
        # motor from it, not from the measured speed: in target mode the motor moves from its
        # set-point, and the measured speed's ripple and noise (1 rad/s on the gusty levels)
        # would otherwise read as a ±20 rad/s² ramp that never happened.
        self._cmd = self.layout.command
        self._d = self.obs_dim + (self._cmd is not None)   # columns kept per observation
        self.state_size = self._d + 2 + 4 * len(self.radii)
        # The rig (issue 42): a voltage-driven motor, delays, a camera without velocities.
        # Such configurations take `_predict_rig`; every other keeps the path above, step for
        # step as before.
        self._voltage = c.action_mode == "voltage"
        self._camera = not c.observe_velocity
        self.delay_aware = bool(delay_aware)
        self._rig = self._voltage or self._camera or c.obs_delay > 0 or c.action_delay > 0
        self._obs_config = c
        if self._rig:
            if c.obs_frame != "rotating":
                raise ValueError("mpc on a rig configuration (voltage mode, delays or a "
                                 "positions-only camera) needs obs_frame='rotating'")
            # The estimate is kept as a full observation of one frame (x, y, vx, vy, Ω),
            # read back by `states_from_observations` with this configuration.
            self._obs_config = EnvConfig.from_kwargs(**dict(
                c.as_dict(), observe_velocity=True, observe_command=False, observe_angle=False,
                obs_history=1))
            self.position_gain, self.velocity_gain = position_gain, velocity_gain
            self.speed_gain, self.voltage_span = speed_gain, voltage_span
            d_obs, d_act = (c.obs_delay, c.action_delay) if self.delay_aware else (0.0, 0.0)
            self._obs_delay, self._act_delay = d_obs, d_act
            T = c.control_period
            # commands given up to this many periods ago can be in force between the
            # previous observation's time and the moment the next command takes effect
            self._history = math.ceil((d_obs + d_act) / T + 1e-9) + 2
            self._d = 5
            self._hist_at = 2 + self._d + 4 * len(self.radii)
            self.state_size = self._hist_at + self._history
            self._top = c.motor_gain * c.voltage_max

    # -- estimation ----------------------------------------------------------------------
    def states(self, obs: np.ndarray, radius: int | None = None,
               spin: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(n, 5) physics states and (n,) speeds estimated from a float64 batch of
        observations, for the candidate radius ``radius`` (default: the nominal one) and
        spins about the normal ``spin`` (n,) [rad/s] (default 0, as at a reset)."""
        j = self.nominal if radius is None else radius
        return states_from_observations(self._obs_config, self._model, self._P[j], obs, spin)

    def _block(self, j: int) -> int:
        return 2 + self._d + 4 * j

    def _update(self, obs: np.ndarray, state: np.ndarray) -> np.ndarray:
        """Advance the estimators of the rows that have a previous observation: predict the
        step just taken from the previous estimate, for every candidate radius; carry the
        hidden spin about the normal over from the prediction; correct the force estimate
        with the error of the predicted centre velocity; accumulate the fit score."""
        c = self.config
        d, nR = self._d, len(self.radii)
        new = state.copy()
        rows = np.flatnonzero(state[:, 0] > 0)
        if len(rows) == 0:
            return new
        n = len(rows)
        prev = state[rows, 1:1 + d]
        action = state[rows, 1 + d]
        dt = c.control_period
        decay = math.exp(-dt / self.id_time)
        for j in range(nR):
            o = self._block(j)
            f0, spin0 = state[rows, o:o + 2], state[rows, o + 3]
            Yp, wp = self.states(prev, j, spin0)
            rate = self.motor_rate(self._motor_speed(prev, wp), action)
            drives = np.zeros((n, 1, Kn.DRIVE_WIDTH))
            drives[:, 0, Kn.DRIVE_W0], drives[:, 0, Kn.DRIVE_RATE] = wp, rate
            drives[:, 0, Kn.DRIVE_FX], drives[:, 0, Kn.DRIVE_FY] = f0[:, 0], f0[:, 1]
            Ypred = predict_batch(self._model, np.repeat(self._P[j][None], n, 0), Yp, drives,
                                  np.full((n, 1), dt), dt, method=METHOD, rtol=self.rtol,
                                  events=(), max_step=self._max_step,
                                  scales=np.repeat(self._scales[j][None], n, 0)).final_state
            vp, spin1 = np.empty((n, 2)), np.empty(n)
            _centre_velocities(self._model, self._P[j], Ypred, vp, spin1)
            vobs = self._observed_velocity(obs[rows])
            dv = vobs - vp
            f1 = _rotate(f0, -(wp * dt + 0.5 * rate * dt * dt))  # the saddle turned by θ
            if self.estimate_force:
                f1 = f1 + self.observer_gain * (1.0 + self._alpha) * dv / dt
            new[rows, o:o + 2] = f1
            new[rows, o + 2] = decay * state[rows, o + 2] + np.sum(dv * dv, 1)
            new[rows, o + 3] = spin1
        return new

    def _batch(self, observation: Any) -> tuple[np.ndarray, bool]:
        """The controllers' columns, plus the commanded speed last when it is observed."""
        base, single = super()._batch(observation)
        if self._cmd is None:
            return base, single
        full = np.asarray(observation, dtype=np.float64).reshape(len(base), -1)
        return np.hstack([base, full[:, self._cmd:self._cmd + 1]]), single

    def _motor_speed(self, batch: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """The speed the motor ramps from: its set-point when observed, else the measured."""
        return batch[:, -1] * self.config.omega_max if self._cmd is not None else measured

    def _observed_velocity(self, obs: np.ndarray) -> np.ndarray:
        """Centre velocity (n, 2) in the saddle's axes [m/s] from observations."""
        Y, _ = self.states(obs)
        v, spin = np.empty((len(obs), 2)), np.empty(len(obs))
        _centre_velocities(self._model, self._P[self.nominal], Y, v, spin)
        return v

    # -- planning ------------------------------------------------------------------------
    def plan(self, obs: np.ndarray, force: np.ndarray | None = None,
             radius: np.ndarray | None = None,
             spin: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Predicted cost, smallest N/mg and event status of every candidate ((n, K) arrays)
        for balls of candidate radius index ``radius`` (n,) with spin ``spin`` (n,) about the
        normal, under the lab-fixed ``force`` (n, 2) [m/s², saddle axes now]; defaults: the
        nominal radius, no spin, no force."""
        n = len(obs)
        radius = np.full(n, self.nominal) if radius is None else np.asarray(radius, np.int64)
        spin = np.zeros(n) if spin is None else np.asarray(spin, float)
        Y = np.zeros((n, Kn.STATE_WIDTH))
        omega = np.zeros(n)
        for j in np.unique(radius):
            sel = radius == j
            Y[sel], omega[sel] = self.states(obs[sel], int(j), spin[sel])
        return self.plan_states(Y, omega, force, radius)

    def plan_states(self, Y: np.ndarray, omega: np.ndarray, force: np.ndarray | None,
                    radius: np.ndarray) -> dict[str, np.ndarray]:
        """`plan` from physics states ``Y`` (n, STATE_WIDTH) and motor speeds ``omega`` (n,)
        [rad/s] (estimated, or predicted through a delay) rather than observations."""
        c = self.config
        n, K = len(Y), len(self.levels)
        force = np.zeros((n, 2)) if force is None else np.ascontiguousarray(force, float)
        drives, durations = np.empty((n * K, 3, Kn.DRIVE_WIDTH)), np.empty((n * K, 3))
        if self._voltage:
            _candidate_drives_voltage(omega, force, self._targets(radius), self._ref[radius],
                                      self.ramps, c.motor_tau, self.hold, drives, durations)
        else:
            _candidate_drives(omega, force, self._ref[radius], self._low[radius],
                              self._high[radius], self.levels * c.max_accel, self.ramps,
                              c.max_accel, self.hold, drives, durations)
        pred = predict_batch(self._model, np.repeat(self._P[radius], K, 0), np.repeat(Y, K, 0),
                             drives, durations, self.sample, method=METHOD, rtol=self.rtol,
                             max_step=self._max_step, scales=np.repeat(self._scales[radius], K, 0))
        cost, normal = np.zeros((n, K)), np.zeros((n, K))
        _score(self._model, self._P[radius], radius, self._ref[radius], self._grid_lo,
               self._grid_step, self._modes, pred.state, pred.normal, pred.status, cost, normal)
        return {"cost": cost, "min_normal": normal, "status": pred.status.reshape(n, K),
                "omega": omega, "radius": radius}

    def choose(self, plan: dict[str, np.ndarray]) -> np.ndarray:
        """Actions from a `plan`."""
        c = self.config
        cost, normal, status = plan["cost"], plan["min_normal"], plan["status"]
        ok = (status == 0) & (normal >= self.margin) & np.isfinite(cost)
        choice = np.argmin(np.where(ok, cost, np.inf), axis=1)
        for i in np.flatnonzero(~ok.any(axis=1)):
            # No safe candidate: no predicted loss first, then the most support.
            choice[i] = min(range(len(self.levels)),
                            key=lambda k: (status[i, k] != 0, -normal[i, k], abs(self.levels[k])))
        j = plan["radius"]
        if self._voltage:  # the voltage of the chosen candidate's steady speed
            steady = self._targets(j)[np.arange(len(choice)), choice]
            return 2.0 * steady / self._top - 1.0
        rate = self.levels[choice] * c.max_accel
        start = plan.get("command", plan["omega"])   # the set-point the motor ramps from
        target = np.clip(start + rate * c.control_period, self._low[j], self._high[j])
        return self.speed_action(start, target)

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """As `Controller.predict`; ``state`` ((n, state_size), or None at the start) carries
        the estimators from step to step: pass back the returned one, with
        ``episode_start`` (n,) True where a new episode began."""
        batch, single = self._batch(observation)
        n, d = batch.shape
        if state is None:
            state = np.zeros((n, self.state_size))
        state = np.array(state, dtype=np.float64).reshape(n, self.state_size)
        if episode_start is not None:
            start = np.asarray(episode_start, dtype=bool).reshape(n)
            state[start] = 0.0
        if self._rig:
            act, state = self._predict_rig(batch, state)
            out = act.astype(np.float32).reshape(-1, 1)
            return (out[0] if single else out), state
        state = self._update(batch, state)
        blocks = state[:, 2 + d:].reshape(n, len(self.radii), 4)
        radius = np.where(state[:, 0] > 0, np.argmin(blocks[:, :, 2], axis=1), self.nominal)
        mine = blocks[np.arange(n), radius]
        force = mine[:, :2] if self.estimate_force else None
        # Outside the window around the reference speed: approach it as fast as the motor
        # allows (the base policy); inside: plan.
        omega = self._motor_speed(batch, batch[:, self.obs_dim - 1] * self.config.omega_max)
        act = self.speed_action(omega, self._ref[radius])
        near = np.flatnonzero((omega >= self._low[radius] - 1e-9) &
                              (omega <= self._high[radius] + 1e-9))
        if len(near):
            plan = self.plan(batch[near], None if force is None else force[near], radius[near],
                             mine[near, 3])
            plan["command"] = omega[near]
            act[near] = self.choose(plan)
        act = np.clip(act, -1.0, 1.0)
        act = act.astype(np.float32).astype(np.float64)   # what the environment receives
        state[:, 0] = 1.0
        state[:, 1:1 + d] = batch
        state[:, 1 + d] = act
        out = act.astype(np.float32).reshape(-1, 1)
        return (out[0] if single else out), state

    # -- the rig: a voltage-driven motor, delays, a camera without velocities ------------
    def _targets(self, radius: np.ndarray) -> np.ndarray:
        """(n, K) steady speeds [rad/s] of the candidates' voltages (voltage mode): the
        reference plus level × ``voltage_span``, within what the motor can reach."""
        return np.clip(self._ref[radius][:, None] + self.levels[None, :] * self.voltage_span,
                       0.0, self._top)

    def _segments(self, t0: float, t1: float) -> list[tuple[int, float]]:
        """The pieces of [t0, t1] (seconds from now) by the command in force, oldest first:
        (j, length) for the command given j control periods ago, which is in force from
        ``action_delay`` − j·T for one period (the delays as this controller knows them)."""
        T, a = self.config.control_period, self._act_delay
        out = []
        for j in range(self._history, 0, -1):
            lo, hi = max(t0, a - j * T), min(t1, a - (j - 1) * T)
            if hi - lo > 1e-12:
                out.append((j, hi - lo))
        return out

    def _drive_chain(self, omega: np.ndarray, force: np.ndarray, history: np.ndarray,
                     segments: list[tuple[int, float]]
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Drive rows (n, S, DRIVE_WIDTH) and durations (n, S) of the commands in force over
        ``segments`` (`_segments`) from motor speed ``omega`` (n,), with the lab-fixed
        ``force`` (n, 2) in the saddle's axes at the start; the motor's speed at the end and
        the angle the saddle turned (n,). A NaN command (none given yet) holds the speed."""
        c = self.config
        n, S = len(omega), len(segments)
        drives, durations = np.zeros((n, S, Kn.DRIVE_WIDTH)), np.zeros((n, S))
        w, turned = np.array(omega, dtype=float), np.zeros(n)
        for s, (j, length) in enumerate(segments):
            cmd = history[:, j - 1]
            hold = np.isnan(cmd)
            cmd = np.nan_to_num(cmd)
            row = drives[:, s]
            row[:, Kn.DRIVE_FX], row[:, Kn.DRIVE_FY] = force[:, 0], force[:, 1]
            if self._voltage:
                steady = np.where(hold, w, 0.5 * (cmd + 1.0) * self._top)
                row[:, Kn.DRIVE_W0], row[:, Kn.DRIVE_DECAY] = steady, w - steady
                row[:, Kn.DRIVE_DECAY_RATE] = 1.0 / c.motor_tau
                e = math.exp(-length / c.motor_tau)
                turned += steady * length + (w - steady) * (1.0 - e) * c.motor_tau
                w = steady + (w - steady) * e
            else:
                rate = np.where(hold, 0.0, self.motor_rate(w, cmd))
                row[:, Kn.DRIVE_W0], row[:, Kn.DRIVE_RATE] = w, rate
                turned += w * length + 0.5 * rate * length * length
                w = w + rate * length
            durations[:, s] = length
        return drives, durations, w, turned

    def _advance(self, radius: np.ndarray, Y: np.ndarray, drives: np.ndarray,
                 durations: np.ndarray) -> np.ndarray:
        """States ``Y`` (balls of candidate radius index ``radius``) carried through the
        drive chain by the exact model (no events): the final states."""
        return predict_batch(self._model, self._P[radius], np.ascontiguousarray(Y), drives,
                             durations, float(durations[0].sum()) or 1.0, method=METHOD,
                             rtol=self.rtol, events=(), max_step=self._max_step,
                             scales=self._scales[radius]).final_state

    def _carry(self, Y: np.ndarray, radius: np.ndarray, omega: np.ndarray, force: np.ndarray,
               history: np.ndarray, t0: np.ndarray, t1: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """States ``Y``, motor speeds and the angle turned, carried from ``t0[i]`` to
        ``t1[i]`` (seconds from now, per row; rows with the same pair go together) through
        the commands in force (`_drive_chain`). Before the episode's start the camera shows
        the starting state, so no time is carried from before it."""
        Y, omega, turned = Y.copy(), np.array(omega, dtype=float), np.zeros(len(Y))
        keys = np.round(np.column_stack([t0, t1]), 12)
        for key in np.unique(keys, axis=0):
            if key[1] - key[0] <= 1e-12:
                continue
            sel = np.flatnonzero((keys == key).all(axis=1))
            drives, durations, omega[sel], turned[sel] = self._drive_chain(
                omega[sel], force[sel], history[sel], self._segments(key[0], key[1]))
            end = self._advance(radius[sel], Y[sel], drives, durations)
            Y[sel, :end.shape[1]] = end
        return Y, omega, turned

    def _predict_rig(self, raw: np.ndarray, state: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
        """`predict` on a rig configuration. The estimate is the ball's state at the time the
        observation shows (``obs_delay`` ago): each step the last estimate is carried one
        period forward through the commands then in force and corrected by the new
        observation (positions by ``position_gain``, velocities by ``velocity_gain`` × the
        position error / T when the camera gives no velocities, the motor's speed by
        ``speed_gain`` × the tachometer's error, the force as in `_update`); the candidate
        radius whose predictions fit the positions best is used. Then, ``delay_aware``, the
        estimate is carried through the delays (``obs_delay`` + ``action_delay``, the
        commands given meanwhile in force) to when the next command takes effect, and the
        plan starts there; delay-blind, it starts from the estimate as if it were now.
        ``state[:, 0]`` counts the observations of the episode before this one."""
        c = self.config
        T, L, d, H = c.control_period, c.rim_radius, self._d, self._history
        n = len(raw)
        count = state[:, 0].copy()
        has = count > 0
        start = -count * T   # the episode's start, seconds from now
        history = state[:, self._hist_at:self._hist_at + H].copy()
        history[~has] = np.nan
        pos = raw[:, :2] * L
        w_meas = raw[:, self.obs_dim - 1] * c.omega_max
        vel = None if self._camera else raw[:, 2:4] * VELOCITY_SCALE
        new = state.copy()
        pseudo = np.zeros((n, 5))
        fresh = np.flatnonzero(~has)
        if len(fresh):
            pseudo[fresh] = self._placed(pos[fresh], None if vel is None else vel[fresh],
                                         w_meas[fresh])
            new[fresh, 2 + d:self._hist_at] = 0.0
        radius = np.full(n, self.nominal)
        rows = np.flatnonzero(has)
        if len(rows):
            radius[rows], pseudo[rows] = self._corrected(
                state[rows], pos[rows], None if vel is None else vel[rows], w_meas[rows],
                start[rows], history[rows], new, rows)
        act = self._act_on_estimates(new, pseudo, radius, history, start)
        new[:, 0] = count + 1
        new[:, 1:1 + d] = pseudo
        new[:, 1 + d] = act
        hist = new[:, self._hist_at:self._hist_at + H]
        hist[:, 1:] = history[:, :-1]
        hist[:, 0] = act
        return act, new

    def _placed(self, pos: np.ndarray, vel: np.ndarray | None, w: np.ndarray) -> np.ndarray:
        """The scaled estimate (x, y, vx, vy, Ω) of balls in a new episode: the ball as placed
        (at rest in the laboratory unless the config starts it at rest on the saddle), the
        tachometer's speed."""
        c = self.config
        if vel is not None:
            v = vel
        elif c.init_start == "lab-rest":
            v = np.column_stack([w * pos[:, 1], -w * pos[:, 0]])
        else:
            v = np.zeros((len(pos), 2))
        return np.column_stack([pos / c.rim_radius, v / VELOCITY_SCALE, w / c.omega_max])

    def _corrected(self, state: np.ndarray, pos: np.ndarray, vel: np.ndarray | None,
                   w_meas: np.ndarray, start: np.ndarray, history: np.ndarray,
                   new: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Balls ``rows`` that were observed before (``state`` and the rest are their rows):
        each candidate radius's last estimate carried one period forward and corrected by
        the observation, its force, fit score and spin stored in ``new``; returns the
        best-fitting radius and its scaled estimate (x, y, vx, vy, Ω)."""
        c = self.config
        T, L, d, nR = c.control_period, c.rim_radius, self._d, len(self.radii)
        m = len(rows)
        prev = state[:, 1:1 + d]
        t0 = np.maximum(start, -T - self._obs_delay)
        t1 = np.maximum(start, -self._obs_delay)
        decay = math.exp(-T / self.id_time)
        cands = np.zeros((nR, m, 4))   # per radius: the corrected centre and velocity
        scores = np.zeros((nR, m))
        w_pred = np.zeros(m)
        for j in range(nR):
            o = self._block(j)
            f0, spin0 = state[:, o:o + 2], state[:, o + 3]
            Yp, wp = self.states(prev, j, spin0)
            Ypred, w_pred, turned = self._carry(
                Yp, np.full(m, j), wp, f0 if self.estimate_force else np.zeros((m, 2)),
                history, t0, t1)
            cs = np.empty((m, 4))
            _centre_states(self._model, self._P[j], Ypred, cs)
            vp, spin1 = np.empty((m, 2)), np.empty(m)
            _centre_velocities(self._model, self._P[j], Ypred, vp, spin1)
            err = pos - cs[:, :2]
            if vel is None:
                v = cs[:, 2:] + self.velocity_gain * err / T
                centre = cs[:, :2] + self.position_gain * err
            else:
                v, centre = vel, pos
            dv = v - cs[:, 2:]
            f1 = _rotate(f0, -turned)
            if self.estimate_force:
                f1 = f1 + self.observer_gain * (1.0 + self._alpha) * dv / T
            scores[j] = decay * state[:, o + 2] + np.sum((err / T) ** 2, 1)
            new[rows, o:o + 2] = f1
            new[rows, o + 2] = scores[j]
            new[rows, o + 3] = spin1
            cands[j] = np.column_stack([centre, v])
        best = np.argmin(scores, axis=0)
        pick = cands[best, np.arange(m)]
        # w_pred: the speed predicted with the last radius
        w_est = w_pred + self.speed_gain * (w_meas - w_pred)
        return best, np.column_stack([pick[:, :2] / L, pick[:, 2:] / VELOCITY_SCALE,
                                      w_est / c.omega_max])

    def _act_on_estimates(self, new: np.ndarray, pseudo: np.ndarray, radius: np.ndarray,
                          history: np.ndarray, start: np.ndarray) -> np.ndarray:
        """The actions from the estimates: carried through the delays (``delay_aware``) to
        when the coming command takes effect, then planned near the stable band, else the
        speed action toward the radius's reference speed."""
        c, d, nR = self.config, self._d, len(self.radii)
        n = len(pseudo)
        blocks = new[:, 2 + d:self._hist_at].reshape(n, nR, 4)
        mine = blocks[np.arange(n), radius]
        force = mine[:, :2].copy() if self.estimate_force else np.zeros((n, 2))
        Y = np.zeros((n, Kn.STATE_WIDTH))
        for j in np.unique(radius):
            sel = radius == j
            Y[sel], _ = self.states(pseudo[sel], int(j), mine[sel, 3])
        omega = pseudo[:, 4] * c.omega_max
        if self._obs_delay + self._act_delay > 0:  # to when the coming command takes effect
            Y, omega, turned = self._carry(Y, radius, omega, force, history,
                                           np.maximum(start, -self._obs_delay),
                                           np.full(n, self._act_delay))
            force = _rotate(force, -turned)
        act = self.speed_action(omega, self._ref[radius])
        near = np.flatnonzero((omega >= self._low[radius] - 1e-9) &
                              (omega <= self._high[radius] + 1e-9))
        if len(near):
            plan = self.plan_states(Y[near], omega[near],
                                    force[near] if self.estimate_force else None, radius[near])
            plan["command"] = omega[near]
            act[near] = self.choose(plan)
        return np.clip(act, -1.0, 1.0).astype(np.float32).astype(np.float64)

    def executed(self, state: np.ndarray, actions: Any) -> np.ndarray:
        """``state`` (from `predict`) told that the environment received ``actions`` (n,)
        instead of the ones this controller chose: when another policy drives and mpc only
        watches (imitation labels), its estimators must predict the step the motor took."""
        state = np.array(state, dtype=np.float64)
        sent = np.asarray(actions, dtype=np.float32).astype(np.float64).reshape(-1)
        state[:, 1 + self._d] = sent
        if self._rig:
            state[:, self._hist_at] = sent
        return state


__all__ = ["ModelPredictiveController"]
