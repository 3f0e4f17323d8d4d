"""The Ray RLlib back end of `agents.training.trainer` (``train.py --backend rllib``), and running
its checkpoints.

All Ray code of the project lives here, and ray is imported only inside the functions that
need it: importing this module (or `saddle_env`, or `agents`) never imports ray. Install it
with the ``[rllib]`` extra (``pip install -e ".[rllib]"``, torch==2.13.0 first; CPU-only from
``--index-url https://download.pytorch.org/whl/cpu``).

**Sampling.** RLlib's new API stack: ``num_env_runners`` EnvRunner actors, each stepping
``num_envs_per_env_runner`` balls through the native vector env (`SaddleTrapVectorEnv`,
every ball in one compiled call per step) — RLlib's ``gym_env_vectorize_mode=
"vector_entry_point"`` with the env creator `make_env`, not one Python env per ball. The
learner runs in the driver (``num_learners=0``). Runner w (1..N) steps balls with seeds
``seed + w·n`` .. ``seed + w·n + n − 1`` (n balls per runner), so no two balls share a seed.

**Hyperparameters** come from the same zoo YAML files as the SB3 path
(``agents/hyperparams/<algo>.yml``), translated: PPO's ``n_steps × n_envs`` samples per
update (``train_batch_size_per_learner``), ``batch_size`` (minibatch), ``n_epochs``,
``gamma``, ``gae_lambda``, ``clip_range``, ``ent_coef``, ``learning_rate`` and the
``net_arch`` of ``policy_kwargs`` (separate policy and value networks, tanh, as SB3);
``n_envs`` is the number of balls per env runner. SAC: ``learning_rate``, ``buffer_size``,
``learning_starts``, ``batch_size``, ``gamma``, ``tau`` and ``net_arch``. Keys with no
RLlib counterpart here (``warm_start``, ``log_std_init``, ``normalize``, ``frame_stack``,
``noise_type``, ...) are named in a note and not used.

**The run folder** (``--log-dir/<algo>_rllib_seed<seed>_<date>-<time>/``): ``config.json``
(what ``--resume`` reads), ``progress.csv`` and TensorBoard logs (one row per training
iteration: steps, sampling and learner throughput, episode return and length, losses),
``checkpoints/`` (RLlib's own checkpoint format, every ``save_freq`` env steps and on
Ctrl-C/SIGTERM, ``checkpoint_<steps>`` / ``interrupted_<steps>``) and ``final/``. Each
checkpoint directory holds ``saddle_env.json`` (the level, the overriding options, the
episode length, the algorithm, the steps), which ``saddle-eval --policy DIR`` reads.
``--resume DIR`` rebuilds the algorithm from the run's settings (the number of env runners
and ``--address`` may change) and restores the checkpoint, the lifetime step count included.
As every back end's run (`agents.training.trainer`), a finished one ends with ``learning_curve.png``
(here from the training episodes' running mean, ``evaluations_wall.csv``: RLlib has no
validation during training, so no model selection, and its curve has no reference lines:
no reference policy ran its training episodes, `agents.training.run_report`) and the
comparison of ``final/`` with best-const and mpc on fresh episodes (``comparison.md``).

**Faults.** ``restart_failed_env_runners``: an env runner that dies is replaced by a fresh
one (same index, same seeds) and training goes on with the learner's state intact.
"""

from __future__ import annotations

import json
import logging
import math
import os
import signal
import socket
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from saddle_env.envs.vector import SaddleTrapVectorEnv

from ...cli_args import MissingExtra, install_hint, level_overrides, missing, parse_address
from ...evaluation.rllib_policy import (
    CHECKPOINT_MARKER,
    SIDECAR,
    WEIGHTS_FILE,
    RllibPolicy,
    checkpoint_sidecar,
    is_checkpoint,
    latest_checkpoint,
    load_policy,
)
from ..recipes import parse_policy_kwargs
from ..run_report import append_curve_point
from ..runs import BACKEND_ALGOS, RunSettings, Stop, TrainSettings, sigterm_stops

RLLIB_ALGOS = BACKEND_ALGOS["rllib"]
RLLIB_MODULES = ("ray", "torch", "yaml")
ENV_NAME = "saddle_env_vector"       # the name of `make_env` in Ray's registry
# Resuming restores RLlib's own checkpoint, which is pickled: only with --trust-model.
RESUME_NEEDS_TRUST = True
LOCAL_OBJECT_STORE = 300 * 1024 ** 2   # bytes: the payloads are small
CONNECT_TIMEOUT_S = 3.0
# Zoo keys translated into RLlib settings, per algorithm (everything else: a note).
_ZOO_COMMON = {"n_envs", "n_timesteps", "policy", "policy_kwargs", "gamma", "learning_rate"}
_ZOO_USED = {"ppo": _ZOO_COMMON | {"n_steps", "batch_size", "n_epochs", "gae_lambda",
                                   "clip_range", "ent_coef"},
             "sac": _ZOO_COMMON | {"buffer_size", "learning_starts", "batch_size", "tau"}}


# ---------------------------------------------------------------------------------------
# the environment on an env runner
# ---------------------------------------------------------------------------------------
class RunnerVectorEnv(SaddleTrapVectorEnv):
    """The native vector env as an env runner builds it, with seeds apart per runner.

    RLlib resets runner w's env with ``seed + w`` (its config's seed plus the runner's
    index); the vector env would then give ball i the seed ``seed + w + i``, overlapping the
    next runner's balls. Here ball i of runner w gets ``seed + w·n + i`` instead."""

    def __init__(self, num_envs: int = 1, max_episode_steps: int | None = 500,
                 base_seed: int = 0, **kwargs: Any):
        super().__init__(num_envs=num_envs, max_episode_steps=max_episode_steps, **kwargs)
        self.base_seed = int(base_seed)

    def reset(self, *, seed=None, options=None):
        """Reset, with each env runner's seed spread so that no two runners share episodes."""
        if isinstance(seed, (int, np.integer)):
            runner = int(seed) - self.base_seed
            seed = self.base_seed + runner * self.num_envs
        return super().reset(seed=seed, options=options)


def make_env(env_config: dict[str, Any]):
    """Ray's env creator: ``env_config`` holds ``env_id``, ``env_kwargs`` (options over the
    level's), ``max_episode_steps``, ``seed`` and (from RLlib) ``num_envs``: the vector env
    of ``num_envs`` balls; without ``num_envs`` one ball's env (for RLlib's ``sync`` mode,
    which the benchmark compares with)."""
    from saddle_env.envs import get_level

    ctx = dict(env_config)
    level = get_level(ctx["env_id"])
    kwargs = {**level.options, **(ctx.get("env_kwargs") or {})}
    if "num_envs" not in ctx:    # one Python env per ball (gym_env_vectorize_mode="sync")
        from gymnasium.wrappers import TimeLimit

        from saddle_env.envs import SaddleTrapEnv

        return TimeLimit(SaddleTrapEnv(**kwargs),
                         ctx.get("max_episode_steps") or level.max_episode_steps)
    return RunnerVectorEnv(num_envs=int(ctx.get("num_envs", 1)),
                           max_episode_steps=ctx.get("max_episode_steps") or level.max_episode_steps,
                           base_seed=int(ctx.get("seed") or 0), **kwargs)


# ---------------------------------------------------------------------------------------
# settings
# ---------------------------------------------------------------------------------------
def env_config(settings: TrainSettings) -> dict[str, Any]:
    """What `make_env` needs on an env runner: the level, its overriding options, the
    episode length and the base seed."""
    level, config = settings.environment()
    return {"env_id": level.id, "env_kwargs": level_overrides(level, config),
            "max_episode_steps": settings.max_episode_steps, "seed": settings.seed}


def check_dependencies(progress_bar: bool = True) -> None:
    """One line naming the extra to install if Ray or torch is missing."""
    lacking = missing(RLLIB_MODULES)
    if lacking:
        raise MissingExtra(f"--backend rllib needs {', '.join(lacking)}, not installed: "
                           f"{install_hint('rllib')} (torch==2.13.0 first; CPU-only: pip install "
                           "torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu)")


# ---------------------------------------------------------------------------------------
# Ray
# ---------------------------------------------------------------------------------------
def check_reachable(address: str, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """A one-line ValueError, within ``timeout`` seconds, if nothing listens at
    ``address`` (ray.init would otherwise retry for a long time)."""
    target = parse_address(address)
    if target is None:
        return
    try:
        socket.create_connection(target, timeout=timeout).close()
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        if isinstance(exc, TimeoutError | socket.timeout):
            reason = f"no answer in {timeout:g} s"
        raise ValueError(f"--address {address}: cannot reach a Ray head there ({reason}); "
                         f"start one with `ray start --head` and pass the address it prints"
                         ) from None


def init_ray(address: str | None = None, num_cpus: int | None = None) -> bool:
    """Start a local Ray (``num_cpus`` cores, default the machine's; no dashboard, no usage
    statistics) or join the cluster at ``address``. False if Ray was already initialised
    (the caller then leaves it running), True if this call started or joined it."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    if address is not None:
        check_reachable(address)
    import ray

    if ray.is_initialized():
        return False
    if address is not None:
        try:
            ray.init(address=address, logging_level=logging.ERROR, log_to_driver=False)
        except (ConnectionError, RuntimeError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ValueError(f"--address {address}: {first}") from None
        return True
    ray.init(num_cpus=num_cpus or os.cpu_count() or 1, include_dashboard=False,
             object_store_memory=LOCAL_OBJECT_STORE, logging_level=logging.ERROR,
             log_to_driver=False)
    return True


def _net_arch(hyper: dict[str, Any], default: list[int]) -> list[int]:
    arch = parse_policy_kwargs(hyper.get("policy_kwargs")).get("net_arch", default)
    if isinstance(arch, dict):
        arch = arch.get("pi", default)
    return [int(n) for n in arch]


def module_config(algo: str, hyper: dict[str, Any]) -> dict[str, Any]:
    """The policy network's RLlib model config (DefaultModelConfig keywords), also recorded
    in each checkpoint's sidecar so that evaluation can rebuild the network as data."""
    if algo == "ppo":
        return {"fcnet_hiddens": _net_arch(hyper, [64, 64]), "fcnet_activation": "tanh",
                "vf_share_layers": False}
    return {"fcnet_hiddens": _net_arch(hyper, [256, 256]), "fcnet_activation": "relu"}


def build_config(settings: RunSettings, hyper: dict[str, Any]):
    """The RLlib AlgorithmConfig of a run (Ray must be initialised: the CPUs per env
    runner are shared out among the cluster's CPUs if there are more runners than CPUs)."""
    import ray
    from ray.rllib.algorithms.algorithm_config import AlgorithmConfig
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
    from ray.tune.registry import register_env

    register_env(ENV_NAME, make_env)
    n_envs = settings.n_envs
    runners = settings.env_runners
    cpus = float(ray.cluster_resources().get("CPU", 1.0))
    cpus_per_runner = min(1.0, cpus / max(runners, 1))
    model = DefaultModelConfig(**module_config(settings.algo, hyper))
    config: AlgorithmConfig
    if settings.algo == "ppo":
        from ray.rllib.algorithms.ppo import PPOConfig

        batch = int(hyper.get("n_steps", 256)) * n_envs
        config = PPOConfig().training(
            train_batch_size_per_learner=batch,
            minibatch_size=min(batch, int(hyper.get("batch_size", 64))),
            num_epochs=int(hyper.get("n_epochs", 10)),
            lr=float(hyper.get("learning_rate", 3e-4)),
            gamma=float(hyper.get("gamma", 0.99)), lambda_=float(hyper.get("gae_lambda", 0.95)),
            clip_param=float(hyper.get("clip_range", 0.2)),
            entropy_coeff=float(hyper.get("ent_coef", 0.0)), use_kl_loss=False)
    else:
        from ray.rllib.algorithms.sac import SACConfig

        lr = float(hyper.get("learning_rate", 3e-4))
        config = SACConfig().training(
            actor_lr=lr, critic_lr=lr, alpha_lr=lr, gamma=float(hyper.get("gamma", 0.99)),
            tau=float(hyper.get("tau", 0.005)),
            train_batch_size_per_learner=int(hyper.get("batch_size", 256)),
            num_steps_sampled_before_learning_starts=int(hyper.get("learning_starts", 1000)),
            replay_buffer_config={"type": "PrioritizedEpisodeReplayBuffer",
                                  "capacity": int(hyper.get("buffer_size", 200_000))})
    config = (config
              .environment(env=ENV_NAME, env_config=env_config(settings))
              .env_runners(num_env_runners=runners, num_envs_per_env_runner=n_envs,
                           gym_env_vectorize_mode="vector_entry_point",
                           # Ray's hint says int, but its CPU requests take fractions (a
                           # share of a CPU when there are more runners than CPUs); without
                           # Ray installed mypy sees no hint, hence unused-ignore.
                           num_cpus_per_env_runner=cpus_per_runner,  # type: ignore[arg-type, unused-ignore]
                           rollout_fragment_length="auto" if settings.algo == "ppo" else 1)
              .learners(num_learners=0)
              .rl_module(model_config=model)
              .fault_tolerance(restart_failed_env_runners=True,
                               max_num_env_runner_restarts=1000,
                               delay_between_env_runner_restarts_s=1.0,
                               env_runner_health_probe_timeout_s=10.0)
              .debugging(seed=int(settings.seed), log_level="ERROR"))
    return config


def _note_unused(hyper: dict[str, Any], algo: str) -> None:
    unused = sorted(k for k, v in hyper.items() if k not in _ZOO_USED[algo] and v is not None)
    if unused:
        print(f"train.py: --backend rllib does not use these hyperparameters: "
              f"{', '.join(unused)}", file=sys.stderr)


# ---------------------------------------------------------------------------------------
# training
# ---------------------------------------------------------------------------------------
# progress.csv columns: (name, path in RLlib's result dict)
COLUMNS = (
    ("iteration", ("training_iteration",)),
    ("env_steps", ("env_runners", "num_env_steps_sampled_lifetime")),
    ("env_steps_this_iter", ("env_runners", "num_env_steps_sampled")),
    ("time_this_iter_s", ("time_this_iter_s",)),
    ("episode_return_mean", ("env_runners", "episode_return_mean")),
    ("episode_len_mean", ("env_runners", "episode_len_mean")),
    ("num_healthy_env_runners", ("fault_tolerance", "num_healthy_workers")),
    ("num_env_runner_restarts", ("fault_tolerance", "num_remote_worker_restarts")),
    ("policy_loss", ("learners", "default_policy", "policy_loss")),
    ("vf_loss", ("learners", "default_policy", "vf_loss")),
    ("entropy", ("learners", "default_policy", "entropy")),
    ("qf_loss", ("learners", "default_policy", "qf_loss")),
    ("alpha_value", ("learners", "default_policy", "alpha_value")),
)


def _get(result: dict[str, Any], path: tuple[str, ...]) -> Any:
    for key in path:
        if not isinstance(result, dict) or key not in result:
            return None
        result = result[key]
    return result


def _scalar(value: Any) -> float | None:
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def result_row(result: dict[str, Any], wall_s: float) -> dict[str, Any]:
    """One progress.csv row from a training iteration's result: RLlib's figures, the wall
    time and the iteration's throughput (env steps sampled and learned per second)."""
    row = {name: _scalar(_get(result, path)) for name, path in COLUMNS}
    steps = row["env_steps_this_iter"] or 0.0
    row["wall_s"] = round(wall_s, 3)
    row["steps_per_s"] = steps / row["time_this_iter_s"] if row["time_this_iter_s"] else None
    return row


class RunLog:
    """progress.csv and TensorBoard scalars, one row per training iteration."""

    def __init__(self, run_dir: Path):
        self.path = run_dir / "progress.csv"
        self.writer = None
        try:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(run_dir / "tb"))
        except ImportError:     # tensorboard is in the extra; the CSV is enough without it
            self.writer = None

    def add(self, row: dict[str, Any]) -> None:
        """Append one iteration's ``row`` to progress.csv and, if TensorBoard is installed, its scalars."""
        import csv

        new = not self.path.is_file()
        with open(self.path, "a", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(row))
            if new:
                w.writeheader()
            w.writerow(row)
        if self.writer is not None:
            step = int(row.get("env_steps") or 0)
            for key, value in row.items():
                if value is not None and key != "env_steps":
                    self.writer.add_scalar(f"rllib/{key}", value, step)
            self.writer.flush()

    def close(self) -> None:
        """Close the TensorBoard writer."""
        if self.writer is not None:
            self.writer.close()


def lifetime_steps(algo) -> int:
    """Env steps sampled since the run began (restored with a checkpoint)."""
    from ray.rllib.utils.metrics import ENV_RUNNER_RESULTS, NUM_ENV_STEPS_SAMPLED_LIFETIME

    return int(algo.metrics.peek((ENV_RUNNER_RESULTS, NUM_ENV_STEPS_SAMPLED_LIFETIME),
                                 default=0) or 0)


def save_checkpoint(algo, path: Path, settings: TrainSettings, steps: int,
                    extra: dict[str, Any] | None = None) -> Path:
    """RLlib's checkpoint at ``path``, and in it our sidecar and the policy network's
    weights as plain tensors (`WEIGHTS_FILE`): RLlib's own files are pickles, which
    evaluation reads only with trust; the weights and the sidecar's ``module`` config
    rebuild the network as data."""
    import torch
    from ray.rllib.core import DEFAULT_MODULE_ID

    path = Path(path).resolve()
    path.parent.mkdir(parents=True, exist_ok=True)
    algo.save_to_path(str(path))
    weights = algo.learner_group.get_weights()[DEFAULT_MODULE_ID]
    torch.save({k: torch.as_tensor(np.asarray(v)) for k, v in weights.items()},
               path / WEIGHTS_FILE)
    level, config = settings.environment()
    side = {"backend": "rllib", "algo": settings.algo, "env_id": level.id,
            "env_kwargs": level_overrides(level, config),
            "max_episode_steps": settings.max_episode_steps, "seed": settings.seed,
            "steps": int(steps), "frame_stack": 1, "normalize": False,
            "module": module_config(settings.algo, settings.hyperparams_used)}
    side.update(extra or {})
    (path / SIDECAR).write_text(json.dumps(side, indent=2, default=list) + "\n")
    return path


def run(settings: RunSettings, hyper: dict[str, Any], run_dir: Path,
        resume: str | os.PathLike | None = None, trust: bool = False,
        began: float | None = None) -> Path | None:
    """Train (or resume: RLlib's own checkpoint, pickled, which `agents.training.trainer` lets
    through only with trust) in ``run_dir``; return the final checkpoint, or None if the
    run was interrupted (a checkpoint was saved). Starts a local Ray or joins
    ``settings.address`` unless Ray is already up (then leaves it running)."""
    _note_unused(hyper, settings.algo)
    started = init_ray(settings.address, settings.num_cpus)
    try:
        return _train(settings, hyper, run_dir, resume,
                      time.time() if began is None else began)
    finally:
        if started:
            import ray

            ray.shutdown()


def _train(settings: RunSettings, hyper: dict[str, Any], run_dir: Path,
           resume: str | os.PathLike | None, began: float) -> Path | None:
    import contextlib

    import torch

    torch.set_num_threads(settings.torch_threads)
    algo = build_config(settings, hyper).build_algo()
    if resume is not None:
        algo.restore_from_path(str(Path(resume).resolve()))
    steps = lifetime_steps(algo)
    dt = settings.environment()[1].control_period
    print(f"RLlib {settings.algo.upper()} on {settings.env_id}: {settings.num_env_runners} env "
          f"runner(s) x {settings.n_envs} balls (native vector env), "
          f"{steps:,} of {settings.total_timesteps:,} steps done; run folder {run_dir}",
          flush=True)
    log = RunLog(run_dir)
    bar = _progress_bar(settings, steps)
    last_save = steps
    start = time.time()
    final = None
    try:
        with sigterm_stops(deferred=True) as stop_requested:
            while steps < settings.total_timesteps:
                if stop_requested.is_set():
                    raise Stop()
                result = algo.train()
                steps = lifetime_steps(algo)
                row = result_row(result, time.time() - start)
                row["env_steps"] = steps
                log.add(row)
                if row["episode_len_mean"] is not None:   # the curve: training episodes
                    append_curve_point(run_dir, steps, time.time() - began,
                                       row["episode_return_mean"],
                                       row["episode_len_mean"] * dt)
                if bar is not None:
                    bar.update(steps - bar.n)
                    ret = row["episode_return_mean"]
                    bar.set_postfix_str("" if ret is None else f"return {ret:.1f}")
                if steps - last_save >= settings.save_freq:
                    save_checkpoint(algo, run_dir / "checkpoints" / f"checkpoint_{steps}",
                                    settings, steps)
                    last_save = steps
    except (KeyboardInterrupt, Stop):
        # Ctrl-C or SIGTERM again while saving would leave a half-written checkpoint.
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        steps = lifetime_steps(algo)
        path = save_checkpoint(algo, run_dir / "checkpoints" / f"interrupted_{steps}",
                               settings, steps)
        print(f"\ninterrupted at {steps} steps; checkpoint saved to {path}\n"
              f"continue with: python train.py --resume {path} --trust-model", flush=True)
    else:
        final = save_checkpoint(algo, run_dir / "final", settings, steps)
        print(f"trained {steps:,} env steps in {time.time() - start:.0f} s; checkpoint "
              f"{final}\nevaluate with: saddle-eval --policy {final}", flush=True)
    finally:
        if bar is not None:
            bar.close()
        log.close()
        with contextlib.suppress(Exception):   # shutting down; the checkpoint is on disk
            algo.stop()
    return final


def _progress_bar(settings: TrainSettings, done: int):
    if not settings.progress_bar:
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=settings.total_timesteps, initial=done, unit="step", unit_scale=True,
                dynamic_ncols=True)


__all__ = ["CHECKPOINT_MARKER", "ENV_NAME", "RESUME_NEEDS_TRUST", "RLLIB_ALGOS",
           "RllibPolicy", "RunnerVectorEnv", "build_config", "check_dependencies",
           "check_reachable", "checkpoint_sidecar", "env_config", "init_ray", "is_checkpoint",
           "latest_checkpoint", "load_policy", "make_env", "run", "save_checkpoint"]
