"""How much a run's recorded score flatters the network it ships:
``python -m agents.benchmark.selection_bias RUN [RUN ...]``.

For each finished run (a folder with ``selection.json``, `agents.training.selection`) it
evaluates the selection's candidates on ``--episodes`` episodes no part of training or
selection saw (seeds from `COMPARE_SEED`, never the test set) and compares, for two rules
applied to the same run's snapshots:

* **max**: the snapshot with the highest mean validation return (the latest, on ties), with
  its score on the validation curve (the rule before issue 44);
* **top-k re-evaluated**: the snapshot the trainer ships, with its score on the fresh
  episodes it was chosen on;
* **top-k, report score** (the trainer's): the same snapshot, with its score on the report
  episodes, which chose nothing (the score its sidecar records).

The bias of a rule is its recorded score minus the same network's score on the unseen
episodes (mean trapping time [s]; the mean return beside it), and beside it the part of it
that is the scoring episodes' own offset, not the choice (`run_rows`). The report gives, per
level, the mean bias over runs ± its standard error. The unseen episodes are one set for
every run of a level, so their own sampling error is shared by all the runs and does not
show in their spread: the standard error adds it (the selected network's per-episode SD /
sqrt(episodes)) in quadrature to the SD over runs / sqrt(runs). Writes ``<out>.json`` and
``<out>.csv`` (a row per run, written as each run is done).

    python -m agents.benchmark.selection_bias runs/issue44/*_seed* --out bias
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import statistics
import sys
from pathlib import Path
from typing import Any

from ..seeds import COMPARE_SEED

RULES = ("max", "top-k re-evaluated", "top-k, report score")
FIELDS = ["env_id", "run", "rule", "selected_at_steps", "recorded_trapping_time",
          "unseen_trapping_time", "bias_trapping_time", "set_offset_trapping_time",
          "unseen_se_trapping_time", "recorded_return", "unseen_return", "bias_return",
          "set_offset_return", "unseen_se_return"]


def run_rows(run_dir: Path, episodes: int) -> list[dict[str, Any]]:
    """The three rules' rows of one run: every candidate and the final network scored on
    the unseen episodes. ``set_offset``: how much the rule's scoring episodes flatter a
    network they did not choose, against the unseen ones (the validation set: the final
    network, whose curve point is no choice; the fresh set: the mean over the candidates,
    which the validation set chose; the report set: NaN, its one score is the row's own).
    ``unseen_se``: the selected network's standard error on the unseen episodes. A run
    made before the trainer's current sets (fresh and report episodes of its own per seed)
    is scored on the sets the trainer now gives its seed, and the choice made again."""
    import numpy as np

    from ..control.rollout import episode_set
    from ..training import selection
    from ..training.runs import recorded_settings

    record = json.loads((run_dir / selection.SELECTION_JSON).read_text())
    path = {int(c["steps"]): run_dir / "candidates" / f"snapshot_{c['steps']}_steps.zip"
            for c in record["candidates"]}
    settings = recorded_settings(next(iter(path.values())))
    _, config = settings.environment()
    unseen_set = episode_set(config, COMPARE_SEED, episodes, settings.max_episode_steps)
    by_steps = {int(c["steps"]): c for c in record["candidates"]}
    fresh, reported = selection.fresh_set(settings), selection.report_set(settings)
    if record["fresh_episodes"] != fresh:
        for steps, c in by_steps.items():
            again = selection.score(path[steps], settings, fresh)
            c["fresh_mean_return"] = again["mean_return"]
            c["fresh_mean_trapping_time"] = again["mean_trapping_time"]
        record["selected_at_steps"] = max(by_steps, key=lambda k: (
            by_steps[k]["fresh_mean_return"], k))
    pick = by_steps[int(record["selected_at_steps"])]
    if record.get("report_episodes") != reported or "report_mean_return" not in record:
        again = selection.score(path[pick["steps"]], settings, reported)
        record["report_mean_return"] = again["mean_return"]
        record["report_mean_trapping_time"] = again["mean_trapping_time"]
    pick["report_mean_return"] = record["report_mean_return"]
    pick["report_mean_trapping_time"] = record["report_mean_trapping_time"]
    for steps, c in by_steps.items():
        c["unseen"] = selection.score(path[steps], settings, unseen_set)
    offsets = {"mean_trapping_time": 0.0, "mean_return": 0.0}
    fresh_offsets = {k: float(np.mean([c[f"fresh_{k}"] - c["unseen"][k]
                                       for c in by_steps.values()])) for k in offsets}
    final = run_dir / "final_model.zip"
    curve = run_dir / "evaluations.npz"
    if final.is_file() and curve.is_file():
        data = np.load(curve)
        unseen_final = selection.score(final, settings, unseen_set)
        offsets = {"mean_trapping_time": float(data["trapping_times"][-1].mean())
                   - unseen_final["mean_trapping_time"],
                   "mean_return": float(data["results"][-1].mean())
                   - unseen_final["mean_return"]}
    nan = {"mean_trapping_time": float("nan"), "mean_return": float("nan")}
    rows = []
    for rule, steps, prefix, offset in (
            ("max", record["max_rule_at_steps"], "", offsets),
            ("top-k re-evaluated", record["selected_at_steps"], "fresh_", fresh_offsets),
            ("top-k, report score", record["selected_at_steps"], "report_", nan)):
        c = by_steps[int(steps)]
        u = c["unseen"]
        se = {k: _se(u[a]) if a in u else float("nan")
              for k, a in (("mean_trapping_time", "trapping_times"), ("mean_return", "returns"))}
        rows.append({"env_id": settings.env_id, "run": run_dir.name, "rule": rule,
                     "selected_at_steps": int(steps),
                     "recorded_trapping_time": c[prefix + "mean_trapping_time"],
                     "unseen_trapping_time": u["mean_trapping_time"],
                     "bias_trapping_time": c[prefix + "mean_trapping_time"]
                     - u["mean_trapping_time"],
                     "set_offset_trapping_time": offset["mean_trapping_time"],
                     "unseen_se_trapping_time": se["mean_trapping_time"],
                     "recorded_return": c[prefix + "mean_return"],
                     "unseen_return": u["mean_return"],
                     "bias_return": c[prefix + "mean_return"] - u["mean_return"],
                     "set_offset_return": offset["mean_return"],
                     "unseen_se_return": se["mean_return"]})
    return rows


def _se(values: Any) -> float:
    """Standard error of the mean of per-episode values."""
    values = [float(v) for v in values]
    return statistics.stdev(values) / math.sqrt(len(values)) if len(values) > 1 else float("nan")


def summarise(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per level and rule: runs, mean bias ± standard error, in trapping time and return.
    The bias's standard error adds the unseen set's own (shared by every run, so absent
    from their spread) in quadrature to the spread's; the offset's is the spread's alone."""
    out = []
    for env_id in sorted({r["env_id"] for r in rows}):
        for rule in RULES:
            sel = [r for r in rows if r["env_id"] == env_id and r["rule"] == rule]
            if not sel:
                continue
            entry: dict[str, Any] = {"env_id": env_id, "rule": rule, "runs": len(sel)}
            for key in ("bias_trapping_time", "bias_return", "set_offset_trapping_time"):
                values = [r[key] for r in sel if math.isfinite(r[key])]
                if not values:                      # the report set's offset: none
                    entry[key] = {"mean": float("nan"), "se": float("nan")}
                    continue
                se = _se(values)
                if key.startswith("bias_"):
                    shared = statistics.fmean(
                        r.get("unseen_se_" + key[len("bias_"):], float("nan")) for r in sel)
                    if math.isfinite(shared):
                        se = math.hypot(se, shared)
                entry[key] = {"mean": statistics.fmean(values), "se": se}
            out.append(entry)
    return out


def markdown(summary: list[dict[str, Any]]) -> str:
    """The selection-bias ``summary`` as a Markdown table."""
    lines = ["| level | rule | runs | bias, trapping time [s] | of which the episode set's "
             "offset [s] | bias, return |", "|---|---|---|---|---|---|"]
    for e in summary:
        t, r, o = e["bias_trapping_time"], e["bias_return"], e["set_offset_trapping_time"]
        lines.append(f"| {e['env_id']} | {e['rule']} | {e['runs']} | "
                     f"{t['mean']:+.3f} ± {t['se']:.3f} | "
                     f"{'–' if math.isnan(o['mean']) else format(o['mean'], '+.3f')} | "
                     f"{r['mean']:+.1f} ± {r['se']:.1f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    ap = argparse.ArgumentParser(description="The bias of model selection: recorded score "
                                             "against unseen episodes, max rule and top-k.")
    ap.add_argument("runs", nargs="+", metavar="RUN", help="finished run folders")
    ap.add_argument("--episodes", type=int, default=2000,
                    help="unseen episodes per network (seeds from COMPARE_SEED)")
    ap.add_argument("--out", default="selection_bias", help="<out>.json and <out>.csv")
    ap.add_argument("--resume", action="store_true",
                    help="read the rows of runs already in <out>.csv (by folder name) "
                         "instead of evaluating them again")
    args = ap.parse_args(argv)
    if args.episodes < 2:
        ap.error(f"--episodes must be at least 2, got {args.episodes}")
    out = Path(args.out)
    rows: list[dict[str, Any]] = []
    done: dict[str, list[dict[str, Any]]] = {}
    if args.resume and out.with_suffix(".csv").is_file():
        with open(out.with_suffix(".csv"), newline="") as f:
            for row in csv.DictReader(f):
                parsed: dict[str, Any] = {k: row[k] for k in ("env_id", "run", "rule")}
                parsed.update({k: float(row[k]) for k in FIELDS if k not in parsed})
                parsed["selected_at_steps"] = int(parsed["selected_at_steps"])
                done.setdefault(parsed["run"], []).append(parsed)
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=FIELDS)
        w.writeheader()
        for run in args.runs:
            run_dir = Path(run)
            if run_dir.name in done:
                w.writerows(done[run_dir.name])
                rows += done[run_dir.name]
                continue
            if not (run_dir / "selection.json").is_file():
                print(f"{run}: no selection.json (unfinished, or not a selecting run); "
                      f"skipped", file=sys.stderr)
                continue
            new = run_rows(run_dir, args.episodes)
            w.writerows(new)
            f.flush()
            rows += new
            print(f"{run_dir.name}: " + "; ".join(
                f"{r['rule']} {r['recorded_trapping_time']:.2f} -> "
                f"{r['unseen_trapping_time']:.2f} s" for r in new), flush=True)
    summary = summarise(rows)
    command = "python -m agents.benchmark.selection_bias " + " ".join(sys.argv[1:] if argv is None
                                                                      else argv)
    out.with_suffix(".json").write_text(json.dumps(
        {"command": command, "episodes": args.episodes, "seed": COMPARE_SEED,
         "summary": summary, "runs": rows}, indent=1) + "\n")
    print(markdown(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
