"""Real saddles: the lab's measured trapping times, the imperfections a real rig adds to the
rigid-ball model (tilt, launcher, dissipation, evaporation), their calibration and
`predict_lifetimes` (the ``saddle-lifetimes`` command)."""

from .data import Series, cutoff, load_lab_series, median_log_error, onset
from .model import LabModel, LifetimePrediction, load_calibration, predict_lifetimes

__all__ = ["LabModel", "LifetimePrediction", "Series", "cutoff", "load_calibration",
           "load_lab_series", "median_log_error", "onset", "predict_lifetimes"]
