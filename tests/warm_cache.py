"""Compile, beside a test session, kernels its tests need later: `conftest.py` starts this
in a second process when the session is large, so that a cold run (CI's fresh clone) uses the
second core for compiling while the first runs tests. What this compiles is written to
numba's on-disk cache, which the test process then loads instead of compiling; anything the
test process reaches first it compiles itself, as without this helper.

The suite runs each scene's own copy of the kernels (conftest.py), and the install's
ahead-of-time build holds the copies of the registered levels and of each contact model.
What is left to compile is listed here in about the order the suite first needs it (a cold
run with numba's compile events, docs/coldstart.md): the vector env's threaded step
(numba's ``prange``, which no build holds; the clairvoyant's rollouts), the copies of
scenes no level draws (a batch mixing contact models, rolling with Coulomb friction,
rolling resistance, a slipping-only environment), the full kernels that the tests of the
copies compare them with, and Storm's threaded step.
"""

import os

import numpy as np


def _steps(make, n_steps: int = 3) -> None:
    """Reset and a few steps of the environment ``make()`` returns (single or vector)."""
    env = make()
    env.reset(seed=0)
    for _ in range(n_steps):
        env.step(env.action_space.sample())
    env.close()


def _threaded_step(level_id: str) -> None:
    import gymnasium as gym

    from saddle_env.lockstep import LANES
    _steps(lambda: gym.make_vec(level_id, num_envs=2 * LANES))


def _mixed_batch() -> None:
    """`simulate_batch` over rolling, slipping and point balls (test_air_drag.py)."""
    import saddle_env as se

    scenes = [se.Scene(), se.Scene(contact="slipping"), se.Scene(contact="point")]
    states = [se.initial_state(sc, 0.003, 0.002) for sc in scenes]
    width = max(len(s) for s in states)
    padded = np.array([np.pad(s, (0, width - len(s))) for s in states])
    se.simulate_batch(scenes, padded, 0.05, omega=20.0, dt_out=0.01)


def _coulomb_and_resistance() -> None:
    """Rolling with Coulomb friction in the environment, and rolling resistance on rolling
    and Coulomb balls (test_coulomb.py)."""
    import gymnasium as gym

    import saddle_env as se

    _steps(lambda: gym.make("SaddleTrap-v0", contact_models=("rolling", "coulomb"),
                            mu_range=(0.05, 0.5)))
    for contact in ("rolling", "coulomb"):
        kw = {"mu": 0.05, "mu_static": 0.06} if contact == "coulomb" else {}
        sc = se.Scene(contact=contact, rolling_resistance=0.01, **kw)
        se.simulate(sc, se.initial_state(sc, 0.003, 0.002), 0.05, omega=20.0, dt_out=0.01)


def _slipping_env() -> None:
    """A slipping-only environment, single and vector (test_env.py)."""
    import gymnasium as gym

    from saddle_env.envs._step import MIN_BLOCK
    _steps(lambda: gym.make("SaddleTrap-v0", contact="slipping"))
    _steps(lambda: gym.make_vec("SaddleTrap-v0", num_envs=MIN_BLOCK, contact="slipping"))


def _full_kernels() -> None:
    """The full kernels (every contact model in one copy), which the tests of the copies
    compare them with: a level's single env and `simulate`."""
    import gymnasium as gym

    import saddle_env as se

    os.environ["SADDLE_ENV_FULL_KERNELS"] = "1"
    try:
        _steps(lambda: gym.make("SaddleTrap-v0"))
        sc = se.Scene()
        se.simulate(sc, se.initial_state(sc, 0.003, 0.002), 0.05, omega=20.0, dt_out=0.01)
    finally:
        os.environ["SADDLE_ENV_FULL_KERNELS"] = "0"


def main() -> None:
    for job in (lambda: _threaded_step("SaddleTrap-v0"), _mixed_batch,
                _coulomb_and_resistance, _full_kernels, _slipping_env,
                lambda: _threaded_step("SaddleTrap-Storm-v0")):
        try:
            job()
        except Exception:   # noqa: BLE001 - a helper's failure only costs the tests time
            pass


if __name__ == "__main__":
    main()
