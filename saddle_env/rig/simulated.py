"""`SimulatedRig`: a level's physics advancing in wall-clock time, behind the `Rig` interface.

The rig runs the environment itself (`SaddleTrapEnv`, the compiled step every tool uses; no
second right-hand side) with the control period set to the camera's frame interval: one
step of that environment is one camera frame. What the level models of the rig comes with
it unchanged: the camera's latency (``obs_delay``, exact: a frame shows the ball as it was
``obs_delay`` before), its pixels and tracking noise, the tachometer's noise, the
voltage-driven motor's lag (``motor_tau``), the draught and the motor's ripple.

Time: frame k ends at ``t0 + k / frame_rate`` on the rig's clock (``t0``: the first
release). The physics is brought up to the clock's present by a thread of its own (every
frame interval) and by every `read` and `write`, under one lock, so a read always sees every
frame finished by now. A written voltage reaches the motor at the start of the next frame
interval (a driver's update period; 5 ms at the default 200 frames/s), and frame k is
stepped with the voltage in force at its start, whatever the thread's timing: the physics
depends on the write times only. With a `VirtualClock` a run is therefore deterministic.

A release (`release`) is an episode of the environment: the ball placed as the level places
it, the saddle keeping the speed it has. After the ball is lost the camera reports no
position (NaN) until the next release; the frames it took before the loss still arrive,
``obs_delay`` late. Between releases the motor keeps turning under the voltage written.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from typing import Any

import numpy as np

from ..envs import EnvConfig, SaddleTrapEnv, level_config
from ..envs import control_step as S
from ..envs.observation import layout
from .clock import Clock, MonotonicClock
from .interface import Frame

DEFAULT_LEVEL = "SaddleTrap-Lab-v0"
FRAME_RATES = (1.0, 10_000.0)   # [frames/s] the camera rates a rig may have
TIME_TOLERANCE = 1e-9           # [s] times this close are one (sums of frame intervals)


class SimulatedRig:
    """A level's physics as a rig (see the module).

    Parameters
    ----------
    level
        A registered level id in ``action_mode="voltage"`` (default the Lab level), or an
        `EnvConfig` with that mode.
    frame_rate
        The camera's frames per second (default 200; one physics step each).
    seed
        Seeds the releases (the first is ``env.reset(seed=seed)``: the same ball, start
        and speed as the environment's episode of that seed).
    clock
        The clock frames are timed on (default `MonotonicClock`; a `VirtualClock` for
        tests).
    threaded
        Run the physics in a thread of its own (default). Without it the physics
        advances on `read` and `write` only, the same frames at the same times.
    **env_kwargs
        Options on top of the level's (e.g. ``air_force=0``).
    """

    def __init__(self, level: str | EnvConfig = DEFAULT_LEVEL, *, frame_rate: float = 200.0,
                 seed: int | None = None, clock: Clock | None = None, threaded: bool = True,
                 **env_kwargs: Any):
        if isinstance(level, EnvConfig):
            config = EnvConfig.from_kwargs(**{**level.as_dict(), **env_kwargs})
        else:
            config = level_config(level, **env_kwargs)
        if config.action_mode != "voltage":
            raise ValueError(f"a simulated rig drives its motor by a voltage: the level needs "
                             f"action_mode='voltage', got {config.action_mode!r}")
        rate = float(frame_rate)
        if not FRAME_RATES[0] <= rate <= FRAME_RATES[1]:
            raise ValueError(f"frame_rate must be in [{FRAME_RATES[0]:g}, {FRAME_RATES[1]:g}] "
                             f"frames/s, got {frame_rate!r}")
        self.config = config            # what the rig is: the loop's controller sees this level
        self.frame_rate = rate
        self.frame_interval = 1.0 / rate
        self.clock: Clock = clock if clock is not None else MonotonicClock()
        # The environment stepping one frame at a time: one frame of history (the loop keeps
        # its own), the angle observed so that positions can be turned into the laboratory.
        inner = dict(config.as_dict(), control_period=self.frame_interval, obs_history=1)
        if config.obs_frame == "rotating":
            inner["observe_angle"] = True
        self.env = SaddleTrapEnv(**inner)
        # One step now loads (or compiles) the compiled step, which would otherwise stall the
        # first frames of the first release; the releases reset the environment.
        self.env.reset()
        self.env.step(np.zeros(1))
        self._layout = layout(self.env.config)
        self._seed = seed
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._closed = False
        self._t0: float | None = None       # clock time of frame 0 (the first release)
        self._k = 0                         # frames stepped since t0
        self._frame: Frame | None = None
        self._voltage: float | None = None  # in force (None: the motor holds its start speed)
        self._writes: deque[tuple[float, float]] = deque()   # (time, volts) not yet in force
        self._ball = False                  # a ball is on the saddle (since its release)
        # frames the camera took before a loss, still on their way: (time, row, angle offset)
        self._pending: deque[tuple[float, np.ndarray, float]] = deque()
        self._theta_offset = 0.0            # the saddle's angle at the episode's start
        self._t0_episode = 0.0              # clock time of the episode's start
        self._theta_last: float | None = None
        self.releases = 0
        self.lost: list[dict[str, Any]] = []   # per loss: cause, time (the truth, for tests)
        # [s] the most the physics fell behind a real clock (a virtual one jumps ahead by
        # design, so there it says nothing)
        self.max_lag = 0.0
        self._thread: threading.Thread | None = None
        if threaded:
            self._thread = threading.Thread(target=self._run, name="SimulatedRig physics",
                                            daemon=True)
            self._thread.start()

    # -- the Rig interface ---------------------------------------------------------------
    def read(self) -> Frame | None:
        """The newest frame the camera has delivered by now (see the module)."""
        with self._lock:
            self._advance()
            return self._frame

    def write(self, voltage: float) -> None:
        """Set the motor's voltage [V], in [0, ``voltage_max``]; it takes effect at the next
        frame interval's start."""
        v = float(voltage)
        self.config.action_of_voltage(v)   # the range check, with its message
        with self._lock:
            self._advance()
            self._writes.append((self.clock.now(), v))

    def release(self, options: dict[str, Any] | None = None) -> None:
        """Put a ball on the saddle now: the level's start (the environment's reset; the
        first with ``seed``), the saddle at the speed it has (the level's start speed at the
        first release). ``options`` are the environment's reset options (``x, y, vx, vy``...)
        to place it exactly."""
        with self._lock:
            self._advance()
            opts = dict(options or {})
            if self._t0 is None:
                self._t0 = self.clock.now()
                self._reset(seed=self._seed, options=opts or None)
                if self._voltage is None:   # hold the start speed until a write
                    self._voltage = min(self.config.voltage_max,
                                        self.env.omega / self.config.motor_gain)
            else:
                opts.setdefault("omega", self.env.omega)
                self._reset(options=opts)
            # the first frame: the ball as placed (the environment's reset observation)
            obs = np.array(self.env.engine.frame[0], dtype=np.float64)
            self._publish(self._t0_episode - self.config.obs_delay, obs, True,
                          self._theta_offset)
            self._ball = True
            self._pending.clear()
            self.releases += 1

    def close(self) -> None:
        """Stop the physics thread (joined); idempotent. Reads and writes then fail."""
        self._stop.set()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=5.0)
        with self._lock:
            self._closed = True

    def __enter__(self) -> SimulatedRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def running(self) -> bool:
        """Whether the physics thread is alive."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def frames(self) -> int:
        """Camera frames (physics steps) taken since the first release."""
        with self._lock:
            return self._k

    @property
    def ball_on(self) -> bool:
        """Whether the simulated ball is on the saddle (the truth, which a real rig's loop
        infers from the frames)."""
        with self._lock:
            return self._ball

    # -- physics -------------------------------------------------------------------------
    def _run(self) -> None:
        """The physics thread: catch up with the clock every frame interval until closed."""
        dt = self.frame_interval
        while not self._stop.is_set():
            try:
                with self._lock:
                    self._advance()
                    nxt = None if self._t0 is None else self._t0 + (self._k + 1) * dt
            except BaseException as exc:   # handed to the next read or write
                self._error = exc
                return
            wait = dt if nxt is None else min(dt, max(nxt - self.clock.now(), 5e-4))
            self._stop.wait(wait)

    def _advance(self) -> None:
        """Step every frame that has ended by the clock's present (the lock is held)."""
        if self._error is not None:
            raise RuntimeError("the simulated rig's physics failed") from self._error
        if self._closed:
            raise RuntimeError("the simulated rig is closed")
        if self._t0 is None:
            return
        now = self.clock.now()
        dt = self.frame_interval
        due = math.floor((now - self._t0) / dt + TIME_TOLERANCE / dt)
        if due - self._k > 1:
            self.max_lag = max(self.max_lag, now - (self._t0 + (self._k + 1) * dt))
        while self._k < due:
            start = self._t0 + self._k * dt
            while self._writes and self._writes[0][0] <= start + TIME_TOLERANCE:
                self._voltage = self._writes.popleft()[1]
            self._step(start)

    def _step(self, start: float) -> None:
        """One frame interval from ``start`` under the voltage in force."""
        assert self._voltage is not None   # set at the first release
        action = np.array([self.config.action_of_voltage(self._voltage)])
        obs, _, terminated, _, info = self.env.step(action)
        self._k += 1
        shown = start + self.frame_interval - self.config.obs_delay   # the frame's time
        row = np.array(obs, dtype=np.float64)
        if terminated:
            if self._ball:
                event = self._t0_episode + info["event_time"]
                self.lost.append({"cause": info["cause"], "time": event})
                self._keep_frames_before(event, shown)
            self._publish(shown, row, self._ball, self._theta_offset)
            self._ball = False
            self._reset(options={"omega": self.env.omega, "x": 0.0, "y": 0.0, "vx": 0.0,
                                 "vy": 0.0})   # the saddle turns on without a ball
            return
        if self._pending:   # frames of a lost ball still on their way from the camera
            when, frame, offset = self._pending.popleft()
            self._publish(when, frame, True, offset)
        else:
            self._publish(shown, row, self._ball, self._theta_offset)

    def _keep_frames_before(self, event: float, shown: float) -> None:
        """At a loss: the frames the camera took before it, still in the latency's queue."""
        for i, frame in enumerate(self.env.engine.frames_in_flight(0), 1):
            when = shown + i * self.frame_interval
            if when > event + TIME_TOLERANCE:
                break
            self._pending.append((when, np.array(frame, dtype=np.float64), self._theta_offset))

    def _reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> None:
        if self._k > 0 or self._frame is not None:   # the angle carries on from this episode
            self._theta_offset += float(self.env.engine.balls[0, S.B_THETA])
        self.env.reset(seed=seed, options=options)
        assert self._t0 is not None
        self._t0_episode = self._t0 + self._k * self.frame_interval

    def _publish(self, t: float, obs: np.ndarray, ball: bool, offset: float) -> None:
        """The frame the camera delivers for observation row ``obs`` showing time ``t``: the
        level's observation turned into laboratory metres (``offset``: the saddle's angle
        at the start of the observation's episode), the angle unwrapped."""
        lay, c = self._layout, self.config
        assert lay.cos is not None
        angle = math.atan2(obs[lay.cos + 1], obs[lay.cos]) + offset
        if self._theta_last is not None:   # unwrap: |Δθ| < π per frame below 600 rad/s
            angle += 2.0 * math.pi * round((self._theta_last - angle) / (2.0 * math.pi))
        self._theta_last = angle
        px, py = obs[lay.x] * c.rim_radius, obs[lay.y] * c.rim_radius
        if lay.lab_frame:
            X, Y = px, py
        else:
            th = angle   # the rotating frame is the saddle's: turn it by θ
            X, Y = math.cos(th) * px - math.sin(th) * py, math.sin(th) * px + math.cos(th) * py
        if not ball:
            X = Y = math.nan
        self._frame = Frame(t, X, Y, float(obs[lay.omega] * c.omega_max), angle)


__all__ = ["DEFAULT_LEVEL", "SimulatedRig"]
