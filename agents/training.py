"""Training SB3 agents on the task levels (the logic behind ``train.py``).

The environment is stepped through the batch adapter (`saddle_env.envs.sb3`), so all
``n_envs`` balls advance in one compiled call. Hyperparameters come from YAML files keyed by
environment id (rl-baselines3-zoo format, ``agents/hyperparams/<algo>.yml``); a level with no
entry of its own uses the ``SaddleTrap-v0`` entry (a note says so).

Zoo keys honoured besides the algorithm's own arguments: ``n_envs``, ``n_timesteps``,
``policy``, ``noise_type``/``noise_std`` (off-policy action noise), ``normalize`` (``true`` or
``"dict(norm_obs=True, norm_reward=False)"``: VecNormalize, its statistics saved next to
every model as ``<model>.vecnormalize.json``), ``frame_stack`` (VecFrameStack with that many
frames), ``warm_start`` (`agents.warm_start`), ``imitation`` (its settings for
``warm_start: mpc``, `agents.imitation`), ``train_episode_steps`` (shorter *training*
episodes; evaluation keeps the level's) and ``reward_shaping`` (training rewards only,
`agents.shaping`). ``env_wrapper`` and ``callback`` are
rejected with an error (no wrapper or callback classes are importable by name here).
Evaluation (`agents.policies.load_policy`) applies the same normalisation and stacking from
the sidecar.

Every run writes to its own folder: ``config.json`` (everything needed to rebuild the
environment and resume), TensorBoard logs, ``progress.csv``, ``evaluations.npz``,
``best_model.zip`` (SB3's EvalCallback: the *first* evaluation that reached the highest mean
return), ``selected_model.zip`` (see below), ``checkpoints/`` and ``final_model.zip``, each
model with a ``.json`` sidecar that records the level (``env_id``), the options overriding
it (``env_kwargs``), the episode length and the wrappers, and ``learning_curve.png``.
Ctrl-C or SIGTERM saves a checkpoint (and the replay buffer of off-policy algorithms);
``--resume CHECKPOINT.zip`` continues from it. Everything a run writes is read back as data
(JSON, tensors, npz: `agents.model_files`); a checkpoint that needs unpickling (SB3's own
files, older runs' pickles) is resumed only with ``--trust-model``.

**Model selection.** Every ``eval_freq`` steps (default: a twentieth of the budget), and
once more on the final model, the policy is evaluated on ``eval_episodes`` validation
episodes (seeds from `VALIDATION_SEED`, never used for training or for the leaderboard's
test set). ``selected_model.zip`` is the *latest*
snapshot whose mean validation return is at least the best mean seen so far: ties go to the
later snapshot, so a run whose curve reaches its plateau early ships a model from the end of
the plateau, not its first point (which ``best_model.zip`` keeps, as SB3 does).

**What learning bought.** A finished run ends by evaluating the selected model beside
``best-const`` and ``mpc`` on ``compare_episodes`` fresh episodes (seeds from
`COMPARE_SEED`), printed and saved as ``comparison.md``/``comparison.json``.
"""

from __future__ import annotations

import json
import signal
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from saddle_env.envs import ENV_ID, EnvConfig, Level

from .cli_args import (  # noqa: F401
    MissingExtra,
    install_hint,
    level_overrides,
    missing,
    parse_env_kwargs,
    resolve_env,
    saved_settings,
)
from .literal_kwargs import parse_kwargs_string
from .seeds import COMPARE_SEED, VALIDATION_SEED

# The main job (`python train.py`): a level where learning shows within minutes.
MAIN_JOB_ENV_ID = "SaddleTrap-Capture-v0"
HYPERPARAMS_DIR = Path(__file__).parent / "hyperparams"
ALGO_NAMES = ("ppo", "sac", "td3", "a2c")
# Keys of the zoo format that are not constructor arguments of the algorithm.
ZOO_ONLY_KEYS = {"n_envs", "n_timesteps", "policy", "noise_type", "noise_std", "normalize",
                 "env_wrapper", "frame_stack", "callback", "warm_start", "imitation",
                 "train_episode_steps", "reward_shaping"}
# Zoo keys this trainer cannot honour: an error, never silently dropped.
REJECTED_KEYS = {"env_wrapper": "environment wrappers by class name are not supported; wrap "
                                "in code (agents.training.make_vec_env) instead",
                 "callback": "callbacks by class name are not supported"}
# Validation episodes (model selection during training) start here: apart from the training
# seeds (0-99), the best-constant search (12,345 on) and the leaderboard's test set.
# What training imports beyond the core install (all in the "train" extra).
TRAIN_MODULES = ("stable_baselines3", "torch", "yaml", "matplotlib")
PROGRESS_MODULES = ("tqdm", "rich")


def algo_class(name: str):
    from stable_baselines3 import A2C, PPO, SAC, TD3

    classes = {"ppo": PPO, "sac": SAC, "td3": TD3, "a2c": A2C}
    if name not in classes:
        raise ValueError(f"algo must be one of {sorted(classes)}, got {name!r}")
    return classes[name]


@dataclass
class TrainSettings:
    """What a run needs; saved as ``config.json`` in the run folder. The defaults here are
    the command line's (``train.py`` reads them from this class)."""

    algo: str = "ppo"
    # The main job (`python train.py`) trains on a level where learning shows within minutes:
    # the untrained policy loses balls that the trained one keeps (docs/agents.md).
    env_id: str = MAIN_JOB_ENV_ID
    env_kwargs: dict[str, Any] = field(default_factory=dict)   # options over the level's
    seed: int = 0
    n_envs: int | None = None
    total_timesteps: int | None = None
    hyperparams: str | None = None
    log_dir: str = "runs"
    run_name: str | None = None
    eval_freq: int | None = None     # None: 20 evaluations per run (at least 20,000 steps apart)
    eval_episodes: int = 64
    save_freq: int = 50_000
    max_episode_steps: int | None = None                       # None: the level's
    progress_bar: bool = True
    device: str = "cpu"
    # One torch thread: small MLPs gain nothing from more, and on a 2-core machine extra
    # threads fight the environment for the cores (PPO measured 2,900 steps/s with 1 thread,
    # 200 with 2, on a loaded machine).
    torch_threads: int = 1
    compare_episodes: int = 200      # the closing comparison (0: none)
    hyperparams_used: dict[str, Any] = field(default_factory=dict)

    NON_NEGATIVE = ("compare_episodes",)
    POSITIVE = ("n_envs", "total_timesteps", "eval_freq", "eval_episodes", "save_freq",
                "max_episode_steps", "torch_threads")

    def validate(self) -> TrainSettings:
        """Check every setting (ValueError naming the flag); fill in the level's episode
        length. Returns self."""
        if self.algo not in ALGO_NAMES:
            raise ValueError(f"--algo must be one of {list(ALGO_NAMES)}, got {self.algo!r}")
        for name in self.POSITIVE:
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int)
                                      or value < 1):
                raise ValueError(f"--{name.replace('_', '-')} must be a positive integer, "
                                 f"got {value}")
        for name in self.NON_NEGATIVE:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"--{name.replace('_', '-')} must be an integer >= 0, "
                                 f"got {value}")
        level, _ = self.environment()
        if self.max_episode_steps is None:
            self.max_episode_steps = level.max_episode_steps
        return self

    def environment(self) -> tuple[Level, EnvConfig]:
        """The level and its config with ``env_kwargs`` on top (ValueError if invalid)."""
        try:
            return resolve_env(self.env_id, self.env_kwargs)
        except TypeError as exc:
            raise ValueError(f"--env-kwargs: {exc}") from None


def settings_for_resume(checkpoint: str | Path, total_timesteps: int | None = None,
                        progress_bar: bool = True) -> TrainSettings:
    """The settings of the run a checkpoint belongs to (its ``config.json``), with a new
    budget if given."""
    ckpt = Path(checkpoint)
    config = ckpt.resolve().parent.parent / "config.json"
    if not ckpt.is_file() or not config.is_file():
        raise ValueError(f"--resume: need an existing checkpoint inside a run folder with "
                         f"config.json, got {str(checkpoint)!r}")
    return saved_settings(TrainSettings, config, total_timesteps, progress_bar).validate()


def check_dependencies(progress_bar: bool) -> None:
    """One line naming the extra to install if training cannot import what it needs."""
    lacking = missing(TRAIN_MODULES + (PROGRESS_MODULES if progress_bar else ()))
    if lacking:
        raise MissingExtra(f"training needs {', '.join(lacking)}, not installed: "
                           f"{install_hint('train')}")


# ---------------------------------------------------------------------------------------
# hyperparameters
# ---------------------------------------------------------------------------------------
def load_hyperparams(algo: str, env_id: str = ENV_ID, path: str | Path | None = None,
                     note: bool = False) -> dict[str, Any]:
    """The entry for ``env_id`` in the algorithm's YAML file (zoo format); a level without
    an entry uses the ``SaddleTrap-v0`` one (printing a note if ``note``)."""
    import yaml

    file = Path(path) if path else HYPERPARAMS_DIR / f"{algo}.yml"
    if not file.is_file():
        raise ValueError(f"hyperparams file not found: {file}")
    data = yaml.safe_load(file.read_text()) or {}
    if env_id not in data and ENV_ID in data and env_id != ENV_ID:
        if note:
            print(f"train.py: {file.name} has no entry for {env_id}; using its {ENV_ID} entry",
                  file=sys.stderr)
        env_id = ENV_ID
    if env_id not in data:
        raise ValueError(f"{file} has no entry for {env_id!r} (has: {sorted(data)})")
    hyper = dict(data[env_id])
    for key, why in REJECTED_KEYS.items():
        if hyper.get(key) is not None:
            raise ValueError(f"{file}: {key}: {why}")
    if hyper.get("imitation") is not None and hyper.get("warm_start") != "mpc":
        raise ValueError(f"{file}: imitation: only used with warm_start: mpc")
    return hyper


def parse_policy_kwargs(value: Any) -> dict[str, Any]:
    """Policy kwargs from YAML: a mapping, or the zoo's string form ``"dict(net_arch=[64, 64])"``,
    read as data by `agents.literal_kwargs` (literals and allowed class names; nothing is
    evaluated or called)."""
    if value is None:
        return {}
    if isinstance(value, dict):
        return value
    if not isinstance(value, str):
        raise ValueError(f"policy_kwargs must be a mapping or a string, got {value!r}")
    return parse_kwargs_string(value, "policy_kwargs")


# ---------------------------------------------------------------------------------------
# environments
# ---------------------------------------------------------------------------------------
def make_vec_env(n_envs: int, seed: int, env_kwargs: dict[str, Any], max_episode_steps: int,
                 env_id: str = ENV_ID):
    """The batch environment for SB3 (level ``env_id`` with ``env_kwargs`` on top), with
    episode statistics (VecMonitor)."""
    from stable_baselines3.common.vec_env import VecMonitor

    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    _, config = resolve_env(env_id, env_kwargs)
    env = SaddleTrapSB3VecEnv(num_envs=n_envs, max_episode_steps=max_episode_steps,
                              **config.as_dict())
    env.seed(seed)
    return VecMonitor(env)


def wrapper_settings(hyper: dict[str, Any]) -> tuple[dict[str, Any] | None, int]:
    """(VecNormalize keywords or None, frames to stack) from the zoo keys ``normalize`` and
    ``frame_stack``; ValueError for a value the zoo would not accept either."""
    norm = hyper.get("normalize")
    if norm in (None, False):
        norm_kw = None
    elif norm is True:
        norm_kw = {}
    elif isinstance(norm, (str, dict)):
        norm_kw = parse_policy_kwargs(norm) if isinstance(norm, str) else dict(norm)
        allowed = {"norm_obs", "norm_reward", "clip_obs", "clip_reward", "gamma", "epsilon"}
        bad = set(norm_kw) - allowed
        if bad:
            raise ValueError(f"normalize: unknown VecNormalize option(s) {sorted(bad)}; "
                             f"allowed: {sorted(allowed)}")
    else:
        raise ValueError(f"normalize must be true/false or a dict of VecNormalize options, "
                         f"got {norm!r}")
    k = hyper.get("frame_stack") or 1
    if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= 64:
        raise ValueError(f"frame_stack must be an integer in [1, 64], got {k!r}")
    return norm_kw, k


def wrap_env(env, norm_kw: dict[str, Any] | None, frame_stack: int, training: bool = True):
    """VecNormalize, then VecFrameStack, as the zoo orders them (frames are stacked after
    normalisation). An evaluation env normalises with the training statistics (synced by
    EvalCallback) and leaves rewards alone."""
    from stable_baselines3.common.vec_env import VecFrameStack, VecNormalize

    if norm_kw is not None:
        kw = dict(norm_kw)
        if not training:
            kw.update(training=False, norm_reward=False)
        env = VecNormalize(env, **kw)
    if frame_stack > 1:
        env = VecFrameStack(env, frame_stack)
    return env


def train_episode_steps(hyper: dict[str, Any], steps: int) -> int:
    """Length of the *training* episodes: the recipe's ``train_episode_steps`` if set (at
    most ``steps``), else ``steps``. Model selection, the comparison and every evaluation
    keep the full episode (``steps``); a training episode cut short is a time-limit
    truncation, which PPO bootstraps from the value of its last state. On Capture, where
    balls are lost in the first seconds, this spends the samples where the decisions are."""
    k = hyper.get("train_episode_steps")
    if k is None:
        return steps
    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise ValueError(f"train_episode_steps must be a positive integer, got {k!r}")
    return min(k, steps)


def _action_noise(hyper: dict[str, Any]):
    kind = hyper.get("noise_type")
    if kind is None:
        return None
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

    std = float(hyper.get("noise_std", 0.1))
    cls = {"normal": NormalActionNoise, "ornstein-uhlenbeck": OrnsteinUhlenbeckActionNoise}.get(kind)
    if cls is None:
        raise ValueError(f"noise_type must be 'normal' or 'ornstein-uhlenbeck', got {kind!r}")
    return cls(mean=np.zeros(1), sigma=std * np.ones(1))


# ---------------------------------------------------------------------------------------
# training
# ---------------------------------------------------------------------------------------
class _Stop(Exception):
    """Raised in the main thread by SIGTERM so the run can checkpoint and exit."""


def save_model(model, path: Path, settings: TrainSettings, extra: dict[str, Any] | None = None
               ) -> Path:
    """Save ``model`` at ``path`` with its sidecar and, if observations are normalised, the
    statistics next to it as JSON (what evaluation needs to act as in training)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path)
    save_model_extras(model, path, settings, extra)
    return path


def save_model_extras(model, path: Path, settings: TrainSettings,
                      extra: dict[str, Any] | None = None) -> None:
    """The sidecar and normalisation statistics (JSON) of a model file, written when it is
    saved (also for SB3's own best_model.zip)."""
    from .model_files import save_normalizer
    from .policies import vecnormalize_path

    norm = model.get_vec_normalize_env()
    if norm is not None:
        save_normalizer(norm, vecnormalize_path(path))
    write_sidecar(path, settings, extra)


def checkpoint_statistics(checkpoint: str | Path) -> tuple[Path | None, Path | None]:
    """(JSON, pickle) normalisation statistics saved with a checkpoint, each None if absent:
    ours (``<stem>.vecnormalize.json``), or the pickles older runs and SB3's
    CheckpointCallback wrote (``<stem>.vecnormalize.pkl``,
    ``checkpoint_vecnormalize_<steps>_steps.pkl``)."""
    from .policies import vecnormalize_path

    ckpt = Path(checkpoint)
    ours = vecnormalize_path(ckpt)
    prefix, _, steps = ckpt.stem.partition("_")
    pickles = [vecnormalize_path(ckpt, pickled=True),
               ckpt.with_name(f"{prefix}_vecnormalize_{steps}.pkl")]
    return (ours if ours.is_file() else None,
            next((p for p in pickles if p.is_file()), None))


REPLAY_SUFFIX = ".replay.npz"


def _save_checkpoint(model, folder: Path, tag: str, settings: TrainSettings) -> Path:
    from .model_files import save_replay_buffer

    path = save_model(model, folder / f"{tag}_{model.num_timesteps}_steps.zip", settings)
    if getattr(model, "replay_buffer", None) is not None:
        save_replay_buffer(model.replay_buffer, path.with_suffix(REPLAY_SUFFIX))
    return path


def _checkpoint_callback(folder: Path, settings: TrainSettings, n_envs: int):
    """Every ``save_freq`` steps, a checkpoint as `_save_checkpoint` writes it (model,
    sidecar, JSON statistics, npz replay buffer): SB3's CheckpointCallback pickles the
    statistics and the buffer, which a resume would then have to unpickle."""
    from stable_baselines3.common.callbacks import BaseCallback

    every = max(1, settings.save_freq // n_envs)   # callbacks count vector steps

    class Checkpoints(BaseCallback):
        def _on_step(self) -> bool:
            if self.n_calls % every == 0:
                _save_checkpoint(self.model, folder, "checkpoint", settings)
            return True

    return Checkpoints()


def _new_model(cls, hyper: dict[str, Any], env, settings: TrainSettings):
    """The algorithm as the hyperparameters describe it, untrained."""
    from .schedules import with_schedules

    kwargs = with_schedules({k: v for k, v in hyper.items() if k not in ZOO_ONLY_KEYS})
    kwargs["policy_kwargs"] = parse_policy_kwargs(kwargs.get("policy_kwargs"))
    noise = _action_noise(hyper)
    if noise is not None:
        kwargs["action_noise"] = noise
    return cls(hyper.get("policy", "MlpPolicy"), env, seed=settings.seed,
               device=settings.device, verbose=0, **kwargs)


def _resume(cls, checkpoint: Path, env, hyper: dict[str, Any], norm_kw: dict[str, Any] | None,
            frame_stack: int, settings: TrainSettings, trust: bool):
    """The model of ``checkpoint``, ready to learn on (wrapped) ``env``.

    By default as data: the algorithm is rebuilt from the run's hyperparameters, then the
    checkpoint's tensors (weights and optimiser state, ``weights_only``), its step counters
    (plain JSON), normaliser statistics (JSON) and replay buffer (npz) are put into it.
    ``trust``: SB3's own loader and the pickles older runs wrote."""
    from .model_files import (
        load_replay_buffer,
        read_archive,
        read_normalizer,
        restore_normalizer,
        untrusted,
    )

    stats_json, stats_pickle = checkpoint_statistics(checkpoint)
    if norm_kw is not None and stats_json is None and stats_pickle is not None:
        if not trust:
            raise untrusted(stats_pickle, "normaliser statistics stored as a pickle")
        from stable_baselines3.common.vec_env import VecNormalize

        env = wrap_env(VecNormalize.load(str(stats_pickle), env), None, frame_stack)
    else:
        env = wrap_env(env, norm_kw, frame_stack)
        if norm_kw is not None and stats_json is not None:
            norm = env.venv if frame_stack > 1 else env
            restore_normalizer(norm, read_normalizer(stats_json, norm.observation_space.shape[0]))
    buffer_npz = checkpoint.with_suffix(REPLAY_SUFFIX)
    buffer_pickle = checkpoint.with_suffix(".replay.pkl")
    if trust:
        model = cls.load(checkpoint, env=env, device=settings.device)
        if hasattr(model, "load_replay_buffer") and buffer_pickle.is_file() \
                and not buffer_npz.is_file():
            model.load_replay_buffer(buffer_pickle)
    else:
        archive = read_archive(checkpoint)
        model = _new_model(cls, hyper, env, settings)
        try:
            model.set_parameters(archive.params, exact_match=True, device=settings.device)
        except (ValueError, KeyError, RuntimeError) as exc:
            raise ValueError(f"{checkpoint}: its tensors do not fit the run's {settings.algo} "
                             f"model ({str(exc).splitlines()[0][:200]})") from None
        wanted = set(model._get_torch_save_params()[1])     # e.g. SAC's log_ent_coef
        for name, value in (archive.variables or {}).items():
            if name in wanted and value is not None:
                getattr(model, name).data = value.data
        for counter in ("num_timesteps", "_n_updates", "_episode_num"):
            value = archive.data.get(counter, 0)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{checkpoint}: data field {counter!r} must be a "
                                 f"non-negative integer, got {value!r}")
            setattr(model, counter, value)
    if getattr(model, "replay_buffer", None) is not None:
        if buffer_npz.is_file():
            load_replay_buffer(model.replay_buffer, buffer_npz)
        elif buffer_pickle.is_file() and not trust:
            raise untrusted(buffer_pickle, "a replay buffer stored as a pickle")
    return model


def write_sidecar(model_path: Path, settings: TrainSettings,
                  extra: dict[str, Any] | None = None) -> None:
    """Record what a saved model was trained on, for evaluation tools: the level
    (``env_id``), only the options that override it (``env_kwargs``), the episode length,
    the seed and the observation wrappers (``frame_stack``, ``normalize``)."""
    level, config = settings.environment()
    norm_kw, frame_stack = wrapper_settings(settings.hyperparams_used)
    sidecar = {"algo": settings.algo, "env_id": level.id,
               "env_kwargs": level_overrides(level, config),
               "max_episode_steps": settings.max_episode_steps, "seed": settings.seed,
               "frame_stack": frame_stack, "normalize": norm_kw is not None}
    sidecar.update(extra or {})
    Path(model_path).with_suffix(".json").write_text(json.dumps(sidecar, indent=2, default=list))


def _selection_callback(eval_env, settings: TrainSettings, run_dir: Path, n_envs: int,
                        began: float | None = None):
    """SB3's EvalCallback (writes evaluations.npz and best_model.zip, the first best), which
    also keeps ``selected_model.zip``: the latest snapshot whose mean validation return is
    at least the best so far (ties go to the later snapshot; see the module docstring)."""
    from stable_baselines3.common.callbacks import EvalCallback

    began = time.time() if began is None else began
    dt = settings.environment()[1].control_period

    class SelectingEvalCallback(EvalCallback):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.selected_mean = -np.inf
            self.selected_steps: int | None = None
            self.last_eval_steps: int | None = None

        def _on_step(self) -> bool:
            due = self.eval_freq > 0 and self.n_calls % self.eval_freq == 0
            best_before = self.best_mean_reward
            keep_going = super()._on_step()
            if due:
                if self.best_mean_reward != best_before:   # SB3 just wrote best_model.zip
                    save_model_extras(self.model, run_dir / "best_model.zip", settings)
                self._select()
            return keep_going

        def _select(self) -> None:
            self.last_eval_steps = self.num_timesteps
            # The curve against wall-clock time (since train() began: warm start and
            # imitation included), for the learning curve and agents.time_to_target.
            lengths = np.asarray(self.evaluations_length[-1], dtype=float)
            with open(run_dir / "evaluations_wall.csv", "a") as f:
                if f.tell() == 0:
                    f.write("timesteps,wall_seconds,mean_return,mean_trapping_time\n")
                f.write(f"{self.num_timesteps},{time.time() - began:.2f},"
                        f"{self.last_mean_reward},{lengths.mean() * dt}\n")
            if self.last_mean_reward >= self.selected_mean:
                self.selected_mean = float(self.last_mean_reward)
                self.selected_steps = int(self.num_timesteps)
                save_model(self.model, run_dir / "selected_model.zip", settings,
                           {"selected_at_steps": self.selected_steps,
                            "validation_mean_return": self.selected_mean,
                            "validation_episodes": self.n_eval_episodes,
                            "validation_seed": VALIDATION_SEED})

        def evaluate_now(self) -> None:
            """One more evaluation (of the final model), unless the last one was of it."""
            if self.last_eval_steps == self.num_timesteps:
                return
            period, self.eval_freq = self.eval_freq, 1   # due now, whatever n_calls is
            try:
                self._on_step()
            finally:
                self.eval_freq = period

    per_env = max(1, settings.eval_freq // n_envs)    # callbacks count vector steps
    return SelectingEvalCallback(eval_env, n_eval_episodes=settings.eval_episodes,
                                 eval_freq=per_env, best_model_save_path=str(run_dir),
                                 log_path=str(run_dir), deterministic=True, verbose=0)


def _progress_callback():
    """A progress bar that ends at the number of steps actually taken: SB3's counts to the
    budget asked for, but on-policy algorithms collect whole rollouts (n_steps × n_envs)
    and finish past it (e.g. 303,104 of 300,000), so the bar's total follows the count."""
    from stable_baselines3.common.callbacks import ProgressBarCallback

    class ExactProgressBar(ProgressBarCallback):
        def _on_training_start(self) -> None:
            super()._on_training_start()
            self.pbar.total = self._expected()
            self.pbar.refresh()

        def _expected(self) -> int:
            remaining = self.locals["total_timesteps"] - self.model.num_timesteps
            chunk = self.training_env.num_envs * int(getattr(self.model, "n_steps", 1))
            return -(-remaining // chunk) * chunk          # whole rollouts of `chunk` steps

        def _on_step(self) -> bool:
            self.pbar.update(self.training_env.num_envs)
            if self.pbar.n > self.pbar.total:               # never show more than the total
                self.pbar.total = self.pbar.n
            return True

        def _on_training_end(self) -> None:
            self.pbar.total = self.pbar.n                    # the true number of steps
            super()._on_training_end()

    return ExactProgressBar()


def train(settings: TrainSettings, resume: str | Path | None = None, trust: bool = False
          ) -> Path:
    """Train (or resume) an agent; return the run folder. ``trust``: a resumed checkpoint
    may be unpickled (see `_resume`)."""
    check_dependencies(settings.progress_bar)
    import torch
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.logger import configure

    began = time.time()
    settings.validate()
    torch.set_num_threads(settings.torch_threads)
    cls = algo_class(settings.algo)
    hyper = load_hyperparams(settings.algo, settings.env_id, settings.hyperparams, note=True)
    settings.hyperparams_used = hyper
    norm_kw, frame_stack = wrapper_settings(hyper)
    n_envs = int(settings.n_envs or hyper.get("n_envs", 8))
    total = int(settings.total_timesteps or float(hyper.get("n_timesteps", 1e5)))
    if n_envs < 1 or total < 1:
        raise ValueError("n_envs and total_timesteps must be positive")
    settings.n_envs, settings.total_timesteps = n_envs, total
    if settings.eval_freq is None:
        settings.eval_freq = max(20_000, total // 20)
    name = settings.run_name or f"{settings.algo}_seed{settings.seed}_{time.strftime('%Y%m%d-%H%M%S')}"
    run_dir = Path(settings.log_dir) / name
    if resume is not None:
        run_dir = Path(resume).resolve().parent.parent
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.json").write_text(json.dumps(asdict(settings), indent=2, default=list))

    steps = settings.max_episode_steps
    env = make_vec_env(n_envs, settings.seed, settings.env_kwargs,
                       train_episode_steps(hyper, steps), settings.env_id)
    eval_env = make_vec_env(min(settings.eval_episodes, 16), VALIDATION_SEED + settings.seed,
                            settings.env_kwargs, steps, settings.env_id)
    if hyper.get("reward_shaping") is not None:      # training rewards only (agents.shaping)
        from .shaping import shape

        env = shape(env, hyper["reward_shaping"], settings.environment()[1])
        eval_env = shape(eval_env, hyper["reward_shaping"], settings.environment()[1],
                         training=False)
    if resume is not None:
        model = _resume(cls, Path(resume), env, hyper, norm_kw, frame_stack, settings, trust)
    else:
        env = wrap_env(env, norm_kw, frame_stack)
        model = _new_model(cls, hyper, env, settings)
        if hyper.get("warm_start"):
            from .warm_start import warm_start

            _, config = settings.environment()
            began = time.time()
            done = warm_start(model, config, hyper["warm_start"], steps, settings.seed,
                              hyper.get("imitation"))
            done["seconds"] = round(time.time() - began, 1)   # wall time beside RL's
            (run_dir / "warm_start.json").write_text(json.dumps(done, indent=2))
    eval_env = wrap_env(eval_env, norm_kw, frame_stack, training=False)
    model.set_logger(configure(str(run_dir), ["csv", "tensorboard"]))
    selector = _selection_callback(eval_env, settings, run_dir, n_envs, began)
    callbacks = [_checkpoint_callback(run_dir / "checkpoints", settings, n_envs), selector]
    if settings.progress_bar:
        callbacks.append(_progress_callback())

    def on_sigterm(signum, frame):  # noqa: ARG001
        raise _Stop()

    previous = signal.signal(signal.SIGTERM, on_sigterm)
    remaining = total - model.num_timesteps
    interrupted = False
    if resume is None and hyper.get("warm_start") == "mpc":
        # The imitating network is a candidate too: RL fine-tuning may not improve on it.
        # (Only here: an extra evaluation moves later validation episodes along their
        # seeds' streams, and the other recipes' runs stay as they were.)
        selector.init_callback(model)
        selector.evaluate_now()
    try:
        if remaining > 0:
            model.learn(remaining, callback=CallbackList(callbacks),
                        reset_num_timesteps=resume is None)
    except (KeyboardInterrupt, _Stop):
        interrupted = True
        path = _save_checkpoint(model, run_dir / "checkpoints", "interrupted", settings)
        print(f"\ninterrupted at {model.num_timesteps} steps; checkpoint saved to {path}\n"
              f"continue with: python train.py --resume {path}")
    finally:
        signal.signal(signal.SIGTERM, previous)
    if not interrupted:
        if remaining > 0:
            selector.evaluate_now()      # the final model is a candidate too
        save_model(model, run_dir / "final_model.zip", settings)
        if (run_dir / "best_model.zip").is_file():
            write_sidecar(run_dir / "best_model.zip", settings)
        plot_learning_curve(run_dir)
        if settings.compare_episodes > 0:
            compare(run_dir, settings)
    env.close()
    eval_env.close()
    return run_dir


def compare(run_dir: Path, settings: TrainSettings) -> str:
    """The selected model beside best-const and mpc on fresh episodes (`COMPARE_SEED`):
    print the table, save ``comparison.md`` and ``comparison.json``; return the Markdown."""
    from .evaluation import evaluate, markdown
    from .policies import load_policy

    _, config = settings.environment()
    model = run_dir / "selected_model.zip"
    if not model.is_file():
        model = run_dir / "final_model.zip"
    steps = int(settings.max_episode_steps or 500)
    print(f"comparing {model.name} with best-const and mpc on {settings.compare_episodes} fresh "
          f"episodes (seeds from {COMPARE_SEED:,}) ...", flush=True)
    specs = [(str(model), load_policy(model, config)), "best-const", "mpc"]
    table, _ = evaluate(specs, config, settings.compare_episodes, COMPARE_SEED,
                        max_episode_steps=steps, examples=0, env_id=settings.env_id,
                        progress=settings.progress_bar)
    text = markdown(table)
    refs = {row["policy"]: row["trapping_time"]["mean"] for row in table["policies"]
            if row["policy"] in ("best-const", "mpc")}
    plot_learning_curve(run_dir, refs, f" ({settings.compare_episodes} fresh ep.)")
    (run_dir / "comparison.md").write_text(text)
    (run_dir / "comparison.json").write_text(json.dumps(table, indent=1) + "\n")
    print(text)
    return text


def plot_learning_curve(run_dir: Path, references: dict[str, float] | None = None,
                        reference_note: str = "") -> Path | None:
    """Validation trapping time against timesteps and against wall-clock seconds (from
    evaluations.npz and evaluations_wall.csv) as PNG, and the curve as CSV. ``references``
    (policy name -> mean trapping time, e.g. best-const and mpc from the closing
    comparison) are drawn as horizontal lines."""
    data_file = run_dir / "evaluations.npz"
    if not data_file.is_file():
        return None
    data = np.load(data_file, allow_pickle=False)
    steps, results, lengths = data["timesteps"], data["results"], data["ep_lengths"]
    dt = 0.02
    config_file = run_dir / "config.json"
    if config_file.is_file():
        try:
            saved = json.loads(config_file.read_text())
            dt = resolve_env(saved["env_id"], saved.get("env_kwargs") or {})[1].control_period
        except (KeyError, ValueError, TypeError):
            pass
    wall: dict[int, float] = {}
    wall_file = run_dir / "evaluations_wall.csv"
    if wall_file.is_file():
        for line in wall_file.read_text().splitlines()[1:]:
            cells = line.split(",")
            wall[int(cells[0])] = float(cells[1])
    seconds = [wall.get(int(s), float("nan")) for s in steps]
    rows = ["timesteps,mean_return,std_return,mean_length,wall_seconds"]
    rows += [f"{s},{r.mean()},{r.std()},{n.mean()},{w}"
             for s, r, n, w in zip(steps, results, lengths, seconds)]
    (run_dir / "learning_curve.csv").write_text("\n".join(rows) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    trap = lengths.mean(axis=1) * dt
    have_wall = bool(wall) and np.isfinite(seconds).any()
    fig, axes = plt.subplots(1, 2 if have_wall else 1, figsize=(10 if have_wall else 6, 3.5),
                             dpi=100, sharey=True, squeeze=False)
    xs = [(steps, "timesteps")] + ([(np.asarray(seconds), "wall-clock seconds since training "
                                     "began")] if have_wall else [])
    for ax, (x, label) in zip(axes[0], xs):
        ax.plot(x, trap, color="C0", marker="o", ms=3,
                label=f"validation ({lengths.shape[1]} episodes)")
        for k, (name, value) in enumerate((references or {}).items()):
            ax.axhline(value, color=("0.4", "C3", "C2")[k % 3], ls=("--", "-.", ":")[k % 3],
                       label=f"{name} {value:.2f}{reference_note}")
        ax.set_xlabel(label)
    axes[0][0].set_ylabel("mean trapping time [s]")
    axes[0][-1].legend(fontsize=7, loc="lower right")
    fig.suptitle(run_dir.name, fontsize=9)
    fig.tight_layout()
    out = run_dir / "learning_curve.png"
    fig.savefig(out)
    plt.close(fig)
    return out


__all__ = ["ALGO_NAMES", "MAIN_JOB_ENV_ID", "VALIDATION_SEED", "TrainSettings",
           "check_dependencies", "compare", "load_hyperparams", "make_vec_env",
           "parse_env_kwargs", "parse_policy_kwargs", "plot_learning_curve", "save_model",
           "settings_for_resume", "train", "wrapper_settings", "write_sidecar"]
