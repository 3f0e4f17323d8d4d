"""The figure store: every measured number that the README or a user page states, in one file
(``docs/figures/figures.yml``), and the renderer that writes it into the text.

A figure has a name, a value, its unit, the date and machine of the measurement and the
command that remakes it. Its value is either typed into the store (``value:``), read from a
results file a tool wrote (``source:`` a JSON file of the repository, ``key:`` a dotted path
into it, list positions included, ``combine: sum`` to add up a mapping's values,
``over:`` a second key whose value divides the first, ``scale:`` a factor such as 1/3600,
or ``derive:`` one of ``DERIVED``'s computations over the file's content, which may also be
a CSV file's rows, with ``args:`` a mapping of its keyword arguments if it takes any, e.g.
``derive: bench-cell`` with ``args: {column: us_per_sim_s, row: {tier: rolling, method:
dop853, rtol: 1e-10}}`` for one cell of saddle-bench's CSV), or one of the
leaderboard's results, which are figures without a store entry:
``lb.LEVEL.POLICY`` is the mean trapping time [95 % interval] of a policy on a level
(``LEVEL`` is the id without ``SaddleTrap-`` and ``-v0``, ``default`` for ``SaddleTrap-v0``;
``POLICY`` a key of ``docs/leaderboard.json``, ``shipped`` for the level's shipped agent),
``lb.LEVEL.POLICY.kept`` the percentage of balls kept 10 s (``.detach``: detached),
``lb.LEVEL.best-const.omega`` the best constant speed in rad/s,
``lb.LEVEL.shipped.margin`` the shipped agent's mean less best-const's upper bound [s],
``lb.date`` the leaderboard's date. A figure whose value is a mapping (a table's rows, say)
is also named cell by cell, ``NAME.ROW.COLUMN``, with the table's unit, date and command.

A text names a figure with a marker pair around its rendered copy, which reads right on
GitHub as well as on the site::

    about <!-- fig main-job-seconds -->364<!-- /fig --> s

``<!-- fig NAME SPEC -->`` renders with a format spec of Python's ``format`` (``.0f``,
``,.0f``), which may round the stored value; ``mean`` before the spec keeps an interval's
mean alone; ``<!-- fig NAME date -->`` renders the date of the figure's measurement. The
docs build (docs/hooks.py) replaces each pair by the current value, and

    python -m agents.figures --write     # rewrite README.md and docs/ in place
    python -m agents.figures --check     # exit 1 naming each stale file

keep the files' own copies current; tests/test_figures.py fails on a stale copy or an
unknown name.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import math
import re
import sys
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

import yaml

from .paths import REPO_ROOT

STORE = REPO_ROOT / "docs" / "figures" / "figures.yml"
LEADERBOARD = REPO_ROOT / "docs" / "leaderboard.json"
LEADERBOARD_COMMAND = "python -m agents.benchmark.leaderboard --resume --no-progress"
REQUIRED = ("unit", "date", "machine", "command")
_INTERVAL = {"mean", "low", "high"}   # a figure with its 95 % interval

# <!-- fig NAME [mean] [SPEC] -->old copy<!-- /fig -->
MARKER = re.compile(r"<!-- fig (?P<name>[\w.@-]+)(?P<opts>(?: [^ >]+)*) -->(?P<copy>.*?)<!-- /fig -->",
                    re.DOTALL)


class FigureError(ValueError):
    """A figure that the store does not have, or a store entry that lacks a field."""


def _short_level(env_id: str) -> str:
    if env_id == "SaddleTrap-v0":
        return "default"
    return env_id.removeprefix("SaddleTrap-").removesuffix("-v0")


def _leaderboard_figures(board: dict[str, Any]) -> dict[str, dict[str, Any]]:
    figures: dict[str, dict[str, Any]] = {}
    common = {"date": str(board["date"]), "machine": board["machine"],
              "command": LEADERBOARD_COMMAND}
    figures["lb.date"] = {"value": str(board["date"]), "unit": "", **common}
    for env_id, level in board["levels"].items():
        short = _short_level(env_id)
        for policy in level["policies"]:
            key = "shipped" if policy["kind"] not in ("baseline",) else policy["key"]
            name = f"lb.{short}.{key}"
            time = policy["trapping_time"]
            figures[name] = {"value": {k: time[k] for k in ("mean", "low", "high")},
                             "unit": "s", "format": ".2f", **common}
            for share in ("kept", "detach"):
                if share in policy:
                    figures[f"{name}.{share}"] = {
                        "value": {k: 100 * policy[share][k] for k in ("mean", "low", "high")},
                        "unit": "%", "format": ".0f", **common}
            if "omega" in policy:
                figures[name + ".omega"] = {"value": policy["omega"], "unit": "rad/s",
                                            "format": "g", **common}
        shipped, best = figures.get(f"lb.{short}.shipped"), figures.get(f"lb.{short}.best-const")
        if shipped and best:   # how far the shipped agent's mean lies above best-const's interval
            figures[f"lb.{short}.shipped.margin"] = {
                "value": shipped["value"]["mean"] - best["value"]["high"], "unit": "s",
                "format": ".1f", **common}
    return figures


def _steel(row: dict[str, Any]) -> bool:
    return "steel" in row["series"]


def _variant(rows: list[dict[str, Any]], variant: str) -> list[dict[str, Any]]:
    return [r for r in rows if r["variant"] == variant]


def _peak_ratio(row: dict[str, Any]) -> float:
    """A series' longest predicted mean over the lab's longest."""
    return row["max_predicted_s"] / max(row["lab_mean_s"])


def _least_and_most(values: Any) -> list[float]:
    values = list(values)
    return [min(values), max(values)]


def best_const_voltage(board: dict[str, Any], env_id: str = "SaddleTrap-Lab-v0") -> float:
    """The voltage that holds the saddle at a voltage-mode level's best constant speed on the
    leaderboard: that speed over the level's steady motor gain [rad/s per V]."""
    from saddle_env.envs import level_config  # only this figure needs a level's motor

    omega = next(p["omega"] for p in board["levels"][env_id]["policies"]
                 if p["key"] == "best-const")
    return float(omega) / level_config(env_id).motor_gain


def _precession_excess(summary: dict[str, Any], release_m: float) -> float:
    convergence = summary["precession_convergence"]
    angle = convergence["angle_deg"][convergence["release_m"].index(release_m)]
    return float(angle - summary["precession_deg_linear_limit"]["value"])


def _paper_area_excess(summary: dict[str, Any], omega: int) -> float:
    areas = summary[f"feasible_area_paper_eom_{omega}"]
    return float(100 * (areas["paper_eom_cm2"] / areas["exact_cm2"] - 1))


def _bench_row(rows: list[dict[str, Any]], tier: str, method: str, rtol: float = math.nan,
               dt: float = math.nan, solver: str = "saddle_env",
               max_step: float = math.nan) -> dict[str, Any]:
    """saddle-bench's row (bench.csv, bench_results.csv) of ``solver`` on ``tier`` at an
    adaptive ``rtol`` or a fixed step ``dt``; the simulator's rows under the default step cap
    unless ``max_step`` names another (100: uncapped). A field left out must be blank (nan)
    in the row, so that one setting never matches two rows."""
    def same(a: Any, b: Any) -> bool:
        b = float(b)   # the store's YAML reads 1e-10 (no dot) as a string
        return math.isnan(b) if math.isnan(a) else math.isclose(a, b)

    found = [r for r in rows if r["solver"] == solver and r["tier"] == tier
             and r["method"] == method and same(r["rtol"], rtol) and same(r["dt"], dt)
             and same(r["max_step"], max_step)]
    if len(found) != 1:
        raise FigureError(f"saddle-bench's rows hold {len(found)} rows of {solver} {method} on "
                          f"{tier} at rtol {rtol}, dt {dt}, max_step {max_step}, not one")
    return found[0]


def bench_cell(rows: list[dict[str, Any]], column: str, row: dict[str, Any],
               over: dict[str, Any] | None = None) -> float:
    """``derive: bench-cell``: the ``column`` of saddle-bench's row picked by the fields
    ``row`` (`_bench_row`'s arguments), or its ratio to the same column of the row ``over``;
    the store's ``args:`` name them, so that each figure shows which row it quotes."""
    value = float(_bench_row(rows, **row)[column])
    return value / float(_bench_row(rows, **over)[column]) if over is not None else value


# the rolling ball's rows of "Why the defaults" (docs/accuracy.md): dop853 under the default
# step cap at the simulator's default rtol 1e-10, and the looser settings it is weighed against
_ROLLING_DEFAULT = {"tier": "rolling", "method": "dop853", "rtol": 1e-10}
_LOOSER_RTOLS = (1e-7, 1e-6, 1e-5, 1e-4)


def _rolling_dop853(rows: list[dict[str, Any]], column: str, rtol: float) -> float:
    return bench_cell(rows, column, {**_ROLLING_DEFAULT, "rtol": rtol})


def coulomb_tier(rows: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """docs/accuracy.md's table of the coulomb tier against the rolling ball: error [m] and
    wall time [µs per simulated s] per setting, from saddle-bench's bench.csv."""
    table: dict[str, dict[str, float]] = {}
    for name, method, rtol, dt in (("rtol-1e-8", "dop853", 1e-8, math.nan),
                                   ("rtol-1e-10", "dop853", 1e-10, math.nan),
                                   ("rtol-1e-11", "dop853", 1e-11, math.nan),
                                   ("rk4-1ms", "rk4", math.nan, 1e-3),
                                   ("rk4-500us", "rk4", math.nan, 5e-4),
                                   ("rk4-100us", "rk4", math.nan, 1e-4)):
        cells = table[name] = {}
        for tier in ("coulomb", "rolling"):
            row = _bench_row(rows, tier, method, rtol, dt)
            cells[f"{tier}_error"], cells[f"{tier}_us"] = row["error_m"], row["us_per_sim_s"]
    return table


def coulomb_phases(rows: list[dict[str, Any]]) -> dict[str, float]:
    """The coulomb tier's changes of phase at the default rtol 1e-10, the least and most at
    rtol 1e-9 to 1e-13, and the share of the run it slips at 1e-10 [%]."""
    at = {e: _bench_row(rows, "coulomb", "dop853", 10.0 ** -e) for e in range(9, 14)}
    changes = [at[e]["phase_changes"] for e in at]
    return {"changes": at[10]["phase_changes"], "changes_least": min(changes),
            "changes_most": max(changes), "slipping_percent": 100 * at[10]["slipping_share"]}


def coulomb_cost_ratio(rows: list[dict[str, Any]]) -> list[float]:
    """The coulomb ball's wall time per simulated second over the rolling ball's at the same
    rtol, least and most over 1e-8, 1e-10 and 1e-11."""
    return _least_and_most(bench_cell(rows, "us_per_sim_s", {**_ROLLING_DEFAULT, "rtol": r,
                                                             "tier": "coulomb"},
                                      over={**_ROLLING_DEFAULT, "rtol": r})
                           for r in (1e-8, 1e-10, 1e-11))


def _damping_rates(summary: dict[str, Any]) -> list[tuple[str, float, float]]:
    """(drag key, simulated rate, theory's rate) of every point of the damping figure."""
    return [(k1, sim, theory) for panel in ("symmetric", "asymmetric")
            for k1, runs in summary["damping"][panel].items()
            for sim, theory in zip(runs["growth_simulated"], runs["growth_theory"])]


# Figures computed from a results file's rows (``derive:`` in the store): the real-saddle
# check's held-out predictions (docs/figures/lifetimes_validation.json, one row per series
# and model variant), and the Lab level's best constant as a voltage (docs/leaderboard.json).
DERIVED: dict[str, Any] = {
    "lab-best-const-voltage": best_const_voltage,
    # the calibrated model's worst onset on a steel series, |predicted / lab - 1| in %
    "lifetimes-onset-error-steel": lambda rows: max(
        100 * abs(r["onset_rps"] / r["lab_onset_rps"] - 1)
        for r in _variant(rows, "calibrated") if _steel(r)),
    # how far the rigid-ball theory's threshold lies below the lab's onset, worst steel series, %
    "lifetimes-theory-onset-early": lambda rows: max(
        100 * (1 - r["theory_threshold_rps"] / r["lab_onset_rps"])
        for r in _variant(rows, "calibrated") if _steel(r)),
    # the worst series' median lifetime error as a factor, exp(median |ln(pred / lab)|)
    "lifetimes-median-factor": lambda rows: math.exp(max(
        r["median_abs_log_ratio"] for r in _variant(rows, "calibrated"))),
    "lifetimes-rigid-median-factor": lambda rows: math.exp(max(
        r["median_abs_log_ratio"] for r in _variant(rows, "rigid ball"))),
    # the same worst error as a log ratio, and the rigid ball's best series and its count > 2
    "lifetimes-median-log": lambda rows: max(
        r["median_abs_log_ratio"] for r in _variant(rows, "calibrated")),
    "lifetimes-rigid-median-factor-least": lambda rows: math.exp(min(
        r["median_abs_log_ratio"] for r in _variant(rows, "rigid ball"))),
    "lifetimes-rigid-series-above-2": lambda rows: sum(
        math.exp(r["median_abs_log_ratio"]) > 2 for r in _variant(rows, "rigid ball")),
    # the steel ball's window on P4: how much earlier than the lab's the model closes it
    # [rev/s], and its longest mean over the lab's longest
    "lifetimes-p4-cutoff-early": lambda rows: next(
        r["lab_cutoff_rps"] - r["cutoff_rps"] for r in _variant(rows, "calibrated")
        if "P4 steel" in r["series"]),
    "lifetimes-p4-peak-ratio": lambda rows: next(
        _peak_ratio(r) for r in _variant(rows, "calibrated") if "P4 steel" in r["series"]),
    # the 6.3 mm ball's plateau, predicted over measured (the longest means)
    "lifetimes-small-ball-plateau-ratio": lambda rows: next(
        _peak_ratio(r) for r in _variant(rows, "calibrated") if "6.3 mm" in r["series"]),
    # just below the lab's onset: the largest predicted / measured mean over every series
    "lifetimes-below-onset-worst-ratio": lambda rows: max(
        p / m for r in _variant(rows, "calibrated")
        for f, p, m in zip(r["rps"], r["predicted_s"], r["lab_mean_s"])
        if f < r["lab_onset_rps"]),
    # droplets on P4, which the lab never kept: the held-out model's longest mean [s], and
    # the same without the tilt and the speed error ("+ dissipation")
    "lifetimes-p4-droplets-longest": lambda rows: next(
        r["max_predicted_s"] for r in _variant(rows, "calibrated") if "P4 LN2" in r["series"]),
    "lifetimes-p4-droplets-longest-level": lambda rows: next(
        r["max_predicted_s"] for r in _variant(rows, "+ dissipation")
        if "P4 LN2" in r["series"]),
    # saddle-reproduce's summary.json (docs/figures/reproduce_summary.json): the precession's
    # excess over linear theory's limit at the 1 mm and the 0.125 mm release, degrees
    "reproduce-precession-excess-1mm": lambda summary: _precession_excess(summary, 0.001),
    "reproduce-precession-excess-0.125mm": lambda summary: _precession_excess(summary, 0.000125),
    # how much larger the paper's equation makes the feasible area, Omega = 35 and 45 rad/s, %
    "reproduce-feasible-paper-excess-35": lambda summary: _paper_area_excess(summary, 35),
    "reproduce-feasible-paper-excess-45": lambda summary: _paper_area_excess(summary, 45),
    # how far the nonlinear rolling threshold of the paper's three balls lies below theory, %
    "reproduce-omega-crt-below-theory": lambda summary: _least_and_most(
        100 * (1 - summary["omega_crt"][ball]["nonlinear_rolling"]
               / summary["omega_crt"][ball]["theory"])
        for ball in ("R=2.23cm", "R=2.65cm", "R=3.30cm")),
    # the damping figure's simulated growth rates against theory: the largest relative
    # difference of a damped rate in %, and the largest drag-free rate (theory: 0) in 1/s
    "reproduce-damping-rel-diff": lambda summary: 100 * max(
        abs(sim / theory - 1) for k1, sim, theory in _damping_rates(summary) if k1 != "k1=0"),
    "reproduce-damping-drag-free": lambda summary: max(
        abs(sim) for k1, sim, _ in _damping_rates(summary) if k1 == "k1=0"),
    # how early the calibrated model's onset comes for the 19 mm steel balls, least and most, %
    "lifetimes-onset-early-19mm": lambda rows: _least_and_most(
        100 * (1 - r["onset_rps"] / r["lab_onset_rps"])
        for r in _variant(rows, "calibrated") if _steel(r) and "19 mm" in r["series"]),
    # saddle-bench --tiers rolling,coulomb (docs/figures/coulomb_tier/bench.csv): the coulomb
    # tier's table, phases, cost over the rolling ball's, and steps at the default rtol 1e-10
    "coulomb-tier": coulomb_tier,
    "coulomb-phases": coulomb_phases,
    "coulomb-cost-ratio": coulomb_cost_ratio,
    "coulomb-steps": lambda rows: {
        "switching": _bench_row(rows, "coulomb", "dop853", 1e-10)["steps"],
        "rolling": _bench_row(rows, "rolling", "dop853", 1e-10)["steps"]},
    "coulomb-steps-ratio": lambda rows: bench_cell(
        rows, "steps", {**_ROLLING_DEFAULT, "tier": "coulomb"}, over=_ROLLING_DEFAULT),
    # saddle-bench --peers all (docs/figures/bench_results.csv): one column of one row, or a
    # ratio of two rows, as the store's args: name them
    "bench-cell": bench_cell,
    # the default's cost at rtol 1e-11 over the default's, less one, %
    "bench-dop853-rtol11-extra-percent": lambda rows: 100 * (
        _rolling_dop853(rows, "us_per_sim_s", 1e-11)
        / _rolling_dop853(rows, "us_per_sim_s", 1e-10) - 1),
    # the default's wall time over the cheapest looser setting's (rtol 1e-7 ... 1e-4)
    "bench-looser-max-saving": lambda rows: _rolling_dop853(rows, "us_per_sim_s", 1e-10) / min(
        _rolling_dop853(rows, "us_per_sim_s", r) for r in _LOOSER_RTOLS),
    # the looser settings' errors over the default's, least and most
    "bench-looser-error-ratio": lambda rows: _least_and_most(
        _rolling_dop853(rows, "error_m", r) / _rolling_dop853(rows, "error_m", 1e-10)
        for r in _LOOSER_RTOLS),
    # the linearised tier (matrix exponential, one row): the default's one-ball time over its
    # own, and its time per ball in the batch
    "bench-linear-tier-cost": lambda rows: {
        "default_over_linear": _rolling_dop853(rows, "us_per_sim_s", 1e-10) / bench_cell(
            rows, "us_per_sim_s", {"tier": "linear", "method": "expm"}),
        "batch_us_per_ball": bench_cell(rows, "batch_us_per_ball_sim_s",
                                        {"tier": "linear", "method": "expm"})},
}


def _number(text: str) -> Any:
    try:
        return float(text) if text != "" else math.nan
    except ValueError:
        return text


def read_source(path: Path) -> Any:
    """A results file's content for ``derive:``: a JSON file's value, or a CSV file's rows
    as mappings (a cell that reads as a number as a float, a blank one as nan)."""
    if path.suffix == ".csv":
        with open(path, newline="", encoding="utf-8") as fh:
            return [{k: _number(v) for k, v in row.items()} for row in csv.DictReader(fh)]
    return json.loads(path.read_text())


_MISSING = object()


def _walk(value: Any, parts: list[str]) -> Any:
    """The value at the path ``parts``, or _MISSING; a mapping key may hold dots itself, so
    each way of joining the next parts into one key is tried."""
    if not parts:
        return value
    if isinstance(value, list) and parts[0].isdigit() and int(parts[0]) < len(value):
        return _walk(value[int(parts[0])], parts[1:])
    if isinstance(value, dict):
        for n in range(1, len(parts) + 1):
            part = ".".join(parts[:n])
            if part in value:
                found = _walk(value[part], parts[n:])
                if found is not _MISSING:
                    return found
    return _MISSING


def _lookup(path: Path, key: str) -> Any:
    """The value at ``key``, a dotted path of mapping keys and list positions (``paths.0.x``);
    a mapping key that holds a dot itself (``omega_crt.R=2.23cm.theory``) is found too."""
    value = _walk(json.loads(path.read_text()), key.split("."))
    if value is _MISSING:
        raise FigureError(f"{path.relative_to(REPO_ROOT)} has no key {key!r}")
    return value


def _is_date(text: object) -> bool:
    try:
        datetime.date.fromisoformat(str(text))
    except ValueError:
        return False
    return bool(re.fullmatch(r"\d{4}-\d{2}-\d{2}", str(text)))


def load_store(store: Path = STORE, leaderboard: Path = LEADERBOARD) -> dict[str, dict[str, Any]]:
    """Every figure by name, each with ``value``, ``unit``, ``date``, ``machine`` and
    ``command``. Raises FigureError on an entry that lacks one of them."""
    entries = yaml.safe_load(store.read_text()) or {}
    figures = _leaderboard_figures(json.loads(leaderboard.read_text()))
    for name, entry in entries.items():
        if not isinstance(entry, dict):
            raise FigureError(f"{store.name}: {name!r} is not a mapping")
        missing = [k for k in REQUIRED if k not in entry]
        if "value" not in entry and "source" not in entry:
            missing.insert(0, "value (or source and key)")
        if missing:
            raise FigureError(f"{store.name}: figure {name!r} lacks {', '.join(missing)}")
        entry = dict(entry)
        if isinstance(entry["date"], datetime.date):
            entry["date"] = entry["date"].isoformat()
        if not _is_date(entry["date"]):
            raise FigureError(f"{store.name}: figure {name!r}: date {entry['date']!r} is not "
                              "a date (YYYY-MM-DD: the day of the measurement, not a range)")
        if "derive" in entry:
            if entry["derive"] not in DERIVED:
                raise FigureError(f"{store.name}: {name!r}: no derivation {entry['derive']!r}")
            rows = read_source(REPO_ROOT / entry["source"])
            entry["value"] = DERIVED[entry["derive"]](rows, **entry.get("args", {}))
        elif "source" in entry:
            entry["value"] = _lookup(REPO_ROOT / entry["source"], entry["key"])
            if entry.get("combine") == "sum":
                entry["value"] = sum(entry["value"].values())
            if "over" in entry:   # a ratio of two values of the same file
                entry["value"] /= _lookup(REPO_ROOT / entry["source"], entry["over"])
            if "scale" in entry:  # an interval's ends too; a table (other cells) as it is
                value = entry["value"]
                entry["value"] = ({k: v * entry["scale"] for k, v in value.items()}
                                  if isinstance(value, dict) and set(value) == _INTERVAL
                                  else value * entry["scale"])
        if name in figures:
            raise FigureError(f"{store.name}: {name!r} is a leaderboard figure already")
        figures[name] = entry
    return figures


@lru_cache(maxsize=1)
def _cached(mtimes: tuple[float, float]) -> dict[str, dict[str, Any]]:
    return load_store()


def figures() -> dict[str, dict[str, Any]]:
    """The store, read again when its file or the leaderboard's changes."""
    return _cached((STORE.stat().st_mtime, LEADERBOARD.stat().st_mtime))


def format_figure(figure: dict[str, Any], opts: Sequence[str] = ()) -> str:
    """A figure as text: a number with the spec (the marker's or the figure's ``format``; a
    signed spec such as ``+.2f`` writes a negative value with the minus sign), an
    interval as ``mean [low, high]``, a mean with its standard error as ``mean ± se``, a
    pair as ``low–high``, a longer list (one value per seed, say) as ``a, b, c``, anything
    else as it is."""
    opts = list(opts)
    mean_only = "mean" in opts
    opts = [o for o in opts if o != "mean"]
    if len(opts) > 1:
        raise FigureError(f"figure options {opts!r}: at most one format spec (and 'mean')")
    spec = opts[0] if opts else figure.get("format", "")
    value = figure["value"]

    def number(x: Any) -> str:
        if not isinstance(x, (int, float)):
            return str(x)
        # 1.9e-8, as the texts write it, not Python's 1.9e-08
        text = re.sub(r"e([+-])0(\d)$", r"e\1\2", format(x, spec))
        # a signed spec (+.2f) writes a difference: with the minus sign, as the texts do
        return "\u2212" + text[1:] if spec.startswith("+") and text.startswith("-") else text

    if isinstance(value, dict) and "se" in value:   # a mean and its standard error
        return number(value["mean"]) if mean_only else \
            f"{number(value['mean'])} ± {format(value['se'], spec.lstrip('+'))}"
    if isinstance(value, dict):
        if mean_only:
            return number(value["mean"])
        return f"{number(value['mean'])} [{number(value['low'])}, {number(value['high'])}]"
    if isinstance(value, list) and len(value) == 2:
        return f"{number(value[0])}–{number(value[1])}"
    if isinstance(value, list):
        return ", ".join(number(x) for x in value)
    return number(value)


def render_figure(name: str, opts: str = "") -> str:
    """The figure ``name`` of the store, formatted with ``opts`` (`format_figure`); ``date``
    alone gives the date of its measurement, so that a text dates a figure without retyping it.

    Raises
    ------
    FigureError
        If the store has no figure ``name``.
    """
    figure = find_figure(name)
    if opts.split() == ["date"]:
        return str(figure["date"])
    return format_figure(figure, opts.split())


def find_figure(name: str) -> dict[str, Any]:
    """The store's figure ``name``, or one cell of a figure whose value is a mapping (a
    table's rows): ``TABLE.ROW.COLUMN`` is the value at that path, with the table's unit,
    date, machine and command.

    Raises
    ------
    FigureError
        If the store has neither the figure nor a table with that cell.
    """
    store = figures()
    if name in store:
        return store[name]
    parts = name.split(".")
    for cut in range(len(parts) - 1, 0, -1):   # the longest stored prefix is the table
        table = store.get(".".join(parts[:cut]))
        if table is None or not isinstance(table["value"], dict):
            continue
        value = _walk(table["value"], parts[cut:])   # a cell's key may hold a dot too
        if value is _MISSING:
            raise FigureError(f"figure {'.'.join(parts[:cut])!r} has no cell "
                              f"{'.'.join(parts[cut:])!r}")
        return {**table, "value": value}
    raise FigureError(f"unknown figure {name!r}: add it to {STORE.relative_to(REPO_ROOT)}")


def render(text: str, keep_markers: bool = True) -> str:
    """``text`` with every marker pair's copy replaced by its figure's current value; the
    markers stay (a file's own copy) or go (the site's page)."""

    def one(m: re.Match) -> str:
        value = render_figure(m.group("name"), m.group("opts"))
        if not keep_markers:
            return value
        return f"<!-- fig {m.group('name')}{m.group('opts')} -->{value}<!-- /fig -->"

    return MARKER.sub(one, text)


def rendered_files() -> list[Path]:
    """The files that may hold figures: the README, CONTRIBUTING (a page of the site too) and
    every page of docs/."""
    return [REPO_ROOT / "README.md", REPO_ROOT / "CONTRIBUTING.md",
            *sorted((REPO_ROOT / "docs").rglob("*.md"))]


def stale_files() -> list[Path]:
    """The rendered files whose figures differ from the store's."""
    return [p for p in rendered_files() if render(p.read_text()) != p.read_text()]


def _is_table(value: Any) -> bool:
    return isinstance(value, dict) and not {"mean", "se"} & set(value)


def _show_value(name: str, figure: dict[str, Any]) -> list[str]:
    """``--show``'s lines for a figure's value: a table's cells one per line, by the names
    a text gives them (``NAME.ROW.COLUMN``)."""
    if not _is_table(figure["value"]):
        return [f"{name} = {format_figure(figure)} {figure['unit']}".rstrip()]
    lines = [f"{name}: a table [{figure['unit']}]"] if "." not in name else []
    for key, cell in figure["value"].items():
        lines += _show_value(f"{name}.{key}", {**figure, "value": cell, "unit": ""})
    return lines


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m agents.figures``."""
    p = argparse.ArgumentParser(
        prog="python -m agents.figures",
        description="Render the figure store (docs/figures/figures.yml and the leaderboard's "
                    "results) into the README and the docs' pages, or check their copies.")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--write", action="store_true",
                      help="rewrite each stale copy in README.md and docs/ in place")
    what.add_argument("--check", action="store_true",
                      help="exit 1 naming each file whose copy of a figure is stale")
    what.add_argument("--show", metavar="NAME",
                      help="print one figure with its unit, date, machine and command")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        if args.show:
            figure = find_figure(args.show)
            print("\n".join(_show_value(args.show, figure)))
            for key in ("date", "machine", "command", "what"):
                if key in figure:
                    print(f"  {key}: {figure[key]}")
            return 0
        stale = stale_files()
        for path in stale:
            if args.write:
                path.write_text(render(path.read_text()))
            print(f"{'rewrote' if args.write else 'stale'}: {path.relative_to(REPO_ROOT)}")
    except FigureError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 1 if stale and args.check else 0


if __name__ == "__main__":
    raise SystemExit(main())
