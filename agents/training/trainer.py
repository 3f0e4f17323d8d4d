"""Training an agent on a task level: the one seam every training back end sits behind (the
logic behind ``train.py``).

Settings go in (`agents.training.runs.TrainSettings`, whose ``backend`` names the back end); a run
folder comes out, with the model and its sidecar, ``config.json``, the learning curve and
the closing comparison. `train` does what every back end shares:

1. checks the back end's dependencies and the settings;
2. reads the recipe (`agents.training.recipes`: the zoo-format YAML entry for the level) and fills
   what the command line left to it (balls, budget, evaluation period);
3. opens the run folder (a resumed checkpoint's own) and saves ``config.json``;
4. hands the run to the back end, each a room of its own:

   * ``sb3``: `agents.training.backends.sb3` (Stable-Baselines3 in this process; validation and
     model selection during training);
   * ``sbx``: `agents.training.backends.sbx` (SBX's PPO, SB3's API on JAX: the SB3 back end's run
     with a faster learner; its model files are SB3's);
   * ``rllib``: `agents.training.backends.rllib` (Ray RLlib, local or on a cluster);

   A back end is a module with ``check_dependencies(progress_bar)``, a flag
   ``RESUME_NEEDS_TRUST`` and ``run(settings, hyper, run_dir, resume, trust, began)``,
   which trains and returns the model to compare, or None when interrupted (it saved a
   checkpoint that ``--resume`` continues from); optionally ``RECIPES``, its recipe file
   when ``--hyperparams`` names none (else ``agents/hyperparams/<algo>.yml``);
5. when the run finished: draws the learning curve and compares the model with
   best-const and mpc on ``compare_episodes`` fresh episodes (seeds from `COMPARE_SEED`),
   printed and saved as ``comparison.md``/``comparison.json`` (`agents.training.run_report`).

A new back end is one module with those three names, added to `BACKENDS` and to
`agents.training.runs.BACKEND_ALGOS`.
"""

from __future__ import annotations

import time
from pathlib import Path
from types import ModuleType

from ..cli_args import parse_env_kwargs
from ..evaluation.model_files import untrusted
from ..seeds import COMPARE_SEED, VALIDATION_SEED
from . import compile_ahead
from .backends import rllib as rllib_backend
from .backends import sb3 as sb3_backend
from .backends import sbx as sbx_backend
from .recipes import load_hyperparams, parse_policy_kwargs, wrapper_settings
from .run_report import compare, plot_learning_curve
from .runs import (
    ALGO_NAMES,
    BACKEND_ALGOS,
    MAIN_JOB_ENV_ID,
    TrainSettings,
    settings_for_resume,
)

BACKENDS: dict[str, ModuleType] = {"sb3": sb3_backend, "sbx": sbx_backend,
                                    "rllib": rllib_backend}
assert set(BACKENDS) == set(BACKEND_ALGOS), "agents.training.runs.BACKEND_ALGOS names the back ends"


def backend(settings: TrainSettings) -> ModuleType:
    """The back end module that trains ``settings``."""
    try:
        return BACKENDS[settings.backend]
    except KeyError:
        raise ValueError(f"--backend must be one of {sorted(BACKENDS)}, "
                         f"got {settings.backend!r}") from None


def check_dependencies(settings: TrainSettings) -> None:
    """One line naming the extra to install if ``settings``' back end cannot import what
    it needs (`agents.cli_args.MissingExtra`)."""
    backend(settings).check_dependencies(settings.progress_bar)


def recipe(settings: TrainSettings, note: bool = False) -> dict:
    """The recipe ``settings`` train with: the entry of ``--hyperparams`` or of the back
    end's own file (``RECIPES``, else agents/hyperparams/<algo>.yml) for the level or
    ``--recipe-of``'s."""
    return load_hyperparams(settings.algo, settings.recipe_of or settings.env_id,
                            settings.hyperparams or getattr(backend(settings), "RECIPES", None),
                            note=note)


def train(settings: TrainSettings, resume: str | Path | None = None, trust: bool = False
          ) -> Path:
    """Train (or resume from the checkpoint ``resume``) an agent; return the run folder.
    ``trust``: a resumed checkpoint may be unpickled (``--trust-model``)."""
    back = backend(settings)
    back.check_dependencies(settings.progress_bar)
    began = time.time()
    checked = settings.validate()
    if resume is not None and back.RESUME_NEEDS_TRUST and not trust:
        raise untrusted(resume, f"resuming restores {settings.backend}'s own checkpoint, "
                                f"which is pickled (evaluating it does not need this)")
    hyper = recipe(checked, note=True)
    run = checked.with_recipe(hyper)
    run_dir = run.open_run_folder(resume)
    ahead = compile_ahead.start(run, run_dir)   # the comparison's kernels and the curve's
    # reference lines, on the other core
    try:
        model = back.run(run, hyper, run_dir, resume, trust, began)
        if model is not None:
            plot_learning_curve(run_dir)
            if run.compare_episodes > 0:
                compile_ahead.finish(ahead)     # waits for it: the comparison needs its work
                compare(run_dir, run, model)
    finally:
        compile_ahead.finish(ahead, wait_s=0)   # stopped however the run ends
    return run_dir


__all__ = ["ALGO_NAMES", "BACKENDS", "COMPARE_SEED", "MAIN_JOB_ENV_ID", "VALIDATION_SEED",
           "TrainSettings", "backend", "check_dependencies", "compare", "load_hyperparams",
           "recipe",
           "parse_env_kwargs", "parse_policy_kwargs", "plot_learning_curve",
           "settings_for_resume", "train", "wrapper_settings"]
