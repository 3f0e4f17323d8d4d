"""Figures and the summary of a benchmark run, made from its CSV alone."""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

from .core import MODEL_TIERS, TIERS

# A row of bench.csv as `read_rows` returns it: the NUMERIC columns as floats, the others as
# strings. Read by computed column names (``r[key]``), which a TypedDict cannot check.
Row = dict[str, Any]
# The summary (summary.json): a JSON document of nested dicts and lists of mixed values.
Summary = dict[str, Any]

TARGET_ERROR = 1e-9          # [m] target 1: one rolling ball at <= 1e-9 m over the run
TARGET_SPEEDUP = 100.0
TARGET_BALL_STEPS = 2e6      # target 2: ball-steps per second, batch of 1024, rk4 dt = 1 ms
TARGET_JACOBI = 1e-9         # target 3: relative Jacobi drift over 1e4 saddle periods

NUMERIC = ("rtol", "dt", "max_step", "a", "R", "omega", "x0", "y0", "t_end", "dt_out",
           "wall_s", "repeats", "us_per_sim_s", "steps", "rhs_evals", "error_m",
           "model_error_m", "phase_changes", "slipping_share", "batch_n", "batch_t_end",
           "batch_wall_s", "batch_threads", "batch_us_per_ball_sim_s", "batch_ball_steps_per_s",
           "batch_alone_us_per_ball_sim_s", "compile_s", "batch_compile_s")
# The errors at which the peers are compared with the simulator [m], and their keys in the
# summary (no dot: the figure store reads them as one step of a dotted path).
PEER_ERRORS = {"1e-6": 1e-6, "1e-9": 1e-9}


def read_rows(path: str | Path) -> list[Row]:
    """The CSV's rows with numeric columns as floats (blank → nan)."""
    rows = []
    with open(path, newline="", encoding="utf-8") as fh:
        for raw in csv.DictReader(fh):
            row: Row = dict(raw)
            for k in NUMERIC:
                v = raw.get(k, "")
                row[k] = float(v) if v not in ("", None) else math.nan
            rows.append(row)
    return rows


def _ok(row: Row, key: str = "error_m") -> bool:
    v = row[key]
    return row["status"] == "ok" and isinstance(v, float) and math.isfinite(v)


def cheapest_meeting(rows, tol: float, key: str = "error_m", cost: str = "us_per_sim_s"):
    """The row of least ``cost`` whose ``key`` error is at most ``tol`` (None if none)."""
    good = [r for r in rows if _ok(r, key) and r[key] <= tol and math.isfinite(r[cost])]
    return min(good, key=lambda r: r[cost]) if good else None


def interpolated_cost(rows, tol: float, key: str = "error_m", cost: str = "us_per_sim_s"
                      ) -> float:
    """Cost at exactly ``tol`` on the lower convex hull... simplified: log-log interpolation
    between the cheapest row meeting ``tol`` and the most accurate cheaper row missing it."""
    good = [r for r in rows if _ok(r, key) and math.isfinite(r[cost])]
    meet = cheapest_meeting(good, tol, key, cost)
    if meet is None:
        return math.nan
    cheaper = [r for r in good if r[key] > tol and r[cost] < meet[cost]]
    if not cheaper:
        return float(meet[cost])
    miss = min(cheaper, key=lambda r: r[key])
    x0, x1 = math.log(miss[key]), math.log(max(meet[key], 1e-300))
    y0, y1 = math.log(miss[cost]), math.log(meet[cost])
    if x0 == x1:
        return float(meet[cost])
    return float(math.exp(y0 + (math.log(tol) - x0) * (y1 - y0) / (x1 - x0)))


def summarize(rows: list[Row], extra: Summary | None = None) -> Summary:
    """The targets and the per-tier work-precision fronts, from the rows."""
    out: Summary = {}
    rolling = [r for r in rows if r["tier"] == "rolling"]
    ours = [r for r in rolling if r["solver"] == "saddle_env"]
    # The target's peer is scipy on the plain-numpy model (label "scipy DOP853"); the lean
    # and njit right-hand sides under the same stepper are peers of their own (`peer_comparison`).
    dop = [r for r in rolling if r["solver"] == "scipy" and r["label"] == "scipy DOP853"]
    best_ours = cheapest_meeting(ours, TARGET_ERROR)
    best_dop = cheapest_meeting(dop, TARGET_ERROR)
    t1: Summary = {"target": f">= {TARGET_SPEEDUP:g}x less wall time per simulated "
                                       f"second than scipy DOP853 at <= {TARGET_ERROR:g} m"}
    if best_ours:
        t1["ours"] = _brief(best_ours)
    if best_dop:
        t1["scipy_dop853"] = _brief(best_dop)
    if best_ours and best_dop:
        t1["speedup_cheapest_rows"] = best_dop["us_per_sim_s"] / best_ours["us_per_sim_s"]
        ci, cd = interpolated_cost(ours, TARGET_ERROR), interpolated_cost(dop, TARGET_ERROR)
        t1["speedup_interpolated"] = cd / ci if ci > 0 else math.nan
        t1["met"] = bool(t1["speedup_cheapest_rows"] >= TARGET_SPEEDUP)
    out["target_speedup"] = t1
    rk4 = [r for r in ours if r["method"] == "rk4" and r["dt"] == 1e-3
           and math.isfinite(r["batch_ball_steps_per_s"])]
    if rk4:
        r = rk4[0]
        out["target_batch"] = {
            "target": f">= {TARGET_BALL_STEPS:g} ball-steps/s, batch of 1024 rolling balls, "
                      "rk4 dt = 1 ms",
            "batch_n": r["batch_n"], "threads": r["batch_threads"],
            "ball_steps_per_s": r["batch_ball_steps_per_s"],
            "us_per_ball_sim_s": r["batch_us_per_ball_sim_s"], "error_m": r["error_m"],
            "single_ball_steps_per_s": r["steps"] / r["wall_s"],
            "met": bool(r["batch_ball_steps_per_s"] >= TARGET_BALL_STEPS)}
    fronts: dict[str, list[Summary]] = {}
    for tier in TIERS:
        tier_rows = [r for r in rows if r["tier"] == tier and r["solver"] == "saddle_env"]
        if not tier_rows:
            continue
        fronts[tier] = []
        for tol in (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11):
            key = "model_error_m" if tier == "linear" else "error_m"
            r = cheapest_meeting(tier_rows, tol, key)
            if r is not None:
                fronts[tier].append({"error_at_most_m": tol, **_brief(r)})
    out["cheapest_setting_per_error"] = fronts
    tiers = {}
    for tier in TIERS:
        tier_rows = [r for r in rows if r["tier"] == tier and _ok(r, "model_error_m")]
        if tier_rows:
            best = min(tier_rows, key=lambda r: r["model_error_m"])
            tiers[tier] = {"model_error_m": best["model_error_m"],
                           "cheapest_us_per_sim_s": min(r["us_per_sim_s"] for r in tier_rows)}
    out["model_error_vs_rolling"] = tiers
    peers = peer_comparison(rows)
    if peers:
        out["peers"] = peers
    if extra:
        out.update(extra)
    return out


def _peer_key(r: Row) -> str:
    """A peer row's key: the compiled peer's, or "plain" for scipy on the plain-numpy model."""
    return str(r.get("peer") or ("plain" if r["label"] == "scipy DOP853" else ""))


def peer_comparison(rows: list[Row]) -> Summary:
    """Each peer against the simulator on the rolling ball, for one ball and per ball in
    the batch, at each of `PEER_ERRORS`: for every solver the cheapest setting of its sweep
    that meets the error, and the peer's time over ours (``time_vs_project`` < 1: the peer
    is faster). Empty when the run had no peer."""
    rolling = [r for r in rows if r["tier"] == "rolling"]
    ours = [r for r in rolling if r["solver"] == "saddle_env"]
    by_peer: dict[str, list[Row]] = defaultdict(list)
    for r in rolling:
        if r["solver"] != "saddle_env" and _peer_key(r):
            by_peer[_peer_key(r)].append(r)
    if not by_peer or not ours:
        return {}
    out: Summary = {}
    for form, cost in (("one_ball", "us_per_sim_s"), ("batch", "batch_us_per_ball_sim_s")):
        section: Summary = {}
        for name, tol in PEER_ERRORS.items():
            mine = cheapest_meeting(ours, tol, cost=cost)
            if mine is None:
                continue
            level: Summary = {"project": {**_brief(mine), "time": mine[cost]}}
            for key, prs in sorted(by_peer.items()):
                best = cheapest_meeting(prs, tol, cost=cost)
                if best is None:
                    continue
                compile_s = [r["compile_s" if form == "one_ball" else "batch_compile_s"]
                             for r in prs]
                level[key] = {"label": best["label"], "rhs": best.get("rhs", ""),
                              "setting": best["rtol"], "error_m": best["error_m"],
                              "time": best[cost], "time_vs_project": best[cost] / mine[cost],
                              "threads": best["batch_threads"],
                              "compile_s": max((c for c in compile_s if math.isfinite(c)),
                                               default=math.nan)}
            peers_here = [k for k in level if k != "project"]
            if peers_here:
                fastest = min(peers_here, key=lambda k: level[k]["time"])
                level["fastest"] = {"peer": fastest, "label": level[fastest]["label"],
                                    "time_vs_project": level[fastest]["time_vs_project"]}
            section[name] = level
        if section:
            out[form] = section
    batch_rows = [r for r in ours if math.isfinite(r["batch_n"])]
    if batch_rows:
        out["batch_n"] = batch_rows[0]["batch_n"]
        out["threads"] = batch_rows[0]["batch_threads"]
    return out


def merge_rounds(peers: Summary, timed: Summary) -> None:
    """Add the alternating rounds' times (`core.rounds`) to `peer_comparison`'s entries:
    ``time_rounds`` [µs per simulated s] and ``time_vs_project_rounds``; and the fastest
    peer by them, ``fastest_rounds``."""
    for form, levels in timed.items():
        for bound, times in levels.items():
            level = peers.get(form, {}).get(bound)
            if level is None or "project" not in times:
                continue
            for key, t in times.items():
                if key in level:
                    level[key]["time_rounds"] = t
                    if key != "project":
                        level[key]["time_vs_project_rounds"] = t / times["project"]
            timed_peers = [k for k in times if k != "project" and k in level]
            if timed_peers:
                fastest = min(timed_peers, key=lambda k: times[k])
                level["fastest_rounds"] = {
                    "peer": fastest, "label": level[fastest]["label"],
                    "time_vs_project": level[fastest]["time_vs_project_rounds"]}


def _brief(r: Row) -> Summary:
    setting = r["rtol"] if r["kind"] == "adaptive" else r["dt"]
    return {"label": r["label"], "method": r["method"], "kind": r["kind"], "setting": setting,
            "max_step": r["max_step"], "error_m": r["error_m"],
            "us_per_sim_s": r["us_per_sim_s"],
            "batch_us_per_ball_sim_s": r["batch_us_per_ball_sim_s"]}


# ----------------------------------------------------------------------------------------
# Figures
# ----------------------------------------------------------------------------------------
STYLE = {
    "dop853 rtol": ("C0", "o", "-"), "dop853 rtol (uncapped)": ("C0", "o", ":"),
    "dopri5 rtol": ("C1", "s", "-"), "dopri5 rtol (uncapped)": ("C1", "s", ":"),
    "rk4 fixed dt": ("C2", "^", "-"), "dop853 fixed dt": ("C4", "v", "-"),
    "scipy DOP853": ("C3", "D", "--"), "scipy RK45 default tol": ("C3", "*", "none"),
    "linearised (expm)": ("k", "P", "none"),
    "scipy DOP853 (python)": ("C3", "d", "-."), "scipy DOP853 (njit)": ("C3", "x", ":"),
    "numbalsoda DOP853": ("C6", "D", "-"), "numbalsoda LSODA": ("C6", "s", "--"),
    "diffrax Dopri8": ("C8", "o", "-"), "diffrax Tsit5": ("C8", "^", "--"),
    "scikit-sundae CVODE Adams": ("C9", "p", "-"),
}


def plot(rows: list[Row], out_dir: str | Path, batch: bool = False,
         default: dict[str, Any] | None = None) -> Path:
    """Work-precision diagram: one panel per contact model (numerical error against the
    model's own reference) and one for the tiers (error against the rolling reference).
    ``batch=True`` plots wall time per ball in the batch instead of one ball's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cost = "batch_us_per_ball_sim_s" if batch else "us_per_sim_s"
    # A panel per contact model the run measured (saddle-bench --tiers), and the tiers' panel.
    tiers = [t for t in MODEL_TIERS if any(r["tier"] == t for r in rows)] or list(MODEL_TIERS)
    fig, axes = plt.subplots(1, len(tiers) + 1, figsize=(4 * len(tiers) + 4, 4.2), sharey=True)
    panels = [(tier, "error_m") for tier in tiers] + [(None, "model_error_m")]
    for ax, (tier, key) in zip(axes, panels):
        groups: dict[tuple[str, str], list] = defaultdict(list)
        for r in rows:
            if tier is not None and r["tier"] != tier:
                continue
            if tier is None and r["solver"] != "saddle_env":
                continue
            if tier is None and r["label"] not in ("dop853 rtol", "linearised (expm)"):
                continue
            if not (_ok(r, key) and math.isfinite(r[cost])):
                continue
            groups[(str(r["tier"]), str(r["label"]))].append(r)
        for (t, label), grp in sorted(groups.items()):
            grp.sort(key=lambda r: r[key])
            x = [max(r[key], 1e-16) for r in grp]
            y = [r[cost] for r in grp]
            color, marker, ls = STYLE.get(label, ("0.5", ".", "-"))
            if tier is None:
                color = {"rolling": "C0", "slipping": "C1", "point": "C2", "coulomb": "C5",
                         "linear": "k"}[t]
                label = f"{t}" + ("" if t == "linear" else f" ({label})")
            ax.plot(x, y, marker=marker, ls=ls, color=color, label=label, ms=4, lw=1)
        if tier is not None and default:
            d = [r for r in rows if r["tier"] == tier and r["solver"] == "saddle_env"
                 and r["method"] == default["method"] and r["kind"] == "adaptive"
                 and math.isclose(r["rtol"], default["rtol"])
                 and math.isnan(r["max_step"]) and _ok(r) and math.isfinite(r[cost])]
            if d:
                ax.plot([max(d[0]["error_m"], 1e-16)], [d[0][cost]], "o", ms=11, mfc="none",
                        mec="k", label="default")
        ax.axvline(TARGET_ERROR, color="0.7", lw=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.grid(True, which="major", alpha=0.3)
        ax.set_title(f"{tier}: numerical error" if tier else "model tiers: error vs rolling")
        ax.set_xlabel("max centre position error over the run [m]")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=6.5, loc="best", framealpha=0.6)
    ref = rows[0] if rows else {}
    who = f"per ball, batch of {int(ref.get('batch_n', 0))}" if batch else "one ball"
    axes[0].set_ylabel(f"wall time per simulated second [µs], {who}")
    fig.suptitle(f"saddle-bench: a = {ref.get('a')} m, R = {ref.get('R')} m, "
                 f"Ω = {ref.get('omega')} s⁻¹, release ({ref.get('x0')}, {ref.get('y0')}) m "
                 f"{ref.get('start')}, {ref.get('t_end')} s", fontsize=10)
    fig.tight_layout()
    path = Path(out_dir) / ("bench_batch.png" if batch else "bench_single.png")
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path
