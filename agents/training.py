"""Training SB3 agents on SaddleTrap-v0 (the logic behind ``train.py``).

The environment is stepped through the batch adapter (`saddle_env.envs.sb3`), so all
``n_envs`` balls advance in one compiled call. Hyperparameters come from YAML files keyed by
environment id (rl-baselines3-zoo format, ``agents/hyperparams/<algo>.yml``).

Every run writes to its own folder: ``config.json`` (everything needed to rebuild the
environment and resume), TensorBoard logs, ``progress.csv``, ``evaluations.npz``,
``best_model.zip``, ``checkpoints/`` and ``final_model.zip`` with a ``.json`` sidecar that
records the environment options the model was trained on, and ``learning_curve.png``.
Ctrl-C or SIGTERM saves a checkpoint (and the replay buffer of off-policy algorithms);
``--resume CHECKPOINT.zip`` continues from it.
"""

from __future__ import annotations

import ast
import json
import signal
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ENV_ID = "SaddleTrap-v0"
HYPERPARAMS_DIR = Path(__file__).parent / "hyperparams"
ALGO_NAMES = ("ppo", "sac", "td3", "a2c")
# Keys of the zoo format that are not constructor arguments of the algorithm.
ZOO_ONLY_KEYS = {"n_envs", "n_timesteps", "policy", "noise_type", "noise_std", "normalize",
                 "env_wrapper", "frame_stack", "callback"}


def algo_class(name: str):
    from stable_baselines3 import A2C, PPO, SAC, TD3

    classes = {"ppo": PPO, "sac": SAC, "td3": TD3, "a2c": A2C}
    if name not in classes:
        raise ValueError(f"algo must be one of {sorted(classes)}, got {name!r}")
    return classes[name]


@dataclass
class TrainSettings:
    """What a run needs; saved as ``config.json`` in the run folder."""

    algo: str = "ppo"
    env_id: str = ENV_ID
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    n_envs: int | None = None
    total_timesteps: int | None = None
    hyperparams: str | None = None
    log_dir: str = "runs"
    run_name: str | None = None
    eval_freq: int = 20_000
    eval_episodes: int = 32
    save_freq: int = 50_000
    max_episode_steps: int = 500
    progress_bar: bool = True
    device: str = "cpu"
    # One torch thread: small MLPs gain nothing from more, and on a 2-core machine extra
    # threads fight the environment for the cores (PPO measured 2,900 steps/s with 1 thread,
    # 200 with 2, on a loaded machine).
    torch_threads: int = 1
    hyperparams_used: dict[str, Any] = field(default_factory=dict)


# ---------------------------------------------------------------------------------------
# hyperparameters
# ---------------------------------------------------------------------------------------
def load_hyperparams(algo: str, env_id: str = ENV_ID, path: str | Path | None = None) -> dict[str, Any]:
    """The entry for ``env_id`` in the algorithm's YAML file (zoo format)."""
    file = Path(path) if path else HYPERPARAMS_DIR / f"{algo}.yml"
    if not file.is_file():
        raise ValueError(f"hyperparams file not found: {file}")
    data = yaml.safe_load(file.read_text()) or {}
    if env_id not in data:
        raise ValueError(f"{file} has no entry for {env_id!r} (has: {sorted(data)})")
    return dict(data[env_id])


def parse_policy_kwargs(value: Any) -> dict[str, Any]:
    """Policy kwargs from YAML: a mapping, or the zoo's string form ``"dict(net_arch=[64, 64])"``
    (evaluated with only ``dict`` and torch.nn activations in scope; no builtins)."""
    if value is None:
        return {}
    if isinstance(value, dict):
        return value
    if not isinstance(value, str):
        raise ValueError(f"policy_kwargs must be a mapping or a string, got {value!r}")
    import torch.nn as nn

    tree = ast.parse(value, mode="eval")
    allowed = (ast.Expression, ast.Call, ast.Name, ast.Load, ast.keyword, ast.Constant,
               ast.List, ast.Tuple, ast.Dict, ast.Attribute, ast.UnaryOp, ast.USub)
    for node in ast.walk(tree):
        if not isinstance(node, allowed):
            raise ValueError(f"policy_kwargs: unsupported syntax {type(node).__name__} in {value!r}")
    try:
        result = eval(compile(tree, "<policy_kwargs>", "eval"), {"__builtins__": {}},  # noqa: S307
                      {"dict": dict, "nn": nn})
    except Exception as exc:  # a name outside dict/nn, a bad call, ...
        raise ValueError(f"policy_kwargs: cannot evaluate {value!r}: {exc}") from None
    if not isinstance(result, dict):
        raise ValueError(f"policy_kwargs must evaluate to a dict, got {type(result).__name__}")
    return result


def parse_env_kwargs(pairs: list[str] | None) -> dict[str, Any]:
    """``key=value`` (or the zoo's ``key:value``) pairs; values are read as YAML."""
    out: dict[str, Any] = {}
    for pair in pairs or []:
        sep = "=" if "=" in pair else ":"
        key, _, raw = pair.partition(sep)
        if not key or not _:
            raise ValueError(f"--env-kwargs items must look like key=value, got {pair!r}")
        value = yaml.safe_load(raw)
        if isinstance(value, list):
            value = tuple(value)
        out[key.strip()] = value
    return out


# ---------------------------------------------------------------------------------------
# environments
# ---------------------------------------------------------------------------------------
def make_vec_env(n_envs: int, seed: int, env_kwargs: dict[str, Any], max_episode_steps: int):
    """The batch environment for SB3, with episode statistics (VecMonitor)."""
    from stable_baselines3.common.vec_env import VecMonitor

    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    env = SaddleTrapSB3VecEnv(num_envs=n_envs, max_episode_steps=max_episode_steps, **env_kwargs)
    env.seed(seed)
    return VecMonitor(env)


def _action_noise(hyper: dict[str, Any]):
    kind = hyper.get("noise_type")
    if kind is None:
        return None
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

    std = float(hyper.get("noise_std", 0.1))
    cls = {"normal": NormalActionNoise, "ornstein-uhlenbeck": OrnsteinUhlenbeckActionNoise}.get(kind)
    if cls is None:
        raise ValueError(f"noise_type must be 'normal' or 'ornstein-uhlenbeck', got {kind!r}")
    return cls(mean=np.zeros(1), sigma=std * np.ones(1))


# ---------------------------------------------------------------------------------------
# training
# ---------------------------------------------------------------------------------------
class _Stop(Exception):
    """Raised in the main thread by SIGTERM so the run can checkpoint and exit."""


def _save_checkpoint(model, folder: Path, tag: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{tag}_{model.num_timesteps}_steps.zip"
    model.save(path)
    if hasattr(model, "replay_buffer") and model.replay_buffer is not None:
        model.save_replay_buffer(path.with_suffix(".replay.pkl"))
    return path


def write_sidecar(model_path: Path, settings: TrainSettings) -> None:
    """Record what a saved model was trained on, for evaluation tools."""
    sidecar = {"algo": settings.algo, "env_id": settings.env_id,
               "env_kwargs": settings.env_kwargs, "max_episode_steps": settings.max_episode_steps,
               "seed": settings.seed}
    model_path.with_suffix(".json").write_text(json.dumps(sidecar, indent=2, default=list))


def train(settings: TrainSettings, resume: str | Path | None = None) -> Path:
    """Train (or resume) an agent; return the run folder."""
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback, EvalCallback
    from stable_baselines3.common.logger import configure

    import torch

    torch.set_num_threads(settings.torch_threads)
    cls = algo_class(settings.algo)
    hyper = load_hyperparams(settings.algo, settings.env_id, settings.hyperparams)
    settings.hyperparams_used = hyper
    n_envs = int(settings.n_envs or hyper.get("n_envs", 8))
    total = int(settings.total_timesteps or float(hyper.get("n_timesteps", 1e5)))
    if n_envs < 1 or total < 1:
        raise ValueError("n_envs and total_timesteps must be positive")
    settings.n_envs, settings.total_timesteps = n_envs, total
    name = settings.run_name or f"{settings.algo}_seed{settings.seed}_{time.strftime('%Y%m%d-%H%M%S')}"
    run_dir = Path(settings.log_dir) / name
    if resume is not None:
        run_dir = Path(resume).resolve().parent.parent
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.json").write_text(json.dumps(asdict(settings), indent=2, default=list))

    env = make_vec_env(n_envs, settings.seed, settings.env_kwargs, settings.max_episode_steps)
    eval_env = make_vec_env(min(settings.eval_episodes, 16), settings.seed + 10_000,
                            settings.env_kwargs, settings.max_episode_steps)
    if resume is not None:
        model = cls.load(resume, env=env, device=settings.device)
        buffer = Path(resume).with_suffix(".replay.pkl")
        if hasattr(model, "load_replay_buffer") and buffer.is_file():
            model.load_replay_buffer(buffer)
    else:
        kwargs = {k: v for k, v in hyper.items() if k not in ZOO_ONLY_KEYS}
        kwargs["policy_kwargs"] = parse_policy_kwargs(kwargs.get("policy_kwargs"))
        noise = _action_noise(hyper)
        if noise is not None:
            kwargs["action_noise"] = noise
        model = cls(hyper.get("policy", "MlpPolicy"), env, seed=settings.seed,
                    device=settings.device, verbose=0, **kwargs)
    model.set_logger(configure(str(run_dir), ["csv", "tensorboard"]))
    per_env = lambda steps: max(1, steps // n_envs)  # noqa: E731  (callbacks count vec steps)
    callbacks = CallbackList([
        CheckpointCallback(per_env(settings.save_freq), str(run_dir / "checkpoints"),
                           name_prefix="checkpoint",
                           save_replay_buffer=hasattr(model, "replay_buffer")),
        EvalCallback(eval_env, n_eval_episodes=settings.eval_episodes,
                     eval_freq=per_env(settings.eval_freq), best_model_save_path=str(run_dir),
                     log_path=str(run_dir), deterministic=True, verbose=0),
    ])

    def on_sigterm(signum, frame):  # noqa: ARG001
        raise _Stop()

    previous = signal.signal(signal.SIGTERM, on_sigterm)
    remaining = total - model.num_timesteps
    interrupted = False
    try:
        if remaining > 0:
            model.learn(remaining, callback=callbacks, progress_bar=settings.progress_bar,
                        reset_num_timesteps=resume is None)
    except (KeyboardInterrupt, _Stop):
        interrupted = True
        path = _save_checkpoint(model, run_dir / "checkpoints", "interrupted")
        write_sidecar(path, settings)
        print(f"\ninterrupted at {model.num_timesteps} steps; checkpoint saved to {path}\n"
              f"continue with: python train.py --resume {path}")
    finally:
        signal.signal(signal.SIGTERM, previous)
    if not interrupted:
        final = run_dir / "final_model.zip"
        model.save(final)
        write_sidecar(final, settings)
        if (run_dir / "best_model.zip").is_file():
            write_sidecar(run_dir / "best_model.zip", settings)
        plot_learning_curve(run_dir)
    env.close()
    eval_env.close()
    return run_dir


def plot_learning_curve(run_dir: Path) -> Path | None:
    """Mean evaluation return vs timesteps (from evaluations.npz) as PNG and CSV."""
    data_file = run_dir / "evaluations.npz"
    if not data_file.is_file():
        return None
    data = np.load(data_file)
    steps, results, lengths = data["timesteps"], data["results"], data["ep_lengths"]
    rows = ["timesteps,mean_return,std_return,mean_length"]
    rows += [f"{s},{r.mean()},{r.std()},{n.mean()}" for s, r, n in zip(steps, results, lengths)]
    (run_dir / "learning_curve.csv").write_text("\n".join(rows) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5), dpi=100)
    mean, std = results.mean(axis=1), results.std(axis=1)
    ax.plot(steps, mean, color="C0")
    ax.fill_between(steps, mean - std, mean + std, color="C0", alpha=0.2)
    ax.set_xlabel("timesteps")
    ax.set_ylabel("evaluation return")
    ax.set_title(run_dir.name)
    fig.tight_layout()
    out = run_dir / "learning_curve.png"
    fig.savefig(out)
    plt.close(fig)
    return out


__all__ = ["ALGO_NAMES", "TrainSettings", "load_hyperparams", "make_vec_env",
           "parse_env_kwargs", "parse_policy_kwargs", "plot_learning_curve", "train"]