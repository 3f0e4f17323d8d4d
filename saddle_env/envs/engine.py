"""State and episode logic shared by the single and the vector environment.

`TrapEngine` holds n balls as arrays, places them at reset (randomised from the caller's
generator), steps them through the compiled control step (`control_step`) and exposes the
observations, rewards and events. The single environment is an engine with n = 1; the
vector environment adds autoreset on top. Physics is never duplicated here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from itertools import pairwise
from typing import Literal, NamedTuple, TypedDict, cast

import numba
import numpy as np

from .. import kernels as K
from ..compilation.specialise import checked, specialise
from ..compilation.threads import threads_usable
from ..integrators import (
    EVENT_DETACH,
    EVENT_ESCAPE,
    EVENT_KINDS,
    METHODS,
    STATUS_MAX_STEPS,
    StepControl,
    state_scale,
    step_control,
)
from ..lifetimes.model import speed_factor
from ..scene import N_PARAMS, P_RESIST, P_TILT_FORCE, Scene
from ..simulate import SimulationError, default_max_step
from . import control_step as S
from .config import MAX_STEPS_PER_CONTROL_STEP, EnvConfig
from .observation import VELOCITY_SCALE, layout


class DelayPlan:
    """Where a control period is split so that delays are exact.

    With period T, a delay d = m·T + f (0 <= f < T) is m whole periods plus a fraction:

    * ``obs_delay``: the observation after period j is the state at (j + 1)·T − d, which lies
      in period j − m at offset T − f; each period takes a sample there (the end of the
      period when f = 0) and the observation is the sample taken m periods before.
    * ``action_delay``: the command given at the start of period j takes effect at offset f
      of period j + m and stays in force for one control period, so a period runs the
      command given m + 1 periods before until f and the one given m before after it.

    ``segments`` are the (start, end) offsets of the pieces a period is integrated in; the
    integrator restarts at each cut, which is exact to its tolerance. A delay within 1e-9 of
    a whole number of periods counts as whole (0.06 s / 0.02 s is 2.9999999999999996).
    """

    def __init__(self, config: EnvConfig):
        T = config.control_period
        self.period = T
        self.obs_periods, obs_frac = _whole_and_fraction(config.obs_delay, T)
        self.act_periods, act_frac = _whole_and_fraction(config.action_delay, T)
        # Cuts closer than 1e-9 periods are one (0.03 s − 0.02 s is 0.009999999999999998, and a
        # 2e-18 s segment is no step an integrator can take).
        cuts: list[float] = []
        for cut in sorted({0.0, T, T - obs_frac, act_frac}):
            if not cuts or cut - cuts[-1] > 1e-9 * T:
                cuts.append(cut)
        cuts[-1] = T
        snap = lambda v: min(cuts, key=lambda cut: abs(cut - v))  # noqa: E731
        self.sample_at = snap(T - obs_frac)   # offset of the period's sample (T: its end)
        self.switch_at = snap(act_frac)       # offset where the next command takes effect
        self.segments = tuple(pairwise(cuts))
        self.active = config.obs_delay > 0 or config.action_delay > 0


def _whole_and_fraction(delay: float, period: float) -> tuple[int, float]:
    q = delay / period
    m = round(q)
    if abs(q - m) <= 1e-9:
        return int(m), 0.0
    m = math.floor(q)
    return int(m), delay - m * period


RESET_OPTION_KEYS = ("x", "y", "vx", "vy", "omega", "R", "a", "contact", "start", "spin_normal")


class DrawnScene(NamedTuple):
    """A ball's scene as a reset draws it (`TrapEngine._draw_scene`), with what the compiled
    step reads of it: its packed parameters, state scales and contact model's code."""

    scene: Scene
    params: np.ndarray
    scale: np.ndarray
    model_code: int


class ResetOptions(TypedDict, total=False):
    """``reset(options=...)`` as `_check_options` returns it: its numbers as floats."""

    x: float
    y: float
    vx: float
    vy: float
    omega: float
    R: float
    a: float
    contact: str
    start: Literal["lab-rest", "rotating-rest"]
    spin_normal: float


class TrapEngine:
    """n balls on n saddles, stepped together.

    Parameters
    ----------
    config : EnvConfig
    n : int
        Number of balls.
    parallel : bool
        Step with numba threads (worth it from a few dozen balls).
    lockstep : bool
        Step balls that fit one integrator step per control period together in
        SIMD blocks (`saddle_env.lockstep`); False forces the scalar path for every ball.
        Results are identical either way (tested); only the speed differs.
    """

    def __init__(self, config: EnvConfig, n: int, parallel: bool | None = None,
                 lockstep: bool = True):
        if not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"num_envs must be a positive integer, got {n!r}")
        self.config = config
        self.n = int(n)
        # Threads pay from two full SIMD blocks on (measured: 64 balls ran no faster on two
        # threads than on one).
        self.parallel = self.n >= 2 * S.LANES if parallel is None else parallel
        self._lockstep = bool(lockstep)
        self.layout = layout(config)
        self.obs_dim = self.layout.dim            # the whole observation (all frames)
        self.frame_dim = self.layout.frame_dim    # one frame, what the compiled step writes
        self.method = METHODS[config.method]
        self.tableau = self.method.tableau
        self.control = self._build_control(config)
        # what the compiled step takes for the two records (see `control_step.step_serial`)
        self._record_fields = (tuple(self.tableau), tuple(self.control))
        self.cfg = self._build_cfg(config)
        self.models = np.zeros(self.n, dtype=np.int64)
        self.P = np.zeros((self.n, N_PARAMS))
        self.scales = np.ones((self.n, K.STATE_WIDTH))
        self.Y = np.zeros((self.n, K.STATE_WIDTH))
        self.balls = np.zeros((self.n, S.BALL_WIDTH))
        self.out = np.zeros((self.n, S.OUT_WIDTH))
        # The compiled step writes this step's frame; with ``obs_history`` k > 1 the
        # observation holds the last k frames, newest first (the same array when k = 1).
        self.frame = np.zeros((self.n, self.frame_dim), dtype=np.float32)
        self.obs = self.frame if self.layout.frames == 1 else \
            np.zeros((self.n, self.obs_dim), dtype=np.float32)
        self.noise = np.zeros((self.n, self.frame_dim))
        self.scenes: list[Scene] = [config.scene()] * self.n
        # Each ball's drive error (``speed_error``): its saddle turns at this factor times
        # the speed its action asks for, drawn at reset.
        self.speed_factor = np.ones(self.n)
        # The compiled step for the contact models the configuration draws from, and rolling
        # resistance if it has any (`compilation.specialise`: a rolling scene does not compile the
        # coulomb machinery); a reset that brings something else widens it.
        self._uses = contact_uses(config)
        self._S = specialise(*self._uses, S)
        self._entries: dict[str, object] = {}  # `_entry`
        self._serial_call: tuple | None = None  # `_run`'s last serial call, made again
        self._scene_cache: dict[tuple, DrawnScene] = {}
        self._noise_scale = self._build_noise_scale(config)
        self._air_decay = math.exp(-config.control_period / config.air_force_tau)
        self.delays = DelayPlan(config)
        if self.delays.active:
            self._init_delays()
        # A step is the compiled call alone: no random draws, delays or frame history.
        self._plain = (config.air_force == 0 and self._noise_scale is None
                       and not self.delays.active and self.layout.frames == 1)
        # Scratch memory for the compiled step, allocated once rather than on every step: one
        # row for the serial step, one per chunk in parallel.
        self._scratch, self._iscratch = (a[0] for a in self._new_scratch(1))
        self._chunk_scratch = self._new_scratch(self._chunks())

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        del state["_S"], state["_entries"]  # compiled code: found again from ``_uses``
        state["_serial_call"] = None
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._S = specialise(*self._uses, S)
        self._entries = {}
        self._serial_call = None

    def _entry(self, name: str, args: tuple):
        """``self._S``'s entry point ``name`` for ``args``, checked once
        (`kernels.checked`: an ahead-of-time one only for exactly its argument types). The
        engine's arguments keep their types from call to call: its own arrays are made once
        and never rebound, and the caller's indices, actions and flags are made int64,
        float64 and bool vectors (`_per_ball`)."""
        fn = self._entries.get(name)
        if fn is None:
            fn = self._entries[name] = checked(self._S, name, args)
        return fn

    @property
    def lockstep(self) -> bool:
        """Whether balls are stepped in SIMD blocks where they can be (see the class doc)."""
        return self._lockstep

    @lockstep.setter
    def lockstep(self, on: bool) -> None:
        self._lockstep = bool(on)
        self._serial_call = None  # `_run` picks the entry by it
        for cfg in (self.cfg, *getattr(self, "_seg_cfgs", ())):
            cfg[S.C_LOCKSTEP] = 1.0 if on else 0.0

    def _chunks(self) -> int:
        """Up to four chunks per thread for load balance, each at least one full SIMD block."""
        return max(1, min(4 * numba.get_num_threads(), self.n // S.LANES))

    def _new_scratch(self, rows: int) -> tuple[np.ndarray, np.ndarray]:
        return (np.zeros((rows, S.scratch_size(self.method.stages))),
                np.zeros((rows, 4 + S.LANES), dtype=np.int64))

    @property
    def delay_arrays(self) -> tuple[str, ...]:
        """Names of the per-ball arrays (rows by ball) the delays and the drive's error keep
        beside the ball rows: what a copy of a ball's state must carry too (the clairvoyant
        reference's copies)."""
        drive = ("speed_factor",) if self.config.speed_error > 0 else ()
        return drive + (("_commands", "_in_force", "_samples") if self.delays.active else ())

    def frames_in_flight(self, ball: int) -> np.ndarray:
        """The frames of ``ball`` taken but not yet shown (the camera's latency), oldest
        first, one per control period; the next observation is the first. Empty without
        an observation delay."""
        if not self.delays.active:
            return np.zeros((0, self.frame_dim), dtype=np.float32)
        m = self.delays.obs_periods      # the queue is newest first; the last row is shown
        return self._samples[ball, m - 1::-1].copy() if m else self._samples[ball, :0].copy()

    def _init_delays(self) -> None:
        """The queues of the delayed step (`_step_delayed`): commands given, newest first
        (NaN: none yet, the motor holds its speed), the Ω̇ (or voltage) in force, and the
        observation samples, newest first."""
        plan = self.delays
        self._commands = np.full((self.n, plan.act_periods + 2), np.nan)
        self._in_force = np.zeros(self.n)
        self._samples = np.zeros((self.n, plan.obs_periods + 1, self.frame_dim),
                                 dtype=np.float32)
        self._covered = np.zeros(self.n)
        self._seg_active = np.zeros(self.n, dtype=bool)
        # One configuration vector per segment: its length as the period, the actions given
        # as Ω̇ (`control_step.C_GIVEN`); the effort is charged once per period on the command.
        self._seg_cfgs = []
        for lo, hi in plan.segments:
            cfg = self.cfg.copy()
            cfg[S.C_DT] = hi - lo
            cfg[S.C_GIVEN] = 1.0
            cfg[S.C_EFFORT_COST] = 0.0
            self._seg_cfgs.append(cfg)

    # -- configuration -------------------------------------------------------------------
    @staticmethod
    def _build_control(c: EnvConfig) -> StepControl:
        """How the integrator steps through a control period: fixed substeps or adaptive
        steps under the same step cap as `simulate`; both events on."""
        rtol = c.rtol if c.rtol is not None else 1e-8
        max_step = math.inf if c.substep else default_max_step(c.omega_max + c.ripple_amp)
        return step_control(c.substep or 0.0, rtol, rtol, max_step, EVENT_DETACH | EVENT_ESCAPE,
                            MAX_STEPS_PER_CONTROL_STEP)

    def _build_cfg(self, c: EnvConfig) -> np.ndarray:
        cfg = np.zeros(S.CFG_WIDTH)
        cfg[S.C_DT] = c.control_period
        cfg[S.C_MAX_ACCEL] = c.max_accel
        cfg[S.C_OMEGA_MAX] = c.omega_max
        cfg[S.C_TARGET_MODE] = 1.0 if c.action_mode == "target" else 0.0
        cfg[S.C_VOLTAGE_MODE] = 1.0 if c.action_mode == "voltage" else 0.0
        cfg[S.C_MOTOR_TOP] = c.motor_gain * c.voltage_max
        cfg[S.C_MOTOR_RATE] = 1.0 / c.motor_tau
        cfg[S.C_LAB_FRAME] = 1.0 if c.obs_frame == "lab" else 0.0
        cfg[S.C_POS_SCALE] = c.rim_radius
        cfg[S.C_VEL_SCALE] = VELOCITY_SCALE
        cfg[S.C_RIPPLE_AMP] = c.ripple_amp
        cfg[S.C_RIPPLE_FREQ] = c.ripple_freq
        cfg[S.C_LOSS] = c.loss_penalty
        cfg[S.C_DIST_COST] = c.distance_cost
        cfg[S.C_EFFORT_COST] = c.effort_cost
        cfg[S.C_LOCKSTEP] = 1.0 if self._lockstep else 0.0
        lay = layout(c)
        cfg[S.C_OBS_OMEGA] = lay.omega
        cfg[S.C_OBS_VEL] = 1.0 if lay.vx is not None else 0.0
        cfg[S.C_POS_QUANTUM] = c.position_quantum / c.rim_radius
        cfg[S.C_OBS_COMMAND] = -1 if lay.command is None else lay.command
        # In the lab frame the angle is always observed; in the rotating frame on request.
        cfg[S.C_OBS_COS] = -1 if lay.cos is None else lay.cos
        return cfg

    def _build_noise_scale(self, c: EnvConfig) -> np.ndarray | None:
        if c.position_noise == c.velocity_noise == c.omega_noise == 0.0:
            return None
        scale = np.zeros(self.frame_dim)
        scale[:2] = c.position_noise / c.rim_radius
        if self.layout.vx is not None:
            scale[2:4] = c.velocity_noise / VELOCITY_SCALE
        scale[self.layout.omega] = c.omega_noise / c.omega_max
        return scale

    # -- reset ---------------------------------------------------------------------------
    def _place(self, idx: np.ndarray, x: np.ndarray, y: np.ndarray, vx: np.ndarray,
               vy: np.ndarray, lab_rest: np.ndarray, spin: float | np.ndarray) -> None:
        """Set balls ``idx`` to their drawn starts in one compiled call (one per ball where
        each has its own ``spin`` about the normal), first widening the compiled kernels to
        any contact model or rolling resistance the draws brought."""
        models, resist = self._uses
        drawn = frozenset(int(m) for m in self.models[idx])
        resisted = resist or bool((self.P[idx, P_RESIST] != 0.0).any())
        if not drawn <= models or resisted != resist:   # widen only by what was drawn
            self._uses = (models | drawn, resisted)
            self._S = specialise(*self._uses, S)
            self._entries = {}
            self._serial_call = None
        if isinstance(spin, np.ndarray):  # one spin per ball: placed one by one
            for j in range(idx.size):
                args = (idx[j:j + 1], self.models, self.P, self.Y, self.balls, self.cfg,
                        x[j:j + 1], y[j:j + 1], vx[j:j + 1], vy[j:j + 1], lab_rest[j:j + 1],
                        float(spin[j]), self.noise, self.frame, self.out)
                self._entry("place", args)(*args)
        else:
            args = (idx, self.models, self.P, self.Y, self.balls, self.cfg, x, y, vx, vy,
                    lab_rest, spin, self.noise, self.frame, self.out)
            self._entry("place", args)(*args)

    def reset(self, idx: np.ndarray, rngs: Sequence[np.random.Generator],
              options: Mapping[str, object] | None = None) -> None:
        """Place balls ``idx`` at the start of a new episode (randomised from ``rngs[i]``, one
        generator per ball, or as ``options`` say)."""
        opts = _check_options(options)
        c = self.config
        check_reset_omega(opts, c.omega_max)
        check_reset_start(opts, c)
        idx = np.ascontiguousarray(np.atleast_1d(idx), dtype=np.int64)
        k = idx.size
        # Draws per ball, from its own generator and in a fixed order; the states follow
        # in one compiled call (`control_step.place`).
        given_velocity = "vx" in opts or "vy" in opts
        spin = float(opts.get("spin_normal", 0.0))
        hits, omegas, xs, ys, vxs, vys, phases, forces = self._draw_starts(
            idx, rngs, opts, given_velocity, spin)
        start = opts.get("start", c.init_start)
        # The lab's launcher: a ball not spinning in the laboratory spins at -Ω about the
        # normal relative to the saddle (as `saddle_env.lifetimes.release_times` starts it).
        lab_spin = c.init_spin == "lab" and "spin_normal" not in opts
        for i, hit in zip(idx, hits):
            self.scenes[i] = hit.scene
        self.models[idx] = [hit.model_code for hit in hits]
        self.P[idx] = [hit.params for hit in hits]
        self.scales[idx] = [hit.scale for hit in hits]
        b = np.zeros((k, S.BALL_WIDTH))
        b[:, S.B_OMEGA] = omegas
        b[:, S.B_PHASE] = phases
        b[:, S.B_FX:S.B_FY + 1] = forces
        self.balls[idx] = b
        x, y, vx, vy = (np.array(v, dtype=np.float64) for v in (xs, ys, vxs, vys))
        lab_rest = np.full(k, not given_velocity and start == "lab-rest")
        spins = -b[:, S.B_OMEGA] if lab_spin else spin
        mask = np.zeros(self.n, dtype=bool)
        mask[idx] = True
        self._draw_noise(rngs, mask)
        self._place(idx, x, y, vx, vy, lab_rest, spins)
        if self.delays.active:
            self._reset_delays(idx)
        if self.obs is not self.frame:  # a new episode's history: its first frame, k times
            self.obs[idx] = np.tile(self.frame[idx], self.layout.frames)
        bad = ~np.isfinite(self.Y[idx]).all(axis=1)
        if bad.any():
            j = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"initial state is not finite for x = {x[j]:g}, y = {y[j]:g}, vx = {vx[j]:g}, "
                f"vy = {vy[j]:g} m: the position or velocity is too large for the saddle")
        normal = self.out[idx, S.O_NORMAL]
        lifted = ~(normal > 0)
        if lifted.any():
            # The ball would leave the surface at t = 0: no episode to play. The options (or
            # the level's start ranges) asked for a start the physics does not allow.
            j = int(np.flatnonzero(lifted)[0])
            i = int(idx[j])
            given = "reset options" if opts else ("the level's start options (init_offset, "
                                                  "init_speed, omega0_range)")
            raise ValueError(
                f"{given} give a start where the normal force is N/mg = {normal[j]:.3g} <= 0 "
                f"(x = {x[j]:g}, y = {y[j]:g} m, vx = {vx[j]:g}, vy = {vy[j]:g} m/s, omega = "
                f"{self.balls[i, S.B_OMEGA]:g} rad/s): the ball would leave the surface at "
                f"once; start nearer the centre, slower, or at a lower omega")

    def _draw_starts(self, idx: np.ndarray, rngs: Sequence[np.random.Generator],
                     opts: ResetOptions, given_velocity: bool,
                     spin: float) -> tuple[list, ...]:
        """Each ball's draws for a reset, from its own generator in a fixed order: its scene
        (`_draw_scene`), Ω₀, the start's position and velocity (``given_velocity``: the
        options hold it), the ripple's phase and the lab-fixed force, as lists over ``idx``;
        ``spin`` (the options' spin about the normal) is checked against each scene."""
        c = self.config
        placed = "x" in opts or "y" in opts
        two_pi = 2.0 * math.pi
        # Each ball's draws go to lists, written to the rows after the loop: a numpy item
        # write per value was a third of a reset's cost (a vector env's 1,024 balls reset
        # once an episode, 500 steps).
        hits, omegas, xs, ys, vxs, vys, phases, forces = [], [], [], [], [], [], [], []
        for i in idx:
            rng = rngs[i]
            hit = self._draw_scene(rng, opts)
            hits.append(hit)
            R = hit.scene.R
            if spin and abs(spin) * R > c.max_start_speed:
                raise ValueError(f"reset option 'spin_normal' must satisfy |spin_normal| R <= "
                                 f"{c.max_start_speed:g} m/s (|spin_normal| <= "
                                 f"{c.max_start_speed / R:g} rad/s for R = "
                                 f"{R:g} m), got {spin:g} rad/s")
            omega0 = opts["omega"] if "omega" in opts else _uniform(rng, *c.omega0_range)
            if c.speed_error > 0:   # drawn after the levels' older draws: theirs do not move
                self.speed_factor[i] = float(speed_factor(c.speed_error, rng.standard_normal()))
                omega0 *= self.speed_factor[i]
            omegas.append(omega0)
            if placed:
                xs.append(opts.get("x", 0.0))
                ys.append(opts.get("y", 0.0))
            elif c.init_spread > 0:
                px, py = rng.normal(0.0, c.init_spread, size=2)
                xs.append(px)
                ys.append(py)
            else:
                r = c.init_offset * math.sqrt(rng.random())
                phi = _uniform(rng, 0.0, two_pi)
                xs.append(r * math.cos(phi))
                ys.append(r * math.sin(phi))
            if given_velocity:
                vxs.append(opts.get("vx", 0.0))
                vys.append(opts.get("vy", 0.0))
            elif c.init_speed > 0 and not placed:
                sp = c.init_speed * math.sqrt(rng.random())
                ang = _uniform(rng, 0.0, two_pi)
                vxs.append(sp * math.cos(ang))
                vys.append(sp * math.sin(ang))
            else:
                vxs.append(0.0)
                vys.append(0.0)
            phases.append(_uniform(rng, 0.0, two_pi) if c.ripple_amp > 0 else 0.0)
            fx = fy = 0.0
            if c.air_force > 0:
                fx, fy = rng.normal(0.0, c.air_force, size=2)
            if c.tilt_direction == "random":
                # The scene leans the axis toward the laboratory's x axis (g·sin(tilt) along
                # x); the lab-fixed force turns that share of gravity to the drawn direction.
                psi = _uniform(rng, 0.0, two_pi)
                lean = hit.params[P_TILT_FORCE]
                fx, fy = lean * (math.cos(psi) - 1.0), lean * math.sin(psi)
            forces.append((fx, fy))
        return hits, omegas, xs, ys, vxs, vys, phases, forces

    def _reset_delays(self, idx: np.ndarray) -> None:
        """Empty queues for a new episode: no command given yet (a voltage-driven motor
        holds its start speed on the voltage that keeps it there) and every sample the
        starting state (what the camera shows of times before the start)."""
        c = self.config
        hold = np.nan
        for i in idx:
            if c.action_mode == "voltage":
                top = c.motor_gain * c.voltage_max
                hold = min(1.0, 2.0 * self.balls[i, S.B_OMEGA] / top - 1.0)
            self._commands[i] = hold
            self._in_force[i] = 0.0 if math.isnan(hold) else hold
            self._samples[i] = self.frame[i]

    def _draw_scene(self, rng: np.random.Generator,
                    opts: Mapping[str, object]) -> DrawnScene:
        """The ball's scene (drawn when randomised), its packed parameters, state scales and
        contact model's code.

        Scenes are cached by their changes: building and validating a Scene for every ball
        of every reset was most of the cost of a reset."""
        c = self.config
        changes: dict[str, object] = {}
        if "R" in opts:
            changes["R"] = opts["R"]
        elif c.ball_radii is not None:
            changes["R"] = c.ball_radii[rng.integers(len(c.ball_radii))]
        if "a" in opts:
            changes["a"] = opts["a"]
        elif c.a_range is not None:
            changes["a"] = _uniform(rng, *c.a_range)
        if "contact" in opts:
            changes["contact"] = opts["contact"]
        elif c.contact_models is not None:
            changes["contact"] = c.contact_models[rng.integers(len(c.contact_models))]
        if c.mu_range is not None and changes.get("contact", c.contact) == "coulomb":
            changes["mu"] = _uniform(rng, *c.mu_range)
        key = tuple(sorted(changes.items())) if changes else ()
        hit = self._scene_cache.get(key)
        if hit is None:
            scene = c.scene(**changes)
            params = scene.params()
            hit = DrawnScene(scene, params, state_scale(params, scene.model_code),
                             scene.model_code)
            if len(self._scene_cache) >= 256:  # continuous randomisation: keep it bounded
                self._scene_cache.clear()
            self._scene_cache[key] = hit
        return hit

    def _draw_noise(self, rngs: Sequence[np.random.Generator], mask: np.ndarray) -> None:
        if self._noise_scale is not None:
            for i in np.flatnonzero(mask):
                self.noise[i] = rngs[int(i)].standard_normal(self.frame_dim) * self._noise_scale

    # -- step ----------------------------------------------------------------------------
    def step(self, actions: np.ndarray, active: np.ndarray,
             rngs: Sequence[np.random.Generator]) -> None:
        """Advance the ``active`` balls by one control period.

        Per-step random draws (air current, sensor noise) come from each ball's own
        generator, so a ball's run does not depend on how many others share the batch.
        """
        call = self._serial_call
        if self._plain and call is not None and call[1] is actions and call[2] is active \
                and not self.parallel:
            # The arrays of the last step, checked then (a single env passes its own buffers):
            # straight to the compiled step.
            if call[3](*call[4]):
                self._raise_failed(active)
            return
        c = self.config
        actions = self._per_ball("actions", actions, np.float64)
        active = self._per_ball("active", active, np.bool_)
        if c.speed_error > 0:
            # The speed an action asks for, (a + 1)/2 of the top (target or voltage mode),
            # times the drive's error; the drive's top stays its limit.
            actions = np.minimum(self.speed_factor * (actions + 1.0) - 1.0, 1.0)
        if c.air_force > 0:
            kick_std = c.air_force * math.sqrt(1 - self._air_decay ** 2)
            for i in np.flatnonzero(active):
                f = self.balls[i, S.B_FX:S.B_FY + 1]
                f[:] = self._air_decay * f + rngs[int(i)].normal(0.0, kick_std, size=2)
        if self._noise_scale is not None:
            self._draw_noise(rngs, active)
        if self.delays.active:
            self._step_delayed(actions, active)
        else:
            self._run(self.cfg, actions, active)
        if self.obs is not self.frame:
            self._push_frames(active)

    def _step_delayed(self, actions: np.ndarray, active: np.ndarray) -> None:
        """One control period in the segments of `DelayPlan`: the command queue advanced,
        each segment stepped with the Ω̇ (or voltage) in force, the sample taken where it
        falls, the outputs of the segments combined into the period's (trapped fraction,
        reward), and the observation the sample of ``obs_periods`` periods before."""
        plan, c = self.delays, self.config
        cmds = self._commands
        rows = np.flatnonzero(active)
        cmds[rows, 1:] = cmds[rows, :-1]
        cmds[rows, 0] = actions[rows]
        seg_active = self._seg_active
        seg_active[:] = active
        covered = self._covered
        covered[:] = 0.0
        for (lo, hi), cfg in zip(plan.segments, self._seg_cfgs):
            if lo == plan.switch_at:  # the next command takes effect
                S.command_rates(self.cfg, self.balls, np.ascontiguousarray(
                    cmds[:, plan.act_periods]), seg_active, self._in_force)
            if seg_active.any():
                self._run(cfg, self._in_force, seg_active)
                covered[seg_active] += self.out[seg_active, S.O_TIME]
            if hi == plan.sample_at:
                samples = self._samples
                samples[rows, 1:] = samples[rows, :-1]
                samples[rows, 0] = self.frame[rows]
            # A ball lost in this segment is not stepped further this period.
            seg_active &= self.out[:, S.O_STATUS] == 0
        out = self.out[rows]
        lost = out[:, S.O_STATUS] != 0
        trapped = np.where(lost, covered[rows] / plan.period, 1.0)
        out[:, S.O_REWARD] += trapped - out[:, S.O_TRAPPED] - c.effort_cost * actions[rows] ** 2
        out[:, S.O_TRAPPED] = trapped
        out[:, S.O_TIME] = covered[rows]
        self.out[rows] = out
        self.frame[rows] = self._samples[rows, plan.obs_periods]

    def _run(self, cfg: np.ndarray, actions: np.ndarray, active: np.ndarray) -> None:
        """The compiled step of the ``active`` balls over ``cfg``'s period."""
        call = self._serial_call
        if call is not None and call[0] is cfg and call[1] is actions and call[2] is active \
                and not self.parallel:
            # The same arrays as last time (a single env's step passes its own buffers): the
            # argument tuple and the entry are kept, a third of the Python side of its step.
            if call[3](*call[4]):
                self._raise_failed(active)
            return
        args = (self.models, self.P, self.scales, self.Y, self.balls, cfg, actions, active,
                *self._record_fields, self.noise, self.frame, self.out)
        if self.parallel and threads_usable():
            chunks = self._chunks()
            if self._chunk_scratch[0].shape[0] != chunks:  # the thread count was changed
                self._chunk_scratch = self._new_scratch(chunks)
            parallel_args = (*args, *self._chunk_scratch)
            failed = self._entry("step_parallel", parallel_args)(*parallel_args)
        else:
            # Where no SIMD block can form, the entry compiled without them (less to
            # compile on a first step; the same results).
            name = "step_serial" if self._lockstep and self.n >= S.MIN_BLOCK else "step_scalar"
            serial_args = (*args, self._scratch, self._iscratch)
            fn = self._entry(name, serial_args)
            self._serial_call = (cfg, actions, active, fn, serial_args)
            failed = fn(*serial_args)
        if failed:
            self._raise_failed(active)

    def _raise_failed(self, active: np.ndarray) -> None:
        """SimulationError naming the first ball of ``active`` whose step failed."""
        bad = int(np.flatnonzero(active & (self.out[:, S.O_STATUS] < 0))[0])
        code = int(self.out[bad, S.O_STATUS])
        why = "the step limit was hit" if code == STATUS_MAX_STEPS else "the state became non-finite"
        raise SimulationError(
            f"ball {bad}: integration failed at t = {self.balls[bad, S.B_TIME]:.6f} s "
            f"({why}); scene {self.scenes[bad]}")

    def _per_ball(self, name: str, values, dtype) -> np.ndarray:
        """``values`` as a contiguous vector of ``dtype``, one per ball (what the compiled
        step reads)."""
        if (type(values) is np.ndarray and values.shape == (self.n,) and values.dtype == dtype
                and values.flags.c_contiguous):
            return values  # the usual case, at half the cost of the conversion below
        arr = np.ascontiguousarray(values, dtype=dtype)
        if arr.size != self.n:
            raise ValueError(f"{name} must hold one value per ball ({self.n}), got shape "
                             f"{arr.shape}")
        return arr.reshape(self.n)

    def _push_frames(self, active: np.ndarray) -> None:
        """Shift the stepped balls' histories by one frame and put this step's in front."""
        d = self.frame_dim
        if active.all():
            self.obs[:, d:] = self.obs[:, :-d]
            self.obs[:, :d] = self.frame
        else:
            rows = np.flatnonzero(active)
            hist = self.obs[rows]
            hist[:, d:] = hist[:, :-d]
            hist[:, :d] = self.frame[rows]
            self.obs[rows] = hist

    # -- views ---------------------------------------------------------------------------
    def cause(self, i: int | np.integer) -> str | None:
        """How ball ``i``'s episode ended ("detach", "escape"), or None while it runs."""
        return EVENT_KINDS.get(int(self.out[i, S.O_STATUS]))


def _uniform(rng: np.random.Generator, low: float, high: float) -> float:
    """``rng.uniform(low, high)`` to the last bit (numpy computes low + (high - low)·u from
    one double u, as ``rng.random()`` gives it), at a third of its cost per call."""
    return low + (high - low) * rng.random()


def contact_uses(config: EnvConfig) -> tuple[frozenset[int], bool]:
    """The contact model codes ``config`` draws its balls from, and whether any rolling
    resistance: what its compiled step is specialised for (`compilation.specialise`)."""
    return (frozenset(config.scene(contact=m).model_code
                      for m in (config.contact_models or (config.contact,))),
            config.rolling_resistance != 0.0)


def _check_options(options: Mapping[str, object] | None) -> ResetOptions:
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise ValueError(f"options must be a dict, got {type(options).__name__}")
    unknown = sorted(set(options) - set(RESET_OPTION_KEYS))
    if unknown:
        raise ValueError(f"unknown reset option(s) {unknown}; allowed: {list(RESET_OPTION_KEYS)}")
    out = dict(options)
    for key in ("x", "y", "vx", "vy", "omega", "R", "a", "spin_normal"):
        if key in out:
            v = out[key]
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(float(v)):
                raise ValueError(f"reset option {key!r} must be a finite number, got {v!r}")
            out[key] = float(v)
    if "start" in out and out["start"] not in ("lab-rest", "rotating-rest"):
        raise ValueError(f"reset option 'start' must be 'lab-rest' or 'rotating-rest', "
                         f"got {out['start']!r}")
    return cast(ResetOptions, out)  # the checks above: known keys, numbers made floats


def check_reset_start(opts: ResetOptions, c: EnvConfig) -> None:
    """ValueError for a placed start outside the rim or faster than the config's
    ``max_start_speed``."""
    if "x" in opts or "y" in opts:
        x, y = float(opts.get("x", 0.0)), float(opts.get("y", 0.0))
        if not math.hypot(x, y) < c.rim_radius:
            raise ValueError(f"reset options 'x', 'y' must place the ball inside the rim, "
                             f"sqrt(x² + y²) < rim_radius = {c.rim_radius:g} m, got "
                             f"x = {x:g}, y = {y:g} (r = {math.hypot(x, y):g} m)")
    if "vx" in opts or "vy" in opts:
        u, v = float(opts.get("vx", 0.0)), float(opts.get("vy", 0.0))
        if math.hypot(u, v) > c.max_start_speed:
            raise ValueError(f"reset options 'vx', 'vy' must give a speed sqrt(vx² + vy²) <= "
                             f"omega_max * rim_radius = {c.max_start_speed:g} m/s, got "
                             f"vx = {u:g}, vy = {v:g} m/s")


def check_reset_omega(opts: ResetOptions, omega_max: float) -> None:
    """Check the reset option ``omega`` against [0, ``omega_max``].

    Raises
    ------
    ValueError
        If it lies outside.
    """
    if "omega" in opts and not 0 <= float(opts["omega"]) <= omega_max:
        raise ValueError(f"reset option 'omega' must lie in [0, omega_max = {omega_max}], "
                         f"got {opts['omega']}")

