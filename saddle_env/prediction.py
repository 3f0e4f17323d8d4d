"""Batch prediction: many short runs of the compiled integrator, each through a chain of
drive segments, sampled on a regular grid — what a model-predictive controller asks of the
model every control step.

`predict_batch` runs each of n balls from its own state through S segments. Segment j of
run r lasts ``durations[r, j]`` seconds under the drive row ``drives[r, j]`` (`kernels`'s
DRIVE_* layout: Ω ramping linearly or relaxing exponentially, ripple, lab-fixed force), its
time starting at 0; the saddle angle carries over from segment to segment, so a lab-fixed
force keeps its direction in the laboratory. The run is sampled ``ceil(duration / sample)``
times per segment, evenly, ending on the segment's end, and stops at the first event. It is `simulate`'s integrator
(`integrators.integrate_h`), so a one-segment prediction is `simulate` on the same drive,
sample for sample.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass

import numba as nb
import numpy as np

from . import kernels as K
from .compilation.jit import python_entry
from .compilation.specialise import entry, specialisable
from .compilation.threads import in_threads
from .integrators import integrate_h, state_scale, workspace
from .kernels import rhs
from .runner import DEFAULT_EVENTS, Settings, default_max_step, padded_width
from .scene import N_PARAMS, P_RESIST


@dataclass
class Prediction:
    """The sampled runs of `predict_batch` (run r, segment j, sample k).

    Attributes
    ----------
    t
        (n, S, m) time of each sample since the run's start [s].
    state
        (n, S, m, k) state at each sample, padded as in `simulate_batch` (`padded_width`);
        NaN where a segment has fewer samples, was skipped (duration ≤ 0) or was not reached
        (an event came first).
    normal
        (n, S, m) N/m at each sample [m/s²] (NaN where ``state`` is).
    status
        (n,) STATUS_* code of each run (an event, a failure or STATUS_DONE).
    final_state
        (n, 5) the state where each run ended (at the event if one fired).
    """

    t: np.ndarray
    state: np.ndarray
    normal: np.ndarray
    status: np.ndarray
    final_state: np.ndarray


@nb.njit(cache=True)
def samples_in(duration, sample):
    """Samples of a segment of ``duration`` seconds at spacing at most ``sample`` (a duration
    a rounding error past a multiple of ``sample`` gets no extra sample)."""
    return max(1, int(math.ceil(duration / sample - 1e-9)))


@python_entry
@nb.njit(cache=True, nogil=True)
def integrate_segments(lo, hi, models, P, scales, Y, drives, durations, sample, tab, ctl, t_out,
                       Y_out, N_out, status):
    """The kernel of `predict_batch`, for runs ``lo`` to ``hi - 1``: run r from ``Y[r]``
    (advanced in place to its final state) through the segments of ``drives[r]`` and
    ``durations[r]``, filling row r of ``t_out``, ``Y_out`` and ``N_out`` (NaN-filled by the
    caller) and ``status[r]``. The step size carries over from segment to segment, as in one
    run. One thread; `predict_batch` runs ranges on several (`compilation.threads.in_threads`), and
    without the GIL so that they run at once."""
    S = durations.shape[1]
    for r in range(lo, hi):
        model, p, y = models[r], P[r], Y[r]
        stats = np.zeros(4, dtype=np.int64)
        work = workspace(tab)
        dy = np.empty(K.STATE_WIDTH)
        h = 0.0
        st = 0
        elapsed = 0.0
        theta = drives[r, 0, K.DRIVE_THETA0]
        for j in range(S):
            T = durations[r, j]
            if T <= 0.0:
                continue
            prof = drives[r, j].copy()
            prof[K.DRIVE_THETA0] = theta  # where the previous segment left the saddle
            theta = K.angle_at(prof, T)
            m = samples_in(T, sample)
            t = np.arange(1, m + 1) * (T / m)
            res = integrate_h(model, p, prof, y, 0.0, t, tab, ctl, scales[r], Y_out[r, j],
                              stats, h, work)
            st, h = res.status, res.h_next
            for k in range(m):
                if not math.isfinite(Y_out[r, j, k, 0]):
                    break
                t_out[r, j, k] = elapsed + t[k]
                N_out[r, j, k] = rhs(model, p, prof, t[k], Y_out[r, j, k], dy, True)
            elapsed += T
            if st != 0:
                break
        status[r] = st


def predict_batch(models: int | np.ndarray, P: np.ndarray, Y0: np.ndarray, drives: np.ndarray,
                  durations: np.ndarray, sample: float, *, method: str | None = None,
                  rtol: float | None = None, atol: float | None = None,
                  events: Sequence[str] = DEFAULT_EVENTS, max_step: float | None = None,
                  max_steps: int = 100_000, scales: np.ndarray | None = None) -> Prediction:
    """Predict n balls through S drive segments each (see the module docstring).

    Parameters
    ----------
    models : int or numpy.ndarray
        Contact model codes (`Scene.model_code`): one for all, or an (n,) array, one per
        run (any other shape is a ValueError naming ``models``).
    P
        (n, N_PARAMS) packed scene parameters (`Scene.params()`).
    Y0
        (n, k ≤ 7) start states (padded as in `simulate_batch`), or (n, STATE_WIDTH) kernel
        states (with the work slot, as `states_from_observations` builds them).
    drives
        (n, S, DRIVE_WIDTH) drive rows (DRIVE_*); the angle θ0 of segments after the first is
        replaced by where the previous one ended.
    durations
        (n, S) [s]; a segment of duration ≤ 0 is skipped.
    sample : float
        Largest spacing of the samples [s].
    method, rtol, atol, events, max_steps
        As in `simulate` (adaptive steps only).
    max_step : float
        Largest step [s]; default as in `simulate`, from the largest |Ω| the
        drives reach.
    scales
        (n, STATE_WIDTH) state scales for the tolerances; default `state_scale` of each row.

    Returns
    -------
    Prediction
    """
    P = np.ascontiguousarray(P, dtype=float)
    Y = np.array(Y0, dtype=float)
    if Y.ndim == 2 and Y.shape[1] <= K.DYNAMICS_WIDTH:  # padded public states
        Y = np.concatenate([Y, np.zeros((len(Y), K.STATE_WIDTH - Y.shape[1]))], axis=1)
    drives = np.ascontiguousarray(drives, dtype=float)
    durations = np.ascontiguousarray(durations, dtype=float)
    n, S = durations.shape
    if P.shape != (n, P.shape[1]) or Y.shape != (n, K.STATE_WIDTH) or \
            drives.shape != (n, S, K.DRIVE_WIDTH):
        raise ValueError(f"shapes disagree: P {P.shape}, Y0 {np.shape(Y0)}, drives {drives.shape}, "
                         f"durations {durations.shape} (want (n, {N_PARAMS}), "
                         f"(n, {K.DYNAMICS_WIDTH}), (n, S, {K.DRIVE_WIDTH}), (n, S))")
    if not (isinstance(sample, (int, float)) and math.isfinite(sample) and sample > 0):
        raise ValueError(f"sample must be a positive number of seconds, got {sample!r}")
    # always a fresh, writable array: a view of the caller's (read-only once broadcast)
    # would be another argument type, which the install's build has no entry point for
    codes = _model_codes(models, n)
    settings = Settings.build(method, rtol, atol, None, events, max_step, max_steps)
    if max_step is None:
        max_step = default_max_step(_speed_bound(drives, durations))
    if scales is None:
        scales = np.array([state_scale(P[r], codes[r]) for r in range(n)])
    elif np.shape(scales) != (n, K.STATE_WIDTH):
        raise ValueError(f"scales must have shape ({n}, {K.STATE_WIDTH}) (one row per run), "
                         f"got {np.shape(scales)}")
    longest = durations.max(axis=0) if n else np.zeros(S)
    m = max((samples_in(float(T), float(sample)) for T in longest if T > 0), default=1)
    t = np.full((n, S, m), np.nan)
    state = np.full((n, S, m, K.STATE_WIDTH), np.nan)
    normal = np.full((n, S, m), np.nan)
    status = np.zeros(n, dtype=np.int64)
    args = (codes, P, np.ascontiguousarray(scales, dtype=float), Y, drives, durations,
            float(sample), settings.method.tableau, settings.control(max_step), t, state, normal,
            status)
    # compiled for the contact models (and rolling resistance) of these runs alone
    kernel = entry(np.unique(codes), bool((P[:, P_RESIST] != 0.0).any()),
                     sys.modules[__name__], "integrate_segments", (0, n, *args))
    in_threads(kernel, n, *args, simulated_s=float(np.maximum(durations, 0.0).sum()))
    width = padded_width(codes)
    return Prediction(t, np.ascontiguousarray(state[..., :width]), normal, status,
                      np.ascontiguousarray(Y[:, :width]))


def _model_codes(models: object, n: int) -> np.ndarray:
    """The contact model codes, one per run: one code for all, or exactly n of them. A
    sequence of any other length (one code of a list included) is refused, never
    broadcast."""
    arr = np.asarray(models)
    if arr.dtype.kind not in "iu" or (arr.ndim and arr.shape != (n,)):
        raise ValueError(f"models must be one contact model code (Scene.model_code) or {n} "
                         f"of them, one per run, got {type(models).__name__} of shape "
                         f"{arr.shape} and dtype {arr.dtype}")
    return np.array(np.broadcast_to(arr.astype(np.int64), (n,)))


def _speed_bound(drives: np.ndarray, durations: np.ndarray) -> float:
    """Largest |Ω| [rad/s] any segment reaches (linear ramp or a voltage-driven motor's
    monotone relaxation, plus the ripple's amplitude: extremes at the segment's ends)."""
    d = np.maximum(durations, 0.0)
    decay = drives[..., K.DRIVE_DECAY]
    w0 = drives[..., K.DRIVE_W0] + decay
    w1 = drives[..., K.DRIVE_W0] + drives[..., K.DRIVE_RATE] * d + \
        decay * np.exp(-drives[..., K.DRIVE_DECAY_RATE] * d)
    return float(np.max(np.maximum(np.abs(w0), np.abs(w1)) + np.abs(drives[..., K.DRIVE_AMP])))


specialisable(__name__)

__all__ = ["Prediction", "predict_batch"]
