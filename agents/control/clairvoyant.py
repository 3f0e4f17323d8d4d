"""``clairvoyant``: an upper reference that knows the episode's future and plans on copies of
the episode's own environment.

The clairvoyant controller is not a controller a real apparatus could run. It reads the
environment itself, not the observation: the ball (size, contact model, mu), the true state
(no sensor noise) and, through a copy of the ball's random generator, every future air
current and sensor draw. It plans with the environment's own compiled step, so a plan that
keeps a ball on the copy keeps it in the episode, bit for bit.

**How it plans** (per episode, at its start; `ClairvoyantPlanner`):

1. **Incumbents: `mpc`'s own episode, and the shipped agents'.** The whole batch of balls,
   engine state and generators copied, is driven by `mpc` (`agents.control.mpc`, built exactly as
   ``saddle-eval --policy mpc`` builds it) for the full episode, and so by each shipped
   agent trained on the level (`shipped_agents`; in batches of ``CHUNK`` balls as
   ``saddle-eval`` runs model files). Each ball's first plan is the actions of the one that
   kept it longest (mpc on a tie), and each one's trapping time is its trapping time on
   that episode (the same episode: same generator, same observations, same actions).
2. **Improvement, only where the incumbent loses the ball.** Backing off from the step in
   which the ball is lost (2, 5, 10, ... 500 steps, down to the episode's start), candidate
   plans are scored from that step to the episode's end on a batch engine of copies of the
   ball at that step (its state and generator). The candidates (`_candidates`): the
   incumbent's own remaining actions; each of 14 target speeds (0.85-1.6 Ω_crt of the true
   ball, and the speed commanded now) held for 2, 6, 15 or 40 steps, then either the
   incumbent's remaining actions or that speed held, or held to the end (in ``voltage``
   mode the voltages whose steady speeds these are); in ``acceleration`` mode
   accelerations of ±0.2, ±0.5 and ±1 of the motor's limit instead, followed by holding
   the speed reached. The rest of the ``candidates`` slots (128 by default: 1 in target
   and voltage mode, 73 in acceleration mode) are smooth random perturbations of
   the incumbent. A candidate that keeps the ball strictly longer than the incumbent (from
   the same step, with the same future) replaces it, and the search starts again from the
   new loss. It stops when the ball is kept, when backing off to the episode's start finds
   no improvement, or after ``max_rounds`` candidate batches (400).
3. **Execution.** The plan is replayed open loop; every step the real engine's ball is
   checked against the plan's predicted state (bit-identical, else `RuntimeError`).

**The guarantee.** A plan is replaced only by one that keeps the ball longer on an exact
copy of the episode, so the executed plan keeps every ball at least as long as `mpc` (and
every incumbent agent) does on the same episode: not on average, on every episode. For a
model file the incumbent is its episode in a batch of ``CHUNK`` balls (padded), as
``saddle-eval`` runs it: the same batches when both start from the same seed (a policy
network's output can depend on the batch's shape). Starts the search does not rescue are
reported as *doomed* for this planner: an upper bound on the share no controller can keep
(a better search could rescue some).

`agents.benchmark.headroom.evaluate_clairvoyant` runs it on seeded episodes of a level and returns
the trapping times (with `mpc`'s and the agents', free from step 1), the doomed share with a
Wilson interval and the time per episode. ``saddle-eval --policy clairvoyant`` runs it
through `agents.control.rollout`, which hands the environment to actors that ask for it
(``attach``).
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from saddle_env.envs import EnvConfig
from saddle_env.envs import control_step as S
from saddle_env.envs.engine import TrapEngine
from saddle_env.linear import critical_omega
from saddle_env.simulate import SimulationError

from ..paths import MODELS_DIR
from .controllers import Controller

BACKOFFS = (2, 5, 10, 20, 35, 50, 75, 100, 150, 200, 300, 400, 500)  # steps before the loss
WINDOWS = (2, 6, 15, 40)   # steps a candidate's deviation lasts before its tail


# --------------------------------------------------------------------------------------
# One ball's state in an engine, and batches of copies of it
# --------------------------------------------------------------------------------------

def _book(engine: Any, active: np.ndarray, k: int, dt: float, t: np.ndarray,
          loss: np.ndarray, status: np.ndarray) -> None:
    """After step ``k`` of the balls ``active``: add their trapped time, record the step and
    cause of each loss, and drop the lost balls from ``active`` (in place)."""
    t[active] += engine.out[active, S.O_TRAPPED] * dt
    lost = active & (engine.out[:, S.O_STATUS] > 0)
    loss[lost] = k
    status[lost] = engine.out[lost, S.O_STATUS]
    active &= ~lost

def copy_rng(rng: np.random.Generator) -> np.random.Generator:
    """An independent generator in ``rng``'s exact state (its future draws, without
    advancing it); cheaper than `copy.deepcopy`, which it falls back to."""
    bg = rng.bit_generator
    try:
        twin = type(bg)(0)
        twin.state = bg.state
    except (TypeError, ValueError):
        return copy.deepcopy(rng)
    return np.random.Generator(twin)


@dataclass
class BallState:
    """Everything a `TrapEngine` keeps for one ball, and its random generator (a copy)."""

    model: int
    P: np.ndarray
    scale: np.ndarray
    Y: np.ndarray
    ball: np.ndarray
    out: np.ndarray
    frame: np.ndarray
    obs: np.ndarray
    noise: np.ndarray
    scene: Any
    rng: np.random.Generator      # a copy, never stepped itself
    delays: dict[str, np.ndarray]  # the delays' queues (`TrapEngine.delay_arrays`)

    @classmethod
    def capture(cls, engine: TrapEngine, rngs: Any, i: int) -> BallState:
        """Copy ball ``i``'s whole state out of ``engine`` (and its random generator from ``rngs``)."""
        return cls(int(engine.models[i]), engine.P[i].copy(), engine.scales[i].copy(),
                   engine.Y[i].copy(), engine.balls[i].copy(), engine.out[i].copy(),
                   engine.frame[i].copy(), engine.obs[i].copy(), engine.noise[i].copy(),
                   engine.scenes[i], copy_rng(rngs[i]),
                   {name: getattr(engine, name)[i].copy() for name in engine.delay_arrays})

    def put(self, engine: TrapEngine, rows: np.ndarray) -> list[np.random.Generator]:
        """Write this state into ``rows`` of ``engine``; returns a fresh generator copy per row."""
        engine.models[rows] = self.model
        engine.P[rows] = self.P
        engine.scales[rows] = self.scale
        engine.Y[rows] = self.Y
        engine.balls[rows] = self.ball
        engine.out[rows] = self.out
        engine.frame[rows] = self.frame
        engine.obs[rows] = self.obs
        engine.noise[rows] = self.noise
        for name, value in self.delays.items():
            getattr(engine, name)[rows] = value
        for r in rows:
            engine.scenes[r] = self.scene
        return [copy_rng(self.rng) for _ in rows]


def copy_engine(engine: TrapEngine, rngs: Any) -> tuple[TrapEngine, list[np.random.Generator]]:
    """A new engine holding a copy of every ball of ``engine``, and copies of the generators."""
    twin = TrapEngine(engine.config, engine.n)
    for name in ("models", "P", "scales", "Y", "balls", "out", "frame", "obs", "noise",
                 *engine.delay_arrays):
        getattr(twin, name)[:] = getattr(engine, name)
    twin.scenes = list(engine.scenes)
    return twin, [copy_rng(r) for r in rngs]


@dataclass
class Rollout:
    """Outcome of open-loop plans from a common state: per plan the trapped time [s] over the
    simulated steps, the step (0-based, from the start) in which the ball was lost (the
    number of steps if kept) and the cause (``O_STATUS`` code, 0 if kept)."""

    time: np.ndarray
    loss: np.ndarray
    status: np.ndarray


def run_plans(engine: TrapEngine, rngs: list, plans: np.ndarray) -> Rollout:
    """Step every row of ``engine`` through its row of ``plans`` (n, steps) (float32 actions,
    as the environment receives them) until its ball is lost; rows are independent."""
    n, steps = plans.shape
    dt = engine.config.control_period
    active = np.ones(n, dtype=bool)
    t = np.zeros(n)
    loss = np.full(n, steps, dtype=np.int64)
    status = np.zeros(n, dtype=np.int64)
    acts = np.zeros(n)
    for k in range(steps):
        acts[:] = plans[:, k].astype(np.float64)
        engine.step(acts, active, rngs)
        _book(engine, active, k, dt, t, loss, status)
        if not active.any():
            break
    return Rollout(t, loss, status)


# --------------------------------------------------------------------------------------
# The planner
# --------------------------------------------------------------------------------------
@dataclass
class BallPlan:
    """One ball's plan: its actions for the whole episode (float32), the time it keeps the
    ball [s], the step it is lost in (the episode length if kept), `mpc`'s time and every
    incumbent's."""

    actions: np.ndarray
    time: float
    loss: int
    mpc_time: float
    rounds: int = 0
    improved: int = 0
    incumbents: dict[str, float] | None = None   # each incumbent policy's time [s]
    source: str = "mpc"                           # the incumbent the search started from


class ClairvoyantPlanner:
    """Plans for a batch of balls just reset in an engine (see the module docstring).

    ``max_rounds``: candidate batches scored per lost ball at most; ``candidates``: plans
    per batch (the fixed families, then random perturbations up to this number);
    ``seed``: the generator of those perturbations (the plan is deterministic for a seed);
    ``agents``: the policies whose episodes are incumbents besides `mpc`'s: True, the
    shipped agents trained on exactly this config (`shipped_agents`); False, none; or a
    list of model files / baseline names, loaded with ``loader`` (`agents.evaluation.policies.
    load_policy`, which the registered ``clairvoyant`` passes; this module cannot import it,
    as `agents.evaluation.policies` imports this one).
    """

    def __init__(self, config: EnvConfig, max_rounds: int = 400, candidates: int = 128,
                 seed: int = 0, mpc: Any = None, agents: bool | list[str] = False,
                 loader: Any = None):
        self.config = config
        self.max_rounds = int(max_rounds)
        self.candidates = int(candidates)
        self.seed = int(seed)
        self._mpc = mpc
        self._agent_specs = agents
        self._loader = loader
        self._agents: list[tuple[str, Any]] | None = None
        self._engines: dict[int, TrapEngine] = {}

    @property
    def agents(self) -> list[tuple[str, Any]]:
        """(name, policy) of the incumbents besides `mpc` (loaded on first use)."""
        if self._agents is None:
            specs = self._agent_specs
            if specs is True:
                specs = [str(p) for p in shipped_agents(self.config)]
            if specs and self._loader is None:
                raise ValueError("agents as incumbents need a loader "
                                 "(loader=agents.evaluation.policies.load_policy)")
            self._agents = [(Path(str(sp)).name, self._loader(sp, self.config))
                            for sp in (specs or [])]
        return self._agents

    @property
    def mpc(self) -> Any:
        """`mpc` as ``saddle-eval --policy mpc`` builds it (the reference speed searched or
        read from the best-constant cache on first use)."""
        if self._mpc is None:
            from .mpc import ModelPredictiveController
            self._mpc = ModelPredictiveController(self.config)
        return self._mpc

    def _engine(self, n: int) -> TrapEngine:
        if n not in self._engines:
            self._engines[n] = TrapEngine(self.config, n)
        return self._engines[n]

    # -- 1. the incumbents: mpc's own episode, and the agents' --------------------------
    def mpc_episode(self, engine: TrapEngine, rngs: Any, steps: int
                    ) -> tuple[np.ndarray, Rollout]:
        """`closed_loop` of `mpc`."""
        return self.closed_loop(self.mpc, engine, rngs, steps)

    def closed_loop(self, policy: Any, engine: TrapEngine, rngs: Any, steps: int
                    ) -> tuple[np.ndarray, Rollout]:
        """Drive a copy of every ball of ``engine`` with ``policy`` for ``steps`` steps, as
        `agents.control.rollout.run_episodes` does: (actions (n, steps) float32, outcome). A policy
        that is not row-independent (a model file) sees batches of ``CHUNK`` balls, padded
        with copies, as in `run_episodes`."""
        from .rollout import CHUNK, PolicyActor

        if getattr(policy, "row_independent", False) or engine.n == CHUNK:
            return self._closed_loop(PolicyActor(policy), *copy_engine(engine, rngs), steps)
        parts = []
        for lo in range(0, engine.n, CHUNK):
            rows = np.arange(lo, min(lo + CHUNK, engine.n))
            rows = np.concatenate([rows, np.full(CHUNK - len(rows), rows[0])])
            twin = TrapEngine(engine.config, CHUNK)
            for name in ("models", "P", "scales", "Y", "balls", "out", "frame", "obs", "noise",
                         *engine.delay_arrays):
                getattr(twin, name)[:] = getattr(engine, name)[rows]
            twin.scenes = [engine.scenes[r] for r in rows]
            keep = min(CHUNK, engine.n - lo)
            plans, r = self._closed_loop(PolicyActor(policy), twin,
                                         [copy_rng(rngs[i]) for i in rows], steps)
            parts.append((plans[:keep], r.time[:keep], r.loss[:keep], r.status[:keep]))
        return (np.concatenate([p[0] for p in parts]),
                Rollout(*(np.concatenate([p[k] for p in parts]) for k in (1, 2, 3))))

    def _closed_loop(self, actor: Any, twin: TrapEngine, trngs: list, steps: int
                     ) -> tuple[np.ndarray, Rollout]:
        n = twin.n
        actor.start(n)
        dt = self.config.control_period
        plans = np.zeros((n, steps), dtype=np.float32)
        alive = np.ones(n, dtype=bool)
        t = np.zeros(n)
        loss = np.full(n, steps, dtype=np.int64)
        status = np.zeros(n, dtype=np.int64)
        actions = np.zeros(n)
        for k in range(steps):
            idx = np.flatnonzero(alive)
            obs = twin.obs.copy()
            a = np.asarray(actor(obs, idx), dtype=np.float32).reshape(len(idx))
            plans[idx, k] = a
            actions[:] = 0.0
            actions[idx] = np.clip(a.astype(np.float64), -1.0, 1.0)
            twin.step(actions, alive.copy(), trngs)
            _book(twin, alive, k, dt, t, loss, status)
            if not alive.any():
                break
        # After a loss the plan holds its last action (never executed: the episode is over).
        for i in range(n):
            if loss[i] < steps:
                plans[i, loss[i] + 1:] = plans[i, loss[i]]
        return plans, Rollout(t, loss, status)

    # -- 2. improvement of a lost ball ------------------------------------------------
    def _snapshots(self, start: BallState, plan: np.ndarray, upto: int) -> list[BallState]:
        """The ball's state at the start of steps 0 .. ``upto`` under ``plan``."""
        eng = self._engine(1)
        rngs = start.put(eng, np.array([0]))
        snaps = [start]
        a = np.zeros(1)
        active = np.ones(1, dtype=bool)
        for k in range(upto):
            a[0] = float(plan[k])
            eng.step(a, active, rngs)
            snaps.append(BallState.capture(eng, rngs, 0))
        return snaps

    def _speeds(self, state: BallState) -> np.ndarray:
        """Target speeds the candidates try, around this ball's Ω_crt [rad/s]."""
        c = self.config
        try:
            wc = critical_omega(state.scene)
        except Exception:   # noqa: BLE001 — a scene the linear theory does not cover
            wc = math.sqrt(2 * c.g / c.a)
        grid = np.concatenate([wc * np.linspace(0.85, 1.6, 13), [state.ball[S.B_OMEGA]]])
        return np.clip(grid, 0.0, c.omega_max)

    def _candidates(self, state: BallState, tail: np.ndarray, rng: np.random.Generator
                    ) -> np.ndarray:
        """Candidate plans (K, len(tail)) from a state whose incumbent continues with ``tail``."""
        c = self.config
        m = len(tail)
        rows = [tail.copy()]
        if c.action_mode == "target":
            levels = 2.0 * self._speeds(state) / c.omega_max - 1.0
            hold = None                      # a held target is the level itself
        elif c.action_mode == "voltage":     # a held voltage holds its steady speed K·V
            levels = np.minimum(2.0 * self._speeds(state) / (c.motor_gain * c.voltage_max)
                                - 1.0, 1.0)
            hold = None
        else:
            levels = np.array([-1.0, -0.5, -0.2, 0.2, 0.5, 1.0])
            hold = 0.0                       # acceleration 0 holds the speed reached
        for v in levels:
            full = np.full(m, v)
            rows.append(full if hold is None else np.where(np.arange(m) < 10, v, hold))
            for w in WINDOWS:
                if w >= m:
                    continue
                a = tail.copy()
                a[:w] = v
                rows.append(a)
                b = np.full(m, v if hold is None else hold)
                b[:w] = v
                rows.append(b)
        plans = np.array(rows)
        extra = self.candidates - len(plans)
        if extra > 0:
            # Random perturbations of the incumbent: smooth (a random walk) over a random window.
            scale = rng.choice(np.array([0.003, 0.01, 0.03]), size=(extra, 1))
            noise = np.cumsum(rng.normal(0.0, 1.0, size=(extra, m)) * scale, axis=1)
            span = rng.integers(5, max(6, min(m, 120)) + 1, size=extra)
            noise[np.arange(m)[None, :] >= span[:, None]] *= 0.0
            plans = np.vstack([plans, tail[None, :] + noise])
        return np.clip(plans[:max(self.candidates, 1)], -1.0, 1.0).astype(np.float32)

    def improve(self, start: BallState, plan: BallPlan, steps: int, rng: np.random.Generator
                ) -> BallPlan:
        """Search for a plan that keeps this ball longer than ``plan`` (see the module doc)."""
        rounds, j = 0, 0
        snaps = self._snapshots(start, plan.actions, plan.loss)
        while plan.loss < steps and rounds < self.max_rounds and j < len(BACKOFFS):
            s = max(0, plan.loss - BACKOFFS[j])
            tail = plan.actions[s:]
            cands = self._candidates(snaps[s], tail, rng)
            eng = self._engine(len(cands))
            rngs = snaps[s].put(eng, np.arange(len(cands)))
            rounds += 1
            try:
                res = run_plans(eng, rngs, cands)
            except SimulationError:
                # A candidate the integrator cannot follow (its step limit): this batch
                # proves nothing, so it changes nothing; back off further.
                res = None
            # The time before s is common to every candidate; row 0 is the incumbent.
            best = 0 if res is None else int(np.argmax(res.time))
            if res is not None and res.time[best] > res.time[0]:
                actions = np.concatenate([plan.actions[:s], cands[best]])
                prefix = plan.time - res.time[0]
                plan = BallPlan(actions, prefix + float(res.time[best]),
                                s + int(res.loss[best]), plan.mpc_time, plan.rounds,
                                plan.improved + 1, plan.incumbents, plan.source)
                if plan.loss < steps:
                    snaps = snaps[:s] + self._snapshots(snaps[s], actions[s:], plan.loss - s)
                j = 0
            else:
                j += 1
                if s == 0:
                    break
        plan.rounds += rounds
        return plan

    # -- the batch ---------------------------------------------------------------------
    def plan(self, engine: TrapEngine, rngs: Any, steps: int) -> list[BallPlan]:
        """A plan for every ball of ``engine`` (just reset) for an episode of ``steps`` steps."""
        runs = [("mpc", *self.mpc_episode(engine, rngs, steps))]
        runs += [(name, *self.closed_loop(pol, engine, rngs, steps)) for name, pol in self.agents]
        plans = []
        for i in range(engine.n):
            times = {name: float(r.time[i]) for name, _, r in runs}
            best = max(range(len(runs)), key=lambda k: (runs[k][2].time[i], -k))  # ties: mpc
            name, actions, r = runs[best]
            p = BallPlan(actions[i].copy(), float(r.time[i]), int(r.loss[i]), times["mpc"],
                         incumbents=times, source=name)
            if p.loss < steps:
                start = BallState.capture(engine, rngs, i)
                # A generator per ball from the planner's seed and the ball's start (so a
                # ball's plan does not depend on the others in the batch).
                key = np.frombuffer(start.Y.tobytes() + start.ball.tobytes(), dtype=np.uint32)
                p = self.improve(start, p, steps, np.random.default_rng([self.seed, *key]))
                # Exact score of the final plan from the start (the guarantee's check).
                eng = self._engine(1)
                r = run_plans(eng, start.put(eng, np.array([0])), p.actions[None, :])
                if r.time[0] < max(times.values()):
                    raise RuntimeError(f"clairvoyant plan of ball {i} keeps it {r.time[0]:.6f} s, "
                                       f"less than an incumbent's ({times})")
                p.time, p.loss = float(r.time[0]), int(r.loss[0])
            plans.append(p)
        return plans


# --------------------------------------------------------------------------------------
# The policy: a named baseline that needs the environment
# --------------------------------------------------------------------------------------
class ClairvoyantController(Controller):
    """``clairvoyant``: the upper reference (module docstring). It acts through
    `ClairvoyantActor`, which `agents.control.rollout.run_episodes` gives the environment; its
    ``predict`` alone (observations only) cannot act and raises."""

    name = "clairvoyant"
    row_independent = True

    def __init__(self, config: EnvConfig, max_rounds: int = 400, candidates: int = 128,
                 seed: int = 0, agents: bool | list[str] = False, loader: Any = None):
        super().__init__(config)
        self.planner = ClairvoyantPlanner(config, max_rounds, candidates, seed, agents=agents,
                                          loader=loader)

    def episode_actor(self) -> ClairvoyantActor:
        """A fresh actor that plans each episode from the environment's state."""
        return ClairvoyantActor(self.planner)

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """Not available: this controller reads the environment, not the observation.

        Raises
        ------
        RuntimeError
            Always; run it through `agents.control.rollout.run_episodes` instead.
        """
        raise RuntimeError("the clairvoyant controller reads the environment, not the "
                           "observation: run it through agents.control.rollout.run_episodes "
                           "(saddle-eval --policy clairvoyant) or evaluate_clairvoyant")


class ClairvoyantActor:
    """``act(obs, idx)`` for `run_episodes`: plans at ``attach`` (after the batch's reset),
    then replays each ball's plan, checking the engine against it every step."""

    def __init__(self, planner: ClairvoyantPlanner):
        self.planner = planner
        self.plans: list[BallPlan] = []
        self.env: Any = None
        self._step = np.zeros(0, dtype=np.int64)
        self._expect: list[list[np.ndarray] | None] = []
        self.plan_seconds = 0.0

    def start(self, n: int) -> None:
        """Prepare for ``n`` balls."""
        self._step = np.zeros(n, dtype=np.int64)

    def attach(self, env: Any, max_episode_steps: int) -> None:
        """Plan for every ball of the vector env ``env`` just reset."""
        t0 = time.perf_counter()
        e = env.engine
        self.env = env
        self.plans = self.planner.plan(e, env._rngs, max_episode_steps)
        self._step = np.zeros(e.n, dtype=np.int64)
        # The state every ball should be in before each of its steps (for the check).
        self._expect = []
        for i, p in enumerate(self.plans):
            eng = self.planner._engine(1)
            rngs = BallState.capture(e, env._rngs, i).put(eng, np.array([0]))
            ys = [e.Y[i].copy()]
            a, on = np.zeros(1), np.ones(1, dtype=bool)
            for k in range(min(p.loss + 1, max_episode_steps)):
                a[0] = float(p.actions[k])
                eng.step(a, on, rngs)
                ys.append(eng.Y[0].copy())
            self._expect.append(ys)
        self.plan_seconds += time.perf_counter() - t0

    def __call__(self, obs: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """The planned action of each ball in ``idx`` at its current step."""
        if self.env is None:
            raise RuntimeError("the clairvoyant actor needs the environment (attach)")
        Y = self.env.engine.Y
        out = np.empty(len(idx), dtype=np.float32)
        for j, i in enumerate(idx):
            k = int(self._step[i])
            want = self._expect[i][k] if k < len(self._expect[i]) else None
            if want is not None and not np.array_equal(Y[i], want, equal_nan=True):
                raise RuntimeError(f"ball {i} left its plan at step {k}: the environment is not "
                                   "the copy the clairvoyant planned on")
            out[j] = self.plans[i].actions[min(k, len(self.plans[i].actions) - 1)]
            self._step[i] += 1
        return out


def shipped_agents(config: EnvConfig, models_dir: Path | None = None) -> list[Path]:
    """The shipped model files (``agents/models``) trained on exactly ``config``: their
    sidecar's level with its ``env_kwargs`` resolves to it. Empty without the ``[train]``
    extra (stable-baselines3), which loading them needs."""
    import importlib.util
    import json

    from saddle_env.envs import get_level

    if importlib.util.find_spec("stable_baselines3") is None:
        return []
    models_dir = MODELS_DIR if models_dir is None else models_dir
    out = []
    for path in sorted(models_dir.glob("*.zip")):
        try:
            side = json.loads(path.with_suffix(".json").read_text())
            trained = get_level(side["env_id"]).config(**(side.get("env_kwargs") or {}))
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if trained == config:
            out.append(path)
    return out


def clairvoyant(config: EnvConfig, loader: Any = None, **planner: Any) -> ClairvoyantController:
    """The ``clairvoyant`` baseline: incumbents `mpc` and, given a ``loader``
    (`agents.evaluation.policies.load_policy`), the shipped agents trained on ``config``."""
    return ClairvoyantController(config, agents=loader is not None, loader=loader, **planner)


__all__ = ["BallPlan", "BallState", "ClairvoyantActor", "ClairvoyantController",
           "ClairvoyantPlanner", "clairvoyant", "copy_engine", "copy_rng", "run_plans",
           "shipped_agents"]
