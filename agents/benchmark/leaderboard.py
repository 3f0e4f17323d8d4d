"""The leaderboard: every baseline and every shipped agent on every task level, on a frozen
test set of seeded episodes, written as ``docs/leaderboard.md`` (+ JSON and survival-curve
PNGs) by one command::

    python -m agents.benchmark.leaderboard                 # 1,000 episodes per level (about 30 min)
    python -m agents.benchmark.leaderboard --episodes 50 --out /tmp/lb --levels SaddleTrap-Gusty-v0

The test seeds (``TEST_SEED`` onwards) are used by nothing else: training runs use seeds
0-99 (each run's balls are seeded from its own seed), the best-constant search 12,345
onwards, model selection during training ``VALIDATION_SEED`` and ``RESELECT_SEED`` onwards. Results are written
policy by policy as they finish (``leaderboard.json``, with every episode's trapping time),
so an interrupted run keeps what finished and ``--resume`` does only the rest; a shipped
model is keyed by a digest of its file, so a retrained one is evaluated afresh.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from saddle_env.envs import LEVELS, EnvConfig, get_level
from saddle_env.jobs.files import write_text_atomically
from saddle_env.jobs.signals import sigterm_interrupts

from ..control.best_constant import PAIRED_EPISODES, SEARCH_EPISODES
from ..evaluation.model_files import TRUST_FLAG
from ..evaluation.policies import is_exported_folder, load_policy
from ..evaluation.user_code import parse_policy_kwargs, source_digest
from ..paths import DOCS_DIR, MODELS_DIR, REPO_ROOT
from ..seeds import RESELECT_SEED, SEARCH_SEED, TEST_SEED, VALIDATION_SEED
from .report import clairvoyant_reference

TEST_EPISODES = 1000           # 200-episode sets move the kept fraction by about 7 points
BASELINE_POLICIES = ("zero", "random", "const-1.0", "const-1.2", "const-1.5", "best-const",
                     "mpc")
# On a level whose camera or motor is late (obs_delay, action_delay): mpc planning as if the
# delayed picture were now, so that the board shows what ignoring the delay costs.
DELAY_BASELINES = ("mpc-blind",)
DOCS = DOCS_DIR


def shipped_agents(env_id: str, models_dir: Path = MODELS_DIR) -> list[Path]:
    """The shipped model files trained on level ``env_id`` (their sidecar's ``env_id``, with
    no option overridden)."""
    out = []
    for path in sorted(models_dir.glob("*.zip")):
        try:
            side = json.loads(path.with_suffix(".json").read_text())
        except (OSError, ValueError):
            continue
        if isinstance(side, dict) and side.get("env_id") == env_id and not side.get("env_kwargs"):
            out.append(path)
    return out


def baseline_policies(env_id: str) -> list[str]:
    """The baselines of level ``env_id``: `BASELINE_POLICIES`, and `DELAY_BASELINES` where
    the level delays its observations or its commands."""
    config = get_level(env_id).config()
    delayed = config.obs_delay > 0 or config.action_delay > 0
    return list(BASELINE_POLICIES) + (list(DELAY_BASELINES) if delayed else [])


def policy_specs(env_id: str, models_dir: Path = MODELS_DIR,
                 extra: Sequence[str] = ()) -> list[str]:
    """What the leaderboard runs on ``env_id``: every baseline, then the agents in
    ``models_dir`` (the shipped ones by default), then the ``extra`` policies (``--policy``:
    a controller class of yours, another model file)."""
    return (baseline_policies(env_id) + [str(p) for p in shipped_agents(env_id, models_dir)]
            + list(extra))


def shown_spec(spec: str) -> str:
    """How a policy is named in the results: a file inside this repository by its path from
    the repository's root (the results do not carry one machine's folders), anything else
    as given."""
    path = Path(spec)
    if path.is_absolute():
        try:
            return str(path.resolve().relative_to(REPO_ROOT))
        except ValueError:
            pass
    return spec


def policy_key(spec: str) -> str:
    """A baseline's name, or a model file's (an exported folder's, a controller class's
    file's) name with a digest of its bytes (a retrained model or an edited controller is a
    new entry, not a stale one)."""
    path = Path(spec)
    if spec.endswith(".zip") and path.is_file():
        return f"{path.name}@{hashlib.sha256(path.read_bytes()).hexdigest()[:12]}"
    if is_exported_folder(spec):   # policy.json holds the graph's own digest
        digest = hashlib.sha256((path / "policy.json").read_bytes()).hexdigest()[:12]
        return f"{path.name}@{digest}"
    source = source_digest(spec)
    if source is not None:
        return f"{Path(spec).name}@{source}"
    return spec


def evaluate_policy(env_id: str, spec: str, episodes: int, seed: int, progress: bool = True,
                    trust: bool = False, policy_kwargs: dict[str, Any] | None = None
                    ) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """(table row, per-episode results) of one policy on level ``env_id``'s test episodes
    (model files read as data unless ``trust``, controller classes built with
    ``policy_kwargs``: see `agents.evaluation.policies.load_policy`)."""
    from ..evaluation.evaluate import evaluate

    level = get_level(env_id)
    table, details = evaluate([spec], level.config(), episodes, seed,
                              max_episode_steps=level.max_episode_steps, progress=progress,
                              examples=0, env_id=env_id, trust=trust,
                              policy_kwargs=policy_kwargs)
    return table["policies"][0], details[table["policies"][0]["policy"]]


def survival_plot(env_id: str, details: dict[str, Any], horizon: float, path: Path) -> None:
    """Fraction of balls still trapped against time, one curve per policy (``details``:
    label -> {"time": trapping times [s], "kept": whether kept})."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2))
    grid = np.linspace(0.0, horizon, 501)
    for label, res in details.items():
        t = np.sort(np.asarray(res["time"], dtype=float))
        alive = 1.0 - np.searchsorted(t, grid, side="right") / len(t)
        alive[-1] = float(np.mean(res["kept"]))
        ax.step(grid, alive, where="post", label=Path(label).stem if label.endswith(".zip")
                else label, lw=1.8 if label.endswith(".zip") or label == "mpc" else 1.0)
    ax.set(xlabel="t [s]", ylabel="fraction of balls still trapped", ylim=(-0.02, 1.02),
           title=f"{env_id}: survival ({len(t)} test episodes per policy)")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _cell(d: dict[str, float], fmt: str, scale: float = 1.0) -> str:
    return f"{d['mean'] * scale:{fmt}} [{d['low'] * scale:{fmt}}, {d['high'] * scale:{fmt}}]"


def level_markdown(table: dict[str, Any], figure: str | None) -> str:
    """One level's section of the leaderboard page, from its results ``table`` and survival ``figure``."""
    level = get_level(table["env_id"])
    lines = [f"## {level.id}", "", level.summary[0].upper() + level.summary[1:] + ".", ""]
    clair = clairvoyant_reference(level.id)
    random_t = next((r["trapping_time"]["mean"] for r in table["policies"]
                     if r["policy"] == "random"), None)

    def score(row: dict[str, Any]) -> str:
        """0 for uniform random actions, 1 for the clairvoyant (docs/benchmark.md)."""
        if clair is None or random_t is None or clair["clairvoyant"] <= random_t:
            return "—"
        return f"{(row['trapping_time']['mean'] - random_t) / (clair['clairvoyant'] - random_t):.2f}"

    lines += ["| policy | trapping time [s] | score | kept [%] | detach [%] | escape [%] | "
              "mean distance [mm] | effort (action²) |", "|" + "---|" * 8]
    for row in sorted(table["policies"], key=lambda r: -r["trapping_time"]["mean"]):
        name = row["policy"]
        if name.endswith(".zip"):
            name = f"**{Path(name).stem}** ({row['kind']})"
        elif "omega" in row:
            name += f", Ω = {row['omega']:.2f}"
        lines.append(f"| {name} | {_cell(row['trapping_time'], '.2f')} | {score(row)} | "
                     f"{_cell(row['kept'], '.1f', 100)} | {_cell(row['detach'], '.1f', 100)} | "
                     f"{_cell(row['escape'], '.1f', 100)} | "
                     f"{_cell(row['mean_distance_mm'], '.2f')} | {_cell(row['effort'], '.3f')} |")
    lines += ["", f"{table['episodes']} episodes per policy, seeds {table['seed']}–"
              f"{table['seed'] + table['episodes'] - 1}, {table['episode_length_s']:g} s each."]
    if clair is not None:
        lines += ["", f"Upper reference: the clairvoyant controller keeps the ball "
                  f"{clair['clairvoyant']:.2f} s [{clair['clairvoyant_ci']['low']:.2f}, "
                  f"{clair['clairvoyant_ci']['high']:.2f}] on the first {clair['episodes']:,} "
                  f"of these episodes; {100 * clair['doomed']:.1f} % "
                  f"[{100 * clair['doomed_ci']['low']:.1f}, {100 * clair['doomed_ci']['high']:.1f}] "
                  f"of its starts are doomed (lost even by it). *Score*: (T − T_random) / "
                  f"(T_clairvoyant − T_random) ([Benchmark](benchmark.md))."]
    if figure:
        lines += ["", f"![{level.id} survival]({figure})"]
    return "\n".join(lines) + "\n"


def write_markdown(results: dict[str, Any], path: Path, figures: dict[str, str],
                   command: str) -> None:
    """Write the leaderboard page to ``path``, with the ``command`` that made it."""
    head = [
        "# Leaderboard",
        "",
        f"Generated by `{command}` on {results['date']} "
        f"({results['machine']}); do not edit by hand.",
        "",
        "Every policy runs the same frozen test episodes of each level (episode i is "
        "`reset(seed=seed + i)`); trapping time is the time until the ball detaches or "
        "leaves the rim, the episode length if it is kept. Mean [95 % interval]: percentile "
        "bootstrap for times, distances and effort, Wilson score intervals (binomial) for "
        "rates. `zero` always sends "
        "action 0, `random` uniform actions; `const-K` holds K·Ω_crt of the nominal ball, "
        "`best-const` the best constant speed of the level (a grid searched on 64 seeded "
        "episodes, its choice checked against the next four speeds on 512 more, paired), "
        "`mpc` is the model-predictive controller, and on a level whose camera is late "
        "`mpc-blind` the same controller planning as if the late picture were now. Agents "
        "(bold) are the network alone, deterministic.",
        "",
        "Seeds (agents/seeds.py): test episodes from "
        f"{results['seed']:,} (used by nothing else); training runs seed 0-99; model "
        f"selection during training on validation episodes from {VALIDATION_SEED:,} and "
        f"{RESELECT_SEED:,}; best-const search {SEARCH_SEED:,}–"
        f"{SEARCH_SEED + SEARCH_EPISODES + PAIRED_EPISODES - 1:,}.",
        "",
    ]
    body = [level_markdown(results["levels"][lid], figures.get(lid))
            for lid in results["order"] if lid in results["levels"]]
    write_text_atomically(path, "\n".join(head) + "\n" + "\n".join(body))


# Levels whose section on docs/levels.md states how feedback does against the best constant
# speed, from the committed board: the real saddle (issue 57), whose question that is. Each
# names the figure of plotted test episodes, the command that drew it and what it shows
# (agents.evaluation.speed_modulation's figures, on the first test episodes).
ANSWERED_LEVELS: dict[str, tuple[str, str, str]] = {
    "SaddleTrap-RealSaddle-v0": (
        "figures/realsaddle_episodes.png",
        "saddle-eval --env SaddleTrap-RealSaddle-v0 --policy best-const --policy mpc "
        "--policy agents/models/ppo_realsaddle.zip --episodes 4 --seed 2000000 --examples 2 "
        "--out DIR",
        "By what means: the agent swings the speed between about 6.6 and 10 rad/s (5th to "
        "95th percentile) around 8.3 rad/s, a fifth of the time below the rigid ball's "
        "threshold (7.43 rad/s), at 2.65-2.67 Hz: twice the saddle's turning frequency. The "
        "speed follows the saddle's angle, fast in one orientation and slow in the other, "
        "with a phase that stays put through each episode: a component at twice the angle, about "
        "1.1 rad/s, explains 52-63 % of the speed's variance, and the ball stays about 6 mm "
        "from the centre for the whole minute. `mpc` swings the speed as widely, but not "
        "with the angle (that component explains none of its variance), for the first 20-30 "
        "s, then holds about 7.5 rad/s and lets the ball circle 45-52 mm out; at the constant "
        "speed the orbit grows to the rim in 18-19 s. The figures for the first four test "
        "episodes: `python -m agents.evaluation.speed_modulation --policy "
        "agents/models/ppo_realsaddle.zip --episodes 4` (and `--policy mpc`), 2026-11-29."),
}


def _answer(level_id: str, on_board: dict[str, Any], date: str) -> list[str]:
    """The paragraph `ANSWERED_LEVELS` asks for: best-const against mpc and the shipped agent
    (and the clairvoyant where measured) on the level's test episodes, with the command and
    the date; none until the level is on the board."""
    if level_id not in ANSWERED_LEVELS or level_id not in on_board:
        return []
    figure, command, means = ANSWERED_LEVELS[level_id]
    table = on_board[level_id]
    rows = {r["key"]: r for r in table["policies"]}
    if "best-const" not in rows or "mpc" not in rows:
        return []
    best, mpc = rows["best-const"], rows["mpc"]
    bt, mt = best["trapping_time"], mpc["trapping_time"]
    length = table["episode_length_s"]
    text = (f"**Does feedback keep the ball longer?** On the level's {table['episodes']:,} test "
            f"episodes ({length:g} s each; `python -m agents.benchmark.leaderboard --levels "
            f"{level_id} --resume`, {date}): the best constant speed, Ω = {best['omega']:g} "
            f"rad/s (the lab's practice), keeps the ball {_cell(bt, '.2f')} s, "
            f"{100 * best['kept']['mean']:.1f} % to the end; `mpc`, feedback on the speed with "
            f"the level's own model, {_cell(mt, '.2f')} s, {_cell(mpc['kept'], '.1f', 100)} % "
            f"to the end: {mt['mean'] / bt['mean']:.2f} times as long, its interval clear of "
            f"the constant's" if mt["low"] > bt["high"] else "")
    if not text:
        text = (f"**Does feedback keep the ball longer?** Not measurably: on the level's "
                f"{table['episodes']:,} test episodes `mpc` keeps the ball {_cell(mt, '.2f')} s "
                f"against the best constant speed's {_cell(bt, '.2f')} s")
    agents = [r for r in table["policies"] if r["kind"] != "baseline"]
    for agent in agents:
        at = agent["trapping_time"]
        name = Path(agent["policy"]).stem
        text += (f"; the shipped agent, `{name}` (PPO, [Shipped agents](shipped-agents.md)), "
                 f"{_cell(at, '.2f')} s, {_cell(agent['kept'], '.1f', 100)} % to the end: "
                 f"{at['mean'] / bt['mean']:.2f} times as long as the constant "
                 + ("(the episode's length caps it)" if at["low"] >= length - 1e-6 else
                    "its interval clear of the constant's" if at["low"] > bt["high"] else
                    "not clear of the constant's interval"))
    clair = clairvoyant_reference(level_id)
    if clair is not None:
        text += (f". The clairvoyant reference, which starts from `mpc`'s and the shipped "
                 f"agents' episodes and improves on them, keeps it {clair['clairvoyant']:.2f} s "
                 f"[{clair['clairvoyant_ci']['low']:.2f}, {clair['clairvoyant_ci']['high']:.2f}] "
                 f"on the first {clair['episodes']:,} of these episodes, losing "
                 f"{100 * clair['doomed']:.1f} % [{100 * clair['doomed_ci']['low']:.1f}, "
                 f"{100 * clair['doomed_ci']['high']:.1f}]")
    shown = "best-const, mpc and the shipped agent" if agents else "best-const against mpc"
    return ["", text + ".", "", f"![{level_id}: the saddle's speed and the ball's distance "
            f"from the centre in two test episodes, {shown}]({figure})", "",
            f"*Two test episodes (seeds 2,000,000 and 2,000,001): `{command}` (its "
            f"examples.png), {date}.* {means}"]


def levels_markdown() -> str:
    """``docs/levels.md``: every registered level, what it models, why it is hard, and its
    options, from the registry itself (`saddle_env.LEVELS`)."""
    lines = ["# Task levels", "",
             "Generated from `saddle_env.LEVELS` by `python -m agents.benchmark.leaderboard --levels-doc`; "
             "do not edit by hand. Each id is a fixed set of options: `gym.make(ID)` and "
             "`gym.make_vec(ID, num_envs=n)` need no keywords, and keywords still override one "
             "option (`gym.make(\"SaddleTrap-Gusty-v0\", air_force=0.1)`). A change of "
             "meaning gets a new version, never a silent edit. How every baseline and agent "
             "does on each: [Leaderboard](leaderboard.md).", "",
             "**Reward threshold.** Each level's `gym.spec(ID).reward_threshold`, Gymnasium's "
             "\"solved\" marker (read by tools such as SB3's `StopTrainingOnRewardThreshold`), "
             "is the mean return of `mpc` on the level's frozen test set (1,000 episodes, "
             "[Leaderboard](leaderboard.md)), rounded down to 0.1: an agent that reaches it "
             "traps as long as the model-predictive controller. A return is the sum over the "
             "episode's control steps of the per-step reward (the fraction of the step the ball "
             "stayed trapped, less 10 in the step it is lost; [Reward](environment.md#reward)), so 500 is "
             "a ball kept for the full 10 s. The "
             "tests check each threshold against the committed leaderboard.", "",
             "| id | summary | episode | reward threshold |", "|---|---|---|---|"]
    for level in LEVELS:
        lines.append(f"| `{level.id}` | {level.summary} | {level.max_episode_steps} steps | "
                     f"{level.reward_threshold} |")
    board = DOCS / "leaderboard.json"
    committed = json.loads(board.read_text()) if board.is_file() else {}
    on_board, date = committed.get("levels", {}), str(committed.get("date", ""))
    for level in LEVELS:
        opts = ", ".join(f"`{k}={v!r}`" for k, v in level.options.items()) or \
            "none: every option at its default"
        # a level registered before its test episodes are run has no board section to link
        answer = _answer(level.id, on_board, date)
        how = (f"[Leaderboard: {level.id}](leaderboard.md#{level.id.lower()})"
               if level.id in on_board else
               "not on the [Leaderboard](leaderboard.md) yet: its test episodes have not "
               "been run")
        # the docs build fills in the level's spaces, reward and limits from its spec
        # (docs/hooks.py)
        lines += ["", f"## {level.id}", "", f"<!-- generated: level-summary {level.id} -->", "",
                  f"**What it models.** {level.models}", "",
                  f"**Why it is hard.** {level.why_hard}", "", f"**Options.** {opts}.", "",
                  f"**How policies do on it.** {how}.", *answer]
    return "\n".join(lines) + "\n"


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m agents.benchmark.leaderboard``."""
    p = argparse.ArgumentParser(
        prog="python -m agents.benchmark.leaderboard",
        description="Evaluate every baseline and shipped agent on every task level on a frozen "
                    "test set; write docs/leaderboard.md, leaderboard.json and survival PNGs.")
    p.add_argument("--episodes", type=int, default=TEST_EPISODES,
                   help=f"test episodes per policy and level (default {TEST_EPISODES})")
    p.add_argument("--seed", type=int, default=TEST_SEED,
                   help=f"first test seed (default {TEST_SEED})")
    p.add_argument("--levels", nargs="+", default=None, metavar="ID",
                   help="level ids (default: every registered level)")
    p.add_argument("--out", default=str(DOCS), metavar="DIR",
                   help="where leaderboard.md, leaderboard.json and figures/ go (default docs/)")
    p.add_argument("--resume", action="store_true",
                   help="keep the results already in DIR/leaderboard.json with the same "
                        "episodes and seed (per level and policy)")
    p.add_argument("--no-progress", action="store_true",
                   help="print no progress while the episodes run")
    p.add_argument("--policy", action="append", default=[], metavar="SPEC",
                   help="an extra row on every level: your controller class "
                        "(path/to/file.py:ClassName or package.module:ClassName; imported and "
                        "run) or another model file; repeat for several")
    p.add_argument("--policy-kwargs", default=None, metavar="JSON",
                   help="a JSON object of arguments the --policy classes are built with")
    p.add_argument("--models", default=str(MODELS_DIR), metavar="DIR",
                   help="the agents to rank: every .zip in DIR whose JSON sidecar names the "
                        "level (default: the shipped agents). Read as data, never unpickled")
    p.add_argument(TRUST_FLAG, action="store_true",
                   help="also load agents whose reading needs unpickling, which runs code they "
                        "carry: only for files you trust (docs/security.md)")
    p.add_argument("--levels-doc", action="store_true",
                   help="only (re)write DIR/levels.md from the registry, evaluating nothing")
    return p


def _checked_args(parser: argparse.ArgumentParser, argv: Sequence[str] | None
                  ) -> tuple[argparse.Namespace, Any, list[str]]:
    """The arguments, the policy keywords and the level ids, each checked before an hour
    of baselines (exit 2 on a bad one)."""
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    try:
        policy_kwargs = parse_policy_kwargs(args.policy_kwargs)
    except ValueError as exc:
        parser.error(str(exc))
    for spec in args.policy:  # a bad class fails before an hour of baselines, not after
        try:
            load_policy(spec, EnvConfig(), trust=args.trust_model, policy_kwargs=policy_kwargs)
        except ValueError as exc:
            parser.error(f"--policy: {exc}")
    ids = args.levels or [level.id for level in LEVELS]
    for lid in ids:
        try:
            get_level(lid)
        except ValueError as exc:
            parser.error(f"--levels: {exc}")
    return args, policy_kwargs, ids


def _resume(json_path: Path, args: argparse.Namespace, results: dict[str, Any]
            ) -> dict[str, dict[str, Any]]:
    """With ``--resume``, the rows of an earlier board of the same episodes and seed
    (level -> policy key -> (row, episodes)), its levels copied into ``results``."""
    done: dict[str, dict[str, Any]] = {}
    if args.resume and json_path.is_file():
        old = json.loads(json_path.read_text())
        if old.get("episodes") == args.episodes and old.get("seed") == args.seed:
            for lid, table in old.get("levels", {}).items():
                eps = old.get("episode_results", {}).get(lid, {})
                done[lid] = {row["key"]: (row, eps[row["key"]]) for row in table["policies"]
                             if row.get("key") in eps}
                # Kept as they were until this run reaches the level again; a level this
                # run does not evaluate (``--levels`` names others) stays on the board.
                results["levels"][lid] = table
                results["episode_results"][lid] = eps
    return done


def _evaluate_level(lid: str, args: argparse.Namespace, policy_kwargs: Any,
                    done: dict[str, dict[str, Any]], results: dict[str, Any], json_path: Path,
                    term: Any) -> int:
    """Every listed policy on level ``lid`` (a resumed row is reused), the board saved after
    each; returns how many were evaluated."""
    level = get_level(lid)
    table = {"env_id": lid, "episodes": args.episodes, "seed": args.seed,
             "episode_length_s": round(level.max_episode_steps
                                       * level.config().control_period, 9),
             "policies": []}
    # Only the rows this run lists: a retrained agent's old file (another key) and
    # a policy no longer ranked leave with their episodes.
    episodes: dict[str, Any] = {}
    results["episode_results"][lid] = episodes
    results["levels"][lid] = table
    computed = 0
    for spec in policy_specs(lid, Path(args.models), args.policy):
        key = policy_key(spec)
        term.raise_if_lost()
        if key in done.get(lid, {}):
            row, eps = done[lid][key]
        else:
            print(f"{lid}: {spec}, {args.episodes} episodes", file=sys.stderr, flush=True)
            try:
                row, res = evaluate_policy(lid, spec, args.episodes, args.seed,
                                           progress=not args.no_progress,
                                           trust=args.trust_model,
                                           policy_kwargs=policy_kwargs)
            except ValueError as exc:   # one bad submission does not stop the board
                print(f"{lid}: skipped {spec}: {exc}", file=sys.stderr, flush=True)
                continue
            row = {**row, "policy": shown_spec(spec), "key": key}
            eps = {"time": np.round(np.asarray(res["time"], float), 6).tolist(),
                   "kept": np.asarray(res["kept"], bool).tolist()}
            computed += 1
        table["policies"].append(row)
        episodes[key] = eps
        # as it comes, whole: a stop mid-write keeps the previous file for --resume
        write_text_atomically(json_path, json.dumps(results, indent=1) + "\n")
    return computed


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    args, policy_kwargs, ids = _checked_args(build_parser(), argv)
    out = Path(args.out)
    if args.levels_doc:
        out.mkdir(parents=True, exist_ok=True)
        (out / "levels.md").write_text(levels_markdown())
        print(f"wrote {out / 'levels.md'}")
        return 0
    figs = out / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    json_path = out / "leaderboard.json"
    import platform

    results: dict[str, Any] = {"episodes": args.episodes, "seed": args.seed, "order": ids,
                               "date": time.strftime("%Y-%m-%d"),
                               "machine": f"{platform.machine()}, {_cores()} cores",
                               "levels": {}, "episode_results": {}}
    done = _resume(json_path, args, results)
    # The board lists its levels in the registry's order, whichever were updated.
    results["order"] = [level.id for level in LEVELS
                        if level.id in ids or level.id in results["levels"]]
    command = "python -m agents.benchmark.leaderboard" + (
        "" if argv is None and len(sys.argv) <= 1 else " " + " ".join(argv or sys.argv[1:]))
    figures: dict[str, str] = {lid: f"figures/leaderboard_{lid}.png" for lid in results["levels"]
                               if lid not in ids and (figs / f"leaderboard_{lid}.png").is_file()}

    import torch

    torch.set_num_threads(1)  # the same actions on any machine
    computed = 0
    try:
        # SIGTERM finishes like Ctrl-C, keeping what finished
        with sigterm_interrupts() as term:
            for lid in ids:
                computed += _evaluate_level(lid, args, policy_kwargs, done, results, json_path,
                                            term)
                table = results["levels"][lid]
                fig = figs / f"leaderboard_{lid}.png"
                survival_plot(lid, {row["policy"]: results["episode_results"][lid][row["key"]]
                                    for row in table["policies"]},
                              table["episode_length_s"], fig)
                figures[lid] = f"figures/{fig.name}"
                write_markdown(results, out / "leaderboard.md", figures, command)
    except KeyboardInterrupt:
        print(f"interrupted: {json_path} keeps every policy that finished; --resume goes on",
              file=sys.stderr)
        return 130
    write_markdown(results, out / "leaderboard.md", figures, command)
    print(f"wrote {out / 'leaderboard.md'}, {json_path} and {len(figures)} figure(s) "
          f"({computed} policy-level evaluation(s) run)")
    return 0


def _cores() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


if __name__ == "__main__":
    raise SystemExit(main())
