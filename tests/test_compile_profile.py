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
