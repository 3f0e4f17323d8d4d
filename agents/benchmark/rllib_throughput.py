"""Training throughput: RLlib with 1 and 2 env runners against the SB3 path, in one run.

    python -m agents.benchmark.rllib_throughput [--seconds S] [--n-envs N] [--runners 1,2]
                                     [--num-cpus C] [--out DIR] [--no-figure]

PPO on SaddleTrap-v0 with the same recipe on every path (the level's ``ppo.yml`` entry:
``n_steps × n_envs`` samples per update, 10 epochs, 64-64 networks). For each path:

* **sampling**: env steps sampled per second — SB3: ``collect_rollouts`` (the policy and
  the batch adapter, all balls in one compiled call), RLlib: RLlib's own synchronous
  sampling over every env runner, each stepping ``--n-envs`` balls through the native
  vector env (``gym_env_vectorize_mode="vector_entry_point"``); for comparison RLlib's
  ``sync`` mode, one Python env per ball, with the largest runner count;
* **learner**: env steps of a rollout learned per second (all epochs of one update);
* **training**: env steps per second of whole training iterations (sample + learn +
  weight sync).

Every figure is the mean over ``--seconds`` of repeated measurements, after one warm-up.
Writes to ``--out`` (default ``bench_results/rllib``) after every measurement, so that
Ctrl-C keeps what was done: ``throughput.json`` (all figures and the machine),
``throughput.csv`` (one row per path) and ``throughput.png`` (bars; needs matplotlib).
On a shared machine the absolute numbers are noisy; the ratios within one run are the
figures to quote. Needs the ``[rllib]`` extra.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

COLUMNS = ("path", "env_runners", "balls_per_runner", "sampling_steps_per_s",
           "learner_steps_per_s", "training_steps_per_s")
ENV_ID = "SaddleTrap-v0"


class _Results:
    """Figures written to disk as soon as they are measured."""

    def __init__(self, out: Path, meta: dict):
        out.mkdir(parents=True, exist_ok=True)
        self.rows: list[dict]
        self.out, self.meta, self.rows = out, meta, []

    def add(self, row: dict) -> None:
        self.rows.append(row)
        with open(self.out / "throughput.csv", "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=COLUMNS)
            w.writeheader()
            w.writerows({k: r.get(k) for k in COLUMNS} for r in self.rows)
        (self.out / "throughput.json").write_text(
            json.dumps(dict(self.meta, paths=self.rows), indent=2) + "\n")


def _rate(fn, seconds: float) -> float:
    """Steps per second of ``fn()`` (which returns the steps it did and the seconds to
    count), repeated for ``seconds`` after one warm-up call."""
    fn()
    steps = spent = 0.0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds or spent == 0:
        n, dt = fn()
        steps, spent = steps + n, spent + dt
    return steps / spent


def sb3_rates(n_envs: int, seconds: float) -> dict:
    """Sampling, learner and training throughput of the SB3 path (`agents.training.trainer`)."""
    import torch
    from stable_baselines3 import PPO

    from ..cli_args import resolve_env
    from ..training.backends.sb3 import make_vec_env
    from ..training.recipes import load_hyperparams, parse_policy_kwargs

    torch.set_num_threads(1)
    hyper = load_hyperparams("ppo", ENV_ID)
    env = make_vec_env(n_envs, 0, resolve_env(ENV_ID)[1], 500)
    kwargs = {k: hyper[k] for k in ("n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda",
                                    "learning_rate", "clip_range", "ent_coef")}
    model = PPO("MlpPolicy", env, seed=0, device="cpu", verbose=0,
                policy_kwargs=parse_policy_kwargs(hyper["policy_kwargs"]), **kwargs)
    batch = model.n_steps * n_envs
    timer: dict[str, Any] = {"train": 0.0}   # seconds in train(); "last": (total, train)
    train = model.train

    def timed_train():
        t = time.perf_counter()
        train()
        timer["train"] += time.perf_counter() - t

    timed_model: Any = model  # Any: an instance's method replaced, which SB3's types forbid
    timed_model.train = timed_train
    model.learn(batch)                                    # warm-up (compiles, allocates)

    def iteration():
        timer["train"] = 0.0
        t = time.perf_counter()
        model.learn(batch, reset_num_timesteps=False)
        total = time.perf_counter() - t
        timer["last"] = (total, timer["train"])
        return batch, total

    samples = {"sample": 0.0, "learn": 0.0, "steps": 0}

    def both():
        n, total = iteration()
        samples["sample"] += total - timer["train"]
        samples["learn"] += timer["train"]
        samples["steps"] += n
        return n, total

    training = _rate(both, seconds)
    env.close()
    return {"path": "sb3", "env_runners": 0, "balls_per_runner": n_envs,
            "sampling_steps_per_s": samples["steps"] / samples["sample"],
            "learner_steps_per_s": samples["steps"] / samples["learn"],
            "training_steps_per_s": training}


def rllib_rates(runners: int, n_envs: int, seconds: float, mode: str = "vector_entry_point",
                learner: bool = True) -> dict:
    """Sampling (and learner, training) throughput of RLlib with ``runners`` env runners."""
    from ray.rllib.env.single_agent_episode import SingleAgentEpisode
    from ray.rllib.execution.rollout_ops import synchronous_parallel_sample
    from ray.rllib.utils.metrics import NUM_ENV_STEPS_SAMPLED_LIFETIME

    from ..training.backends import rllib as rb
    from ..training.recipes import load_hyperparams
    from ..training.runs import TrainSettings

    hyper = load_hyperparams("ppo", ENV_ID)
    settings = TrainSettings(backend="rllib", env_id=ENV_ID, num_env_runners=runners,
                             n_envs=n_envs).validate().with_recipe(hyper)
    config = rb.build_config(settings, hyper)
    if mode != "vector_entry_point":
        config = config.env_runners(gym_env_vectorize_mode=mode)
    algo = config.build_algo()
    batch = config.total_train_batch_size
    try:
        def episodes_of_one_batch() -> list[SingleAgentEpisode]:
            # With the new env runners RLlib's sampler returns single-agent episodes; its
            # return type names every kind it ever returned.
            got = synchronous_parallel_sample(worker_set=algo.env_runner_group,
                                              max_env_steps=batch, _uses_new_env_runners=True)
            episodes = [e for e in got if isinstance(e, SingleAgentEpisode)] \
                if isinstance(got, list) else []
            if not isinstance(got, list) or len(episodes) != len(got):
                raise TypeError(f"RLlib sampled {type(got).__name__}, not single-agent episodes")
            return episodes

        def sample():
            t = time.perf_counter()
            episodes = episodes_of_one_batch()
            return sum(len(e) for e in episodes), time.perf_counter() - t

        row = {"path": f"rllib ({'native vector env' if mode == 'vector_entry_point' else mode})",
               "env_runners": runners, "balls_per_runner": n_envs,
               "sampling_steps_per_s": _rate(sample, seconds)}
        if learner:
            def learn():
                episodes = episodes_of_one_batch()
                n = sum(len(e) for e in episodes)
                t = time.perf_counter()
                algo.learner_group.update(episodes=episodes,
                                          timesteps={NUM_ENV_STEPS_SAMPLED_LIFETIME: n},
                                          num_epochs=config.num_epochs,
                                          minibatch_size=config.minibatch_size,
                                          shuffle_batch_per_epoch=True)
                return n, time.perf_counter() - t

            def train():
                before = rb.lifetime_steps(algo)
                t = time.perf_counter()
                algo.train()
                return rb.lifetime_steps(algo) - before, time.perf_counter() - t

            row["learner_steps_per_s"] = _rate(learn, seconds)
            row["training_steps_per_s"] = _rate(train, seconds)
        return row
    finally:
        algo.stop()


def plot(rows: list[dict], path: Path) -> bool:
    """Plot the throughput ``rows`` to ``path``; False if matplotlib is missing."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    labels = [f"{r['path']}\n{r['env_runners']} runner(s)" if r["env_runners"] else r["path"]
              for r in rows]
    keys = ("sampling_steps_per_s", "learner_steps_per_s", "training_steps_per_s")
    fig, ax = plt.subplots(figsize=(8.5, 4.2))
    width = 0.27
    for k, key in enumerate(keys):
        ax.bar([i + (k - 1) * width for i in range(len(rows))],
               [r.get(key) or 0 for r in rows], width, label=key.replace("_steps_per_s", ""))
    ax.set_xticks(range(len(rows)), labels, fontsize=8)
    ax.set_ylabel("env steps per second")
    ax.set_title("PPO on SaddleTrap-v0: SB3 against RLlib (same run)")
    ax.legend()
    ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def _ints(text: str) -> list[int]:
    try:
        values = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected positive integers, got {text!r}")
    return values


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m agents.benchmark.rllib_throughput``."""
    ap = argparse.ArgumentParser(prog="python -m agents.benchmark.rllib_throughput",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="timing window per figure")
    ap.add_argument("--n-envs", type=int, default=16,
                    help="balls per env runner, and the SB3 path's balls (default 16, the "
                         "SaddleTrap-v0 recipe's)")
    ap.add_argument("--runners", type=_ints, default=[1, 2], help="env runner counts (1,2)")
    ap.add_argument("--num-cpus", type=int, default=None, help="CPUs of the local Ray")
    ap.add_argument("--out", type=Path, default=Path("bench_results/rllib"), metavar="DIR",
                    help="folder for throughput.json, .csv and .png (default bench_results/rllib)")
    ap.add_argument("--no-sync", action="store_true",
                    help="skip RLlib's sync mode (one Python env per ball)")
    ap.add_argument("--no-figure", action="store_true",
                    help="write no throughput.png (matplotlib not needed)")
    return ap


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    ap = build_parser()
    args = ap.parse_args(argv)
    if not args.seconds > 0 or args.n_envs < 1:
        ap.error("--seconds must be > 0 and --n-envs >= 1")
    from ..training.backends import rllib as rb

    try:
        rb.check_dependencies()
    except rb.MissingExtra as exc:
        ap.exit(2, f"{ap.prog}: error: {exc}\n")
    import numba

    meta = {"env_id": ENV_ID, "seconds": args.seconds, "n_envs": args.n_envs,
            "machine": {"python": platform.python_version(), "platform": platform.platform(),
                        "cpus": os.cpu_count(), "numba_threads": numba.get_num_threads(),
                        "load_average_at_start": list(os.getloadavg())}}
    res = _Results(args.out, meta)
    started = False
    try:
        print("SB3 path ...", flush=True)
        row = sb3_rates(args.n_envs, args.seconds)
        res.add(row)
        _say(row)
        started = rb.init_ray(None, args.num_cpus)
        import ray

        meta["ray"] = ray.__version__
        meta["ray_cpus"] = ray.cluster_resources().get("CPU")
        for n in args.runners:
            print(f"RLlib, {n} env runner(s) ...", flush=True)
            row = rllib_rates(n, args.n_envs, args.seconds)
            res.add(row)
            _say(row)
        if not args.no_sync:
            n = max(args.runners)
            print(f"RLlib, {n} env runner(s), sync mode (one Python env per ball) ...",
                  flush=True)
            row = rllib_rates(n, args.n_envs, args.seconds, mode="sync", learner=False)
            res.add(row)
            _say(row)
    except KeyboardInterrupt:
        print(f"\ninterrupted: the figures measured so far are in {args.out}", file=sys.stderr)
        return 130
    finally:
        if "ray" in sys.modules and started:
            sys.modules["ray"].shutdown()
    meta["load_average_at_end"] = list(os.getloadavg())
    (args.out / "throughput.json").write_text(json.dumps(dict(meta, paths=res.rows), indent=2)
                                              + "\n")
    if not args.no_figure and plot(res.rows, args.out / "throughput.png"):
        print(f"wrote {args.out / 'throughput.png'}")
    print(f"wrote {args.out / 'throughput.json'}, throughput.csv")
    return 0


def _say(row: dict) -> None:
    parts = [f"{k.replace('_steps_per_s', '')} {row[k]:,.0f}/s" for k in COLUMNS[3:]
             if row.get(k) is not None]
    print(f"  {row['path']}, {row['env_runners']} runner(s) x {row['balls_per_runner']} balls: "
          + ", ".join(parts), flush=True)


if __name__ == "__main__":
    sys.exit(main())
