"""What a run on the rig leaves behind, written as it goes.

In the log folder:

* ``release_001.csv``, ``release_002.csv``, ...: one track file per release of the ball
  (`saddle_env.calibrate.tracks`, written by its `write_track`): the frames the loop read,
  from the release on, each once, up to the ball's last position: ``t`` the frame's time
  on the loop's clock, ``x, y`` [m] in the laboratory, ``omega`` the tachometer, ``theta``
  the encoder (when the rig gives it), ``voltage`` the voltage in force on the motor at the
  frame's time (the last one the loop wrote before ``t``; empty before its first write).
  ``saddle-fit`` reads them.
* ``periods.tsv``: one tab-separated row per control period (not ``.csv``: the folder's
  ``*.csv`` files are its tracks, as ``saddle-fit`` reads a folder): its release, scheduled
  start, how late the loop woke, the controller's compute time, when the voltage was
  written, whether the deadline (the next period's start) was missed, the voltage and the
  age of the frame it acted on; appended at the end of each release.
* ``summary.json``: the counts and the timing statistics (median, p99, max, in ms) over the
  whole run, one entry per release, and the level's options the controller was run for;
  rewritten whole (atomically) after every release, every few seconds, and when the run
  stops, by its end, Ctrl-C, SIGTERM or an exception.
"""

from __future__ import annotations

import bisect
import csv
import datetime
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..calibrate.tracks import MIN_POSITIONS, Track, TrackError, write_track
from ..envs import EnvConfig
from ..jobs.files import write_text_atomically
from .interface import Frame

PERIOD_COLUMNS = ("release", "period", "start", "lateness", "compute", "written", "missed",
                  "voltage", "frame_age")
SUMMARY_EVERY = 5.0   # [s] of the run's clock between rewrites of summary.json


def _stats(values: list[float]) -> dict[str, float | None]:
    """Median, 99th percentile and maximum [ms] of times in seconds (None when empty)."""
    if not values:
        return {"median": None, "p99": None, "max": None}
    a = np.asarray(values) * 1e3
    return {"median": round(float(np.median(a)), 4),
            "p99": round(float(np.percentile(a, 99)), 4), "max": round(float(a.max()), 4)}


class RunRecorder:
    """Collects a run's frames, writes and period timings, and writes the files above
    (``log_dir`` None: keeps the summary in memory only)."""

    def __init__(self, log_dir: str | Path | None, config: EnvConfig, period: float,
                 meta: dict[str, Any] | None = None):
        self.dir = None if log_dir is None else Path(log_dir)
        if self.dir is not None:
            self.dir.mkdir(parents=True, exist_ok=True)
            existing = sorted(self.dir.glob("release_*.csv"))
            if existing or (self.dir / "summary.json").exists():
                raise FileExistsError(f"{self.dir} already holds a run (summary.json or "
                                      f"release_*.csv); give an empty or new log_dir")
        self.config = config
        self.period = period
        self.meta = dict(meta or {})
        self.started = datetime.datetime.now(datetime.timezone.utc).isoformat(
            timespec="seconds")
        self.releases: list[dict[str, Any]] = []
        self.writes_t: list[float] = []
        self.writes_v: list[float] = []
        self.lateness: list[float] = []
        self.compute: list[float] = []
        self.cycle: list[float] = []
        self.frame_age: list[float] = []
        self.periods = self.misses = self.skipped = 0
        self.stopped: str | None = None
        self.complete = False
        self._rows: list[tuple] = []
        self._frames: list[Frame] = []
        self._release: dict[str, Any] | None = None
        self._last_summary = -math.inf

    # -- during a release ----------------------------------------------------------------
    def start_release(self, t: float) -> None:
        """Open a new release of the ball at time ``t``."""
        self._release = {"index": len(self.releases) + 1, "start": t, "end": None,
                         "seconds": None, "periods": 0, "misses": 0, "skipped": 0,
                         "frames": 0, "cause": None, "file": None}
        self._frames = []

    def frame(self, frame: Frame) -> None:
        """A new frame read during the release (kept from the release's time on)."""
        rel = self._release
        if rel is not None and frame.t >= rel["start"] and \
                (not self._frames or frame.t > self._frames[-1].t):
            self._frames.append(frame)

    def wrote(self, t: float, voltage: float) -> None:
        """Record a write of ``voltage`` to the motor at time ``t``."""
        self.writes_t.append(t)
        self.writes_v.append(voltage)

    def period_done(self, k: int, start: float, woke: float, compute: float | None,
                    written: float | None, missed: bool, voltage: float | None,
                    frame_age: float | None) -> None:
        """Record control period ``k``: its timings, whether it missed its deadline, what it wrote."""
        rel = self._release
        assert rel is not None
        self.periods += 1
        rel["periods"] += 1
        self.lateness.append(woke - start)
        if compute is not None:
            self.compute.append(compute)
        if written is not None:
            self.cycle.append(written - woke)
        if frame_age is not None:
            self.frame_age.append(frame_age)
        if missed:
            self.misses += 1
            rel["misses"] += 1
        nan = math.nan
        self._rows.append((rel["index"], k, start, woke - start,
                           nan if compute is None else compute,
                           nan if written is None else written, int(missed),
                           nan if voltage is None else voltage,
                           nan if frame_age is None else frame_age))

    def skip(self, n: int) -> None:
        """``n`` periods passed without the loop (it was too late for them): misses too."""
        assert self._release is not None
        self.skipped += n
        self.misses += n
        self._release["skipped"] += n
        self._release["misses"] += n

    def end_release(self, t: float, cause: str) -> dict[str, Any]:
        """Close the release: its track file and period rows written, the summary too."""
        rel = self._release
        assert rel is not None
        rel.update(end=t, seconds=t - rel["start"], cause=cause, frames=len(self._frames))
        if self.dir is not None:
            name = f"release_{rel['index']:03d}.csv"
            track = self._track(rel["index"])
            if track is None:
                rel["file"] = None
                rel["note"] = f"no track file: fewer than {MIN_POSITIONS} tracked frames"
            else:
                write_track(self.dir / name, track, comments=[
                    f"saddle_env.rig run, release {rel['index']}, ended by {cause}",
                    "t: frame time on the loop's clock [s]; voltage: in force at t [V]"])
                rel["file"] = name
            self._append_periods()
        self.releases.append(rel)
        self._release = None
        self.write_summary()
        return rel

    def _track(self, index: int) -> Track | None:
        frames = list(self._frames)
        while frames and not math.isfinite(frames[-1].x):   # the ball gone: nothing to fit
            frames.pop()
        if sum(math.isfinite(f.x) for f in frames) < MIN_POSITIONS:
            return None
        cols = {n: np.array([getattr(f, n) for f in frames], dtype=float)
                for n in ("t", "x", "y", "omega")}
        if all(f.theta is not None for f in frames):
            cols["theta"] = np.array([f.theta for f in frames], dtype=float)
        volts = np.full(len(frames), math.nan)
        for i, f in enumerate(frames):
            j = bisect.bisect_right(self.writes_t, f.t) - 1
            if j >= 0:
                volts[i] = self.writes_v[j]
        cols["voltage"] = volts
        try:
            return Track(**cols, source=f"release {index}")
        except TrackError as exc:   # a rig that breaks the format: say so, keep running
            raise TrackError(f"the rig's frames of release {index} do not make a track: "
                             f"{exc}") from None

    def _append_periods(self) -> None:
        assert self.dir is not None
        path = self.dir / "periods.tsv"
        new = not path.exists()
        with open(path, "a", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh, delimiter="\t")
            if new:
                w.writerow(PERIOD_COLUMNS)
            w.writerows(self._rows)
        self._rows = []

    # -- the summary ---------------------------------------------------------------------
    def maybe_write_summary(self, now: float) -> bool:
        """Rewrite summary.json if `SUMMARY_EVERY` seconds have passed; whether it did."""
        if now - self._last_summary >= SUMMARY_EVERY:
            self._last_summary = now
            self.write_summary()
            return True
        return False

    def summary(self) -> dict[str, Any]:
        """The run so far: its settings, the releases and the deadlines missed."""
        releases = list(self.releases)
        if self._release is not None:
            releases.append(dict(self._release, cause="running"))
        return {
            **self.meta,
            "started_utc": self.started,
            "period_s": self.period,
            "complete": self.complete,
            "stopped": self.stopped,
            "periods": self.periods,
            "misses": self.misses,
            "miss_fraction": self.misses / self.periods if self.periods else None,
            "skipped_periods": self.skipped,
            "lateness_ms": _stats(self.lateness),
            "compute_ms": _stats(self.compute),
            "cycle_ms": _stats(self.cycle),
            "frame_age_ms": _stats(self.frame_age),
            "releases": releases,
        }

    def write_summary(self) -> None:
        """Write `summary` to ``summary.json`` in the log folder (if there is one)."""
        if self.dir is not None:
            write_text_atomically(self.dir / "summary.json",
                                  json.dumps(self.summary(), indent=1, allow_nan=False) + "\n")

    def stop(self, t: float, reason: str) -> None:
        """The run was stopped (``reason``): the open release closed and everything written."""
        self.stopped = reason
        if self._release is not None:
            self.end_release(t, "stopped")
        self.write_summary()

    def finish(self) -> None:
        """Mark the run complete and write the summary."""
        self.complete = True
        self.write_summary()


__all__ = ["PERIOD_COLUMNS", "RunRecorder"]
