"""Where a training run's time goes: ``python -m agents.benchmark.profile_training``.

Runs a short training (the main job's recipe unless told otherwise, through
`agents.training.trainer.train`, so with its callbacks, evaluation and model selection) on SB3
(PPO, SAC, TD3, A2C), SBX (PPO on JAX, `--backend sbx`) or RLlib (PPO, SAC; its env runner in this
process, ``num_env_runners=0``, so that every piece is in reach of the timers) and, with
``--imitation``, a few DAgger rounds of the imitation warm start, with timers around the
pieces of one iteration:

The categories, and what each times:

- *env stepping*: the batch env's ``step_wait`` / ``step`` (the compiled physics and its
  Python shell); RLlib: ``EnvRunner._try_env_step``.
- *policy forward*: the rollout's ``policy(obs)`` and ``predict_values`` (SB3 on-policy),
  ``_sample_action`` (SB3 off-policy), ``forward_exploration`` (RLlib), the network's actions
  (imitation).
- *advantages (GAE)*: ``RolloutBuffer.compute_returns_and_advantage``; RLlib: its GAE connector
  (the value forward included).
- *gradient updates*: the algorithm's ``train`` (SB3: every epoch and minibatch), RLlib's
  ``TorchLearner._update``, imitation's ``fit``.
- *evaluation + selection*: the selection's evaluations (`agents.training.selection`: the
  snapshots on the validation episodes, the best few again on fresh ones at the end) and
  model saves (snapshots, checkpoints); RLlib: its checkpoints (it does not select).
- *mpc queries*: ``ModelPredictiveController.predict`` and ``executed`` (imitation labels).
- *warm start*: the best-constant search or cache read that sets the starting action.
- *start-up*: building the environments and the model; RLlib: starting Ray and building the
  algorithm.
- *other*: the rest of the wall time: the rollout loop (tensor conversion, buffer adds,
  callbacks), RLlib's connectors and metrics.

A timer inside another timed section does not count: the outer one has it (an evaluation's
env steps are evaluation). The closing comparison (``compare_episodes``) is left out.

    python -m agents.benchmark.profile_training                         # main job's recipe, 6e5 steps
    python -m agents.benchmark.profile_training --algo sac --total-timesteps 60000 --eval-freq 15000
    python -m agents.benchmark.profile_training --backend sbx           # needs the [sbx] extra
    python -m agents.benchmark.profile_training --backend rllib         # needs the [rllib] extra
    python -m agents.benchmark.profile_training --imitation --rounds 2 --episodes 64
    python -m agents.benchmark.profile_training --hyperparams my.yml --total-timesteps 300000

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
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..training.runs import RunSettings

CATEGORIES = ("env stepping", "policy forward", "advantages (GAE)", "gradient updates",
              "evaluation + selection", "mpc queries", "warm start", "start-up", "other")


class Timers:
    """Wall time per category; only the outermost timed call counts."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._depth = 0
        self._patches: list[tuple[Any, str, Any]] = []

    def wrap(self, owner: Any, name: str, category: str) -> None:
        """Time every call of ``owner.name`` under ``category`` until `restore`."""
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
        """Put back every method that `wrap` replaced."""
        for owner, name, original in reversed(self._patches):
            if original is None:
                delattr(owner, name)
            else:
                setattr(owner, name, original)
        self._patches.clear()

    def table(self, wall: float) -> list[dict[str, Any]]:
        """Seconds, share of ``wall`` and calls per category; "other" is the untimed rest."""
        rows = []
        timed = sum(self.seconds.values())
        for cat in CATEGORIES:
            sec = wall - timed if cat == "other" else self.seconds.get(cat, 0.0)
            rows.append({"category": cat, "seconds": round(sec, 2),
                         "share": round(sec / wall, 4) if wall > 0 else 0.0,
                         "calls": self.calls.get(cat, 0)})
        return rows


def markdown(rows: list[dict[str, Any]], wall: float, title: str) -> str:
    """The rows of `Timers.table` as a Markdown table under ``title``."""
    out = [f"**{title}** — wall {wall:.1f} s", "",
           "| part | seconds | share | calls |", "|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['category']} | {r['seconds']:.1f} | {100 * r['share']:.1f} % "
                   f"| {r['calls']:,} |")
    return "\n".join(out)


def _sb3_loop_timers() -> Timers:
    """Timers around what the SB3 back end's loop does with either learner (SB3's own or
    SBX's): the batch env, the rollout buffer's GAE, evaluations and saves, the warm start,
    building the environments."""
    from stable_baselines3.common import base_class
    from stable_baselines3.common.buffers import RolloutBuffer

    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    from ..training import selection, warm_start
    from ..training.backends import sb3 as sb3_backend

    t = Timers()
    t.wrap(SaddleTrapSB3VecEnv, "step_wait", "env stepping")
    t.wrap(RolloutBuffer, "compute_returns_and_advantage", "advantages (GAE)")
    t.wrap(selection.Selection, "offer", "evaluation + selection")
    t.wrap(selection.Selection, "choose", "evaluation + selection")
    t.wrap(base_class.BaseAlgorithm, "save", "evaluation + selection")
    t.wrap(warm_start, "warm_start", "warm start")
    t.wrap(sb3_backend, "make_vec_env", "start-up")
    return t


def _sb3_timers(algo: str) -> Timers:
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
    from stable_baselines3.common.policies import ActorCriticPolicy

    from ..training.backends import sb3 as sb3_backend
    from ..training.backends.sb3 import algo_class

    t = _sb3_loop_timers()
    t.wrap(ActorCriticPolicy, "forward", "policy forward")            # PPO, A2C rollouts
    t.wrap(ActorCriticPolicy, "predict_values", "policy forward")
    t.wrap(OffPolicyAlgorithm, "_sample_action", "policy forward")    # SAC, TD3 collection
    t.wrap(algo_class(algo), "train", "gradient updates")
    t.wrap(sb3_backend, "_new_model", "start-up")
    return t


def _sbx_timers() -> Timers:
    """Timers around SBX's PPO (JAX) in the SB3 back end's loop (`agents.training.backends.sbx`):
    its rollout's ``predict_all``, its ``train``; saves include copying the flax network into
    the SB3 twin that is written, and checkpoints the learner state."""
    from sbx import PPO
    from sbx.ppo.policies import PPOPolicy

    from ..training.backends import sbx as sbx_backend

    t = _sb3_loop_timers()
    t.wrap(PPOPolicy, "predict_all", "policy forward")
    t.wrap(PPO, "train", "gradient updates")
    t.wrap(sbx_backend.SbxLearner, "save", "evaluation + selection")
    t.wrap(sbx_backend.SbxLearner, "checkpoint", "evaluation + selection")
    t.wrap(sbx_backend.SbxLearner, "new_model", "start-up")
    return t


def _rllib_timers() -> Timers:
    """Timers around RLlib's pieces in the driver process: with no remote env runners
    (``num_env_runners=0``) the sampling runs there too, so every part is timed."""
    from ray.rllib.algorithms.algorithm_config import AlgorithmConfig
    from ray.rllib.connectors.learner.general_advantage_estimation import (
        GeneralAdvantageEstimation,
    )
    from ray.rllib.core.learner.torch.torch_learner import TorchLearner
    from ray.rllib.core.rl_module.torch.torch_rl_module import TorchRLModule
    from ray.rllib.env.env_runner import EnvRunner

    from ..training.backends import rllib as rllib_backend

    t = Timers()
    t.wrap(EnvRunner, "_try_env_step", "env stepping")
    t.wrap(TorchRLModule, "forward_exploration", "policy forward")
    t.wrap(GeneralAdvantageEstimation, "__call__", "advantages (GAE)")  # values + GAE
    t.wrap(TorchLearner, "_update", "gradient updates")               # every minibatch
    t.wrap(rllib_backend, "save_checkpoint", "evaluation + selection")
    t.wrap(rllib_backend, "init_ray", "start-up")
    t.wrap(AlgorithmConfig, "build_algo", "start-up")
    return t


def _timed_train(settings: Any, timers: Timers) -> tuple[float, int, RunSettings]:
    """Wall seconds of `agents.training.trainer.train` (no closing comparison) under ``timers``,
    the env steps it trained (whole rollouts or iterations: at least the budget) and the
    settings the run resolved and recorded (its ``config.json``: the recipe's counts)."""
    from ..training.run_report import read_curve
    from ..training.runs import settings_of_run
    from ..training.trainer import train

    start = time.perf_counter()
    try:
        run_dir = train(settings)
    finally:
        wall = time.perf_counter() - start
        timers.restore()
    curve = read_curve(run_dir)
    done = int(curve["timesteps"][-1]) if curve is not None else 0
    return wall, max(done, int(settings.total_timesteps)), settings_of_run(run_dir)


def profile_training(env_id: str, total_timesteps: int, eval_freq: int | None,
                     hyperparams: str | None, seed: int = 0, n_envs: int | None = None,
                     run_name: str | None = None, algo: str = "ppo",
                     backend: str = "sb3") -> dict[str, Any]:
    """Time the pieces of a short `agents.training.trainer.train` run of ``algo`` on ``backend``.
    RLlib runs with its env runner in the driver process (``num_env_runners=0``), where
    the timers can see it; its PPO has no separate evaluation (the curve is the training
    episodes'), so "evaluation + selection" is its checkpoint saves."""
    from ..training.trainer import TrainSettings

    with tempfile.TemporaryDirectory() as tmp:
        settings = TrainSettings(env_id=env_id, seed=seed, total_timesteps=total_timesteps,
                                 eval_freq=eval_freq, hyperparams=hyperparams, n_envs=n_envs,
                                 log_dir=tmp, run_name=run_name or "profile", algo=algo,
                                 backend=backend, num_cpus=2 if backend == "rllib" else None,
                                 num_env_runners=0 if backend == "rllib" else None,
                                 progress_bar=False, compare_episodes=0).validate()
        timers = (_rllib_timers() if backend == "rllib" else _sbx_timers()
                  if backend == "sbx" else _sb3_timers(algo))
        wall, steps, recorded = _timed_train(settings, timers)
        used = dict(recorded.hyperparams_used)
    return {"path": f"{backend}-{algo}", "env_id": env_id, "total_timesteps": steps,
            "eval_freq": recorded.eval_freq, "n_envs": recorded.n_envs,
            "hyperparams": {k: str(v) for k, v in used.items()},
            "wall": wall, "steps_per_s": steps / wall, "rows": timers.table(wall)}


def profile_imitation(env_id: str, rounds: int, episodes: int, epochs: int = 10,
                      seed: int = 0) -> dict[str, Any]:
    """Time the pieces of ``rounds`` DAgger rounds of ``episodes`` episodes on ``env_id``
    (the level's PPO recipe's network)."""
    import torch
    from stable_baselines3 import PPO

    from saddle_env.envs.vector import SaddleTrapVectorEnv

    from ..cli_args import resolve_env
    from ..control.mpc import ModelPredictiveController
    from ..training import imitation
    from ..training.backends.sb3 import make_vec_env
    from ..training.recipes import load_hyperparams, parse_policy_kwargs

    torch.set_num_threads(1)
    level, config = resolve_env(env_id, {})
    hyper = load_hyperparams("ppo", env_id)
    env = make_vec_env(4, seed, config, level.max_episode_steps)
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
    """Run the command line; returns the exit status."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--env", default="SaddleTrap-Capture-v0", metavar="ID",
                    help="the task level to train on (an id of saddle_env.LEVELS)")
    ap.add_argument("--total-timesteps", type=int, default=600_000,
                    help="length of the profiled training in env steps")
    ap.add_argument("--eval-freq", type=int, default=150_000,
                    help="steps between evaluations (the main job's: a twentieth of 3e6)")
    ap.add_argument("--algo", default="ppo", choices=("ppo", "sac", "td3", "a2c"),
                    help="the learning algorithm (sbx and rllib: ppo; rllib also sac)")
    ap.add_argument("--backend", default="sb3", choices=("sb3", "sbx", "rllib"),
                    help="sbx: SBX's PPO (JAX, the [sbx] extra); rllib: RLlib's PPO or SAC "
                         "with its env runner in this process")
    ap.add_argument("--hyperparams", default=None, metavar="FILE.yml",
                    help="the recipe (None: the back end's file in agents/hyperparams/)")
    ap.add_argument("--n-envs", type=int, default=None,
                    help="balls stepped together (None: the recipe's n_envs)")
    ap.add_argument("--imitation", action="store_true",
                    help="profile the imitation rounds instead of PPO")
    ap.add_argument("--rounds", type=int, default=2,
                    help="--imitation: DAgger rounds to profile")
    ap.add_argument("--episodes", type=int, default=64,
                    help="--imitation: episodes recorded per round")
    ap.add_argument("--epochs", type=int, default=10,
                    help="--imitation: passes over the recorded data per round")
    ap.add_argument("--json", default=None, metavar="FILE",
                    help="also write the table, the wall time and the command as JSON")
    args = ap.parse_args(argv)
    if args.imitation:
        result = profile_imitation(args.env, args.rounds, args.episodes, args.epochs)
        title = (f"imitation on {args.env}: {args.rounds} rounds x {args.episodes} episodes, "
                 f"{args.epochs} epochs")
    else:
        result = profile_training(args.env, args.total_timesteps, args.eval_freq,
                                  args.hyperparams, n_envs=args.n_envs, algo=args.algo,
                                  backend=args.backend)
        name = {"sb3": "SB3", "sbx": "SBX", "rllib": "RLlib"}[args.backend]
        title = (f"{name} {args.algo.upper()} on "
                 f"{args.env}: {result['total_timesteps']:,} steps, evaluation every "
                 f"{result['eval_freq']:,}; {result['steps_per_s']:,.0f} steps/s overall")
    result["command"] = "python -m agents.benchmark.profile_training " + " ".join(argv or sys.argv[1:])
    print(markdown(result["rows"], result["wall"], title))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
