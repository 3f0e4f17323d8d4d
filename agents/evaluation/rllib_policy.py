"""RLlib checkpoints as policies: the policy network (RLModule) of a checkpoint that
``train.py --backend rllib`` wrote, acting deterministically with SB3's ``predict``
signature, for ``saddle-eval`` and `agents.evaluation.policies.load_policy`.

Importing this module does not import ray; loading a checkpoint needs ray and torch
installed (the ``[rllib]`` extra) but no running Ray. Training is `agents.training.backends.rllib`.

RLlib's own checkpoint files are pickles (the module's class and constructor arguments, its
state). By default they are not read: the network is rebuilt from RLlib's default module
class for the algorithm the sidecar names, the sidecar's ``module`` config (checked) and the
spaces of the level it was trained on, and its weights come from `WEIGHTS_FILE` through
``torch.load(weights_only=True)``. ``trust=True`` (``--trust-model``) uses RLlib's loader,
for checkpoints without that file.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..cli_args import MissingExtra, install_hint, missing

SIDECAR = "saddle_env.json"          # in every checkpoint directory train.py writes
CHECKPOINT_MARKER = "rllib_checkpoint.json"  # RLlib writes it in every checkpoint directory
MODULE_PATH = ("learner_group", "learner", "rl_module", "default_policy")
WEIGHTS_FILE = "policy_weights.pt"   # the module's state dict, plain tensors (train.py writes it)
_ACTIVATIONS = ("tanh", "relu", "swish", "silu", "elu", "linear")


def is_checkpoint(path: str | os.PathLike) -> bool:
    """Whether ``path`` is an RLlib checkpoint directory (no ray import)."""
    p = Path(path)
    return p.is_dir() and (p / CHECKPOINT_MARKER).is_file()


def latest_checkpoint(path: str | os.PathLike) -> Path | None:
    """``path`` if it is a checkpoint; for a run folder its ``final/`` checkpoint, else the
    checkpoint with the most steps in ``checkpoints/``; None if there is none."""
    p = Path(path)
    if is_checkpoint(p):
        return p
    if is_checkpoint(p / "final"):
        return p / "final"
    found = [c for c in (p / "checkpoints").glob("*") if is_checkpoint(c)]
    if not found:
        return None
    return max(found, key=lambda c: (checkpoint_sidecar(c) or {}).get("steps", -1))


def checkpoint_sidecar(path: str | os.PathLike) -> dict[str, Any] | None:
    """The sidecar of the RLlib checkpoint at ``path``, or None if it has none or it is unreadable."""
    try:
        data = json.loads((Path(path) / SIDECAR).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


class RllibPolicy:
    """A checkpoint's policy network (RLModule) acting deterministically, with SB3's
    ``predict`` signature, as `agents.control.rollout` expects. Needs ray (and torch) installed,
    not a running Ray: only the module is loaded, not the algorithm."""

    row_independent = False

    def __init__(self, path: str | os.PathLike, trust: bool = False):
        import gymnasium as gym
        import torch

        self.path = Path(path)
        self.sidecar = checkpoint_sidecar(self.path) or {}
        self.module = _module_from_rllib(self.path) if trust else _module_as_data(self.path,
                                                                                 self.sidecar)
        self.module.eval()
        self._torch = torch
        self.algo_name = f"RLlib {str(self.sidecar.get('algo', '')).upper()}".strip()
        self.observation_space = self.module.observation_space
        self.action_space = self.module.action_space or gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self._dist = self.module.get_inference_action_dist_cls()

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """The actions of the checkpoint's module for ``observation`` (one or a batch)."""
        torch = self._torch
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.ndim == 1
        batch = torch.from_numpy(obs.reshape(1, -1) if single else obs)
        with torch.no_grad():
            out = self.module.forward_inference({"obs": batch})
            dist = self._dist.from_logits(out["action_dist_inputs"])
            if deterministic:
                dist = dist.to_deterministic()
            actions = dist.sample().numpy()
        low, high = self.action_space.low, self.action_space.high
        actions = np.clip(actions, low, high).astype(np.float32)   # as RLlib's env runner
        return (actions[0] if single else actions), state


def _module_from_rllib(path: Path) -> Any:
    """RLlib's own loader: unpickles the module's class, arguments and state."""
    from ray.rllib.core.rl_module.rl_module import RLModule

    module_dir = path.resolve().joinpath(*MODULE_PATH)   # RLlib wants it absolute
    if not module_dir.is_dir():
        raise ValueError(f"{path}: no policy module in this RLlib checkpoint "
                         f"(expected {'/'.join(MODULE_PATH)})")
    return RLModule.from_checkpoint(str(module_dir))


def _module_config(side: dict[str, Any], path: Path) -> dict[str, Any]:
    """The sidecar's ``module`` config, checked: layer widths and an activation by name."""
    from .model_files import MAX_LAYER_WIDTH, MAX_LAYERS

    cfg = side.get("module")
    if not isinstance(cfg, dict) or set(cfg) - {"fcnet_hiddens", "fcnet_activation",
                                                 "vf_share_layers"}:
        raise ValueError(f"{path}: sidecar 'module' must be a dict of fcnet_hiddens, "
                         f"fcnet_activation and vf_share_layers, got {cfg!r}")
    hidden = cfg.get("fcnet_hiddens")
    if not isinstance(hidden, list) or not 1 <= len(hidden) <= MAX_LAYERS or not all(
            isinstance(w, int) and not isinstance(w, bool) and 1 <= w <= MAX_LAYER_WIDTH
            for w in hidden):
        raise ValueError(f"{path}: fcnet_hiddens must be 1 to {MAX_LAYERS} widths in "
                         f"[1, {MAX_LAYER_WIDTH}], got {hidden!r}")
    if cfg.get("fcnet_activation", "tanh") not in _ACTIVATIONS:
        raise ValueError(f"{path}: fcnet_activation must be one of {_ACTIVATIONS}, "
                         f"got {cfg.get('fcnet_activation')!r}")
    if not isinstance(cfg.get("vf_share_layers", False), bool):
        raise ValueError(f"{path}: vf_share_layers must be true or false")
    return dict(cfg)


def _module_as_data(path: Path, side: dict[str, Any]) -> Any:
    """The module rebuilt from RLlib's default class for the sidecar's algorithm and its
    weights file, nothing unpickled."""
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec

    from saddle_env.envs.observation import observation_space
    from saddle_env.envs.saddle_trap import action_space

    from ..cli_args import resolve_env
    from .model_files import load_tensors, untrusted

    weights = path / WEIGHTS_FILE
    if not weights.is_file() or "module" not in side:
        raise untrusted(path, f"this RLlib checkpoint has no {WEIGHTS_FILE} and sidecar "
                              f"'module' config, and RLlib's own files are pickles")
    from ray.rllib.algorithms.algorithm_config import AlgorithmConfig
    from ray.rllib.core.rl_module.torch import TorchRLModule

    config_class: type[AlgorithmConfig]
    module_class: type[TorchRLModule]
    algo = str(side.get("algo", "")).lower()
    if algo == "ppo":
        from ray.rllib.algorithms.ppo import PPOConfig
        from ray.rllib.algorithms.ppo.torch.default_ppo_torch_rl_module import (
            DefaultPPOTorchRLModule,
        )
        config_class, module_class = PPOConfig, DefaultPPOTorchRLModule
    elif algo == "sac":
        from ray.rllib.algorithms.sac import SACConfig
        from ray.rllib.algorithms.sac.torch.default_sac_torch_rl_module import (
            DefaultSACTorchRLModule,
        )
        config_class, module_class = SACConfig, DefaultSACTorchRLModule
    else:
        raise ValueError(f"{path}: sidecar algo must be 'ppo' or 'sac', got {algo!r}")
    env_kwargs = side.get("env_kwargs") or {}
    if not isinstance(env_kwargs, dict):
        raise ValueError(f"{path}: sidecar env_kwargs must be a dict, got {env_kwargs!r}")
    _, config = resolve_env(str(side.get("env_id", "")) or None, env_kwargs)
    # The algorithm's config adds what its module needs beyond the sidecar's keys (SAC's
    # twin_q), exactly as training built it (agents.training.backends.rllib.build_config).
    model_config = config_class().rl_module(
        model_config=DefaultModelConfig(**_module_config(side, path))).model_config
    spec = RLModuleSpec(module_class=module_class, observation_space=observation_space(config),
                        action_space=action_space(), inference_only=False,
                        model_config=model_config)
    module = spec.build()
    if not isinstance(module, TorchRLModule):  # RLModuleSpec.build is typed as any RLModule
        raise TypeError(f"RLlib built a {type(module).__name__}, not the torch module "
                        f"{module_class.__name__}")
    state = load_tensors(weights, str(weights))
    if isinstance(state, dict):
        # The learner's module also holds target networks (SAC's target_*), which a policy
        # does not use; everything else must match exactly.
        extra = [k for k in state if k not in module.state_dict()]
        if extra and not all(str(k).startswith("target_") for k in extra):
            raise ValueError(f"{weights}: tensors {extra[:3]} do not belong to the sidecar's "
                             f"{algo} module")
        state = {k: v for k, v in state.items() if k not in extra}
    try:
        module.load_state_dict(state, strict=True)
    except (RuntimeError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{weights}: the weights do not fit the sidecar's {algo} module "
                         f"({str(exc).splitlines()[0][:200]})") from None
    return module


def load_policy(path: str | os.PathLike, trust: bool = False) -> RllibPolicy:
    """The policy of an RLlib checkpoint directory (or of a run folder's latest one), read
    as data unless ``trust`` (see the module docstring)."""
    ckpt = latest_checkpoint(path)
    if ckpt is None:
        raise ValueError(f"{path}: not an RLlib checkpoint directory or run folder")
    lacking = missing(("ray", "torch"))
    if lacking:
        raise MissingExtra(f"evaluating an RLlib checkpoint needs {', '.join(lacking)}, not "
                           f"installed: {install_hint('rllib')}")
    return RllibPolicy(ckpt, trust=trust)



__all__ = ["CHECKPOINT_MARKER", "MODULE_PATH", "SIDECAR", "WEIGHTS_FILE", "RllibPolicy", "checkpoint_sidecar",
           "is_checkpoint", "latest_checkpoint", "load_policy"]
