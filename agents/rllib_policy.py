"""RLlib checkpoints as policies: the policy network (RLModule) of a checkpoint that
``train.py --backend rllib`` wrote, acting deterministically with SB3's ``predict``
signature, for ``saddle-eval`` and `agents.policies.load_policy`.

Importing this module does not import ray; loading a checkpoint needs ray and torch
installed (the ``[rllib]`` extra) but no running Ray. Training is `agents.rllib_backend`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from .cli_args import MissingExtra, install_hint, missing

SIDECAR = "saddle_env.json"          # in every checkpoint directory train.py writes
CHECKPOINT_MARKER = "rllib_checkpoint.json"  # RLlib writes it in every checkpoint directory
MODULE_PATH = ("learner_group", "learner", "rl_module", "default_policy")


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
    try:
        data = json.loads((Path(path) / SIDECAR).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


class RllibPolicy:
    """A checkpoint's policy network (RLModule) acting deterministically, with SB3's
    ``predict`` signature, as `agents.rollout` expects. Needs ray (and torch) installed,
    not a running Ray: only the module is loaded, not the algorithm."""

    row_independent = False

    def __init__(self, path: str | os.PathLike):
        import gymnasium as gym
        import torch
        from ray.rllib.core.rl_module.rl_module import RLModule

        self.path = Path(path)
        module_dir = self.path.resolve().joinpath(*MODULE_PATH)   # RLlib wants it absolute
        if not module_dir.is_dir():
            raise ValueError(f"{path}: no policy module in this RLlib checkpoint "
                             f"(expected {'/'.join(MODULE_PATH)})")
        self.module = RLModule.from_checkpoint(str(module_dir))
        self.module.eval()
        self._torch = torch
        self.sidecar = checkpoint_sidecar(self.path) or {}
        self.algo_name = f"RLlib {str(self.sidecar.get('algo', '')).upper()}".strip()
        self.observation_space = self.module.observation_space
        self.action_space = self.module.action_space or gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self._dist = self.module.get_inference_action_dist_cls()

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
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


def load_policy(path: str | os.PathLike) -> RllibPolicy:
    """The policy of an RLlib checkpoint directory (or of a run folder's latest one)."""
    ckpt = latest_checkpoint(path)
    if ckpt is None:
        raise ValueError(f"{path}: not an RLlib checkpoint directory or run folder")
    lacking = missing(("ray", "torch"))
    if lacking:
        raise MissingExtra(f"evaluating an RLlib checkpoint needs {', '.join(lacking)}, not "
                           f"installed: {install_hint('rllib')}")
    return RllibPolicy(ckpt)



__all__ = ["CHECKPOINT_MARKER", "MODULE_PATH", "SIDECAR", "RllibPolicy", "checkpoint_sidecar",
           "is_checkpoint", "latest_checkpoint", "load_policy"]
