"""The benchmark's report, from the result files alone: normalised scores, rliable's
aggregates (IQM and mean with stratified-bootstrap 95 % intervals, performance profiles,
probability of improvement) per level and across levels; `python -m agents.benchmark
--report` writes docs/benchmark.md and its figures, ``--json`` prints the same data.

**Normalised score.** A run's mean trapping time T on the level's test set, mapped so that
uniform random actions score 0 and the upper reference scores 1:
(T − T_random) / (T_upper − T_random). T_random, T_best-const and T_mpc are the
leaderboard's (the same 1,000 test episodes, docs/leaderboard.json); the upper reference is
the clairvoyant controller where ``benchmark_data/references.json`` has it for the level, else
``mpc`` (the report says which).
"""

from __future__ import annotations

import json
import sys
import warnings
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from ..paths import BENCHMARK_DATA, DOCS_DIR, REPO_ROOT

DOCS = DOCS_DIR
REFERENCES = BENCHMARK_DATA / "references.json"
REPS = 5000           # bootstrap replications (intervals stable to ~0.01 at 3-5 seeds)
PROFILE_TAUS = np.linspace(-0.25, 1.25, 61)


def load_results(out: Path) -> list[dict[str, Any]]:
    """Every finished cell's result under ``out`` (``<level>/<algo>/seed<s>.json``)."""
    results = []
    for path in sorted(Path(out).glob("*/*/seed*.json")):
        data = json.loads(path.read_text())
        if not all(k in data for k in ("level", "algo", "seed", "trapping_time")):
            raise ValueError(f"{path}: not a benchmark result (level, algo, seed, "
                             f"trapping_time)")
        results.append(data)
    return results


def references(board_path: Path = DOCS / "leaderboard.json",
               extra_path: Path = REFERENCES) -> dict[str, dict[str, float]]:
    """Per level: the test-set mean trapping times of random, best-const and mpc (the
    leaderboard), the clairvoyant's where measured, and which is the upper reference."""
    board = json.loads(Path(board_path).read_text())
    extra = json.loads(Path(extra_path).read_text()) if Path(extra_path).is_file() else {}
    refs: dict[str, dict[str, Any]] = {}
    for lid, table in board["levels"].items():
        rows = {r["policy"]: r["trapping_time"]["mean"] for r in table["policies"]}
        ref = {k: rows[k] for k in ("random", "best-const", "mpc") if k in rows}
        clair = extra.get("levels", {}).get(lid, {}).get("clairvoyant")
        if clair is not None:
            ref["clairvoyant"] = float(clair)
        ref["upper"] = "clairvoyant" if clair is not None else "mpc"
        refs[lid] = ref
    return refs


def clairvoyant_reference(level_id: str, path: Path = REFERENCES) -> dict[str, Any] | None:
    """The clairvoyant's test-set result on ``level_id`` (mean trapping time, its interval,
    the doomed share with its interval, episodes), or None where not measured."""
    if not Path(path).is_file():
        return None
    entry = json.loads(Path(path).read_text()).get("levels", {}).get(level_id)
    if entry is None:
        return None
    return {k: entry[k] for k in ("clairvoyant", "clairvoyant_ci", "doomed", "doomed_ci",
                                  "episodes", "seed")}


def normalise(t: float, ref: dict[str, Any]) -> float:
    """Trapping time ``t`` on the scale where random is 0 and the reference's upper policy is 1."""
    lo, hi = ref["random"], ref[ref["upper"]]
    return (t - lo) / (hi - lo)


def _aggregates(score_dict: dict[str, np.ndarray]) -> dict[str, dict[str, Any]]:
    from rliable import library as rly
    from rliable import metrics

    def both(x):
        return np.array([metrics.aggregate_iqm(x), metrics.aggregate_mean(x)])

    out = {}
    for a, scores in score_dict.items():
        # One stream per row, seeded by its name, so that a row's interval is the same in
        # every run whatever the other rows are
        with _bootstrap_stream(zlib.crc32(a.encode())) as stream:
            point, interval = rly.get_interval_estimates({a: scores}, both, reps=REPS,
                                                         random_state=stream)
        out[a] = {"iqm": float(point[a][0]), "iqm_ci": [float(v) for v in interval[a][:, 0]],
                  "mean": float(point[a][1]), "mean_ci": [float(v) for v in interval[a][:, 1]]}
    return out


@contextmanager
def _bootstrap_stream(seed: int) -> Iterator[np.random.RandomState]:
    """A seeded stream for one of rliable's bootstraps. rliable 1.2's stratified bootstraps
    draw their indices from numpy's global stream (``np.random.choice``) and ignore the
    ``random_state`` they pass on to arch, so the global stream is seeded here too, and
    given back as it was after: without this the intervals changed from run to run in
    the second decimal."""
    saved = np.random.get_state()
    np.random.seed(seed)
    try:
        with warnings.catch_warnings():   # arch's notice that random_state will change name
            warnings.simplefilter("ignore", FutureWarning)
            yield np.random.RandomState(seed)
    finally:
        np.random.set_state(saved)


def _improvement(scores: np.ndarray, baseline: np.ndarray) -> tuple[float, list[float]]:
    """P(a run of the algorithm scores above the baseline), with its bootstrap interval;
    ``baseline`` is a deterministic policy's score per task, repeated per run."""
    from rliable import library as rly
    from rliable import metrics

    y = np.broadcast_to(baseline, scores.shape).copy()
    with _bootstrap_stream(1) as stream:
        point, interval = rly.get_interval_estimates(
            {"x": (scores, y)}, metrics.probability_of_improvement, reps=REPS // 5,
            random_state=stream)
    return float(point["x"]), [float(v) for v in np.ravel(interval["x"])]


def _load_at_end(run: dict[str, Any]) -> float | None:
    """The machine's 1-minute load average when the run ended (None: not recorded)."""
    load = run.get("load_average_at_end")
    return float(load[0]) if load else None


def _median_run(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The run of median training time (the lower of the two middle ones for an even count),
    so that its wall time is shown with the load it was measured under."""
    return sorted(runs, key=lambda r: r["train_wall_s"])[(len(runs) - 1) // 2]


def report_data(results: list[dict[str, Any]], refs: dict[str, dict[str, Any]]
                ) -> dict[str, Any]:
    """The report's numbers: per level and algorithm, and across levels."""
    levels = sorted({r["level"] for r in results},
                    key=lambda lid: list(refs).index(lid) if lid in refs else 99)
    algos = sorted({r["algo"] for r in results})
    data: dict[str, Any] = {"levels": {}, "across_levels": {}, "references": refs,
                            "normalisation": "0 = uniform random actions, 1 = the level's "
                                             "upper reference (clairvoyant, else mpc)"}
    by: dict[tuple[str, str], list[dict[str, Any]]] = {(r["level"], r["algo"]): [] for r in results}
    for r in results:
        by[(r["level"], r["algo"])].append(r)
    for lid in levels:
        ref = refs[lid]
        runs = {a: sorted(by[(lid, a)], key=lambda r: r["seed"]) for a in algos
                if (lid, a) in by}
        scores = {a: np.array([[normalise(r["trapping_time"]["mean"], ref)] for r in rs])
                  for a, rs in runs.items()}
        agg = _aggregates(scores)
        table = {}
        for a, rs in runs.items():
            times = [r["trapping_time"]["mean"] for r in rs]
            median_run = _median_run(rs)
            row = {"seeds": len(rs), "seed_list": [r["seed"] for r in rs], **agg[a],
                   "trapping_time_mean": float(np.mean(times)),
                   "trapping_time_runs": [round(t, 4) for t in times],
                   "kept_mean": float(np.mean([r["kept"]["mean"] for r in rs])),
                   "budget_steps": rs[0]["budget_steps"],
                   # wall times compare only between runs trained under similar load
                   "train_wall_s_median_run": float(median_run["train_wall_s"]),
                   "load_at_end_median_run": _load_at_end(median_run),
                   "test_episodes": rs[0]["test"]["episodes"]}
            for base in ("best-const", "mpc"):
                p, ci = _improvement(scores[a], np.array([[normalise(ref[base], ref)]]))
                row[f"p_improve_{base}"], row[f"p_improve_{base}_ci"] = p, ci
            table[a] = row
        data["levels"][lid] = table
    # Across levels: the rows are compared on the same levels, those every row has run (a
    # level one row has not reached yet, as the Lab level's newer cells, would otherwise
    # drop every other row from the aggregate), each over the seeds all those levels have
    # for it (a runs x levels matrix).
    shared = [lid for lid in levels if all(by.get((lid, a)) for a in algos)]
    data["across_levels_levels"] = shared
    matrices = {}
    for a in algos:
        common = set.intersection(*[{r["seed"] for r in by.get((lid, a), [])}
                                    for lid in shared]) if shared else set()
        if not common:
            continue
        seeds = sorted(common)
        matrices[a] = np.array([[normalise(next(r for r in by[(lid, a)] if r["seed"] == s)
                                           ["trapping_time"]["mean"], refs[lid])
                                 for lid in shared] for s in seeds])
        data["across_levels"][a] = {"seeds": len(seeds), "levels": shared}
    if matrices:
        for a, agg in _aggregates(matrices).items():
            data["across_levels"][a].update(agg)
            for base in ("best-const", "mpc"):
                p, ci = _improvement(matrices[a], np.array(
                    [[normalise(refs[lid][base], refs[lid]) for lid in shared]]))
                data["across_levels"][a][f"p_improve_{base}"] = p
                data["across_levels"][a][f"p_improve_{base}_ci"] = ci
    data["_matrices"] = matrices
    return data


def figures(data: dict[str, Any], figs: Path) -> list[str]:
    """Interval estimates and performance profiles across levels (rliable's plots)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from rliable import library as rly
    from rliable import plot_utils

    matrices = data["_matrices"]
    if not matrices:
        return []
    figs.mkdir(parents=True, exist_ok=True)
    algos = sorted(matrices)
    from matplotlib.colors import ListedColormap

    tab10 = plt.get_cmap("tab10")
    assert isinstance(tab10, ListedColormap)  # matplotlib's ten qualitative colours
    # matplotlib's stubs give .colors its constructor argument's type (any array-like or one
    # colour), though it is the list of colours
    colors: dict[str, Any] = dict(zip(algos, tab10.colors))  # type: ignore[arg-type]
    across = data["across_levels"]
    point = {a: np.array([across[a]["iqm"], across[a]["mean"]]) for a in algos}
    interval = {a: np.array([across[a]["iqm_ci"], across[a]["mean_ci"]]).T for a in algos}
    fig, axes = plot_utils.plot_interval_estimates(
        point, interval, metric_names=["IQM", "Mean"], algorithms=algos, colors=colors,
        xlabel="normalised trapping time (0 random, 1 upper reference)")
    fig.savefig(figs / "benchmark_aggregates.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    profiles, cis = rly.create_performance_profile(matrices, PROFILE_TAUS)
    fig, ax = plt.subplots(figsize=(6.5, 4.0))
    plot_utils.plot_performance_profiles(profiles, PROFILE_TAUS, performance_profile_cis=cis,
                                         colors=colors, xlabel=r"normalised score $\tau$",
                                         ax=ax)
    levels = next(iter(across.values()))["levels"]
    refs = data["references"]
    for base, style in (("best-const", ":"), ("mpc", "--")):   # the baselines' mean score
        x = float(np.mean([normalise(refs[lid][base], refs[lid]) for lid in levels]))
        ax.axvline(x, color="0.3", linestyle=style, linewidth=1)
        ax.text(x, 1.02, base, ha="center", fontsize=8, transform=ax.get_xaxis_transform())
    ax.legend([plt.Line2D([], [], color=colors[a]) for a in algos], algos, loc="lower left",
              fontsize=9)
    fig.savefig(figs / "benchmark_profiles.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return ["figures/benchmark_aggregates.png", "figures/benchmark_profiles.png"]


def _ci(v: float, ci: list[float], fmt: str = "{:.2f}") -> str:
    return f"{fmt.format(v)} [{fmt.format(ci[0])}, {fmt.format(ci[1])}]"


def provenance(results: list[dict[str, Any]]) -> dict[str, Any]:
    """The library versions, machines, dates and loads the results were made with."""
    versions: dict[str, set[str]] = {}
    for r in results:
        for k, v in r.get("versions", {}).items():
            versions.setdefault(k, set()).add(v)
    loads = [x for x in map(_load_at_end, results) if x is not None]
    training_s: dict[str, float] = {}
    for r in results:
        training_s[r["algo"]] = training_s.get(r["algo"], 0.0) + r["train_wall_s"]
    return {"versions": {k: sorted(v) for k, v in sorted(versions.items())},
            "training_s": {k: round(v, 1) for k, v in sorted(training_s.items())},
            "seeds": sorted({r["seed"] for r in results}),
            "machines": sorted({r.get("machine", "?") for r in results}),
            "dates": sorted({str(r.get("date", "?"))[:10] for r in results}),
            "load_average": [round(min(loads), 1), round(max(loads), 1)] if loads else None}


def missing_cells(data: dict[str, Any], rows: dict[str, Any], seeds: tuple[int, ...],
                  levels: list[str]) -> dict[str, dict[str, list[int]]]:
    """Per level of the suite (``levels``, on the leaderboard) and row of ``rows``: the seeds
    of ``seeds`` with no result file (only where some are missing)."""
    out: dict[str, dict[str, list[int]]] = {}
    for lid in levels:
        if lid not in data["references"]:
            continue
        table = data["levels"].get(lid, {})
        for a in rows:
            have = set(table[a]["seed_list"]) if a in table else set()
            lack = [s for s in seeds if s not in have]
            if lack:
                out.setdefault(lid, {})[a] = lack
    return out


def _intro_lines(results_dir: str, test_episodes: int) -> list[str]:
    """The page's opening: what was run and how it is scored."""
    lines = ["# Benchmark", "",
             "Generated by `python -m agents.benchmark --report` from the result files in "
             f"`{results_dir}`; do not edit by hand. Each row is an algorithm with its "
             "library's generic hyperparameters (no per-level tuning, no imitation), trained "
             "on each non-calm level from several seeds for one fixed budget of env steps; "
             "each run's final network is evaluated alone, deterministic, on the level's frozen "
             f"test set ({test_episodes} episodes from seed 2,000,000, docs/leaderboard.md). "
             "The `ppo-fast` row is the exception: the project's fast recipe, one recipe for "
             "every level, trained as `train.py` trains (its model selected on validation "
             "episodes); `ppo-fast-sbx` is the same recipe with SBX's PPO as the learner.",
             "", "## Scores", "",
             "**Normalised score**: a run's mean trapping time T mapped so that uniform random "
             "actions score 0 and the level's upper reference 1, (T - T_random) / (T_upper - "
             "T_random). Aggregates are rliable's: the interquartile mean (IQM: the mean of "
             "the middle half of the runs' scores) and the mean "
             "over runs with stratified-bootstrap 95 % intervals; P(>best-const) and P(>mpc) "
             "are the probability that a run beats the deterministic baseline's score (0.5 "
             "for a tie), with bootstrap intervals.", ""]
    return lines


def _reference_lines(data: dict[str, Any], shown: list[str]) -> list[str]:
    """The references per level: random, best-const, mpc and the clairvoyant controller."""
    lines: list[str] = []
    refs = data["references"]
    lines += ["The references, on the same test episodes: random, best-const and mpc from the "
              "leaderboard; the clairvoyant controller (`agents/control/clairvoyant.py`: it knows the "
              "ball and the future disturbances and plans with the true simulator, never "
              "keeping a ball shorter than mpc or the shipped agent) from "
              "`benchmark_data/references.json` (`python -m agents.benchmark.headroom`). *Doomed*: the share "
              "of starts the clairvoyant still loses (Wilson score 95 % interval, a binomial "
              "interval), an estimate of "
              "what no controller can win.", "",
              "| level | random | best-const | mpc | clairvoyant | doomed | upper reference |",
              "|---|---|---|---|---|---|---|"]
    for lid in shown:
        r = refs[lid]
        c = clairvoyant_reference(lid)
        clair = (f"{c['clairvoyant']:.2f} s [{c['clairvoyant_ci']['low']:.2f}, "
                 f"{c['clairvoyant_ci']['high']:.2f}] ({c['episodes']} episodes)"
                 if c else "not measured")
        doomed = (f"{100 * c['doomed']:.1f} % [{100 * c['doomed_ci']['low']:.1f}, "
                  f"{100 * c['doomed_ci']['high']:.1f}]" if c else "—")
        lines.append(f"| `{lid}` | {r['random']:.2f} s | {r['best-const']:.2f} s | "
                     f"{r['mpc']:.2f} s | {clair} | {doomed} | {r['upper']} |")
    return lines


def _across_levels_lines(data: dict[str, Any], figure_paths: list[str]) -> list[str]:
    """The aggregates across levels and the figures (none before every row has run)."""
    lines: list[str] = []
    if data["across_levels"]:
        left_out = [lid for lid in data["levels"] if lid not in data["across_levels_levels"]]
        lines += ["", "### Across levels", "",
                  "On " + ", ".join(f"`{lid}`" for lid in data["across_levels_levels"])
                  + (": the levels every row has run (left out: "
                     + ", ".join(f"`{lid}`" for lid in left_out) + ")." if left_out else "."),
                  "",
                  "| algorithm | runs per level | IQM | mean | P(>best-const) | P(>mpc) |",
                  "|---|---|---|---|---|---|"]
        for a, row in data["across_levels"].items():
            lines.append(f"| {a} | {row['seeds']} | {_ci(row['iqm'], row['iqm_ci'])} | "
                         f"{_ci(row['mean'], row['mean_ci'])} | "
                         f"{_ci(row['p_improve_best-const'], row['p_improve_best-const_ci'])} | "
                         f"{_ci(row['p_improve_mpc'], row['p_improve_mpc_ci'])} |")
        lines += [""] + [f"![{Path(p).stem}]({p})" for p in figure_paths]
    return lines


def _missing_note(missing: dict[str, dict[str, list[int]]]) -> list[str]:
    """How cells not run yet are marked (nothing when every cell has run)."""
    lines: list[str] = []
    if missing:
        lines += ["", "Cells not run yet are marked *not run* (no result file; `python -m "
                  "agents.benchmark --levels ID --algos ROW` runs them); a row with fewer seeds "
                  "than the suite's names the missing ones. The aggregates across levels compare the "
                  "rows on the levels every row has run."]
    return lines


def _level_lines(data: dict[str, Any], shown: list[str], rows: dict[str, Any],
                 seeds: tuple[int, ...], missing: dict[str, dict[str, list[int]]]
                 ) -> list[str]:
    """One table per level: every row's runs, scores, budget and training time."""
    lines: list[str] = []
    for lid in shown:
        table = data["levels"].get(lid, {})
        lines += ["", f"### {lid}", "",
                  "| algorithm | seeds | trapping time (mean of runs) [s] | kept | IQM | mean "
                  "| P(>best-const) | P(>mpc) | budget | training (median run; load at its end) |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for a in rows:
            lack = missing.get(lid, {}).get(a)
            if a not in table and lack:
                lines.append(f"| {a} | *not run* (0 of {len(seeds)}) | — | — | — | — | — | — "
                             f"| — | — |")
        for a, row in table.items():
            runs = ", ".join(f"{t:.2f}" for t in row["trapping_time_runs"])
            lines.append(
                f"| {a} | {row['seeds']} ({', '.join(map(str, row['seed_list']))}"
                + (f"; *not run*: {', '.join(map(str, missing[lid][a]))}"
                   if missing.get(lid, {}).get(a) else "") + ") | "
                f"{row['trapping_time_mean']:.2f} ({runs}) | {100 * row['kept_mean']:.0f} % | "
                f"{_ci(row['iqm'], row['iqm_ci'])} | {_ci(row['mean'], row['mean_ci'])} | "
                f"{_ci(row['p_improve_best-const'], row['p_improve_best-const_ci'])} | "
                f"{_ci(row['p_improve_mpc'], row['p_improve_mpc_ci'])} | "
                f"{row['budget_steps']:,} steps | {row['train_wall_s_median_run'] / 60:.1f} min"
                + (f" ({row['load_at_end_median_run']:.1f})"
                   if row["load_at_end_median_run"] is not None else "") + " |")
    return lines


def _rows_lines(rows: dict[str, Any]) -> list[str]:
    """The suite's rows: library, budget and hyperparameters."""
    lines: list[str] = []
    lines += ["", "## The rows", "", "| row | library | budget | hyperparameters |",
              "|---|---|---|---|"]
    for a in rows.values():
        lines.append(f"| {a.name} | {a.library}.{a.cls} ({a.policy}) | {a.budget:,} env steps "
                     f"| {a.note}; {a.n_envs} ball(s) stepped together |")
    return lines


def _running_lines(seeds: tuple[int, ...]) -> list[str]:
    """How to run the suite, add a row, and which seeds it uses."""
    lines: list[str] = []
    lines += ["", "## Running it", "",
              "```bash",
              "pip install -e \".[benchmark]\"                 # rliable, sb3-contrib",
              "python -m agents.benchmark                        # every missing cell, in turn",
              "python -m agents.benchmark --only SaddleTrap-Storm-v0/sac/1   # one cell",
              "python -m agents.benchmark --address HOST:PORT    # as Ray tasks on a cluster",
              "python -m agents.benchmark --algos ppo-fast --keep-runs RUNS   # keep the runs "
              "(curves) for agents.benchmark.time_to_target --reuse",
              "python -m agents.benchmark --report               # this page and its figures",
              "python -m agents.benchmark --report --json        # the same data as JSON",
              "```", "",
              f"The default cells are every non-calm level x every row x seeds "
              f"{', '.join(map(str, seeds))}. A cell writes `benchmark_data/results/<level>/<algo>/"
              "seed<s>.json` when it finishes (atomically): the test-set trapping time with its "
              "interval, kept share, return, every episode's trapping time, the budget, the "
              "wall time, the library versions and the machine. A killed suite rerun skips "
              "finished cells (`--redo` reruns them); commit each finished file. On a Ray "
              "cluster (`--address`, the `[rllib]` extra's Ray) every cell is a one-CPU task and "
              "the driver writes the files as they arrive.", "",
              "**Adding a row.** Add an `Algo` to `ALGOS` in `agents/benchmark/run.py` (library, "
              "class, policy, budget, the keywords it runs with), run its cells, commit the "
              "files and regenerate this page. A recipe of `agents/hyperparams/ppo.yml` is a "
              "row with `recipe_of` (the level whose entry it runs everywhere; `backend` "
              "picks the `train.py` back end). A method "
              "outside SB3 needs `run_cell` to train "
              "it and hand `agents.evaluation.evaluate.evaluate` an object with SB3's `predict`.", "",
              "**Seeds.** Training run s steps episodes seeded from s (training episodes); the "
              "test set is seeds 2,000,000 onwards (`agents/seeds.py`), used for nothing else. "
              "The generic rows do no model selection (the final network is evaluated); the "
              "recipe row selects on the validation episodes (seeds from 1,000,000), which "
              "neither training nor the test set uses.", ""]
    return lines


def _provenance_lines(data: dict[str, Any]) -> list[str]:
    """Why this many seeds, and the versions and machines the runs were made with."""
    lines: list[str] = []
    prov = data.get("provenance")
    if prov and prov.get("seeds"):
        hours = {a: s / 3600 for a, s in prov["training_s"].items()}
        n_seeds = len(prov["seeds"])
        lines += [f"**Why {n_seeds} seeds.** The committed runs took "
                  f"{sum(hours.values()):.1f} hours of training wall time ("
                  + ", ".join(f"{a} {h:.1f} h" for a, h in hours.items())
                  + f") on {', '.join(prov['machines'])}, an upper bound of their cost since "
                  "many ran beside other jobs, so each further seed would cost up to "
                  f"{sum(hours.values()) / n_seeds:.0f} hours more. The intervals above are over "
                  "these runs; more seeds narrow them: `python -m agents.benchmark --seeds "
                  f"{max(prov['seeds']) + 1} {max(prov['seeds']) + 2}` adds two without redoing "
                  "any.", ""]
    if prov:
        vers = ", ".join(f"{k} {'/'.join(v)}" for k, v in prov["versions"].items())
        load = prov["load_average"]
        lines += ["**Versions and machine.** " + vers + f". Machine: {', '.join(prov['machines'])}"
                  f"; runs made on {', '.join(prov['dates'])}"
                  + (f", 1-minute load average at the end of a run {load[0]}-{load[1]} "
                     "(wall times are comparable only between runs made under similar load; "
                     "scores do not depend on it)" if load else "") + ".", ""]
    return lines


def markdown(data: dict[str, Any], figure_paths: list[str], results_dir: str,
             rows: dict[str, Any], seeds: tuple[int, ...], test_episodes: int) -> str:
    """docs/benchmark.md; ``rows`` are the suite's algorithms (`agents.benchmark.run.ALGOS`),
    passed in so that the report does not import the runner. Cells without a result
    (``data["missing"]``, `missing_cells`) are marked, a level without any listed."""
    missing: dict[str, dict[str, list[int]]] = data.get("missing", {})
    shown = list(data["levels"]) + [lid for lid in missing if lid not in data["levels"]]

    lines = _intro_lines(results_dir, test_episodes)
    lines += _reference_lines(data, shown)
    lines += _across_levels_lines(data, figure_paths)
    lines += _missing_note(missing)
    lines += _level_lines(data, shown, rows, seeds, missing)
    lines += _rows_lines(rows)
    lines += _running_lines(seeds)
    lines += _provenance_lines(data)
    return "\n".join(lines) + "\n"


def main_report(out: Path, rows: dict[str, Any], seeds: tuple[int, ...], test_episodes: int,
                docs: Path | None = None, as_json: bool = False,
                levels: list[str] | None = None) -> int:
    """docs/benchmark.md and benchmark.json (or, ``as_json``, the data on stdout) from the
    results under ``out``; ``levels``: the suite's levels, whose cells without a result are
    marked (default: only the levels that have results)."""
    results = load_results(out)
    if not results:
        print(f"no result files in {out}: run python -m agents.benchmark first",
              file=sys.stderr)
        return 1
    data = report_data(results, references())
    data["provenance"] = provenance(results)
    data["missing"] = missing_cells(data, rows, seeds, list(levels or data["levels"]))
    data.pop("_matrices") if as_json else None
    if as_json:
        sys.stdout.write(json.dumps(data, indent=1) + "\n")
        return 0
    docs = docs or DOCS
    paths = figures(data, docs / "figures")
    data.pop("_matrices")
    try:
        shown = str(Path(out).resolve().relative_to(REPO_ROOT))
    except ValueError:
        shown = str(out)
    (docs / "benchmark.md").write_text(markdown(data, paths, shown, rows, seeds, test_episodes))
    (docs / "benchmark.json").write_text(json.dumps(data, indent=1) + "\n")
    print(f"wrote {docs / 'benchmark.md'}, benchmark.json and {len(paths)} figure(s) from "
          f"{len(results)} result file(s)")
    return 0


__all__ = ["clairvoyant_reference", "load_results", "main_report", "missing_cells", "normalise",
           "references", "report_data"]
