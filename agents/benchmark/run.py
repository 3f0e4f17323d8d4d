"""The benchmark: standard algorithms on every non-calm level over training seeds, each run
evaluated on the level's frozen test set, aggregated with rliable (`agents.benchmark.report`).

    python -m agents.benchmark                         # every cell, one after the other
    python -m agents.benchmark --only SaddleTrap-Gusty-v0/ppo/0
    python -m agents.benchmark --address HOST:PORT     # the cells as tasks on a Ray cluster
    python -m agents.benchmark --report [--json]       # docs/benchmark.md from the results

A cell is (level, algorithm, training seed). Each algorithm runs with its library's generic
hyperparameters (`ALGOS`: no per-level tuning, no imitation: the row a researcher gets on a
first try) for one fixed budget of env steps; the ``ppo-fast`` row is the project's fast
recipe. Training starts from seed s (training episodes), and the final model is evaluated,
the network alone and deterministic, on the level's frozen test episodes (`TEST_SEED` ..,
never used in training). Each finished cell writes one JSON file to ``--out``
(``<level>/<algo>/seed<s>.json``), atomically; a killed suite resumes without redoing a
finished cell. docs/benchmark.md says how to add a row.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from saddle_env.envs import LEVELS, get_level
from saddle_env.jobs.files import write_text_atomically
from saddle_env.jobs.signals import SignalRecord, sigterm_interrupts

from ..paths import BENCHMARK_DATA
from ..seeds import TEST_SEED
from ..training.recipes import HYPERPARAMS_DIR

RESULTS = BENCHMARK_DATA / "results"
TEST_EPISODES = 1000          # the leaderboard's frozen test set
SEEDS = (0, 1, 2)
CALM = "SaddleTrap-v0"        # every sensible policy keeps every ball: not benchmarked


@dataclass(frozen=True)
class Algo:
    """One row: an algorithm, its library, the generic keywords it runs with and its
    budget in env steps."""

    name: str
    library: str                 # "stable_baselines3", "sb3_contrib" or "sbx" (recipe rows)
    cls: str
    budget: int
    n_envs: int
    policy: str = "MlpPolicy"
    kwargs: dict[str, Any] = field(default_factory=dict)
    note: str = ""
    # A project recipe instead of library defaults: the level whose entry in
    # agents/hyperparams/ppo.yml the row runs on every level, through
    # `agents.training.trainer.train` (warm start, wrappers, model selection on validation episodes,
    # as `train.py` does).
    recipe_of: str | None = None
    # The `train.py --backend` a recipe row trains with ("sbx": SBX's PPO). A recipe row
    # always reads ppo.yml (`hyperparams`), whatever the back end's own file: the SBX row
    # is ppo-fast's recipe with another learner, while agents/hyperparams/ppo_sbx.yml's
    # Capture entry has since been tuned for Capture alone (its rollout, schedule and
    # selection).
    backend: str = "sb3"


# Generic hyperparameters: each library's defaults, as a first try would use them. The only
# choices made are the number of balls stepped together (on-policy methods collect from a
# batch, off-policy ones step one ball per gradient step, as their defaults assume) and the
# budget, sized so a cell takes minutes on the 2-core machine (docs/benchmark.md).
ALGOS: dict[str, Algo] = {a.name: a for a in (
    Algo("ppo", "stable_baselines3", "PPO", budget=1_000_000, n_envs=8,
         note="SB3 defaults (n_steps 2048, batch 64, 10 epochs, lr 3e-4, 64x64 tanh)"),
    Algo("sac", "stable_baselines3", "SAC", budget=50_000, n_envs=1,
         note="SB3 defaults (lr 3e-4, batch 256, buffer 1e6, 1 gradient step per env step, "
              "256x256 ReLU, automatic entropy)"),
    Algo("tqc", "sb3_contrib", "TQC", budget=50_000, n_envs=1,
         note="sb3-contrib defaults (as SAC, 2 critics x 25 quantiles, drop 2 per net)"),
    Algo("recurrent-ppo", "sb3_contrib", "RecurrentPPO", budget=200_000, n_envs=8,
         policy="MlpLstmPolicy",
         note="sb3-contrib defaults (n_steps 128, batch 128, 10 epochs, LSTM 256, 64x64)"),
    Algo("ppo-fast", "stable_baselines3", "PPO", budget=3_000_000, n_envs=64,
         recipe_of="SaddleTrap-Capture-v0",
         note="the project's fast recipe (time to target, docs/training_profile.md): the "
              "fast entry of agents/hyperparams/ppo.yml (Gusty's, which Capture and Lab share) on "
              "every level (64 balls, 128x128, "
              "150-step training episodes, orbit-size reward shaping, normalised "
              "observations, warm start at the level's best constant speed), the model "
              "selected on validation episodes; no imitation"),
    Algo("ppo-fast-sbx", "sbx", "PPO", budget=3_000_000, n_envs=64,
         recipe_of="SaddleTrap-Capture-v0", backend="sbx",
         note="ppo-fast's recipe, steps and selection with SBX's PPO (JAX) as the learner "
              "(`train.py --backend sbx`): what the learner alone changes"),
)}


def cells(levels: Sequence[str] | None = None, algos: Sequence[str] | None = None,
          seeds: Sequence[int] = SEEDS) -> list[tuple[str, str, int]]:
    """(level, algorithm, seed) of every cell, in a fixed order."""
    levels = list(levels or [lv.id for lv in LEVELS if lv.id != CALM])
    algos = list(algos or ALGOS)
    # Seed-major: a partial table has every row on every level before any row has more seeds.
    return [(lv, a, s) for s in seeds for lv in levels for a in algos]


def result_path(out: Path, level: str, algo: str, seed: int) -> Path:
    """The result file of one run: ``<out>/<level>/<algo>/seed<seed>.json``."""
    return Path(out) / level / algo / f"seed{seed}.json"


def parse_only(text: str) -> tuple[str, str, int]:
    """``LEVEL/ALGO/SEED`` of ``--only``, checked."""
    parts = text.split("/")
    if len(parts) != 3:
        raise ValueError(f"--only must be LEVEL/ALGO/SEED, got {text!r}")
    level, algo, seed = parts
    get_level(level)
    if algo not in ALGOS:
        raise ValueError(f"--only: unknown algorithm {algo!r}; known: {sorted(ALGOS)}")
    try:
        s = int(seed)
    except ValueError:
        raise ValueError(f"--only: SEED must be an integer, got {seed!r}") from None
    if s < 0:
        raise ValueError(f"--only: SEED must be >= 0, got {s}")
    return level, algo, s


class RecurrentPolicy:
    """A RecurrentPPO model with the per-ball state `agents.control.rollout.PolicyActor` keeps: the
    LSTM's (hidden, cell) pair, (layers, balls, size) each in SB3, travels as one
    (balls, 2, layers, size) array."""

    row_independent = False

    def __init__(self, model: Any):
        self.model = model
        self.algo_name = "RecurrentPPO"
        self.observation_space = model.observation_space
        self.action_space = model.action_space

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """The actions for ``observation``, with each ball's LSTM state packed in ``state``."""
        lstm = None if state is None else (np.ascontiguousarray(state[:, 0].swapaxes(0, 1)),
                                           np.ascontiguousarray(state[:, 1].swapaxes(0, 1)))
        actions, (h, c) = self.model.predict(observation, state=lstm,
                                             episode_start=episode_start,
                                             deterministic=deterministic)
        return actions, np.stack([h.swapaxes(0, 1), c.swapaxes(0, 1)], axis=1)


def _versions() -> dict[str, str]:
    import importlib.metadata as md

    out = {"python": platform.python_version()}
    for pkg in ("saddle-env", "stable-baselines3", "sb3-contrib", "sbx-rl", "jax", "torch",
                "numpy", "numba", "gymnasium"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            pass
    return out


def run_cell(level_id: str, algo_name: str, seed: int, *, budget: int | None = None,
             episodes: int = TEST_EPISODES, torch_threads: int = 1,
             keep_runs: str | None = None) -> dict[str, Any]:
    """Train ``algo_name`` on ``level_id`` from training seed ``seed`` for its budget, then
    evaluate the final network on the level's test set; the result as a JSON-ready dict.
    ``keep_runs``: a recipe row's run folder is kept in ``<keep_runs>/<level>/runs/
    <algo>_seed<s>`` (its curve and models), where ``agents.benchmark.time_to_target --reuse``
    reads it; otherwise it is temporary."""
    import importlib

    import torch

    from ..evaluation.evaluate import evaluate
    from ..training.backends.sb3 import make_vec_env

    torch.set_num_threads(torch_threads)
    level = get_level(level_id)
    algo = ALGOS[algo_name]
    steps = int(budget or algo.budget)
    hyperparameters = {**algo.kwargs, "n_envs": algo.n_envs}
    began = time.time()
    if algo.recipe_of is not None:
        if keep_runs:
            policy, steps_done, hyperparameters = _train_recipe(
                level, algo, seed, steps, Path(keep_runs) / level.id, torch_threads)
        else:
            with tempfile.TemporaryDirectory(prefix="saddle-benchmark-") as work:
                policy, steps_done, hyperparameters = _train_recipe(level, algo, seed, steps,
                                                                    Path(work), torch_threads)
    else:
        cls = getattr(importlib.import_module(algo.library), algo.cls)
        env = make_vec_env(algo.n_envs, seed, level.config(), level.max_episode_steps)
        model = cls(algo.policy, env, seed=seed, device="cpu", verbose=0, **algo.kwargs)
        model.learn(steps)
        env.close()
        steps_done = int(model.num_timesteps)
        policy = RecurrentPolicy(model) if algo.cls == "RecurrentPPO" else model
    train_s = time.time() - began
    began = time.time()
    table, details = evaluate([(algo_name, policy)], level.config(), episodes, TEST_SEED,
                              max_episode_steps=level.max_episode_steps, examples=0,
                              env_id=level.id)
    eval_s = time.time() - began
    row = table["policies"][0]
    per_episode = details[row["policy"]]
    return {"level": level.id, "algo": algo_name, "seed": seed,
            "library": f"{algo.library}.{algo.cls}", "policy": algo.policy,
            "hyperparameters": hyperparameters, "note": algo.note,
            "budget_steps": steps, "steps_done": steps_done,
            "train_wall_s": round(train_s, 1), "steps_per_s": round(steps_done
                                                                    / max(train_s, 1e-9)),
            "eval_wall_s": round(eval_s, 1),
            "test": {"seed": TEST_SEED, "episodes": episodes},
            "trapping_time": row["trapping_time"], "kept": row["kept"], "return": row["return"],
            "episode_times": np.round(np.asarray(per_episode["time"], float), 4).tolist(),
            "versions": _versions(), "machine": f"{platform.machine()}, {os.cpu_count()} cores",
            "load_average_at_end": list(os.getloadavg()),
            "date": time.strftime("%Y-%m-%d %H:%M")}


def _train_recipe(level: Any, algo: Algo, seed: int, steps: int, work: Path,
                  torch_threads: int) -> tuple[Any, int, dict[str, Any]]:
    """Train ``algo``'s recipe (the ppo.yml entry of ``algo.recipe_of``, as ``train.py
    --recipe-of`` does) on ``level`` with `agents.training.trainer.train` into
    ``work/runs/<algo>_seed<s>`` (the layout `agents.benchmark.time_to_target` reads); the selected
    network as a policy, the steps done and the recipe. A run stopped by Ctrl-C or SIGTERM
    raises KeyboardInterrupt (no result)."""
    from ..evaluation.model_files import read_archive
    from ..evaluation.policies import load_policy
    from ..training.runs import recorded_settings
    from ..training.trainer import TrainSettings, train

    settings = TrainSettings(algo="ppo", env_id=level.id, seed=seed, total_timesteps=steps,
                             hyperparams=str(HYPERPARAMS_DIR / "ppo.yml"),
                             recipe_of=algo.recipe_of, backend=algo.backend,
                             log_dir=str(work / "runs"),
                             run_name=f"{algo.name}_seed{seed}",
                             compare_episodes=0, progress_bar=False,
                             torch_threads=torch_threads).validate()
    run_dir = train(settings)
    if not (run_dir / "final_model.zip").is_file():
        raise KeyboardInterrupt            # the back end stopped early: not a finished cell
    model = run_dir / "selected_model.zip"
    if not model.is_file():
        model = run_dir / "final_model.zip"
    # PPO learns whole rollouts, so it can pass the budget: the count the final model records
    steps_done = int(read_archive(run_dir / "final_model.zip").data["num_timesteps"])
    # the recipe the run trained with, as its config.json recorded it (the settings above are
    # the command line's; train() resolves the recipe into its own frozen copy)
    recipe = dict(recorded_settings(model).hyperparams_used)
    return load_policy(model, level.config()), steps_done, recipe


def write_result(out: Path, result: dict[str, Any]) -> Path:
    """Write a cell's result atomically (a killed run never leaves half a file)."""
    path = result_path(out, result["level"], result["algo"], int(result["seed"]))
    return write_text_atomically(path, json.dumps(result, indent=1) + "\n")


def _run_local(todo: list[tuple[str, str, int]], out: Path, cell: dict[str, Any],
               term: SignalRecord) -> int:
    for i, (lv, algo, seed) in enumerate(todo, 1):
        term.raise_if_lost()
        print(f"[{i}/{len(todo)}] {lv}/{algo}/{seed}: training "
              f"{cell['budget'] or ALGOS[algo].budget:,} steps", file=sys.stderr, flush=True)
        result = run_cell(lv, algo, seed, **cell)
        path = write_result(out, result)
        print(f"  {result['trapping_time']['mean']:.2f} s "
              f"[{result['trapping_time']['low']:.2f}, {result['trapping_time']['high']:.2f}], "
              f"{result['train_wall_s']:.0f} s training -> {path}", file=sys.stderr, flush=True)
    return len(todo)


def _run_ray(todo: list[tuple[str, str, int]], out: Path, cell: dict[str, Any],
             address: str) -> int:
    """Every cell as a Ray task (one CPU each) on the cluster at ``address``; results are
    written by the driver as they arrive."""
    import ray

    from ..training.backends.rllib import check_reachable

    if address != "local":
        check_reachable(address)
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    if address == "local":    # tests: a local Ray of two CPUs
        ray.init(num_cpus=2, include_dashboard=False, logging_level=logging.ERROR,
                 log_to_driver=False)
    else:
        ray.init(address=address, logging_level=logging.ERROR, log_to_driver=False)
    try:
        task = ray.remote(num_cpus=1)(run_cell)
        pending = {task.remote(lv, a, s, **cell): (lv, a, s)
                   for lv, a, s in todo}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            done_cell = pending.pop(done[0])
            path = write_result(out, ray.get(done[0]))
            print(f"{'/'.join(map(str, done_cell))} -> {path}", file=sys.stderr, flush=True)
    finally:
        ray.shutdown()
    return len(todo)


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m agents.benchmark``."""
    p = argparse.ArgumentParser(
        prog="python -m agents.benchmark",
        description="Standard algorithms on every non-calm level over training seeds, each "
                    "evaluated on the frozen test set; one JSON per finished run. --report "
                    "writes docs/benchmark.md and its figures from the result files.")
    p.add_argument("--levels", nargs="+", metavar="ID", default=None,
                   help="levels (default: every non-calm level)")
    p.add_argument("--algos", nargs="+", metavar="NAME", default=None,
                   help=f"rows (default: all of {', '.join(ALGOS)})")
    p.add_argument("--seeds", nargs="+", type=int, default=list(SEEDS),
                   help="training seeds (default 0 1 2)")
    p.add_argument("--only", metavar="LEVEL/ALGO/SEED", default=None, help="run one cell")
    p.add_argument("--budget", type=int, default=None,
                   help="env steps per run instead of each algorithm's (tests, smoke runs: "
                        "results at another budget are not the benchmark's)")
    p.add_argument("--episodes", type=int, default=TEST_EPISODES,
                   help=f"test episodes per run (default {TEST_EPISODES})")
    p.add_argument("--out", default=str(RESULTS), metavar="DIR",
                   help="result files (default benchmark_data/results)")
    p.add_argument("--address", default=None, metavar="HOST:PORT",
                   help="run the cells as tasks on this Ray cluster (the [rllib] extra's Ray); "
                        "'local' starts a local Ray of two CPUs")
    p.add_argument("--redo", action="store_true", help="rerun cells that have a result")
    p.add_argument("--keep-runs", default=None, metavar="DIR",
                   help="keep recipe rows' run folders in DIR/<level>/runs/ (curves, models), "
                        "where `python -m agents.benchmark.time_to_target --out DIR/<level> --label "
                        "ppo-fast --recipe-of SaddleTrap-Capture-v0 --reuse` reads them; "
                        "on a cluster DIR must be on a filesystem every node shares"),
    p.add_argument("--report", action="store_true",
                   help="write docs/benchmark.md and its figures from the result files")
    p.add_argument("--json", action="store_true", help="with --report: print the data as JSON")
    p.add_argument("--docs", default=None, metavar="DIR",
                   help="with --report: where benchmark.md and figures/ go (default docs/)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    out = Path(args.out)
    if args.report:
        from .report import main_report

        return main_report(out, ALGOS, SEEDS, TEST_EPISODES,
                           docs=Path(args.docs) if args.docs else None, as_json=args.json,
                           levels=[lv.id for lv in LEVELS if lv.id != CALM])
    try:
        if args.only:
            todo = [parse_only(args.only)]
        else:
            for lv in args.levels or []:
                get_level(lv)
            unknown = sorted(set(args.algos or []) - set(ALGOS))
            if unknown:
                raise ValueError(f"--algos: unknown {unknown}; known: {sorted(ALGOS)}")
            if any(s < 0 for s in args.seeds):
                raise ValueError("--seeds must be >= 0")
            todo = cells(args.levels, args.algos, args.seeds)
        if args.budget is not None and args.budget < 1:
            raise ValueError(f"--budget must be >= 1, got {args.budget}")
        if args.episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    except ValueError as exc:
        parser.error(str(exc))
    done = [c for c in todo if result_path(out, *c).is_file()]
    if not args.redo:
        todo = [c for c in todo if c not in done]
        if done:
            print(f"{len(done)} cell(s) already have results in {out}; running "
                  f"{len(todo)}", file=sys.stderr)

    try:
        cell = {"budget": args.budget, "episodes": args.episodes, "keep_runs": args.keep_runs}
        with sigterm_interrupts() as term:   # SIGTERM ends like Ctrl-C
            n = (_run_ray(todo, out, cell, args.address) if args.address
                 else _run_local(todo, out, cell, term))
    except KeyboardInterrupt:
        print(f"interrupted: the finished cells' results are in {out}; the same command "
              f"resumes", file=sys.stderr)
        return 130
    print(f"{n} cell(s) run; results in {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
