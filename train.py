#!/usr/bin/env python
"""Train an agent on a task level — a thin command line over ``agents.training.trainer``.

    python train.py                                  # PPO (SB3) on SaddleTrap-Gusty-v0
    python train.py --backend sbx                    # the same with SBX's PPO: about 2x faster
    python train.py --env SaddleTrap-Storm-v0        # a registered level (saddle_env.LEVELS)
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
    from agents.training.runs import ALGO_NAMES, BACKENDS, DEFAULT_EVAL_EPISODES, TrainSettings
    from saddle_env.envs import LEVEL_IDS

    d = TrainSettings()
    ap = argparse.ArgumentParser(description="Train an agent on a SaddleTrap task level: "
                                             "Stable-Baselines3 in this process, or Ray RLlib "
                                             "(--backend rllib).",
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--algo", choices=ALGO_NAMES, default=d.algo,
                    help="the learning algorithm (its recipe: agents/hyperparams/<algo>.yml)")
    ap.add_argument("--env", default=d.env_id, metavar="ID",
                    help=f"task level: {', '.join(LEVEL_IDS)} (also the hyperparams entry)")
    ap.add_argument("--env-kwargs", nargs="*", default=[], metavar="KEY=VALUE",
                    help="options over the level's: key=value items (values as JSON/Python/YAML "
                         "literals, e.g. R=0.033 air_force=0.1) or one JSON object")
    ap.add_argument("--seed", type=int, default=d.seed,
                    help="seed of the learner and of the training episodes (the validation "
                         "and comparison episodes have their own fixed seeds)")
    ap.add_argument("--n-envs", type=int, default=d.n_envs,
                    help="parallel balls (None: the hyperparams' n_envs)")
    ap.add_argument("--total-timesteps", type=int, default=d.total_timesteps,
                    help="budget in env steps (None: the hyperparams' n_timesteps)")
    ap.add_argument("--hyperparams", default=d.hyperparams, metavar="FILE.yml",
                    help="zoo-format YAML (None: agents/hyperparams/<algo>.yml)")
    ap.add_argument("--recipe-of", default=d.recipe_of, metavar="ID",
                    help="train with another level's entry of the hyperparams (e.g. "
                         "SaddleTrap-Capture-v0: the fast recipe, on any level)")
    ap.add_argument("--log-dir", default=d.log_dir, metavar="DIR",
                    help="folder that holds the run folders")
    ap.add_argument("--run-name", default=d.run_name, metavar="NAME",
                    help="the run folder's name under --log-dir (None: algorithm, back end, "
                         "seed and start time)")
    ap.add_argument("--eval-freq", type=int, default=d.eval_freq,
                    help="env steps between evaluations on the validation seeds")
    ap.add_argument("--eval-episodes", type=int, default=d.eval_episodes,
                    help="validation episodes per evaluation (None: the recipe's, else "
                         f"{DEFAULT_EVAL_EPISODES})")
    ap.add_argument("--save-freq", type=int, default=d.save_freq,
                    help="env steps between checkpoints")
    ap.add_argument("--max-episode-steps", type=int, default=d.max_episode_steps,
                    help="control steps per episode (None: the level's)")
    ap.add_argument("--torch-threads", type=int, default=d.torch_threads,
                    help="torch CPU threads (1, the default, makes a run repeat bit for bit; 2 is "
                         "a little faster on 2 cores: docs/how-to/train.md#train)")
    ap.add_argument("--compare-episodes", type=int, default=d.compare_episodes,
                    help="fresh episodes on which the trained agent is compared with best-const "
                         "and mpc at the end (0: skip)")
    ap.add_argument("--no-progress-bar", action="store_true",
                    help="print no progress bar (for logs and batch jobs)")
    ap.add_argument("--resume", default=None, metavar="CHECKPOINT",
                    help="continue a run from a checkpoint (its config.json supplies the rest): "
                         "a .zip (sb3) or an RLlib checkpoint directory (rllib)")
    ap.add_argument("--trust-model", action="store_true",
                    help="--resume from a checkpoint whose reading needs unpickling (SB3's own "
                         "files, older runs' pickled statistics or buffers, RLlib's "
                         "checkpoints), which runs code it carries: only for files you trust "
                         "(docs/security.md). Default: checkpoints are read as data")
    rl = ap.add_argument_group("Ray RLlib (--backend rllib; docs/scaling.md)")
    rl.add_argument("--backend", choices=BACKENDS, default=d.backend,
                    help="sb3: Stable-Baselines3 in this process; sbx: SBX's PPO (SB3's API "
                         "on JAX, about twice the steps per second; the [sbx] extra; model "
                         "files are SB3's); rllib: Ray RLlib, on a local Ray or a cluster "
                         "(--address); needs the [rllib] extra")
    rl.add_argument("--num-env-runners", type=int, default=d.num_env_runners, metavar="N",
                    help="RLlib env runners (N >= 0; default 2), each stepping --n-envs balls "
                         "through the native vector env; 0 samples in the driver process")
    rl.add_argument("--address", default=d.address, metavar="HOST:PORT",
                    help="join a running Ray cluster (the `ray start --head` address, or auto); "
                         "default: start a local Ray")
    rl.add_argument("--num-cpus", type=int, default=d.num_cpus,
                    help="CPUs of the local Ray (default: the machine's cores)")
    return ap


# Flags whose value goes into the TrainSettings field of another name.
FIELD_OF_FLAG = {"env": "env_id"}


def settings_from_args(args: argparse.Namespace):
    """The run's settings: each TrainSettings field from the flag of its name (or
    `FIELD_OF_FLAG`'s), validated; from the checkpoint's run folder for ``--resume``."""
    from agents.cli_args import parse_env_kwargs
    from agents.training.runs import TrainSettings, settings_for_resume

    progress_bar = not args.no_progress_bar
    if args.resume:
        return settings_for_resume(args.resume, args.total_timesteps, progress_bar,
                                   num_env_runners=args.num_env_runners,
                                   address=args.address, num_cpus=args.num_cpus)
    flags = vars(args)
    values = {FIELD_OF_FLAG.get(flag, flag): value for flag, value in flags.items()}
    values.update(env_kwargs=parse_env_kwargs(args.env_kwargs), progress_bar=progress_bar)
    known = TrainSettings.__dataclass_fields__
    return TrainSettings(**{k: v for k, v in values.items() if k in known}).validate()


def main(argv: list[str] | None = None) -> int:
    """Build the settings, train through the one seam (`agents.training.trainer.train`), print the
    run folder. Bad input and a missing extra end as one-line errors (exit 2)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    from agents.cli_args import MissingExtra

    try:
        settings = settings_from_args(args)
        if settings.address is not None:
            from agents.training.backends.rllib import check_reachable

            check_reachable(settings.address)   # a one-line error within seconds, not a hang
        from agents.training.trainer import check_dependencies, train

        check_dependencies(settings)
        start = time.time()
        run_dir = train(settings, resume=args.resume, trust=args.trust_model)
    except MissingExtra as exc:
        parser.exit(2, f"{parser.prog}: error: {exc}\n")
    except ValueError as exc:
        parser.error(str(exc))
    print(f"run folder: {run_dir}  ({time.time() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
