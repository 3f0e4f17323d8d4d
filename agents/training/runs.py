"""A training run's settings, its folder and its interruption: what every training back end
(`agents.training.backends.sb3`, `agents.training.backends.sbx`, `agents.training.backends.rllib`)
takes in, behind the one seam `agents.training.trainer.train`.

`TrainSettings` is the one declaration of a run's settings, for every back end: the command
line (``train.py``) builds it from its flags, a run saves it as ``config.json``, and
``--resume`` reads it back (`settings_for_resume`). Each setting is declared here once, with
its default; a back end reads the ones it uses and `validate` refuses the ones it cannot
honour. Settings are frozen: `validate` returns a checked copy, and `with_recipe` the
`RunSettings` a back end trains with, every count the recipe decides filled in.
"""

from __future__ import annotations

import json
import signal
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, fields, replace
from functools import cached_property
from pathlib import Path
from typing import Any

from saddle_env.envs import LEVEL_IDS, EnvConfig, Level
from saddle_env.jobs.signals import SignalRecord

from ..cli_args import parse_address, resolve_env, saved_settings
from ..seeds import MAX_EVAL_EPISODES

# The main job (`python train.py`): a level where learning shows within minutes and a
# learned agent can beat mpc. Gusty, not Capture: on Capture mpc is within 0.02 s of the
# clairvoyant reference (docs/benchmark.md), and the fast recipe's agents stay 0.1-0.5 s
# below it; on Gusty they pass mpc with every seed in 3x10^6 steps (4.5 min of training on
# the faster of the machines it was timed on, 9.6 min on the slower; docs/training_profile.md).
MAIN_JOB_ENV_ID = "SaddleTrap-Gusty-v0"
# The algorithms each back end trains (the first back end's are the command line's choices).
BACKEND_ALGOS = {"sb3": ("ppo", "sac", "td3", "a2c"), "sbx": ("ppo",), "rllib": ("ppo", "sac")}
BACKENDS = tuple(BACKEND_ALGOS)
ALGO_NAMES = BACKEND_ALGOS["sb3"]
# Balls stepped together when the recipe has no n_envs: SB3's batch env, or per RLlib runner.
DEFAULT_N_ENVS = {"sb3": 8, "sbx": 8, "rllib": 16}
DEFAULT_ENV_RUNNERS = 2
DEFAULT_EVAL_EPISODES = 64   # validation episodes per evaluation, unless the recipe says
# Settings only the RLlib back end uses (flag names in errors).
RLLIB_ONLY = ("num_env_runners", "address", "num_cpus")


@dataclass(frozen=True)
class TrainSettings:
    """What a run asks for; saved as ``config.json`` in the run folder. The defaults here
    are the command line's (``train.py`` reads its flags' defaults from this class). None
    leaves a setting to the level or the recipe (`validate`, `with_recipe`)."""

    algo: str = "ppo"
    # The main job (`python train.py`) trains on a level where learning shows within minutes:
    # the untrained policy loses balls that the trained one keeps (docs/shipped-agents.md).
    env_id: str = MAIN_JOB_ENV_ID
    env_kwargs: dict[str, Any] = field(default_factory=dict)   # options over the level's
    seed: int = 0
    n_envs: int | None = None            # None: the recipe's (RLlib: balls per env runner)
    total_timesteps: int | None = None   # None: the recipe's n_timesteps
    hyperparams: str | None = None       # None: agents/hyperparams/<algo>.yml
    recipe_of: str | None = None         # the level whose entry is the recipe (None: env_id's)
    log_dir: str = "runs"
    run_name: str | None = None
    # Model selection on the validation seeds. None: the recipe's ``eval_freq`` and
    # ``eval_episodes``, else 20 evaluations per run (at least 20,000 steps apart) of
    # DEFAULT_EVAL_EPISODES episodes.
    eval_freq: int | None = None
    eval_episodes: int | None = None
    save_freq: int = 50_000
    max_episode_steps: int | None = None                       # None: the level's
    progress_bar: bool = True
    device: str = "cpu"
    # One torch thread: small MLPs gain nothing from more, and on a 2-core machine extra
    # threads fight the environment for the cores (PPO measured 2,900 steps/s with 1 thread,
    # 200 with 2, on a loaded machine).
    torch_threads: int = 1
    compare_episodes: int = 200      # the closing comparison (0: none)
    backend: str = "sb3"             # "sb3": Stable-Baselines3 in this process; "sbx": SBX's
    #                                  PPO (JAX) in this process; "rllib": Ray
    # RLlib: env runner actors (None: DEFAULT_ENV_RUNNERS; 0: sampling in the driver process,
    # where a profiler's timers can see it)
    num_env_runners: int | None = None
    address: str | None = None       # RLlib: a running cluster's head (None: a local Ray)
    num_cpus: int | None = None      # RLlib, local Ray only (None: the machine's cores)
    hyperparams_used: dict[str, Any] = field(default_factory=dict)

    NON_NEGATIVE = ("compare_episodes", "num_env_runners")
    POSITIVE = ("n_envs", "total_timesteps", "eval_freq", "eval_episodes", "save_freq",
                "max_episode_steps", "torch_threads", "num_cpus")

    def validate(self) -> TrainSettings:
        """Check every setting (ValueError naming the flag); return a copy with the level's
        episode length and RLlib's runner count filled in."""
        if self.backend not in BACKEND_ALGOS:
            raise ValueError(f"--backend must be one of {list(BACKENDS)}, got {self.backend!r}")
        algos = BACKEND_ALGOS[self.backend]
        if self.algo not in algos:
            where = "" if self.backend == "sb3" else f" with --backend {self.backend}"
            raise ValueError(f"--algo must be one of {list(algos)}{where}, got {self.algo!r}")
        if self.backend != "rllib":
            given = [f"--{k.replace('_', '-')}" for k in RLLIB_ONLY
                     if getattr(self, k) is not None]
            if given:
                verb = "needs" if len(given) == 1 else "need"
                raise ValueError(f"{' and '.join(given)} {verb} --backend rllib")
        for name in self.POSITIVE:
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int)
                                      or value < 1):
                raise ValueError(f"--{name.replace('_', '-')} must be a positive integer "
                                 f"(>= 1), got {value}")
        for name in self.NON_NEGATIVE:
            value = getattr(self, name)
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"--{name.replace('_', '-')} must be an integer >= 0, "
                                 f"got {value}")
        self._check_eval_episodes()
        if self.address is not None:
            parse_address(self.address)
        if self.recipe_of is not None and self.recipe_of not in LEVEL_IDS:
            raise ValueError(f"--recipe-of must be a level id ({', '.join(LEVEL_IDS)}), "
                             f"got {self.recipe_of!r}")
        filled: dict[str, Any] = {}
        if self.backend == "rllib" and self.num_env_runners is None:
            filled["num_env_runners"] = DEFAULT_ENV_RUNNERS
        level, _ = self.environment()
        if self.max_episode_steps is None:
            filled["max_episode_steps"] = level.max_episode_steps
        return replace(self, **filled)

    def environment(self) -> tuple[Level, EnvConfig]:
        """The level and its config with ``env_kwargs`` on top (ValueError if invalid)."""
        try:
            return resolve_env(self.env_id, self.env_kwargs)
        except TypeError as exc:
            raise ValueError(f"--env-kwargs: {exc}") from None

    def with_recipe(self, hyper: dict[str, Any]) -> RunSettings:
        """The settings a back end trains with: what the command line left to the recipe
        filled in (the balls, the budget and the model selection's evaluations) and the
        recipe recorded (``config.json`` keeps it). Call on validated settings (the episode
        length comes from `validate`)."""
        if self.max_episode_steps is None:
            raise ValueError("with_recipe needs validated settings: call validate() first")
        total = int(self.total_timesteps or float(hyper.get("n_timesteps", 1e5)))
        eval_episodes = self.eval_episodes
        if eval_episodes is None:
            eval_episodes = int(hyper.get("eval_episodes") or DEFAULT_EVAL_EPISODES)
        eval_freq = self.eval_freq
        if eval_freq is None:
            eval_freq = int(hyper.get("eval_freq") or max(20_000, total // 20))
        run = RunSettings(**{**{f.name: getattr(self, f.name) for f in fields(self)},
                             "hyperparams_used": hyper,
                             "n_envs": int(self.n_envs or hyper.get("n_envs",
                                                                    DEFAULT_N_ENVS[self.backend])),
                             "total_timesteps": total, "eval_freq": eval_freq,
                             "eval_episodes": eval_episodes,
                             "max_episode_steps": self.max_episode_steps})
        run._check_eval_episodes()
        return run

    def _check_eval_episodes(self) -> None:
        if self.eval_episodes is not None and self.eval_episodes > MAX_EVAL_EPISODES:
            raise ValueError(f"--eval-episodes must be at most {MAX_EVAL_EPISODES:,} (the "
                             f"validation and re-selection seed ranges must not meet), "
                             f"got {self.eval_episodes}")

    def open_run_folder(self, resume: str | Path | None = None) -> Path:
        """The run folder (a resumed checkpoint's own, else ``log_dir/run_name``, named
        after the algorithm, back end, seed and start time when unnamed), created, with
        the settings saved in it as ``config.json``."""
        if resume is not None:
            run_dir = run_folder_of(resume)
        else:
            tag = "" if self.backend == "sb3" else f"_{self.backend}"
            name = self.run_name or (f"{self.algo}{tag}_seed{self.seed}_"
                                     f"{time.strftime('%Y%m%d-%H%M%S')}")
            run_dir = Path(self.log_dir) / name
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "config.json").write_text(json.dumps(asdict(self), indent=2, default=list))
        return run_dir


@dataclass(frozen=True, kw_only=True)
class RunSettings(TrainSettings):
    """`TrainSettings` resolved for training (`TrainSettings.with_recipe`): validated, and
    every count the command line may leave to the level or the recipe filled in. What the
    back ends, the model selection and the run's report take."""

    n_envs: int
    total_timesteps: int
    eval_freq: int
    eval_episodes: int
    max_episode_steps: int

    def environment(self) -> tuple[Level, EnvConfig]:
        """The level and its config with ``env_kwargs`` on top, checked on the first call
        only: the run's back end, model selection and report share it."""
        return self._environment

    @cached_property
    def _environment(self) -> tuple[Level, EnvConfig]:
        return super().environment()

    @property
    def env_runners(self) -> int:
        """RLlib's env runner actors (`validate` fills ``num_env_runners`` for RLlib)."""
        return DEFAULT_ENV_RUNNERS if self.num_env_runners is None else self.num_env_runners


def run_folder_of(checkpoint: str | Path) -> Path:
    """The run folder a checkpoint belongs to: the nearest of its parent and grandparent
    with a ``config.json`` (``<run>/checkpoints/<ckpt>`` or RLlib's ``<run>/final``)."""
    ckpt = Path(checkpoint).resolve()
    for folder in (ckpt.parent.parent, ckpt.parent):
        if (folder / "config.json").is_file():
            return folder
    raise ValueError(f"--resume: need a checkpoint inside a run folder with config.json, "
                     f"got {str(checkpoint)!r}")


def settings_for_resume(checkpoint: str | Path, total_timesteps: int | None = None,
                        progress_bar: bool = True, **overrides: Any) -> TrainSettings:
    """The settings of the run a checkpoint belongs to (its ``config.json``), with a new
    budget, and RLlib's runner count or address, if given."""
    from ..evaluation.rllib_policy import is_checkpoint

    ckpt = Path(checkpoint)
    if not (ckpt.is_file() or is_checkpoint(ckpt)):
        raise ValueError(f"--resume: need an existing checkpoint (a .zip, or an RLlib "
                         f"checkpoint directory) inside a run folder, got {str(checkpoint)!r}")
    config = run_folder_of(ckpt) / "config.json"
    return saved_settings(TrainSettings, config, total_timesteps, progress_bar,
                          **overrides).validate()


def settings_of_run(run_dir: str | Path) -> RunSettings:
    """The settings a run trained with, from its folder's ``config.json``, which recorded
    every count the recipe gave and the recipe itself (``hyperparams_used``; the recipe
    file is not re-read: it may have changed since)."""
    config = Path(run_dir) / "config.json"
    recipe = json.loads(config.read_text()).get("hyperparams_used", {})
    if not isinstance(recipe, dict) or not all(isinstance(k, str) for k in recipe):
        raise ValueError(f"{config}: hyperparams_used must be a mapping of names to values, "
                         f"got {type(recipe).__name__}")
    return saved_settings(TrainSettings, config).validate().with_recipe(recipe)


def recorded_settings(checkpoint: str | Path) -> RunSettings:
    """The settings a checkpoint's run trained with (`settings_of_run` of its folder)."""
    return settings_of_run(run_folder_of(checkpoint))


class Stop(BaseException):
    """Raised in the main thread by SIGTERM, so that a run checkpoints and exits as on
    Ctrl-C. A BaseException, as KeyboardInterrupt is: it can arrive inside any code, and an
    ``except Exception`` there (the model loader's, which turns torch's many errors on a
    corrupt file into one message) must not take it for that code's own failure."""


class _Held:
    """A stop that came while files were being written (`stops_held`)."""

    depth = 0
    pending: BaseException | None = None


@contextmanager
def stops_held() -> Iterator[None]:
    """Within the block, a stop (SIGTERM's `Stop` or Ctrl-C's KeyboardInterrupt, under
    `sigterm_stops`) waits and is raised when the block ends: a save it interrupted would be
    left half-written, and the exception would not even come out as itself (torch's zip
    writer, closing early, raises a RuntimeError in its place), so the run would crash
    instead of checkpointing."""
    _Held.depth += 1
    try:
        yield
    finally:
        _Held.depth -= 1
    if _Held.depth == 0 and _Held.pending is not None:
        stop, _Held.pending = _Held.pending, None
        raise stop


class StopRequest(SignalRecord):
    """Set by SIGTERM (or Ctrl-C under `sigterm_stops`), remembering the stop it raised; its
    `raise_if_lost`, called once per training step, raises a stop that a ``__del__`` swallowed
    (`saddle_env.jobs.signals`). A stop held by `stops_held` is not lost: it comes when the
    save ends."""

    def lost(self) -> bool:
        """Whether the stop is lost: never while a save holds it."""
        return super().lost() and not _Held.depth


@contextmanager
def sigterm_stops(deferred: bool = False) -> Iterator[StopRequest]:
    """Within the block, SIGTERM raises `Stop` and Ctrl-C KeyboardInterrupt (as ever), each
    held until the end of a `stops_held` block in progress; the previous handlers come back
    after.

    With ``deferred=True`` SIGTERM only sets the yielded event and the loop checks it
    between iterations (Ctrl-C is left alone): an exception raised from a signal handler
    while the main thread waits inside Ray's compiled ``CoreWorker.wait`` comes out as a
    ``SystemError`` ("returned a result with an exception set"), not as `Stop`."""
    requested = StopRequest()

    def on_signal(signum, frame):
        requested.set()
        if deferred:
            return
        stop = Stop() if signum == signal.SIGTERM else KeyboardInterrupt()
        requested.stop = requested.stop or stop
        if _Held.depth:
            _Held.pending = _Held.pending or stop
            return
        raise stop

    previous = {signal.SIGTERM: signal.signal(signal.SIGTERM, on_signal)}
    if not deferred and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, on_signal)
    try:
        yield requested
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        _Held.pending = None


__all__ = ["ALGO_NAMES", "BACKENDS", "BACKEND_ALGOS", "DEFAULT_ENV_RUNNERS", "DEFAULT_N_ENVS",
           "MAIN_JOB_ENV_ID", "RunSettings", "Stop", "StopRequest", "TrainSettings",
           "recorded_settings", "run_folder_of", "settings_for_resume", "sigterm_stops",
           "stops_held"]
