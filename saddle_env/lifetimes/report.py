"""The validation page's tables, rendered from the files the fit writes (so the page and
the files cannot disagree): the calibrated imperfections with their intervals, and the
leave-one-series-out thresholds and errors of each model; and the summary figures the
README and the page quote (`summary`), which
``python -m saddle_env.lifetimes.report --out docs/figures`` writes as
``lifetimes_summary.json`` from the shipped ``lifetimes_validation.json``."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

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
    """The calibrated parameters, each with its 95 % bootstrap interval; an interval or a
    value that reaches a bound the grid holds on purpose (`fit.PRIORS`) says so."""
    from .fit import PRIORS  # the bounds the code states (a record of before them has none)

    priors = record.get("priors") or PRIORS
    model, intervals = record["model"], record.get("intervals_95", {})
    lines = ["| parameter | calibrated | 95 % interval | unit |", "|---|---|---|---|"]
    for key, text, scale, unit in PARAMETERS:
        lo, hi = intervals.get(key, (None, None))
        interval = f"[{_num(lo, scale)}, {_num(hi, scale)}]" if lo is not None else "—"
        bound = _prior_bound(key, model, priors, scale)
        if bound is not None:
            interval += f" — clipped: {bound} is the prior's bound (below)"
        lines.append(f"| {text} | {_num(model.get(key), scale)} | {interval} | {unit} |")
    return "\n".join(lines)


def _prior_bound(key: str, model: dict, priors: dict, scale: float) -> str | None:
    """The upper bound of ``key`` that the fitted value sits on, in words, if a prior states
    one (the evaporation spread's is a fraction of the mean)."""
    value = model.get(key)
    if value is None:
        return None
    if key in priors and math.isclose(value, priors[key]["upper"]):
        return _num(priors[key]["upper"], scale)
    fraction = priors.get(key + "_fraction")
    mean = model.get("evaporation_mean")
    if fraction and mean and math.isclose(value, fraction["upper"] * mean):
        return f"{100 * fraction['upper']:.0f} % of the mean"
    return None


def validation_markdown(rows: list[dict], coverage: dict | None = None) -> str:
    """Per series: the lab's onset and cutoff, rigid-ball theory's threshold, and each model's
    onset, cutoff and median |ln(predicted/measured)|, predicted with the series held out;
    with ``coverage`` (``lifetimes_coverage.json``), the calibrated model's row adds the
    fraction of the lab's means inside its held-out 95 % band of the mean."""
    series = list(dict.fromkeys(r["series"] for r in rows))
    share = {b["series"]: b for b in (coverage or {}).get("series", [])}
    head = ["| series | lab onset | theory threshold | model | onset (gap) | cutoff (lab) "
            "| median \\|ln(pred/meas)\\| | longest mean | lab means in 95 % band |",
            "|---|---|---|---|---|---|---|---|---|"]
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
                f"| {r['max_predicted_s']:.1f} s | {_inside(share.get(name), r['variant'])} |")
    return "\n".join(lines)


def _inside(band: dict | None, variant: str) -> str:
    if band is None or variant != "calibrated":
        return ""
    return f"{sum(band['inside'])}/{len(band['inside'])} ({100 * band['coverage']:.0f} %)"


def size_holdout_markdown(result: dict) -> str:
    """From ``lifetimes_sizes.json`` (`sizes`): each steel ball size predicted by models
    fitted without it."""
    lines = ["| held out | series | model | onset, lab | onset, predicted (gap) "
             "| median \\|ln(pred/meas)\\| | longest mean, lab | longest mean, predicted |",
             "|---|---|---|---|---|---|---|---|"]
    for r in result["size_holdout"]:
        lab_on, on = r["lab_onset_rps"], r["onset_rps"]
        gap = f" ({100 * (on / lab_on - 1):+.1f} %)" if math.isfinite(on) else ""
        lines.append(f"| {r['held_out_size_mm']:g} mm | {r['series']} "
                     f"| {VARIANT_NAMES[r['variant']]} | {_num(lab_on)} | {_num(on)}{gap} "
                     f"| {r['median_abs_log_ratio']:.2f} | {r['lab_longest_s']:.1f} s "
                     f"| {r['longest_s']:.1f} s |")
    return "\n".join(lines)


def onset_budget_markdown(result: dict) -> str:
    """From ``lifetimes_sizes.json``: each steel series' onset above Ω_crt in linear theory
    with the release's spin, in the lab, under the calibrated model and with one of its
    effects off."""
    budget = result["onset_budget"]
    effects = list(dict.fromkeys(e for r in budget for e in r["model_onset_without_pct"]))
    lines = ["| series | linear theory, released spin | lab | calibrated model | "
             + " | ".join(f"model without {e}" for e in effects) + " |",
             "|---|---|---|---|" + "---|" * len(effects)]
    for r in budget:
        off = r["model_onset_without_pct"]
        cells = " | ".join(f"{off[e]:+.1f} %" if e in off else "—" for e in effects)
        lines.append(f"| {r['series']} | {r['spin_threshold_pct']:+.1f} % "
                     f"| {r['lab_onset_pct']:+.1f} % | {r['model_onset_pct']:+.1f} % | {cells} |")
    return "\n".join(lines)


def summary(rows: list[dict]) -> dict[str, object]:
    """The held-out check's figures over every series, as the README and the page quote them:
    the worst onset error of the calibrated model (all series, then steel and droplets
    apart), with the series it is on. A series whose curve has no onset would make this
    fail, not drop out: every series is counted."""
    calibrated = [r for r in rows if r["variant"] == "calibrated"]

    def errors(keep) -> list[tuple[float, str]]:
        out = []
        for r in calibrated:
            if keep(r):
                e = 100 * abs(r["onset_rps"] / r["lab_onset_rps"] - 1)
                if not math.isfinite(e):
                    raise ValueError(f"{r['series']}: no onset, in the lab or held out")
                out.append((e, r["series"]))
        return out

    every = errors(lambda r: True)
    steel = errors(lambda r: "steel" in r["series"])
    drops = errors(lambda r: "LN2" in r["series"])
    return {"onset_error_worst_pct": max(every)[0], "onset_error_worst_series": max(every)[1],
            "onset_error_steel_worst_pct": max(steel)[0],
            "onset_error_droplets_worst_pct": max(drops)[0],
            "onset_error_droplets_worst_series": max(drops)[1],
            "series_counted": len(every),
            "source": "docs/figures/lifetimes_validation.json, variant 'calibrated'",
            "command": "python -m saddle_env.lifetimes.report --out docs/figures"}


def main(argv: list[str] | None = None) -> int:
    """Write ``lifetimes_summary.json`` from the held-out check; exit 2 naming an error."""
    p = argparse.ArgumentParser(prog="python -m saddle_env.lifetimes.report",
                                description="The held-out check's summary figures.")
    p.add_argument("--out", type=Path, required=True, help="folder of lifetimes_validation.json")
    args = p.parse_args(argv)
    try:
        rows = json.loads((args.out / "lifetimes_validation.json").read_text())
        text = json.dumps(summary(rows), indent=1) + "\n"
        (args.out / "lifetimes_summary.json").write_text(text)
    except (ValueError, OSError, KeyError) as exc:
        print(f"{p.prog}: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
