"""The rig's parts (issue 42): exact delays, the voltage-driven motor, camera observations."""

import gymnasium as gym
import numpy as np
import pytest

from saddle_env.envs import SaddleTrapEnv
from saddle_env.envs.config import EnvConfig
from saddle_env.envs.engine import DelayPlan

T = 0.02  # the default control period
# Every contact model (coulomb with its friction coefficient).
MODELS = [dict(contact="rolling"), dict(contact="slipping"), dict(contact="point"),
          dict(contact="coulomb", mu=0.05)]


def _run(actions, seed=3, **kwargs):
    """Observations (reset's first) and rewards of a run of ``actions`` from a fixed start."""
    env = SaddleTrapEnv(**kwargs)
    obs, _ = env.reset(seed=seed)
    trace, rewards = [obs], []
    for a in actions:
        obs, r, te, _, _ = env.step(np.array([a], np.float32))
        trace.append(obs)
        rewards.append(r)
        assert not te, "the test's run must keep the ball"
    return np.array(trace), np.array(rewards)


def _actions(n, seed=0, scale=0.5):
    return np.random.default_rng(seed).uniform(-scale, scale, n)


def test_delay_plan_splits_a_period_where_a_sample_or_a_command_falls():
    plan = DelayPlan(EnvConfig(obs_delay=0.06, action_delay=0.025))
    assert (plan.obs_periods, plan.sample_at) == (3, T)   # 0.06/0.02 = 2.9999999999999996
    assert plan.act_periods == 1 and plan.switch_at == pytest.approx(0.005)
    assert plan.segments == ((0.0, plan.switch_at), (plan.switch_at, T))
    plan = DelayPlan(EnvConfig(obs_delay=0.03))
    assert plan.obs_periods == 1 and plan.sample_at == pytest.approx(0.01)
    assert len(plan.segments) == 2 and not DelayPlan(EnvConfig()).active
    # 0.03 - 0.02 = 0.009999999999999998: the sample and the switch are one cut, not two
    plan = DelayPlan(EnvConfig(obs_delay=0.03, action_delay=0.01))
    assert len(plan.segments) == 2 and plan.sample_at == plan.switch_at


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m["contact"])
def test_obs_delay_of_whole_periods_shifts_the_observations(model):
    acts = _actions(40)
    ref, ref_r = _run(acts, **model)
    for k, delay in ((1, T), (3, 0.06)):
        got, got_r = _run(acts, obs_delay=delay, **model)
        assert np.array_equal(got[k:], ref[:-k])     # bit for bit, k steps late
        assert np.array_equal(got[:k + 1], np.repeat(ref[:1], k + 1, axis=0))
        assert np.array_equal(got_r, ref_r)          # the reward is the present's


def test_frames_in_flight_are_the_next_observations_in_order():
    """What the camera took and has not shown yet (the simulated rig's frames of a lost
    ball): with a delay of 3 periods, the three frames the next three steps show."""
    env = SaddleTrapEnv(obs_delay=0.06)
    env.reset(seed=3)
    acts = _actions(12)
    for a in acts[:6]:
        env.step(np.array([a], np.float32))
    in_flight = env.engine.frames_in_flight(0)
    assert in_flight.shape == (3, env.engine.frame_dim)
    for k, a in enumerate(acts[6:9]):
        env.step(np.array([a], np.float32))
        assert np.array_equal(env.engine.frame[0], in_flight[k])
    assert SaddleTrapEnv().engine.frames_in_flight(0).shape[0] == 0


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m["contact"])
def test_half_period_obs_delay_equals_a_run_at_half_the_period(model):
    # An observation half a period old is the state in the middle of the period: what a run
    # at half the control period observes there, with each command held for two of its steps.
    acts = _actions(30)
    got, _ = _run(acts, obs_delay=T / 2, **model)
    half, _ = _run(np.repeat(acts, 2), control_period=T / 2, **model)
    assert np.allclose(got[1:], half[1::2], rtol=0, atol=2e-6)
    assert not np.allclose(got[1:], half[2::2], rtol=0, atol=2e-6)  # not the period's end


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m["contact"])
def test_action_delay_of_whole_periods_shifts_the_commands(model):
    acts = _actions(40)
    for k, delay in ((1, T), (2, 0.04)):
        got, _ = _run(acts, action_delay=delay, **model)
        # until the first command arrives the motor holds its speed: action 0
        ref, _ = _run(np.concatenate([np.zeros(k), acts]), **model)
        assert np.array_equal(got, ref[:len(got)])


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m["contact"])
def test_half_period_action_delay_equals_a_run_at_half_the_period(model):
    acts = _actions(30)
    got, _ = _run(acts, action_delay=T / 2, **model)
    half, _ = _run(np.concatenate([[0.0], np.repeat(acts, 2)[:-1]]), control_period=T / 2,
                   **model)
    assert np.allclose(got, half[::2], rtol=0, atol=2e-6)


def test_delays_with_target_and_voltage_modes_hold_the_speed_until_the_first_command():
    for mode in ("target", "voltage"):
        env = SaddleTrapEnv(action_mode=mode, action_delay=0.05)
        env.reset(seed=0)
        w0 = env.omega
        for _ in range(2):  # 40 ms: the command given at t = 0 has not arrived
            env.step(np.array([1.0], np.float32))
            assert env.omega == pytest.approx(w0, abs=1e-12)
        env.step(np.array([1.0], np.float32))  # it arrives 10 ms into the third period
        assert env.omega > w0 + 0.1


@pytest.mark.parametrize("kwargs", [
    dict(obs_delay=0.033, action_delay=0.011, position_noise=1e-3, air_force=0.1),
    dict(obs_delay=0.027, action_delay=0.045, action_mode="voltage", contact_models=(
        "rolling", "slipping"), ball_radii=(0.0223, 0.033), obs_history=3),
])
def test_delayed_vector_env_equals_single_envs_with_autoreset(kwargs):
    n, steps = 4, 120
    kw = dict(kwargs, omega0_range=(8.0, 20.0), init_offset=0.03)
    venv = gym.make_vec("SaddleTrap-v0", num_envs=n, max_episode_steps=40, **kw)
    singles = [gym.make("SaddleTrap-v0", max_episode_steps=40, **kw) for _ in range(n)]
    vo, _ = venv.reset(seed=5)
    assert np.array_equal(vo, np.array([s.reset(seed=5 + i)[0] for i, s in enumerate(singles)]))
    rng = np.random.default_rng(1)
    pending, resets, lost = [False] * n, 0, 0
    for _ in range(steps):
        acts = rng.uniform(-1, 1, size=(n, 1)).astype(np.float32)
        vo, vr, vt, _, _ = venv.step(acts)
        for i, s in enumerate(singles):
            if pending[i]:
                o, _ = s.reset()
                r, te, pending[i] = 0.0, False, False
                resets += 1
            else:
                o, r, te, tr, _ = s.step(acts[i])
                pending[i] = te or tr
                lost += te
            assert np.array_equal(o, vo[i]) and r == vr[i] and te == vt[i]
    assert resets >= 4 and lost >= 1  # autoreset and a loss inside a split period


def test_seeded_delayed_rollouts_are_deterministic_and_the_loss_is_booked_once():
    kw = dict(obs_delay=0.031, action_delay=0.007, position_noise=1e-3, omega0_range=(8, 11),
              init_offset=0.03, ball_radii=(0.0223, 0.033))

    def roll(seed):
        env = gym.make("SaddleTrap-v0", **kw)
        env.reset(seed=seed)
        rng = np.random.default_rng(0)
        out = []
        for _ in range(300):
            o, r, te, _, info = env.step(rng.uniform(-1, 1, 1).astype(np.float32))
            out.append(np.concatenate([o, [r, info["trapped_fraction"]]]))
            if te:
                # the lost step: trapped until the event, less the penalty, nothing else
                assert r == pytest.approx(info["trapped_fraction"] - 10.0)
                assert 0 <= info["trapped_fraction"] < 1
                assert info["event_time"] == pytest.approx(
                    (len(out) - 1 + info["trapped_fraction"]) * T, abs=1e-9)
                break
            assert r == 1.0
        return np.array(out), te

    a, lost = roll(4)
    assert lost
    assert np.array_equal(a, roll(4)[0])
    assert not np.array_equal(a[:5], roll(5)[0][:5])


@pytest.mark.parametrize("name, value, message", [
    ("obs_delay", -0.01, "obs_delay must be >= 0"),
    ("action_delay", float("nan"), "action_delay"),
    ("obs_delay", 11.0, "obs_delay must be <= 10 s"),
])
def test_bad_delays(name, value, message):
    with pytest.raises(ValueError, match=message):
        EnvConfig(**{name: value})


# -- the voltage-driven motor ---------------------------------------------------------------

def test_voltage_mode_matches_an_independent_integration_with_omega_as_a_state():
    """The env's drive row carries Ω(t) in closed form; scipy integrates τ Ω̇ = K V − Ω and the
    saddle's angle as two more states beside the ball's (the ball's rates from the shared
    kernel, fed the Ω and Ω̇ of the moment)."""
    from scipy.integrate import solve_ivp

    from saddle_env import kernels as K

    kw = dict(action_mode="voltage", rtol=1e-11, air_force=0.3, ripple_amp=0.7,
              ripple_freq=25.0)
    env = SaddleTrapEnv(**kw)
    env.reset(seed=2)
    eng = env.engine
    cfg = env.config
    tau = cfg.motor_tau
    model, p = int(eng.models[0]), eng.P[0].copy()
    n = env.scene.state_size
    phase = eng.balls[0, 3]
    z = np.concatenate([env.state, [env.omega, 0.0]])
    drive, dy = np.zeros(K.DRIVE_WIDTH), np.zeros(K.STATE_WIDTH)

    def f(t, z, V):
        w = z[n]
        wdot = (cfg.motor_gain * V - w) / tau
        drive[:] = 0.0
        drive[K.DRIVE_W0], drive[K.DRIVE_RATE] = w, wdot  # at this instant (t' = 0 of the row)
        drive[K.DRIVE_AMP], drive[K.DRIVE_FREQ] = cfg.ripple_amp, cfg.ripple_freq
        drive[K.DRIVE_PHASE] = phase + cfg.ripple_freq * t
        drive[K.DRIVE_THETA0] = z[n + 1] + cfg.ripple_amp / cfg.ripple_freq * (
            np.cos(phase) - np.cos(phase + cfg.ripple_freq * t))
        drive[K.DRIVE_FX], drive[K.DRIVE_FY] = eng.balls[0, 4], eng.balls[0, 5]  # this step's
        y = np.zeros(K.STATE_WIDTH)
        y[:n] = z[:n]
        K.rhs(model, p, drive, 0.0, y, dy, False)
        return np.concatenate([dy[:n], [wdot, w]])

    volts = np.random.default_rng(1).uniform(-1, 1, 25).astype(np.float32)
    for k, a in enumerate(volts):
        _, _, te, _, info = env.step(np.array([a], np.float32))
        assert not te
        V = 0.5 * (float(a) + 1) * cfg.voltage_max
        sol = solve_ivp(f, (k * T, (k + 1) * T), z, method="DOP853", rtol=1e-12, atol=1e-13,
                        args=(V,))
        z = sol.y[:, -1]
        assert info["omega"] == pytest.approx(z[n], abs=1e-9)          # Ω: the motor's lag
        t = (k + 1) * T   # θ: the motor's integral plus the ripple's
        theta = z[n + 1] + cfg.ripple_amp / cfg.ripple_freq * (
            np.cos(phase) - np.cos(phase + cfg.ripple_freq * t))
        assert eng.balls[0, 1] == pytest.approx(theta, abs=1e-9)
        assert np.allclose(env.state, z[:n], rtol=0, atol=1e-8)         # the ball
    assert abs(z[n] - 20) > 1  # the motor moved


def test_voltage_mode_relaxes_to_gain_times_voltage_with_the_motor_time_constant():
    env = SaddleTrapEnv(action_mode="voltage", motor_tau=0.1, motor_gain=1.5, voltage_max=20.0,
                        omega_max=30.0)
    env.reset(seed=0, options={"omega": 20.0})
    for k in range(1, 11):
        _, _, _, _, info = env.step(np.array([0.5], np.float32))  # V = 15 V: K V = 22.5
        assert info["omega"] == pytest.approx(22.5 - 2.5 * np.exp(-k * T / 0.1), rel=1e-13)


def test_voltage_mode_options_are_checked():
    with pytest.raises(ValueError, match="motor_gain \\* voltage_max"):
        EnvConfig(action_mode="voltage", motor_gain=2.0)
    with pytest.raises(ValueError, match="motor_tau must be > 0"):
        EnvConfig(action_mode="voltage", motor_tau=0.0)
    with pytest.raises(ValueError, match="omega0_range must lie within"):
        EnvConfig(action_mode="voltage", motor_gain=0.5, omega0_range=(15.0, 25.0))
    with pytest.raises(ValueError, match="action_mode must be one of"):
        EnvConfig(action_mode="current")
    with pytest.raises(ValueError, match="observe_command needs a speed servo"):
        EnvConfig(action_mode="voltage", observe_command=True)


# -- camera observations --------------------------------------------------------------------

@pytest.mark.parametrize("kw", [dict(), dict(obs_frame="lab", observe_command=True),
                                dict(observe_angle=True, observe_command=True, obs_history=2)])
def test_a_camera_sees_the_positions_and_everything_else_but_the_velocities(kw):
    full, cam = SaddleTrapEnv(**kw), SaddleTrapEnv(observe_velocity=False, **kw)
    assert cam.observation_space.shape[0] == full.observation_space.shape[0] - 2 * (
        kw.get("obs_history", 1))
    a, _ = full.reset(seed=1)
    b, _ = cam.reset(seed=1)
    for _ in range(5):
        d = full.engine.frame_dim
        keep = np.r_[0:2, 4:d]           # every column of a frame but the velocities
        frames_full = a.reshape(-1, d)
        frames_cam = b.reshape(-1, d - 2)
        assert np.array_equal(frames_cam, frames_full[:, keep])
        assert cam.observation_space.contains(b)
        a, *_ = full.step(np.array([0.3], np.float32))
        b, *_ = cam.step(np.array([0.3], np.float32))
    assert cam.engine.layout.omega == full.engine.layout.omega - 2


def test_position_quantum_rounds_positions_to_pixels_after_the_noise():
    q, rim = 5e-4, 0.1
    exact = SaddleTrapEnv(position_noise=1e-3, observe_velocity=False)
    pix = SaddleTrapEnv(position_noise=1e-3, position_quantum=q, observe_velocity=False)
    a, _ = exact.reset(seed=7)
    b, _ = pix.reset(seed=7)
    for _ in range(20):
        assert np.allclose(b[:2] * rim, np.round(a[:2] * rim / q) * q, rtol=0, atol=1e-9)
        assert np.allclose(b[:2] * rim / q, np.round(b[:2] * rim / q), atol=1e-4)  # on pixels
        assert b[2] == a[2]   # the tachometer as it was
        a, *_ = exact.step(np.array([0.1], np.float32))
        b, *_ = pix.step(np.array([0.1], np.float32))
    with pytest.raises(ValueError, match="position_quantum must be >= 0"):
        EnvConfig(position_quantum=-1e-3)


# -- mpc on the rig ---------------------------------------------------------------------

def _lab(**overrides):
    from saddle_env.envs import level_config

    # no draught or noise unless asked: what is tested is the estimator and the delays
    base = dict(air_force=0.0, ripple_amp=0.0, position_noise=0.0, omega_noise=0.0,
                position_quantum=0.0, ball_radii=None, obs_history=1)
    return level_config("SaddleTrap-Lab-v0", **{**base, **overrides})


def test_mpc_estimates_velocities_from_positions_through_the_camera_delay():
    from agents.control.mpc import ModelPredictiveController
    from saddle_env.envs.observation import VELOCITY_SCALE

    config = _lab(obs_delay=0.04)   # two whole periods: the truth is the state two steps back
    env = SaddleTrapEnv(**config.as_dict())
    mpc = ModelPredictiveController(config, omega_ref=20.0)
    obs, _ = env.reset(seed=3)
    state, truth, errors = None, [], []
    for k in range(40):
        v = np.empty((1, 4))
        from agents.control.mpc import _centre_states
        _centre_states(int(env.engine.models[0]), env.engine.P[0], env.engine.Y[:1], v)
        truth.append(v[0, 2:])
        action, state = mpc.predict(obs, state, episode_start=np.array([k == 0]))
        if k >= 2:
            estimate = state[0, 1 + 2:1 + 4] * VELOCITY_SCALE
            errors.append(np.abs(estimate - truth[k - 2]).max())
        obs, _, te, _, _ = env.step(action)
        assert not te
    speed = np.abs(np.array(truth)).max()
    assert speed > 0.05                           # the ball moves
    assert max(errors[10:]) < 0.02 * speed        # and the estimate follows it


def test_mpc_blind_and_aware_agree_without_delays_and_differ_with_them():
    from agents.control.mpc import ModelPredictiveController

    def actions(config):
        env = SaddleTrapEnv(**config.as_dict())
        out = []
        for aware in (True, False):
            mpc = ModelPredictiveController(config, omega_ref=20.0, delay_aware=aware)
            obs, _ = env.reset(seed=5)
            state, acts = None, []
            for k in range(15):
                a, state = mpc.predict(obs, state, episode_start=np.array([k == 0]))
                obs, *_ = env.step(a)
                acts.append(float(a[0]))
            out.append(acts)
        return out

    aware, blind = actions(_lab(obs_delay=0.0))
    assert aware == blind
    aware, blind = actions(_lab(obs_delay=0.03, action_delay=0.01))
    assert aware != blind


def test_the_clairvoyant_copies_of_a_delayed_engine_carry_its_queues():
    from agents.control.clairvoyant import BallState, copy_engine
    from saddle_env.envs.vector import SaddleTrapVectorEnv

    env = SaddleTrapVectorEnv(num_envs=2, max_episode_steps=None, obs_delay=0.03,
                              action_delay=0.01)
    env.reset(seed=1)
    for a in (0.3, -0.4, 0.8):
        env.step(np.full((2, 1), a, np.float32))
    twin, rngs = copy_engine(env.engine, env._rngs)
    other, other_rngs = copy_engine(env.engine, env._rngs)
    other_rngs[1:] = BallState.capture(env.engine, env._rngs, 0).put(other, np.array([1]))
    on = np.ones(2, dtype=bool)
    for a in (0.5, -0.2, 0.1):
        env.engine.step(np.full(2, a), on, env._rngs)
        twin.step(np.full(2, a), on, rngs)
        other.step(np.full(2, a), on, other_rngs)
        assert np.array_equal(env.engine.obs, twin.obs) and np.array_equal(env.engine.Y, twin.Y)
        assert np.array_equal(other.Y[1], env.engine.Y[0])   # ball 0's state, queues and all


def test_delayed_engines_step_the_same_on_threads_and_pickled():
    import pickle

    from saddle_env.envs.engine import TrapEngine

    config = EnvConfig(obs_delay=0.031, action_delay=0.012, action_mode="voltage",
                       air_force=0.1, position_noise=1e-3)
    engines = [TrapEngine(config, 64, parallel=p) for p in (False, True)]
    rngs = [[np.random.default_rng(i) for i in range(64)] for _ in engines]
    for e, r in zip(engines, rngs):
        e.reset(np.arange(64), r)
    on = np.ones(64, dtype=bool)
    for k in range(6):
        if k == 3:  # a pickled engine continues where it was
            engines[1] = pickle.loads(pickle.dumps(engines[1]))
        acts = np.random.default_rng(k).uniform(-1, 1, 64)
        for e, r in zip(engines, rngs):
            e.step(acts, on, r)
        assert np.array_equal(engines[0].obs, engines[1].obs)
        assert np.array_equal(engines[0].out, engines[1].out)


def test_ball_density_gives_each_ball_the_drag_of_its_size():
    from saddle_env.envs.config import quadratic_drag

    c = EnvConfig(ball_radii=(0.0223, 0.033), ball_density=25.0)
    assert c.scene().drag_quadratic == pytest.approx(3 * 0.47 * 1.2 / (8 * 25.0 * 0.0265))
    env = SaddleTrapEnv(**c.as_dict())
    seen = set()
    for seed in range(8):
        env.reset(seed=seed)
        seen.add((env.scene.R, env.scene.drag_quadratic))
    assert seen == {(R, quadratic_drag(R, 25.0)) for R in (0.0223, 0.033)}
    with pytest.raises(ValueError, match="drag_quadratic or ball_density"):
        EnvConfig(ball_density=25.0, drag_quadratic=0.2)


def test_constant_speed_in_voltage_mode_is_the_voltage_of_that_steady_speed():
    from agents.control.controllers import ConstantSpeed

    config = EnvConfig(action_mode="voltage")
    policy = ConstantSpeed(config, 30.0)
    env = SaddleTrapEnv(**config.as_dict())
    obs, _ = env.reset(seed=0, options={"omega": 20.0})
    state = None
    for _ in range(100):   # 2 s = 8 motor time constants
        action, state = policy.predict(obs, state)
        assert action[0] == pytest.approx(2 * 30.0 / 45.0 - 1)
        obs, *_ = env.step(action)
    assert env.omega == pytest.approx(30.0, abs=10 * np.exp(-8) + 1e-6)
