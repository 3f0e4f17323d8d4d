"""Training recipes: the hyperparameter files every training back end reads.

A recipe is an entry keyed by environment id in a zoo-format YAML file
(``agents/hyperparams/<algo>.yml``, rl-baselines3-zoo's layout); a level with no entry of
its own uses the ``SaddleTrap-v0`` entry (a note says so). Besides the algorithm's own
arguments, the zoo keys in `ZOO_ONLY_KEYS` are read here or by the back ends:
``n_envs``, ``n_timesteps``, ``policy``, ``noise_type``/``noise_std``, ``normalize``,
``frame_stack``, ``warm_start``, ``imitation``, ``train_episode_steps``,
``reward_shaping``, and the model selection's ``eval_freq`` and ``eval_episodes`` (the
command line's ``--eval-freq`` and ``--eval-episodes`` win). ``env_wrapper`` and ``callback`` are
rejected (no class is importable by name here), and strings such as ``policy_kwargs`` are parsed as
data (`agents.evaluation.literal_kwargs`), never evaluated.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from saddle_env.envs import ENV_ID

from ..evaluation.literal_kwargs import parse_kwargs_string
from ..paths import HYPERPARAMS_DIR

# Keys of the zoo format that are not constructor arguments of the algorithm.
ZOO_ONLY_KEYS = {"n_envs", "n_timesteps", "policy", "noise_type", "noise_std", "normalize",
                 "env_wrapper", "frame_stack", "callback", "warm_start", "imitation",
                 "train_episode_steps", "reward_shaping", "eval_freq", "eval_episodes"}
# Zoo keys no back end can honour: an error, never silently dropped.
REJECTED_KEYS = {"env_wrapper": "environment wrappers by class name are not supported; wrap "
                                "in code (agents.training.backends.sb3.make_vec_env) instead",
                 "callback": "callbacks by class name are not supported"}


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
    read as data by `agents.evaluation.literal_kwargs` (literals and allowed class names; nothing is
    evaluated or called)."""
    if value is None:
        return {}
    if isinstance(value, dict):
        return value
    if not isinstance(value, str):
        raise ValueError(f"policy_kwargs must be a mapping or a string, got {value!r}")
    return parse_kwargs_string(value, "policy_kwargs")


def wrapper_settings(hyper: dict[str, Any]) -> tuple[dict[str, Any] | None, int]:
    """(VecNormalize keywords or None, frames to stack) from the zoo keys ``normalize`` and
    ``frame_stack``; ValueError for a value the zoo would not accept either."""
    norm = hyper.get("normalize")
    norm_kw: dict[str, Any] | None
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


__all__ = ["HYPERPARAMS_DIR", "REJECTED_KEYS", "ZOO_ONLY_KEYS", "load_hyperparams",
           "parse_policy_kwargs", "train_episode_steps", "wrapper_settings"]
