"""The Stable-Baselines3 back end of `agents.training.trainer`: PPO, SAC, TD3 and A2C in this
process, on the batch adapter (`saddle_env.envs.sb3`), so all ``n_envs`` balls advance in
one compiled call.

The recipe's zoo keys it honours besides the algorithm's own arguments (`agents.training.recipes`):
``policy``, ``noise_type``/``noise_std`` (off-policy action noise), ``normalize`` (``true``
or ``"dict(norm_obs=True, norm_reward=False)"``: VecNormalize, its statistics saved next to
every model as ``<model>.vecnormalize.json``), ``frame_stack`` (VecFrameStack with that many
frames), ``warm_start`` (`agents.training.warm_start`), ``imitation`` (its settings for
``warm_start: mpc``, `agents.training.imitation`), ``train_episode_steps`` (shorter *training*
episodes; evaluation keeps the level's) and ``reward_shaping`` (training rewards only,
`agents.training.shaping`). Evaluation (`agents.evaluation.policies.load_policy`) applies the same
normalisation and stacking from the sidecar.

What it writes in the run folder: TensorBoard logs, ``progress.csv``, ``evaluations.npz``
(every evaluation's per-episode returns and trapping times), ``evaluations_wall.csv`` and
``curve_episodes.json`` (the episodes of the curve), ``best_model.zip`` (the *first*
evaluation that reached the highest mean return, as SB3's EvalCallback keeps it),
``selected_model.zip`` and ``selection.json`` (below), ``candidates/``, ``checkpoints/`` and
``final_model.zip``, each model with a ``.json`` sidecar that records the level
(``env_id``), the options overriding it (``env_kwargs``), the episode length and the
wrappers. Ctrl-C or SIGTERM saves a checkpoint (and the replay buffer of off-policy
algorithms); ``--resume CHECKPOINT.zip`` continues from it (the selection then sees the
evaluations after the resume only). Everything a run writes is read back as data (JSON,
tensors, npz: `agents.evaluation.model_files`); a checkpoint that needs unpickling (SB3's
own files, older runs' pickles) is resumed only with ``--trust-model``.

**Model selection** (`agents.training.selection`). Every ``eval_freq`` steps (default: a
twentieth of the budget), and once more on the final model, the network is saved and
evaluated on the ``eval_episodes`` validation episodes ``reset(seed=VALIDATION_SEED + i)``
(the same for every seed of a recipe, never used for training or for the leaderboard's
test set) by the evaluation tool's own function, so that the curve and the reference lines
drawn beside it come from the same episodes. The best few snapshots are re-evaluated on
fresh episodes when training ends and the best there is shipped as ``selected_model.zip``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from saddle_env.envs import EnvConfig

from ...cli_args import MissingExtra, install_hint, level_overrides, missing
from ..recipes import (
    ZOO_ONLY_KEYS,
    parse_policy_kwargs,
    train_episode_steps,
    wrapper_settings,
)
from ..run_report import append_curve_point
from ..runs import RunSettings, Stop, StopRequest, TrainSettings, sigterm_stops, stops_held
from ..schedules import with_schedules

# What training imports beyond the core install (all in the "train" extra).
TRAIN_MODULES = ("stable_baselines3", "torch", "yaml", "matplotlib")
PROGRESS_MODULES = ("tqdm", "rich")
# A resumed checkpoint is read as data; only older runs' pickles need --trust-model.
RESUME_NEEDS_TRUST = False


def algo_class(name: str):
    """The SB3 algorithm class named ``name`` (ppo, sac, td3, a2c).

    Raises
    ------
    ValueError
        If ``name`` is none of these.
    """
    from stable_baselines3 import A2C, PPO, SAC, TD3

    classes = {"ppo": PPO, "sac": SAC, "td3": TD3, "a2c": A2C}
    if name not in classes:
        raise ValueError(f"algo must be one of {sorted(classes)}, got {name!r}")
    return classes[name]


def check_dependencies(progress_bar: bool) -> None:
    """One line naming the extra to install if training cannot import what it needs."""
    lacking = missing(TRAIN_MODULES + (PROGRESS_MODULES if progress_bar else ()))
    if lacking:
        raise MissingExtra(f"training needs {', '.join(lacking)}, not installed: "
                           f"{install_hint('train')}")


# ---------------------------------------------------------------------------------------
# environments
# ---------------------------------------------------------------------------------------
def make_vec_env(n_envs: int, seed: int, config: EnvConfig, max_episode_steps: int):
    """The batch environment for SB3, with episode statistics (VecMonitor).

    Parameters
    ----------
    n_envs : int
        The number of balls.
    seed : int
        Ball i's first episode is seeded ``seed + i``.
    config : EnvConfig
        A level's config with its options on top (`agents.cli_args.resolve_env`), checked
        there: the environment uses it as given.
    max_episode_steps : int
        The episode length in control steps.
    """
    from stable_baselines3.common.vec_env import VecMonitor

    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    env = SaddleTrapSB3VecEnv(num_envs=n_envs, max_episode_steps=max_episode_steps,
                              config=config)
    env.seed(seed)
    return VecMonitor(env)


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
# models, checkpoints and callbacks
# ---------------------------------------------------------------------------------------
class Sb3Learner:
    """How this back end makes, warm-starts, saves, checkpoints and resumes a model. A back
    end on SB3's API (`agents.training.backends.sbx`) replaces these five and shares the rest of the
    run (`train_with`): environments, callbacks, model selection and interruption."""

    resume_needs_trust = RESUME_NEEDS_TRUST

    def new_model(self, hyper: dict[str, Any], env, settings: TrainSettings):
        """Make the untrained model.

        Parameters
        ----------
        hyper : dict
            The run's hyperparameters (the recipe's YAML entry).
        env : VecEnv
            The (wrapped) training environment.
        settings : TrainSettings
            The run's resolved settings (algorithm, seed, device).

        Returns
        -------
        BaseAlgorithm
            The model, ready to learn.
        """
        return _new_model(algo_class(settings.algo), hyper, env, settings)

    def warm_start(self, model, config, hyper: dict[str, Any], steps: int, seed: int
                   ) -> dict[str, Any]:
        """Apply the recipe's warm start to the new ``model`` before training.

        Parameters
        ----------
        model : BaseAlgorithm
            The model that `new_model` made.
        config : EnvConfig
            The training level's configuration.
        hyper : dict
            The run's hyperparameters; ``hyper["warm_start"]`` names the warm start.
        steps : int
            The episode length, in env steps.
        seed : int
            The seed of the warm start's episodes.

        Returns
        -------
        dict
            What was done, for the run folder.
        """
        from ..warm_start import warm_start

        return warm_start(model, config, hyper["warm_start"], steps, seed, hyper.get("imitation"))

    def save(self, model, path: Path, settings: TrainSettings,
             extra: dict[str, Any] | None = None) -> Path:
        """Save ``model`` as a model file that evaluation loads.

        Parameters
        ----------
        model : BaseAlgorithm
            The model.
        path : Path
            The model file (``.zip``).
        settings : TrainSettings
            The run's settings, written to the sidecar.
        extra : dict, optional
            More entries for the sidecar.

        Returns
        -------
        Path
            The file written.
        """
        return save_model(model, path, settings, extra)

    def checkpoint(self, model, folder: Path, tag: str, settings: TrainSettings) -> Path:
        """Save a checkpoint that `resume` can continue from.

        Parameters
        ----------
        model : BaseAlgorithm
            The model.
        folder : Path
            The run's checkpoint folder.
        tag : str
            The start of the file name (``<tag>_<steps>_steps.zip``).
        settings : TrainSettings
            The run's settings, written to the sidecar.

        Returns
        -------
        Path
            The checkpoint's model file.
        """
        return _save_checkpoint(model, folder, tag, settings)

    def resume(self, checkpoint: Path, env, hyper: dict[str, Any], norm_kw, frame_stack: int,
               settings: TrainSettings, trust: bool):
        """Load ``checkpoint`` to continue training on ``env``.

        Parameters
        ----------
        checkpoint : Path
            A model file that `checkpoint` wrote.
        env : VecEnv
            The training environment, before the run's wrappers.
        hyper : dict
            The run's hyperparameters (the algorithm is rebuilt from them).
        norm_kw : dict or None
            The observation normaliser's options, None if observations are not normalised.
        frame_stack : int
            Observations stacked per step.
        settings : TrainSettings
            The run's settings.
        trust : bool
            Whether pickled files (older runs') may be loaded.

        Returns
        -------
        BaseAlgorithm
            The model, with its weights, counters, statistics and replay buffer restored.
        """
        return _resume(algo_class(settings.algo), checkpoint, env, hyper, norm_kw, frame_stack,
                       settings, trust)


def save_model(model, path: Path, settings: TrainSettings, extra: dict[str, Any] | None = None
               ) -> Path:
    """Save ``model`` at ``path`` with its sidecar and, if observations are normalised, the
    statistics next to it as JSON (what evaluation needs to act as in training)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    from ...evaluation.model_files import save_normalizer
    from ...evaluation.policies import vecnormalize_path

    with stops_held():    # a stop during the save comes after it, with the files whole
        model.save(path)
        norm = model.get_vec_normalize_env()
        if norm is not None:
            save_normalizer(norm, vecnormalize_path(path))
        write_sidecar(path, settings, extra)
    return path


def checkpoint_statistics(checkpoint: str | Path) -> tuple[Path | None, Path | None]:
    """(JSON, pickle) normalisation statistics saved with a checkpoint, each None if absent:
    ours (``<stem>.vecnormalize.json``), or the pickles older runs and SB3's
    CheckpointCallback wrote (``<stem>.vecnormalize.pkl``,
    ``checkpoint_vecnormalize_<steps>_steps.pkl``)."""
    from ...evaluation.policies import vecnormalize_path

    ckpt = Path(checkpoint)
    ours = vecnormalize_path(ckpt)
    prefix, _, steps = ckpt.stem.partition("_")
    pickles = [vecnormalize_path(ckpt, pickled=True),
               ckpt.with_name(f"{prefix}_vecnormalize_{steps}.pkl")]
    return (ours if ours.is_file() else None,
            next((p for p in pickles if p.is_file()), None))


REPLAY_SUFFIX = ".replay.npz"


def _save_checkpoint(model, folder: Path, tag: str, settings: TrainSettings) -> Path:
    from ...evaluation.model_files import save_replay_buffer

    with stops_held():
        path = save_model(model, folder / f"{tag}_{model.num_timesteps}_steps.zip", settings)
        if getattr(model, "replay_buffer", None) is not None:
            save_replay_buffer(model.replay_buffer, path.with_suffix(REPLAY_SUFFIX))
    return path


def _checkpoint_callback(folder: Path, settings: TrainSettings, n_envs: int,
                         learner: Sb3Learner):
    """Every ``save_freq`` steps, a checkpoint as ``learner`` writes it (here: model,
    sidecar, JSON statistics, npz replay buffer): SB3's CheckpointCallback pickles the
    statistics and the buffer, which a resume would then have to unpickle."""
    from stable_baselines3.common.callbacks import BaseCallback

    every = max(1, settings.save_freq // n_envs)   # callbacks count vector steps

    class Checkpoints(BaseCallback):
        def _on_step(self) -> bool:
            if self.n_calls % every == 0:
                learner.checkpoint(self.model, folder, "checkpoint", settings)
            return True

    return Checkpoints()


def _new_model(cls, hyper: dict[str, Any], env, settings: TrainSettings):
    """The algorithm as the hyperparameters describe it, untrained."""
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
    from ...evaluation.model_files import load_replay_buffer, read_archive, untrusted

    env = resume_env(checkpoint, env, norm_kw, frame_stack, trust)
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


def resume_env(checkpoint: Path, env, norm_kw: dict[str, Any] | None, frame_stack: int,
               trust: bool):
    """``env`` wrapped as the run wraps it, its normaliser holding the statistics saved with
    ``checkpoint`` (JSON; an older run's pickle only with ``trust``)."""
    from ...evaluation.model_files import read_normalizer, restore_normalizer, untrusted

    stats_json, stats_pickle = checkpoint_statistics(checkpoint)
    if norm_kw is not None and stats_json is None and stats_pickle is not None:
        if not trust:
            raise untrusted(stats_pickle, "normaliser statistics stored as a pickle")
        from stable_baselines3.common.vec_env import VecNormalize

        return wrap_env(VecNormalize.load(str(stats_pickle), env), None, frame_stack)
    env = wrap_env(env, norm_kw, frame_stack)
    if norm_kw is not None and stats_json is not None:
        norm = env.venv if frame_stack > 1 else env
        restore_normalizer(norm, read_normalizer(stats_json, norm.observation_space.shape[0]))
    return env


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


def _selection_callback(settings: RunSettings, run_dir: Path, n_envs: int,
                        learner: Sb3Learner, began: float | None = None):
    """Every ``eval_freq`` steps (and on demand, `evaluate_now`): the network saved by
    ``learner`` as a snapshot and offered to the run's `agents.training.selection.Selection`
    (the validation curve, ``evaluations.npz``, ``best_model.zip`` and the best few
    candidates); `finish` re-evaluates the candidates on fresh episodes and ships one."""
    from stable_baselines3.common.callbacks import BaseCallback

    from ..selection import Selection

    start_s = time.time() if began is None else began
    per_env = max(1, settings.eval_freq // n_envs)    # callbacks count vector steps

    class SelectingCallback(BaseCallback):
        def __init__(self) -> None:
            super().__init__(verbose=0)
            self.selection = Selection(run_dir, settings)
            self.last_eval_steps: int | None = None

        def _on_step(self) -> bool:
            if self.n_calls % per_env == 0:
                self.evaluate_now()
            return True

        def evaluate_now(self) -> None:
            """Evaluate the current network, unless the last evaluation was of it."""
            if self.last_eval_steps == self.num_timesteps:
                return
            self.last_eval_steps = steps = int(self.num_timesteps)
            model = self.model
            result = self.selection.offer(
                steps, lambda path: learner.save(model, path, settings))
            # The curve against wall-clock time (since train() began: warm start and
            # imitation included), for the learning curve and agents.benchmark.time_to_target.
            append_curve_point(run_dir, steps, time.time() - start_s, result["mean_return"],
                               result["mean_trapping_time"])

        def finish(self) -> Path | None:
            return self.selection.choose()

    return SelectingCallback()


def _lost_stop_callback(requested: StopRequest):
    """Raises, at the next step, a stop whose exception Python dropped (`StopRequest`)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class LostStop(BaseCallback):
        def _on_step(self) -> bool:
            requested.raise_if_lost()
            return True

    return LostStop()


def progress_callback():
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




# ---------------------------------------------------------------------------------------
# the run
# ---------------------------------------------------------------------------------------
def run(settings: RunSettings, hyper: dict[str, Any], run_dir: Path,
        resume: str | Path | None = None, trust: bool = False,
        began: float | None = None) -> Path | None:
    """Train (or resume) in ``run_dir`` with the recipe ``hyper`` (settings validated and
    filled by `agents.training.trainer.train`); return the model to compare (the selected one), or
    None if the run was interrupted (a checkpoint was saved). ``trust``: a resumed
    checkpoint may be unpickled (see `_resume`)."""
    return train_with(Sb3Learner(), settings, hyper, run_dir, resume, trust, began)


def train_with(learner: Sb3Learner, settings: RunSettings, hyper: dict[str, Any],
               run_dir: Path, resume: str | Path | None = None, trust: bool = False,
               began: float | None = None) -> Path | None:
    """`run` with the model made, warm-started, saved and resumed by ``learner``."""
    import torch
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.logger import configure

    began = time.time() if began is None else began
    torch.set_num_threads(settings.torch_threads)
    norm_kw, frame_stack = wrapper_settings(hyper)
    n_envs, steps = settings.n_envs, settings.max_episode_steps
    _, config = settings.environment()
    env = make_vec_env(n_envs, settings.seed, config, train_episode_steps(hyper, steps))
    if hyper.get("reward_shaping") is not None:      # training rewards only (agents.training.shaping)
        from ..shaping import shape

        env = shape(env, hyper["reward_shaping"], config)
    if resume is not None:
        model = learner.resume(Path(resume), env, hyper, norm_kw, frame_stack, settings, trust)
    else:
        env = wrap_env(env, norm_kw, frame_stack)
        model = learner.new_model(hyper, env, settings)
        if hyper.get("warm_start"):
            began = time.time()
            done = learner.warm_start(model, config, hyper, steps, settings.seed)
            done["seconds"] = round(time.time() - began, 1)   # wall time beside RL's
            (run_dir / "warm_start.json").write_text(json.dumps(done, indent=2))
    model.set_logger(configure(str(run_dir), ["csv", "tensorboard"]))
    selector = _selection_callback(settings, run_dir, n_envs, learner, began)
    callbacks = [_checkpoint_callback(run_dir / "checkpoints", settings, n_envs, learner),
                 selector]
    if settings.progress_bar:
        callbacks.append(progress_callback())
    remaining = settings.total_timesteps - model.num_timesteps
    if resume is None and hyper.get("warm_start") == "mpc":
        # The imitating network is a candidate too: RL fine-tuning may not improve on it.
        selector.init_callback(model)
        selector.evaluate_now()
    try:
        with sigterm_stops() as requested:
            if remaining > 0:
                model.learn(remaining, callback=CallbackList([_lost_stop_callback(requested),
                                                              *callbacks]),
                            reset_num_timesteps=resume is None)
    except (KeyboardInterrupt, Stop):
        path = learner.checkpoint(model, run_dir / "checkpoints", "interrupted", settings)
        print(f"\ninterrupted at {model.num_timesteps} steps; checkpoint saved to {path}\n"
              f"continue with: python train.py --resume {path}")
        env.close()
        return None
    if remaining > 0:
        selector.evaluate_now()      # the final model is a candidate too
    env.close()
    learner.save(model, run_dir / "final_model.zip", settings)
    selected = selector.finish()
    return selected if selected is not None else run_dir / "final_model.zip"


__all__ = ["REPLAY_SUFFIX", "RESUME_NEEDS_TRUST", "Sb3Learner", "TRAIN_MODULES", "algo_class",
           "check_dependencies", "checkpoint_statistics", "make_vec_env", "progress_callback",
           "resume_env", "run", "save_model", "train_with", "wrap_env", "write_sidecar"]
