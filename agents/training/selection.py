"""Model selection during training, for the back ends that select (``sb3`` and ``sbx``; RLlib
ships its final network and draws no validation curve).

**The validation curve.** Every evaluation runs the network on the same episodes:
``reset(seed=VALIDATION_SEED + i)`` for i < ``eval_episodes``, each to its end, through
`agents.evaluation.evaluate.evaluate` (the function every reference line goes through:
best-const and ``mpc`` in `agents.benchmark.time_to_target` and on the learning curve). Every
run of every seed uses that one set, recorded as ``curve_episodes.json`` (an
`agents.control.rollout.episode_set`), so a reference line can be checked to come from the
episodes of the curve it is drawn beside.

**The rule: the best few, re-evaluated on fresh episodes.** The maximum of a dozen noisy
evaluations is biased upward: the snapshot that scored best is, on average, one that was
lucky on those episodes (the winner's curse). So the run keeps the `TOP` snapshots with the
highest mean validation return (ties: the later one), and when training ends it evaluates
them again on four times as many *fresh* episodes (`fresh_set`: seeds from `RESELECT_SEED`,
a set of its own for each run, disjoint from the validation set and from the leaderboard's
test set) and ships the one with the highest
mean return there (ties: the later one) as ``selected_model.zip``.

**Its recorded score comes from episodes that chose nothing.** The shipped network is
scored once more on a second set of the same size (`report_set`, the next seeds of the
run's block), and that is the score its sidecar records. A score taken on the episodes a
choice was made on is a maximum of noisy estimates again, however few; one taken on
episodes no choice saw is an unbiased estimate of the network's score, whatever the rule
chose. Smoothing the curve would trade the curse for a lag on a curve that rises, and
keeping the final network would give up the selection that the learning rate's schedule and
the plateaus of the curves need (docs/model_selection.md, with the bias measured on Capture
and Storm).

``selection.json`` records the rule, the three episode sets, every candidate's two scores,
the shipped network's report score, and the snapshot the previous rule (the latest maximum
of the curve) would have shipped.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..control.rollout import episode_set
from ..seeds import RESELECT_SEED, TEST_SEED, VALIDATION_SEED
from .run_report import CURVE_EPISODES
from .runs import RunSettings

TOP = 3                                   # snapshots re-evaluated on fresh episodes
FRESH_FACTOR = 4                          # fresh episodes per validation episode
SELECTION_JSON = "selection.json"
RULE = (f"the {TOP} snapshots with the highest mean validation return, re-evaluated on "
        f"fresh episodes; the highest there is shipped (ties: the later snapshot) and "
        f"scored on a second fresh set that chose nothing")


def validation_set(settings: RunSettings) -> dict[str, Any]:
    """The episodes of every evaluation during a run of ``settings`` (`VALIDATION_SEED`)."""
    return _set(settings, VALIDATION_SEED)


def fresh_set(settings: RunSettings) -> dict[str, Any]:
    """The episodes the best snapshots of run ``settings.seed`` are re-evaluated on:
    `FRESH_FACTOR` × ``eval_episodes`` of them, the first half of the run's own block of
    seeds (`_reselect_block`), so that the offset of one set of episodes (easier or harder
    than the level's average) is noise across runs rather than a bias shared by all of them
    (how much sets of episodes differ: docs/model_selection.md)."""
    start, n, steps = _reselect_block(settings)
    return episode_set(settings.environment()[1], start, n, steps)


def report_set(settings: RunSettings) -> dict[str, Any]:
    """The episodes the shipped network's recorded score comes from: the second half of the
    run's block, as many as `fresh_set` and disjoint from it, so that no choice was made on
    them."""
    start, n, steps = _reselect_block(settings)
    return episode_set(settings.environment()[1], start + n, n, steps)


def _reselect_block(settings: RunSettings) -> tuple[int, int, int]:
    """Run ``settings.seed``'s first re-selection seed, the size of each of its two sets
    (2 · `FRESH_FACTOR` · ``eval_episodes`` seeds from ``RESELECT_SEED + seed · 2n``) and the
    episodes' length."""
    n = FRESH_FACTOR * settings.eval_episodes
    start = RESELECT_SEED + settings.seed * 2 * n
    if settings.seed < 0 or start + 2 * n > TEST_SEED:
        raise ValueError(f"--seed {settings.seed} with --eval-episodes {settings.eval_episodes}: "
                         f"the re-selection episodes (seeds from {RESELECT_SEED:,} + seed x 2 x "
                         f"{FRESH_FACTOR} x eval_episodes) must end before the test set's "
                         f"{TEST_SEED:,}; use a seed in "
                         f"[0, {(TEST_SEED - RESELECT_SEED) // (2 * n) - 1}]")
    return start, n, settings.max_episode_steps


def _set(settings: RunSettings, seed: int) -> dict[str, Any]:
    return episode_set(settings.environment()[1], seed, settings.eval_episodes,
                       settings.max_episode_steps)


def score(model_path: Path, settings: RunSettings, episodes: dict[str, Any]
          ) -> dict[str, Any]:
    """The saved model's mean return and trapping time on the `episode_set` ``episodes``,
    as the evaluation tool measures them (the model file read as data, with its sidecar's
    normalisation and frame stacking)."""
    from ..evaluation.evaluate import evaluate
    from ..evaluation.policies import load_policy

    _, config = settings.environment()
    table, details = evaluate([(str(model_path), load_policy(model_path, config))], config,
                              episodes["episodes"], episodes["seed"],
                              max_episode_steps=episodes["max_episode_steps"], examples=0,
                              env_id=settings.env_id)
    assert table["episode_set"] == episodes, (table["episode_set"], episodes)
    res = next(iter(details.values()))
    returns, times = np.asarray(res["return"], float), np.asarray(res["time"], float)
    return {"mean_return": float(returns.mean()), "mean_trapping_time": float(times.mean()),
            "returns": returns, "trapping_times": times}


def model_files(path: Path) -> list[Path]:
    """A saved model and the files beside it (sidecar, normalisation statistics)."""
    from ..evaluation.policies import vecnormalize_path

    return [path, path.with_suffix(".json"), vecnormalize_path(path)]


def copy_model(src: Path, dst: Path, extra: dict[str, Any] | None = None) -> None:
    """``src`` and its companion files as ``dst``; ``extra`` merged into the sidecar."""
    for a, b in zip(model_files(src), model_files(dst)):
        if a.is_file():
            shutil.copyfile(a, b)
    if extra:
        side = dst.with_suffix(".json")
        data = json.loads(side.read_text()) if side.is_file() else {}
        data.update(extra)
        side.write_text(json.dumps(data, indent=2, default=list))


class Selection:
    """The running state of a run's model selection: its curve, the `TOP` candidates (saved
    under ``candidates/``), and the choice at the end (`choose`)."""

    def __init__(self, run_dir: Path, settings: RunSettings, top: int = TOP):
        if isinstance(top, bool) or not isinstance(top, int) or top < 1:
            raise ValueError(f"top must be a positive integer, got {top!r}")
        self.run_dir, self.settings, self.top = Path(run_dir), settings, top
        self.folder = self.run_dir / "candidates"
        self.episodes = validation_set(settings)
        fresh_set(settings)           # a seed whose fresh episodes would not fit fails now
        self.kept: list[dict[str, Any]] = []
        self.steps: list[int] = []
        self.returns: list[np.ndarray] = []
        self.times: list[np.ndarray] = []
        self.best_mean = -np.inf
        (self.run_dir / CURVE_EPISODES).write_text(json.dumps(self.episodes, indent=1) + "\n")

    def offer(self, steps: int, save: Callable[[Path], Any]) -> dict[str, Any]:
        """Evaluate the network at ``steps`` (``save(path)`` writes it) on the validation
        episodes, record it on the curve, keep it if it is among the best `TOP`; return its
        score. ``best_model.zip`` is the first snapshot that reached the highest mean (as
        SB3's EvalCallback keeps it)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        path = self.folder / f"snapshot_{int(steps)}_steps.zip"
        save(path)
        result = score(path, self.settings, self.episodes)
        self.steps.append(int(steps))
        self.returns.append(result["returns"])
        self.times.append(result["trapping_times"])
        np.savez(self.run_dir / "evaluations.npz", timesteps=np.asarray(self.steps),
                 results=np.stack(self.returns), trapping_times=np.stack(self.times))
        if result["mean_return"] > self.best_mean:
            self.best_mean = result["mean_return"]
            copy_model(path, self.run_dir / "best_model.zip")
        entry = {"steps": int(steps), "path": path, "mean_return": result["mean_return"],
                 "mean_trapping_time": result["mean_trapping_time"]}
        ranked = sorted(self.kept + [entry], key=lambda c: (c["mean_return"], c["steps"]),
                        reverse=True)
        self.kept = ranked[:self.top]
        for dropped in ranked[self.top:]:
            for f in model_files(dropped["path"]):
                f.unlink(missing_ok=True)
        return result

    def choose(self) -> Path | None:
        """Re-evaluate the candidates on the fresh episodes, ship the best as
        ``selected_model.zip``, score it on the report episodes (its sidecar records the rule
        and the scores, the report score as its own), write
        ``selection.json``; return the selected model (None if nothing was evaluated)."""
        if not self.kept:
            return None
        fresh = fresh_set(self.settings)
        for c in self.kept:
            result = score(c["path"], self.settings, fresh)
            c["fresh_mean_return"] = result["mean_return"]
            c["fresh_mean_trapping_time"] = result["mean_trapping_time"]
        pick = max(self.kept, key=lambda c: (c["fresh_mean_return"], c["steps"]))
        max_rule = max(self.kept, key=lambda c: (c["mean_return"], c["steps"]))
        reported = report_set(self.settings)
        report = score(pick["path"], self.settings, reported)
        candidates = [{k: v for k, v in c.items() if k != "path"} for c in
                      sorted(self.kept, key=lambda c: c["steps"])]
        record = {"rule": RULE, "top": self.top, "validation_episodes": self.episodes,
                  "fresh_episodes": fresh, "report_episodes": reported,
                  "candidates": candidates, "selected_at_steps": pick["steps"],
                  "report_mean_return": report["mean_return"],
                  "report_mean_trapping_time": report["mean_trapping_time"],
                  "max_rule_at_steps": max_rule["steps"]}
        selected = self.run_dir / "selected_model.zip"
        copy_model(pick["path"], selected, {
            "selected_at_steps": pick["steps"],
            # the recorded score: the report episodes', which chose nothing (ship compares
            # runs on it)
            "validation_mean_return": report["mean_return"],
            "validation_mean_trapping_time": report["mean_trapping_time"],
            "validation_episodes": reported["episodes"], "validation_seed": reported["seed"],
            "in_run_mean_return": pick["mean_return"],
            "in_run_mean_trapping_time": pick["mean_trapping_time"],
            "fresh_mean_return": pick["fresh_mean_return"],
            "fresh_mean_trapping_time": pick["fresh_mean_trapping_time"],
            "selection": record})
        (self.run_dir / SELECTION_JSON).write_text(json.dumps(record, indent=1) + "\n")
        return selected


__all__ = ["CURVE_EPISODES", "FRESH_FACTOR", "RULE", "SELECTION_JSON", "TOP", "Selection", "copy_model",
           "fresh_set", "model_files", "report_set", "score", "validation_set"]
