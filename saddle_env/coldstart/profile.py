"""Where the first call's compile time goes: numba compiles, per function and signature.

    python -m saddle_env.coldstart.profile [--fresh] [--isolated [--aot] [--out FILE]]
                                           [--top N] [--phases] [SCENARIO ...]

A scenario is ``simulate`` (the README's rolling ball, 10 s) or a registered level id
(``gym.make(ID).reset(seed=0); step()``); by default ``simulate`` and every level of
`saddle_env.LEVELS`. In one process (the default) the scenarios run in order, so each one's
row is what it adds to the ones before; with ``--isolated`` each runs in a fresh interpreter
on an empty cache (the first step after a fresh install; implies ``--fresh``). The JIT's
compile is what is measured, so the install's ahead-of-time build is turned off, unless
``--aot`` keeps it on: then the rows are what a user's first call costs after the install.
``--out FILE`` writes the ``--isolated`` rows as JSON (the figures quoted on the docs' pages
read it).

``--fresh`` empties the package's in-tree numba cache first (`saddle_env.compilation.cache.clear`):
the numbers are then those of a fresh install. Without it they are what this machine's
cache leaves to compile.

numba reports each compile through its event API (``numba.core.event``, kind
``numba:compile``); a function's callees compile inside it, so the table gives each
function's own time (``self``: typing, lowering and optimising its code, including the
callees' code that LLVM inlines into it) apart from its callees' (``total`` includes them).
Loads from the on-disk cache are not compiles and cost milliseconds.

``--phases`` adds where the compile's CPU time goes by phase, summed over the functions
(`CompilePhases`): numba's type inference, its lowering to LLVM IR and its other passes,
LLVM's optimisation of each function and of each module with its callees linked in, LLVM's
machine code, the wrappers numba builds for Python and C callers, and the cache write.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import subprocess
import sys
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from ..compilation import aot as _aot


@dataclass
class _Row:
    self_s: float = 0.0
    total_s: float = 0.0
    signatures: list = field(default_factory=list)


class CompileRecorder:
    """Collects numba's compile events: own and inclusive seconds per function, and the
    signatures it was compiled for. Use as a context manager."""

    def __init__(self):
        from numba.core import event

        self._event = event
        self.rows: dict[str, _Row] = defaultdict(_Row)
        self._stack: list[list] = []  # [name, start, seconds spent in nested compiles]
        recorder = self

        class _Listener(event.Listener):
            def on_start(self, ev):
                d = ev.data["dispatcher"]
                name = f"{d.py_func.__module__}.{d.py_func.__qualname__}"
                recorder._stack.append([name, time.perf_counter(), 0.0, ev.data["args"]])

            def on_end(self, ev):
                name, start, nested, args = recorder._stack.pop()
                took = time.perf_counter() - start
                row = recorder.rows[name]
                row.self_s += took - nested
                row.total_s += took
                row.signatures.append(args)
                if recorder._stack:
                    recorder._stack[-1][2] += took

        self._listener = _Listener()

    def __enter__(self):
        self._event.register("numba:compile", self._listener)
        return self

    def __exit__(self, *exc):
        self._event.unregister("numba:compile", self._listener)

    def compiled_seconds(self) -> float:
        """Seconds spent in outermost compiles (each nested one is inside its caller's)."""
        return sum(r.self_s for r in self.rows.values())


class LLVMSize:
    """Counts the LLVM instructions numba optimises and turns into machine code: the
    optimised size of every module it finalises, which holds the function's code and the
    code of every callee linked into it. Unlike seconds it does not depend on the machine's
    load. Reads numba internals (``CPUCodeLibrary._optimize_final_module``): diagnostic only.
    """

    def __init__(self):
        from numba.core import codegen

        # Any: its method is replaced while counting (numba's own types forbid the assignment)
        self._cls: Any = codegen.CPUCodeLibrary
        self._orig = self._cls._optimize_final_module
        self.modules = 0
        self.instructions = 0

    def __enter__(self):
        orig, counter = self._orig, self

        def optimize(library):
            orig(library)
            counter.modules += 1
            counter.instructions += sum(
                len(list(b.instructions)) for f in library._final_module.functions
                if not f.is_declaration for b in f.blocks)

        self._cls._optimize_final_module = optimize
        return self

    def __exit__(self, *exc):
        self._cls._optimize_final_module = self._orig


class CompilePhases:
    """CPU seconds of a compile by phase, each phase's own time (compiles nested inside it
    are counted in their own phases): numba's passes by name (grouped in `PHASES`), LLVM's
    three stages, the wrappers numba builds for Python and C callers, and the cache write.
    Wraps numba internals (``PassManager._runPass``, ``CPUCodeLibrary``'s optimise and
    finalise steps, ``CPUContext``'s wrapper builders, ``Cache.save_overload``) while
    active: diagnostic only."""

    # Phase of a numba pass, by its name; other passes count as "numba: other passes".
    PHASES: ClassVar[dict[str, str]] = {"nopython_type_inference": "numba: type inference",
                                        "native_lowering": "numba: lowering to LLVM IR"}
    _TARGETS = (("numba.core.compiler_machinery", "PassManager", "_runPass", None),
                ("numba.core.codegen", "CPUCodeLibrary", "_optimize_functions",
                 "LLVM: optimising each function"),
                ("numba.core.codegen", "CPUCodeLibrary", "_optimize_final_module",
                 "LLVM: optimising the module, callees linked in"),
                ("numba.core.codegen", "CPUCodeLibrary", "_finalize_final_module",
                 "LLVM: machine code"),
                ("numba.core.cpu", "CPUContext", "create_cpython_wrapper",
                 "numba: wrapper for Python callers"),
                ("numba.core.cpu", "CPUContext", "create_cfunc_wrapper",
                 "numba: wrapper for C callers"),
                ("numba.core.caching", "Cache", "save_overload", "numba: writing the cache"))

    OTHER = "numba: other passes"
    PASSES_LISTED = 8   # the largest of the other passes, named under the table

    def __init__(self):
        self.seconds: dict[str, float] = defaultdict(float)
        # The "other passes" by pass name: what a pipeline without some of them could save.
        self.other_passes: dict[str, float] = defaultdict(float)
        self._stack: list[float] = []   # per open phase: seconds of phases nested in it
        self._saved: list[tuple[type, str, object]] = []

    def _timed(self, phase, fn):
        recorder = self

        def timed(*args, **kwargs):
            pass_name: str = "" if phase else args[2].name()  # read only when phase is None
            label = phase or recorder.PHASES.get(pass_name, recorder.OTHER)
            start = time.process_time()
            recorder._stack.append(0.0)
            try:
                return fn(*args, **kwargs)
            finally:
                took = time.process_time() - start
                own = took - recorder._stack.pop()
                recorder.seconds[label] += own
                if label == recorder.OTHER:
                    recorder.other_passes[pass_name] += own
                if recorder._stack:
                    recorder._stack[-1] += took

        return timed

    def __enter__(self):
        import importlib

        for module, cls_name, attr, phase in self._TARGETS:
            cls = getattr(importlib.import_module(module), cls_name)
            original = cls.__dict__[attr]
            self._saved.append((cls, attr, original))
            setattr(cls, attr, self._timed(phase, original))
        return self

    def __exit__(self, *exc):
        for cls, attr, original in reversed(self._saved):
            setattr(cls, attr, original)
        self._saved.clear()

    def table(self) -> str:
        """The phases' own CPU seconds and shares as a text table."""
        total = sum(self.seconds.values())
        lines = [f"{'phase (own CPU seconds)':<48} {'s':>6} {'share':>6}"]
        for label, sec in sorted(self.seconds.items(), key=lambda kv: -kv[1]):
            lines.append(f"{label:<48} {sec:>6.2f} {sec / total:>6.0%}")
        passes = sorted(self.other_passes.items(), key=lambda kv: -kv[1])
        if passes:
            lines.append(f"{self.OTHER}, the largest:")
            for name, sec in passes[:self.PASSES_LISTED]:
                lines.append(f"  {name:<46} {sec:>6.2f} {sec / total:>6.0%}")
            if len(passes) > self.PASSES_LISTED:
                rest = sum(sec for _, sec in passes[self.PASSES_LISTED:])
                lines.append(f"  {f'{len(passes) - self.PASSES_LISTED} more':<46} "
                             f"{rest:>6.2f} {rest / total:>6.0%}")
        return "\n".join(lines)


def readme_ball():
    """The README's rolling ball: (scene, state at rest in the lab frame at Ω = 30 rad/s)."""
    import saddle_env as se

    scene = se.Scene(a=0.159, R=0.02, contact="rolling")
    return scene, se.initial_state(scene, x=0.001, y=0.001, start="lab-rest", omega=30.0)


def first_step(env) -> None:
    """An env's (or a vector env's) first ``reset(seed=0)`` and ``step``, then close it."""
    env.reset(seed=0)
    env.step(env.action_space.sample() * 0)
    env.close()


def run_scenario(name: str) -> None:
    """Run one scenario: ``simulate`` or a level id's first reset and step."""
    import gymnasium as gym

    import saddle_env as se

    if name == "simulate":
        scene, state = readme_ball()
        se.simulate(scene, state, t_end=10.0, omega=30.0, dt_out=0.01)
        return
    first_step(gym.make(name))


def _scenarios(names: list[str]) -> list[str]:
    if names:
        return names
    import saddle_env

    return ["simulate"] + [level.id for level in saddle_env.LEVELS]


def _short(name: str) -> str:
    return name.removeprefix("saddle_env.")


def _profile_here(names: list[str], top: int, signatures: bool = False,
                  phases: bool = False) -> list[tuple[str, float, float]]:
    """Run the scenarios in this process; print the per-function table (and, with
    ``phases``, the seconds by compile phase); return (scenario, wall seconds, compile
    seconds) rows."""
    results = []
    by_phase = CompilePhases()
    with CompileRecorder() as rec, LLVMSize() as size, \
            (by_phase if phases else contextlib.nullcontext()):
        for name in names:
            before = rec.compiled_seconds()
            t0 = time.perf_counter()
            run_scenario(name)
            wall = time.perf_counter() - t0
            results.append((name, wall, rec.compiled_seconds() - before))
    rows = sorted(rec.rows.items(), key=lambda kv: -kv[1].self_s)
    n_sigs = sum(len(r.signatures) for _, r in rows)
    print(f"{len(rows)} functions compiled, {n_sigs} specialisations, "
          f"{rec.compiled_seconds():.1f} s in all; {size.modules} LLVM modules finalised, "
          f"{size.instructions:,} LLVM instructions optimised and compiled")
    print(f"{'function':<46} {'specs':>5} {'self s':>7} {'total s':>8}")
    for fname, r in rows[:top]:
        print(f"{_short(fname):<46} {len(r.signatures):>5} {r.self_s:>7.2f} {r.total_s:>8.2f}")
    many = [(f, r) for f, r in rows if len(r.signatures) > 1]
    if many:
        print("\nfunctions compiled for more than one signature:")
        for fname, r in many:
            print(f"  {_short(fname)}: {len(r.signatures)}")
            if signatures:
                for sig in r.signatures:
                    print("      (" + ", ".join(map(str, sig)) + ")")
    if phases:
        print("\n" + by_phase.table())
    return results


def _isolated(names: list[str]) -> list[dict[str, Any]]:
    """Each scenario in a fresh interpreter on an empty cache: its name, the import's and
    the first call's wall seconds, the first call's CPU and compiling seconds."""
    from ..compilation import cache as _cache

    results: list[dict[str, Any]] = []
    for name in names:
        _cache.clear()
        code = ("import time; t0 = time.perf_counter(); import saddle_env; "
                "t1 = time.perf_counter(); c1 = time.process_time(); "
                "from saddle_env.coldstart.profile import run_scenario, CompileRecorder\n"
                "from saddle_env.compilation import aot\n"
                "with CompileRecorder() as r:\n"
                f"    run_scenario({name!r})\n"
                # the folder relative to the package: a results file names no local paths
                "print(aot.status().replace(str(aot.AOT_DIR), 'saddle_env/_aot'))\n"
                "print(time.perf_counter() - t1, time.process_time() - c1, "
                "r.compiled_seconds(), t1 - t0)")
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             check=True, env=dict(os.environ))
        lines = out.stdout.strip().splitlines()
        wall, cpu, compiled, imp = (float(v) for v in lines[-1].split())
        results.append({"scenario": name, "import_s": imp, "first_call_s": wall,
                        "first_call_cpu_s": cpu, "compiling_s": compiled,
                        "kernels": lines[-2]})
        # CPU seconds: what the wall time is on an idle machine (numba compiles on one
        # thread); on a loaded one the wall time is longer.
        print(f"{name:<26} import {imp:5.2f} s, first call {wall:6.2f} s wall, "
              f"{cpu:6.2f} s CPU (compiling {compiled:6.2f} s)", flush=True)
    return results


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """What the pages quote of `_isolated`'s rows: a level's first step, least and most over
    the levels, and a first ``simulate``'s (each present only if run)."""
    levels = [r["first_call_s"] for r in rows if r["scenario"] != "simulate"]
    out: dict[str, Any] = {}
    if levels:
        out["level_first_step_s"] = [min(levels), max(levels)]
    for r in rows:
        if r["scenario"] == "simulate":
            out["simulate_first_call_s"] = r["first_call_s"]
    return out


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m saddle_env.coldstart.profile``."""
    ap = argparse.ArgumentParser(prog="python -m saddle_env.coldstart.profile",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("scenarios", nargs="*",
                    help="'simulate' and/or level ids (default: simulate and every level)")
    ap.add_argument("--fresh", action="store_true",
                    help="empty the in-tree numba cache first (a fresh install)")
    ap.add_argument("--isolated", action="store_true",
                    help="each scenario in a fresh process on an empty cache")
    ap.add_argument("--aot", action="store_true",
                    help="with --isolated: keep the install's ahead-of-time build on (a "
                         "user's first call after the install)")
    ap.add_argument("--out", default=None, metavar="FILE",
                    help="with --isolated: also write the rows as JSON")
    ap.add_argument("--top", type=int, default=25, help="functions listed (default 25)")
    ap.add_argument("--signatures", action="store_true",
                    help="print the signatures of functions compiled more than once")
    ap.add_argument("--phases", action="store_true",
                    help="also the compile's CPU seconds by phase (numba's passes, LLVM)")
    return ap


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    ap = build_parser()
    args = ap.parse_args(argv)
    if (args.aot or args.out) and not args.isolated:
        ap.error("--aot and --out go with --isolated")
    # What numba's JIT compiles is measured here: the ahead-of-time build, which a first call
    # would use instead (`saddle_env.compilation.aot`), stays out (also in the --isolated
    # processes), unless --aot asks for a user's first call after the install.
    os.environ[_aot.AOT_ENV] = "1" if args.aot else "0"
    names = _scenarios(args.scenarios)
    if args.isolated:
        rows = _isolated(names)
        if args.out:
            Path(args.out).parent.mkdir(parents=True, exist_ok=True)
            Path(args.out).write_text(json.dumps(
                {"aot": args.aot,
                 "machine": f"{platform.machine()}, {os.cpu_count()} cores",
                 "date": time.strftime("%Y-%m-%d"), "rows": rows,
                 **_summary(rows)}, indent=1))
            print(f"wrote {args.out}")
        return 0
    if args.fresh:
        from ..compilation import cache as _cache

        _cache.clear()
    results = _profile_here(names, args.top, args.signatures, args.phases)
    print(f"\n{'scenario':<26} {'wall s':>7} {'compile s':>10}")
    for name, wall, compiled in results:
        print(f"{name:<26} {wall:>7.2f} {compiled:>10.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
