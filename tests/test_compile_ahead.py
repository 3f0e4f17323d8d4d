"""agents.training.compile_ahead: started only where it cannot race the run, stopped when the run
stops, waited for before the comparison; (slow) after it a fresh process's comparison
steps compile nothing."""

import os
import subprocess
import sys

import pytest
from helpers import compiled_in_fresh_process, gone_within

from agents.training import compile_ahead as ca
from agents.training.runs import TrainSettings


def _settings(**kw):
    return TrainSettings(**{"env_id": "SaddleTrap-Gusty-v0", "compare_episodes": 200,
                            **kw}).validate()


def test_started_for_a_registered_level_with_its_best_constant_cached(monkeypatch):
    started = []
    monkeypatch.setattr(ca.subprocess, "Popen", lambda args, **kw: started.append(args) or "p")
    monkeypatch.setenv(ca.OFF_ENV, "1")
    assert ca.start(_settings()) == "p"
    assert started[0][1:] == ["-m", "agents.training.compile_ahead", "SaddleTrap-Gusty-v0", "200", "500"]
    # nothing to compile for, or a race on the best-const cache: not started
    assert ca.start(_settings(compare_episodes=0)) is None
    assert ca.start(_settings(env_kwargs={"air_force": 0.2})) is None
    assert ca.start(_settings(backend="rllib", num_env_runners=0)) is None
    monkeypatch.setattr("agents.control.best_constant.cached_best_constant", lambda *a, **k: None)
    assert ca.start(_settings()) is None
    monkeypatch.setenv(ca.OFF_ENV, "0")
    assert len(started) == 1


def test_finish_waits_then_stops_a_process_still_running():
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    ca.finish(proc, wait_s=0.2)
    assert proc.returncode is not None          # stopped, not left running
    quick = subprocess.Popen([sys.executable, "-c", "pass"])
    ca.finish(quick)
    assert quick.returncode == 0
    ca.finish(None)


@pytest.mark.slow
def test_a_comparison_after_it_compiles_nothing(tmp_path):
    """On an empty cache, compile_ahead for Capture's comparison (200 balls: the threaded
    step; mpc's look-ahead); then a fresh process steps both baselines as the comparison
    does, and numba compiles nothing."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("SADDLE_ENV_FULL_KERNELS", None)           # the per-scene copies, as users run
    level = "SaddleTrap-Capture-v0"
    done = subprocess.run([sys.executable, "-m", "agents.training.compile_ahead", level, "200", "500"],
                          env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    code = ("from agents.training import compile_ahead\n"
            "compile_ahead.STEPS = 20\n"
            f"compile_ahead.compile_comparison({level!r}, 200, 500)")
    assert compiled_in_fresh_process(code, env) == ["<lambda>"]


def test_it_exits_when_the_run_that_started_it_is_killed(tmp_path):
    """A run killed before its SIGTERM handler is in place cannot stop it: it notices that
    its parent is gone and exits."""
    import time

    pid_file = tmp_path / "child.pid"
    child = ("import os, time, sys\n"
             "from agents.training.compile_ahead import _exit_with_parent\n"
             "_exit_with_parent()\n"
             f"open({str(pid_file)!r}, 'w').write(str(os.getpid()))\n"
             "time.sleep(60)\n")
    parent = subprocess.Popen([sys.executable, "-c",
                               "import subprocess, sys, time\n"
                               f"subprocess.Popen([sys.executable, '-c', {child!r}])\n"
                               "time.sleep(60)\n"])
    for _ in range(200):
        if pid_file.is_file() and pid_file.read_text():
            break
        time.sleep(0.05)
    pid = int(pid_file.read_text())
    parent.kill()
    parent.wait()
    assert gone_within(pid, 5), "the compile-ahead process outlived its parent by 5 s"
