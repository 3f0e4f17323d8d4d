"""Compile, beside a test session, kernels its tests need later: `conftest.py` starts this
in a second process when the session is large, so that a cold run (CI's fresh clone) uses the
second core for compiling while the first runs tests. What this compiles is written to
numba's on-disk cache, which the test process then loads instead of compiling; anything the
test process reaches first it compiles itself, as without this helper.

The order follows the suite's (a cold run, docs/coldstart.md): the tests compile the full
kernels' first step and `mpc`'s prediction at once (too soon to help), then the vector env's
steps, the batch integrator and the clairvoyant reference, and much later each level's own
per-scene copies and `mpc`'s for two sets of contact models.
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


def main() -> None:
    quiet = {"log": lambda line: None}
    precompile(["vector:SaddleTrap-v0", "batch"], **quiet)
    _clairvoyant()
    os.environ["SADDLE_ENV_FULL_KERNELS"] = "0"    # as the tests of the per-scene copies
    precompile(["SaddleTrap-v0", "SaddleTrap-Storm-v0", "SaddleTrap-Slippery-v0"], **quiet)
    _mpc("SaddleTrap-v0")
    _mpc("SaddleTrap-Storm-v0")


if __name__ == "__main__":
    main()
