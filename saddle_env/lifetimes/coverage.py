"""How often the lab's means fall inside the held-out predictions' 95 % intervals.

``python -m saddle_env.lifetimes.coverage --out docs/figures`` reads the shipped held-out
check (``docs/figures/lifetimes_validation.json``: per series, the model fitted on the other
series and, from a run that kept them, that fit's own bootstrap fits) and, for each series,
simulates the held-out model and its bootstrap models at the fit's releases and seed, and
the other series at the held-out model, whose residuals give its model error
(`fit.model_error`). The models' `model.mean_interval` per speed, widened by that error, is
the band `predict_lifetimes` would give as ``mean_s_95`` had the series never been
measured; the coverage of a series is the fraction of the lab's means inside it. The held-out model's own
curve must be the validation's ``predicted_s`` bit for bit (the command refuses otherwise):
the band is around the prediction the page shows.

Nothing of the held-out series reaches its band: the centre, the bootstrap fits and the
model error all come from the other series (`fit.validation_row`). A validation file
without a held-out bootstrap (an older one) takes the spread of the full calibration
instead, and says so.

It writes ``lifetimes_coverage.json`` and ``lifetimes_bands.png`` (the bands against the
lab's means) into ``--out``. A minute or two on the 2-core machine (8 series × 41 curves,
and the other series at each held-out fit).
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
from . import grid as G
from .data import load_lab_series
from .fit import Fitter, choice_of, lab_terms, model_error
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


def held_out_bands(rows: list[dict], record: dict, models: int = 40,
                   progress: bool = True) -> list[dict[str, object]]:
    """Per series (the validation's "calibrated" rows): the held-out 95 % band of each mean
    (``mean_s_95``; ``model_mean_s_95`` without the model error), the lab's means and the
    fraction of them inside; ``models``: at most that many of the row's bootstrap fits."""
    everything = load_lab_series()
    releases, seed = int(record["releases_per_speed"]), int(record["seed"])
    # the other series' curves at each held-out fit, for its model error (a few dozen
    # curves: many held-out fits share points)
    fitter = Fitter(everything, G.OnDemand(everything, releases, seed), seed)
    index = {s.name: i for i, s in enumerate(everything)}
    out = []
    start = time.monotonic()
    for row in (r for r in rows if r["variant"] == "calibrated"):
        i = index[row["series"]]
        s = everything[i]
        others = [j for j in range(len(everything)) if j != i]
        error = model_error(fitter, others, choice_of(row["fitted_on_others"]))
        centre = _model(row["fitted_on_others"])
        kept = row.get("held_out_models") or []
        if kept:
            spread = [_model(m) for m in kept[:models]]
            source = f"{len(spread)} bootstrap fits on the other series"
        else:
            spread = spread_models(record, centre, models, seed)
            source = f"{len(spread)} models of the full calibration's spread"
        curves = []
        for m in [centre, *spread]:
            escapes = release_times(m, s.c_plus, s.c_minus, s.obj, s.diameter_mm, s.rps,
                                    releases, seed)
            curves.append(lifetimes_of(m, s.obj, escapes, seed))
        predicted = curves[0].mean(axis=1)
        if predicted.tolist() != row["predicted_s"]:
            raise RuntimeError(f"{s.name}: the held-out model's curve is not the validation's "
                               "predicted_s; the validation file and the code disagree")
        narrow = mean_interval(curves)
        band = mean_interval(curves, extra_var=np.full(len(s.rps), error * error))
        # What a lab's mean of so few releases adds (its own standard error in ln, as the
        # fit's objective takes it): the band a measured mean should fall in.
        wide = mean_interval(curves, extra_var=lab_terms(s)[1] + error * error)
        lab = s.mean
        inside, in_narrow, in_wide = (_inside(b, lab) for b in (band, narrow, wide))
        out.append({"series": s.name, "rps": [float(f) for f in s.rps],
                    "lab_mean_s": [float(v) for v in lab],
                    "predicted_s": [float(v) for v in predicted],
                    "spread_from": source, "model_error_ln": error,
                    "mean_s_95": _pairs(band), "inside": [bool(v) for v in inside],
                    "coverage": float(inside.mean()),
                    "model_mean_s_95": _pairs(narrow),
                    "coverage_model_mean": float(in_narrow.mean()),
                    "lab_mean_95": _pairs(wide),
                    "coverage_with_lab_error": float(in_wide.mean())})
        if progress:
            print(f"coverage: {s.name}: {int(inside.sum())}/{inside.size} lab means inside "
                  f"({time.monotonic() - start:.0f} s)", flush=True)
    return out


def _model(params: dict) -> LabModel:
    known = {f for f in LabModel.__dataclass_fields__}
    return LabModel(**{k: (math.inf if v is None else float(v)) for k, v in params.items()
                       if k in known})


def _inside(band: np.ndarray, values: np.ndarray) -> np.ndarray:
    return (band[:, 0] <= values) & (values <= band[:, 1])


def _pairs(band: np.ndarray) -> list[list[float]]:
    return [[float(lo), float(hi)] for lo, hi in band]


def summary(bands: list[dict], models: int, record: dict) -> dict[str, Any]:
    """The file ``lifetimes_coverage.json`` holds: the bands and their coverage overall."""
    total = sum(len(b["inside"]) for b in bands)

    def overall(key: str) -> float:
        return sum(b[key] * len(b["inside"]) for b in bands) / total

    inside = sum(sum(b["inside"]) for b in bands)
    return {"coverage_all": inside / total, "inside": inside, "speeds": total,
            "coverage_all_model_mean": overall("coverage_model_mean"),
            "coverage_all_with_lab_error": overall("coverage_with_lab_error"),
            "coverage_least": min(b["coverage"] for b in bands),
            "least_series": min(bands, key=lambda b: b["coverage"])["series"],
            "model_error_ln_range": [min(b["model_error_ln"] for b in bands),
                                     max(b["model_error_ln"] for b in bands)],
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
                        label="held out: 95 % interval of the mean\n"
                              "(calibration, releases, model error)")
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
    p.add_argument("--models", type=int, default=40,
                   help="models of the calibration's uncertainty per series: the first of the "
                        "held-out fit's own bootstrap fits where the file keeps them, else "
                        "drawn from the full calibration's spread (0-64)")
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
          f" ({result['least_series']}); without the model error "
          f"{100 * result['coverage_all_model_mean']:.0f} %, with the lab's own error "
          f"{100 * result['coverage_all_with_lab_error']:.0f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
