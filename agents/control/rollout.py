"""Running seeded episodes of a batch of balls and collecting per-episode statistics: the
layer both the evaluation tool (`agents.evaluation.evaluate`) and the best-constant search
(`agents.control.best_constant`) stand on, so neither has to import the other.

`run_episodes` steps `SaddleTrapVectorEnv` with an ``act(obs, idx)`` callable; `PolicyActor`
turns any policy with Stable-Baselines3's ``predict`` into one. `episode_set` names the
episodes a call runs (first seed, count, length, options), so that a curve and the reference
lines drawn beside it can be checked to come from the same episodes (`same_episodes`).
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from saddle_env.envs import DEFAULT_EPISODE_STEPS, EnvConfig

CHUNK = 100          # episodes per batch for model files (fixed: batch-independent actions)

Actor = Callable[[np.ndarray, np.ndarray], np.ndarray]


def episode_set(config: EnvConfig, seed: int, episodes: int,
                max_episode_steps: int = DEFAULT_EPISODE_STEPS) -> dict[str, Any]:
    """The episodes `run_episodes` runs for ``seeds = seed .. seed + episodes − 1`` on
    ``config``: episode i is ``reset(seed=seed + i)``, run to its end (at most
    ``max_episode_steps`` steps). ``options`` is a digest of every option of ``config``, so
    two sets are the same episodes exactly when the dicts are equal (`same_episodes`)."""
    for name, value, low in (("seed", seed, 0), ("episodes", episodes, 1),
                             ("max_episode_steps", max_episode_steps, 1)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    text = json.dumps(config.as_dict(), sort_keys=True, default=str)
    return {"seed": int(seed), "episodes": int(episodes),
            "max_episode_steps": int(max_episode_steps),
            "options": hashlib.sha256(text.encode()).hexdigest()[:16]}


def same_episodes(a: dict[str, Any] | None, b: dict[str, Any] | None, what: str) -> None:
    """ValueError naming ``what`` (e.g. "the validation curve and best-const's line") unless
    the `episode_set` dicts ``a`` and ``b`` are the same episodes."""
    if a is None or b is None:
        raise ValueError(f"{what}: an episode set is not recorded ({a!r} and {b!r}), so "
                         f"they cannot be shown to come from the same episodes")
    keys = ("seed", "episodes", "max_episode_steps", "options")
    differ = [k for k in keys if a.get(k) != b.get(k)]
    if differ:
        raise ValueError(f"{what} come from different episodes: "
                         + ", ".join(f"{k} {a.get(k)!r} against {b.get(k)!r}" for k in differ))


def _chunks(seeds: np.ndarray, row_independent: bool) -> list[np.ndarray]:
    """The batches the episodes run in: all at once, or CHUNK at a time with the last one
    padded with extra seeds (a policy then always sees the same batch shape)."""
    if row_independent:
        return [seeds]
    pad = (-len(seeds)) % CHUNK
    padded = np.concatenate([seeds, seeds.max() + 1 + np.arange(pad)]) if pad else seeds
    return [padded[i:i + CHUNK] for i in range(0, len(padded), CHUNK)]


def _progress_bar(progress: bool | str, total: int) -> Any:
    """A tqdm bar over ``total`` steps on stderr, or None (no progress asked, or no tqdm)."""
    if not progress:
        return None
    try:
        from tqdm.auto import tqdm
    except ImportError:  # the bar is a nicety; the command lines say how to get it
        return None
    return tqdm(total=total, unit="step", file=sys.stderr,
                desc=progress if isinstance(progress, str) else None, leave=False,
                mininterval=0.5)


@dataclass
class _Traces:
    """Ω and r at every step end of the first ``record`` episodes (NaN after the end)."""

    omega: np.ndarray   # (record, steps + 1)
    r: np.ndarray       # (record, steps + 1)


def _run_chunk(config: EnvConfig, act: Actor, chunk: np.ndarray, start: int, keep: int,
               max_episode_steps: int, traces: _Traces, bar: Any) -> dict[str, np.ndarray]:
    """One batch of episodes (episode ``start + j`` is row j; the first ``keep`` rows are
    real episodes): its per-row sums, filling the traces of the recorded rows."""
    from saddle_env.envs.vector import SaddleTrapVectorEnv

    m, dt = len(chunk), config.control_period
    env = SaddleTrapVectorEnv(num_envs=m, max_episode_steps=max_episode_steps,
                              **config.as_dict())
    obs, info = env.reset(seed=[int(s) for s in chunk])
    if hasattr(act, "start"):
        act.start(m)
    if hasattr(act, "attach"):    # actors that plan on the environment itself (clairvoyant)
        act.attach(env, max_episode_steps)
    alive = np.ones(m, dtype=bool)
    t_trap, r_sum, a_sum, ret = np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m)
    steps = np.zeros(m, dtype=np.int64)
    min_n = np.asarray(info["N_over_mg"], dtype=float).copy()
    cause = np.full(m, "kept", dtype=object)
    rec = [j for j in range(m) if start + j < len(traces.omega)]
    for j in rec:
        traces.omega[start + j, 0] = info["omega"][j]
        traces.r[start + j, 0] = math.hypot(*env.engine.Y[j, :2])
    actions = np.zeros((m, 1), dtype=np.float32)
    for step in range(max_episode_steps):
        idx = np.flatnonzero(alive)
        a = np.asarray(act(obs, idx), dtype=np.float32).reshape(len(idx))
        actions[:] = 0.0
        actions[idx, 0] = a
        obs, rew, term, trunc, info = env.step(actions)
        r = np.hypot(env.engine.Y[:, 0], env.engine.Y[:, 1])
        t_trap[idx] += info["trapped_fraction"][idx] * dt
        r_sum[idx] += r[idx]
        a_sum[idx] += np.clip(a.astype(np.float64), -1, 1) ** 2
        ret[idx] += rew[idx]
        steps[idx] += 1
        min_n[idx] = np.minimum(min_n[idx], info["N_over_mg"][idx])
        for j in rec:
            if alive[j]:
                traces.omega[start + j, step + 1] = info["omega"][j]
                traces.r[start + j, step + 1] = r[j]
        for i in np.flatnonzero(term & alive):
            cause[i] = info["cause"][i]
        alive &= ~(term | trunc)
        if bar is not None:
            bar.update(1)
        if not alive[:keep].any():
            if bar is not None:
                bar.update(max_episode_steps - step - 1)
            break
    env.close()
    return {"time": t_trap, "r_sum": r_sum, "a_sum": a_sum, "return": ret, "steps": steps,
            "min_normal": min_n, "cause": cause}


def run_episodes(config: EnvConfig, act: Actor, seeds: Sequence[int] | np.ndarray, *,
                 max_episode_steps: int = DEFAULT_EPISODE_STEPS, row_independent: bool = True,
                 record: int = 0, progress: bool | str = False) -> dict[str, np.ndarray]:
    """Run one episode per seed (episode i: ``reset(seed=seeds[i])``) and collect statistics.

    ``act(obs, idx)`` returns the actions (len(idx),) or (len(idx), 1) for the balls ``idx``
    still in play, given the batch of observations ``obs``. With ``row_independent`` the
    whole set runs as one batch; otherwise in chunks of ``CHUNK`` episodes (the last padded
    with extra seeds), so that a policy always sees the same batch shape.

    Returns per-episode arrays: ``time`` [s], ``kept``, ``cause`` ("detach", "escape" or
    "kept"), ``mean_r`` [m], ``effort``, ``return``, ``min_normal`` (N/mg at step ends), and
    for the first ``record`` episodes ``trace_omega``, ``trace_r`` ((record, steps + 1),
    NaN after the end) and ``trace_t``.
    """
    seeds = np.asarray(seeds, dtype=np.int64)
    n = len(seeds)
    chunks = _chunks(seeds, row_independent)
    out: dict[str, np.ndarray] = {"time": np.zeros(n), "kept": np.zeros(n, dtype=bool),
           "cause": np.full(n, "kept", dtype=object), "mean_r": np.zeros(n),
           "effort": np.zeros(n), "return": np.zeros(n), "min_normal": np.full(n, np.inf)}
    record = min(record, n)
    traces = _Traces(np.full((record, max_episode_steps + 1), np.nan),
                     np.full((record, max_episode_steps + 1), np.nan))
    bar = _progress_bar(progress, len(chunks) * max_episode_steps)
    start = 0
    for chunk in chunks:
        keep = min(len(chunk), n - start)                  # rows that are real episodes
        got = _run_chunk(config, act, chunk, start, keep, max_episode_steps, traces, bar)
        sl = slice(start, start + keep)
        out["time"][sl] = got["time"][:keep]
        out["cause"][sl] = got["cause"][:keep]
        out["kept"][sl] = got["cause"][:keep] == "kept"
        out["mean_r"][sl] = got["r_sum"][:keep] / np.maximum(got["steps"][:keep], 1)
        out["effort"][sl] = got["a_sum"][:keep] / np.maximum(got["steps"][:keep], 1)
        out["return"][sl] = got["return"][:keep]
        out["min_normal"][sl] = got["min_normal"][:keep]
        start += keep
    if bar is not None:
        bar.close()
    out["trace_omega"], out["trace_r"] = traces.omega, traces.r
    out["trace_t"] = np.arange(max_episode_steps + 1) * config.control_period
    return out


class PolicyActor:
    """``act(obs, idx)`` for `run_episodes` from a policy with SB3's ``predict``.

    Row-independent policies (the baselines) see only the balls in play; others (model
    files) the whole batch. A state returned by ``predict`` (SB3's recurrent slot, used by
    the ``mpc`` baseline's estimators) is kept per ball and passed back, with
    ``episode_start`` True on each ball's first step.
    """

    def __init__(self, policy: Any):
        self.policy = policy
        self.row_independent = bool(getattr(policy, "row_independent", False))
        self.state: np.ndarray | None = None
        self.fresh = np.ones(0, dtype=bool)

    def start(self, n: int) -> None:
        """Prepare for ``n`` balls, each at the start of an episode."""
        self.state, self.fresh = None, np.ones(n, dtype=bool)

    def __call__(self, obs: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """The policy's actions for the balls ``idx``, keeping each ball's recurrent state."""
        rows = idx if self.row_independent else np.arange(len(obs))
        if len(rows) == 0:
            return np.zeros(0)
        state = None if self.state is None else self.state[rows]
        actions, new_state = self.policy.predict(obs[rows], state=state,
                                                 episode_start=self.fresh[rows],
                                                 deterministic=True)
        if isinstance(new_state, np.ndarray) and new_state.ndim >= 1 and len(new_state) == len(rows):
            if self.state is None:
                self.state = np.zeros((len(obs),) + new_state.shape[1:], dtype=new_state.dtype)
            self.state[rows] = new_state
        self.fresh[rows] = False
        actions = np.asarray(actions).reshape(len(rows))
        return actions if self.row_independent else actions[idx]


def policy_actor(policy: Any) -> tuple[Any, bool]:
    """(actor, row_independent) for `run_episodes`: the policy's own actor if it makes one
    (``clairvoyant``, which reads the environment), else a `PolicyActor`."""
    # not "actor" or "make_actor": SB3 models and policies (SAC, TD3) have those
    if hasattr(policy, "episode_actor"):
        return policy.episode_actor(), bool(getattr(policy, "row_independent", False))
    actor = PolicyActor(policy)
    return actor, actor.row_independent


__all__ = ["CHUNK", "Actor", "PolicyActor", "episode_set", "policy_actor", "run_episodes",
           "same_episodes"]
