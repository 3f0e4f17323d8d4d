"""Warm start by imitation: begin reinforcement learning from a network that does what
``mpc`` does (``warm_start: mpc`` in a recipe).

Why: on the hardest level PPO from a best-constant start plateaus below ``mpc``; its
exploration has to rediscover, from the reward alone, the feedback that the model-based
controller computes. Imitation gives the network that feedback first and RL then improves
on it. At evaluation time the policy is still the network alone: ``mpc`` only labels the
training data.

How (DAgger, Ross, Gordon & Bagnell 2011): round 0 lets ``mpc`` drive and records what it
sees and does; each later round lets the network drive, with ``mpc`` watching the same
observations and saying what it would have done, so the network also learns to recover from
the states its own mistakes lead to. After every round the network's action mean is fitted
to all labels so far (mean squared error; the exploration noise ``log_std`` is left as the
recipe sets it), and its value head to the discounted returns of the episodes recorded
(so PPO's first advantages are not the noise of an untrained critic).

With normalised observations (a recipe's ``normalize``: the model's VecNormalize) the network
sees, during imitation as during RL, the observations through the normaliser: its statistics
are set from round 0's observations (those of ``mpc``'s episodes) before the first fit, and RL
goes on updating them from there. Without this the network would learn from raw
observations and meet normalised ones from RL's first step on.

Episodes use their own seed range (`agents.seeds.IMITATION_SEED`), apart from validation,
test and comparison seeds.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from saddle_env.envs import EnvConfig

from ..seeds import IMITATION_SEED


@dataclass(frozen=True)
class ImitationSettings:
    """The ``imitation`` mapping of a recipe (every key optional)."""

    rounds: int = 3            # round 0: mpc drives; later rounds: the network drives
    episodes: int = 256        # episodes per round (one ball each, run as one batch)
    epochs: int = 8            # passes over all labels so far, after every round
    batch_size: int = 1024
    learning_rate: float = 1e-3
    episode_steps: int | None = None   # control steps per imitation episode (None: the run's)

    @classmethod
    def from_hyper(cls, value: Any) -> ImitationSettings:
        """Settings from a recipe's ``imitation`` value (None or a mapping)."""
        if value is None:
            return cls()
        if not isinstance(value, dict):
            raise ValueError(f"imitation must be a mapping of {sorted(cls.__annotations__)}, "
                             f"got {value!r}")
        unknown = set(value) - set(cls.__annotations__)
        if unknown:
            raise ValueError(f"imitation: unknown keys {sorted(unknown)}; allowed: "
                             f"{sorted(cls.__annotations__)}")
        settings = cls(**value)
        for name in ("rounds", "episodes", "epochs", "batch_size", "episode_steps"):
            v = getattr(settings, name)
            if name == "episode_steps" and v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"imitation.{name} must be a positive integer, got {v!r}")
        lr = settings.learning_rate
        if not (isinstance(lr, (int, float)) and math.isfinite(lr) and lr > 0):
            raise ValueError(f"imitation.learning_rate must be a positive number, got {lr!r}")
        return settings


def _heads(policy: Any, obs: Any) -> tuple[Any, Any]:
    """The action mean (n, 1) and the value (n,) of an SB3 actor-critic policy, through
    the same layers as its ``forward``."""
    features = policy.extract_features(obs)
    if policy.share_features_extractor:
        latent_pi, latent_vf = policy.mlp_extractor(features)
    else:
        latent_pi = policy.mlp_extractor.forward_actor(features[0])
        latent_vf = policy.mlp_extractor.forward_critic(features[1])
    return policy.action_net(latent_pi), policy.value_net(latent_vf).flatten()


def network_actions(policy: Any, obs: np.ndarray) -> np.ndarray:
    """The network's deterministic actions (n,) in [-1, 1] for a batch of observations
    (SB3's own ``predict``: what evaluation runs)."""
    return policy.predict(obs, deterministic=True)[0].astype(np.float64).reshape(-1)


def discounted_returns(rewards: np.ndarray, alive: np.ndarray, kept: np.ndarray,
                       gamma: float) -> np.ndarray:
    """Return-to-go of every recorded step ((steps, n) arrays; ``alive`` marks recorded
    steps). An episode cut by the time limit (``kept``) goes on in the eyes of a value
    function: its tail is continued as its last reward forever, r / (1 − γ)."""
    steps, n = rewards.shape
    out = np.zeros_like(rewards)
    last = np.flatnonzero(alive.any(axis=0))
    tail = np.zeros(n)
    for i in last:
        end = np.flatnonzero(alive[:, i])[-1]
        if kept[i]:
            tail[i] = rewards[end, i] / (1.0 - gamma)
    running = tail.copy()
    for t in range(steps - 1, -1, -1):
        running = np.where(alive[t], rewards[t] + gamma * running, tail)
        out[t] = running
    return out


def record_round(config: EnvConfig, expert: Any, policy: Any | None, seeds: np.ndarray,
                 max_episode_steps: int, gamma: float,
                 view: Callable[[np.ndarray], np.ndarray] | None = None
                 ) -> dict[str, np.ndarray]:
    """One episode per seed with ``policy`` driving (``None``: the expert drives; ``view``:
    what the policy's input is made from the observation, e.g. a normaliser); every
    observation is labelled with the expert's action. Returns the recorded ``obs`` (raw),
    ``action`` (the expert's) and ``ret`` (discounted return-to-go), and per episode
    ``time`` [s] and ``kept``."""
    from saddle_env.envs.vector import SaddleTrapVectorEnv

    n = len(seeds)
    env = SaddleTrapVectorEnv(num_envs=n, max_episode_steps=max_episode_steps,
                              **config.as_dict())
    obs, _ = env.reset(seed=[int(s) for s in seeds])
    state, start = None, np.ones(n, dtype=bool)
    alive = np.ones(n, dtype=bool)
    kept = np.zeros(n, dtype=bool)
    length = np.zeros(n, dtype=np.int64)
    O, A = [], []
    R = np.zeros((max_episode_steps, n))
    M = np.zeros((max_episode_steps, n), dtype=bool)
    for t in range(max_episode_steps):
        label, state = expert.predict(obs, state, episode_start=start)
        label = label.reshape(-1).astype(np.float64)
        action = label if policy is None else \
            network_actions(policy, obs if view is None else view(obs))
        if policy is not None:   # the expert's estimators must know what the motor was told
            state = expert.executed(state, action)
        O.append(obs[alive])
        A.append(label[alive])
        M[t] = alive
        obs, reward, terminated, truncated, _ = env.step(action.astype(np.float32).reshape(-1, 1))
        R[t] = np.where(alive, reward, 0.0)
        length += alive
        kept |= alive & truncated & ~terminated
        alive &= ~(terminated | truncated)
        start = np.zeros(n, dtype=bool)
        if not alive.any():
            break
    env.close()
    ret = discounted_returns(R, M, kept, gamma)
    return {"obs": np.concatenate(O), "action": np.concatenate(A),
            "ret": ret[M],
            "time": length * config.control_period, "kept": kept}


def fit(policy: Any, obs: np.ndarray, action: np.ndarray, ret: np.ndarray,
        settings: ImitationSettings, rng: np.random.Generator) -> dict[str, float]:
    """Fit the action mean to ``action`` and the value to ``ret`` (mean squared errors);
    the policy's ``log_std`` is not touched. Returns the final losses."""
    import torch

    params = [p for name, p in policy.named_parameters() if name != "log_std"]
    optimizer = torch.optim.Adam(params, lr=settings.learning_rate)
    O = torch.as_tensor(obs, dtype=torch.float32)
    A = torch.as_tensor(action, dtype=torch.float32).reshape(-1, 1)
    G = torch.as_tensor(ret, dtype=torch.float32)
    scale = float(max(np.var(ret), 1e-6))   # value loss in units of the returns' variance
    n = len(O)
    losses = {"action_mse": math.nan, "value_mse": math.nan}
    for _ in range(settings.epochs):
        order = torch.as_tensor(rng.permutation(n))
        sum_a = sum_v = 0.0
        for k in range(0, n, settings.batch_size):
            idx = order[k:k + settings.batch_size]
            mean, value = _heads(policy, O[idx])
            loss_a = torch.mean((mean - A[idx]) ** 2)
            loss_v = torch.mean((value - G[idx]) ** 2)
            optimizer.zero_grad()
            (loss_a + loss_v / scale).backward()
            optimizer.step()
            sum_a += float(loss_a.detach()) * len(idx)
            sum_v += float(loss_v.detach()) * len(idx)
        losses = {"action_mse": sum_a / n, "value_mse": sum_v / n}
    return losses


def observation_normaliser(model: Any) -> Any | None:
    """The model's VecNormalize if it normalises observations, else None."""
    get = getattr(model, "get_vec_normalize_env", None)
    norm = get() if callable(get) else None
    return norm if norm is not None and getattr(norm, "norm_obs", False) else None


def set_statistics(norm: Any, obs: np.ndarray) -> None:
    """Set the VecNormalize ``norm``'s observation statistics to those of ``obs`` (n, d), as
    if it had seen exactly these observations."""
    if obs.ndim != 2 or len(obs) < 2 or not np.all(np.isfinite(obs)):
        raise ValueError(f"observation statistics need a finite (n >= 2, d) array, got shape "
                         f"{obs.shape}")
    rms = norm.obs_rms
    if tuple(rms.mean.shape) != obs.shape[1:]:
        raise ValueError(f"the normaliser holds {rms.mean.shape} statistics, the observations "
                         f"are {obs.shape[1:]}")
    rms.mean = obs.mean(axis=0).astype(np.float64)
    rms.var = obs.var(axis=0).astype(np.float64)
    rms.count = float(len(obs))


def imitate(model: Any, config: EnvConfig, max_episode_steps: int, seed: int,
            settings: ImitationSettings, log: Any = print) -> list[dict[str, float | int | str]]:
    """DAgger warm start of the SB3 actor-critic ``model`` (PPO, A2C) on ``config``
    (run ``seed`` picks a disjoint block of imitation seeds). Returns one summary per
    round: the driver's mean trapping time and kept fraction, the labels so far, the
    losses."""
    from ..control.mpc import ModelPredictiveController

    policy = getattr(model, "policy", None)
    if policy is None or not hasattr(policy, "action_net") or not hasattr(policy, "value_net"):
        raise ValueError(f"warm_start 'mpc' works for PPO and A2C (an actor-critic with an "
                         f"action head), not for {type(model).__name__}")
    expert = ModelPredictiveController(config)
    gamma = float(getattr(model, "gamma", 0.99))
    rng = np.random.default_rng(seed)
    per_run = settings.rounds * settings.episodes
    data: dict[str, list[np.ndarray]] = {"obs": [], "action": [], "ret": []}
    history = []
    if settings.episode_steps is not None:   # shorter episodes: fewer mpc queries per round
        max_episode_steps = min(max_episode_steps, settings.episode_steps)
    norm = observation_normaliser(model)
    view = None if norm is None else norm.normalize_obs
    policy.set_training_mode(False)
    for r in range(settings.rounds):
        first = IMITATION_SEED + seed * per_run + r * settings.episodes
        seeds = np.arange(first, first + settings.episodes)
        rec = record_round(config, expert, None if r == 0 else policy, seeds,
                           max_episode_steps, gamma, view)
        if r == 0 and norm is not None:   # the normaliser's statistics: mpc's observations
            set_statistics(norm, rec["obs"])
        for key, labels in data.items():
            labels.append(rec[key])
        policy.set_training_mode(True)
        obs, action, ret = (np.concatenate(data[k]) for k in ("obs", "action", "ret"))
        losses = fit(policy, obs if view is None else view(obs), action, ret, settings, rng)
        policy.set_training_mode(False)
        summary = {"round": r, "driver": "mpc" if r == 0 else "network",
                   "mean_time": float(np.mean(rec["time"])), "kept": float(np.mean(rec["kept"])),
                   "labels": int(sum(len(a) for a in data["action"])), **losses}
        history.append(summary)
        log(f"imitation round {r}: {summary['driver']} drove, mean {summary['mean_time']:.2f} s, "
            f"kept {summary['kept']:.0%}; {summary['labels']} labels, action mse "
            f"{summary['action_mse']:.4f}")
    return history


__all__ = ["ImitationSettings", "discounted_returns", "fit", "imitate", "network_actions",
           "observation_normaliser", "record_round", "set_statistics"]
