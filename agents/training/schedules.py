"""Schedules in a recipe, rl-baselines3-zoo style: ``learning_rate: lin_3e-4`` (or
``clip_range: lin_0.2``) decays the value linearly from the given number at the start of
training to 0 at the end of the budget (SB3 calls a schedule with the progress remaining,
1 → 0).

Why: PPO at a constant step keeps moving after its curve has flattened, and its validation
scores then wander by more than the evaluation's noise (docs/training_profile.md); a step
that shrinks to nothing makes the last snapshots of a run its steadiest.

A value that is not a string is returned as it is; any other string is an error (nothing
is evaluated).
"""

from __future__ import annotations

import math
from typing import Any

SCHEDULED_KEYS = ("learning_rate", "clip_range")


def parse_schedule(key: str, value: Any) -> Any:
    """``value`` itself, or for ``"lin_<number>"`` SB3's linear schedule from that number
    to 0; ValueError for any other string or a number that is not positive and finite."""
    if not isinstance(value, str):
        return value
    if not value.startswith("lin_"):
        raise ValueError(f"{key}: a schedule must be written lin_<number>, got {value!r}")
    try:
        start = float(value[4:])
    except ValueError:
        raise ValueError(f"{key}: {value!r} is not lin_<number>") from None
    if not math.isfinite(start) or start <= 0:
        raise ValueError(f"{key}: the start of {value!r} must be a positive number")
    from stable_baselines3.common.utils import LinearSchedule

    return LinearSchedule(start, 0.0, 1.0)


def with_schedules(kwargs: dict[str, Any]) -> dict[str, Any]:
    """The algorithm's keyword arguments with every ``lin_`` string made a schedule."""
    out = dict(kwargs)
    for key in SCHEDULED_KEYS:
        if key in out:
            out[key] = parse_schedule(key, out[key])
    return out


__all__ = ["SCHEDULED_KEYS", "parse_schedule", "with_schedules"]
