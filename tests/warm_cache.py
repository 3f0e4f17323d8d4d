"""Compile, beside a test session, kernels its tests need later: `conftest.py` starts this
in a second process when the session is large, so that a cold run (CI's fresh clone) uses the
second core for compiling while the first runs tests. What this compiles is written to
numba's on-disk cache, which the test process then loads instead of compiling; anything the
test process reaches first it compiles itself, as without this helper.

The suite runs each scene's own copy of the kernels (conftest.py), and the install's
ahead-of-time build holds the copies of the registered levels, of each contact model alone,
of a batch mixing a level's models and of the ion trap. What is left to compile is listed in
`JOBS`, in this order (a cold run with numba's compile events, docs/coldstart.md): small
kernels the first test files call from Python, the vector env's threaded step (numba's
``prange``, which no build holds; the clairvoyant's rollouts), an environment mixing
rolling and Coulomb balls (no level draws that mix), rolling resistance, the full kernels
that the tests of the copies compare them with, and Storm's threaded step. The tests that
need the big ones run last in a session with this helper, and wait for its job rather than
compile the same beside it (`conftest.WAIT_FOR_HELPER`).
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


def _small_kernels() -> None:
    """Kernels the suite's first files call from Python, a second or three each: `mpc`'s
    own (test_agents.py) and a trajectory's observables (test_air_drag.py)."""
    import gymnasium as gym

    import saddle_env as se
    from agents.control.mpc import ModelPredictiveController
    from saddle_env.envs import EnvConfig

    env = gym.make("SaddleTrap-v0")
    obs, _ = env.reset(seed=1)
    ModelPredictiveController(EnvConfig(), omega_ref=20.0).predict(obs)
    sc = se.Scene()
    _ = se.simulate(sc, se.initial_state(sc, 0.003, 0.002), 0.05, omega=20.0).N_over_mg


def _threaded_step(level_id: str) -> None:
    import gymnasium as gym

    from saddle_env.lockstep import LANES
    _steps(lambda: gym.make_vec(level_id, num_envs=2 * LANES))


def _rolling_and_coulomb_env() -> None:
    """An environment drawing rolling and Coulomb balls (test_coulomb.py)."""
    import gymnasium as gym

    _steps(lambda: gym.make("SaddleTrap-v0", contact_models=("rolling", "coulomb"),
                            mu_range=(0.05, 0.5)))


def _rolling_resistance() -> None:
    """Rolling resistance on rolling and Coulomb balls (test_coulomb.py)."""
    import gymnasium as gym

    import saddle_env as se

    for contact in ("rolling", "coulomb"):
        kw = {"mu": 0.05, "mu_static": 0.06} if contact == "coulomb" else {}
        sc = se.Scene(contact=contact, rolling_resistance=0.01, **kw)
        se.simulate(sc, se.initial_state(sc, 0.003, 0.002), 0.05, omega=20.0, dt_out=0.01)
    gym.make("SaddleTrap-v0", rolling_resistance=0.01).reset(seed=0)


def _full_kernels() -> None:
    """The full kernels (every contact model in one copy), which the tests of the copies
    compare them with: a level's single env, `simulate` and `predict_batch`."""
    import gymnasium as gym

    import saddle_env as se

    os.environ["SADDLE_ENV_FULL_KERNELS"] = "1"
    try:
        _steps(lambda: gym.make("SaddleTrap-v0"))
        sc = se.Scene()
        start = se.initial_state(sc, 0.003, 0.002)
        se.simulate(sc, start, 0.05, omega=20.0, dt_out=0.01)
        drives = np.zeros((2, 1, se.kernels.DRIVE_WIDTH))
        drives[:, :, 0] = 20.0
        se.predict_batch(sc.model_code, np.repeat(sc.params()[None], 2, 0),
                         np.repeat(start[None], 2, 0), drives, np.full((2, 1), 0.05), 0.01)
    finally:
        os.environ["SADDLE_ENV_FULL_KERNELS"] = "0"


# What this compiles, in order, by the name `conftest.py` waits for: the test files that
# need a job wait until it is done (`conftest.WAIT_FOR_HELPER`) rather than compile the same
# kernels beside it.
JOBS = {
    "small kernels": _small_kernels,
    "threaded step": lambda: _threaded_step("SaddleTrap-v0"),
    "rolling and coulomb env": _rolling_and_coulomb_env,
    "rolling resistance": _rolling_resistance,
    "full kernels": _full_kernels,
    "storm threaded step": lambda: _threaded_step("SaddleTrap-Storm-v0"),
}


def main(done_file: str | None) -> None:
    """Run every job in order; after each, append its name to ``done_file`` (if given)."""
    # below the tests in the CPU's queue: they run threads of their own on both cores
    os.nice(10)
    for name, job in JOBS.items():
        try:
            job()
        except Exception:   # noqa: BLE001 - a helper's failure only costs the tests time
            pass
        if done_file:
            with open(done_file, "a") as f:
                f.write(name + "\n")


if __name__ == "__main__":
    import sys
    main(sys.argv[1] if len(sys.argv) > 1 else None)
