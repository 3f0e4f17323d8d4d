"""How often the lab's means fall inside the held-out predictions' 95 % intervals.

``python -m saddle_env.lifetimes.coverage --out docs/figures`` reads the shipped held-out
check (``docs/figures/lifetimes_validation.json``: per series, the model fitted on the other
series) and the shipped calibration, and for each series simulates the held-out model and
the models that span the calibration's uncertainty (`model.spread_models`), at the fit's
releases and seed. Their `model.mean_interval` per speed is the band `predict_lifetimes`
would give as ``mean_s_95``; the coverage of a series is the fraction of the lab's means
inside it. The held-out model's own curve must be the validation's ``predicted_s`` bit for
bit (the command refuses otherwise): the band is around the prediction the page shows.

It writes ``lifetimes_coverage.json`` and ``lifetimes_bands.png`` (the bands against the
lab's means) into ``--out``. About a minute on one core (8 series × 9 curves).

The calibration's spread is the full fit's (its bootstrap intervals), the centre the fit
without the series: a bootstrap of every held-out fit would need the grid's hours again.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from datetime import date
from pathlib import Path
from typing import Any

import numpy as np

from ..jobs.files import write_text_atomically
from .data import load_lab_series
from .fit import MODEL_ERROR, lab_terms
from .model import (
    LabModel,
    lifetimes_of,
    load_calibration,
    mean_interval,
    release_times,
    spread_models,
)

ROOT = Path(__file__).resolve().parents[2]
VALIDATION = ROOT / "docs" / "figures" / "lifetimes_validation.json"
COMMAND = "python -m saddle_env.lifetimes.coverage --out docs/figures"


def held_out_bands(rows: list[dict], record: dict, models: int = 8,
                   progress: bool = True) -> list[dict[str, object]]:
    """Per series (the validation's "calibrated" rows): the held-out 95 % band of each mean,
    the lab's means and the fraction of them inside."""
    series = {s.name: s for s in load_lab_series()}
    releases, seed = int(record["releases_per_speed"]), int(record["seed"])
    known = {f for f in LabModel.__dataclass_fields__}
    out = []
    start = time.monotonic()
    for row in (r for r in rows if r["variant"] == "calibrated"):
        s = series[row["series"]]
        centre = LabModel(**{k: (math.inf if v is None else float(v))
                             for k, v in row["fitted_on_others"].items() if k in known})
        curves = []
        for m in [centre, *spread_models(record, centre, models, seed)]:
            escapes = release_times(m, s.c_plus, s.c_minus, s.obj, s.diameter_mm, s.rps,
                                    releases, seed)
            curves.append(lifetimes_of(m, s.obj, escapes, seed))
        predicted = curves[0].mean(axis=1)
        if predicted.tolist() != row["predicted_s"]:
            raise RuntimeError(f"{s.name}: the held-out model's curve is not the validation's "
                               "predicted_s; the validation file and the code disagree")
        band = mean_interval(curves)
        lab = s.mean
        inside = (band[:, 0] <= lab) & (lab <= band[:, 1])
        # What a lab's mean of so few releases adds (its own standard error in ln, as the
        # fit's objective takes it), and that with the model's own error of the objective:
        # the band a measured mean should fall in, not the model's mean's.
        lab_var = lab_terms(s)[1]
        wide = mean_interval(curves, extra_var=lab_var)
        wider = mean_interval(curves, extra_var=lab_var + MODEL_ERROR ** 2)
        in_wide = (wide[:, 0] <= lab) & (lab <= wide[:, 1])
        in_wider = (wider[:, 0] <= lab) & (lab <= wider[:, 1])
        out.append({"series": s.name, "rps": [float(f) for f in s.rps],
                    "lab_mean_s": [float(v) for v in lab],
                    "predicted_s": [float(v) for v in predicted],
                    "mean_s_95": [[float(lo), float(hi)] for lo, hi in band],
                    "inside": [bool(v) for v in inside],
                    "coverage": float(inside.mean()),
                    "lab_mean_95": [[float(lo), float(hi)] for lo, hi in wide],
                    "coverage_with_lab_error": float(in_wide.mean()),
                    "coverage_with_lab_and_model_error": float(in_wider.mean())})
        if progress:
            print(f"coverage: {s.name}: {int(inside.sum())}/{inside.size} lab means inside "
                  f"({time.monotonic() - start:.0f} s)", flush=True)
    return out


def summary(bands: list[dict], models: int, record: dict) -> dict[str, Any]:
    """The file ``lifetimes_coverage.json`` holds: the bands and their coverage overall."""
    inside = sum(sum(b["inside"]) for b in bands)
    total = sum(len(b["inside"]) for b in bands)
    def overall(key: str) -> float:
        return sum(b[key] * len(b["inside"]) for b in bands) / total

    return {"coverage_all": inside / total, "inside": inside, "speeds": total,
            "coverage_all_with_lab_error": overall("coverage_with_lab_error"),
            "coverage_all_with_lab_and_model_error": overall("coverage_with_lab_and_model_error"),
            "coverage_least": min(b["coverage"] for b in bands),
            "least_series": min(bands, key=lambda b: b["coverage"])["series"],
            "calibration_models": models, "releases_per_speed": record["releases_per_speed"],
            "seed": record["seed"], "command": COMMAND, "date": date.today().isoformat(),
            "series": bands}


def plot_bands(bands: list[dict], path: Path) -> None:
    """Each series: the lab's means and the held-out 95 % band of the predicted mean."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 4, figsize=(15, 6.5), sharey=False)
    for ax, b in zip(axes.ravel(), bands):
        band = np.array(b["mean_s_95"])
        ax.fill_between(b["rps"], band[:, 0], band[:, 1], color="tab:blue", alpha=0.3,
                        label="held out: 95 % of the mean")
        ax.plot(b["rps"], b["predicted_s"], color="tab:blue", lw=1)
        ok = np.array(b["inside"])
        rps, lab = np.array(b["rps"]), np.array(b["lab_mean_s"])
        ax.plot(rps[ok], lab[ok], "ko", ms=4, label="lab mean, inside")
        ax.plot(rps[~ok], lab[~ok], "rx", ms=6, label="lab mean, outside")
        ax.set_yscale("log")
        ax.set_title(f"{b['series']}\n{100 * b['coverage']:.0f} % inside", fontsize=9)
        ax.set_xlabel("rev/s")
    axes[0, 0].set_ylabel("mean lifetime [s]")
    axes[1, 0].set_ylabel("mean lifetime [s]")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (2 with a named message on an error)."""
    p = argparse.ArgumentParser(prog="python -m saddle_env.lifetimes.coverage",
                                description="Held-out 95 % bands of the mean lifetimes and "
                                            "the fraction of the lab's means inside them.")
    p.add_argument("--out", type=Path, required=True, help="folder for the JSON and figure")
    p.add_argument("--validation", type=Path, default=VALIDATION,
                   help="the held-out check (default the shipped one)")
    p.add_argument("--models", type=int, default=8,
                   help="models of the calibration's uncertainty per series (0-64)")
    p.add_argument("--no-figure", action="store_true", help="write the JSON only")
    args = p.parse_args(argv)
    if not 0 <= args.models <= 64:
        p.error(f"--models must lie in [0, 64], got {args.models}")
    try:
        rows = json.loads(args.validation.read_text())
        record = load_calibration()[1]
        bands = held_out_bands(rows, record, args.models)
        result = summary(bands, args.models, record)
        args.out.mkdir(parents=True, exist_ok=True)
        write_text_atomically(args.out / "lifetimes_coverage.json",
                              json.dumps(result, indent=1) + "\n")
        if not args.no_figure:
            plot_bands(bands, args.out / "lifetimes_bands.png")
    except (ValueError, RuntimeError, OSError, KeyError) as exc:
        print(f"{p.prog}: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # nothing half-written: the files are written at the end
        print(f"{p.prog}: interrupted, nothing written", file=sys.stderr)
        return 130
    print(f"held out: {result['inside']}/{result['speeds']} lab means inside the 95 % bands "
          f"({100 * result['coverage_all']:.0f} %); least {100 * result['coverage_least']:.0f} %"
          f" ({result['least_series']}); with the lab's own error "
          f"{100 * result['coverage_all_with_lab_error']:.0f} %, and the model's "
          f"{100 * result['coverage_all_with_lab_and_model_error']:.0f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
