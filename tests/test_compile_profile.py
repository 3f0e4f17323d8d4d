"""The compile profiler's phase accounting (`saddle_env.coldstart.profile`)."""

from __future__ import annotations

import time

import pytest


def test_compile_phases_account_for_a_compile_and_restore_numba():
    """`compile_profile --phases`: each phase's own CPU seconds add up to no more than the
    compile took, the type inference and LLVM phases are seen, and numba is left as it was."""
    import numba
    from numba.core import codegen, compiler_machinery

    from saddle_env.coldstart.profile import CompilePhases

    before = (compiler_machinery.PassManager.__dict__["_runPass"],
              codegen.CPUCodeLibrary.__dict__["_finalize_final_module"])

    @numba.njit(cache=False)
    def poly(x):
        return 3.0 * x * x + 2.0 * x + 1.0

    with CompilePhases() as phases:
        start = time.process_time()
        assert poly(2.0) == 17.0
        took = time.process_time() - start
    seconds = dict(phases.seconds)
    assert seconds["numba: type inference"] > 0 and seconds["LLVM: machine code"] > 0
    assert 0 < sum(seconds.values()) <= took + 1e-3
    assert "numba: type inference" in phases.table()
    # the other passes are named too, under the table
    assert "translate_bytecode" in phases.other_passes
    assert "  translate_bytecode" in phases.table()
    assert (compiler_machinery.PassManager.__dict__["_runPass"],
            codegen.CPUCodeLibrary.__dict__["_finalize_final_module"]) == before


@pytest.mark.parametrize("n_passes", [2, 8, 11])
def test_the_other_passes_list_the_largest_and_count_the_rest(n_passes):
    """Under the table: the largest `PASSES_LISTED` passes by name, largest first, then one
    line for the rest with their count and seconds, only when there is a rest."""
    from saddle_env.coldstart.profile import CompilePhases

    phases = CompilePhases()
    phases.seconds[CompilePhases.OTHER] = float(sum(range(1, n_passes + 1)))
    for i in range(1, n_passes + 1):
        phases.other_passes[f"pass_{i}"] = float(i)
    lines = phases.table().splitlines()
    listed = [ln.split()[0] for ln in lines if ln.startswith("  pass_")]
    shown = min(n_passes, CompilePhases.PASSES_LISTED)
    assert listed == [f"pass_{i}" for i in range(n_passes, n_passes - shown, -1)]
    rest = [ln for ln in lines if ln.strip().split()[1:2] == ["more"]]
    if n_passes > CompilePhases.PASSES_LISTED:
        left = n_passes - CompilePhases.PASSES_LISTED
        assert rest[0].split()[:3] == [str(left), "more", f"{sum(range(1, left + 1)):.2f}"]
    else:
        assert rest == []


def test_isolated_rows_are_written_with_the_build_named(tmp_path, monkeypatch, capsys):
    """--isolated --aot --out: one fresh interpreter per scenario, the ahead-of-time build
    left on for it, and the rows (with each process's kernels status) written as JSON;
    --aot and --out without --isolated are refused."""
    import json
    import subprocess

    from saddle_env.coldstart import profile
    from saddle_env.compilation import aot

    seen = []

    def fake_run(cmd, **kw):
        seen.append(kw["env"][aot.AOT_ENV])
        return subprocess.CompletedProcess(
            cmd, 0, stdout="ahead-of-time kernels in use (6 modules)\n0.5 0.4 0.0 0.7\n")

    monkeypatch.setattr(profile.subprocess, "run", fake_run)
    monkeypatch.setattr("saddle_env.compilation.cache.clear", lambda *a: None)
    monkeypatch.delenv(aot.AOT_ENV, raising=False)
    out = tmp_path / "first.json"
    assert profile.main(["--isolated", "--aot", "--out", str(out), "simulate",
                         "SaddleTrap-v0"]) == 0
    data = json.loads(out.read_text())
    assert seen == ["1", "1"] and data["aot"] is True
    assert [r["scenario"] for r in data["rows"]] == ["simulate", "SaddleTrap-v0"]
    assert data["rows"][0]["kernels"].startswith("ahead-of-time kernels in use")
    assert data["level_first_step_s"] == [0.5, 0.5] and data["simulate_first_call_s"] == 0.5
    with pytest.raises(SystemExit):
        profile.main(["--aot"])
    assert "--aot and --out go with --isolated" in capsys.readouterr().err
