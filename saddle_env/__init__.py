"""saddle-env: a rigid ball on a rotating saddle — physics, simulator and Gymnasium environment."""

from .integrators import METHODS, Method
from .omega import OmegaProfile
from .scene import CONTACT_MODELS, Scene
from .simulate import (DEFAULT_METHOD, DEFAULT_RTOL, BatchResult, Event, SimulationError,
                       Trajectory, initial_state, simulate, simulate_batch)

__all__ = ["CONTACT_MODELS", "DEFAULT_METHOD", "DEFAULT_RTOL", "METHODS", "BatchResult", "Event",
           "Method", "OmegaProfile", "Scene", "SimulationError", "Trajectory", "initial_state",
           "simulate", "simulate_batch"]
__version__ = "0.1.0"

from .envs import register as _register_envs  # noqa: E402

_register_envs()
