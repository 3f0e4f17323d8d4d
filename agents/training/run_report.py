"""What a finished training run shows, whichever back end trained it: the learning curve
(``learning_curve.png`` and ``.csv``) and the closing comparison of the trained agent with
``best-const`` and ``mpc`` on fresh episodes (``comparison.md`` and ``.json``).

The curve comes from the run folder alone:

* ``evaluations.npz`` (`agents.training.selection`) with ``evaluations_wall.csv``: the
  validation episodes' trapping time at each evaluation, against steps and wall-clock
  seconds, on the episodes ``curve_episodes.json`` names;
* or, without it, ``evaluations_wall.csv`` alone (the RLlib back end writes one row per
  training iteration: its *training* episodes' running mean, labelled so on the plot, with
  no reference lines: no reference policy ran those episodes).

The reference lines on the curve (best-const and ``mpc``) are measured on the curve's own
episodes (``curve_references.json`` records them with their episode set); `plot_learning_curve`
refuses lines from any other set. The closing comparison's table is on other, fresh episodes
(`COMPARE_SEED`): it compares the shipped network, not the curve.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

from saddle_env.envs import EnvConfig
from saddle_env.jobs.files import write_text_atomically

from ..cli_args import resolve_env
from ..control.rollout import same_episodes
from ..seeds import COMPARE_SEED
from .runs import TrainSettings

WALL_CSV = "evaluations_wall.csv"
CURVE_EPISODES = "curve_episodes.json"    # written by agents.training.selection
CURVE_REFERENCES = "curve_references.json"
REFERENCE_NAMES = ("best-const", "mpc")
WALL_HEADER = "timesteps,wall_seconds,mean_return,mean_trapping_time"


def append_curve_point(run_dir: Path, timesteps: int, wall_seconds: float, mean_return: float,
                       mean_trapping_time: float) -> None:
    """One row of ``evaluations_wall.csv``: the curve against wall-clock time (seconds since
    the run began, warm start and imitation included), which `plot_learning_curve` and
    `agents.benchmark.time_to_target` read."""
    with open(Path(run_dir) / WALL_CSV, "a") as f:
        if f.tell() == 0:
            f.write(WALL_HEADER + "\n")
        f.write(f"{int(timesteps)},{wall_seconds:.2f},{mean_return},{mean_trapping_time}\n")


def compare(run_dir: Path, settings: TrainSettings, model: Path | None = None) -> str:
    """The trained agent (``model``: by default the run's ``selected_model.zip``, else its
    ``final_model.zip``) beside best-const and mpc on fresh episodes (`COMPARE_SEED`): print
    the table, save ``comparison.md`` and ``comparison.json``; return the Markdown."""
    from ..evaluation.evaluate import evaluate, markdown
    from ..evaluation.policies import load_policy

    _, config = settings.environment()
    if model is None:
        model = run_dir / "selected_model.zip"
        if not model.is_file():
            model = run_dir / "final_model.zip"
    steps = int(settings.max_episode_steps or 500)
    print(f"comparing {model.name} with best-const and mpc on {settings.compare_episodes} fresh "
          f"episodes (seeds from {COMPARE_SEED:,}) ...", flush=True)
    specs: list[str | tuple[str, Any]] = [(str(model), load_policy(model, config)), "best-const",
                                          "mpc"]
    table, _ = evaluate(specs, config, settings.compare_episodes, COMPARE_SEED,
                        max_episode_steps=steps, examples=0, env_id=settings.env_id,
                        progress=settings.progress_bar)
    text = markdown(table)
    plot_learning_curve(run_dir, curve_references(run_dir, settings))
    (run_dir / "comparison.md").write_text(text)
    (run_dir / "comparison.json").write_text(json.dumps(table, indent=1) + "\n")
    print(text)
    return text


def curve_episodes(run_dir: Path) -> dict[str, Any] | None:
    """The `agents.control.rollout.episode_set` of the run's validation curve
    (``curve_episodes.json``), None if the run has none (RLlib's curve, older runs)."""
    path = Path(run_dir) / CURVE_EPISODES
    return json.loads(path.read_text()) if path.is_file() else None


def curve_references(run_dir: Path, settings: TrainSettings,
                     names: tuple[str, ...] = REFERENCE_NAMES) -> dict[str, Any] | None:
    """best-const and mpc on the episodes of the run's validation curve (the same seeds,
    order, length and options), saved as ``curve_references.json``: {"episode_set",
    "policies": {name: mean trapping time}}; None if the curve has no recorded episodes.
    Lines already drawn there (by `agents.training.compile_ahead`, on the other core while
    the run trained) are read instead, if they are for the curve's episode set."""
    episodes = curve_episodes(run_dir)
    if episodes is None:
        return None
    path = Path(run_dir) / CURVE_REFERENCES
    if path.is_file():
        refs = json.loads(path.read_text())
        try:
            same_episodes(episodes, refs.get("episode_set"), "the curve and its reference lines")
        except ValueError:
            refs = None
        if refs is not None and set(names) <= set(refs.get("policies", {})):
            return refs
    _, config = settings.environment()
    return reference_lines(run_dir, config, settings.env_id, names)


def reference_lines(run_dir: Path, config: EnvConfig, env_id: str | None,
                    names: tuple[str, ...] = REFERENCE_NAMES,
                    strict: bool = True) -> dict[str, Any] | None:
    """Evaluate ``names`` on the run's curve episodes with ``config`` and save them as
    ``curve_references.json``. If ``config`` does not make the curve's episodes (the check
    `same_episodes` makes): ValueError, or with ``strict=False`` None and nothing saved."""
    from ..evaluation.evaluate import evaluate

    episodes = curve_episodes(run_dir)
    if episodes is None:
        return None
    table, _ = evaluate(list(names), config, episodes["episodes"], episodes["seed"],
                        max_episode_steps=episodes["max_episode_steps"], examples=0,
                        env_id=env_id)
    try:
        same_episodes(episodes, table["episode_set"], "the curve and its reference lines")
    except ValueError:
        if strict:
            raise
        return None
    refs = {"episode_set": table["episode_set"],
            "policies": {row["policy"]: row["trapping_time"]["mean"]
                         for row in table["policies"]}}
    write_text_atomically(Path(run_dir) / CURVE_REFERENCES, json.dumps(refs, indent=1) + "\n")
    return refs


def read_wall_rows(run_dir: Path) -> list[dict[str, float]]:
    """The rows of a run's ``evaluations_wall.csv`` (`WALL_CSV`) by column name, as floats;
    [] if the run has none."""
    path = Path(run_dir) / WALL_CSV
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]


def read_curve(run_dir: Path) -> dict[str, Any] | None:
    """The run's curve as arrays (``timesteps``, ``wall_seconds``, ``mean_return``,
    ``std_return``, ``trapping_time``) and its ``label``; None if the run has none."""
    saved: dict[str, Any] = {}
    config_file = run_dir / "config.json"
    if config_file.is_file():
        try:
            saved = json.loads(config_file.read_text())
        except ValueError:
            saved = {}
    wall_rows = read_wall_rows(run_dir)
    data_file = run_dir / "evaluations.npz"
    if data_file.is_file():
        data = np.load(data_file, allow_pickle=False)
        steps, results = data["timesteps"], data["results"]
        if "trapping_times" in data:
            trapping = data["trapping_times"]
        else:   # SB3's EvalCallback (older runs): episode lengths
            dt = 0.02
            try:
                dt = resolve_env(saved["env_id"],
                                 saved.get("env_kwargs") or {})[1].control_period
            except (KeyError, ValueError, TypeError):
                pass
            trapping = data["ep_lengths"] * dt
        wall = {int(r["timesteps"]): r["wall_seconds"] for r in wall_rows}
        return {"timesteps": np.asarray(steps),
                "wall_seconds": np.array([wall.get(int(s), np.nan) for s in steps]),
                "mean_return": results.mean(axis=1), "std_return": results.std(axis=1),
                "trapping_time": trapping.mean(axis=1),
                "label": f"validation ({trapping.shape[1]} episodes)",
                "episode_set": curve_episodes(run_dir)}
    if not wall_rows:
        return None
    def column(name: str) -> np.ndarray:
        return np.array([r[name] for r in wall_rows])

    return {"timesteps": column("timesteps").astype(np.int64),
            "wall_seconds": column("wall_seconds"), "mean_return": column("mean_return"),
            "std_return": np.full(len(wall_rows), np.nan),
            "trapping_time": column("mean_trapping_time"),
            "label": f"training episodes ({saved.get('backend', 'sb3')}, running mean)",
            "episode_set": None}


def plot_learning_curve(run_dir: Path, references: dict[str, Any] | None = None
                        ) -> Path | None:
    """The curve's trapping time against timesteps and against wall-clock seconds as
    ``learning_curve.png``, and the curve as ``learning_curve.csv``. ``references``
    (`curve_references`: {"episode_set", "policies": {name: mean trapping time}}) are drawn
    as horizontal lines; ValueError if they were measured on other episodes than the
    curve."""
    curve = read_curve(run_dir)
    if curve is None:
        return None
    lines: dict[str, float] = {}
    if references is not None:
        same_episodes(curve["episode_set"], references.get("episode_set"),
                      "the learning curve and its reference lines")
        lines = dict(references["policies"])
    steps, seconds, trap = curve["timesteps"], curve["wall_seconds"], curve["trapping_time"]
    rows = ["timesteps,mean_return,std_return,mean_trapping_time,wall_seconds"]
    rows += [f"{s},{r},{sd},{t},{w}" for s, r, sd, t, w in
             zip(steps, curve["mean_return"], curve["std_return"], trap, seconds)]
    (run_dir / "learning_curve.csv").write_text("\n".join(rows) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    have_wall = bool(np.isfinite(seconds).any())
    fig, axes = plt.subplots(1, 2 if have_wall else 1, figsize=(10 if have_wall else 6, 3.5),
                             dpi=100, sharey=True, squeeze=False)
    xs = [(steps, "timesteps")] + ([(seconds, "wall-clock seconds since training began")]
                                   if have_wall else [])
    for ax, (x, label) in zip(axes[0], xs):
        ax.plot(x, trap, color="C0", marker="o", ms=3, label=curve["label"])
        for k, (name, value) in enumerate(lines.items()):
            ax.axhline(value, color=("0.4", "C3", "C2")[k % 3], ls=("--", "-.", ":")[k % 3],
                       label=f"{name} {value:.2f} (same episodes)")
        ax.set_xlabel(label)
    axes[0][0].set_ylabel("mean trapping time [s]")
    axes[0][-1].legend(fontsize=7, loc="lower right")
    fig.suptitle(run_dir.name, fontsize=9)
    fig.tight_layout()
    out = run_dir / "learning_curve.png"
    fig.savefig(out)
    plt.close(fig)
    return out


__all__ = ["CURVE_EPISODES", "WALL_CSV", "append_curve_point", "compare", "curve_episodes",
           "curve_references", "plot_learning_curve", "read_curve", "read_wall_rows"]
