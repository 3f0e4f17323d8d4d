"""The compile profiler's phase accounting (`saddle_env.compile_profile`)."""

from __future__ import annotations

import time

import pytest


def test_compile_phases_account_for_a_compile_and_restore_numba():
    """`compile_profile --phases`: each phase's own CPU seconds add up to no more than the
    compile took, the type inference and LLVM phases are seen, and numba is left as it was."""
    import numba
    from numba.core import codegen, compiler_machinery

    from saddle_env.compile_profile import CompilePhases

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
    # the other passes are named too, and they are the group's time, split
    assert "translate_bytecode" in phases.other_passes
    assert sum(phases.other_passes.values()) == \
        pytest.approx(seconds["numba: other passes"])
    assert (compiler_machinery.PassManager.__dict__["_runPass"],
            codegen.CPUCodeLibrary.__dict__["_finalize_final_module"]) == before
