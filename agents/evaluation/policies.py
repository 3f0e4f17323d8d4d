"""Policies by name or file: the registry of baselines (`BASELINES`) and loading
Stable-Baselines3 model files with their sidecars.

`load_policy` takes a baseline name (``BASELINES``, or ``const-<K>`` for any K) or the path
of a model file. A model file is loaded on the CPU with its algorithm detected; if its
sidecar (the ``.json`` next to it that ``train.py`` writes) says training stacked frames
(``frame_stack``) or normalised observations (``normalize``, statistics in the
``.vecnormalize.pkl`` next to the model), the returned policy does the same to the raw
observations it is given, so it can be evaluated on the plain environment.

Model files are read as data (`agents.evaluation.model_files`): the network is rebuilt from JSON and
tensors, nothing is unpickled. ``trust=True`` (``--trust-model`` on the command line) opts
in to Stable-Baselines3's own loader and to pickled statistics, for files from a trusted
source that the safe reader refuses.
"""

from __future__ import annotations

import json
import os
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from saddle_env.envs import EnvConfig
from saddle_env.envs.observation import observation_space, stack_frames

from ..control.best_constant import best_const
from ..control.clairvoyant import clairvoyant as _clairvoyant
from ..control.controllers import (
    CONST_MULTIPLES,
    Controller,
    UniformRandom,
    ZeroAction,
    constant_multiple,
    mass_point,
    parse_constant,
)
from ..control.mpc import ModelPredictiveController
from .model_files import (
    ObservationNormalizer,
    UntrustedFileError,
    build_policy,
    read_archive,
    read_normalizer,
    untrusted,
)
from .user_code import is_controller_spec, load_controller

BASELINES: dict[str, Callable[..., Controller]] = {
    **{f"const-{k:.1f}": constant_multiple(k) for k in CONST_MULTIPLES},
    "masspoint": mass_point,
    "best-const": best_const,
    "mpc": ModelPredictiveController,
    # mpc that ignores the delays (issue 42): what ignoring a camera's latency costs
    "mpc-blind": lambda config: ModelPredictiveController(config, delay_aware=False,
                                                         name="mpc-blind"),
    "clairvoyant": lambda config: _clairvoyant(config, loader=load_policy),
    "zero": ZeroAction,
    "random": UniformRandom,
}
SB3_ALGOS = ("PPO", "SAC", "TD3", "A2C", "DDPG")
# Statistics of observation normalisation saved next to a model: <model>.vecnormalize.json
# (JSON, `agents.evaluation.model_files.save_normalizer`); the older pickle is read only with trust.
VECNORMALIZE_SUFFIX = ".vecnormalize.json"
VECNORMALIZE_PICKLE_SUFFIX = ".vecnormalize.pkl"


def model_sidecar(path: str | os.PathLike) -> dict[str, Any] | None:
    """The JSON sidecar ``train.py`` writes next to a model (``algo``, ``env_id``,
    ``env_kwargs`` (options over the level's), ``max_episode_steps``, ...), or None."""
    side = Path(path).with_suffix(".json")
    try:
        data = json.loads(side.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def policy_sidecar(spec: str | os.PathLike) -> dict[str, Any] | None:
    """The sidecar of a ``--policy`` argument: a model file's (``X.zip`` or ``X``), or the
    ``saddle_env.json`` of an RLlib checkpoint directory (a run folder: its latest)."""
    if is_exported_folder(spec):
        from saddle_env.deploy import PolicyFolderError, read_spec

        try:
            exported = read_spec(spec)
        except PolicyFolderError:
            return None      # load_policy reports what is wrong with it
        return {"env_id": exported.env_id, "env_kwargs": exported.env_kwargs}
    if Path(spec).is_dir():
        from .rllib_policy import checkpoint_sidecar, latest_checkpoint

        ckpt = latest_checkpoint(spec)
        return checkpoint_sidecar(ckpt) if ckpt is not None else None
    text = str(spec)
    return model_sidecar(text if text.endswith(".zip") else text + ".zip")


def is_exported_folder(spec: str | os.PathLike) -> bool:
    """Whether ``spec`` is a folder ``saddle-export`` wrote (it holds ``policy.json``), which
    `load_policy` runs with `saddle_env.deploy.Controller`, not as an RLlib checkpoint."""
    from saddle_env.deploy.folder import POLICY_JSON

    return Path(spec).is_dir() and (Path(spec) / POLICY_JSON).is_file()


def vecnormalize_path(model_path: str | os.PathLike, pickled: bool = False) -> Path:
    """Where the observation-normalisation statistics of a model file are kept (the JSON
    file; ``pickled=True``: the pickle older runs wrote)."""
    p = Path(model_path)
    return p.with_name(p.stem + (VECNORMALIZE_PICKLE_SUFFIX if pickled else VECNORMALIZE_SUFFIX))


def _algorithm(side: dict[str, Any] | None, data: dict[str, Any]) -> str:
    """The SB3 algorithm: the sidecar's ``algo``, else told by the zip's JSON ``data`` (the
    policy class's module, noted in plain text, and algorithm-specific fields)."""
    if side and str(side.get("algo", "")).upper() in SB3_ALGOS:
        return str(side["algo"]).upper()
    policy_class = data.get("policy_class")
    module = str(policy_class.get("__module__", "")) if isinstance(policy_class, dict) else ""
    if ".sac." in module:
        return "SAC"
    if ".td3." in module:  # DDPG is TD3 with one critic update per actor update, no smoothing
        if data.get("policy_delay") == 1 and data.get("target_noise_clip") == 0.0:
            return "DDPG"
        return "TD3"
    return "PPO" if "clip_range" in data else "A2C"


def sb3_algorithm(path: str | os.PathLike) -> str:
    """Name of the SB3 algorithm that saved ``path``: from the sidecar if there is one,
    else read from the zip's JSON ``data``."""
    side = model_sidecar(path)
    if side and str(side.get("algo", "")).upper() in SB3_ALGOS:
        return str(side["algo"]).upper()
    archive = read_archive(path)
    return _algorithm(None, {**archive.data, **archive.serialized})


def load_model(path: str | os.PathLike, config: EnvConfig | None = None, frame_stack: int = 1,
               trust: bool = False) -> Any:
    """A Stable-Baselines3 model file's policy on the CPU, its algorithm detected (set as
    ``algo_name``). The bare network: see `load_policy` for the observation pipeline
    (frame stacking, normalisation) its sidecar asks for.

    By default the network is rebuilt from the file's JSON and tensors for the observations
    of ``config`` (``frame_stack`` frames of them); nothing is unpickled and a file that
    would need it raises `UntrustedFileError`. ``trust=True`` loads with SB3's own loader,
    which unpickles what the file carries (the full model object, optimiser included)."""
    from ..cli_args import require

    sb3 = require("stable_baselines3", "train", "loading model files")
    if trust:
        try:
            algo = sb3_algorithm(path)
        except (KeyError, ValueError, zipfile.BadZipFile) as exc:
            raise ValueError(f"{path}: not a Stable-Baselines3 model file ({exc})") from None
        model = getattr(sb3, algo).load(path, device="cpu")
        model.algo_name = algo
        return model
    import gymnasium as gym

    from saddle_env.envs.saddle_trap import action_space

    archive = read_archive(path)
    side = model_sidecar(path)
    algo = _algorithm(side, {**archive.data, **archive.serialized})
    obs = observation_space(EnvConfig() if config is None else config)
    if frame_stack > 1:
        obs = gym.spaces.Box(np.tile(obs.low, frame_stack), np.tile(obs.high, frame_stack),
                             dtype=obs.low.dtype.type)
    policy = build_policy(archive, algo, obs, action_space(), side)
    policy.algo_name = algo
    return policy


class WrappedModel:
    """A model file whose training wrapped the environment (VecNormalize, VecFrameStack),
    acting on the plain environment's observations.

    Each raw observation is normalised with the saved statistics (as VecNormalize did in
    training: clipped, not updated), then stacked as VecFrameStack stacks: the last
    ``frame_stack`` frames, oldest first, zeros before the episode's first frame. The
    stack is per ball and travels in ``predict``'s ``state`` (SB3's recurrent slot, which
    saddle-eval passes back with ``episode_start``).
    """

    row_independent = False

    def __init__(self, model: Any, config: EnvConfig, frame_stack: int = 1,
                 normalizer: Any = None):
        self.model = model
        self.algo_name = model.algo_name
        self.frame_stack = int(frame_stack)
        self.normalizer = normalizer
        self.observation_space = observation_space(config)  # what it is given, unstacked
        self.action_space = model.action_space

    def _normalise(self, obs: np.ndarray) -> np.ndarray:
        if self.normalizer is None:
            return obs
        return np.asarray(self.normalizer.normalize_obs(obs), dtype=np.float32)

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """The actions for ``observation`` (one or a batch), normalised and frame-stacked as in training."""
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.ndim == 1
        batch = self._normalise(obs.reshape(1, -1) if single else obs)
        k = self.frame_stack
        if k > 1:
            inputs, state = stack_frames(batch, state, episode_start, k)
        else:
            inputs = batch
        actions, _ = self.model.predict(inputs, deterministic=deterministic)
        actions = np.asarray(actions)
        return (actions[0] if single else actions), state


def load_policy(name_or_path: str | os.PathLike, config: EnvConfig | None = None,
                max_episode_steps: int | None = None, trust: bool = False,
                policy_kwargs: dict[str, Any] | None = None) -> Any:
    """A policy by name or path, ready to act on ``config``'s level.

    Parameters
    ----------
    name_or_path : str or os.PathLike
        A baseline's name (``BASELINES``, or ``const-<K>`` for any K); a user's controller
        class (``path/to/file.py:ClassName`` or ``package.module:ClassName``, built with
        ``policy_kwargs``: `agents.evaluation.user_code`); a Stable-Baselines3 model file
        (``.zip``; algorithm detected, wrapped as its sidecar's ``frame_stack`` and
        ``normalize`` say); a folder ``saddle-export`` wrote (run by
        `saddle_env.deploy.Controller`); or an RLlib checkpoint directory.
    config : EnvConfig, optional
        The level's configuration; default `EnvConfig`'s defaults.
    max_episode_steps : int, optional
        The episode length ``best-const`` is searched for (default: the search's own).
    trust : bool
        Load files with their pickles; default: as data (see `load_model`).
    policy_kwargs : dict, optional
        The arguments a controller class is built with.

    Returns
    -------
    object
        A policy with Stable-Baselines3's ``predict``.
    """
    config = EnvConfig() if config is None else config
    name = str(name_or_path)
    if name == "best-const" and max_episode_steps is not None:
        return best_const(config, max_episode_steps=max_episode_steps)
    if name in BASELINES:
        return BASELINES[name](config)
    const = parse_constant(name)
    if const is not None:
        return const(config)
    if is_controller_spec(name) and not Path(name).exists():
        return load_controller(name, config, policy_kwargs)
    if is_exported_folder(name):  # saddle-export's folder: run without torch, read as data
        from ..cli_args import require

        require("onnxruntime", "deploy", "an exported policy folder")
        from saddle_env.deploy import Controller

        return Controller.from_dir(name)
    if Path(name).is_dir():      # an RLlib checkpoint directory (or an RLlib run folder)
        from .rllib_policy import latest_checkpoint
        from .rllib_policy import load_policy as load_rllib_policy

        if latest_checkpoint(name) is not None:
            return load_rllib_policy(name, trust=trust)
    path = Path(name if name.endswith(".zip") or Path(name).exists() else name + ".zip")
    if path.is_file():
        return _load_with_pipeline(path, config, trust)
    raise ValueError(f"unknown policy {name!r}: not a baseline ({', '.join(BASELINES)}, "
                     f"const-<K>), no model file {str(path)!r} and no controller class "
                     "(path/to/file.py:ClassName or package.module:ClassName)")


def _load_with_pipeline(path: Path, config: EnvConfig, trust: bool = False) -> Any:
    side = model_sidecar(path) or {}
    frame_stack = side.get("frame_stack") or 1
    if isinstance(frame_stack, bool) or not isinstance(frame_stack, int) or \
            not 1 <= frame_stack <= 64:
        raise ValueError(f"{path}: sidecar frame_stack must be an integer in [1, 64], "
                         f"got {frame_stack!r}")
    if not isinstance(side.get("normalize", False), bool):
        raise ValueError(f"{path}: sidecar normalize must be true or false, "
                         f"got {side['normalize']!r}")
    model = load_model(path, config, frame_stack, trust=trust)
    normalizer = _normalizer(path, config, trust) if side.get("normalize") else None
    if frame_stack == 1 and normalizer is None:
        return model
    return WrappedModel(model, config, frame_stack, normalizer)


def _normalizer(path: Path, config: EnvConfig, trust: bool) -> Any:
    """The saved normalisation statistics of a model: the JSON file, or (with trust only)
    the pickle older runs wrote."""
    stats = vecnormalize_path(path)
    if stats.is_file():
        return ObservationNormalizer(read_normalizer(stats, observation_space(config).shape[0]))
    pickled = vecnormalize_path(path, pickled=True)
    if not pickled.is_file():
        raise ValueError(f"{path}: its sidecar says observations were normalised in "
                         f"training, but the statistics file {stats.name} is missing")
    if not trust:
        raise untrusted(pickled, "normaliser statistics stored as a pickle")
    import pickle

    with open(pickled, "rb") as fh:
        normalizer = pickle.load(fh)  # noqa: S301 — the user passed trust=True
    normalizer.training = False
    return normalizer


__all__ = ["BASELINES", "SB3_ALGOS", "UntrustedFileError", "WrappedModel", "is_exported_folder",
           "load_model", "load_policy", "model_sidecar", "policy_sidecar", "sb3_algorithm", "vecnormalize_path"]
