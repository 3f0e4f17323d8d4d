"""Where a training run's time goes: ``python -m agents.profile_training``.

Runs a short SB3 PPO training (the main job's recipe unless told otherwise, through
`agents.training.train`, so with its callbacks, evaluation and model selection) and,
with ``--imitation``, a few DAgger rounds of the imitation warm start, with timers around
the pieces of one iteration:

| category | what is timed |
|---|---|
| env stepping | the batch env's ``step_wait`` / ``step`` (the compiled physics and its Python shell) |
| policy forward | the rollout's ``policy(obs)`` and ``predict_values`` (SB3), the network's actions (imitation) |
| advantages (GAE) | ``RolloutBuffer.compute_returns_and_advantage`` |
| gradient updates | ``PPO.train`` (every epoch and minibatch), imitation's ``fit`` |
| evaluation + selection | ``evaluate_policy`` inside the selection callback, and model saves (selected model, checkpoints) |
| mpc queries | ``ModelPredictiveController.predict`` and ``executed`` (imitation labels) |
| warm start | the best-constant search or cache read that sets the starting action |
| other | the rest of the wall time: SB3's rollout loop (tensor conversion, buffer adds, callbacks, progress) |

A timer inside another timed section does not count: the outer one has it (an evaluation's
env steps are evaluation). The closing comparison (``compare_episodes``) is left out.

    python -m agents.profile_training                         # main job's recipe, 6e5 steps
    python -m agents.profile_training --imitation --rounds 2 --episodes 64
    python -m agents.profile_training --hyperparams my.yml --total-timesteps 300000

Prints a Markdown table (also written as JSON with ``--json FILE``).
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import tempfile
import time
from collections import defaultdict
from typing import Any

CATEGORIES = ("env stepping", "policy forward", "advantages (GAE)", "gradient updates",
              "evaluation + selection", "mpc queries", "warm start", "other")


class Timers:
    """Wall time per category; only the outermost timed call counts."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._depth = 0
        self._patches: list[tuple[Any, str, Any]] = []

    def wrap(self, owner: Any, name: str, category: str) -> None:
        original = getattr(owner, name)
        timers = self

        @functools.wraps(original)
        def timed(*args, **kwargs):
            if timers._depth:
                return original(*args, **kwargs)
            timers._depth += 1
            start = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                timers.seconds[category] += time.perf_counter() - start
                timers.calls[category] += 1
                timers._depth -= 1

        self._patches.append((owner, name, owner.__dict__.get(name, None)))
        setattr(owner, name, timed)

    def restore(self) -> None:
        for owner, name, original in reversed(self._patches):
            if original is None:
                delattr(owner, name)
            else:
                setattr(owner, name, original)
        self._patches.clear()

    def table(self, wall: float) -> list[dict[str, Any]]:
        rows = []
        timed = sum(self.seconds.values())
        for cat in CATEGORIES:
            sec = wall - timed if cat == "other" else self.seconds.get(cat, 0.0)
            rows.append({"category": cat, "seconds": round(sec, 2),
                         "share": round(sec / wall, 4) if wall > 0 else 0.0,
                         "calls": self.calls.get(cat, 0)})
        return rows


def markdown(rows: list[dict[str, Any]], wall: float, title: str) -> str:
    out = [f"**{title}** — wall {wall:.1f} s", "",
           "| part | seconds | share | calls |", "|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['category']} | {r['seconds']:.1f} | {100 * r['share']:.1f} % "
                   f"| {r['calls']:,} |")
    return "\n".join(out)


def _sb3_timers() -> Timers:
    from stable_baselines3 import PPO
    from stable_baselines3.common import base_class, callbacks
    from stable_baselines3.common.buffers import RolloutBuffer
    from stable_baselines3.common.policies import ActorCriticPolicy

    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    from . import warm_start

    t = Timers()
    t.wrap(SaddleTrapSB3VecEnv, "step_wait", "env stepping")
    t.wrap(ActorCriticPolicy, "forward", "policy forward")
    t.wrap(ActorCriticPolicy, "predict_values", "policy forward")
    t.wrap(RolloutBuffer, "compute_returns_and_advantage", "advantages (GAE)")
    t.wrap(PPO, "train", "gradient updates")
    t.wrap(callbacks, "evaluate_policy", "evaluation + selection")
    t.wrap(base_class.BaseAlgorithm, "save", "evaluation + selection")
    t.wrap(warm_start, "warm_start", "warm start")
    return t


def profile_sb3(env_id: str, total_timesteps: int, eval_freq: int | None,
                hyperparams: str | None, seed: int = 0, n_envs: int | None = None,
                run_name: str | None = None) -> dict[str, Any]:
    """Time the pieces of a short `agents.training.train` run (no closing comparison)."""
    from .training import TrainSettings, train

    timers = _sb3_timers()
    with tempfile.TemporaryDirectory() as tmp:
        settings = TrainSettings(env_id=env_id, seed=seed, total_timesteps=total_timesteps,
                                 eval_freq=eval_freq, hyperparams=hyperparams, n_envs=n_envs,
                                 log_dir=tmp, run_name=run_name or "profile",
                                 progress_bar=False, compare_episodes=0).validate()
        start = time.perf_counter()
        try:
            train(settings)
        finally:
            wall = time.perf_counter() - start
            timers.restore()
        used = dict(settings.hyperparams_used)
    return {"path": "sb3-ppo", "env_id": env_id, "total_timesteps": total_timesteps,
            "eval_freq": settings.eval_freq, "n_envs": settings.n_envs,
            "hyperparams": {k: str(v) for k, v in used.items()},
            "wall": wall, "steps_per_s": total_timesteps / wall,
            "rows": timers.table(wall)}


def profile_imitation(env_id: str, rounds: int, episodes: int, epochs: int = 10,
                      seed: int = 0) -> dict[str, Any]:
    """Time the pieces of ``rounds`` DAgger rounds of ``episodes`` episodes on ``env_id``
    (the level's PPO recipe's network)."""
    import torch
    from stable_baselines3 import PPO

    from saddle_env.envs.vector import SaddleTrapVectorEnv

    from . import imitation
    from .cli_args import resolve_env
    from .mpc import ModelPredictiveController
    from .recipes import load_hyperparams, parse_policy_kwargs
    from .sb3_backend import make_vec_env

    torch.set_num_threads(1)
    level, config = resolve_env(env_id, {})
    hyper = load_hyperparams("ppo", env_id)
    env = make_vec_env(4, seed, {}, level.max_episode_steps, env_id)
    model = PPO("MlpPolicy", env, seed=seed, device="cpu", gamma=hyper.get("gamma", 0.99),
                policy_kwargs=parse_policy_kwargs(hyper.get("policy_kwargs")))
    ModelPredictiveController(config)          # best-const cache / numba compile, untimed
    t = Timers()
    t.wrap(SaddleTrapVectorEnv, "step", "env stepping")
    t.wrap(imitation, "network_actions", "policy forward")
    t.wrap(imitation, "fit", "gradient updates")
    t.wrap(ModelPredictiveController, "predict", "mpc queries")
    t.wrap(ModelPredictiveController, "executed", "mpc queries")
    settings = imitation.ImitationSettings(rounds=rounds, episodes=episodes, epochs=epochs)
    start = time.perf_counter()
    try:
        imitation.imitate(model, config, level.max_episode_steps, seed, settings,
                          log=lambda s: print(s, file=sys.stderr))
    finally:
        wall = time.perf_counter() - start
        t.restore()
    env.close()
    return {"path": "imitation (DAgger)", "env_id": env_id, "rounds": rounds,
            "episodes": episodes, "epochs": epochs, "wall": wall, "rows": t.table(wall)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--env", default="SaddleTrap-Capture-v0", metavar="ID")
    ap.add_argument("--total-timesteps", type=int, default=600_000)
    ap.add_argument("--eval-freq", type=int, default=150_000,
                    help="steps between evaluations (the main job's: a twentieth of 3e6)")
    ap.add_argument("--hyperparams", default=None, metavar="FILE.yml")
    ap.add_argument("--n-envs", type=int, default=None)
    ap.add_argument("--imitation", action="store_true",
                    help="profile the imitation rounds instead of PPO")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--episodes", type=int, default=64)
    ap.add_argument("--epochs", type=int, default=10)
    ap.add_argument("--json", default=None, metavar="FILE")
    args = ap.parse_args(argv)
    if args.imitation:
        result = profile_imitation(args.env, args.rounds, args.episodes, args.epochs)
        title = (f"imitation on {args.env}: {args.rounds} rounds x {args.episodes} episodes, "
                 f"{args.epochs} epochs")
    else:
        result = profile_sb3(args.env, args.total_timesteps, args.eval_freq, args.hyperparams,
                             n_envs=args.n_envs)
        title = (f"SB3 PPO on {args.env}: {args.total_timesteps:,} steps, evaluation every "
                 f"{result['eval_freq']:,}; {result['steps_per_s']:,.0f} steps/s overall")
    result["command"] = "python -m agents.profile_training " + " ".join(argv or sys.argv[1:])
    print(markdown(result["rows"], result["wall"], title))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
