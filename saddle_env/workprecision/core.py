"""Work-precision measurements: wall time per simulated second against position error.

Every measurement is one row (a dict with the columns of `COLUMNS`); `saddle-bench`
appends rows to a CSV as they complete, and the figures and the summary are made from the
CSV alone (`saddle_env.workprecision.report`), so a finished run can be re-plotted and checked
without re-running it.

Error definitions (the issue's):

* ``error_m`` — numerical error: the maximum over the output grid of the distance between
  the ball centre's horizontal position (rotating frame) and that of a DOP853 solve of the
  *same* model at rtol = atol = 1e-12 (`REFERENCE_RTOL`);
* ``model_error_m`` — the same distance measured against the *rolling* reference: the
  total error of a cheaper tier (slipping, mass point, linearised) used in place of the
  rolling model. (The coulomb tier is no cheaper model: it is a ball that sticks and slips,
  so its run time per simulated second is what friction costs.)
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from functools import partial
from typing import Literal, TypeVar, cast

import numpy as np

from .. import kernels as K
from ..accuracy import IntegratorKwargs
from ..integrators import STATUS_DONE
from ..linear import abcd, linear_trajectory
from ..runner import Start, Trajectory
from ..scene import P_A, P_B, P_R, Scene
from ..simulate import initial_state, simulate, simulate_batch
from .peer import PeerModel
from .peers import BY_KEY, Solver, build, missing

REFERENCE_RTOL = 1e-12
# The simulator's batch rows are timed with shared steps (`simulate_batch(...,
# shared_steps=True)`, its fastest batch); each ball stepping alone is timed beside it.
BATCH_SHARED = True
# A contact model (`Scene.contact`) or the linearised rolling model.
Tier = Literal["rolling", "slipping", "point", "coulomb", "linear"]
TIERS: tuple[Tier, ...] = ("rolling", "slipping", "point", "coulomb", "linear")
# The exact models, each measured against its own reference solve (the linearised tier
# against the rolling one).
MODEL_TIERS = TIERS[:-1]
T = TypeVar("T")

COLUMNS = (
    # what was run
    "tier", "solver", "method", "kind", "rtol", "dt", "max_step", "label",
    # the case (enough to re-run the row)
    "a", "R", "omega", "x0", "y0", "start", "t_end", "dt_out",
    # single ball
    "wall_s", "repeats", "us_per_sim_s", "steps", "rhs_evals", "status",
    "error_m", "model_error_m",
    # a coulomb ball: its changes between sticking and slipping, and the share of the run
    # it slips (what its cost per simulated second depends on)
    "phase_changes", "slipping_share",
    # batch
    "batch_n", "batch_t_end", "batch_wall_s", "batch_threads", "batch_us_per_ball_sim_s",
    "batch_ball_steps_per_s", "batch_alone_us_per_ball_sim_s",
    # the compiled peers (saddle_env.workprecision.peers): which, how its right-hand side is
    # compiled, and the compile (JIT) time its first call took, excluded from the timings
    "peer", "rhs", "compile_s", "batch_compile_s",
)


@dataclass(frozen=True)
class Case:
    """The benchmark scene: the paper's saddle, a 2 cm solid ball, constant Ω, a release
    that every contact model keeps on the saddle for the whole run."""

    a: float = 0.159
    R: float = 0.02
    omega: float = 20.0          # [rad/s], Ω_crt = 12.8 (rolling/slipping), 11.1 (point)
    x0: float = 0.005            # contact point at release [m]
    y0: float = 0.0025
    start: Start = "lab-rest"
    t_end: float = 10.0          # [s]
    dt_out: float = 0.1          # error sampled (and outputs landed on) every dt_out [s]
    batch_n: int = 1024
    batch_t_end: float = 2.0     # batch runs are shorter; cost is per simulated second
    # The coulomb tier's friction: this release then sticks and slips, 82 changes of phase
    # in 10 s (slipping 27 % of the time), and stays on the saddle.
    mu: float = 0.022

    def scene(self, tier: Tier) -> Scene:
        """The case's scene for the contact ``tier`` ("linear" runs the rolling scene)."""
        contact = "rolling" if tier == "linear" else tier
        if contact == "coulomb":
            return Scene(a=self.a, R=self.R, contact=contact, rim_radius=0.1, mu=self.mu)
        return Scene(a=self.a, R=self.R, contact=contact, rim_radius=0.1)

    def state(self, tier: Tier, x0: float | None = None, y0: float | None = None) -> np.ndarray:
        """The initial state for ``tier``, released at (``x0``, ``y0``) or the case's own point."""
        return initial_state(self.scene(tier), self.x0 if x0 is None else x0,
                             self.y0 if y0 is None else y0, start=self.start, omega=self.omega)

    def grid(self) -> np.ndarray:
        """The output times, every ``dt_out`` from 0 to ``t_end``."""
        n = int(round(self.t_end / self.dt_out))
        return np.arange(n + 1) * self.dt_out

    def columns(self) -> dict[str, object]:
        """The case's parameters as the results table's columns."""
        return {k: v for k, v in asdict(self).items()
                if k in ("a", "R", "omega", "x0", "y0", "start", "t_end", "dt_out")}


@dataclass(frozen=True)
class Config:
    """One solver setting: ours (`simulate`) or the scipy peer (`solve_ivp`)."""

    solver: str            # "saddle_env" or "scipy"
    method: str            # dop853 / dopri5 / rk4, or scipy's DOP853 / RK45; "expm" (linear)
    rtol: float = math.nan
    dt: float = math.nan   # fixed step [s]
    max_step: float = math.nan  # nan: the simulator's default cap
    peer: str = ""         # a compiled peer's key (saddle_env.workprecision.peers.BY_KEY)

    @property
    def kind(self) -> str:
        """"exact" (expm), "fixed" (a fixed step) or "adaptive"."""
        if self.method == "expm":
            return "exact"
        return "fixed" if math.isfinite(self.dt) else "adaptive"

    @property
    def label(self) -> str:
        """The setting's name in the tables and figures."""
        if self.method == "expm":
            return "linearised (expm)"
        if self.peer:
            return BY_KEY[self.peer].label
        if self.solver == "scipy":
            base = f"scipy {self.method}"
            return base + (" default tol" if self.method == "RK45" and self.rtol == 1e-3 else "")
        if self.kind == "fixed":
            return f"{self.method} fixed dt"
        return f"{self.method} rtol" + ("" if math.isnan(self.max_step) else " (uncapped)")


def _decades(hi: int, lo: int, step: int = 1) -> list[float]:
    return [10.0 ** -k for k in range(hi, lo + 1, step)]


def our_configs(quick: bool) -> list[Config]:
    """The sweep of the compiled integrators."""
    if quick:
        return ([Config("saddle_env", "dop853", rtol=r) for r in (1e-6, 1e-10)]
                + [Config("saddle_env", "dop853", rtol=r, max_step=100.0) for r in (1e-6, 1e-10)]
                + [Config("saddle_env", "rk4", dt=d) for d in (0.01, 0.001)])
    out = [Config("saddle_env", "dop853", rtol=r) for r in _decades(4, 13)]
    out += [Config("saddle_env", "dop853", rtol=r, max_step=100.0) for r in _decades(4, 13)]
    out += [Config("saddle_env", "dopri5", rtol=r) for r in _decades(4, 12)]
    out += [Config("saddle_env", "dopri5", rtol=r, max_step=100.0) for r in _decades(4, 12)]
    out += [Config("saddle_env", "rk4", dt=d) for d in (0.02, 0.01, 0.005, 0.002, 0.001, 5e-4,
                                                          2e-4, 1e-4)]
    out += [Config("saddle_env", "dop853", dt=d) for d in (0.04, 0.02, 0.01, 0.005, 0.0025)]
    return out


def compiled_peer_configs(quick: bool, keys: tuple[str, ...]) -> list[Config]:
    """The sweep of each compiled peer named in ``keys`` (and installed): the same rtol
    decades as our adaptive integrators, atol = rtol × the state scales."""
    rtols = (1e-6, 1e-10) if quick else _decades(4, 13)
    out = []
    for key in keys:
        if key in BY_KEY and missing(BY_KEY[key]) is None:
            peer = BY_KEY[key]
            out += [Config(peer.solver, peer.method, rtol=r, peer=key) for r in rtols]
    return out


def peer_configs(quick: bool) -> list[Config]:
    """scipy ``solve_ivp`` on the plain-numpy peer: RK45 at its defaults, DOP853 matched."""
    rk45 = Config("scipy", "RK45", rtol=1e-3)
    if quick:
        return [rk45, Config("scipy", "DOP853", rtol=1e-6), Config("scipy", "DOP853", rtol=1e-10)]
    return [rk45] + [Config("scipy", "DOP853", rtol=r) for r in _decades(4, 12)]


# ----------------------------------------------------------------------------------------
# Measurements
# ----------------------------------------------------------------------------------------
def _timed(fn: Callable[[], T], budget: float = 0.3, max_repeats: int = 7
           ) -> tuple[T, float, int]:
    """Run ``fn`` (at least once, more while the total stays under ``budget`` seconds) and
    return its result and the minimum wall time."""
    best = math.inf
    out = None
    total = 0.0
    n = 0
    while n < max_repeats and (n == 0 or total + best < budget):
        t0 = time.perf_counter()
        out = fn()
        dt = time.perf_counter() - t0
        best = min(best, dt)
        total += dt
        n += 1
    return cast(T, out), best, n  # fn ran: the loop's first pass always does


def centre_xy(scene: Scene, states: np.ndarray) -> np.ndarray:
    """Horizontal ball-centre position (n, 2) [m] for states (n, state_size)."""
    p = scene.params()
    out = np.empty((len(states), 2))
    for i, row in enumerate(states):
        geo = K.geometry(p[P_A], p[P_B], p[P_R], row[0], row[1])
        out[i] = geo.cx, geo.cy
    return out


def max_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance between matching rows; inf if a run stopped early."""
    if a.shape != b.shape:
        return math.inf
    return float(np.max(np.hypot(*(a - b).T)))


class SimKwargs(IntegratorKwargs, total=False):
    """`simulate`'s keywords for a row: the case's speed and output spacing, and the setting."""

    omega: float
    dt_out: float


def _sim_kwargs(case: Case, cfg: Config) -> SimKwargs:
    kw: SimKwargs = {"omega": case.omega, "dt_out": case.dt_out, "method": cfg.method}
    if cfg.kind == "fixed":
        kw["dt"] = cfg.dt
    else:
        kw["rtol"] = cfg.rtol
    if math.isfinite(cfg.max_step):
        kw["max_step"] = cfg.max_step
    return kw


def reference(case: Case, tier: Tier) -> np.ndarray:
    """Centre positions (n, 2) of the model's DOP853 solve at rtol = atol = 1e-12."""
    sc = case.scene(tier)
    tr = simulate(sc, case.state(tier), case.t_end, omega=case.omega, dt_out=case.dt_out,
                  method="dop853", rtol=REFERENCE_RTOL)
    if tr.event is not None:
        raise RuntimeError(f"benchmark case: the {tier} reference stops early ({tr.event})")
    return centre_xy(sc, tr.state)


def _row(case: Case, tier: Tier, cfg: Config, **values: object) -> dict[str, object]:
    row: dict[str, object] = {c: "" for c in COLUMNS}
    row.update(tier=tier, solver=cfg.solver, method=cfg.method, kind=cfg.kind, rtol=cfg.rtol,
               dt=cfg.dt, max_step=cfg.max_step, label=cfg.label, **case.columns())
    row.update(values)
    return row


def batch_states(case: Case, tier: Tier, n: int) -> np.ndarray:
    """n releases spread ±20 % around the case's (deterministic)."""
    rng = np.random.default_rng(12345)
    f = 1.0 + 0.2 * (2.0 * rng.random((n, 2)) - 1.0)
    return np.array([case.state(tier, case.x0 * fx, case.y0 * fy) for fx, fy in f])


def measure_ours(case: Case, tier: Tier, cfg: Config, refs: dict[str, np.ndarray],
                 batch: bool) -> dict[str, object]:
    """Time `saddle_env.simulate` (or the batch) on one case and setting; its error against ``refs``."""
    sc = case.scene(tier)
    s0 = case.state(tier)
    kw = _sim_kwargs(case, cfg)
    tr, wall, reps = _timed(lambda: simulate(sc, s0, case.t_end, **kw))
    xy = centre_xy(sc, tr.state)
    status = "ok" if tr.event is None else tr.event.kind
    if status == "ok" and max_distance(xy, refs[tier]) == 0.0:
        status = "reference"  # the same steps as the reference solve: no error measured
    row = _row(case, tier, cfg, wall_s=wall, repeats=reps, us_per_sim_s=wall / case.t_end * 1e6,
               steps=tr.stats.steps, rhs_evals=tr.stats.rhs_evaluations, status=status,
               error_m=max_distance(xy, refs[tier]), model_error_m=max_distance(xy, refs["rolling"]))
    if tr.phase is not None:
        row.update(phase_changes=tr.transitions_total, slipping_share=slipping_share(tr))
    if batch:
        row.update(measure_batch(case, tier, kw))
    return row


def slipping_share(tr: Trajectory) -> float:
    """The share of a coulomb ball's run that it slips, from its located changes of phase."""
    if tr.phase is None:
        raise ValueError("slipping_share: not a coulomb ball's run (it has no phase)")
    slipping = bool(tr.phase[0] == K.SLIP)
    since, slipped = float(tr.t[0]), 0.0
    for change in tr.transitions:
        if slipping:
            slipped += change.t - since
        slipping, since = change.phase == "slip", change.t
    if slipping:
        slipped += float(tr.t[-1]) - since
    return slipped / (float(tr.t[-1]) - float(tr.t[0]))


def measure_batch(case: Case, tier: Tier, kw: SimKwargs) -> dict[str, object]:
    """Time `saddle_env.simulate_batch` on the case's batch of releases: with shared steps
    (`saddle_env.blockstep`, the simulator's fastest batch, in the ``batch_*`` columns) and
    with each ball stepping alone (``batch_alone_us_per_ball_sim_s``)."""
    import numba

    sc = case.scene(tier)
    states = batch_states(case, tier, case.batch_n)
    res, wall, _ = _timed(lambda: simulate_batch(sc, states, case.batch_t_end,
                                                 shared_steps=BATCH_SHARED, **kw),
                          budget=1.0, max_repeats=3)
    _, alone, _ = _timed(lambda: simulate_batch(sc, states, case.batch_t_end, **kw),
                         budget=1.0, max_repeats=3)
    steps = int(res.stats[:, 0].sum())
    ok = int(np.sum(res.status == STATUS_DONE))
    per_ball = case.batch_n * case.batch_t_end
    return {"batch_n": case.batch_n, "batch_t_end": case.batch_t_end, "batch_wall_s": wall,
            "batch_threads": numba.get_num_threads(),
            "batch_us_per_ball_sim_s": wall / per_ball * 1e6,
            "batch_ball_steps_per_s": steps / wall if ok == case.batch_n else math.nan,
            "batch_alone_us_per_ball_sim_s": alone / per_ball * 1e6}


def measure_peer(case: Case, tier: Tier, cfg: Config, refs: dict[str, np.ndarray]
                 ) -> dict[str, object]:
    """scipy ``solve_ivp`` on the plain-numpy peer. RK45 runs at scipy's own defaults
    (rtol 1e-3, atol 1e-6 absolute); DOP853 at atol = rtol × the simulator's state scales,
    i.e. the same error test as the compiled integrators."""
    from scipy.integrate import solve_ivp

    from ..integrators import state_scale

    sc = case.scene(tier)
    s0 = case.state(tier)
    model = PeerModel.from_scene(sc, (case.omega,))
    grid = case.grid()
    if cfg.method == "RK45" and cfg.rtol == 1e-3:
        atol: object = 1e-6
    else:
        atol = cfg.rtol * state_scale(sc.params(), sc.model_code)[: sc.state_size]
    sol, wall, reps = _timed(lambda: solve_ivp(model.fun(), (0.0, case.t_end), s0,
                                               method=cfg.method, rtol=cfg.rtol, atol=atol,
                                               t_eval=grid), budget=1.0, max_repeats=3)
    status = "ok" if sol.status == 0 else f"failed: {sol.message}"
    xy = centre_xy(sc, sol.y.T) if sol.status == 0 else np.empty((0, 2))
    return _row(case, tier, cfg, wall_s=wall, repeats=reps, us_per_sim_s=wall / case.t_end * 1e6,
                steps="", rhs_evals=sol.nfev, status=status,
                error_m=max_distance(xy, refs[tier]), model_error_m=max_distance(xy, refs["rolling"]))


# Projected batch cost above which a peer's batch row is not run [s]: the slowest peers at
# their tightest tolerances would otherwise hold the benchmark for minutes per row.
PEER_BATCH_BUDGET_S = 60.0


class PeerCache:
    """Each compiled peer's solver, built once per contact tier, and the compile time its
    first call (single ball, batch) took: excluded from the timed runs, reported apart."""

    def __init__(self) -> None:
        self.solvers: dict[tuple[str, str], Solver] = {}
        self.compile_s: dict[tuple[str, str, str], float] = {}

    def solver(self, case: Case, tier: Tier, key: str) -> Solver:
        """The peer's solver for the case's ``tier``."""
        if (key, tier) not in self.solvers:
            self.solvers[(key, tier)] = build(BY_KEY[key], case.scene(tier), case.omega)
        return self.solvers[(key, tier)]

    def first_call(self, key: str, tier: str, form: str, fn: Callable[[], object]) -> float:
        """The compile time of ``fn`` (a peer's ``form`` of call: single or batch): its first
        call's time less its second's. Measured once; 0 on later calls."""
        if (key, tier, form) in self.compile_s:
            return 0.0
        t0 = time.perf_counter()
        fn()
        t1 = time.perf_counter()
        fn()
        self.compile_s[(key, tier, form)] = max((t1 - t0) - (time.perf_counter() - t1), 0.0)
        return self.compile_s[(key, tier, form)]


def measure_compiled_peer(case: Case, tier: Tier, cfg: Config, refs: dict[str, np.ndarray],
                          cache: PeerCache, batch: bool) -> dict[str, object]:
    """Time a compiled peer on one ball (and on the case's batch if the peer has a batch
    form); its error against ``refs`` as for ours. The first row of each peer, tier and form
    carries the compile time (`PeerCache.first_call`) in ``compile_s``/``batch_compile_s``."""
    peer = BY_KEY[cfg.peer]
    sc = case.scene(tier)
    s0 = case.state(tier)
    grid = case.grid()
    solver = cache.solver(case, tier, cfg.peer)
    try:
        compile_s = cache.first_call(cfg.peer, tier, "single",
                                     lambda: solver.single(s0, grid, cfg.rtol))
        (states, nfev), wall, reps = _timed(lambda: solver.single(s0, grid, cfg.rtol))
        status = "ok"
        xy = centre_xy(sc, states)
    except RuntimeError as exc:
        wall, reps, nfev, status, xy = math.nan, 0, math.nan, f"failed: {exc}", np.empty((0, 2))
        compile_s = math.nan
    row = _row(case, tier, cfg, wall_s=wall, repeats=reps, us_per_sim_s=wall / case.t_end * 1e6,
               steps="", rhs_evals="" if math.isnan(nfev) else nfev, status=status,
               error_m=max_distance(xy, refs[tier]), model_error_m=max_distance(xy, refs["rolling"]),
               peer=cfg.peer, rhs=peer.rhs, compile_s=compile_s or "")
    projected = wall / case.t_end * case.batch_t_end * case.batch_n
    if batch and peer.batch and status == "ok" and projected < PEER_BATCH_BUDGET_S:
        row.update(measure_peer_batch(case, tier, cfg, solver, cache))
    return row


def measure_peer_batch(case: Case, tier: Tier, cfg: Config, solver: Solver, cache: PeerCache
                       ) -> dict[str, object]:
    """Time the peer's batch form on the case's batch of releases (as `measure_batch`)."""
    import numba

    states = batch_states(case, tier, case.batch_n)
    n_out = int(round(case.batch_t_end / case.dt_out))
    grid = np.arange(n_out + 1) * case.dt_out
    compile_s = cache.first_call(cfg.peer, tier, "batch",
                                 lambda: solver.batch(states, grid, cfg.rtol))
    _, wall, _ = _timed(lambda: solver.batch(states, grid, cfg.rtol), budget=1.0, max_repeats=3)
    # numbalsoda's batch is a prange loop on numba's threads; XLA runs diffrax's vmap on
    # the threads it starts, one per core.
    threads = numba.get_num_threads() if cfg.solver == "numbalsoda" else os.cpu_count()
    return {"batch_n": case.batch_n, "batch_t_end": case.batch_t_end, "batch_wall_s": wall,
            "batch_threads": threads,
            "batch_us_per_ball_sim_s": wall / (case.batch_n * case.batch_t_end) * 1e6,
            "batch_compile_s": compile_s or ""}


def linear_centre_state(case: Case) -> np.ndarray:
    """(x_c, y_c, ẋ_c, ẏ_c) of the rolling ball's release, from the exact model."""
    sc = case.scene("rolling")
    y = np.zeros(K.STATE_WIDTH)
    y[: sc.state_size] = case.state("rolling")
    p = sc.params()
    geo = K.geometry(p[P_A], p[P_B], p[P_R], y[0], y[1])
    vx, vy = K.contact_velocity(sc.model_code, p, y)
    return np.array([geo.cx, geo.cy, geo.J1x * vx + geo.J2x * vy, geo.J1y * vx + geo.J2y * vy])


def measure_linear(case: Case, refs: dict[str, np.ndarray], batch: bool) -> dict[str, object]:
    """The cheapest tier: the linearised rolling model, solved exactly (matrix exponential)."""
    sc = case.scene("rolling")
    z0 = linear_centre_state(case)
    grid = case.grid()
    out, wall, reps = _timed(lambda: linear_trajectory(sc, case.omega, z0, grid))
    xy = out[:, :2]
    cfg = Config("saddle_env", "expm")
    row = _row(case, "linear", cfg, wall_s=wall, repeats=reps,
               us_per_sim_s=wall / case.t_end * 1e6, steps=len(grid) - 1, rhs_evals=0,
               status="ok", error_m=0.0, model_error_m=max_distance(xy, refs["rolling"]))
    if batch:
        from scipy.linalg import expm

        n = case.batch_n
        Z0 = np.tile(z0, (n, 1)).T * (1.0 + 0.2 * np.random.default_rng(1).random((4, n)))
        steps = int(round(case.batch_t_end / case.dt_out))

        def run() -> np.ndarray:
            E = expm(abcd(sc, case.omega).matrix() * case.dt_out)
            Z = Z0.copy()
            out = np.empty((steps + 1, 4, n))
            out[0] = Z
            for i in range(steps):
                Z = E @ Z
                out[i + 1] = Z
            return out

        _, bwall, _ = _timed(run, budget=1.0, max_repeats=5)
        row.update(batch_n=n, batch_t_end=case.batch_t_end, batch_wall_s=bwall, batch_threads=1,
                   batch_us_per_ball_sim_s=bwall / (n * case.batch_t_end) * 1e6,
                   batch_ball_steps_per_s=n * steps / bwall)
    return row


def warm_up(case: Case) -> None:
    """Compile (or load from the cache) every kernel the benchmark times."""
    for tier in ("rolling", "slipping", "coulomb"):
        sc = case.scene(tier)
        s0 = case.state(tier)
        for m in ("dop853", "dopri5", "rk4"):
            dt = 0.01 if m == "rk4" else None
            simulate(sc, s0, 0.05, omega=case.omega, method=m, dt=dt)
            for shared in (False, True):
                simulate_batch(sc, s0[None, :], 0.05, omega=case.omega, method=m, dt=dt,
                               shared_steps=shared)


def tasks(case: Case, quick: bool, tiers: tuple[Tier, ...] = TIERS,
          peers: bool | tuple[str, ...] = True, batch: bool = True,
          cache: PeerCache | None = None
          ) -> Iterator[tuple[str, Callable[[dict[str, np.ndarray]], dict]]]:
    """(description, measurement) pairs, cheapest first within each tier. ``peers``: True
    for every peer, False for none, or the keys of those to run ("plain" is scipy on the
    plain-numpy `PeerModel`; the others are `saddle_env.workprecision.peers.BY_KEY`'s)."""
    if peers is True:
        keys: tuple[str, ...] = ("plain",) + tuple(BY_KEY)
    else:
        keys = peers or ()
    cache = PeerCache() if cache is None else cache
    for tier in tiers:
        if tier == "linear":
            yield "linear expm", lambda refs: measure_linear(case, refs, batch)
            continue
        for cfg in our_configs(quick):
            yield (f"{tier} {cfg.label} {cfg.rtol if cfg.kind == 'adaptive' else cfg.dt:g}",
                   partial(measure_ours, case, tier, cfg, batch=batch))
        if "plain" in keys and tier != "coulomb":  # the plain-numpy peer has no friction model
            for cfg in peer_configs(quick):
                yield (f"{tier} {cfg.label} {cfg.rtol:g}",
                       partial(measure_peer, case, tier, cfg))
        # the compiled peers' models (on the point ball, R = 0, numbalsoda's cfunc raised
        # ZeroDivisionError at every call: a full run stalled on it, printing each)
        if tier in ("rolling", "slipping"):
            for cfg in compiled_peer_configs(quick, keys):
                yield (f"{tier} {cfg.label} {cfg.rtol:g}",
                       partial(measure_compiled_peer, case, tier, cfg, cache=cache,
                               batch=batch and tier == "rolling"))


def _our_config(brief: dict) -> Config:
    """The simulator's setting a summary entry (`report._brief`) names."""
    fixed = brief["kind"] == "fixed"
    return Config("saddle_env", brief["method"], rtol=math.nan if fixed else brief["setting"],
                  dt=brief["setting"] if fixed else math.nan, max_step=brief["max_step"])


def rounds(case: Case, comparison: dict, cache: PeerCache, n_rounds: int = 5) -> dict:
    """The settings `report.peer_comparison` picked, timed again in alternating rounds.

    The sweep times each row when its turn comes, so on a shared machine the simulator's
    row and a peer's can meet different loads. Here, for each form (one ball, batch) and
    error bound, the simulator and every compiled peer run once per round (after one
    untimed call), in an order that rotates, and each keeps its fastest round: their ratio
    is measured under the same load. scipy on the plain-numpy model is left out (seconds per run, and thousands of
    times slower). Returns {form: {bound: {"project": µs, key: µs, ...}}} with the same
    units as the sweep (µs per simulated second, per ball in the batch)."""
    out: dict = {}
    s0 = case.state("rolling")
    grid = case.grid()
    states = batch_states(case, "rolling", case.batch_n)
    n_out = int(round(case.batch_t_end / case.dt_out))
    bgrid = np.arange(n_out + 1) * case.dt_out
    sc = case.scene("rolling")
    for form in ("one_ball", "batch"):
        for bound, level in comparison.get(form, {}).items():
            kw = _sim_kwargs(case, _our_config(level["project"]))
            fns: dict[str, Callable[[], object]] = {}
            if form == "one_ball":
                fns["project"] = partial(simulate, sc, s0, case.t_end, **kw)
                per = case.t_end
            else:
                fns["project"] = partial(simulate_batch, sc, states, case.batch_t_end,
                                         shared_steps=BATCH_SHARED, **kw)
                per = case.batch_t_end * case.batch_n
            for key, entry in level.items():
                if key in ("project", "fastest", "plain"):
                    continue
                solver = cache.solver(case, "rolling", key)
                fns[key] = (partial(solver.single, s0, grid, entry["setting"])
                            if form == "one_ball"
                            else partial(solver.batch, states, bgrid, entry["setting"]))
            best = best_of_rounds(fns, n_rounds)
            out.setdefault(form, {})[bound] = {k: v / per * 1e6 for k, v in best.items()}
    return out


def best_of_rounds(fns: dict[str, Callable[[], object]], n_rounds: int,
                   clock: Callable[[], float] = time.perf_counter) -> dict[str, float]:
    """Each function's fastest call [s of ``clock``] over ``n_rounds`` rounds in which every
    function runs in turn, in an order that rotates, so that all meet the same load on a
    shared machine; each timed call follows an untimed one of the same function: a call
    right after another solver's ran up to 40 % slower (measured after diffrax and CVODE:
    their caches, XLA's threads), which would charge each for the one before it."""
    best = dict.fromkeys(fns, math.inf)
    names = list(fns)
    for i in range(n_rounds):
        for name in names[i % len(names):] + names[: i % len(names)]:
            fns[name]()
            t0 = clock()
            fns[name]()
            best[name] = min(best[name], clock() - t0)
    return best


def measure_jacobi(case: Case, periods: int, rtol: float = REFERENCE_RTOL) -> dict[str, object]:
    """Jacobi-integral drift of the rolling ball over ``periods`` saddle turns (2π/Ω each)
    at constant Ω, relative to |h(0)| as in tests/test_invariants.py, and the largest
    departure of the centre from its offset surface (distance R along the normal)."""
    sc = case.scene("rolling")
    t_end = periods * 2.0 * math.pi / case.omega
    t0 = time.perf_counter()
    tr = simulate(sc, case.state("rolling"), t_end, omega=case.omega, dt_out=t_end / 2000,
                  rtol=rtol)
    wall = time.perf_counter() - t0
    h = tr.h
    return {"periods": periods, "t_end_s": t_end, "rtol": rtol, "wall_s": wall,
            "steps": tr.stats.steps, "event": None if tr.event is None else tr.event.kind,
            "jacobi_drift_relative": float(np.max(np.abs(h - h[0])) / abs(h[0])),
            "offset_surface_error_m": offset_surface_error(sc, tr.state, tr.centre)}


def offset_surface_error(scene: Scene, states: np.ndarray, centres: np.ndarray) -> float:
    """Largest | |c − o| − R | and departure of c − o from the normal, over the rows [m]."""
    o = np.column_stack([states[:, 0], states[:, 1],
                         states[:, 0] ** 2 / scene.a - states[:, 1] ** 2 / scene.b])
    m = np.column_stack([-2 * states[:, 0] / scene.a, 2 * states[:, 1] / scene.b,
                         np.ones(len(states))])
    n = m / np.linalg.norm(m, axis=1)[:, None]
    return float(np.max(np.linalg.norm(centres - o - scene.radius * n, axis=1)))
