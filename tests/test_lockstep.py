"""The SIMD block step (saddle_env.lockstep) gives exactly the scalar integrator's results.

The environment steps balls that fit one integrator step per control period in blocks,
vectorised across balls; every other ball (and every lane whose step the scalar integrator
would reject, or that meets an event) takes `integrate_h`. These tests run the same episodes
through an engine with the block path and one without, and demand bit-identical states,
observations, rewards, events and step-size hints, step after step, across resets.
"""

from __future__ import annotations

import numpy as np
import pytest

from saddle_env.envs import control_step as S
from saddle_env.envs.config import EnvConfig
from saddle_env.envs.engine import TrapEngine

CONFIGS = {
    "default": {},
    "mixed-models": dict(contact_models=("rolling", "slipping", "point"),
                         ball_radii=(0.0223, 0.0265, 0.033), a_range=(0.17, 0.23)),
    "disturbed": dict(air_force=0.08, ripple_amp=1.0, omega0_range=(8.0, 25.0),
                      position_noise=1e-4, omega_noise=0.1),
    # fast enough to detach soon, not so fast that N <= 0 at t = 0 (which reset refuses)
    "detaching": dict(omega0_range=(30.0, 36.0), init_start="rotating-rest", init_offset=0.02,
                      R=0.033, action_mode="target"),
    "escaping": dict(omega0_range=(2.0, 9.0), init_speed=0.05),
    "dopri5": dict(method="dopri5", rtol=1e-6),
    "rk4-one-step": dict(method="rk4", substep=0.02),
    "rk4-substeps": dict(method="rk4", substep=0.005),
    "tight": dict(rtol=1e-12),
    "lab-frame": dict(obs_frame="lab", distance_cost=0.3, effort_cost=0.1),
    # every observation column the layouts have, and a camera's (the lanes are booked
    # together, `control_step._finish_lanes`: each layout's columns there too)
    "observed-everything": dict(observe_command=True, observe_angle=True, position_noise=1e-4,
                                velocity_noise=1e-3, omega_noise=0.1, position_quantum=1e-4),
    "lab-camera-voltage": dict(obs_frame="lab", observe_velocity=False, position_quantum=2.5e-4,
                               action_mode="voltage"),
    "lab-frame-command": dict(obs_frame="lab", observe_command=True, velocity_noise=1e-3),
    "tilted": dict(tilt=0.03, ripple_amp=1.0),
}

ARRAYS = ("Y", "balls", "out", "obs")
EVENT_OF = {"detaching": "detach", "escaping": "escape"}


def _run_pair(kwargs, n=40, steps=120, parallel=False, seed=7):
    config = EnvConfig.from_kwargs(**kwargs)
    engines = [TrapEngine(config, n, parallel=parallel, lockstep=flag) for flag in (True, False)]
    rngs = [[np.random.default_rng(seed + i) for i in range(n)] for _ in engines]
    for e, r in zip(engines, rngs):
        e.reset(np.arange(n), r)
    action_rng = np.random.default_rng(seed)
    causes = []
    for k in range(steps):
        actions = action_rng.uniform(-1, 1, n)
        active = np.ones(n, dtype=bool)
        for e, r in zip(engines, rngs):
            e.step(actions, active, r)
        for name in ARRAYS:
            a, b = (getattr(e, name) for e in engines)
            assert np.array_equal(a, b, equal_nan=True), (name, k)
        lost = np.flatnonzero(engines[0].out[:, S.O_STATUS] != 0)
        causes += [engines[0].cause(i) for i in lost]
        if lost.size:
            for e, r in zip(engines, rngs):
                e.reset(lost, r)
    return engines, causes


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_block_path_is_bit_identical_to_the_scalar_path(name):
    _, causes = _run_pair(CONFIGS[name])
    if name in EVENT_OF:  # the events (and their fallback to the scalar path) were exercised
        assert causes.count(EVENT_OF[name]) > 10, causes


def test_block_path_carries_most_steps_by_default():
    """The comparison above is not vacuous: with the block path on, the scalar integrator
    takes only the first step of each episode (its stats sit in the engine's int scratch)."""
    engines, _ = _run_pair({}, steps=60)
    with_blocks, scalar_only = (int(e._iscratch[0]) for e in engines)
    assert scalar_only >= 40 * 60
    assert with_blocks <= 40 * 2


def test_parallel_chunks_match_the_serial_block_path():
    config = EnvConfig.from_kwargs(**CONFIGS["mixed-models"])
    n = 300  # several chunks per thread, partial blocks at chunk ends
    engines = [TrapEngine(config, n, parallel=p) for p in (True, False)]
    rngs = [[np.random.default_rng(i) for i in range(n)] for _ in engines]
    for e, r in zip(engines, rngs):
        e.reset(np.arange(n), r)
    act_rng = np.random.default_rng(1)
    active = np.ones(n, dtype=bool)
    active[::7] = False  # inactive balls are skipped and untouched
    frozen = engines[0].Y[~active].copy()
    for _ in range(40):
        actions = act_rng.uniform(-1, 1, n)
        for e, r in zip(engines, rngs):
            e.step(actions, active, r)
        for name in ARRAYS:
            a, b = (getattr(e, name) for e in engines)
            assert np.array_equal(a, b, equal_nan=True), name
    assert np.array_equal(engines[0].Y[~active], frozen)


def test_a_dip_of_N_inside_a_block_step_goes_to_the_scalar_path():
    """N < 0 from t = 0.2410 s to 0.3058 s (test_integrators' case): with one fixed step per
    0.08 s control period, the step 0.24 → 0.32 s has N > 0 at both ends. The block step
    must hand it to the scalar path, which finds the detachment inside."""
    config = EnvConfig.from_kwargs(method="dop853", substep=0.08, control_period=0.08)
    place = {"x": 0.005, "y": 0.005, "omega": 30.0, "start": "rotating-rest", "R": 0.033}
    events = []
    n = S.MIN_BLOCK  # the smallest block
    for flag in (True, False):
        e = TrapEngine(config, n, parallel=False, lockstep=flag)
        rngs = [np.random.default_rng(i) for i in range(n)]
        e.reset(np.arange(n), rngs, place)
        for _ in range(5):
            e.step(np.zeros(n), np.ones(n, dtype=bool), rngs)
            if e.out[0, S.O_STATUS] != 0:
                break
        events.append((e.cause(0), e.balls[0, S.B_TIME]))
    assert events[0] == events[1]
    assert events[0][0] == "detach" and abs(events[0][1] - 0.2410) < 1e-3


def _random_config(rng):
    """A valid configuration drawn across the options the block path depends on."""
    a = rng.uniform(0.12, 0.3)
    omega_max = rng.uniform(25.0, 60.0)
    lo = rng.uniform(0.0, 0.8 * omega_max)
    kw = dict(a=a, b=a * rng.uniform(0.6, 1.5), R=rng.uniform(0.005, 0.4 * a),
              alpha=rng.choice([0.4, 2 / 3]), contact=str(rng.choice(["rolling", "slipping",
                                                                      "point"])),
              control_period=rng.uniform(0.005, 0.025), max_accel=rng.uniform(5.0, 60.0),
              omega_max=omega_max, omega0_range=(lo, rng.uniform(lo, omega_max)),
              action_mode=str(rng.choice(["acceleration", "target"])),
              obs_frame=str(rng.choice(["rotating", "lab"])),
              init_offset=rng.uniform(0.001, 0.03), init_speed=rng.choice([0.0, 0.03]),
              init_start=str(rng.choice(["lab-rest", "rotating-rest"])),
              drilling_friction=rng.choice([0.0, 0.5]),
              air_force=rng.choice([0.0, 0.1]), ripple_amp=rng.choice([0.0, 1.5]),
              ripple_freq=rng.uniform(5.0, 80.0))
    # Mostly settings under which a step covers the control period (the block path's case).
    method = rng.choice(["dop853", "dop853", "dopri5", "rk4"])
    if method == "rk4":
        kw.update(method="rk4", substep=kw["control_period"] * rng.choice([1.0, 2.0]))
    elif method == "dopri5":
        kw.update(method="dopri5", rtol=10.0 ** rng.uniform(-6, -4))
    else:
        kw.update(method="dop853", rtol=10.0 ** rng.uniform(-9, -5))
    return kw


@pytest.mark.parametrize("seed", range(12))
def test_block_path_is_bit_identical_on_random_configurations(seed):
    kwargs = _random_config(np.random.default_rng(seed))
    engines, _ = _run_pair(kwargs, n=24, steps=60, seed=seed)
    with_blocks, scalar_only = (int(e._iscratch[0]) for e in engines)
    assert with_blocks < scalar_only  # the block path took some of the steps
