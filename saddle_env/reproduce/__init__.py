"""Reproduce the seed paper's figures and numbers from this project's model.

``saddle-reproduce`` (`main`) writes, into an output folder, one PNG and its CSV data per
figure of Fan, Du, Wang & Zhou, *Confining rigid balls by mimicking quadrupole ion
trapping*, and ``summary.json`` with the key numbers, each naming the initial-velocity
convention it used. Modules:

* `cli` — the command line; `context` — output files, cache, progress, batched sweeps;
* `theory_figs` — eigen-frequency loci, Ω_crt vs R and a, the asymmetric saddle's band;
* `dynamics_figs` — trajectories and precession, support force, feasible regions,
  trapping time;
* `analogy_fig` — the ion-trap analogy: ball vs RRF ion, Paul trap vs rotating saddle;
* `damping_fig` — air drag: the orbit's growth rate vs Ω and how the stable band moves;
* `paper_eom` — the paper's approximate Eq. (EOM), for comparison only.

Importing this package does not import matplotlib (figure functions import it).
"""

from .cli import FIGURE_NAMES, main

__all__ = ["FIGURE_NAMES", "main"]
