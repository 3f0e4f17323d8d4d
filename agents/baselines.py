"""Deprecated: the names this module held now live in one-job modules; import them from there.

| names | module |
|---|---|
| ``Controller``, ``ConstantSpeed``, ``critical_speed``, ``constant_multiple``, ``mass_point``, ``CONST_MULTIPLES``, ``ZeroAction``, ``UniformRandom`` | `agents.controllers` |
| ``search_best_constant``, ``best_constant``, ``best_const``, ``CACHE_FILE`` | `agents.best_constant` |
| ``ModelPredictiveController`` | `agents.mpc` |
| ``BASELINES``, ``load_policy``, ``load_model``, ``model_sidecar``, ``sb3_algorithm`` | `agents.policies` |

Importing this module still works (with a `DeprecationWarning`) and re-exports every name.
Assigning to its attributes (``baselines.CACHE_FILE = ...``) no longer reaches the code that
uses them: patch `agents.best_constant` instead.
"""

from __future__ import annotations

import warnings

from .best_constant import (
                            CACHE_FILE,
                            SEARCH_EPISODES,
                            SEARCH_SEED,
                            USER_CACHE_FILE,
                            best_const,
                            best_constant,
                            search_best_constant,
)
from .controllers import (
                            CONST_MULTIPLES,
                            ConstantSpeed,
                            Controller,
                            UniformRandom,
                            ZeroAction,
                            constant_multiple,
                            critical_speed,
                            mass_point,
)
from .mpc import ModelPredictiveController
from .policies import BASELINES, SB3_ALGOS, load_model, load_policy, model_sidecar, sb3_algorithm

warnings.warn("agents.baselines is deprecated: import from agents.controllers, "
              "agents.best_constant, agents.mpc or agents.policies", DeprecationWarning,
              stacklevel=2)

__all__ = ["BASELINES", "CACHE_FILE", "CONST_MULTIPLES", "SB3_ALGOS", "SEARCH_EPISODES",
           "SEARCH_SEED", "USER_CACHE_FILE", "ConstantSpeed", "Controller",
           "ModelPredictiveController", "UniformRandom", "ZeroAction", "best_const",
           "best_constant", "constant_multiple", "critical_speed", "load_model", "load_policy",
           "mass_point", "model_sidecar", "sb3_algorithm", "search_best_constant"]
