"""Re-measure the figure store's measured figures in one step: ``python -m agents.remeasure``.

A quick figure is one whose command runs in under a minute and writes a results file that the
store reads (``source:`` and ``key:`` in ``docs/figures/figures.yml``). `MEASUREMENTS` is the
fixed table of those commands: each is run as the argument list it names, never a string
from a file, with ``{out}`` standing for a fresh temporary folder. The files it writes
there are kept at their places in the repository; every store entry that reads one gets
today's date and the machine it ran on (with its load, which the timings depend on); and
the README's and the pages' copies are rewritten (``python -m agents.figures --write``).
With ``--long`` the speed figures whose commands take minutes run too: the environment's
throughput against CartPole and the full work-precision benchmark with the compiled peers.

Training runs and the leaderboard are not here: their own commands write their results
files, and the store names them.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from . import figures
from .paths import REPO_ROOT


@dataclass(frozen=True)
class Measurement:
    """One quick command and the results file the store reads from it."""

    name: str                 # what ``--only`` names
    # run in the repository's root: "{out}" is a temporary folder, "{python}" this
    # interpreter (its environment's packages, whatever the PATH)
    argv: tuple[str, ...]
    produces: str             # the file the command writes, relative to {out}
    keep_as: str              # where the repository keeps it (the store's ``source:``)
    timeout_s: float = 60.0   # quick: under a minute, or it fails
    # more files of the same run the repository keeps: (written, kept as) pairs
    also: tuple[tuple[str, str], ...] = ()
    long: bool = False        # minutes, not seconds: run with --long only

    def kept(self) -> tuple[tuple[str, str], ...]:
        """Every (written, kept as) pair, the store's main results file first."""
        return ((self.produces, self.keep_as), *self.also)


MEASUREMENTS: tuple[Measurement, ...] = (
    # the work-precision benchmark's smoke run: one rolling ball against scipy's DOP853, a
    # batch, the Jacobi drift (docs/accuracy.md)
    Measurement("bench-quick", ("{python}", "-m", "saddle_env.workprecision", "--quick",
                                "--out", "{out}"),
                "summary.json", "docs/figures/bench_quick_summary.json"),
    # simulate(..., tol=...)'s pilot against one run at its pick (docs/accuracy.md)
    Measurement("pilot-cost", ("{python}", "-m", "saddle_env.workprecision", "--pilot-cost",
                               "--out", "{out}"),
                "pilot_cost.json", "docs/figures/bench_pilot/pilot_cost.json"),
    # the environment against CartPole, made as users make both (docs/environment.md)
    Measurement("throughput", ("{python}", "-m", "saddle_env.envs.throughput", "--out", "{out}"),
                "throughput.json", "docs/figures/env/throughput.json", timeout_s=900.0,
                also=(("batch_sizes.csv", "docs/figures/env/batch_sizes.csv"),
                      ("throughput.png", "docs/figures/env/throughput.png")), long=True),
    # the full work-precision benchmark with every installed compiled peer (docs/accuracy.md)
    Measurement("bench", ("{python}", "-m", "saddle_env.workprecision", "--peers", "all",
                          "--out", "{out}"),
                "summary.json", "docs/figures/bench_summary.json", timeout_s=3600.0,
                also=(("summary.json", "docs/figures/bench_peers_summary.json"),
                      ("bench.csv", "docs/figures/bench_results.csv"),
                      ("bench.csv", "docs/figures/bench_peers.csv"),
                      ("bench_single.png", "docs/figures/bench_single.png"),
                      ("bench_batch.png", "docs/figures/bench_batch.png"),
                      ("bench_single.png", "docs/figures/bench_peers_single.png"),
                      ("bench_batch.png", "docs/figures/bench_peers_batch.png")), long=True),
    # the coulomb tier against the rolling ball in one run (docs/accuracy.md, docs/physics.md)
    Measurement("coulomb-tier", ("{python}", "-m", "saddle_env.workprecision", "--tiers",
                                 "rolling,coulomb", "--no-peers", "--no-batch", "--no-figures",
                                 "--jacobi-periods", "0", "--quiet", "--out", "{out}"),
                "bench.csv", "docs/figures/coulomb_tier/bench.csv", timeout_s=900.0,
                also=(("summary.json", "docs/figures/coulomb_tier/summary.json"),), long=True),
    # where one ball's time goes, the simulator's DOP853 against numbalsoda's (docs/accuracy.md)
    Measurement("profile", ("{python}", "-m", "saddle_env.workprecision.profile", "--out",
                            "{out}"),
                "bench_profile.json", "docs/figures/bench_profile.json", timeout_s=600.0, long=True),
)


def machine() -> str:
    """The machine as the store records it: architecture, cores and the load of the last
    minute (other jobs slow the timings down)."""
    return (f"{platform.machine()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f} "
            "when re-measured")


def _argv(m: Measurement, out: Path) -> list[str]:
    fill = {"{out}": str(out), "{python}": sys.executable}
    return [fill.get(a, a) for a in m.argv]


def restamp(store_text: str, source: str, date: str, where: str) -> tuple[str, list[str]]:
    """The store's text with ``date:`` and ``machine:`` of every entry reading ``source``
    replaced, and the names of those entries. Line edits, so the file's comments and order
    stay."""
    blocks = re.split(r"(?m)^(?=\S)", store_text)   # one block per top-level entry
    names = []
    for i, block in enumerate(blocks):
        if re.search(rf"(?m)^  source: {re.escape(source)}\s*$", block):
            names.append(block.split(":", 1)[0].strip().strip("'\""))
            block = re.sub(r"(?m)^  date: .*$", f"  date: {date}", block)
            blocks[i] = re.sub(r"(?m)^  machine: .*$", f"  machine: {where}", block)
    return "".join(blocks), names


def remeasure(only: Sequence[str] = (), store: Path = figures.STORE,
              measurements: Sequence[Measurement] = MEASUREMENTS,
              root: Path = REPO_ROOT, long: bool = False) -> list[str]:
    """Run the measurements (those named in ``only``, or all quick ones and, with ``long``,
    the long ones too), keep their results files under ``root``, re-date the entries of
    ``store`` that read them and, for the repository's own store, rewrite the stale copies
    of the README and the pages. Returns the store entries re-measured.

    Raises
    ------
    ValueError
        ``only`` names no measurement of the table.
    RuntimeError
        A command failed, ran out of time or wrote no results file.
    """
    known = {m.name for m in measurements}
    unknown = sorted(set(only) - known)
    if unknown:
        raise ValueError(f"only must name measurements of {sorted(known)}, got {unknown}")
    chosen = [m for m in measurements
              if ((m.name in only) if only else (long or not m.long))]
    today = datetime.date.today().isoformat()
    done: list[str] = []
    for m in chosen:
        with tempfile.TemporaryDirectory(prefix="saddle-remeasure-") as tmp:
            argv = _argv(m, Path(tmp))
            print(f"{m.name}: {' '.join(argv)}", flush=True)
            try:
                run = subprocess.run(argv, cwd=root, timeout=m.timeout_s, check=False)
            except subprocess.TimeoutExpired:
                raise RuntimeError(f"{m.name}: over {m.timeout_s:g} s, not a quick figure") from None
            missing = [w for w, _ in m.kept() if not (Path(tmp) / w).is_file()]
            if run.returncode != 0 or missing:
                raise RuntimeError(f"{m.name}: {argv[0]} exited {run.returncode} "
                                   f"{'without ' + ', '.join(missing) if missing else ''}")
            for written, keep_as in m.kept():
                shutil.copyfile(Path(tmp) / written, root / keep_as)
        for _, keep_as in m.kept():
            text, names = restamp(store.read_text(), keep_as, today, machine())
            store.write_text(text)
            done += names
    if store == figures.STORE:
        for path in figures.stale_files():
            path.write_text(figures.render(path.read_text()))
            print(f"rewrote: {path.relative_to(REPO_ROOT)}")
    return done


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m agents.remeasure``."""
    p = argparse.ArgumentParser(
        prog="python -m agents.remeasure",
        description="Re-run every quick figure's command (under a minute each), keep the "
                    "results files it writes, re-date the figure store's entries that read "
                    "them and rewrite the README's and the pages' copies; with --long, the "
                    "speed figures that take minutes too.")
    p.add_argument("--only", nargs="+", metavar="NAME", default=[],
                   choices=[m.name for m in MEASUREMENTS],
                   help="re-measure only these (default: all of them)")
    p.add_argument("--long", action="store_true",
                   help="also the long measurements: the environment's throughput, the full "
                        "work-precision benchmark with the compiled peers and the profile of one "
                        "ball against numbalsoda's (about 15 min)")
    p.add_argument("--list", action="store_true",
                   help="print each measurement's command and results file, and stop")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    args = build_parser().parse_args(argv)
    if args.list:
        for m in MEASUREMENTS:
            print(f"{m.name}{' (--long)' if m.long else ''}: {' '.join(m.argv)} -> "
                  f"{', '.join(k for _, k in m.kept())} ({m.timeout_s:g} s at most)")
        return 0
    try:
        names = remeasure(args.only, long=args.long)
    except RuntimeError as err:
        print(f"error: {err}")
        return 1
    print(f"re-measured: {', '.join(names)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
