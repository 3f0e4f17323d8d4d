"""The one thing the build does beyond pyproject.toml: compile the kernels of a first
`env.step` and a first `simulate` ahead of time (`saddle_env.aot_build`), so that a fresh
install starts in about a second instead of compiling with numba for 10-20 s
(docs/coldstart.md).

The build runs in a separate process with a time limit and never fails the install: without
a C compiler, or if anything in it goes wrong, the package installs without it and numba's
JIT compiles on first use, as it always did. ``SADDLE_ENV_AOT=0`` at install time skips it.
"""
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from setuptools import Command, setup
from setuptools.command.build import build
from setuptools.dist import Distribution

BUILD_TIMEOUT_S = 1800


class build_aot(Command):
    description = "compile the first env.step's and simulate's kernels ahead of time"
    user_options: list = []

    def initialize_options(self):
        self.build_lib = None
        self.editable_mode = False  # set by setuptools for `pip install -e`
        self._outputs: list[str] = []

    def finalize_options(self):
        self.set_undefined_options("build", ("build_lib", "build_lib"))

    def run(self):
        if os.environ.get("SADDLE_ENV_AOT", "1") in ("0", ""):
            print("saddle-env: ahead-of-time kernels skipped (SADDLE_ENV_AOT=0)")
            return
        # An editable install imports the source tree; any other install, the build folder
        # that build_py has filled: build next to the sources that will be imported.
        root = Path(__file__).resolve().parent if self.editable_mode else Path(self.build_lib)
        env = dict(os.environ)
        if not self.editable_mode:  # keep numba's JIT cache of the build out of the wheel
            env["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="saddle-env-build-")
        cmd = [sys.executable, "-m", "saddle_env.precompile", "--aot"]
        print(f"saddle-env: {' '.join(cmd[1:])} (about a minute on 2 cores)", flush=True)
        try:
            done = subprocess.run(cmd, cwd=root, env=env, timeout=BUILD_TIMEOUT_S).returncode == 0
        except (OSError, subprocess.SubprocessError) as exc:
            print(f"saddle-env: ahead-of-time build not run ({exc})")
            done = False
        if not done:
            print("saddle-env: installing without ahead-of-time kernels: numba compiles them "
                  "on first use (python -m saddle_env.precompile --aot retries)")
            return
        if not self.editable_mode:
            self._outputs = [str(p) for p in (root / "saddle_env" / "_aot").iterdir()]

    def get_outputs(self):
        return self._outputs

    def get_output_mapping(self):
        return {}


class build_with_aot(build):
    sub_commands = [*build.sub_commands, ("build_aot", None)]


class BinaryDistribution(Distribution):
    """A wheel holding the compiled modules is for this platform and Python only."""

    def has_ext_modules(self):
        return True


setup(cmdclass={"build": build_with_aot, "build_aot": build_aot},
      distclass=BinaryDistribution)
