r"""Time to target: how many wall-clock seconds of training a recipe needs to beat the best
constant speed and to reach ``mpc``, ``python -m agents.benchmark.time_to_target --env ID``.

For each training seed (default 0, 1, 2) it trains the recipe (`agents.training.trainer.train`,
hyperparameters from ``--hyperparams`` or the back end's file: ``agents/hyperparams/ppo.yml``,
``ppo_sbx.yml`` with ``--backend sbx``) and reads the
run's validation curve against wall-clock time (``evaluations_wall.csv``: seconds since
``train()`` began, so the best-constant search or cache read, the imitation rounds with
their ``mpc`` queries, every evaluation and model selection count in the time).

**One sample.** The curve and the two targets are measured on the same episodes:
``reset(seed=VALIDATION_SEED + i)`` for i < ``--eval-episodes``, each to its end, through the
evaluation tool's function (`agents.evaluation.evaluate.evaluate`; every seed's run evaluates
on that set, `agents.training.selection`). The targets are **best-const's upper bound** (its
95 % bootstrap interval) and **mpc's mean**; each run's recorded episode set
(``curve_episodes.json``) is checked against the targets' (`same_episodes`: a ValueError,
not a figure, when they differ). For each seed the time to a target is the first
evaluation at or past it; the report gives the median over seeds (not reached by a seed
counts as never, so the median is "not reached" when most seeds miss).

A validation curve's maximum is a selected, noisy statistic. So each seed's selected model
is then evaluated on ``--final-episodes`` fresh episodes (seeds from `COMPARE_SEED`), with
best-const and ``mpc`` on the same episodes: the issue's target is an agent at ``mpc``'s
mean on 200 fresh episodes. ``--budgets B ...`` adds, on the same episodes, the network each
run would have shipped with a shorter budget B (`shorter_budgets`: what the selection rule
keeps among the evaluations up to B, read from the run's checkpoints).

Writes ``<out>/time_to_target.csv`` (every evaluation of every seed), ``.json`` (targets,
per-seed times, the fresh-episode table, the command) and the figure (``--figure``,
default ``<out>/time_to_target.png``; ``docs/figures/time_to_target.png`` for the docs) with
best-const and ``mpc`` as horizontal lines.

    python -m agents.benchmark.time_to_target --env SaddleTrap-Capture-v0
    python -m agents.benchmark.time_to_target --env SaddleTrap-Capture-v0 --hyperparams my.yml \
        --label fast --figure docs/figures/time_to_target.png
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..control.rollout import same_episodes
from ..seeds import COMPARE_SEED, VALIDATION_SEED
from ..training.runs import BACKEND_ALGOS


def _trapping(table: dict[str, Any], name: str) -> dict[str, float]:
    for row in table["policies"]:
        if row["policy"] == name:
            return row["trapping_time"]
    raise KeyError(name)


def references(env_id: str, episodes: int, seed: int, max_episode_steps: int | None = None,
               env_kwargs: dict[str, Any] | None = None) -> dict[str, Any]:
    """best-const and mpc's trapping time (mean, low, high) on ``episodes`` episodes from
    ``seed``."""
    from ..cli_args import resolve_env
    from ..evaluation.evaluate import evaluate

    level, config = resolve_env(env_id, env_kwargs or {})
    steps = int(max_episode_steps or level.max_episode_steps)
    table, _ = evaluate(["best-const", "mpc"], config, episodes, seed,
                        max_episode_steps=steps, examples=0, env_id=env_id)
    return {"episodes": episodes, "seed": seed, "episode_set": table["episode_set"],
            "best-const": _trapping(table, "best-const"), "mpc": _trapping(table, "mpc")}


def first_time(curve: list[dict[str, float]], level: float, strict: bool = False) -> float | None:
    """Wall seconds of the first evaluation at (or, ``strict``, past) ``level``; None if none."""
    for row in curve:
        t = row["mean_trapping_time"]
        if t > level or (not strict and t >= level):
            return row["wall_seconds"]
    return None


def median_time(times: list[float | None]) -> float | None:
    """Median with 'never' (None) as +inf; None if the median is never."""
    values = sorted(float("inf") if t is None else t for t in times)
    m = statistics.median(values)
    return None if m == float("inf") else m


def run(env_id: str, seeds: list[int], hyperparams: str | None, out: Path,
        label: str = "recipe", total_timesteps: int | None = None,
        eval_freq: int | None = None, eval_episodes: int | None = None,
        final_episodes: int = 200,
        max_episode_steps: int | None = None, figure: Path | None = None,
        log: Any = print, reuse: bool = False, recipe_of: str | None = None,
        algo: str = "ppo", backend: str = "sb3", budgets: Sequence[float] = ()) -> dict[str, Any]:
    """Train ``seeds`` with the recipe, measure the targets, write the files; return the
    summary (what the JSON holds). ``reuse``: a seed whose run folder
    (``<out>/runs/<label>_seed<s>``) holds a finished run is read, not trained again (its
    wall time is that of its last evaluation). ``budgets``: also what each shorter budget
    would have shipped (`shorter_budgets`)."""
    from ..training.run_report import WALL_CSV, curve_episodes, read_wall_rows
    from ..training.trainer import TrainSettings, recipe, train

    out.mkdir(parents=True, exist_ok=True)
    if eval_episodes is None:   # the recipe's, as training will take it
        probe = TrainSettings(algo=algo, backend=backend, env_id=env_id,
                              hyperparams=hyperparams, recipe_of=recipe_of).validate()
        eval_episodes = probe.with_recipe(recipe(probe)).eval_episodes
    log(f"targets: best-const and mpc on {eval_episodes} validation episodes "
        f"(seeds from {VALIDATION_SEED:,}) ...")
    ref = references(env_id, eval_episodes, VALIDATION_SEED, max_episode_steps)
    bc_high, mpc_mean = ref["best-const"]["high"], ref["mpc"]["mean"]
    log(f"best-const {ref['best-const']['mean']:.2f} [.., {bc_high:.2f}], mpc {mpc_mean:.2f}")
    per_seed, rows, run_dirs = [], [], []
    for s in seeds:
        settings = TrainSettings(algo=algo, backend=backend, env_id=env_id, seed=s,
                                 hyperparams=hyperparams,
                                 recipe_of=recipe_of, total_timesteps=total_timesteps, eval_freq=eval_freq,
                                 eval_episodes=eval_episodes, log_dir=str(out / "runs"),
                                 run_name=f"{label}_seed{s}", compare_episodes=0,
                                 max_episode_steps=max_episode_steps,
                                 progress_bar=False).validate()
        run_dir = out / "runs" / f"{label}_seed{s}"
        if reuse and (run_dir / "final_model.zip").is_file() \
                and (run_dir / WALL_CSV).is_file():
            curve = read_wall_rows(run_dir)          # a finished run of this recipe and seed
            wall = curve[-1]["wall_seconds"]
            log(f"seed {s}: reusing the finished run {run_dir}")
        else:
            started = time.time()
            run_dir = train(settings)
            wall = time.time() - started
            curve = read_wall_rows(run_dir)
        same_episodes(curve_episodes(run_dir), ref["episode_set"],
                      f"seed {s}'s validation curve and the best-const and mpc lines")
        run_dirs.append(run_dir)
        for row in curve:
            rows.append({"label": label, "seed": s, **row})
        per_seed.append({"seed": s, "wall_seconds": round(wall, 1),
                         "timesteps": settings.total_timesteps or int(curve[-1]["timesteps"]),
                         "best_validation": max(r["mean_trapping_time"] for r in curve),
                         "to_best_const_high": first_time(curve, bc_high, strict=True),
                         "to_mpc_mean": first_time(curve, mpc_mean)})
        log(f"seed {s}: {wall:.0f} s; best validation "
            f"{per_seed[-1]['best_validation']:.2f} s; past best-const's bound at "
            f"{per_seed[-1]['to_best_const_high']} s, at mpc's mean at "
            f"{per_seed[-1]['to_mpc_mean']} s")
    fresh, shorter = None, shorter_budgets(run_dirs, budgets, label, seeds, reselect=True)
    if final_episodes > 0:
        models = [(str(d / "selected_model.zip"), d / "selected_model.zip") for d in run_dirs]
        models += [(name, pick["model"]) for name, pick in shorter.items()]
        fresh = final_table(env_id, models, final_episodes, max_episode_steps)
    for pick in shorter.values():
        pick["model"] = str(pick["model"])
    summary = {"env_id": env_id, "label": label, "algo": algo, "backend": backend,
               "hyperparams": hyperparams,
               "recipe_of": recipe_of,
               "command": "python -m agents.benchmark.time_to_target " + " ".join(sys.argv[1:]),
               "targets": ref, "seeds": per_seed,
               "median_to_best_const_high": median_time([p["to_best_const_high"]
                                                         for p in per_seed]),
               "median_to_mpc_mean": median_time([p["to_mpc_mean"] for p in per_seed]),
               "shorter_budgets": shorter, "fresh_episodes": fresh}
    with open(out / "time_to_target.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["label", "seed", "timesteps", "wall_seconds",
                                          "mean_return", "mean_trapping_time"])
        w.writeheader()
        w.writerows(rows)
    (out / "time_to_target.json").write_text(json.dumps(summary, indent=1, default=str) + "\n")
    plot(rows, ref, figure or out / "time_to_target.png", f"{env_id}: {label}")
    return summary


def shorter_budgets(run_dirs: list[Path], budgets: Sequence[float], label: str,
                    seeds: list[int], reselect: bool = False) -> dict[str, dict[str, Any]]:
    """For each run and each budget B: the network the selection rule keeps among the
    run's evaluations at or before B steps, by ``<label>_seed<s>@<B>``, with its steps and
    the wall time of the last evaluation up to B. ``reselect``: the trainer's rule (the
    best `agents.training.selection.TOP` re-evaluated on its fresh episodes); else the
    curve's latest maximum alone. A shorter run with the same seed and a constant step
    size is a prefix of this one, so these are its networks, but for the one evaluation it
    would add at its very end. The network is the run's checkpoint at that evaluation: the
    checkpoint period must divide the evaluation period (ValueError otherwise)."""
    from ..training.run_report import read_wall_rows
    from ..training.runs import recorded_settings
    from ..training.selection import TOP, fresh_set, score

    picks = {}
    for seed, run_dir in zip(seeds, run_dirs):
        rows = read_wall_rows(run_dir)
        for budget in budgets:
            if not budget > 0:
                raise ValueError(f"--budgets must be positive step counts, got {budget:g}")
            upto = [r for r in rows if r["timesteps"] <= budget]
            if not upto:
                raise ValueError(f"--budgets: {run_dir} has no evaluation within {budget:g} "
                                 f"steps")
            ranked = sorted(upto, key=lambda r: (r["mean_return"], r["timesteps"]),
                            reverse=True)[:TOP if reselect else 1]
            models = {}
            for r in ranked:
                steps = int(r["timesteps"])
                models[steps] = run_dir / "checkpoints" / f"checkpoint_{steps}_steps.zip"
                if not models[steps].is_file():
                    raise ValueError(f"--budgets: no checkpoint at the evaluation of {steps} "
                                     f"steps in {run_dir} (--save-freq must divide "
                                     f"--eval-freq)")
            steps = int(ranked[0]["timesteps"])
            if reselect and len(models) > 1:
                settings = recorded_settings(models[steps])
                episodes = fresh_set(settings)
                steps = max(models, key=lambda k: (score(models[k], settings, episodes)
                                                   ["mean_return"], k))
            model = models[steps]
            picks[f"{label}_seed{seed}@{budget:g}"] = {
                "seed": seed, "budget": budget, "selected_at_steps": steps, "model": model,
                "wall_seconds": max(r["wall_seconds"] for r in upto)}
    return picks


def final_table(env_id: str, models: list[tuple[str, Path]], episodes: int,
                max_episode_steps: int | None = None) -> dict[str, Any]:
    """The (name, model file) ``models`` beside best-const and mpc on ``episodes`` fresh
    episodes (seeds from `COMPARE_SEED`): trapping time mean [low, high] per policy."""
    from ..cli_args import resolve_env
    from ..evaluation.evaluate import evaluate
    from ..evaluation.policies import load_policy

    level, config = resolve_env(env_id, {})
    steps = int(max_episode_steps or level.max_episode_steps)
    specs: list[Any] = [(name, load_policy(model, config)) for name, model in models]
    table, _ = evaluate(specs + ["best-const", "mpc"], config, episodes, COMPARE_SEED,
                        max_episode_steps=steps, examples=0, env_id=env_id)
    return {"episodes": episodes, "seed": COMPARE_SEED,
            "policies": {row["policy"]: row["trapping_time"] for row in table["policies"]}}


def plot(rows: list[dict[str, Any]], ref: dict[str, Any], path: Path, title: str) -> Path:
    """Plot the time-to-target ``rows`` against the references ``ref``; returns ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 3.8), dpi=100)
    for i, s in enumerate(sorted({r["seed"] for r in rows})):
        pts = [r for r in rows if r["seed"] == s]
        ax.plot([r["wall_seconds"] for r in pts], [r["mean_trapping_time"] for r in pts],
                marker="o", ms=3, color=f"C{i}", label=f"seed {s}")
    bc, mpc = ref["best-const"], ref["mpc"]
    ax.axhline(bc["mean"], color="0.4", ls="--", label=f"best-const {bc['mean']:.2f}")
    ax.axhspan(bc["low"], bc["high"], color="0.4", alpha=0.12)
    ax.axhline(mpc["mean"], color="C3", ls="-.", label=f"mpc {mpc['mean']:.2f}")
    ax.axvline(300, color="k", lw=0.6, ls=":")
    ax.set_xlabel("wall-clock seconds since training began")
    ax.set_ylabel(f"validation trapping time [s] ({ref['episodes']} ep.)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    ap = argparse.ArgumentParser(description="Wall-clock time for a recipe to beat "
                                             "best-const and reach mpc (median over seeds).",
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--env", default="SaddleTrap-Capture-v0", metavar="ID",
                    help="the task level to train on (an id of saddle_env.LEVELS)")
    ap.add_argument("--hyperparams", default=None, metavar="FILE.yml",
                    help="the recipe (None: agents/hyperparams/ppo.yml)")
    ap.add_argument("--recipe-of", default=None, metavar="ID",
                    help="use this level's entry of the recipe file (train.py --recipe-of)")
    ap.add_argument("--algo", choices=BACKEND_ALGOS["sb3"], default="ppo",
                    help="the Stable-Baselines3 algorithm (its file in agents/hyperparams "
                         "unless --hyperparams)")
    ap.add_argument("--backend", choices=("sb3", "sbx"), default="sb3",
                    help="the learner (train.py --backend); sbx reads "
                         "agents/hyperparams/ppo_sbx.yml unless --hyperparams")
    ap.add_argument("--label", default="recipe",
                    help="name of this recipe in the results; each seed's run folder is "
                         "OUT/runs/LABEL_seedS")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2],
                    help="training seeds, one run each (the report gives the median)")
    ap.add_argument("--total-timesteps", type=int, default=None,
                    help="budget of each run in env steps (None: the recipe's n_timesteps)")
    ap.add_argument("--eval-freq", type=int, default=None,
                    help="env steps between evaluations on the validation episodes (None: the "
                         "recipe's)")
    ap.add_argument("--eval-episodes", type=int, default=None,
                    help="validation episodes per evaluation (None: the recipe's, else 64)")
    ap.add_argument("--final-episodes", type=int, default=200,
                    help="fresh episodes for each seed's selected model (0: skip)")
    ap.add_argument("--max-episode-steps", type=int, default=None,
                    help="control steps per episode (None: the level's)")
    ap.add_argument("--out", default="time-to-target", metavar="DIR",
                    help="folder for the runs, time_to_target.csv and .json")
    ap.add_argument("--figure", default=None, metavar="PNG",
                    help="where the figure goes (None: OUT/time_to_target.png)")
    ap.add_argument("--budgets", type=float, nargs="+", default=[], metavar="STEPS",
                    help="also score, on the same fresh episodes, the network each run would "
                         "have selected with this shorter budget (from its checkpoints)")
    ap.add_argument("--reuse", action="store_true",
                    help="read, rather than retrain, a seed whose run folder in OUT/runs "
                         "already holds a finished run")
    args = ap.parse_args(argv)
    summary = run(args.env, args.seeds, args.hyperparams, Path(args.out), args.label,
                  args.total_timesteps, args.eval_freq, args.eval_episodes,
                  args.final_episodes, args.max_episode_steps,
                  Path(args.figure) if args.figure else None, reuse=args.reuse,
                  recipe_of=args.recipe_of, algo=args.algo, backend=args.backend,
                  budgets=args.budgets)
    print(json.dumps({k: summary[k] for k in ("median_to_best_const_high",
                                              "median_to_mpc_mean")}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
