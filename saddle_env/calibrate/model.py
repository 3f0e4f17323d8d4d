"""The forward model of a fit: measured tracks cut into short shooting segments, each predicted
by the project's integrator (`saddle_env.prediction.predict_batch`, all segments at once).

Timing (docs/reference/tracks.md): a frame stamped ``t`` on the tracker's clock shows the ball
where it was at ``t − obs_delay`` (the environment's ``obs_delay``: the observation is the
state at t − obs_delay), while the ``omega``, ``voltage`` and ``theta`` columns are read at
``t`` itself. The saddle's drive is known on that clock:

* from ``omega`` (the tachometer): Ω(t) linear between the readings (constant before the
  first and after the last);
* from ``voltage``: held from its row's time to the next row's, the motor following
  τ Ω̇ = K V − Ω exactly (the kernels' relaxation term, ``DRIVE_DECAY``), from a speed Ω₀ at
  the track's first modelled instant (fitted per track; read against the ``omega`` column
  when there is one).

The saddle's angle θ is integrated from that Ω (`kernels.angle_at`) from θ₀ at the track's
first modelled instant (fitted per track), or, with a ``theta`` column, restarted from the
encoder at every segment's start. The ball's centre, turned by θ into the laboratory and
shifted by the axis offset (x0, y0), is what the camera measured.

Multiple shooting: each track's tracked frames are split into segments of about
``segment`` seconds. The ball's state at each segment's first frame (contact point x, y, its
velocity vx, vy on the saddle and, for rolling balls, the spin about the normal) is a free
variable; the segment is integrated from it through every frame to the next segment's
start, where the mismatch (the continuity defect) is a weighted residual. A chaotic orbit
thus never has to be followed for more than one segment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from .. import kernels as K
from ..envs.config import EnvConfig
from ..prediction import predict_batch
from ..scene import COULOMB, ROLLING, Scene
from .tracks import Track

# What may be fitted: unit, bounds, a typical size (for steps and for judging an interval),
# and whether it is an option of the environment (x0, y0 belong to the tracker).
# name: (unit, low, high, typical, env option)
PARAMETERS: dict[str, tuple[str, float, float, float, bool]] = {
    "drag_quadratic": ("1/m", 0.0, 100.0, 0.3, True),
    "drag_linear": ("1/s", 0.0, 100.0, 0.1, True),
    "rolling_resistance": ("", 0.0, 1.0, 0.01, True),
    "mu": ("", 0.0, 10.0, 0.1, True),
    "obs_delay": ("s", 0.0, 1.0, 0.02, True),
    "motor_tau": ("s", 1e-3, 10.0, 0.25, True),
    "motor_gain": ("rad/s/V", 1e-3, 100.0, 1.0, True),
    "x0": ("m", -0.1, 0.1, 1e-3, False),
    "y0": ("m", -0.1, 0.1, 1e-3, False),
}
SCENE_PARAMETERS = ("drag_quadratic", "drag_linear", "rolling_resistance", "mu")
MERGE = 1e-9          # [s] a drive's knot and a frame's instant closer than this are one point
DEFECT_WEIGHT = 10.0  # continuity defects weigh this much more than a frame's noise


@nb.njit(cache=True)
def _states(model, p, nodes, out):
    """Kernel states from node coordinates (x, y, vx, vy[, spin about the normal])."""
    for i in range(nodes.shape[0]):
        sn = nodes[i, 4] if nodes.shape[1] > 4 else 0.0
        K.state_from_velocity(model, p, nodes[i, 0], nodes[i, 1], nodes[i, 2], nodes[i, 3],
                              sn, out[i])


@nb.njit(cache=True)
def _nodes(model, p, Y, out):
    """Node coordinates of kernel states ``Y`` (padded rows, the work slot excluded)."""
    row = np.zeros(K.STATE_WIDTH)
    for i in range(Y.shape[0]):
        for j in range(K.STATE_WIDTH):
            row[j] = Y[i, j] if j < Y.shape[1] else 0.0
        out[i, 0], out[i, 1] = row[0], row[1]
        if model == COULOMB:
            out[i, 2], out[i, 3] = row[5], row[6]
        else:
            row[K.PHASE_SLOT] = K.STICK
            vx, vy = K.contact_velocity(model, p, row)
            out[i, 2], out[i, 3] = vx, vy
        if out.shape[1] > 4:
            g = K.geometry(p[0], p[1], p[2], row[0], row[1])
            out[i, 4] = row[2] * g.nx + row[3] * g.ny + row[4] * g.nz


@nb.njit(cache=True)
def _centres(p, x, y, out):
    """Horizontal position (cx, cy) of the ball's centre over contact points (x, y)."""
    for i in range(x.shape[0]):
        g = K.geometry(p[0], p[1], p[2], x[i], y[i])
        out[i, 0], out[i, 1] = g.cx, g.cy


@nb.njit(cache=True)
def _drive_chain(B, voltage, omega_at_B, kv, inv_tau, omega0, theta0, rows, omega, theta):
    """The drive rows between successive instants ``B`` and Ω, θ at each instant, through
    the kernels' own `omega_at` and `angle_at`: a linear ramp between the tachometer's values
    ``omega_at_B`` or, with ``voltage``, the motor relaxing to ``kv[l]`` = K·V."""
    omega[0], theta[0] = omega0 if voltage else omega_at_B[0], theta0
    for l in range(B.shape[0] - 1):
        T = B[l + 1] - B[l]
        row = rows[l]
        for j in range(K.DRIVE_WIDTH):
            row[j] = 0.0
        if voltage:
            row[K.DRIVE_W0] = kv[l]
            row[K.DRIVE_DECAY] = omega[l] - kv[l]
            row[K.DRIVE_DECAY_RATE] = inv_tau
        else:
            row[K.DRIVE_W0] = omega[l]
            row[K.DRIVE_RATE] = (omega_at_B[l + 1] - omega[l]) / T
        row[K.DRIVE_THETA0] = theta[l]
        omega[l + 1] = K.omega_at(row, T)[0]
        theta[l + 1] = K.angle_at(row, T)


def _finite_points(t: np.ndarray, v: np.ndarray | None) -> tuple[np.ndarray, np.ndarray] | None:
    if v is None:
        return None
    ok = np.isfinite(v)
    return (t[ok], v[ok]) if ok.any() else None


@dataclass
class TrackPlan:
    """One track's frames, drive and nodes, fixed for the whole fit."""

    track: Track
    t: np.ndarray                  # (n,) tracked frames' times [s]
    xy: np.ndarray                 # (n, 2) measured positions [m]
    nodes: np.ndarray              # (k,) indices into the tracked frames where segments start
    knot_t: np.ndarray             # drive knots [s]: tachometer readings or voltage rows
    knot_v: np.ndarray             # Ω [rad/s] or V [V] at them
    theta: tuple[np.ndarray, np.ndarray] | None   # encoder (times, unwrapped angle)
    omega_obs: tuple[np.ndarray, np.ndarray] | None  # tachometer read against a voltage drive
    free_theta0: bool
    free_omega0: bool

    @property
    def segments(self) -> int:
        """The number of shooting segments."""
        return len(self.nodes) - 1


def plan_track(track: Track, drive: str, segment: float) -> TrackPlan:
    """Split a track into shooting segments of about ``segment`` seconds (at least two frames
    each) and read its drive."""
    seen = track.tracked
    t, xy = track.t[seen], np.column_stack([track.x[seen], track.y[seen]])
    n = len(t)
    frame = float(np.median(np.diff(t)))
    per = max(2, int(round(segment / frame)))
    nodes = list(range(0, n - 1, per)) + [n - 1]
    if len(nodes) > 2 and nodes[-1] - nodes[-2] < per // 2:   # no stub of a last segment
        del nodes[-2]
    if drive == "omega":
        pts = _finite_points(track.t, track.omega)
        if pts is None:
            raise ValueError(f"{track.source}: the drive is 'omega' but the track has no "
                             f"tachometer readings (an 'omega' column with numbers)")
        knot_t, knot_v = pts
        omega_obs = None
    else:
        pts = _finite_points(track.t, track.voltage)
        if pts is None:
            raise ValueError(f"{track.source}: the drive is 'voltage' but the track has no "
                             f"'voltage' column with numbers")
        knot_t, knot_v = pts
        omega_obs = _finite_points(track.t, track.omega)
    theta = _finite_points(track.t, track.theta)
    if theta is not None:
        theta = (theta[0], np.unwrap(theta[1]))
    return TrackPlan(track, t, xy, np.array(nodes), knot_t, knot_v, theta, omega_obs,
                     free_theta0=theta is None, free_omega0=drive == "voltage")


@dataclass
class Layout:
    """Where each unknown sits in the fit's vector: the fitted parameters, then each track's
    nuisance values (θ₀, Ω₀ where free), then each segment start's state."""

    names: tuple[str, ...]         # the fitted parameters
    plans: list[TrackPlan]
    width: int                     # coordinates per node (4, or 5 with the normal spin)
    track_slots: list[dict[str, int]] = field(default_factory=list)
    node_slots: list[int] = field(default_factory=list)   # first index of each track's nodes
    size: int = 0

    def __post_init__(self) -> None:
        i = len(self.names)
        for plan in self.plans:
            slots = {}
            for key, free in (("theta0", plan.free_theta0), ("omega0", plan.free_omega0)):
                if free:
                    slots[key] = i
                    i += 1
            self.track_slots.append(slots)
        for plan in self.plans:
            self.node_slots.append(i)
            i += len(plan.nodes) * self.width
        self.size = i

    def node_block(self, v: np.ndarray, k: int) -> np.ndarray:
        """Track ``k``'s node states in the parameter vector ``v``, one row per node."""
        plan = self.plans[k]
        s = self.node_slots[k]
        return v[s:s + len(plan.nodes) * self.width].reshape(len(plan.nodes), self.width)


@dataclass
class Evaluation:
    """The residuals of one parameter vector, and per track what the plot needs."""

    residuals: np.ndarray
    predicted: list[np.ndarray]    # (n, 2) per track: the model's positions at its frames
    defects: list[np.ndarray]      # (segments, width) per track
    omega: list[np.ndarray]        # Ω [rad/s] at each tracked frame's instant
    failed: int                    # segments whose integration failed


class Model:
    """The residual function of a fit: `residuals(v)` for a vector laid out by `layout`."""

    def __init__(self, config: EnvConfig, plans: list[TrackPlan], names: tuple[str, ...],
                 drive: str, position_noise: float, omega_noise: float, rtol: float = 1e-9):
        self.config = config
        self.scene: Scene = config.scene()
        self.code = self.scene.model_code
        self.drive = drive
        self.names = names
        width = 5 if self.code in (ROLLING, COULOMB) else 4
        self.layout = Layout(names, plans, width)
        self.rtol = rtol
        self.set_noise(position_noise, omega_noise)

    def set_noise(self, position_noise: float, omega_noise: float) -> None:
        """The residuals' weights: the camera's noise [m] and the tachometer's [rad/s]. The
        defects' scales follow the camera's: a position to a tenth of its noise, a velocity to
        that over 50 ms, a spin to that velocity over the ball's radius."""
        self.sigma = position_noise
        self.sigma_omega = omega_noise
        vel = position_noise / 0.05
        scale = [position_noise, position_noise, vel, vel, vel / max(self.scene.radius, 1e-3)]
        self.defect_scale = np.array(scale[:self.layout.width]) / DEFECT_WEIGHT

    # ---------------------------------------------------------------- parameters
    def values(self, v: np.ndarray) -> dict[str, float]:
        """Every model parameter (fitted or fixed) at the vector ``v``."""
        out = self.defaults()
        for i, name in enumerate(self.names):
            out[name] = float(v[i])
        return out

    def defaults(self) -> dict[str, float]:
        """Every model parameter at the configuration's value (the axis offset at 0)."""
        c = self.config
        out = {"obs_delay": c.obs_delay, "motor_tau": c.motor_tau, "motor_gain": c.motor_gain,
               "x0": 0.0, "y0": 0.0}
        for name in SCENE_PARAMETERS:
            out[name] = float(getattr(self.scene, name) or 0.0)
        return out

    def scene_at(self, values: dict[str, float]) -> Scene:
        """The scene with the fitted parameters set to ``values``."""
        changes = {n: values[n] for n in SCENE_PARAMETERS if n in self.names}
        if "mu" in changes and self.scene.mu_static is not None:
            changes["mu_static"] = max(self.scene.mu_static, changes["mu"])
        return self.scene.with_(**changes) if changes else self.scene

    # ---------------------------------------------------------------- the drive
    def timeline(self, plan: TrackPlan, values: dict[str, float], theta0: float,
                 omega0: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                         np.ndarray]:
        """The instants a track's model passes through (frames' instants t − obs_delay and the
        drive's knots, sorted, near-duplicates merged), the index of each frame's instant
        and of each knot among them, the drive rows between them and Ω, θ at each."""
        tau = plan.t - values["obs_delay"]
        # knots up to the last frame's time (Ω is read against the tachometer there)
        knots = plan.knot_t[(plan.knot_t > tau[0]) & (plan.knot_t <= plan.t[-1])]
        allt = np.concatenate([tau, knots])
        order = np.argsort(allt, kind="stable")
        srt = allt[order]
        new = np.concatenate([[True], np.diff(srt) > MERGE])
        B = srt[new]
        index = np.empty(len(allt), dtype=np.int64)
        index[order] = np.cumsum(new) - 1
        frames, knot_index = index[:len(tau)], index[len(tau):]
        L = len(B)
        rows = np.zeros((max(L - 1, 0), K.DRIVE_WIDTH))
        omega, theta = np.empty(L), np.empty(L)
        voltage = self.drive == "voltage"
        if voltage:
            # the voltage written at a knot holds until the next (before the first: the first)
            j = np.clip(np.searchsorted(plan.knot_t, B[:-1] + MERGE, side="right") - 1, 0, None)
            kv = values["motor_gain"] * plan.knot_v[j]
            w_at = np.zeros(L)
        else:
            kv = np.zeros(max(L - 1, 0))
            w_at = np.interp(B, plan.knot_t, plan.knot_v)
        _drive_chain(B, voltage, w_at, kv, 1.0 / values["motor_tau"], omega0, theta0, rows,
                     omega, theta)
        if plan.theta is not None:
            # the encoder's angle between its readings; before the first (a frame's instant
            # is obs_delay earlier than its stamp) and after the last, carried by Ω
            c = np.clip(B, plan.theta[0][0], plan.theta[0][-1])
            theta = theta + (np.interp(c, *plan.theta) - np.interp(c, B, theta))
        return B, frames, knot_index, rows, np.stack([omega, theta])

    # ---------------------------------------------------------------- residuals
    def evaluate(self, v: np.ndarray) -> Evaluation:
        """Simulate every segment from the parameter vector ``v``: residuals and what made them."""
        values = self.values(v)
        scene = self.scene_at(values)
        p = scene.params()
        lay = self.layout
        runs_Y, runs_drive, runs_dur, where = [], [], [], []
        per_track = []
        for k, plan in enumerate(lay.plans):
            slots = lay.track_slots[k]
            theta0 = v[slots["theta0"]] if "theta0" in slots else 0.0
            omega0 = v[slots["omega0"]] if "omega0" in slots else 0.0
            B, frames, knots, rows, wt = self.timeline(plan, values, float(theta0), float(omega0))
            nodes = lay.node_block(v, k)
            Y = np.zeros((len(nodes), K.STATE_WIDTH))
            _states(self.code, p, np.ascontiguousarray(nodes), Y)
            b = frames[plan.nodes]
            for s in range(plan.segments):
                lo, hi = b[s], b[s + 1]
                drv = rows[lo:hi].copy()
                drv[0, K.DRIVE_THETA0] = wt[1, lo]
                runs_Y.append(Y[s])
                runs_drive.append(drv)
                runs_dur.append(np.diff(B[lo:hi + 1]))
                where.append((k, s, lo, hi))
            per_track.append((B, frames, knots, wt, Y, b))
        S = max(len(d) for d in runs_dur)
        n = len(runs_dur)
        drives = np.zeros((n, S, K.DRIVE_WIDTH))
        durations = np.zeros((n, S))
        for r in range(n):
            m = len(runs_dur[r])
            drives[r, :m], durations[r, :m] = runs_drive[r], runs_dur[r]
        pred = predict_batch(self.code, np.tile(p, (n, 1)), np.array(runs_Y), drives,
                             durations, 1e9, rtol=self.rtol, events=())
        ends = pred.state[:, :, 0, :]            # (n, S, width): each piece's end
        failed = int(np.count_nonzero(pred.status < 0))
        res: list[np.ndarray] = []
        predicted, defects, omegas = [], [], []
        r = 0
        for k, plan in enumerate(lay.plans):
            B, frames, knots, wt, Y, b = per_track[k]
            nodes = lay.node_block(v, k)
            # contact point at every instant of the track: nodes at segment starts, the
            # integration's piece ends in between
            q = np.full((len(B), 2), np.nan)
            seg_end = np.zeros((plan.segments, K.STATE_WIDTH))
            for s in range(plan.segments):
                lo, hi = b[s], b[s + 1]
                q[lo] = nodes[s, :2]
                q[lo + 1:hi + 1] = ends[r, :hi - lo, :2]
                seg_end[s, :ends.shape[2]] = ends[r, hi - lo - 1]
                r += 1
            q[b[-1]] = nodes[-1, :2]
            xyq = np.ascontiguousarray(q[frames])
            bad = ~np.isfinite(xyq).all(axis=1)
            xyq[bad] = 0.0
            c = np.empty_like(xyq)
            _centres(p, np.ascontiguousarray(xyq[:, 0]), np.ascontiguousarray(xyq[:, 1]), c)
            th = wt[1, frames]
            ct, st = np.cos(th), np.sin(th)
            lab = np.column_stack([ct * c[:, 0] - st * c[:, 1] + values["x0"],
                                   st * c[:, 0] + ct * c[:, 1] + values["y0"]])
            lab[bad] = np.nan
            predicted.append(lab)
            res.append(((lab - plan.xy) / self.sigma).ravel())
            got = np.zeros((plan.segments, lay.width))
            _nodes(self.code, p, seg_end, got)
            d = (got - nodes[1:]) / self.defect_scale
            defects.append(d)
            res.append(d.ravel())
            omegas.append(wt[0, frames])
            if plan.omega_obs is not None:
                w = np.interp(plan.omega_obs[0], B[knots], wt[0, knots]) if len(knots) else \
                    np.full(len(plan.omega_obs[0]), wt[0, 0])
                res.append((w - plan.omega_obs[1]) / self.sigma_omega)
        out = np.concatenate(res)
        bad = ~np.isfinite(out)
        if bad.any():  # a failed segment: a large residual the optimiser steps away from
            out[bad] = 1e6
        return Evaluation(out, predicted, defects, omegas, failed)

    def residuals(self, v: np.ndarray) -> np.ndarray:
        """The weighted residuals at the parameter vector ``v``."""
        return self.evaluate(v).residuals

    # ---------------------------------------------------------------- structure
    def column_groups(self) -> list[np.ndarray]:
        """Columns whose residuals never overlap, perturbed together in a finite-difference
        Jacobian: each fitted parameter alone; each track's θ₀ (and Ω₀) together across
        tracks; node coordinates of every other segment start together."""
        lay = self.layout
        groups = [np.array([i]) for i in range(len(self.names))]
        for key in ("theta0", "omega0"):
            cols = [s[key] for s in lay.track_slots if key in s]
            if cols:
                groups.append(np.array(cols))
        for parity in range(2):   # node s touches defects s-1 and s: two apart never meet
            for j in range(lay.width):
                cols = [lay.node_slots[k] + s * lay.width + j
                        for k, plan in enumerate(lay.plans)
                        for s in range(parity, len(plan.nodes), 2)]
                if cols:
                    groups.append(np.array(cols))
        return groups

    def row_kinds(self) -> np.ndarray:
        """Each residual's kind: 0 a frame's position, 1 a continuity defect, 2 a
        tachometer reading."""
        kinds = []
        for plan in self.layout.plans:
            kinds.append(np.zeros(2 * len(plan.t), dtype=np.int8))
            kinds.append(np.ones(plan.segments * self.layout.width, dtype=np.int8))
            if plan.omega_obs is not None:
                kinds.append(np.full(len(plan.omega_obs[0]), 2, dtype=np.int8))
        return np.concatenate(kinds)

    def measurement_rows(self) -> np.ndarray:
        """True at the residuals that are measurements (frames, tachometer), False at the
        continuity defects."""
        flags = []
        for plan in self.layout.plans:
            flags.append(np.ones(2 * len(plan.t), dtype=bool))
            flags.append(np.zeros(plan.segments * self.layout.width, dtype=bool))
            if plan.omega_obs is not None:
                flags.append(np.ones(len(plan.omega_obs[0]), dtype=bool))
        return np.concatenate(flags)

    def rows_of(self, column: int) -> np.ndarray:
        """The residuals an unknown of a track (θ₀, Ω₀ or a node's coordinate) can change."""
        lay = self.layout
        start = 0
        for k, plan in enumerate(lay.plans):
            n_pos = 2 * len(plan.t)
            n_def = plan.segments * lay.width
            n_w = len(plan.omega_obs[0]) if plan.omega_obs is not None else 0
            first = lay.node_slots[k]
            if column in lay.track_slots[k].values():
                return np.arange(start, start + n_pos + n_def + n_w)
            if first <= column < first + len(plan.nodes) * lay.width:
                s = (column - first) // lay.width
                f_lo = plan.nodes[s]
                f_hi = plan.nodes[s + 1] if s < plan.segments else plan.nodes[s] + 1
                rows = [np.arange(start + 2 * f_lo, start + 2 * f_hi)]
                d0 = start + n_pos
                for seg in (s - 1, s):
                    if 0 <= seg < plan.segments:
                        rows.append(np.arange(d0 + seg * lay.width, d0 + (seg + 1) * lay.width))
                return np.concatenate(rows)
            start += n_pos + n_def + n_w
        raise ValueError(f"unknown {column} is not a track's")

    def track_rows(self) -> list[np.ndarray]:
        """Each track's position residuals' indices."""
        out, i = [], 0
        for plan in self.layout.plans:
            out.append(np.arange(i, i + 2 * len(plan.t)))
            i += 2 * len(plan.t) + plan.segments * self.layout.width
            if plan.omega_obs is not None:
                i += len(plan.omega_obs[0])
        return out


def contact_from_centre(scene: Scene, cx: np.ndarray, cy: np.ndarray) -> np.ndarray:
    """Contact points (n, 2) under ball centres seen from above (fixed-point iteration on
    c = q + R n(q), converged to rounding in a few steps for a ball on the saddle)."""
    p = scene.params()
    q = np.column_stack([cx, cy]).astype(float)
    c = np.empty_like(q)
    for _ in range(20):
        _centres(p, np.ascontiguousarray(q[:, 0]), np.ascontiguousarray(q[:, 1]), c)
        step = np.column_stack([cx, cy]) - c
        q += step
        if np.max(np.abs(step), initial=0.0) < 1e-12:
            break
    return q


def wrap(angle: float) -> float:
    """``angle`` wrapped into [-π, π)."""
    return float((angle + math.pi) % (2 * math.pi) - math.pi)
