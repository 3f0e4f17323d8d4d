#!/usr/bin/env python
"""Train an agent on a task level — a thin command line over ``agents.training``.

    python train.py                                  # the main job: PPO on SaddleTrap-Capture-v0
    python train.py --env SaddleTrap-Gusty-v0        # a registered level (saddle_env.LEVELS)
    python train.py --algo sac --env-kwargs air_force=0.1 ball_radii=[0.0223,0.0265,0.033]
    python train.py --resume runs/<run>/checkpoints/interrupted_123456_steps.zip
    python train.py --backend rllib --env SaddleTrap-v0 --num-env-runners 2   # Ray RLlib

Ctrl-C saves a checkpoint that --resume continues from. Results go to --log-dir/<run>/.
This file only parses arguments: defaults, checks and the work live in agents/.
"""

from __future__ import annotations

import argparse
import sys
import time


def build_parser() -> argparse.ArgumentParser:
    # Only the core install is needed to build the parser (and print --help).
    from agents.training import ALGO_NAMES, TrainSettings
    from saddle_env.envs import LEVEL_IDS

    d = TrainSettings()
    ap = argparse.ArgumentParser(description="Train an agent on a SaddleTrap task level: "
                                             "Stable-Baselines3 in this process, or Ray RLlib "
                                             "(--backend rllib).",
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--algo", choices=ALGO_NAMES, default=d.algo)
    ap.add_argument("--env", default=d.env_id, metavar="ID",
                    help=f"task level: {', '.join(LEVEL_IDS)} (also the hyperparams entry)")
    ap.add_argument("--env-kwargs", nargs="*", default=[], metavar="KEY=VALUE",
                    help="options over the level's: key=value items (values as JSON/Python/YAML "
                         "literals, e.g. R=0.033 air_force=0.1) or one JSON object")
    ap.add_argument("--seed", type=int, default=d.seed)
    ap.add_argument("--n-envs", type=int, default=d.n_envs,
                    help="parallel balls (None: the hyperparams' n_envs)")
    ap.add_argument("--total-timesteps", type=int, default=d.total_timesteps,
                    help="budget in env steps (None: the hyperparams' n_timesteps)")
    ap.add_argument("--hyperparams", default=d.hyperparams, metavar="FILE.yml",
                    help="zoo-format YAML (None: agents/hyperparams/<algo>.yml)")
    ap.add_argument("--log-dir", default=d.log_dir)
    ap.add_argument("--run-name", default=d.run_name)
    ap.add_argument("--eval-freq", type=int, default=d.eval_freq,
                    help="env steps between evaluations on the validation seeds")
    ap.add_argument("--eval-episodes", type=int, default=d.eval_episodes)
    ap.add_argument("--save-freq", type=int, default=d.save_freq,
                    help="env steps between checkpoints")
    ap.add_argument("--max-episode-steps", type=int, default=d.max_episode_steps,
                    help="control steps per episode (None: the level's)")
    ap.add_argument("--torch-threads", type=int, default=d.torch_threads,
                    help="torch CPU threads (1 is fastest for these small networks on 2 cores)")
    ap.add_argument("--compare-episodes", type=int, default=d.compare_episodes,
                    help="fresh episodes on which the trained agent is compared with best-const "
                         "and mpc at the end (0: skip)")
    ap.add_argument("--no-progress-bar", action="store_true")
    ap.add_argument("--resume", default=None, metavar="CHECKPOINT",
                    help="continue a run from a checkpoint (its config.json supplies the rest): "
                         "a .zip (sb3) or an RLlib checkpoint directory (rllib)")
    ap.add_argument("--trust-model", action="store_true",
                    help="--resume from a checkpoint whose reading needs unpickling (SB3's own "
                         "files, older runs' pickled statistics or buffers, RLlib's "
                         "checkpoints), which runs code it carries: only for files you trust "
                         "(docs/security.md). Default: checkpoints are read as data")
    rl = ap.add_argument_group("Ray RLlib (--backend rllib; docs/scaling.md)")
    rl.add_argument("--backend", choices=("sb3", "rllib"), default="sb3",
                    help="sb3: Stable-Baselines3 in this process; rllib: Ray RLlib, on a local "
                         "Ray or a cluster (--address); needs the [rllib] extra")
    rl.add_argument("--num-env-runners", type=int, default=None, metavar="N",
                    help="RLlib env runners (N >= 1; default 2), each stepping --n-envs balls "
                         "through the native vector env")
    rl.add_argument("--address", default=None, metavar="HOST:PORT",
                    help="join a running Ray cluster (the `ray start --head` address, or auto); "
                         "default: start a local Ray")
    rl.add_argument("--num-cpus", type=int, default=None,
                    help="CPUs of the local Ray (default: the machine's cores)")
    return ap


def _run(parser: argparse.ArgumentParser, prepare, train) -> int:
    """Both backends: build and check the settings (``prepare()``), ``train(settings)``,
    print the run folder. Bad input and a missing extra end as one-line errors (exit 2)."""
    from agents.cli_args import MissingExtra

    try:
        settings = prepare()
        start = time.time()
        run_dir = train(settings)
    except MissingExtra as exc:
        parser.exit(2, f"{parser.prog}: error: {exc}\n")
    except ValueError as exc:
        parser.error(str(exc))
    print(f"run folder: {run_dir}  ({time.time() - start:.0f} s)")
    return 0


def _main_rllib(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """train.py --backend rllib (or --resume of an RLlib checkpoint): all Ray code is in
    agents/rllib_backend.py."""
    from agents import rllib_backend as rb
    from agents.cli_args import parse_env_kwargs

    def prepare():
        if args.num_env_runners is not None and args.num_env_runners < 1:
            raise ValueError(f"--num-env-runners must be >= 1, got {args.num_env_runners}")
        if not args.resume and args.algo not in rb.RLLIB_ALGOS:
            raise ValueError(f"--algo {args.algo} is not available with --backend rllib "
                             f"(choose from {', '.join(rb.RLLIB_ALGOS)})")
        if args.address is not None:
            rb.check_reachable(args.address)   # a one-line error within seconds, not a hang
        rb.check_dependencies()
        if args.resume:
            return rb.settings_for_resume(
                args.resume, args.total_timesteps, not args.no_progress_bar,
                num_env_runners=args.num_env_runners, address=args.address,
                num_cpus=args.num_cpus)
        return rb.RllibSettings(
            algo=args.algo, env_id=args.env, env_kwargs=parse_env_kwargs(args.env_kwargs),
            seed=args.seed, n_envs=args.n_envs, total_timesteps=args.total_timesteps,
            hyperparams=args.hyperparams, log_dir=args.log_dir, run_name=args.run_name,
            save_freq=args.save_freq, max_episode_steps=args.max_episode_steps,
            progress_bar=not args.no_progress_bar, torch_threads=args.torch_threads,
            num_env_runners=(rb.DEFAULT_ENV_RUNNERS if args.num_env_runners is None
                             else args.num_env_runners),
            address=args.address, num_cpus=args.num_cpus).validate()

    return _run(parser, prepare, lambda settings: rb.train(settings, resume=args.resume,
                                                           trust=args.trust_model))


def _is_rllib_checkpoint(path: str) -> bool:
    from agents.rllib_backend import is_checkpoint

    return is_checkpoint(path)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.backend == "rllib" or (args.resume and _is_rllib_checkpoint(args.resume)):
        return _main_rllib(parser, args)
    if args.num_env_runners is not None or args.address is not None:
        parser.error("--num-env-runners and --address need --backend rllib")
    from agents.cli_args import parse_env_kwargs
    from agents.training import TrainSettings, check_dependencies, settings_for_resume, train

    def prepare():
        check_dependencies(not args.no_progress_bar)
        if args.resume:
            return settings_for_resume(args.resume, args.total_timesteps,
                                       not args.no_progress_bar)
        return TrainSettings(
            algo=args.algo, env_id=args.env, env_kwargs=parse_env_kwargs(args.env_kwargs),
            seed=args.seed, n_envs=args.n_envs, total_timesteps=args.total_timesteps,
            hyperparams=args.hyperparams, log_dir=args.log_dir, run_name=args.run_name,
            eval_freq=args.eval_freq, eval_episodes=args.eval_episodes,
            save_freq=args.save_freq, max_episode_steps=args.max_episode_steps,
            progress_bar=not args.no_progress_bar, torch_threads=args.torch_threads,
            compare_episodes=args.compare_episodes).validate()

    return _run(parser, prepare, lambda settings: train(settings, resume=args.resume,
                                                        trust=args.trust_model))


if __name__ == "__main__":
    sys.exit(main())
