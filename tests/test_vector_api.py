"""The native vector env speaks Gymnasium 1.x's vector API: the three autoreset modes, each
equal bit for bit to ``SyncVectorEnv`` over ``gym.make`` on every registered level,
``reset_mask``, ``metadata["autoreset_mode"]``, and Gymnasium's own vector wrappers."""

from __future__ import annotations

import gc

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from gymnasium.wrappers import vector as vw

from saddle_env.envs import LEVEL_IDS
from saddle_env.envs.vector import SaddleTrapVectorEnv

NATIVE = "saddle_env.envs.vector:SaddleTrapVectorEnv"
# Every id Gymnasium builds with the native vector env, read from its registry.
VECTOR_IDS = sorted(i for i, spec in gym.registry.items() if spec.vector_entry_point == NATIVE)
MODES = list(AutoresetMode)
# Starts that end episodes within the test: below the threshold speed and up to 3 cm out,
# the centre pushes the balls away; with a 25-step limit the rest are truncated. (init_spread
# 0: the release in init_offset's disc on the real saddle too, whose launcher is 1 mm.)
HARSH = dict(omega0_range=(8.0, 12.0), init_offset=0.03, init_spread=0.0, max_episode_steps=25)


def test_the_registry_builds_every_level_with_the_native_vector_env():
    assert VECTOR_IDS == sorted(LEVEL_IDS)


def assert_same(a, b, where="result"):
    """``a`` and ``b`` equal bit for bit: same types, keys, dtypes, shapes and bytes."""
    assert type(a) is type(b), (where, type(a), type(b))
    if isinstance(a, dict):
        assert a.keys() == b.keys(), (where, sorted(a), sorted(b))
        for key in a:
            assert_same(a[key], b[key], f"{where}[{key!r}]")
    elif isinstance(a, tuple):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, np.ndarray):
        assert (a.dtype, a.shape) == (b.dtype, b.shape), (where, a, b)
        if a.dtype == object:
            for i, (x, y) in enumerate(zip(a, b)):
                assert_same(x, y, f"{where}[{i}]")
        else:
            assert a.tobytes() == b.tobytes(), (where, a, b)
    else:
        assert a == b, (where, a, b)


def pair(env_id: str, mode: AutoresetMode, n: int, **kwargs):
    """The native vector env and SyncVectorEnv over ``gym.make``, same options and mode."""
    native = gym.make_vec(env_id, num_envs=n, autoreset_mode=mode, **kwargs)
    sync = SyncVectorEnv([lambda: gym.make(env_id, **kwargs) for _ in range(n)],
                         autoreset_mode=mode)
    return native, sync


def drive(native, sync, mode: AutoresetMode, steps: int, seed: int = 7, compare=assert_same):
    """Step both with the same random actions, resetting finished balls by mask where
    autoreset is disabled; ``compare`` every result. Returns the terminated and truncated
    counts."""
    n = native.num_envs
    compare(native.reset(seed=seed), sync.reset(seed=seed), "reset")
    rng = np.random.default_rng(seed)
    ended = np.zeros(2, dtype=int)
    for k in range(steps):
        actions = rng.uniform(-1, 1, (n, 1)).astype(np.float32)
        a, b = native.step(actions), sync.step(actions)
        compare(a, b, f"step {k}")
        ended += a[2].sum(), a[3].sum()
        done = a[2] | a[3]
        if mode is AutoresetMode.DISABLED and done.any():
            # SyncVectorEnv pops the mask from the dict it is given: two dicts
            compare(native.reset(options={"reset_mask": done.copy()}),
                    sync.reset(options={"reset_mask": done.copy()}), f"masked reset {k}")
    return ended


@pytest.mark.parametrize("mode", MODES, ids=[m.name for m in MODES])
@pytest.mark.parametrize("env_id", VECTOR_IDS)
def test_every_mode_equals_sync_vector_env_bit_for_bit(env_id, mode):
    native, sync = pair(env_id, mode, 4, **HARSH)
    assert isinstance(native.unwrapped, SaddleTrapVectorEnv)
    assert native.metadata["autoreset_mode"] is mode is sync.metadata["autoreset_mode"]
    terminated, truncated = drive(native, sync, mode, 80)
    assert terminated >= 2 and truncated >= 1   # episodes ended both ways inside the test


@pytest.mark.slow
@pytest.mark.parametrize("mode", MODES, ids=[m.name for m in MODES])
@pytest.mark.parametrize("env_id", VECTOR_IDS)
def test_every_mode_equals_sync_vector_env_over_long_runs(env_id, mode):
    """The levels as registered (500-step limit, their own starts), more balls and steps."""
    native, sync = pair(env_id, mode, 8, max_episode_steps=100)
    terminated, truncated = drive(native, sync, mode, 450, seed=123)
    assert terminated + truncated >= 8


@pytest.mark.parametrize("mode", MODES, ids=[m.name for m in MODES])
def test_a_ball_lost_on_the_last_step_is_terminated_and_truncated_as_time_limit_says(mode):
    # find the step where ball 0 of this seed is lost, then make it the last one
    probe = SaddleTrapVectorEnv(num_envs=1, **HARSH | dict(max_episode_steps=None))
    probe.reset(seed=3)
    last = 0
    while True:
        last += 1
        if probe.step(np.zeros((1, 1), np.float32))[2][0]:
            break
    assert last < 200
    native, sync = pair("SaddleTrap-v0", mode, 1, **HARSH | dict(max_episode_steps=last))
    assert_same(native.reset(seed=3), sync.reset(seed=3))
    for _ in range(last):
        a, b = native.step(np.zeros((1, 1), np.float32)), sync.step(np.zeros((1, 1), np.float32))
        assert_same(a, b)
    assert a[2][0] and a[3][0]


@pytest.mark.parametrize("mode", MODES + [m.value for m in MODES], ids=str)
def test_autoreset_mode_is_taken_as_enum_or_its_value_and_recorded(mode):
    want = AutoresetMode(mode)
    by_id = gym.make_vec("SaddleTrap-v0", num_envs=2, autoreset_mode=mode)
    direct = SaddleTrapVectorEnv(num_envs=2, autoreset_mode=mode)
    for env in (by_id, direct):
        assert env.metadata["autoreset_mode"] is want and env.autoreset_mode is want
    # per instance: the class keeps the default
    assert SaddleTrapVectorEnv.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    assert SaddleTrapVectorEnv(num_envs=1).metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP


@pytest.mark.parametrize("bad", ["next_step", "NEXT_STEP", "", None, 1, ["SameStep"]])
def test_a_bad_autoreset_mode_names_the_parameter_and_the_allowed_values(bad):
    with pytest.raises(ValueError, match=r"autoreset_mode must be one of .*NEXT_STEP.*'NextStep'"
                                         r".*SAME_STEP.*DISABLED.*'Disabled'"):
        gym.make_vec("SaddleTrap-v0", num_envs=2, autoreset_mode=bad)


def test_vector_kwargs_reach_gymnasiums_vectorisers_and_keywords_the_native_env():
    """Gymnasium's make_vec hands ``vector_kwargs`` to SyncVectorEnv/AsyncVectorEnv and
    refuses them for a registered vector env (its keywords carry the options instead), as
    docs/environment.md says; if a Gymnasium release starts passing them, this fails and the
    page needs a new sentence."""
    sync = gym.make_vec("SaddleTrap-v0", num_envs=2, vectorization_mode="sync",
                        vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP})
    assert isinstance(sync, SyncVectorEnv)
    assert sync.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    with pytest.raises(gym.error.Error, match="only through kwargs"):
        gym.make_vec("SaddleTrap-v0", num_envs=2,
                     vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP})


@pytest.mark.parametrize("mask", [[True, False, True], np.array([1, 0, 1]),
                                  np.ones(2, dtype=bool), np.ones((3, 1), dtype=bool),
                                  np.zeros(3, dtype=bool)], ids=str)
def test_a_bad_reset_mask_is_refused_by_name(mask):
    env = SaddleTrapVectorEnv(num_envs=3)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"reset_mask' must be a numpy bool array of shape \(3,\)"):
        env.reset(options={"reset_mask": mask})


def test_disabled_resets_only_the_masked_balls_and_refuses_to_step_a_finished_one():
    native, sync = pair("SaddleTrap-v0", AutoresetMode.DISABLED, 3, **HARSH)
    obs, _ = native.reset(seed=1)
    sync.reset(seed=1)
    zero = np.zeros((3, 1), np.float32)
    done = np.zeros(3, dtype=bool)
    while not done.any():
        obs, _, term, trunc, _ = native.step(zero)
        sync.step(zero)
        done = term | trunc
    state = native.unwrapped.engine.Y.copy()
    with pytest.raises(RuntimeError, match=r"DISABLED: reset them first with .*reset_mask"):
        native.step(zero)
    with pytest.raises(AssertionError):   # what SyncVectorEnv does: it refuses too
        sync.step(zero)
    assert np.array_equal(native.unwrapped.engine.Y, state)   # nothing moved
    again, info = native.reset(options={"reset_mask": done.copy()})
    assert np.array_equal(again[~done], obs[~done])           # the others kept their state
    assert not np.array_equal(again[done], obs[done])
    assert np.array_equal(info["_omega"], done)
    assert np.all(info["time"][done] == 0.0)
    native.step(zero)                                          # steps again


def test_balls_never_reset_cannot_be_stepped():
    env = SaddleTrapVectorEnv(num_envs=3)
    env.reset(seed=0, options={"reset_mask": np.array([True, False, True])})
    with pytest.raises(RuntimeError, match=r"balls \[1\] were never reset"):
        env.step(np.zeros((3, 1), np.float32))
    env.reset(options={"reset_mask": np.array([False, True, False])})
    env.step(np.zeros((3, 1), np.float32))


# -- Gymnasium's vector wrappers --------------------------------------------------------
def _wrappers(env):
    space = env.single_observation_space
    return {
        "NormalizeObservation": lambda e: vw.NormalizeObservation(e),
        "NormalizeReward": lambda e: vw.NormalizeReward(e),
        "ClipReward": lambda e: vw.ClipReward(e, -0.5, 0.5),
        "ClipAction": lambda e: vw.ClipAction(e),
        "RescaleAction": lambda e: vw.RescaleAction(e, np.float32(-2.0), np.float32(2.0)),
        "RescaleObservation": lambda e: vw.RescaleObservation(
            e, np.full(space.shape, -1.0, np.float32), np.full(space.shape, 1.0, np.float32)),
        "DtypeObservation": lambda e: vw.DtypeObservation(e, np.float64),
        "FlattenObservation": lambda e: vw.FlattenObservation(e),
        "DictInfoToList": lambda e: vw.DictInfoToList(e),
    }


WRAPPERS = list(_wrappers(SaddleTrapVectorEnv(num_envs=1)))


def _same_including_lists(a, b, where="result"):
    """`assert_same`, also over the list of per-ball dicts DictInfoToList gives."""
    if isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same_including_lists(x, y, f"{where}[{i}]")
    elif isinstance(a, tuple):
        assert isinstance(b, tuple) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same_including_lists(x, y, f"{where}[{i}]")
    elif isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), (where, sorted(a), sorted(b))
        for key in a:
            _same_including_lists(a[key], b[key], f"{where}[{key!r}]")
    elif isinstance(a, float | int | str | np.floating | np.integer | np.bool_):
        assert type(a) is type(b) and a == b, (where, a, b)
    else:
        assert_same(a, b, where)


# Gymnasium's Box warns when DtypeObservation widens the float32 box; not ours to fix
@pytest.mark.filterwarnings("ignore:overflow encountered in cast:RuntimeWarning")
@pytest.mark.parametrize("mode", MODES, ids=[m.name for m in MODES])
@pytest.mark.parametrize("wrapper", WRAPPERS)
def test_gymnasiums_vector_wrappers_see_the_same_as_over_sync_vector_env(wrapper, mode):
    """Each wrapper over the native env gives bit for bit what it gives over SyncVectorEnv,
    in every mode it supports; where it refuses a mode over SyncVectorEnv, it refuses it
    over the native env too."""
    native, sync = pair("SaddleTrap-Gusty-v0", mode, 3, **HARSH)
    wrap = _wrappers(native)[wrapper]
    try:
        wrapped_sync = wrap(sync)
    except (AssertionError, ValueError, TypeError) as refused:
        with pytest.raises(type(refused)):
            wrap(native)
        return
    terminated, truncated = drive(wrap(native), wrapped_sync, mode, 40,
                                  compare=_same_including_lists)
    assert terminated and truncated


def _same_but_wall_clock(a, b, where="result"):
    """`assert_same` on step results, leaving out RecordEpisodeStatistics' wall-clock times."""
    if len(a) == 5 and "episode" in a[4]:
        a, b = (a[:4] + ({**a[4], "episode": {**a[4]["episode"], "t": None}},),
                b[:4] + ({**b[4], "episode": {**b[4]["episode"], "t": None}},))
    assert_same(a, b, where)


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP],
                         ids=["NEXT_STEP", "SAME_STEP"])
def test_record_episode_statistics_sees_the_same_as_over_sync_vector_env(mode):
    """(DISABLED: SyncVectorEnv pops ``reset_mask`` out of the options before the wrapper
    reads them, so over it the wrapper restarts every ball's tally at a masked reset; the
    native env leaves the caller's options alone, and the next test checks its counts.)"""
    native, sync = pair("SaddleTrap-Gusty-v0", mode, 3, **HARSH)
    terminated, truncated = drive(vw.RecordEpisodeStatistics(native),
                                  vw.RecordEpisodeStatistics(sync), mode, 40,
                                  compare=_same_but_wall_clock)
    assert terminated and truncated


GYMNASIUM = tuple(int(part) for part in gym.__version__.split(".")[:2])


@pytest.mark.parametrize("mode", [
    AutoresetMode.NEXT_STEP, AutoresetMode.DISABLED,
    pytest.param(AutoresetMode.SAME_STEP, marks=pytest.mark.skipif(
        GYMNASIUM < (1, 4), reason="Gymnasium's RecordEpisodeStatistics counts SAME_STEP "
        "episodes from 1.4 on (1.2.2 leaves out the first step of each episode after an "
        "autoreset); "
        "the comparison with SyncVectorEnv above covers the mode"))],
    ids=["NEXT_STEP", "DISABLED", "SAME_STEP"])
def test_record_episode_statistics_counts_every_episode(mode):
    """RecordEpisodeStatistics reports each episode's return and length as summed here."""
    env = vw.RecordEpisodeStatistics(SaddleTrapVectorEnv(num_envs=3, autoreset_mode=mode,
                                                         **HARSH))
    env.reset(seed=2)
    rng = np.random.default_rng(2)
    ret, length = np.zeros(3), np.zeros(3, dtype=int)
    restart = np.zeros(3, dtype=bool)      # NEXT_STEP: the step after an end is a reset
    episodes = 0
    for _ in range(60):
        _, reward, term, trunc, info = env.step(rng.uniform(-1, 1, (3, 1)).astype(np.float32))
        counts = ~restart
        ret[counts] += reward[counts]
        length[counts] += 1
        done = term | trunc
        if done.any():
            assert np.array_equal(info["_episode"], done)
            assert np.array_equal(info["episode"]["r"][done], ret[done])
            assert np.array_equal(info["episode"]["l"][done], length[done])
            episodes += done.sum()
            ret[done], length[done] = 0.0, 0
            if mode is AutoresetMode.DISABLED:
                env.reset(options={"reset_mask": done})
        restart = done if mode is AutoresetMode.NEXT_STEP else np.zeros(3, dtype=bool)
    assert episodes >= 5 and env.episode_count == episodes


# -- a constructor that raised --------------------------------------------------------------
@pytest.mark.filterwarnings("error::pytest.PytestUnraisableExceptionWarning")
@pytest.mark.parametrize("kwargs", [dict(max_episode_steps=0), dict(air_force=-1.0),
                                    dict(render_mode="human"), dict(autoreset_mode="bogus"),
                                    dict(num_envs=0)], ids=str)
def test_a_failed_constructor_leaves_nothing_for_del_to_trip_over(kwargs):
    with pytest.raises(ValueError):
        SaddleTrapVectorEnv(**kwargs)
    gc.collect()   # Gymnasium 1.2's VectorEnv.__del__ calls close() on the half-built env
    half_built = SaddleTrapVectorEnv.__new__(SaddleTrapVectorEnv)
    half_built.close()                    # what that __del__ does, on any Gymnasium
    assert half_built.closed
