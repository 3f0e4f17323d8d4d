"""The clairvoyant reference (`agents.control.clairvoyant`): its knowledge of the future pays on a
gust `mpc` cannot foresee, it never keeps a ball shorter than `mpc` on the same episode,
it is deterministic and independent of batching, and it runs under ``saddle-eval``."""

import json

import numpy as np
import pytest

from agents.benchmark.headroom import evaluate_clairvoyant
from agents.control.best_constant import best_constant
from agents.control.clairvoyant import BallState, ClairvoyantController
from agents.control.mpc import ModelPredictiveController
from agents.control.rollout import policy_actor, run_episodes
from agents.evaluation.evaluate import main as saddle_eval
from agents.evaluation.policies import BASELINES, load_policy
from saddle_env.envs import EnvConfig, get_level

GUSTY = "SaddleTrap-Gusty-v0"
STEPS = 150                 # 3 s episodes keep the tests short
GUST_SEED = 9_000_011       # a Gusty start that mpc loses to the air current (found below)
# Seeds from 9,000,000 are used by no other part of the project (agents/seeds.py).


def _run(policy, config, seeds, steps=STEPS):
    act, row_independent = policy_actor(policy)
    res = run_episodes(config, act, seeds, max_episode_steps=steps, row_independent=row_independent)
    return res, act


@pytest.fixture(scope="module")
def gusty():
    return get_level(GUSTY).config()


def test_registered_as_a_baseline(gusty):
    assert "clairvoyant" in BASELINES
    policy = load_policy("clairvoyant", gusty)
    assert policy.name == "clairvoyant"
    with pytest.raises(RuntimeError, match="reads the environment"):
        policy.predict(np.zeros(policy.input_dim, dtype=np.float32))


@pytest.mark.slow  # an end-to-end run: CI runs it with -m slow
def test_foresight_beats_mpc_on_a_gust(gusty):
    """Episode GUST_SEED: the same start in still air (the same draws up to the air current's)
    is kept by the same mpc (same reference speed) for the whole episode;
    with the level's air current mpc, which only estimates the push after it has moved the
    ball, loses it early (escape). The clairvoyant, which knows the coming gust, keeps the
    ball longer, and its record of mpc's episode is exactly what mpc did."""
    still = EnvConfig.from_kwargs(**{**gusty.as_dict(), "air_force": 0.0})
    same_mpc = ModelPredictiveController(still, omega_ref=best_constant(gusty)["omega"])
    calm, _ = _run(same_mpc, still, [GUST_SEED])
    assert calm["kept"][0]
    mpc, _ = _run(load_policy("mpc", gusty), gusty, [GUST_SEED])
    assert mpc["cause"][0] == "escape" and mpc["time"][0] < 2.0
    clair, act = _run(ClairvoyantController(gusty), gusty, [GUST_SEED])
    assert act.plans[0].mpc_time == mpc["time"][0]
    assert clair["time"][0] > mpc["time"][0] + 0.5
    assert act.plans[0].time == clair["time"][0]   # the plan's score is what happened


def test_never_shorter_than_mpc(gusty):
    """On every episode (not on average) the clairvoyant keeps the ball at least as long as
    mpc: its first plan is mpc's own episode, and a plan is replaced only by a better one."""
    seeds = list(range(9_000_000, 9_000_006)) + [GUST_SEED]
    mpc, _ = _run(load_policy("mpc", gusty), gusty, seeds)
    clair, act = _run(ClairvoyantController(gusty, max_rounds=60), gusty, seeds)
    np.testing.assert_array_equal([p.mpc_time for p in act.plans], mpc["time"])
    assert np.all(clair["time"] >= mpc["time"])
    assert clair["time"].sum() > mpc["time"].sum()   # GUST_SEED's ball is kept longer


def test_never_shorter_than_the_shipped_agent(gusty):
    """The level's shipped agent is an incumbent too: its episode, run on the copy in a batch
    of CHUNK balls as saddle-eval runs model files, is what saddle-eval measures, and the
    clairvoyant keeps every ball at least that long."""
    from agents.control.clairvoyant import shipped_agents

    (path,) = shipped_agents(gusty)
    seeds = [9_000_000, GUST_SEED]
    agent, _ = _run(load_policy(str(path), gusty), gusty, seeds, steps=80)
    clair, act = _run(ClairvoyantController(gusty, max_rounds=5, agents=True,
                                            loader=load_policy), gusty, seeds, steps=80)
    np.testing.assert_array_equal([p.incumbents[path.name] for p in act.plans], agent["time"])
    assert np.all(clair["time"] >= agent["time"])


@pytest.mark.slow  # an end-to-end run: CI runs it with -m slow
def test_deterministic_and_batch_independent(gusty):
    one, a1 = _run(ClairvoyantController(gusty, max_rounds=20), gusty, [GUST_SEED])
    two, a2 = _run(ClairvoyantController(gusty, max_rounds=20), gusty, [GUST_SEED])
    np.testing.assert_array_equal(a1.plans[0].actions, a2.plans[0].actions)
    assert one["time"][0] == two["time"][0]
    many, a3 = _run(ClairvoyantController(gusty, max_rounds=20), gusty,
                    [9_000_003, GUST_SEED, 9_000_004])
    np.testing.assert_array_equal(a1.plans[0].actions, a3.plans[1].actions)
    assert many["time"][1] == one["time"][0]


def test_plan_is_checked_against_the_environment(gusty):
    """An environment that is not the copy the plan was made on is an error, not a silent
    loss of the guarantee."""
    from saddle_env.envs.vector import SaddleTrapVectorEnv

    env = SaddleTrapVectorEnv(num_envs=1, max_episode_steps=10, **gusty.as_dict())
    obs, _ = env.reset(seed=[9_000_001])
    act = ClairvoyantController(gusty, max_rounds=0).episode_actor()
    act.start(1)
    act.attach(env, 10)
    a = act(obs, np.array([0]))
    env.step(a.reshape(1, 1))
    env.engine.Y[0, 0] += 1e-12        # the world moved off the plan
    with pytest.raises(RuntimeError, match="left its plan"):
        act(obs, np.array([0]))


def test_ball_state_round_trip(gusty):
    from saddle_env.envs.vector import SaddleTrapVectorEnv

    env = SaddleTrapVectorEnv(num_envs=2, max_episode_steps=10, **gusty.as_dict())
    env.reset(seed=[1, 2])
    st = BallState.capture(env.engine, env._rngs, 1)
    draw = env._rngs[1].normal(size=3)          # the copy keeps the future draws
    np.testing.assert_array_equal(st.rng.normal(size=3), draw)


def test_evaluate_reports_doomed_share(gusty):
    r = evaluate_clairvoyant(GUSTY, 3, seed=9_000_009, max_episode_steps=20, max_rounds=5,
                             agents=False)
    assert r["episodes"] == 3 and len(r["time"]) == 3
    d = r["doomed"]
    assert 0.0 <= d["low"] <= d["mean"] <= d["high"] <= 1.0
    assert np.all(r["time"] >= r["mpc_time"])
    assert r["seconds_per_episode"] > 0


def test_saddle_eval_runs_the_clairvoyant(capsys):
    assert saddle_eval(["--policy", "clairvoyant", "--policy", "mpc", "--env", GUSTY,
                        "--episodes", "2", "--max-episode-steps", "25", "--json",
                        "--no-progress"]) == 0
    table = json.loads(capsys.readouterr().out)
    rows = {row["policy"]: row for row in table["policies"]}
    assert rows["clairvoyant"]["trapping_time"]["mean"] >= rows["mpc"]["trapping_time"]["mean"]


def test_a_batch_the_integrator_cannot_follow_changes_nothing(gusty, monkeypatch):
    """A candidate batch that fails to integrate is skipped, not fatal, and the plan still
    keeps the ball at least as long as mpc."""
    import agents.control.clairvoyant as C
    from saddle_env.simulate import SimulationError

    real, calls = C.run_plans, []

    def flaky(engine, rngs, plans):
        calls.append(len(plans))
        if len(calls) == 1:
            raise SimulationError("step limit")
        return real(engine, rngs, plans)

    monkeypatch.setattr(C, "run_plans", flaky)
    clair, act = _run(ClairvoyantController(gusty, max_rounds=3), gusty, [GUST_SEED])
    assert len(calls) >= 2 and act.plans[0].rounds == 3
    assert clair["time"][0] >= act.plans[0].mpc_time


def test_on_the_rig_candidates_hold_voltages_and_plans_replay_through_the_latency():
    """In voltage mode a candidate holds the voltage of a steady speed (a held voltage holds
    its speed, as a held target does), not an acceleration's ±1; and on the Lab level, whose
    camera is 30 ms late, mpc's episode on the copy is what mpc does in the environment."""
    from agents.control.clairvoyant import ClairvoyantPlanner
    from saddle_env.envs.vector import SaddleTrapVectorEnv

    # a motor whose top steady speed (30 rad/s) is not omega_max: voltage is not target
    lab = get_level("SaddleTrap-Lab-v0").config(motor_gain=1.25)
    env = SaddleTrapVectorEnv(num_envs=1, max_episode_steps=10, **lab.as_dict())
    env.reset(seed=[9_000_001])
    planner = ClairvoyantPlanner(lab)
    state = BallState.capture(env.engine, env._rngs, 0)
    plans = planner._candidates(state, np.zeros(50, dtype=np.float32), np.random.default_rng(0))
    held = 2.0 * planner._speeds(state) / (lab.motor_gain * lab.voltage_max) - 1.0
    for v in np.minimum(held, 1.0):
        assert np.any(np.all(np.abs(plans - np.float32(v)) < 1e-6, axis=1)), v
    level = get_level("SaddleTrap-Lab-v0").config()
    seeds = [9_000_000, 9_000_001]
    mpc, _ = _run(load_policy("mpc", level), level, seeds, steps=40)
    clair, act = _run(ClairvoyantController(level, max_rounds=5), level, seeds, steps=40)
    np.testing.assert_array_equal([p.mpc_time for p in act.plans], mpc["time"])
    assert np.all(clair["time"] >= mpc["time"])
