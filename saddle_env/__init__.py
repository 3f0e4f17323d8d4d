"""saddle-env: a rigid ball on a rotating saddle — physics, simulator and Gymnasium environment."""

from . import _moved
from .compilation import cache as _cache
from .compilation import notice as _notice
from .compilation import threads as _threads  # noqa: F401  (numba's threading layer, set before any parallel step)

# Modules that moved (the compile machinery into `saddle_env.compilation`, its tools for the
# first call into `saddle_env.coldstart`, the atomic writer into `saddle_env.jobs`); the old
# names say where.
_moved.announce({
    # renamed by what they measure or hold; the kernels and the control step are public
    "saddle_env.bench": "saddle_env.workprecision",
    "saddle_env.envs.benchmark": "saddle_env.envs.throughput",
    "saddle_env.lifetimes.bench": "saddle_env.lifetimes.timing",
    "saddle_env._kernels": "saddle_env.kernels",
    "saddle_env.envs._step": "saddle_env.envs.control_step",
    "saddle_env.compile_profile": "saddle_env.coldstart.profile",
    "saddle_env.precompile": "saddle_env.coldstart.precompile",
    "saddle_env.aot_build": "saddle_env.coldstart.aot_build",
    "saddle_env.compilation.profile": "saddle_env.coldstart.profile",
    "saddle_env.compilation.precompile": "saddle_env.coldstart.precompile",
    "saddle_env.compilation.aot_build": "saddle_env.coldstart.aot_build",
    "saddle_env.analysis": "saddle_env.reproduce.precession",
    "saddle_env.files": "saddle_env.jobs.files",
})

_cache.refresh()  # before any compiled function is loaded (see saddle_env/compilation/cache.py)
_notice.install()  # a compile that takes more than a moment says so (saddle_env/compilation/notice.py)

from .integrators import METHODS, Method  # noqa: E402
from .omega import OmegaProfile  # noqa: E402
from .prediction import Prediction, predict_batch  # noqa: E402
from .scene import CONTACT_MODELS, Scene  # noqa: E402
from .simulate import (  # noqa: E402
    DEFAULT_METHOD,
    DEFAULT_RTOL,
    BatchResult,
    Event,
    SimulationError,
    Trajectory,
    initial_state,
    simulate,
    simulate_batch,
)

__all__ = ["CONTACT_MODELS", "DEFAULT_METHOD", "DEFAULT_RTOL", "LEVELS", "METHODS",
           "BatchResult", "Event", "Method", "OmegaProfile", "Prediction", "Scene",
           "SimulationError", "Trajectory", "initial_state", "predict_batch", "simulate",
           "simulate_batch"]
__version__ = "0.1.0"

from .envs import LEVELS  # noqa: E402
from .envs import register as _register_envs  # noqa: E402

_register_envs()
