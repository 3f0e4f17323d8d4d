"""The validation page's tables, rendered from the files the fit writes (so the page and
the files cannot disagree): the calibrated imperfections with their intervals, and the
leave-one-series-out thresholds and errors of each model."""

from __future__ import annotations

import math

VARIANT_NAMES = {"rigid ball": "rigid ball, level", "+ tilt, speed error": "+ tilt, speed error",
                 "+ dissipation": "+ dissipation", "calibrated": "calibrated model"}
PARAMETERS = (
    ("tilt", "tilt of the saddle's axis", 1e3, "mrad"),
    ("launch_spread", "launcher: spread of the release point (each axis)", 1e3, "mm"),
    ("launch_speed_spread", "launcher: spread of the release velocity (each axis)", 1e3, "mm/s"),
    ("speed_spread", "drive: spread of the true speed about the stated one", 1e2, "%"),
    ("rolling_resistance", "steel: rolling-resistance coefficient c_rr", 1e3, "× 10⁻³"),
    ("rolling_drag", "steel: rolling drag, 19 mm ball (∝ 1/diameter²)", 1.0, "1/s"),
    ("film_drag", "droplet: vapour-film drag", 1.0, "1/s"),
    ("evaporation_mean", "droplet: mean life before it evaporates", 1.0, "s"),
    ("evaporation_spread", "droplet: spread of that life", 1.0, "s"),
)


def _num(value: float | None, scale: float = 1.0) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "—"
    return f"{value * scale:.3g}"


def calibration_markdown(record: dict) -> str:
    """The calibrated parameters, each with its 95 % bootstrap interval."""
    model, intervals = record["model"], record.get("intervals_95", {})
    lines = ["| parameter | calibrated | 95 % interval | unit |", "|---|---|---|---|"]
    for key, text, scale, unit in PARAMETERS:
        lo, hi = intervals.get(key, (None, None))
        interval = f"[{_num(lo, scale)}, {_num(hi, scale)}]" if lo is not None else "—"
        lines.append(f"| {text} | {_num(model.get(key), scale)} | {interval} | {unit} |")
    return "\n".join(lines)


def validation_markdown(rows: list[dict]) -> str:
    """Per series: the lab's onset and cutoff, rigid-ball theory's threshold, and each model's
    onset, cutoff and median |ln(predicted/measured)|, predicted with the series held out."""
    series = list(dict.fromkeys(r["series"] for r in rows))
    head = ["| series | lab onset | theory threshold | model | onset (gap) | cutoff (lab) "
            "| median \\|ln(pred/meas)\\| | longest mean |",
            "|---|---|---|---|---|---|---|---|"]
    lines = list(head)
    for name in series:
        mine = [r for r in rows if r["series"] == name]
        for k, r in enumerate(mine):
            lab_on, th = r["lab_onset_rps"], r["theory_threshold_rps"]
            on = r["onset_rps"]
            gap = f" ({100 * (on / lab_on - 1):+.1f} %)" if math.isfinite(on) else ""
            cut = f"{_num(r['cutoff_rps'])} ({_num(r['lab_cutoff_rps'])})"
            first = k == 0
            lines.append(
                f"| {name if first else ''} | {_num(lab_on) if first else ''} "
                f"| {_num(th) if first else ''} | {VARIANT_NAMES[r['variant']]} "
                f"| {_num(on)}{gap} | {cut} | {r['median_abs_log_ratio']:.2f} "
                f"| {r['max_predicted_s']:.1f} s |")
    return "\n".join(lines)
