"""What a finished training run shows, whichever back end trained it: the learning curve
(``learning_curve.png`` and ``.csv``) and the closing comparison of the trained agent with
``best-const`` and ``mpc`` on fresh episodes (``comparison.md`` and ``.json``).

The curve comes from the run folder alone:

* ``evaluations.npz`` (SB3's EvalCallback) with ``evaluations_wall.csv``: the validation
  episodes' trapping time at each evaluation, against steps and wall-clock seconds;
* or, without it, ``evaluations_wall.csv`` alone (the RLlib back end writes one row per
  training iteration: its *training* episodes' running mean, labelled so on the plot).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

from agents.cli_args import resolve_env
from agents.seeds import COMPARE_SEED
from agents.training.runs import TrainSettings

WALL_CSV = "evaluations_wall.csv"
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
    from agents.evaluation.evaluate import evaluate, markdown
    from agents.evaluation.policies import load_policy

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
    refs = {row["policy"]: row["trapping_time"]["mean"] for row in table["policies"]
            if row["policy"] in ("best-const", "mpc")}
    plot_learning_curve(run_dir, refs, f" ({settings.compare_episodes} fresh ep.)")
    (run_dir / "comparison.md").write_text(text)
    (run_dir / "comparison.json").write_text(json.dumps(table, indent=1) + "\n")
    print(text)
    return text


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
        steps, results, lengths = data["timesteps"], data["results"], data["ep_lengths"]
        dt = 0.02
        try:
            dt = resolve_env(saved["env_id"], saved.get("env_kwargs") or {})[1].control_period
        except (KeyError, ValueError, TypeError):
            pass
        wall = {int(r["timesteps"]): r["wall_seconds"] for r in wall_rows}
        return {"timesteps": np.asarray(steps),
                "wall_seconds": np.array([wall.get(int(s), np.nan) for s in steps]),
                "mean_return": results.mean(axis=1), "std_return": results.std(axis=1),
                "trapping_time": lengths.mean(axis=1) * dt,
                "label": f"validation ({lengths.shape[1]} episodes)"}
    if not wall_rows:
        return None
    def column(name: str) -> np.ndarray:
        return np.array([r[name] for r in wall_rows])

    return {"timesteps": column("timesteps").astype(np.int64),
            "wall_seconds": column("wall_seconds"), "mean_return": column("mean_return"),
            "std_return": np.full(len(wall_rows), np.nan),
            "trapping_time": column("mean_trapping_time"),
            "label": f"training episodes ({saved.get('backend', 'sb3')}, running mean)"}


def plot_learning_curve(run_dir: Path, references: dict[str, float] | None = None,
                        reference_note: str = "") -> Path | None:
    """The curve's trapping time against timesteps and against wall-clock seconds as
    ``learning_curve.png``, and the curve as ``learning_curve.csv``. ``references`` (policy
    name -> mean trapping time, e.g. best-const and mpc from the closing comparison) are
    drawn as horizontal lines."""
    curve = read_curve(run_dir)
    if curve is None:
        return None
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
        for k, (name, value) in enumerate((references or {}).items()):
            ax.axhline(value, color=("0.4", "C3", "C2")[k % 3], ls=("--", "-.", ":")[k % 3],
                       label=f"{name} {value:.2f}{reference_note}")
        ax.set_xlabel(label)
    axes[0][0].set_ylabel("mean trapping time [s]")
    axes[0][-1].legend(fontsize=7, loc="lower right")
    fig.suptitle(run_dir.name, fontsize=9)
    fig.tight_layout()
    out = run_dir / "learning_curve.png"
    fig.savefig(out)
    plt.close(fig)
    return out


__all__ = ["WALL_CSV", "append_curve_point", "compare", "plot_learning_curve", "read_curve",
           "read_wall_rows"]
