"""Ship a trained agent: among the runs of one recipe (one level and hyperparameters, several
training seeds), take the run whose selected model scored best on its validation episodes
and copy it into ``agents/models/`` with its sidecar and learning curve::

    python -m agents.benchmark.ship runs/Gusty_seed0 runs/Gusty_seed1 runs/Gusty_seed2 --name ppo_gusty

The choice uses validation scores only (never the test episodes the leaderboard reports).
The sidecar records the level, the recipe's hyperparameters, every run's seed, validation
score, budget, wall time and steps/s, so the shipped model says how it was made and how the
other seeds of its recipe fared; ``python train.py --env ID --seed S`` remakes it.
"""

from __future__ import annotations

import argparse
import csv
import json
import shlex
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..paths import MODELS_DIR


def run_summary(run: Path) -> dict[str, Any]:
    """Seed, validation score and cost of one finished run folder."""
    side = json.loads((run / "selected_model.json").read_text())
    config = json.loads((run / "config.json").read_text())
    steps, elapsed = 0, 0.0
    with open(run / "progress.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row.get("time/total_timesteps"):
                steps = max(steps, int(float(row["time/total_timesteps"])))
            if row.get("time/time_elapsed"):
                elapsed = max(elapsed, float(row["time/time_elapsed"]))
    # A warm start (the imitation of mpc: minutes) runs before SB3's clock starts.
    warm = run / "warm_start.json"
    warm_s = float(json.loads(warm.read_text()).get("seconds", 0.0)) if warm.is_file() else 0.0
    return {"run": run.name, "seed": int(config["seed"]), "env_id": side["env_id"],
            "env_kwargs": side.get("env_kwargs") or {},
            "validation_mean_return": float(side["validation_mean_return"]),
            "selected_at_steps": int(side["selected_at_steps"]),
            "total_timesteps": steps, "wall_time_s": round(elapsed + warm_s, 1),
            "warm_start_s": round(warm_s, 1),
            "steps_per_s": round(steps / elapsed) if elapsed > 0 else None,   # RL alone
            "hyperparams": config.get("hyperparams_used", {}),
            "remake": remake_command(side["env_id"], int(config["seed"]), config)}


# Settings that change what a run learns, in the order a remake line gives them. Each is
# written only where the run's value differs from what ``train.py`` would take from the recipe
# (config.json keeps the values a run resolved, not the flags it was given).
_REMADE_SETTINGS = ("n_envs", "total_timesteps", "eval_freq", "eval_episodes",
                    "max_episode_steps", "torch_threads")


def remake_command(env_id: str, seed: int, config: dict[str, Any]) -> str:
    """The ``train.py`` line that trains the run again: the level and seed, the back end and
    algorithm when not the defaults, the recipe when it was not the level's own entry of the
    default file, and every setting in which the run departed from its recipe (a budget or
    an evaluation period given on the command line, as `agents.benchmark.time_to_target` does)."""
    from ..training.runs import TrainSettings

    default = TrainSettings()
    words = ["python", "train.py", "--env", env_id, "--seed", str(seed)]
    for name in ("backend", "algo"):
        if config.get(name, getattr(default, name)) != getattr(default, name):
            words += [f"--{name}", str(config[name])]
    if config.get("hyperparams"):
        words += ["--hyperparams", str(config["hyperparams"])]
    if config.get("recipe_of"):
        words += ["--recipe-of", str(config["recipe_of"])]
    if config.get("env_kwargs"):
        words += ["--env-kwargs", json.dumps(config["env_kwargs"], sort_keys=True)]
    plain = TrainSettings(algo=config.get("algo", default.algo),
                          backend=config.get("backend", default.backend),
                          env_id=env_id, seed=seed).validate().with_recipe(
                              config.get("hyperparams_used") or {})
    for name in _REMADE_SETTINGS:
        if config.get(name) is not None and config[name] != getattr(plain, name):
            words += [f"--{name.replace('_', '-')}", str(config[name])]
    return shlex.join(words)   # a path with spaces stays one argument


def ship(runs: Sequence[Path], name: str, models_dir: Path = MODELS_DIR) -> Path:
    """Copy the best run's selected model to ``models_dir/name.zip`` (+ sidecar, curve)."""
    if not runs:
        raise ValueError("give at least one run folder")
    summaries = []
    for run in runs:
        try:
            summaries.append(run_summary(Path(run)))
        except (OSError, KeyError, ValueError) as exc:
            raise ValueError(f"{run}: not a finished training run ({exc})") from None
    recipes = {(s["env_id"], json.dumps(s["env_kwargs"], sort_keys=True),
                json.dumps(s["hyperparams"], sort_keys=True)) for s in summaries}
    if len(recipes) != 1:
        raise ValueError("the runs differ in level, options or hyperparameters: ship one recipe")
    # Best validation score; among equals the later seed (no preference for the first run).
    best = max(range(len(runs)), key=lambda i: (summaries[i]["validation_mean_return"],
                                                summaries[i]["seed"]))
    src = Path(runs[best])
    models_dir.mkdir(parents=True, exist_ok=True)
    target = models_dir / f"{name}.zip"
    shutil.copyfile(src / "selected_model.zip", target)
    for extra in src.glob("selected_model.vecnormalize.json"):
        shutil.copyfile(extra, models_dir / f"{name}.vecnormalize.json")
    if (src / "learning_curve.png").is_file():
        shutil.copyfile(src / "learning_curve.png", models_dir / f"{name}_learning_curve.png")
    if (src / "learning_curve.csv").is_file():
        shutil.copyfile(src / "learning_curve.csv", models_dir / f"{name}_learning_curve.csv")
    side = json.loads((src / "selected_model.json").read_text())
    shipped = summaries[best]
    side.update({"hyperparams": shipped["hyperparams"],
                 "total_timesteps": shipped["total_timesteps"],
                 "wall_time_s": shipped["wall_time_s"], "warm_start_s": shipped["warm_start_s"],
                 "steps_per_s": shipped["steps_per_s"],
                 "remake": shipped["remake"],
                 # the validation score above is the highest of the seeds': a maximum, so it
                 # flatters the shipped network a little; the leaderboard's test set does not
                 "chosen_among_seeds": (f"the highest validation score of {len(runs)} "
                                        f"seeds; its score on the leaderboard's test set is "
                                        f"the unbiased one" if len(runs) > 1 else None),
                 "recipe_runs": [{k: s[k] for k in ("seed", "validation_mean_return",
                                                   "selected_at_steps", "total_timesteps",
                                                   "wall_time_s", "warm_start_s",
                                                   "steps_per_s")}
                                 for s in summaries]})
    target.with_suffix(".json").write_text(json.dumps(side, indent=2) + "\n")
    return target


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    p = argparse.ArgumentParser(prog="python -m agents.benchmark.ship", description=__doc__.split("\n")[0])
    p.add_argument("runs", nargs="+", type=Path, help="run folders of one recipe")
    p.add_argument("--name", required=True, help="model name in agents/models/ (no .zip)")
    p.add_argument("--models-dir", type=Path, default=MODELS_DIR, metavar="DIR",
                   help="where the model, its sidecar and its curve go (default agents/models/)")
    args = p.parse_args(argv)
    try:
        path = ship(args.runs, args.name, args.models_dir)
    except ValueError as exc:
        p.error(str(exc))
    side = json.loads(path.with_suffix(".json").read_text())
    print(f"shipped {path} (seed {side['seed']}, validation return "
          f"{side['validation_mean_return']:.1f}; runs: "
          + ", ".join(f"seed {r['seed']} {r['validation_mean_return']:.1f}"
                      for r in side["recipe_runs"]) + ")")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
