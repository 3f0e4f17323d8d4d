"""Compile, beside a test session, kernels its tests need later: `conftest.py` starts this
in a second process when the session is large, so that a cold run (CI's fresh clone) uses the
second core for compiling while the first runs tests. What this compiles is written to
numba's on-disk cache, which the test process then loads instead of compiling; anything the
test process reaches first it compiles itself, as without this helper.

The order follows the suite's (a cold run, docs/coldstart.md): the tests compile the full
kernels' first step and `mpc`'s prediction at once (too soon to help), then the vector env's
steps and the batch integrator, and much later each level's own per-scene copies.
"""

import os

from saddle_env.precompile import precompile


def main() -> None:
    precompile(["vector:SaddleTrap-v0", "batch"], log=lambda line: None)
    os.environ["SADDLE_ENV_FULL_KERNELS"] = "0"    # as the tests of the per-scene copies
    precompile(["SaddleTrap-v0", "SaddleTrap-Storm-v0", "SaddleTrap-Slippery-v0"],
               log=lambda line: None)


if __name__ == "__main__":
    main()
