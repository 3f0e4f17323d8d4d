"""The work-precision benchmark's tables for the docs pages, read from a run's results.

`rolling_markdown` turns the rows of ``bench.csv`` into the accuracy page's table of
chosen settings for the rolling ball, and `targets_markdown` turns ``summary.json`` into
its table of targets. The docs build renders both from ``docs/figures/bench_results.csv``
and ``docs/figures/bench_summary.json`` (``docs/hooks.py``), so a new run of
``saddle-bench`` copied there changes the page with no number typed by hand.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

from .report import Row, Summary

# The page's rows: what a reader is shown, and how to find its run in bench.csv (every
# condition must match; numbers compare as numbers). A row whose selector matches several
# runs shows their range. Errors marked "reference" are measured against this very run.
ROLLING_ROWS: tuple[tuple[str, dict[str, object], str], ...] = (
    ("**default: `dop853`, rtol 1e-10**",
     {"solver": "saddle_env", "label": "dop853 rtol", "rtol": 1e-10}, "error"),
    ("`dop853` rtol 1e-8 (the environment's default)",
     {"solver": "saddle_env", "label": "dop853 rtol", "rtol": 1e-8}, "error"),
    ("`dop853` rtol 1e-7 … 1e-4 (the step cap binds)",
     {"solver": "saddle_env", "label": "dop853 rtol", "rtol": (1e-7, 1e-4)}, "error"),
    ("`dop853` rtol 1e-12 (accurate; the reference)",
     {"solver": "saddle_env", "label": "dop853 rtol", "rtol": 1e-12}, "reference"),
    ("`dopri5` rtol 1e-4 (cheapest of all)",
     {"solver": "saddle_env", "label": "dopri5 rtol", "rtol": 1e-4}, "error"),
    ("`rk4` dt = 1 ms", {"solver": "saddle_env", "label": "rk4 fixed dt", "dt": 1e-3}, "error"),
    ("`dop853` fixed dt = 20 ms",
     {"solver": "saddle_env", "label": "dop853 fixed dt", "dt": 0.02}, "error"),
    ("scipy `solve_ivp` DOP853, rtol 1e-10, numpy peer",
     {"solver": "scipy", "label": "scipy DOP853", "rtol": 1e-10}, "error"),
    ("scipy `solve_ivp` RK45 at its defaults",
     {"solver": "scipy", "label": "scipy RK45 default tol"}, "error"),
    ("linearised model (matrix exponential)",
     {"tier": "linear", "label": "linearised (expm)"}, "model error"),
)


def _number(value: object) -> float:
    """A column's value as a number (`report.read_rows` gives NaN for an empty cell)."""
    return value if isinstance(value, float) else math.nan


def _matches(row: Row, condition: Mapping[str, object]) -> bool:
    for key, wanted in condition.items():
        if isinstance(wanted, tuple):  # a closed range of numbers
            value = _number(row.get(key))
            if not min(wanted) * (1 - 1e-9) <= value <= max(wanted) * (1 + 1e-9):
                return False
        elif isinstance(wanted, float):
            if not math.isclose(_number(row.get(key)), wanted, rel_tol=1e-9):
                return False
        elif row.get(key) != wanted:
            return False
    return True


def select(rows: Iterable[Row], condition: Mapping[str, object]) -> list[Row]:
    """The runs matching every condition; the rolling tier unless ``tier`` is given."""
    condition = {"tier": "rolling", **condition}
    found = [r for r in rows if _matches(r, condition)]
    if not found:
        raise LookupError(f"no run in the benchmark's results matches {dict(condition)}")
    return found


def _sci(x: float) -> str:
    """2.2e-10, not Python's 2.2e-10 with a zero-padded exponent."""
    mantissa, exponent = f"{x:.1e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def _thousands(x: float) -> str:
    return f"{x:,.0f}".replace(",", "\u202f")  # a narrow no-break space, as the page writes


def _span(values: list[float], fmt) -> str:
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return "—"
    low, high = fmt(min(finite)), fmt(max(finite))
    return low if low == high else f"{low} … {high}"


def rolling_markdown(rows: list[Row]) -> str:
    """The accuracy page's table: error over the run and cost of the chosen settings."""
    lines = ["| setting | error over 10 s | µs per simulated s, one ball "
             "| per ball, batch of 1024 |", "|---|---|---|---|"]
    for text, condition, error_kind in ROLLING_ROWS:
        runs = select(rows, condition)
        if error_kind == "reference":
            error = "—"
        elif error_kind == "model error":
            error = _span([_number(r["model_error_m"]) for r in runs], _sci) + " m (model error)"
        else:
            error = _span([_number(r["error_m"]) for r in runs], _sci) + " m"
        cost = _span([_number(r["us_per_sim_s"]) for r in runs],
                     lambda v: _thousands(v) if v >= 1 else f"{v:.2g}")
        batch = _span([_number(r.get("batch_us_per_ball_sim_s")) for r in runs],
                      lambda v: _thousands(v) if v >= 1 else f"{v:.2g}")
        lines.append(f"| {text} | {error} | {cost} | {batch} |")
    return "\n".join(lines)


def _power(x: float) -> str:
    """2.39×10⁶."""
    exponent = math.floor(math.log10(abs(x)))
    digits = str(exponent).translate(str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹"))
    return f"{x / 10 ** exponent:.2f}×10{digits}"


def _met(flag: object) -> str:
    return "met" if flag else "**not met**"


def targets_markdown(summary: Summary) -> str:
    """The accuracy page's table of the benchmark's targets, from ``summary.json``."""
    speed, batch, jacobi = (summary["target_speedup"], summary["target_batch"],
                            summary["target_jacobi"])
    ours, peer = speed["ours"], speed["scipy_dop853"]
    return "\n".join([
        "| target | measured | |", "|---|---|---|",
        f"| one rolling ball at ≤ 1e-9 m: ≥ 100× less time than scipy DOP853 at the same "
        f"error | {ours['label']} {_thousands(ours['us_per_sim_s'])} µs/s vs "
        f"{_thousands(peer['us_per_sim_s'])} µs/s: "
        f"**{_thousands(speed['speedup_cheapest_rows'])}×** "
        f"({_thousands(speed['speedup_interpolated'])}× interpolated to exactly 1e-9 m) "
        f"| {_met(speed['met'])} |",
        f"| batch of {int(batch['batch_n'])} rolling balls, rk4 dt = 1 ms: ≥ 2×10⁶ "
        f"ball-steps/s | **{_power(batch['ball_steps_per_s'])}** ball-steps/s on "
        f"{int(batch['threads'])} threads (one ball alone: "
        f"{_power(batch['single_ball_steps_per_s'])}) | {_met(batch['met'])} |",
        f"| Jacobi drift over {jacobi['periods']:.0e} saddle periods at rtol "
        f"{jacobi['rtol']:.0e} | **{_sci(jacobi['jacobi_drift_relative'])}** relative "
        f"| {_met(jacobi['met'])} |",
    ]).replace("1e+04", "10⁴")
