"""The one thing the build does beyond pyproject.toml: compile the kernels of a first
`env.step` and a first `simulate` ahead of time (`saddle_env.coldstart.aot_build`), so that a
fresh install starts in about a second instead of compiling with numba for 10-20 s
(docs/coldstart.md).

The build runs in a separate process with a time limit and never fails the install: without
a C compiler, or if anything in it goes wrong, the package installs without it and numba's
JIT compiles on first use, as it always did. ``SADDLE_ENV_AOT=0`` at install time skips it.
A wheel's build is compiled for the x86-64-v3 level, so that it serves other CPU models, and
where the building machine has AVX-512 once more for x86-64-v4, which CPUs with AVX-512 run;
an editable install's for the installing machine's CPU (``SADDLE_ENV_AOT_CPU`` chooses:
`saddle_env.compilation.aot`).
"""
import os
import shutil
import signal
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
        # An editable install imports the source tree; any other install, the build folder
        # that build_py has filled: build next to the sources that will be imported.
        root = Path(__file__).resolve().parent if self.editable_mode else Path(self.build_lib)
        out = root / "saddle_env" / "_aot"
        shutil.rmtree(out, ignore_errors=True)  # an earlier build's: never ship it instead
        self._record(False)  # until a build has succeeded
        if not aot_enabled():
            print("saddle-env: ahead-of-time kernels skipped (SADDLE_ENV_AOT=0)")
            return
        with tempfile.TemporaryDirectory(prefix="saddle-env-build-") as cache:
            env = dict(os.environ)
            if self.editable_mode:
                # an editable install's build runs only where it is made: this CPU model's
                # own code (AVX-512 where it has it), not the wheel's x86-64-v3 level
                env.setdefault("SADDLE_ENV_AOT_CPU", "host")
            else:  # nothing but the modules goes into the wheel
                env.update(NUMBA_CACHE_DIR=cache, PYTHONDONTWRITEBYTECODE="1")
            done = _run_build(root, env)
        if not self.editable_mode:
            for junk in list((root / "saddle_env").rglob("__pycache__")):
                shutil.rmtree(junk, ignore_errors=True)
        if not done:
            shutil.rmtree(out, ignore_errors=True)
            print("saddle-env: installing without ahead-of-time kernels: numba compiles them "
                  "on first use (python -m saddle_env.coldstart.precompile --aot retries)")
            return
        if not self.editable_mode:
            self._outputs = [str(p) for p in sorted(out.rglob("*")) if p.is_file()]
        self._record(True)

    def _record(self, built: bool) -> None:
        """Tell the distribution whether compiled modules were built, and a wheel being
        made whether it is for this platform only: bdist_wheel decides that before the build
        runs (from `has_ext_modules`, the expectation) and names and lays out the wheel
        after it, from ``root_is_pure``."""
        self.distribution.aot_built = built
        wheel = self.distribution.command_obj.get("bdist_wheel")
        if wheel is not None and getattr(wheel, "root_is_pure", None) is not None:
            wheel.root_is_pure = not built

    def get_outputs(self):
        return self._outputs

    def get_output_mapping(self):
        return {}


def _run_build(root: Path, env: dict) -> bool:
    """``python -m saddle_env.coldstart.precompile --aot`` in ``root``, in a session of its own so that a
    time-out or Ctrl-C stops its worker processes too."""
    cmd = [sys.executable, "-m", "saddle_env.coldstart.precompile", "--aot"]
    print(f"saddle-env: {' '.join(cmd[1:])} (a few minutes on 2 cores)", flush=True)
    try:
        proc = subprocess.Popen(cmd, cwd=root, env=env, start_new_session=True)
    except OSError as exc:
        print(f"saddle-env: ahead-of-time build not started ({exc})")
        return False
    try:
        return proc.wait(timeout=BUILD_TIMEOUT_S) == 0
    except subprocess.TimeoutExpired:
        print(f"saddle-env: ahead-of-time build stopped after {BUILD_TIMEOUT_S} s")
        return False
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


class build_with_aot(build):
    sub_commands = [*build.sub_commands, ("build_aot", None)]


def aot_enabled() -> bool:
    """Whether the ahead-of-time build is to run (``SADDLE_ENV_AOT=0`` skips it)."""
    return os.environ.get("SADDLE_ENV_AOT", "1") not in ("0", "")


class BinaryDistribution(Distribution):
    """A wheel holding the compiled modules is for this platform and Python only; one
    without them (the build skipped or failed) is pure Python, for any platform."""

    aot_built: bool | None = None  # set by build_aot once it has run

    def has_ext_modules(self):
        # before the build (bdist_wheel asks in finalize_options): whether one will run;
        # build_aot corrects the wheel's answer when it has failed
        return aot_enabled() if self.aot_built is None else self.aot_built


if __name__ == "__main__":  # as setuptools runs it (tests import the commands alone)
    setup(cmdclass={"build": build_with_aot, "build_aot": build_aot},
          distclass=BinaryDistribution)
