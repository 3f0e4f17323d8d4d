"""Compile ahead: fill numba's on-disk cache before a first call has to wait for it.

    python -m saddle_env.coldstart.precompile [TARGET ...] [--jobs N]

The first call of a compiled function after an install or an upgrade compiles it (seconds
per level: docs/coldstart.md); the code is then cached on disk, and later processes load it
in milliseconds. This command does that compiling up front, on several cores at once, where
waiting is expected: after ``pip install``, in a container's build step, before a notebook
session or a cluster's job.

A target is what one kind of first call compiles:

* a level id (``SaddleTrap-Storm-v0``): ``gym.make(ID)``, ``reset()`` and one ``step()``;
* ``vector:ID``: the level's vector env (``gym.make_vec(ID, num_envs=n)``) at the batch
  sizes that pick its two compiled steps (SIMD blocks in one thread, and threads);
* ``simulate``: `saddle_env.simulate` of a rolling ball (the README's example);
* ``batch``: `saddle_env.simulate_batch` (the batch integrator over threads).

With ``--aot`` it builds instead what the package's install builds
(`saddle_env.coldstart.aot_build`): the entry points of a first ``env.step`` and a first
``simulate``, compiled ahead of time into C extension modules that a fresh process loads without
compiling (needs a C compiler). Run it after editing the package's sources in a source checkout: a
build made from other sources is not used.

By default every level and ``simulate``. Targets run in ``--jobs`` worker processes (default:
the cores this process may use), each worker taking the next target when it is free; the
order given is the order started, so put targets that share little first (levels with
different contact models compile different code; the rolling levels share theirs). A target
already in the cache loads in well under a second. Exits 1 if any target failed.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable, Sequence

VECTOR = "vector:"


def _vector(env_id: str) -> None:
    import gymnasium as gym

    from ..envs.control_step import MIN_BLOCK
    from ..lockstep import LANES
    from .profile import first_step

    # The engine steps fewer than 2 LANES balls in one thread with SIMD blocks (step_serial)
    # and more over threads (step_parallel): see `envs.engine.TrapEngine`.
    for n in (MIN_BLOCK, 2 * LANES):
        first_step(gym.make_vec(env_id, num_envs=n))


def _batch() -> None:
    import numpy as np

    import saddle_env as se

    from .profile import readme_ball

    scene, state = readme_ball()
    se.simulate_batch(scene, np.repeat(state[None], 2, 0), 0.1, omega=30.0, dt_out=0.01)


def target_runner(target: str) -> Callable[[], None]:
    """The function that compiles ``target`` (ValueError naming the allowed targets)."""
    from ..envs import LEVELS
    from .profile import run_scenario

    ids = [level.id for level in LEVELS]
    if target == "simulate" or target in ids:
        return lambda: run_scenario(target)
    if target == "batch":
        return _batch
    if target.startswith(VECTOR) and target[len(VECTOR):] in ids:
        return lambda: _vector(target[len(VECTOR):])
    raise ValueError(f"unknown target {target!r}: one of simulate, batch, a level id "
                     f"({', '.join(ids)}) or vector:ID")


def default_targets() -> list[str]:
    """Every level and ``simulate``, levels with different contact models first."""
    from ..envs import LEVELS
    from ..envs.engine import contact_uses

    first: list[str] = []
    later: list[str] = []
    seen = set()
    for level in LEVELS:
        uses = contact_uses(level.config())
        (later if uses in seen else first).append(level.id)
        seen.add(uses)
    return first + ["simulate"] + later


def run_target(target: str) -> float:
    """Compile ``target`` in this process; the seconds it took. The compile notices
    (`saddle_env.compilation.notice`) are held back meanwhile: the progress lines say it."""
    import logging

    logger = logging.getLogger("saddle_env")
    level = logger.level
    logger.setLevel(logging.ERROR)
    start = time.perf_counter()
    try:
        target_runner(target)()
    finally:
        logger.setLevel(level)
    return time.perf_counter() - start


def usable_cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # not on Linux
        return os.cpu_count() or 1


def precompile(targets: Sequence[str], jobs: int = 1,
               log: Callable[[str], None] = lambda s: print(s, file=sys.stderr, flush=True)
               ) -> dict[str, float | str]:
    """Compile ``targets`` into the on-disk cache in ``jobs`` worker processes (1: in this
    one). Returns each target's seconds, or its error message."""
    for t in targets:
        target_runner(t)            # unknown targets fail before any work starts
    log(f"compiling {len(targets)} target(s) in {jobs} process(es) into numba's cache")
    results: dict[str, float | str] = {}

    def report(t: str, outcome: float | str) -> None:
        results[t] = outcome
        what = f"{outcome:.1f} s" if isinstance(outcome, float) else f"FAILED: {outcome}"
        log(f"[{len(results)}/{len(targets)}] {t}: {what}")

    if jobs <= 1:
        for t in targets:
            try:
                report(t, run_target(t))
            except Exception as exc:  # noqa: BLE001 - reported, the others still compile
                report(t, f"{type(exc).__name__}: {exc}")
        return results
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # spawn: numba's threading layer does not survive a fork after threads started
    with ProcessPoolExecutor(max_workers=jobs,
                             mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(run_target, t): t for t in targets}
        try:
            for fut in as_completed(futures):
                error = fut.exception()
                report(futures[fut], fut.result() if error is None
                       else f"{type(error).__name__}: {error}")
        except KeyboardInterrupt:
            pool.shutdown(wait=False, cancel_futures=True)
            raise
    return results


def _build_aot(jobs: int) -> int:
    from ..compilation import aot as _aot
    from . import aot_build

    start = time.perf_counter()
    try:
        manifests = aot_build.build(jobs, log=lambda m: print(m, file=sys.stderr))
    except KeyboardInterrupt:
        print("interrupted: no ahead-of-time build in place (the JIT is used)", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - the package still works, with the JIT
        print(f"ahead-of-time build failed ({type(exc).__name__}: {exc}); the kernels "
              "compile with numba's JIT on first use instead", file=sys.stderr)
        return 1
    for manifest in manifests:
        print(f"built {len(manifest['modules'])} ahead-of-time modules for {manifest['cpu']} "
              f"into {_aot.build_folder(manifest['cpu'])}", file=sys.stderr)
    print(f"done in {time.perf_counter() - start:.1f} s", file=sys.stderr)
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m saddle_env.coldstart.precompile``."""
    p = argparse.ArgumentParser(prog="python -m saddle_env.coldstart.precompile",
                                description=__doc__.split("\n")[0])
    p.add_argument("targets", nargs="*", metavar="TARGET",
                   help="simulate, batch, a level id or vector:ID (default: every level "
                        "and simulate)")
    p.add_argument("--jobs", type=int, default=None,
                   help="worker processes (default: the usable cores, at most one per target)")
    p.add_argument("--aot", action="store_true",
                   help="build the ahead-of-time compiled kernels (what the install builds) "
                        "instead of filling numba's cache; no targets")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.jobs is not None and args.jobs < 1:
        parser.error(f"--jobs must be >= 1, got {args.jobs}")
    if args.aot:
        if args.targets:
            parser.error("--aot builds a fixed set of entry points: give no targets")
        return _build_aot(args.jobs or usable_cores())
    targets = args.targets or default_targets()
    jobs = min(args.jobs or usable_cores(), len(targets))
    start = time.perf_counter()
    try:
        results = precompile(targets, jobs)
    except ValueError as exc:
        parser.error(str(exc))
    except KeyboardInterrupt:
        print("interrupted: what finished is cached; run again for the rest", file=sys.stderr)
        return 130
    failed = [t for t, r in results.items() if not isinstance(r, float)]
    print(f"done in {time.perf_counter() - start:.1f} s"
          + (f"; failed: {', '.join(failed)}" if failed else ""), file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
