"""Warm starts: begin training from a policy that already does what a baseline does.

``warm_start: best-const`` (a hyperparameter key) sets the bias of the policy's action head so
that, before any update, the mean action is the level's best constant speed (target-speed
action mode: a constant action is a constant speed; voltage mode: the constant voltage whose
steady speed it is). The untrained network's other weights
are small (SB3 initialises the action head with gain 0.01), so the starting policy is the
best constant plus exploration noise, and learning starts from the baseline it has to beat
rather than from a random speed that loses most balls.

``warm_start: mpc`` first teaches the network to do what ``mpc`` does, by imitation
(`agents.training.imitation`; its settings under the recipe's ``imitation`` key), so that learning
starts from the strongest baseline. At evaluation time the policy is the network alone
either way: the warm start only chooses where training begins.
"""

from __future__ import annotations

import math
from typing import Any

from saddle_env.envs import EnvConfig

WARM_STARTS = ("best-const", "mpc")


def check_warm_start(how: Any) -> str:
    """``how`` if it names a warm start; a ValueError listing them otherwise."""
    if how not in WARM_STARTS:
        raise ValueError(f"warm_start must be one of {list(WARM_STARTS)}, got {how!r}")
    return how


def warm_start(model: Any, config: EnvConfig, how: str, max_episode_steps: int, seed: int,
               imitation: Any = None) -> dict[str, Any]:
    """Apply the warm start ``how`` to the new SB3 ``model``; returns what was done (the
    best-const action, or the imitation rounds) for the run folder."""
    if check_warm_start(how) == "mpc":
        from .imitation import ImitationSettings, imitate

        settings = ImitationSettings.from_hyper(imitation)
        return {"warm_start": how, "imitation": vars(settings),
                "rounds": imitate(model, config, max_episode_steps, seed, settings)}
    action = warm_start_action(config, how, max_episode_steps)
    apply_warm_start(model, action)
    return {"warm_start": how, "action": action}


def warm_start_action(config: EnvConfig, how: str, max_episode_steps: int) -> float:
    """The action the warm start ``how`` (best-const) makes the untrained policy's mean."""
    if check_warm_start(how) != "best-const":
        raise ValueError(f"warm_start {how!r} does not set a constant action")
    if config.action_mode not in ("target", "voltage"):
        raise ValueError("warm_start 'best-const' needs action_mode='target' or 'voltage' (in "
                         "acceleration mode a constant action is a constant acceleration, not a "
                         "speed)")
    from ..control.best_constant import best_constant

    omega = float(best_constant(config, max_episode_steps=max_episode_steps)["omega"])
    # A constant voltage V holds the steady speed K·V (the search's speeds are such steady
    # speeds, up to K·V_max).
    top = config.motor_gain * config.voltage_max if config.action_mode == "voltage" \
        else config.omega_max
    return 2.0 * omega / top - 1.0


def apply_warm_start(model: Any, action: float) -> None:
    """Set the mean action of an SB3 on-policy model (PPO, A2C) to ``action`` in [-1, 1]."""
    import torch

    net = getattr(getattr(model, "policy", None), "action_net", None)
    if net is None or not hasattr(net, "bias"):
        raise ValueError(f"warm_start works for PPO and A2C (a Gaussian policy with an action "
                         f"head), not for {type(model).__name__}")
    if not (math.isfinite(action) and -1.0 <= action <= 1.0):
        raise ValueError(f"warm-start action must lie in [-1, 1], got {action}")
    with torch.no_grad():
        net.bias.fill_(action)
