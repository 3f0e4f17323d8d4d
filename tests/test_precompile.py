"""saddle_env.coldstart.precompile: targets checked before any work, progress and failures
reported,
and (slow) a fresh process's first step after it compiles nothing."""

import os
import subprocess
import sys

import pytest
from helpers import compiled_in_fresh_process

from saddle_env.coldstart import precompile as pc
from saddle_env.envs import LEVELS
from saddle_env.envs.engine import contact_uses


def test_unknown_targets_are_refused_before_any_work(monkeypatch, capsys):
    ran = []
    monkeypatch.setattr(pc, "run_target", lambda t: ran.append(t) or 0.0)
    with pytest.raises(ValueError, match="unknown target 'vector:SaddleTrap-v9'"):
        pc.precompile(["SaddleTrap-v0", "vector:SaddleTrap-v9"])
    assert ran == []
    with pytest.raises(SystemExit):
        pc.main(["simulate", "nothing"])
    with pytest.raises(SystemExit):
        pc.main(["--jobs", "0"])
    err = capsys.readouterr().err
    assert "unknown target 'nothing'" in err and "--jobs must be >= 1" in err


def test_a_failed_target_is_reported_and_the_others_still_compile(monkeypatch):
    def runner(target):
        if target == "batch":
            def fail():
                raise RuntimeError("no luck")
            return fail
        return lambda: None

    monkeypatch.setattr(pc, "target_runner", runner)
    lines = []
    results = pc.precompile(["batch", "simulate"], jobs=1, log=lines.append)
    assert results["batch"] == "RuntimeError: no luck" and isinstance(results["simulate"], float)
    assert lines[0] == "compiling 2 target(s) in 1 process(es) into numba's cache"
    assert lines[1] == "[1/2] batch: FAILED: RuntimeError: no luck"
    assert lines[2].startswith("[2/2] simulate: ")
    assert pc.main(["batch", "simulate", "--jobs", "1"]) == 1


def test_default_targets_start_each_set_of_contact_models_once_before_repeats():
    targets = pc.default_targets()
    levels = {level.id: level for level in LEVELS}
    assert sorted(targets) == sorted(list(levels) + ["simulate"])
    uses = [contact_uses(levels[t].config()) for t in targets[:targets.index("simulate")]]
    assert len(set(uses)) == len(uses)                      # all different before simulate
    assert {contact_uses(levels[t].config()) for t in targets[targets.index("simulate") + 1:]} \
        <= set(uses)                                         # the rest repeat one of them


@pytest.mark.slow
def test_after_precompiling_a_fresh_process_compiles_nothing(tmp_path):
    """Two worker processes fill an empty cache; a new interpreter's first step and first
    simulate then load everything (no numba compile event at all)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("SADDLE_ENV_FULL_KERNELS", None)          # the per-scene copies, as users run
    done = subprocess.run([sys.executable, "-m", "saddle_env.coldstart.precompile", "--jobs", "2",
                           "SaddleTrap-Storm-v0", "simulate"], env=env,
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    assert "[2/2]" in done.stderr and "done in" in done.stderr
    code = ("from saddle_env.coldstart.profile import run_scenario\n"
            "run_scenario('SaddleTrap-Storm-v0'); run_scenario('simulate')")
    assert compiled_in_fresh_process(code, env, timeout=300) == ["<lambda>"]
