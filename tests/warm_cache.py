"""Compile, beside a test session, kernels its tests need later: `conftest.py` starts this
in a second process when the session is large, so that a cold run (CI's fresh clone) uses the
second core for compiling while the first runs tests. What this compiles is written to
numba's on-disk cache, which the test process then loads instead of compiling; anything the
test process reaches first it compiles itself, as without this helper.

The order follows the suite's (a cold run, docs/coldstart.md): the tests compile what their
first file needs at once (too soon to help); `conftest.py` runs test_agents.py, whose first
test needs `mpc`'s look-ahead, last in a session with this helper. So this compiles `mpc`'s
look-ahead first (test_clairvoyant.py needs it within the first minute) and the clairvoyant
reference, then the per-scene copies of the look-ahead test_prediction.py compares, the vector
env's steps (test_training.py), the batch integrator, and last each level's per-scene copies
(nothing to compile where the install's ahead-of-time build is in use).
"""

import os

from saddle_env.precompile import precompile


def _clairvoyant() -> None:
    """A few steps of the clairvoyant reference on Gusty: its plans' rollouts and `mpc`'s
    look-ahead as test_clairvoyant.py runs them."""
    from agents.clairvoyant import ClairvoyantController
    from agents.rollout import policy_actor, run_episodes
    from saddle_env.envs import get_level

    config = get_level("SaddleTrap-Gusty-v0").config()
    act, independent = policy_actor(ClairvoyantController(config, max_rounds=2))
    run_episodes(config, act, [9_000_011], max_episode_steps=4, row_independent=independent)


def _mpc(level_id: str) -> None:
    """`mpc`'s look-ahead for one level's contact models (`saddle_env.prediction`)."""
    import gymnasium as gym

    from agents.policies import load_policy

    env = gym.make(level_id)
    obs, _ = env.reset(seed=0)
    policy = load_policy("mpc", env.unwrapped.config)
    for _ in range(3):
        action, _ = policy.predict(obs[None])
        obs, *_ = env.step(action[0])


def _prediction_copies() -> None:
    """The look-ahead's per-scene copies for a rolling ball and for rolling and slipping balls
    together, as test_prediction.py compiles them (`saddle_env.prediction.predict_batch`)."""
    import numpy as np

    from saddle_env import Scene, initial_state
    from saddle_env import _kernels as K
    from saddle_env.prediction import predict_batch

    scenes = [Scene(), Scene(contact="slipping")]
    Y0 = np.zeros((2, K.DYNAMICS_WIDTH))
    for r, scene in enumerate(scenes):
        state = initial_state(scene, 0.01, 0.0, start="lab-rest", omega=20.0)
        Y0[r, :len(state)] = state
    drives = np.zeros((2, 1, K.DRIVE_WIDTH))
    drives[..., K.DRIVE_W0] = 20.0
    for k in (1, 2):
        predict_batch(np.array([s.model_code for s in scenes[:k]]),
                      np.array([s.params() for s in scenes[:k]]), Y0[:k], drives[:k],
                      np.full((k, 1), 0.05), 0.05)


def main() -> None:
    quiet = {"log": lambda line: None}
    _mpc("SaddleTrap-v0")       # the full kernels' look-ahead (the suite runs the full kernels)
    _clairvoyant()
    os.environ["SADDLE_ENV_FULL_KERNELS"] = "0"    # as the tests of the per-scene copies
    _prediction_copies()
    os.environ["SADDLE_ENV_FULL_KERNELS"] = "1"
    precompile(["vector:SaddleTrap-v0", "batch"], **quiet)
    os.environ["SADDLE_ENV_FULL_KERNELS"] = "0"
    precompile(["SaddleTrap-v0", "SaddleTrap-Storm-v0", "SaddleTrap-Slippery-v0"], **quiet)


if __name__ == "__main__":
    main()
