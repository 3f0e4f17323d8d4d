"""``saddle-bench --pilot-cost``: what `simulate(..., tol=...)`'s pilot costs.

The pilot (`saddle_env.accuracy.choose`) runs candidate settings over the start of the run
before the run itself. Its cost is stated against one run at the setting it picks, on the
benchmark's rolling ball (`core.Case`), for each tolerance of docs/accuracy.md's table.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from typing import Any

from ..accuracy import choose
from ..omega import OmegaProfile
from ..simulate import simulate
from .core import Case, best_of_rounds

# The tolerances [m] of docs/accuracy.md's table of simulate(..., tol=...)'s picks.
PILOT_TOLS = (1e-3, 1e-4, 1e-6, 1e-7, 1e-9, 1e-10)


def pilot_cost(case: Case | None = None, tols: Sequence[float] = PILOT_TOLS,
               n_rounds: int = 21) -> dict[str, Any]:
    """The pilot's wall time over one run at the setting it picks, per tolerance.

    Parameters
    ----------
    case : Case or None
        The scene and run (default: the benchmark's, a 10 s run with outputs every 0.1 s).
    tols : sequence of float
        The tolerances [m] passed to `choose`.
    n_rounds : int
        Alternating rounds; each side keeps its fastest.

    Returns
    -------
    dict
        ``{"case": ..., "n_rounds": ..., "tols": {tol: {"picked", "pilot_s", "run_s",
        "ratio"}}, "ratio": [least, most]}``.
    """
    case = case or Case()
    sc, s0 = case.scene("rolling"), case.state("rolling")
    profile = OmegaProfile(case.omega)

    out: dict[str, Any] = {"case": case.columns(), "n_rounds": n_rounds}
    per_tol: dict[str, dict[str, Any]] = {}
    for tol in tols:
        pilot = partial(choose, sc, [s0], case.t_end, tol, omegas=[profile],
                        dt_out=case.dt_out)
        choice = pilot()
        run = partial(simulate, sc, s0, case.t_end, omega=case.omega, dt_out=case.dt_out,
                      **choice.kwargs())
        best = best_of_rounds({"pilot": pilot, "run": run}, n_rounds)
        per_tol[f"{tol:g}"] = {"picked": choice.describe(), "pilot_s": best["pilot"],
                               "run_s": best["run"], "ratio": best["pilot"] / best["run"]}
    ratios = [v["ratio"] for v in per_tol.values()]
    out.update(tols=per_tol, ratio=[min(ratios), max(ratios)])
    return out
