#!/usr/bin/env python
"""Train an agent on SaddleTrap-v0 — a thin command line over ``agents.training``.

    python train.py                                  # PPO, default budget (a few minutes)
    python train.py --algo sac --env-kwargs air_force=0.1 ball_radii=[0.0223,0.0265,0.033]
    python train.py --resume runs/<run>/checkpoints/interrupted_123456_steps.zip

Ctrl-C saves a checkpoint that --resume continues from. Results go to --log-dir/<run>/.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def build_parser() -> argparse.ArgumentParser:
    from agents.training import ALGO_NAMES, ENV_ID

    ap = argparse.ArgumentParser(description="Train an SB3 agent on SaddleTrap-v0.",
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--algo", choices=ALGO_NAMES, default="ppo")
    ap.add_argument("--env", default=ENV_ID, help="environment id (a key of the hyperparams file)")
    ap.add_argument("--env-kwargs", nargs="*", default=[], metavar="KEY=VALUE",
                    help="environment options, values read as YAML (e.g. R=0.033 air_force=0.1)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n-envs", type=int, default=None, help="parallel balls (default: hyperparams)")
    ap.add_argument("--total-timesteps", type=int, default=None,
                    help="budget in env steps (default: hyperparams n_timesteps)")
    ap.add_argument("--hyperparams", default=None, metavar="FILE.yml",
                    help="zoo-format YAML (default: agents/hyperparams/<algo>.yml)")
    ap.add_argument("--log-dir", default="runs")
    ap.add_argument("--run-name", default=None)
    ap.add_argument("--eval-freq", type=int, default=20_000, help="env steps between evaluations")
    ap.add_argument("--eval-episodes", type=int, default=32)
    ap.add_argument("--save-freq", type=int, default=50_000, help="env steps between checkpoints")
    ap.add_argument("--max-episode-steps", type=int, default=500)
    ap.add_argument("--torch-threads", type=int, default=1,
                    help="torch CPU threads (1 is fastest for these small networks on 2 cores)")
    ap.add_argument("--no-progress-bar", action="store_true")
    ap.add_argument("--resume", default=None, metavar="CHECKPOINT.zip",
                    help="continue a run from a checkpoint (its config.json supplies the rest)")
    return ap


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from agents.training import TrainSettings, parse_env_kwargs, train

    try:
        if args.resume:
            ckpt = Path(args.resume)
            config = ckpt.resolve().parent.parent / "config.json"
            if not ckpt.is_file() or not config.is_file():
                parser.error(f"--resume: need an existing checkpoint inside a run folder with "
                             f"config.json, got {args.resume!r}")
            saved = json.loads(config.read_text())
            saved.pop("hyperparams_used", None)
            settings = TrainSettings(**saved)
            if args.total_timesteps:
                settings.total_timesteps = args.total_timesteps
            settings.progress_bar = not args.no_progress_bar
        else:
            settings = TrainSettings(
                algo=args.algo, env_id=args.env, env_kwargs=parse_env_kwargs(args.env_kwargs),
                seed=args.seed, n_envs=args.n_envs, total_timesteps=args.total_timesteps,
                hyperparams=args.hyperparams, log_dir=args.log_dir, run_name=args.run_name,
                eval_freq=args.eval_freq, eval_episodes=args.eval_episodes,
                save_freq=args.save_freq, max_episode_steps=args.max_episode_steps,
                progress_bar=not args.no_progress_bar, torch_threads=args.torch_threads)
            for name in ("n_envs", "total_timesteps", "eval_freq", "eval_episodes", "save_freq",
                         "max_episode_steps", "torch_threads"):
                value = getattr(settings, name)
                if value is not None and value < 1:
                    parser.error(f"--{name.replace('_', '-')} must be a positive integer, got {value}")
        start = time.time()
        run_dir = train(settings, resume=args.resume)
    except ValueError as exc:
        parser.error(str(exc))
    print(f"run folder: {run_dir}  ({time.time() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
