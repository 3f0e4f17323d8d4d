"""``saddle-eval``: evaluate policies (baselines or Stable-Baselines3 model files) on the
same seeded episodes of SaddleTrap-v0 and tabulate how long they keep the ball.

```
saddle-eval --policy const-1.2 --policy mpc --policy runs/ppo/model.zip \\
            --episodes 200 --seed 0 [--env-kwargs R=0.033 air_force=0.3] [--json] [--out DIR]
```

Episode i is ``reset(seed=seed + i)`` of the environment with ``--env-kwargs``, stepped
until the ball is lost or for ``--max-episode-steps`` control steps. Every policy sees the
same episodes. Results do not depend on batching: balls are independent in the engine;
baselines act row by row, and model files act on fixed-size chunks of ``CHUNK`` episodes
(padded), with torch on one thread (set by the command line).

Metrics per policy (mean and 95 % interval over episodes):

| key | meaning | interval |
|---|---|---|
| ``trapping_time`` | time until the ball is lost (the episode length if it is kept) [s] | bootstrap |
| ``kept`` | fraction kept for the whole episode | Wilson |
| ``detach`` / ``escape`` | fraction lost by detachment / by leaving the rim | Wilson |
| ``mean_distance_mm`` | time-averaged distance of the contact point from the axis [mm] | bootstrap |
| ``effort`` | mean action² per step | bootstrap |
| ``return`` | sum of the environment's rewards | bootstrap |

Writes ``results.json``, ``results.md``, ``episodes.json`` (per-episode values) and, unless
``--no-plots``, ``trapping_time.png`` (survival curves and histograms) and ``examples.png``
(Ω(t) and r(t) of the first episodes) to ``--out``. ``--json`` prints the table as JSON on
stdout and nothing else; progress goes to stderr.
"""

from __future__ import annotations

import argparse
import ast
import json
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from saddle_env.envs import DEFAULT_EPISODE_STEPS, EnvConfig

CHUNK = 100          # episodes per batch for model files (fixed: batch-independent actions)
N_EXAMPLES = 3       # episodes whose Ω(t), r(t) are recorded for the plots
METRICS = ("trapping_time", "kept", "detach", "escape", "mean_distance_mm", "effort", "return")
RATES = ("kept", "detach", "escape")

Actor = Callable[[np.ndarray, np.ndarray], np.ndarray]


# --------------------------------------------------------------------------------------
# Running episodes
# --------------------------------------------------------------------------------------
def run_episodes(config: EnvConfig, act: Actor, seeds: Sequence[int] | np.ndarray, *,
                 max_episode_steps: int = DEFAULT_EPISODE_STEPS, row_independent: bool = True,
                 record: int = 0, progress: bool | str = False) -> dict[str, np.ndarray]:
    """Run one episode per seed (episode i: ``reset(seed=seeds[i])``) and collect statistics.

    ``act(obs, idx)`` returns the actions (len(idx),) or (len(idx), 1) for the balls ``idx``
    still in play, given the batch of observations ``obs``. With ``row_independent`` the
    whole set runs as one batch; otherwise in chunks of ``CHUNK`` episodes (the last padded
    with extra seeds), so that a policy always sees the same batch shape.

    Returns per-episode arrays: ``time`` [s], ``kept``, ``cause`` ("detach", "escape" or
    "kept"), ``mean_r`` [m], ``effort``, ``return``, ``min_normal`` (N/mg at step ends), and
    for the first ``record`` episodes ``trace_omega``, ``trace_r`` ((record, steps + 1),
    NaN after the end) and ``trace_t``.
    """
    from saddle_env.envs.vector import SaddleTrapVectorEnv

    seeds = np.asarray(seeds, dtype=np.int64)
    n = len(seeds)
    if row_independent:
        chunks = [seeds]
    else:
        pad = (-n) % CHUNK
        padded = np.concatenate([seeds, seeds.max() + 1 + np.arange(pad)]) if pad else seeds
        chunks = [padded[i:i + CHUNK] for i in range(0, len(padded), CHUNK)]
    dt = config.control_period
    out = {"time": np.zeros(n), "kept": np.zeros(n, dtype=bool),
           "cause": np.full(n, "kept", dtype=object), "mean_r": np.zeros(n),
           "effort": np.zeros(n), "return": np.zeros(n), "min_normal": np.full(n, np.inf)}
    record = min(record, n)
    trace_omega = np.full((record, max_episode_steps + 1), np.nan)
    trace_r = np.full((record, max_episode_steps + 1), np.nan)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(chunks) * max_episode_steps, unit="step", file=sys.stderr,
                   desc=progress if isinstance(progress, str) else None, leave=False,
                   mininterval=0.5)
    kw = config.as_dict()
    start = 0
    for chunk in chunks:
        m = len(chunk)
        keep = min(m, n - start)                  # rows that are real episodes
        env = SaddleTrapVectorEnv(num_envs=m, max_episode_steps=max_episode_steps, **kw)
        obs, info = env.reset(seed=[int(s) for s in chunk])
        if hasattr(act, "start"):
            act.start(m)
        alive = np.ones(m, dtype=bool)
        t_trap, r_sum, a_sum, ret = np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m)
        steps = np.zeros(m, dtype=np.int64)
        min_n = np.asarray(info["N_over_mg"], dtype=float).copy()
        cause = np.full(m, "kept", dtype=object)
        rec = [j for j in range(m) if start + j < record]
        for j in rec:
            trace_omega[start + j, 0] = info["omega"][j]
            trace_r[start + j, 0] = math.hypot(*env.engine.Y[j, :2])
        actions = np.zeros((m, 1), dtype=np.float32)
        for step in range(max_episode_steps):
            idx = np.flatnonzero(alive)
            a = np.asarray(act(obs, idx), dtype=np.float32).reshape(len(idx))
            actions[:] = 0.0
            actions[idx, 0] = a
            obs, rew, term, trunc, info = env.step(actions)
            r = np.hypot(env.engine.Y[:, 0], env.engine.Y[:, 1])
            t_trap[idx] += info["trapped_fraction"][idx] * dt
            r_sum[idx] += r[idx]
            a_sum[idx] += np.clip(a.astype(np.float64), -1, 1) ** 2
            ret[idx] += rew[idx]
            steps[idx] += 1
            min_n[idx] = np.minimum(min_n[idx], info["N_over_mg"][idx])
            for j in rec:
                if alive[j]:
                    trace_omega[start + j, step + 1] = info["omega"][j]
                    trace_r[start + j, step + 1] = r[j]
            for j in np.flatnonzero(term & alive):
                cause[j] = info["cause"][j]
            alive &= ~(term | trunc)
            if bar is not None:
                bar.update(1)
            if not alive[:keep].any():
                if bar is not None:
                    bar.update(max_episode_steps - step - 1)
                break
        env.close()
        sl = slice(start, start + keep)
        out["time"][sl] = t_trap[:keep]
        out["cause"][sl] = cause[:keep]
        out["kept"][sl] = cause[:keep] == "kept"
        out["mean_r"][sl] = r_sum[:keep] / np.maximum(steps[:keep], 1)
        out["effort"][sl] = a_sum[:keep] / np.maximum(steps[:keep], 1)
        out["return"][sl] = ret[:keep]
        out["min_normal"][sl] = min_n[:keep]
        start += keep
    if bar is not None:
        bar.close()
    out["trace_omega"], out["trace_r"] = trace_omega, trace_r
    out["trace_t"] = np.arange(max_episode_steps + 1) * dt
    return out


class PolicyActor:
    """``act(obs, idx)`` for `run_episodes` from a policy with SB3's ``predict``.

    Row-independent policies (the baselines) see only the balls in play; others (model
    files) the whole batch. A state returned by ``predict`` (SB3's recurrent slot, used by
    the ``mpc`` baseline's estimators) is kept per ball and passed back, with
    ``episode_start`` True on each ball's first step.
    """

    def __init__(self, policy: Any):
        self.policy = policy
        self.row_independent = bool(getattr(policy, "row_independent", False))
        self.state: np.ndarray | None = None
        self.fresh = np.ones(0, dtype=bool)

    def start(self, n: int) -> None:
        self.state, self.fresh = None, np.ones(n, dtype=bool)

    def __call__(self, obs: np.ndarray, idx: np.ndarray) -> np.ndarray:
        rows = idx if self.row_independent else np.arange(len(obs))
        if len(rows) == 0:
            return np.zeros(0)
        state = None if self.state is None else self.state[rows]
        actions, new_state = self.policy.predict(obs[rows], state=state,
                                                 episode_start=self.fresh[rows],
                                                 deterministic=True)
        if isinstance(new_state, np.ndarray) and new_state.ndim >= 1 and len(new_state) == len(rows):
            if self.state is None:
                self.state = np.zeros((len(obs),) + new_state.shape[1:], dtype=new_state.dtype)
            self.state[rows] = new_state
        self.fresh[rows] = False
        actions = np.asarray(actions).reshape(len(rows))
        return actions if self.row_independent else actions[idx]


def policy_actor(policy: Any) -> tuple[PolicyActor, bool]:
    """(actor, row_independent) for `run_episodes`."""
    actor = PolicyActor(policy)
    return actor, actor.row_independent


# --------------------------------------------------------------------------------------
# Statistics
# --------------------------------------------------------------------------------------
BOOTSTRAP = 4000  # resamples of the percentile bootstrap (fixed seed: deterministic)


def bootstrap_interval(x: np.ndarray, seed: int = 0) -> dict[str, float]:
    """Mean and 95 % percentile-bootstrap interval (stays within the data's range, unlike
    a t interval on bounded, skewed data such as trapping times)."""
    x = np.asarray(x, dtype=float)
    mean = float(x.mean())
    if len(x) < 2:
        return {"mean": mean, "low": mean, "high": mean}
    rng = np.random.default_rng(seed)
    means = x[rng.integers(0, len(x), size=(BOOTSTRAP, len(x)))].mean(axis=1)
    low, high = np.quantile(means, [0.025, 0.975])
    return {"mean": mean, "low": min(float(low), mean), "high": max(float(high), mean)}


def t_interval(x: np.ndarray) -> dict[str, float]:
    """Mean and 95 % Student-t interval."""
    from scipy import stats

    x = np.asarray(x, dtype=float)
    mean = float(x.mean())
    if len(x) < 2:
        return {"mean": mean, "low": mean, "high": mean}
    half = float(stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / math.sqrt(len(x)))
    return {"mean": mean, "low": mean - half, "high": mean + half}


def wilson_interval(successes: int, n: int) -> dict[str, float]:
    """A proportion and its 95 % Wilson score interval (sensible at 0 and 1 too)."""
    z = 1.959963984540054
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return {"mean": p, "low": max(0.0, centre - half), "high": min(1.0, centre + half)}


def summarise(res: dict[str, np.ndarray]) -> dict[str, dict[str, float]]:
    n = len(res["time"])
    causes = res["cause"]
    table = {"trapping_time": bootstrap_interval(res["time"]),
             "kept": wilson_interval(int(np.sum(causes == "kept")), n),
             "detach": wilson_interval(int(np.sum(causes == "detach")), n),
             "escape": wilson_interval(int(np.sum(causes == "escape")), n),
             "mean_distance_mm": bootstrap_interval(1000.0 * res["mean_r"]),
             "effort": bootstrap_interval(res["effort"]),
             "return": bootstrap_interval(res["return"])}
    return {k: {kk: round(vv, 6) for kk, vv in v.items()} for k, v in table.items()}


# --------------------------------------------------------------------------------------
# Evaluation of named policies
# --------------------------------------------------------------------------------------
def policy_label(policy: Any, spec: str) -> tuple[str, str]:
    """(label, kind) of a loaded policy: a baseline's name, or a model file's path and algorithm."""
    if hasattr(policy, "algo_name"):
        return spec, policy.algo_name
    return getattr(policy, "name", spec), "baseline"


def evaluate(specs: Sequence[str | tuple[str, Any]], config: EnvConfig, episodes: int, seed: int,
             max_episode_steps: int = DEFAULT_EPISODE_STEPS, progress: bool = False,
             examples: int = N_EXAMPLES) -> tuple[dict[str, Any], dict[str, Any]]:
    """Evaluate every policy on episodes ``seed .. seed + episodes − 1``.

    ``specs``: baseline names or model paths (see `load_policy`), or (spec, policy) pairs of
    already loaded policies. Returns (table, details): the table is what ``--json`` prints;
    details hold the per-episode arrays and traces for files and plots.
    """
    from .baselines import load_policy

    table: dict[str, Any] = {"env_kwargs": _nondefault(config), "episodes": episodes, "seed": seed,
                             "max_episode_steps": max_episode_steps,
                             "episode_length_s": round(max_episode_steps * config.control_period, 9),
                             "policies": []}
    details: dict[str, Any] = {}
    seeds = seed + np.arange(episodes)
    for item in specs:
        spec, policy = item if isinstance(item, tuple) else (item, load_policy(item, config))
        _check_compatible(policy, config, spec)
        label, kind = policy_label(policy, spec)
        act, row_independent = policy_actor(policy)
        res = run_episodes(config, act, seeds, max_episode_steps=max_episode_steps,
                           row_independent=row_independent, record=examples,
                           progress=label if progress else False)
        row = {"policy": label, "kind": kind, **summarise(res)}
        if hasattr(policy, "omega"):
            row["omega"] = round(float(policy.omega), 6)
        table["policies"].append(row)
        details[label] = res
    return table, details


def _check_compatible(policy: Any, config: EnvConfig, spec: str) -> None:
    space = getattr(policy, "observation_space", None)
    want = 7 if config.obs_frame == "lab" else 5
    if space is not None and tuple(space.shape) != (want,):
        raise ValueError(f"{spec}: the policy expects observations of shape {tuple(space.shape)}, "
                         f"the environment gives ({want},) (obs_frame={config.obs_frame!r}); "
                         "pass the --env-kwargs it was trained with")


def _warn_if_trained_elsewhere(spec: str, config: EnvConfig, max_episode_steps: int) -> None:
    from .baselines import model_sidecar

    side = model_sidecar(spec if spec.endswith(".zip") else spec + ".zip")
    if not side or not isinstance(side.get("env_kwargs"), dict):
        return
    try:
        trained = EnvConfig.from_kwargs(**parse_env_kwargs([json.dumps(side["env_kwargs"])]))
    except (ValueError, TypeError):
        return
    if trained != config:
        print(f"saddle-eval: warning: {spec} was trained with env kwargs "
              f"{json.dumps(_nondefault(trained))}, evaluated with "
              f"{json.dumps(_nondefault(config))}", file=sys.stderr)


def _nondefault(config: EnvConfig) -> dict[str, Any]:
    defaults = EnvConfig()
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in config.as_dict().items()
            if v != getattr(defaults, k)}


def markdown(table: dict[str, Any]) -> str:
    """The table as Markdown (mean [95 % interval])."""
    def cell(d: dict[str, float], fmt: str, scale: float = 1.0) -> str:
        return (f"{d['mean'] * scale:{fmt}} [{d['low'] * scale:{fmt}}, "
                f"{d['high'] * scale:{fmt}}]")

    head = ("| policy | trapping time [s] | kept [%] | detach [%] | escape [%] | "
            "mean distance [mm] | effort (action²) |")
    lines = [head, "|" + "---|" * 7]
    for row in table["policies"]:
        name = row["policy"] + (f" ({row['kind']})" if row["kind"] != "baseline" else "")
        if "omega" in row:
            name += f", Ω = {row['omega']:.2f}"
        lines.append(f"| {name} | {cell(row['trapping_time'], '.2f')} | "
                     f"{cell(row['kept'], '.0f', 100)} | {cell(row['detach'], '.0f', 100)} | "
                     f"{cell(row['escape'], '.0f', 100)} | "
                     f"{cell(row['mean_distance_mm'], '.2f')} | {cell(row['effort'], '.3f')} |")
    kw = table["env_kwargs"]
    note = (f"\n{table['episodes']} episodes (seeds {table['seed']}–"
            f"{table['seed'] + table['episodes'] - 1}) of {table['episode_length_s']:g} s; "
            f"env kwargs: {json.dumps(kw) if kw else 'defaults'}. Mean [95 % interval: "
            "percentile bootstrap for times, distances and effort; Wilson for rates].\n")
    return "\n".join(lines) + "\n" + note


# --------------------------------------------------------------------------------------
# Plots
# --------------------------------------------------------------------------------------
def plot(table: dict[str, Any], details: dict[str, Any], config: EnvConfig, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .baselines import critical_speed

    T = table["episode_length_s"]
    files = []
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    bins = np.linspace(0, T, 41)
    for label, res in details.items():
        t = np.sort(res["time"])
        grid = np.linspace(0, T, 401)
        surv = 1.0 - np.searchsorted(t, grid, side="right") / len(t)
        surv[-1] = np.mean(res["kept"])
        ax1.step(grid, surv, where="post", label=label)
        ax2.hist(res["time"], bins=bins, histtype="step", label=label)
    ax1.set(xlabel="t [s]", ylabel="fraction still trapped", title="Survival", ylim=(-0.02, 1.02))
    ax2.set(xlabel="trapping time [s]", ylabel="episodes", title="Trapping-time distribution")
    ax1.legend(fontsize=8)
    fig.tight_layout()
    path = out / "trapping_time.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    files.append(path)

    n_ex = min((res["trace_omega"].shape[0] for res in details.values()), default=0)
    if n_ex:
        fig, axes = plt.subplots(2, n_ex, figsize=(4.2 * n_ex, 6), squeeze=False, sharex=True)
        wc = critical_speed(config)
        for label, res in details.items():
            for e in range(n_ex):
                (line,) = axes[0, e].plot(res["trace_t"], res["trace_omega"][e], lw=1, label=label)
                axes[1, e].plot(res["trace_t"], 1000 * res["trace_r"][e], lw=0.8,
                                color=line.get_color())
        for e in range(n_ex):
            axes[0, e].axhline(wc, color="k", ls="--", lw=0.8)
            axes[0, e].set(title=f"episode {table['seed'] + e}", ylabel="Ω [rad/s]")
            axes[1, e].set(xlabel="t [s]", ylabel="r [mm]")
        axes[0, 0].legend(fontsize=7)
        axes[0, 0].annotate("Ω_crt", (0, wc), fontsize=7, va="bottom")
        fig.tight_layout()
        path = out / "examples.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        files.append(path)
    return files


# --------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------
def parse_env_kwargs(items: Sequence[str] | None) -> dict[str, Any]:
    """``--env-kwargs``: one JSON object, or ``key=value`` items (values as JSON or Python
    literals, else strings)."""
    if not items:
        return {}
    if len(items) == 1 and items[0].lstrip().startswith("{"):
        try:
            kw = json.loads(items[0])
        except ValueError as exc:
            raise ValueError(f"--env-kwargs is not valid JSON: {exc}") from None
        if not isinstance(kw, dict):
            raise ValueError("--env-kwargs JSON must be an object")
    else:
        kw = {}
        for item in items:
            key, sep, text = item.partition("=")
            if not sep or not key.strip():
                raise ValueError(f"--env-kwargs items must be key=value, got {item!r}")
            kw[key.strip()] = _literal(text.strip())
    return {k: tuple(v) if isinstance(v, list) else v for k, v in kw.items()}


def _literal(text: str) -> Any:
    for parse in (json.loads, ast.literal_eval):
        try:
            return parse(text)
        except (ValueError, SyntaxError):
            pass
    return text


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="saddle-eval",
        description="Evaluate policies (baseline names or Stable-Baselines3 .zip files) on the "
                    "same seeded SaddleTrap-v0 episodes; write a table (JSON + Markdown) and plots.")
    p.add_argument("--policy", action="append", required=True, metavar="NAME_OR_PATH",
                   help="a baseline (const-1.0, const-1.2, const-<K>, masspoint, best-const, mpc) "
                        "or a model file; repeat for several")
    p.add_argument("--episodes", type=int, default=100, help="episodes per policy (default 100)")
    p.add_argument("--seed", type=int, default=0, help="episode i uses seed + i (default 0)")
    p.add_argument("--env-kwargs", nargs="+", metavar="KW",
                   help="environment options: one JSON object or key=value items")
    p.add_argument("--max-episode-steps", type=int, default=DEFAULT_EPISODE_STEPS,
                   help=f"control steps per episode (default {DEFAULT_EPISODE_STEPS})")
    p.add_argument("--examples", type=int, default=N_EXAMPLES,
                   help=f"episodes shown in examples.png (default {N_EXAMPLES})")
    p.add_argument("--out", default="eval-results", metavar="DIR",
                   help="output directory (default ./eval-results)")
    p.add_argument("--json", action="store_true", help="print the table as JSON on stdout only")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.max_episode_steps < 1:
        parser.error(f"--max-episode-steps must be >= 1, got {args.max_episode_steps}")
    if args.examples < 0:
        parser.error(f"--examples must be >= 0, got {args.examples}")
    try:
        config = EnvConfig.from_kwargs(**parse_env_kwargs(args.env_kwargs))
    except (ValueError, TypeError) as exc:
        parser.error(f"--env-kwargs: {exc}")
    from .baselines import load_policy

    policies = []
    for spec in args.policy:  # fail on a bad name or file before any work
        try:
            policy = load_policy(spec, config)
            _check_compatible(policy, config, spec)
        except (ValueError, OSError) as exc:
            parser.error(str(exc))
        policies.append((spec, policy))
        if hasattr(policy, "algo_name"):
            import torch

            torch.set_num_threads(1)  # one thread: the same actions on any machine
            _warn_if_trained_elsewhere(spec, config, args.max_episode_steps)
    table, details = evaluate(policies, config, args.episodes, args.seed,
                              args.max_episode_steps, progress=not args.no_progress,
                              examples=args.examples)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(table, indent=1) + "\n")
    md = markdown(table)
    (out / "results.md").write_text(md)
    per_episode = {label: {"time": np.round(res["time"], 9).tolist(),
                           "cause": list(res["cause"]),
                           "mean_r_m": np.round(res["mean_r"], 9).tolist(),
                           "effort": np.round(res["effort"], 9).tolist()}
                   for label, res in details.items()}
    (out / "episodes.json").write_text(json.dumps({"seed": args.seed, "policies": per_episode}) + "\n")
    if not args.no_plots:
        plot(table, details, config, out)
    if args.json:
        sys.stdout.write(json.dumps(table, indent=1) + "\n")
    else:
        sys.stdout.write(md)
        print(f"wrote {out}/results.json, results.md, episodes.json"
              + ("" if args.no_plots else ", trapping_time.png, examples.png"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
