"""agents.evaluation.speed_modulation: the statistics it quotes for a policy's speed."""

import numpy as np
import pytest

from agents.evaluation import speed_modulation as sm


def _locked_trace(phase, dt=0.02, seconds=60.0, amp=1.0, mean=8.0):
    """A speed that follows twice the saddle's angle: dθ/dt = Ω = mean + amp cos(2θ + phase)."""
    n = int(seconds / dt) + 1
    theta, omega = np.zeros(n), np.zeros(n)
    for i in range(n):
        omega[i] = mean + amp * np.cos(2 * theta[i] + phase)
        if i + 1 < n:
            theta[i + 1] = theta[i] + omega[i] * dt
    return omega


def test_a_speed_locked_to_twice_the_angle_is_found_with_its_frequency_and_phase():
    omega = _locked_trace(0.7)
    r = np.full_like(omega, 0.006)
    r[-100:] = np.nan                                   # after the episode's end
    out = sm.modulation(omega, r, 0.02, threshold=7.43)
    assert out["twice_angle_r2"] > 0.95
    assert out["twice_angle_amplitude"] == pytest.approx(1.0, rel=0.05)
    assert out["peak_hz"] == pytest.approx(2 * out["turning_hz"], rel=0.05)
    a, b = out["twice_angle_phase_halves"]
    assert abs(np.angle(np.exp(1j * (a - b)))) < 0.1   # one phase through the episode
    assert out["r_mean_mm"] == pytest.approx(6.0) and out["time_s"] == pytest.approx(58.0)
    assert out["below_threshold"] == pytest.approx(np.mean(omega[:-100] < 7.43))


def test_a_speed_that_ignores_the_angle_explains_nothing():
    rng = np.random.default_rng(0)
    omega = 8.0 + rng.normal(0.0, 1.0, 3001)
    out = sm.modulation(omega, np.full(3001, 0.01), 0.02, threshold=7.43)
    assert out["twice_angle_r2"] < 0.01


def test_a_too_short_episode_and_a_bad_count_are_refused(capsys):
    with pytest.raises(ValueError, match="too short"):
        sm.modulation(np.full(5, 8.0), np.full(5, 0.01), 0.02, 7.43)
    assert sm.main(["--policy", "best-const", "--episodes", "0"]) == 2
    assert "--episodes must be in [1, 1000]" in capsys.readouterr().err
