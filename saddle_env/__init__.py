"""saddle-env: a rigid ball on a rotating saddle — physics, simulator and Gymnasium environment."""

from . import _cache, _notice

_cache.refresh()  # before any compiled function is loaded (see saddle_env/_cache.py)
_notice.install()  # a compile that takes more than a moment says so (saddle_env/_notice.py)

from .integrators import METHODS, Method  # noqa: E402
from .omega import OmegaProfile  # noqa: E402
from .prediction import Prediction, predict_batch  # noqa: E402
from .scene import CONTACT_MODELS, Scene  # noqa: E402
from .simulate import (DEFAULT_METHOD, DEFAULT_RTOL, BatchResult, Event,  # noqa: E402
                       SimulationError, Trajectory, initial_state, simulate, simulate_batch)

__all__ = ["CONTACT_MODELS", "DEFAULT_METHOD", "DEFAULT_RTOL", "LEVELS", "METHODS",
           "BatchResult", "Event", "Method", "OmegaProfile", "Prediction", "Scene",
           "SimulationError", "Trajectory", "initial_state", "predict_batch", "simulate",
           "simulate_batch"]
__version__ = "0.1.0"

from .envs import LEVELS  # noqa: E402
from .envs import register as _register_envs  # noqa: E402

_register_envs()
