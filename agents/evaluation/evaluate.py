r"""``saddle-eval``: evaluate policies (baselines, model files, or controller classes of your
own) on the same seeded episodes of a task level and tabulate how long they keep the ball.

```
saddle-eval --policy const-1.2 --policy mpc --policy runs/ppo/model.zip \
            --policy runs/ppo_rllib_seed0_<date>/final --policy exported/ppo_storm \
            --policy my_controllers.py:Bang --policy-kwargs '{"gain": 2}' \
            --episodes 200 --seed 0 [--env ID] [--env-kwargs R=0.033 air_force=0.3]
            [--json] [--out DIR]
```

In Python, `evaluate_controller` puts any object with SB3's ``predict`` beside the baselines.

The environment is the level ``--env`` (`saddle_env.LEVELS`; default: the level named by the
sidecar of the first model file that has one, else ``SaddleTrap-v0``) with ``--env-kwargs``
overriding single options (`agents.cli_args` has the grammar). Episode i is
``reset(seed=seed + i)``, stepped until the ball is lost or for ``--max-episode-steps``
control steps (default: the level's). Every policy sees the
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

The table records ``env_id``, ``env_kwargs`` (the options over the level's) and ``options``
(every resolved option). Writes ``results.json``, ``results.md``, ``episodes.json``
(per-episode values) and, unless ``--no-plots``, ``trapping_time.png`` (survival curves and
histograms) and ``examples.png`` (Ω(t) and r(t) of the first episodes) to ``--out``.
``--json`` prints the table as JSON on stdout and writes nothing (no files, no plots);
progress goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from saddle_env.envs import DEFAULT_EPISODE_STEPS, ENV_ID, LEVEL_IDS, EnvConfig, get_level
from saddle_env.envs.observation import layout

from ..cli_args import (
    MissingExtra,
    install_hint,
    level_overrides,
    missing,
    parse_env_kwargs,
    resolve_env,
)
from ..control.rollout import (  # noqa: F401
    CHUNK,
    Actor,
    PolicyActor,
    episode_set,
    policy_actor,
    run_episodes,
)
from ..seeds import TEST_SEED
from .model_files import TRUST_FLAG
from .policies import (  # noqa: F401
    is_exported_folder,
    load_policy,
    model_sidecar,
    policy_sidecar,
)
from .user_code import is_controller_spec, parse_policy_kwargs

N_EXAMPLES = 3       # episodes whose Ω(t), r(t) are recorded for the plots
METRICS = ("trapping_time", "kept", "detach", "escape", "mean_distance_mm", "effort", "return")
RATES = ("kept", "detach", "escape")


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


def wilson_interval(successes: int, n: int) -> dict[str, float]:
    """A proportion and its 95 % Wilson score interval (sensible at 0 and 1 too)."""
    z = 1.959963984540054
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return {"mean": p, "low": max(0.0, centre - half), "high": min(1.0, centre + half)}


def summarise(res: dict[str, np.ndarray]) -> dict[str, dict[str, float]]:
    """Intervals of the trapping time and of each end's share, from an evaluation's results."""
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
    """(label, kind) of a loaded policy: a baseline's name, a user's controller class's
    name, or a model file's path and algorithm."""
    if hasattr(policy, "algo_name"):
        return spec, policy.algo_name
    from saddle_env.deploy import Controller

    if isinstance(policy, Controller):   # a folder saddle-export wrote
        return spec, policy.kind
    if is_controller_spec(spec):
        return str(getattr(policy, "name", spec)), "controller"
    return getattr(policy, "name", spec), "baseline"


def evaluate(specs: Sequence[str | tuple[str, Any]], config: EnvConfig, episodes: int, seed: int,
             max_episode_steps: int = DEFAULT_EPISODE_STEPS, progress: bool = False,
             examples: int = N_EXAMPLES, env_id: str | None = None, trust: bool = False,
             policy_kwargs: dict[str, Any] | None = None
             ) -> tuple[dict[str, Any], dict[str, Any]]:
    """Evaluate every policy on episodes ``seed .. seed + episodes − 1``.

    Parameters
    ----------
    specs : sequence of str or (str, policy) pairs
        Baseline names, model paths or controller classes (``file.py:Class``; see
        `load_policy`), or (spec, policy) pairs of already loaded policies.
    config : EnvConfig
        The level's configuration.
    episodes : int
        The number of episodes.
    seed : int
        Episode i is ``reset(seed=seed + i)``.
    max_episode_steps : int
        The episode length.
    progress : bool
        Show a progress bar.
    examples : int
        Episodes whose traces are kept for the plots.
    env_id : str, optional
        The level ``config`` was built from (recorded with the options that override it;
        default: the options over `EnvConfig`'s defaults).
    trust : bool
        Load model files with their pickles (see `load_policy`); default: as data.
    policy_kwargs : dict, optional
        The arguments controller classes are built with.

    Returns
    -------
    table : dict
        What ``saddle-eval --json`` prints.
    details : dict
        The per-episode arrays and traces, for files and plots.
    """
    level = get_level(env_id) if env_id is not None else None
    table: dict[str, Any] = {}
    if level is not None:
        table["env_id"] = level.id
    table.update({"env_kwargs": level_overrides(level, config) if level else _nondefault(config),
                  "options": _jsonable(config.as_dict()),
                  "episodes": episodes, "seed": seed, "max_episode_steps": max_episode_steps,
                  "episode_length_s": round(max_episode_steps * config.control_period, 9),
                  "episode_set": episode_set(config, seed, episodes, max_episode_steps),
                  "policies": []})
    details: dict[str, Any] = {}
    seeds = seed + np.arange(episodes)
    for item in specs:
        spec, policy = item if isinstance(item, tuple) else \
            (item, load_policy(item, config, max_episode_steps=max_episode_steps, trust=trust,
                               policy_kwargs=policy_kwargs))
        _check_compatible(policy, config, spec)
        label, kind = policy_label(policy, spec)
        act, row_independent = policy_actor(policy)
        res = run_episodes(config, act, seeds, max_episode_steps=max_episode_steps,
                           row_independent=row_independent, record=examples,
                           progress=label if progress else False)
        row: dict[str, object] = {"policy": label, "kind": kind, **summarise(res)}
        if hasattr(policy, "omega"):
            row["omega"] = round(float(policy.omega), 6)
        table["policies"].append(row)
        details[label] = res
    return table, details


def evaluate_controller(controller: Any, env_id: str = ENV_ID, episodes: int = 100,
                        seed: int = TEST_SEED,
                        baselines: Sequence[str] = ("const-1.0", "best-const", "mpc"),
                        name: str | None = None, env_kwargs: dict[str, Any] | None = None,
                        max_episode_steps: int | None = None, progress: bool = False
                        ) -> dict[str, Any]:
    """Your controller beside the baselines, on the same seeded episodes of a level.

    Parameters
    ----------
    controller : object or str
        Any object with Stable-Baselines3's ``predict(observation, state=None,
        episode_start=None, deterministic=True) -> (action, state)``, or a spec string that
        `load_policy` takes (``"path/to/file.py:ClassName"``, a baseline's name, a model file).
    env_id : str
        The level.
    episodes : int
        The number of episodes.
    seed : int
        Episode i is ``reset(seed=seed + i)``; the default, the leaderboard's frozen test
        seeds, makes the rows comparable with the leaderboard's (docs/leaderboard.md).
    baselines : sequence of str
        The rows beside yours (``const-1.0`` holds Ω at the rigid ball's Ω_crt).
    name : str, optional
        Your row's name; default the controller's ``name`` or its class's.
    env_kwargs : dict, optional
        Options over the level's.
    max_episode_steps : int, optional
        The episode length; default the level's.
    progress : bool
        Show a progress bar.

    Returns
    -------
    dict
        The table ``saddle-eval --json`` prints: ``table["policies"]`` holds one row per
        policy, yours first, each with the mean trapping time and its 95 % interval.

    Raises
    ------
    TypeError
        If ``controller`` has no ``predict`` method.
    """
    level, config = resolve_env(env_id, dict(env_kwargs or {}))
    steps = max_episode_steps or level.max_episode_steps
    if isinstance(controller, str):
        first: str | tuple[str, Any] = controller
    else:
        if not callable(getattr(controller, "predict", None)):
            raise TypeError("controller must have a method predict(observation, state=None, "
                            "episode_start=None, deterministic=True), got "
                            f"{type(controller).__name__}")
        first = (name or str(getattr(controller, "name", type(controller).__name__)), controller)
    table, _ = evaluate([first, *baselines], config, episodes, seed, steps, progress=progress,
                        examples=0, env_id=level.id)
    return table


def _check_compatible(policy: Any, config: EnvConfig, spec: str) -> None:
    space = getattr(policy, "observation_space", None)
    want = layout(config).dim
    if space is not None and tuple(space.shape) != (want,):
        raise ValueError(f"{spec}: the policy expects observations of shape {tuple(space.shape)}, "
                         f"the environment gives ({want},) (obs_frame={config.obs_frame!r}); "
                         "pass the --env or --env-kwargs it was trained with")


def _warn_if_trained_elsewhere(spec: str, env_id: str, config: EnvConfig) -> None:
    side = policy_sidecar(spec)
    if not side:
        return
    try:
        _, trained = trained_env(side)
    except (ValueError, TypeError):
        return
    if trained != config:
        print(f"saddle-eval: warning: {spec} was trained on {side.get('env_id', ENV_ID)} "
              f"with options {json.dumps(_nondefault(trained))}, evaluated on {env_id} with "
              f"{json.dumps(_nondefault(config))}", file=sys.stderr)


def trained_env(sidecar: dict[str, Any]) -> tuple[str, EnvConfig]:
    """(env id, config) a model was trained on, from its sidecar: ``env_id`` (default the
    calm level, as sidecars written before levels existed) with ``env_kwargs`` on top."""
    env_id = sidecar.get("env_id") or ENV_ID
    kwargs = sidecar.get("env_kwargs") or {}
    if not isinstance(kwargs, dict):
        raise ValueError(f"sidecar env_kwargs must be a mapping, got {kwargs!r}")
    _, config = resolve_env(env_id, parse_env_kwargs([json.dumps(kwargs)]) if kwargs else {})
    return env_id, config


def _nondefault(config: EnvConfig) -> dict[str, Any]:
    defaults = EnvConfig()
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in config.as_dict().items()
            if v != getattr(defaults, k)}


def _jsonable(d: dict[str, Any]) -> dict[str, Any]:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}


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
    where = table.get("env_id", "env")
    note = (f"\n{table['episodes']} episodes (seeds {table['seed']}–"
            f"{table['seed'] + table['episodes'] - 1}) of {table['episode_length_s']:g} s; "
            f"{where}{' with ' + json.dumps(kw) if kw else ''}. Mean [95 % interval: "
            "percentile bootstrap for times, distances and effort; Wilson for rates].\n")
    return "\n".join(lines) + "\n" + note


# --------------------------------------------------------------------------------------
# Plots
# --------------------------------------------------------------------------------------
def plot(table: dict[str, Any], details: dict[str, Any], config: EnvConfig, out: Path) -> list[Path]:
    """Draw the evaluation's figures into ``out``; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..control.controllers import critical_speed

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
def build_parser() -> argparse.ArgumentParser:
    """The command line of ``saddle-eval``."""
    p = argparse.ArgumentParser(
        prog="saddle-eval",
        description="Evaluate policies (baseline names or Stable-Baselines3 .zip files) on the "
                    "same seeded episodes of a task level; write a table (JSON + Markdown) and "
                    "plots, or with --json print the table and write nothing.")
    p.add_argument("--policy", action="append", required=True, metavar="NAME_OR_PATH",
                   help="a baseline (const-1.0, const-1.2, const-<K>, masspoint, best-const, mpc, "
                        "clairvoyant, zero, random), a model file, a folder saddle-export "
                        "wrote, an RLlib checkpoint directory, or your controller class as "
                        "path/to/file.py:ClassName or package.module:ClassName (imported and "
                        "run: name only code you trust); repeat for several")
    p.add_argument("--policy-kwargs", default=None, metavar="JSON",
                   help="a JSON object of arguments your controller classes are built with "
                        "(default: none; a class whose __init__ takes `config` gets the "
                        "level's options)")
    p.add_argument("--env", default=None, metavar="ID",
                   help=f"task level ({', '.join(LEVEL_IDS)}); default: the level a model "
                        f"file's sidecar names, else {ENV_ID}")
    p.add_argument("--episodes", type=int, default=100, help="episodes per policy (default 100)")
    p.add_argument("--seed", type=int, default=0, help="episode i uses seed + i (default 0)")
    p.add_argument("--env-kwargs", nargs="+", metavar="KW",
                   help="options over the level's: key=value items (values as JSON/Python/YAML "
                        "literals) or one JSON object")
    p.add_argument("--max-episode-steps", type=int, default=None,
                   help="control steps per episode (default: the level's, "
                        f"{DEFAULT_EPISODE_STEPS} for {ENV_ID})")
    p.add_argument("--examples", type=int, default=N_EXAMPLES,
                   help=f"episodes shown in examples.png (default {N_EXAMPLES})")
    p.add_argument("--out", default="eval-results", metavar="DIR",
                   help="output directory (default ./eval-results; not used with --json)")
    p.add_argument("--json", action="store_true",
                   help="print the table as JSON on stdout and write no files")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(TRUST_FLAG, action="store_true",
                   help="also load model files whose reading needs unpickling (SB3's own "
                        "loader, pickled normaliser statistics, RLlib's pickled checkpoints): "
                        "this runs code the file carries; only for files you trust "
                        "(docs/security.md). Default: files are read as data")
    return p


def _default_env_id(specs: Sequence[str]) -> str:
    """The level of the first model file whose sidecar names one, else the calm level."""
    for spec in specs:
        side = policy_sidecar(spec)
        if side and side.get("env_id"):
            return str(side["env_id"])
    return ENV_ID


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.max_episode_steps is not None and args.max_episode_steps < 1:
        parser.error(f"--max-episode-steps must be >= 1, got {args.max_episode_steps}")
    if args.examples < 0:
        parser.error(f"--examples must be >= 0, got {args.examples}")
    env_id = args.env or _default_env_id(args.policy)
    try:
        overrides = parse_env_kwargs(args.env_kwargs)
    except ValueError as exc:
        parser.error(f"--env-kwargs: {exc}")
    try:
        level, config = resolve_env(env_id, overrides)
    except ValueError as exc:
        if env_id not in LEVEL_IDS:
            parser.error(f"--env: {exc}")
        parser.error(f"--env-kwargs: {exc}")
    except TypeError as exc:
        parser.error(f"--env-kwargs: {exc}")
    steps = args.max_episode_steps or level.max_episode_steps
    # --json: the table on stdout and nothing on disk, so no plots either.
    plots = not (args.no_plots or args.json)
    if plots and missing(["matplotlib"]):
        parser.error(f"the plots need matplotlib, which is not installed: {install_hint('plot')} "
                     "(or pass --no-plots)")
    progress = not args.no_progress
    if progress and missing(["tqdm"]):
        print(f"saddle-eval: no progress bar (tqdm is not installed: {install_hint('plot')})",
              file=sys.stderr)
        progress = False

    try:
        policy_kwargs = parse_policy_kwargs(args.policy_kwargs)
    except ValueError as exc:
        parser.error(str(exc))
    if policy_kwargs is not None:
        if not any(is_controller_spec(s) for s in args.policy):
            parser.error("--policy-kwargs: no --policy names a controller class "
                         "(path/to/file.py:ClassName) to build with them")
    policies = []
    for spec in args.policy:  # fail on a bad name or file before any work
        try:
            policy = load_policy(spec, config, max_episode_steps=steps, trust=args.trust_model,
                                 policy_kwargs=policy_kwargs)
            _check_compatible(policy, config, spec)
        except (ValueError, OSError, MissingExtra) as exc:
            parser.error(str(exc))
        policies.append((spec, policy))
        if hasattr(policy, "algo_name"):
            import torch

            torch.set_num_threads(1)  # one thread: the same actions on any machine
        if hasattr(policy, "algo_name") or is_exported_folder(spec):
            _warn_if_trained_elsewhere(spec, level.id, config)
    table, details = evaluate(policies, config, args.episodes, args.seed, steps,
                              progress=progress, examples=args.examples, env_id=level.id)
    if args.json:
        sys.stdout.write(json.dumps(table, indent=1) + "\n")
        return 0
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
    (out / "episodes.json").write_text(json.dumps({"seed": args.seed, "policies": per_episode})
                                       + "\n")
    if plots:
        plot(table, details, config, out)
    sys.stdout.write(md)
    print(f"wrote {out}/results.json, results.md, episodes.json"
          + ("" if not plots else ", trapping_time.png, examples.png"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
