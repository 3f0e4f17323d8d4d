"""The real-time loop on a rig: a camera with its tracker, a tachometer, a motor driver.

`Rig` is what the loop needs of an apparatus (`read` a frame, `write` a voltage, `release`
a ball, `close`); `SimulatedRig` is a level's physics behind it, in wall-clock (or virtual)
time; `run` reads, acts and writes every control period, counts the deadlines it misses and
logs one track file per release (`saddle_env.calibrate.tracks`), which ``saddle-fit``
reads. docs/how-to/rig.md shows how to write a `Rig` for real hardware.

```
from saddle_env.deploy import Controller
from saddle_env.rig import SimulatedRig, run

with SimulatedRig("SaddleTrap-Lab-v0") as rig:
    summary = run(rig, Controller.from_dir("DIR"), seconds=30, log_dir="runs/rig")
```
"""

from ..jobs.signals import Terminated
from .clock import Clock, MonotonicClock, VirtualClock
from .interface import Frame, Rig
from .loop import run
from .observe import Observer, as_policy, constant_voltage
from .simulated import SimulatedRig

__all__ = ["Clock", "Frame", "MonotonicClock", "Observer", "Rig", "SimulatedRig", "Terminated",
           "VirtualClock", "as_policy", "constant_voltage", "run"]
