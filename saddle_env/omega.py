"""The saddle's speed as a function of time."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .scene import finite_number


@dataclass(frozen=True)
class OmegaProfile:
    """The saddle's speed, Ω(t) = w0 + rate·t + amp·sin(freq·t + phase) [rad/s].

    Covers constant speed (the paper), a ramp (a motor at constant torque; within one
    control step of the environment) and a ripple. Ω̇ is finite everywhere, so the Euler
    force is well defined.

    Parameters
    ----------
    w0 : float
        The speed at t = 0 [rad/s].
    rate : float
        The ramp's slope [rad/s²].
    amp : float
        The ripple's amplitude [rad/s].
    freq : float
        The ripple's angular frequency [rad/s].
    phase : float
        The ripple's phase at t = 0 [rad].

    Raises
    ------
    ValueError
        If a value is not a finite number.
    """

    w0: float = 0.0
    rate: float = 0.0
    amp: float = 0.0
    freq: float = 0.0
    phase: float = 0.0

    def __post_init__(self) -> None:
        for name in ("w0", "rate", "amp", "freq", "phase"):
            label = {"w0": "omega"}.get(name, f"omega {name}")
            object.__setattr__(self, name, finite_number(label, getattr(self, name)))

    @classmethod
    def coerce(cls, omega: object, name: str = "omega") -> OmegaProfile:
        """One ball's Ω: a profile, or a number (constant speed [rad/s]).

        A sequence is one entry per ball, so for one ball it holds exactly one (a number or
        a profile). A ramp or a ripple is only ever an `OmegaProfile`: a sequence's length
        never chooses between "speeds" and "a profile's parameters".

        Raises
        ------
        ValueError
            Naming ``name``: not a finite number, not a profile, or a sequence of more or
            fewer than one entry.
        """
        if isinstance(omega, OmegaProfile):
            return omega
        if isinstance(omega, (tuple, list)) or (isinstance(omega, np.ndarray) and omega.ndim):
            shape = np.shape(omega) if isinstance(omega, np.ndarray) else (len(omega),)
            if shape != (1,):
                raise ValueError(
                    f"{name} for one ball must be a number [rad/s], an OmegaProfile or a "
                    f"sequence of exactly 1 of them (one per ball), got a "
                    f"{type(omega).__name__} of shape {shape}; a ramp or a ripple is "
                    "OmegaProfile(w0, rate, amp, freq, phase)")
            return cls.coerce(omega[0], name)
        return cls(finite_number(name, omega))

    def array(self) -> np.ndarray:
        """The profile packed as the compiled kernels read it."""
        return np.array([self.w0, self.rate, self.amp, self.freq, self.phase])

    @property
    def constant(self) -> bool:
        """Whether Ω stays constant."""
        return self.rate == 0.0 and (self.amp == 0.0 or self.freq == 0.0)

    def __call__(self, t: np.ndarray | float) -> np.ndarray | float:
        """Ω(t)."""
        return self.w0 + self.rate * t + self.amp * np.sin(self.freq * t + self.phase)

    def rate_at(self, t: np.ndarray | float) -> np.ndarray | float:
        """Ω̇(t)."""
        return self.rate + self.amp * self.freq * np.cos(self.freq * t + self.phase)

    def angle(self, t: np.ndarray | float) -> np.ndarray | float:
        """Saddle angle θ(t) = ∫₀ᵗ Ω dt' [rad] (θ(0) = 0): rotates rotating-frame vectors into the lab."""
        theta = self.w0 * t + 0.5 * self.rate * np.square(t)
        if self.freq != 0.0:
            theta = theta - self.amp / self.freq * (np.cos(self.freq * t + self.phase)
                                                    - math.cos(self.phase))
        else:
            theta = theta + self.amp * math.sin(self.phase) * t
        return theta

    def bound(self, t_end: float) -> float:
        """An upper bound of |Ω| on [0, t_end]."""
        return max(abs(self.w0), abs(self.w0 + self.rate * t_end)) + abs(self.amp)


def omega_rows(omega: object, n: int) -> np.ndarray:
    """Each of n balls' Ω profile, checked, as (n, 5) profile rows (`OmegaProfile.array`).

    ``omega`` is one number or `OmegaProfile` for all, a sequence of exactly n of them (one
    per ball), an (n,) array of constant speeds [rad/s] or an (n, 5) array of profile rows.
    Any other length is refused, never read as a profile's parameters: a sequence's length
    does not choose its meaning (a ramp is an `OmegaProfile`)."""
    if isinstance(omega, np.ndarray) and omega.ndim >= 1:
        if omega.shape == (n,):
            return np.array([OmegaProfile.coerce(w, f"omega[{i}]").array()
                             for i, w in enumerate(omega)])
        if omega.shape == (n, 5):
            return np.array([OmegaProfile(*row).array() for row in omega])
        raise ValueError(f"omega as an array must have shape ({n},) (a speed per ball) or "
                         f"({n}, 5) (a profile row per ball), got {omega.shape}")
    if isinstance(omega, (list, tuple)):
        if len(omega) != n:
            raise ValueError(f"omega as a sequence must hold one speed [rad/s] or OmegaProfile "
                             f"per ball, {n} entries, got {len(omega)}; a ramp or a ripple for "
                             "every ball is one OmegaProfile(w0, rate, amp, freq, phase)")
        return np.array([OmegaProfile.coerce(w, f"omega[{i}]").array()
                         for i, w in enumerate(omega)])
    return np.tile(OmegaProfile.coerce(omega).array(), (n, 1))


def drive_row(profile: OmegaProfile, force: tuple[float, float] = (0.0, 0.0),
              theta0: float = 0.0) -> np.ndarray:
    """The kernels' drive row.

    Parameters
    ----------
    profile : OmegaProfile
        Ω(t).
    force : (fx, fy)
        Lab-frame force per unit mass [m/s²].
    theta0 : float
        The saddle's angle at t = 0 [rad].

    Returns
    -------
    ndarray, shape (DRIVE_WIDTH,)
    """
    from . import kernels as K  # the row's layout; numba comes with the kernels, not with omega

    row = np.zeros(K.DRIVE_WIDTH)
    row[K.DRIVE_W0], row[K.DRIVE_RATE] = profile.w0, profile.rate
    row[K.DRIVE_AMP], row[K.DRIVE_FREQ] = profile.amp, profile.freq
    row[K.DRIVE_PHASE] = profile.phase
    row[K.DRIVE_THETA0] = theta0
    row[K.DRIVE_FX], row[K.DRIVE_FY] = force
    return row
