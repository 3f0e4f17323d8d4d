"""`run`: the real-time loop on a rig — read the camera, act, write the voltage, every period.

Each control period k of a release starts at ``release + k·period`` on the loop's clock:

1. sleep until the period's start (how late the loop woke is its *lateness*);
2. `Rig.read` the newest frame; a frame not seen before goes into the observation
   (`saddle_env.rig.observe.Observer`: the level's observation, as the environment would
   give it) and the log;
3. the controller's action for that observation (its *compute time*), turned into the
   voltage as the level's voltage mode does (`EnvConfig.voltage_of_action`), and
   `Rig.write`;
4. a *deadline miss* when the voltage was written after the period's deadline, the next
   period's start. When the loop is so late that a whole period has passed, it skips to the
   present period and counts the periods it skipped as misses too.

A release ends when the ball is lost, seen in the frames as a real rig sees it: its centre
beyond the saddle's rim (``escape``), or no tracked position for ``lost_after`` seconds of
frames (``lost``: a detached ball leaves the tracker's view), or no new frame for that long
(``no frames``); or when the run's time is up (``time``). Then the next release begins,
until ``seconds`` have passed or ``releases`` releases were run.

The files the run writes (one track per release, the period timings, a JSON summary) are
described in `saddle_env.rig.record`. Ctrl-C, SIGTERM or an exception (the controller's
included) close the release being run, write everything, `Rig.close` the rig (motor off)
and re-raise; a run that ends by its time leaves the rig open for the caller.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..envs import EnvConfig, level_config
from ..jobs.signals import SignalRecord, Terminated, sigterm_interrupts
from .clock import Clock, MonotonicClock
from .interface import Frame, Rig
from .observe import Observer, as_policy
from .record import RunRecorder

DEFAULT_LOST_AFTER = 0.1   # [s] of frames without the ball before a release counts as lost
TIME_TOLERANCE = 1e-9      # [s]


def _resolve_config(rig: Rig, config: EnvConfig | str | None, period: float | None) -> EnvConfig:
    if config is None:
        config = getattr(rig, "config", None) or "SaddleTrap-Lab-v0"
    if isinstance(config, str):
        config = level_config(config)
    if not isinstance(config, EnvConfig):
        raise TypeError(f"config must be an EnvConfig or a level id, got {type(config).__name__}")
    if config.action_mode != "voltage":
        raise ValueError(f"the loop writes voltages: the level needs action_mode='voltage', got "
                         f"{config.action_mode!r}")
    if period is not None:
        p = float(period)
        if not (math.isfinite(p) and 0.0 < p <= 1.0):
            raise ValueError(f"period must be in (0, 1] s, got {period!r}")
        if p != config.control_period:
            config = EnvConfig.from_kwargs(**{**config.as_dict(), "control_period": p})
    return config


def run(rig: Rig, controller: Any, seconds: float, period: float | None = None, *,
        config: EnvConfig | str | None = None, log_dir: str | Path | None = None,
        releases: int | None = None, lost_after: float = DEFAULT_LOST_AFTER,
        clock: Clock | None = None, progress: Callable[[str], None] | None = None
        ) -> dict[str, Any]:
    """Run ``controller`` on ``rig`` for ``seconds`` (see the module); return the summary.

    Parameters
    ----------
    rig
        A `Rig` (`SimulatedRig`, or your camera and motor driver: docs/how-to/rig.md).
    controller
        ``act(observation)`` (`saddle_env.deploy.Controller`), SB3's ``predict``
        (``mpc`` from `agents.control.mpc`, an SB3 model) or a callable; see
        `saddle_env.rig.observe.as_policy`. It sees the level's observation.
    seconds
        The run's length on the loop's clock, (0, 86400].
    period
        The control period [s]; default the level's ``control_period`` (20 ms).
    config
        The level the controller was made for: an id or an `EnvConfig` in voltage mode
        (default the rig's ``config`` attribute, else the Lab level).
    log_dir
        Where the tracks, periods.tsv and summary.json go (None: nothing written).
    releases
        Stop after this many releases (default: as many as fit in ``seconds``).
    lost_after
        Seconds of frames without the ball that end a release.
    clock
        The loop's clock (default the rig's ``clock`` attribute, else `time.monotonic`).
    progress
        Called with a line of text at the end of each release and every few seconds
        (e.g. ``print``).

    Returns
    -------
    dict
        The run's summary (as ``summary.json`` holds it): its settings, the releases and
        the deadlines missed.

    Raises
    ------
    ValueError
        If ``seconds``, ``releases`` or ``lost_after`` is out of range, or the level is not
        in voltage mode.
    """
    cfg = _resolve_config(rig, config, period)
    T = cfg.control_period
    if not (isinstance(seconds, (int, float)) and math.isfinite(seconds)
            and 0.0 < seconds <= 86_400.0):
        raise ValueError(f"seconds must be in (0, 86400], got {seconds!r}")
    if releases is not None and (isinstance(releases, bool) or not isinstance(releases, int)
                                 or releases < 1):
        raise ValueError(f"releases must be a positive integer or None, got {releases!r}")
    if not (math.isfinite(lost_after) and lost_after > 0.0):
        raise ValueError(f"lost_after must be a positive number of seconds, got {lost_after!r}")
    clk: Clock = clock or getattr(rig, "clock", None) or MonotonicClock()
    policy = as_policy(controller)
    observer = Observer(cfg)
    recorder = RunRecorder(log_dir, cfg, T, meta={
        "rig": type(rig).__name__, "controller": getattr(controller, "name", None) or
        type(controller).__name__, "seconds": seconds, "lost_after_s": lost_after,
        "env_options": cfg.as_dict()})
    end = clk.now() + seconds
    try:
        with sigterm_interrupts() as term:
            while clk.now() < end - TIME_TOLERANCE and (releases is None or len(recorder.releases) < releases):
                rel = _release(rig, policy, observer, recorder, cfg, clk, end, lost_after,
                               progress, term)
                if progress is not None:
                    progress(f"release {rel['index']}: {rel['seconds']:.2f} s, ended by "
                             f"{rel['cause']}; {rel['periods']} periods, {rel['misses']} "
                             f"missed; run: {recorder.periods} periods, {recorder.misses} "
                             f"missed")
    except BaseException as exc:
        reason = "SIGTERM" if isinstance(exc, Terminated) else \
            "Ctrl-C" if isinstance(exc, KeyboardInterrupt) else f"{type(exc).__name__}: {exc}"
        try:
            recorder.stop(clk.now(), reason)
        finally:
            rig.close()
        raise
    recorder.finish()
    return recorder.summary()


def _as_frame(frame: Any) -> Frame | None:
    """A rig's frame as a `Frame` (a plain tuple ``(t, x, y, omega[, theta])`` is one too),
    its time checked."""
    if frame is None:
        return None
    if not isinstance(frame, Frame):
        try:
            frame = Frame(*frame)
        except TypeError:
            raise TypeError(f"Rig.read() must return a Frame, a tuple (t, x, y, omega[, theta]) "
                            f"or None, got {frame!r}") from None
    try:
        t = float(frame.t)
    except (TypeError, ValueError):
        t = math.nan
    if not math.isfinite(t):
        raise ValueError(f"a frame's time t must be a finite number of seconds on the loop's "
                         f"clock, got {frame.t!r}")
    return frame


def _release(rig: Rig, policy: Callable[[Any, bool], float], observer: Observer,
             recorder: RunRecorder, cfg: EnvConfig, clk: Clock, end: float,
             lost_after: float, progress: Callable[[str], None] | None,
             term: SignalRecord) -> dict[str, Any]:
    """One release of the ball: the periods until it is lost or the run's time is up."""
    T = cfg.control_period
    rig.release()
    t0 = clk.now()
    observer.reset()
    recorder.start_release(t0)
    k = 0
    first = True
    last_t = -math.inf          # the newest frame's time seen
    last_new = t0               # clock time a new frame last arrived
    last_seen: float | None = None   # time of the newest frame with the ball
    cause = "time"
    while True:
        term.raise_if_lost()
        start = t0 + k * T
        if start >= end - TIME_TOLERANCE:
            clk.sleep_until(end)
            break
        clk.sleep_until(start)
        woke = clk.now()
        frame = _as_frame(rig.read())
        age = None
        if frame is not None and frame.t > last_t:
            last_t, last_new = frame.t, woke
            observer.push(frame)
            recorder.frame(frame)
            if math.isfinite(frame.x) and math.isfinite(frame.y):
                last_seen = frame.t
                if math.hypot(frame.x, frame.y) > cfg.rim_radius:
                    cause = "escape"
        if frame is not None:
            age = woke - frame.t
        if cause == "time":
            if woke - last_new > lost_after:
                cause = "no frames"
            elif last_t - (t0 if last_seen is None else last_seen) > lost_after:
                cause = "lost"
        if cause != "time":
            recorder.period_done(k, start, woke, None, None, False, None, age)
            break
        compute = written = volts = None
        if observer.ready:
            c0 = clk.now()
            action = policy(observer.observation, first)
            compute = clk.now() - c0
            first = False
            volts = cfg.voltage_of_action(action)
            rig.write(volts)
            written = clk.now()
            recorder.wrote(written, volts)
        missed = written is not None and written > start + T + TIME_TOLERANCE
        recorder.period_done(k, start, woke, compute, written, missed, volts, age)
        k += 1
        now = clk.now()
        due = math.floor((now - t0) / T + TIME_TOLERANCE)   # the period the clock is in
        if due > k:   # whole periods passed while this one ran: skip to the present one
            recorder.skip(due - k)
            k = due
        if recorder.maybe_write_summary(now) and progress is not None and k > 1:
            progress(f"release {len(recorder.releases) + 1}: {now - t0:.1f} s; run: "
                     f"{recorder.periods} periods, {recorder.misses} missed")
    return recorder.end_release(clk.now(), cause)


__all__ = ["DEFAULT_LOST_AFTER", "run"]
