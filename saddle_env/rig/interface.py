"""The `Rig` interface: what the real-time loop (`saddle_env.rig.loop.run`) needs of an
apparatus, a camera with its ball tracker, a tachometer (and an encoder) and a motor driver.

Four methods, each for a reason the loop cannot do without:

* `Rig.read` — the control loop's input: the newest frame the tracker has finished, as late
  as the camera makes it (the latency is part of the frame's time, ``t``, not hidden);
* `Rig.write` — its output: the motor's voltage;
* `Rig.release` — one run on the rig is a sequence of releases of the ball (one track file
  each): the loop calls it to start each, and it returns when a ball is on the saddle (an
  operator's keypress, a release mechanism, or the tracker first seeing the ball);
* `Rig.close` — the motor off and the devices free, also when the loop dies of an
  exception or a signal: a crashed controller must not leave a saddle spinning at its last
  voltage.

A rig may also have a ``clock`` attribute (a `saddle_env.rig.clock.Clock`): the clock its
frame times are on, which the loop then uses (default `time.monotonic`).
"""

from __future__ import annotations

from typing import NamedTuple, Protocol, runtime_checkable


class Frame(NamedTuple):
    """One camera frame with the readings of the same moment.

    Attributes
    ----------
    t : float
        When the picture was taken [s], on the loop's clock (a frame read now shows the ball
        at ``t``, the camera's latency ago).
    x, y : float
        The ball's centre [m] seen from above in the laboratory frame, origin on the saddle's
        axis (NaN: tracking lost the ball).
    omega : float
        The tachometer's speed [rad/s].
    theta : float or None
        The saddle's angle [rad] from an encoder, or None without one (the loop needs it for
        levels that observe in the rotating frame or observe the angle, as the Lab level does).
    """

    t: float
    x: float
    y: float
    omega: float
    theta: float | None = None


@runtime_checkable
class Rig(Protocol):
    """A camera, a tachometer and a motor driver, as the loop uses them (see the module)."""

    def read(self) -> Frame | None:
        """The newest frame available now (None before the first); never blocks for long."""
        ...

    def write(self, voltage: float) -> None:
        """Set the motor's voltage [V]; it holds until the next write."""
        ...

    def release(self) -> None:
        """Put a ball on the saddle; return when it is there."""
        ...

    def close(self) -> None:
        """Motor off, devices free; idempotent."""
        ...


__all__ = ["Frame", "Rig"]
