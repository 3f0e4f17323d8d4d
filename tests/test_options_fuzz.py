"""Property fuzz of reset options and level options: every draw ends in a ValueError that
names an option, or in a finite first observation of a ball inside the rim with N/mg > 0.

The default suite draws a bounded number of examples; the ``slow`` variants draw many more.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import saddle_env  # noqa: F401  (registers the levels)
from saddle_env.envs import LEVEL_IDS, EnvConfig
from saddle_env.envs.engine import RESET_OPTION_KEYS

# Values from the sensible to the absurd, for every numeric option.
NUMBERS = st.one_of(
    st.floats(-0.2, 0.2), st.floats(-10.0, 10.0), st.floats(-1e12, 1e12),
    st.sampled_from([0.0, 1e-300, -1e-300, 0.0999, 0.1, 45.0, 45.1, 1e308]),
    st.integers(-5, 5),
)
RESET_FIELDS = {
    "x": NUMBERS, "y": NUMBERS, "vx": NUMBERS, "vy": NUMBERS, "omega": NUMBERS,
    "R": NUMBERS, "a": NUMBERS, "spin_normal": NUMBERS,
    "contact": st.sampled_from(["rolling", "slipping", "masspoint", "coulomb", "gliding"]),
    "start": st.sampled_from(["lab-rest", "rotating-rest", "thrown"]),
}
RESET_OPTIONS = st.fixed_dictionaries({}, optional=RESET_FIELDS)
PAIRS = st.tuples(NUMBERS, NUMBERS)
LEVEL_OPTIONS = st.fixed_dictionaries({}, optional={
    "init_offset": NUMBERS, "init_speed": NUMBERS, "omega0_range": PAIRS, "a_range": PAIRS,
    "omega_max": NUMBERS, "rim_radius": NUMBERS, "R": NUMBERS, "a": NUMBERS,
    "init_start": st.sampled_from(["lab-rest", "rotating-rest", "dropped"]),
    "ball_radii": st.lists(NUMBERS, min_size=1, max_size=3).map(tuple),
})



def _any_value_of(kind: object) -> st.SearchStrategy:
    """Values for an EnvConfig field of this type: the right kind, sensible to absurd, and
    the wrong kinds (text for a number, a number for text, None)."""
    args = typing.get_args(kind) if isinstance(kind, types.UnionType) else (kind,)
    options = [st.none(), st.text(max_size=12), NUMBERS, st.booleans()]
    for arg in args:
        if typing.get_origin(arg) is tuple:
            options.append(st.lists(st.one_of(NUMBERS, st.text(max_size=8)), max_size=4).map(tuple))
        elif arg is str:
            options.append(st.sampled_from(["rolling", "slipping", "coulomb", "masspoint",
                                            "voltage", "target", "lab", "rotating", "dop853",
                                            "rk45", "lab-rest", "dropped", ""]))
    return st.one_of(options)


# Every option of EnvConfig, each drawn or left out, over a level.
ALL_OPTIONS = st.fixed_dictionaries({}, optional={
    f.name: _any_value_of(typing.get_type_hints(EnvConfig)[f.name])
    for f in dataclasses.fields(EnvConfig)})
_KNOWN = ("x", "y", "vx", "vy", "omega", "R", "a", "spin_normal", "contact", "start",
          "init_offset", "init_speed", "omega0_range", "a_range", "omega_max", "rim_radius",
          "init_start", "ball_radii", "normal force")


def _check_start(env, obs, info) -> None:
    engine = env.unwrapped.engine
    x, y = engine.Y[0, 0], engine.Y[0, 1]
    assert np.all(np.isfinite(obs)) and np.all(np.isfinite(engine.Y[0]))
    assert math.hypot(x, y) < engine.config.rim_radius
    assert info["N_over_mg"] > 0


def _reset_case(env_id: str, options: dict) -> None:
    env = _ENVS.setdefault(env_id, gym.make(env_id))
    try:
        obs, info = env.reset(seed=0, options=options)
    except ValueError as exc:
        assert any(k in str(exc) for k in _KNOWN), str(exc)
        return
    _check_start(env, obs, info)


def _level_case(env_id: str, kwargs: dict, seed: int) -> None:
    try:
        env = gym.make(env_id, **kwargs)
        obs, info = env.reset(seed=seed)
    except ValueError as exc:
        assert any(k in str(exc) for k in _KNOWN), str(exc)
        return
    _check_start(env, obs, info)
    env.close()


_ENVS: dict[str, gym.Env] = {}
_FAST = settings(max_examples=40, deadline=None, derandomize=True,
                 suppress_health_check=[HealthCheck.too_slow])
_LONG = settings(max_examples=1500, deadline=None,
                 suppress_health_check=[HealthCheck.too_slow])


def _any_options_case(env_id: str, kwargs: dict) -> None:
    try:
        env = gym.make(env_id, **kwargs)
        obs, info = env.reset(seed=0)
    except ValueError as exc:
        assert any(k in str(exc) for k in (*kwargs, *_KNOWN)), str(exc)
        return
    _check_start(env, obs, info)
    obs, reward, *_ = env.step(env.action_space.sample())
    assert np.all(np.isfinite(obs)) and math.isfinite(reward)
    env.close()


def test_every_reset_option_is_fuzzed():
    assert set(RESET_FIELDS) == set(RESET_OPTION_KEYS)


@_FAST
@given(env_id=st.sampled_from(LEVEL_IDS), options=RESET_OPTIONS)
def test_reset_options_fuzz(env_id, options):
    _reset_case(env_id, options)


@_FAST
@given(env_id=st.sampled_from(LEVEL_IDS), kwargs=LEVEL_OPTIONS, seed=st.integers(0, 2 ** 31))
def test_level_options_fuzz(env_id, kwargs, seed):
    _level_case(env_id, kwargs, seed)


@_FAST
@given(env_id=st.sampled_from(LEVEL_IDS), kwargs=ALL_OPTIONS)
def test_every_env_option_fuzz(env_id, kwargs):
    """Any value of any of EnvConfig's options, several at once: a ValueError naming one,
    or an environment that resets and steps."""
    _any_options_case(env_id, kwargs)


@pytest.mark.slow
@_LONG
@given(env_id=st.sampled_from(LEVEL_IDS), kwargs=ALL_OPTIONS)
def test_every_env_option_fuzz_long(env_id, kwargs):
    _any_options_case(env_id, kwargs)


@pytest.mark.slow
@_LONG
@given(env_id=st.sampled_from(LEVEL_IDS), options=RESET_OPTIONS)
def test_reset_options_fuzz_long(env_id, options):
    _reset_case(env_id, options)


@pytest.mark.slow
@_LONG
@given(env_id=st.sampled_from(LEVEL_IDS), kwargs=LEVEL_OPTIONS, seed=st.integers(0, 2 ** 31))
def test_level_options_fuzz_long(env_id, kwargs, seed):
    _level_case(env_id, kwargs, seed)


@pytest.mark.parametrize("value", [0.0, "", (0.1,), [0.2, 0.1]])
def test_a_bad_mu_range_is_a_value_error_naming_it(value):
    # Found by test_every_env_option_fuzz_long: the nominal scene indexed mu_range before it
    # was checked, so a number gave a TypeError.
    with pytest.raises(ValueError, match="mu_range"):
        EnvConfig(contact="coulomb", mu_range=value)
