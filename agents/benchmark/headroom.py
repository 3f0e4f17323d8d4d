"""How much is left to win on each level: the clairvoyant reference (`agents.control.clairvoyant`)
on seeded episodes, its trapping times beside `mpc`'s and the shipped agents', and the share
of *doomed* starts (balls even the clairvoyant loses) with a Wilson interval.

```
python -m agents.benchmark.headroom --levels SaddleTrap-Gusty-v0 --episodes 200 --seed 2000000 --out F
```
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from saddle_env.envs import EnvConfig

from ..control.clairvoyant import clairvoyant
from ..control.rollout import run_episodes
from ..evaluation.evaluate import bootstrap_interval, wilson_interval
from ..evaluation.policies import load_policy


def evaluate_clairvoyant(env_id: str | EnvConfig, episodes: int, seed: int = 2_000_000,
                         max_episode_steps: int | None = None, batch: int = 100,
                         progress: bool = False, agents: bool = True, **planner: Any
                         ) -> dict[str, Any]:
    """Run the clairvoyant on episodes ``seed .. seed + episodes − 1`` of a level (an id of
    `saddle_env.LEVELS`, or a config) through `agents.control.rollout.run_episodes`, ``batch``
    episodes per engine (results do not depend on it).

    Returns per-episode ``time`` and ``mpc_time`` [s] (mpc's on the same episodes, from
    the planner's first step), ``cause``; the summaries ``trapping_time`` and
    ``mpc_trapping_time`` (mean, bootstrap interval), ``doomed`` (share of balls the
    clairvoyant still loses, Wilson interval), ``mpc_lost``, ``rescued`` (balls mpc loses
    and the clairvoyant keeps) and ``seconds_per_episode`` (wall time, planning included).
    """
    from saddle_env.envs import get_level

    if isinstance(env_id, EnvConfig):
        config, steps, name = env_id, max_episode_steps or 500, None
    else:
        level = get_level(env_id)
        config, name = level.config(), level.id
        steps = max_episode_steps or level.max_episode_steps
    policy = clairvoyant(config, loader=load_policy if agents else None, **planner)
    seeds = seed + np.arange(episodes)
    causes: list[str]
    times, mpc_times, causes, plans = [], [], [], []
    incumbents: dict[str, list[float]] = {}
    t0 = time.perf_counter()
    for b in range(0, episodes, batch):
        act = policy.episode_actor()
        res = run_episodes(config, act, seeds[b:b + batch], max_episode_steps=steps,
                           row_independent=True)
        times.append(res["time"])
        causes.extend(res["cause"])
        mpc_times.append([p.mpc_time for p in act.plans])
        for p in act.plans:
            for k, v in (p.incumbents or {}).items():
                incumbents.setdefault(k, []).append(v)
        plans.extend(act.plans)
        if progress:
            done = min(b + batch, episodes)
            print(f"clairvoyant {name}: {done}/{episodes} episodes, "
                  f"{(time.perf_counter() - t0) / done:.2f} s/episode", flush=True)
    wall = time.perf_counter() - t0
    time_arr = np.concatenate(times)
    mpc_arr = np.concatenate([np.asarray(m, float) for m in mpc_times])
    full = steps * config.control_period
    kept = np.array([c == "kept" for c in causes])
    mpc_kept = mpc_arr >= full - 1e-9

    def share(k: int) -> dict[str, float]:     # Wilson, its rounding kept around the mean
        w = wilson_interval(k, episodes)
        return {"mean": w["mean"], "low": min(w["low"], w["mean"]),
                "high": max(w["high"], w["mean"])}

    return {"env_id": name, "episodes": episodes, "seed": seed, "episode_length_s": full,
            "time": time_arr, "mpc_time": mpc_arr, "cause": np.array(causes, dtype=object),
            "trapping_time": bootstrap_interval(time_arr),
            "mpc_trapping_time": bootstrap_interval(mpc_arr),
            "doomed": share(int((~kept).sum())), "mpc_lost": share(int((~mpc_kept).sum())),
            "rescued": int((kept & ~mpc_kept).sum()),
            "incumbents": {k: np.asarray(v) for k, v in incumbents.items()},
            "incumbent_trapping_time": {k: bootstrap_interval(np.asarray(v))
                                        for k, v in incumbents.items()},
            "rounds": int(sum(p.rounds for p in plans)),
            "seconds_per_episode": wall / episodes}


def main(argv: Any = None) -> int:
    """``python -m agents.benchmark.headroom [--levels ID ...] [--episodes N] [--seed S] [--out F]``:
    the clairvoyant on each level's episodes (default: the leaderboard's test seeds), one JSON
    line per level (also appended to ``--out``)."""
    import argparse
    import json

    from saddle_env.envs import LEVEL_IDS

    p = argparse.ArgumentParser(prog="python -m agents.benchmark.headroom", description=main.__doc__)
    p.add_argument("--levels", nargs="+", default=list(LEVEL_IDS[1:]), metavar="ID",
                   help="level ids (default: every level but the calm SaddleTrap-v0)")
    p.add_argument("--episodes", type=int, default=100,
                   help="episodes per level (default 100)")
    p.add_argument("--seed", type=int, default=2_000_000,
                   help="first episode seed; episodes use SEED .. SEED + EPISODES - 1 "
                        "(default 2000000, the leaderboard's test seeds)")
    p.add_argument("--batch", type=int, default=100,
                   help="episodes per engine (memory against speed; the results do not "
                        "depend on it; default 100)")
    p.add_argument("--max-rounds", type=int, default=400,
                   help="candidate batches the clairvoyant scores per lost ball at most "
                        "(default 400)")
    p.add_argument("--out", default=None, metavar="FILE",
                   help="also append each level's JSON line, with its per-episode results, "
                        "to FILE")
    args = p.parse_args(argv)
    for lvl in args.levels:
        r = evaluate_clairvoyant(lvl, args.episodes, args.seed, batch=args.batch, progress=True,
                                 max_rounds=args.max_rounds)
        row = {k: v for k, v in r.items() if k not in ("time", "mpc_time", "cause", "incumbents")}
        row["max_rounds"] = args.max_rounds
        row["per_episode"] = {"time": np.round(r["time"], 9).tolist(),
                              "mpc_time": np.round(r["mpc_time"], 9).tolist(),
                              "cause": list(r["cause"]),
                              "incumbents": {k: np.round(v, 9).tolist()
                                             for k, v in r["incumbents"].items()}}
        line = json.dumps(row)
        print(json.dumps({k: v for k, v in row.items() if k != "per_episode"}), flush=True)
        if args.out:
            with open(args.out, "a") as fh:
                fh.write(line + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())




__all__ = ["evaluate_clairvoyant", "main"]
