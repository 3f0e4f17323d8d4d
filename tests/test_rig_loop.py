"""The real-time loop on a rig (issue 43, item 5): `SimulatedRig` is the environment's physics
in (virtual) wall-clock time, and `run` reads, acts, writes, counts deadline misses and logs
tracks that the track format reads back."""

import csv
import json
import math
import os
import signal
import time

import numpy as np
import pytest

from agents import figures
from saddle_env.calibrate import read_track, read_tracks
from saddle_env.envs import SaddleTrapEnv, level_config
from saddle_env.rig import (
    Frame,
    MonotonicClock,
    Observer,
    Rig,
    SimulatedRig,
    VirtualClock,
    constant_voltage,
    run,
)

LAB = "SaddleTrap-Lab-v0"
T = 0.02                      # the Lab level's control period
# [V] the voltage of the Lab level's best constant speed on the leaderboard, the figure that
# docs/how-to/rig.md states (docs/leaderboard.json through the figure store)
STEADY = figures.figures()["lab-best-const-voltage"]["value"]
QUIET = dict(air_force=0.0)   # no draught: a constant voltage keeps the ball


def _rotating(frame: Frame) -> tuple[float, float]:
    """A frame's position in the saddle's frame (the env's observation frame)."""
    c, s = math.cos(frame.theta), math.sin(frame.theta)
    return c * frame.x + s * frame.y, -s * frame.x + c * frame.y


class Spy:
    """A rig that records what the loop writes (and passes everything through)."""

    def __init__(self, rig):
        self.rig, self.clock, self.config = rig, rig.clock, rig.config
        self.writes: list[tuple[float, float]] = []

    def read(self):
        return self.rig.read()

    def write(self, voltage):
        self.writes.append((self.clock.now(), voltage))
        self.rig.write(voltage)

    def release(self):
        self.rig.release()

    def close(self):
        self.rig.close()


def test_voltage_of_an_action_is_the_level_voltage_mode():
    c = level_config(LAB)
    for a in (-1.0, -0.3, 0.0, 0.7, 1.0):
        v = c.voltage_of_action(a)
        assert v == pytest.approx((a + 1) / 2 * c.voltage_max)
        assert c.action_of_voltage(v) == pytest.approx(a, abs=1e-15)
    assert c.voltage_of_action(3.0) == c.voltage_max
    with pytest.raises(ValueError, match="voltage must be in"):
        c.action_of_voltage(c.voltage_max + 1)
    with pytest.raises(ValueError, match="finite"):
        c.voltage_of_action(math.nan)
    # the environment's motor settles at motor_gain * that voltage
    env = SaddleTrapEnv(action_mode="voltage", motor_tau=0.05, omega0_range=(20.0, 25.0))
    env.reset(seed=0)
    for _ in range(100):
        env.step(np.array([-0.2]))
    assert env.omega == pytest.approx(env.config.motor_gain * env.config.voltage_of_action(-0.2),
                                      rel=1e-6)


def test_the_rig_frames_are_the_environment_observations_for_the_same_voltages():
    # One frame per control period: the rig is the level's environment, noise and all, seen
    # in the laboratory; the frame k shows the ball obs_delay before k periods.
    clock = VirtualClock()
    rig = SimulatedRig(LAB, frame_rate=1 / T, seed=11, clock=clock, threaded=False)
    env = SaddleTrapEnv(**level_config(LAB).as_dict())
    obs, _ = env.reset(seed=11)
    c = rig.config
    volts = np.random.default_rng(0).uniform(4.0, 12.0, 60)
    rig.release()
    for j, v in enumerate(volts):
        frame = rig.read()
        assert frame.t == pytest.approx(j * T - c.obs_delay, abs=1e-12)
        assert np.allclose(_rotating(frame), np.float64(obs[:2]) * c.rim_radius, rtol=0, atol=1e-15)
        assert math.cos(frame.theta) == pytest.approx(obs[3], abs=1e-7)
        assert math.sin(frame.theta) == pytest.approx(obs[4], abs=1e-7)
        assert frame.omega == pytest.approx(np.float64(obs[2]) * c.omega_max, abs=1e-12)
        rig.write(v)
        clock.sleep_until((j + 1) * T)
        obs, _, terminated, _, _ = env.step(np.array([c.action_of_voltage(v)]))
        assert not terminated
    assert c.position_noise > 0 and rig.lost == []


def test_a_faster_camera_sees_the_same_ball_between_the_periods():
    # 200 frames/s, noise off: the frames at the periods' ends are the environment's
    # observations (integrated in other steps: equal to the integrator's tolerance).
    quiet = dict(position_noise=0.0, omega_noise=0.0, position_quantum=0.0, air_force=0.0,
                 ripple_amp=0.0)
    clock = VirtualClock()
    rig = SimulatedRig(LAB, frame_rate=200, seed=5, clock=clock, threaded=False, **quiet)
    env = SaddleTrapEnv(**level_config(LAB, **quiet).as_dict())
    obs, _ = env.reset(seed=5)
    c = rig.config
    rig.release()
    volts = np.random.default_rng(1).uniform(4.0, 12.0, 50)
    times = []
    for j, v in enumerate(volts):
        rig.write(v)
        clock.sleep_until((j + 1) * T)
        obs, *_ = env.step(np.array([c.action_of_voltage(v)]))
        frame = rig.read()
        times.append(frame.t)
        assert frame.t == pytest.approx((j + 1) * T - c.obs_delay, abs=1e-12)
        assert np.allclose(_rotating(frame), np.float64(obs[:2]) * c.rim_radius, rtol=0, atol=1e-7)
        assert frame.omega == pytest.approx(np.float64(obs[2]) * c.omega_max, abs=1e-5)
    assert np.ptp(np.diff(times)) < 1e-12   # and between the periods: 3 more frames each
    assert rig.env.engine.balls[0, 2] == pytest.approx(len(volts) * T)


def test_the_loop_logs_tracks_of_the_simulated_ball_and_shows_the_controller_the_env_view(
        tmp_path):
    clock = VirtualClock()
    rig = Spy(SimulatedRig(LAB, frame_rate=1 / T, seed=2, clock=clock, **QUIET))
    seen = []

    def controller(obs):
        seen.append(np.array(obs))
        return 2 * STEADY / 24.0 - 1 + 0.05 * math.sin(len(seen) / 7)   # some modulation

    summary = run(rig, controller, 3.0, log_dir=tmp_path)
    rig.close()
    assert not rig.rig.running
    assert summary["complete"] and summary["periods"] == 150 and summary["misses"] == 0
    assert [r["cause"] for r in summary["releases"]] == ["time"]
    track = read_track(tmp_path / "release_001.csv")
    assert track.channels == ("t", "x", "y", "omega", "voltage", "theta")
    # Replay the written voltages in the environment: the track is its ball, and the
    # controller saw its observations (the Lab level's 8 frames, newest first).
    env = SaddleTrapEnv(**level_config(LAB, **QUIET).as_dict())
    obs, _ = env.reset(seed=2)
    c = rig.config
    observations = [obs]
    for _, v in rig.writes:
        obs, _, terminated, _, _ = env.step(np.array([c.action_of_voltage(v)]))
        observations.append(obs)
        assert not terminated
    assert len(seen) == len(rig.writes) == 150
    for k, o in enumerate(seen):
        assert np.allclose(o, observations[k], rtol=0, atol=2e-7), k
    for i in range(len(track)):
        j = round((track.t[i] + c.obs_delay) / T)
        o = observations[j]
        th = track.theta[i]
        rot = (math.cos(th) * track.x[i] + math.sin(th) * track.y[i],
               -math.sin(th) * track.x[i] + math.cos(th) * track.y[i])
        assert np.allclose(rot, np.float64(o[:2]) * c.rim_radius, rtol=0, atol=1e-15)
        # the voltage in force at the frame's time: written at the last period before it
        assert track.voltage[i] == rig.writes[math.floor(track.t[i] / T + 1e-9)][1]
    assert track.t[0] >= 0.0 and np.all(np.diff(track.t) == pytest.approx(T))
    written = json.loads((tmp_path / "summary.json").read_text())
    assert written["periods"] == 150 and written["frame_age_ms"]["median"] == pytest.approx(30)
    assert level_config(LAB, **written["env_options"]) == level_config(LAB, **QUIET)


def test_a_controller_slower_than_the_period_misses_deadlines_and_they_are_counted(tmp_path):
    clock = VirtualClock()

    def slow(obs):
        clock.sleep(0.03)   # computes for 30 ms, the period is 20
        return 0.0

    with SimulatedRig(LAB, seed=1, clock=clock, **QUIET) as rig:
        summary = run(rig, slow, 1.2, log_dir=tmp_path)
    assert summary["periods"] > 0 and summary["skipped_periods"] > 0
    assert summary["misses"] == summary["periods"] + summary["skipped_periods"]
    assert summary["compute_ms"]["median"] == pytest.approx(30.0)
    with open(tmp_path / "periods.tsv") as fh:
        rows = list(csv.DictReader(fh, delimiter="\t"))
    assert len(rows) == summary["periods"]
    assert all(r["missed"] == "1" for r in rows)
    # the same run with a quick controller misses nothing
    with SimulatedRig(LAB, seed=1, clock=VirtualClock(), **QUIET) as rig:
        assert run(rig, lambda obs: 0.0, 1.2)["misses"] == 0


def test_a_lost_ball_ends_the_release_and_the_next_one_begins(tmp_path):
    # The top voltage with the draught throws the ball off (detachment): the camera loses it
    with SimulatedRig(LAB, seed=2, clock=VirtualClock()) as rig:
        summary = run(rig, constant_voltage(rig.config, 24.0), 6.0, releases=2,
                      log_dir=tmp_path)
        lost = list(rig.lost)
    rel = summary["releases"]
    assert [r["cause"] for r in rel] == ["lost", "lost"] and len(lost) == 2
    assert [e["cause"] for e in lost] == ["detach", "detach"]
    for r, e in zip(rel, lost):
        # seen as a real rig sees it: lost_after after the last frame with the ball (within
        # a period of the loss), which arrives the latency late
        assert 0.03 + 0.1 - T < r["end"] - e["time"] <= 0.03 + 0.1 + 2 * T
    tracks = read_tracks(tmp_path)
    assert len(tracks) == 2
    for track, r, e in zip(tracks, rel, lost):
        assert r["start"] <= track.t[0] and track.t[-1] <= e["time"] and track.tracked.all()
        assert e["time"] - track.t[-1] < T   # the frames taken before the loss arrived
    # No voltage: the saddle slows below the threshold and the ball rolls over the rim
    with SimulatedRig(LAB, seed=4, clock=VirtualClock(), **QUIET) as rig:
        summary = run(rig, constant_voltage(rig.config, 0.0), 6.0, releases=1)
    assert summary["releases"][0]["cause"] == "escape"


def test_the_physics_thread_stops_on_close_and_on_an_exception_in_the_controller(tmp_path):
    rig = SimulatedRig(LAB, seed=0, clock=VirtualClock(), **QUIET)
    assert rig.running and isinstance(rig, Rig)
    calls = []

    def broken(obs):
        calls.append(obs)
        if len(calls) == 5:
            raise RuntimeError("controller bug")
        return 0.0

    with pytest.raises(RuntimeError, match="controller bug"):
        run(rig, broken, 2.0, log_dir=tmp_path)
    assert not rig.running
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["stopped"] == "RuntimeError: controller bug" and not summary["complete"]
    assert summary["periods"] == 4 and summary["releases"][0]["cause"] == "stopped"
    with pytest.raises(RuntimeError, match="closed"):
        rig.read()
    with SimulatedRig(LAB, seed=0) as rig:   # wall-clock time: the thread steps unread
        assert rig.running
        rig.release()
        time.sleep(0.2)
        assert rig.frames > 0
    assert not rig.running
    stepped = rig.frames
    time.sleep(0.05)
    assert rig.frames == stepped


class Acting:
    """An exported policy's shape: act(observation) and reset()."""

    def __init__(self):
        self.resets, self.calls = 0, 0

    def reset(self):
        self.resets += 1

    def act(self, obs):
        self.calls += 1
        return np.array([-0.35], np.float32)


class Predicting:
    """SB3's shape: predict(observation, state, episode_start, deterministic) -> (action, state)."""

    def __init__(self):
        self.starts, self.states = [], []

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        self.starts.append(bool(episode_start[0]))
        self.states.append(state)
        return np.array([-0.35], np.float32), (0 if state is None else state + 1)


def test_the_loop_takes_act_predict_and_plain_controllers():
    for controller in (Acting(), Predicting(), lambda obs: -0.35):
        with SimulatedRig(LAB, seed=6, clock=VirtualClock(), **QUIET) as rig:
            summary = run(rig, controller, 0.5)
        assert summary["periods"] == 25 and summary["misses"] == 0
    acting, predicting = Acting(), Predicting()
    for controller in (acting, predicting):
        with SimulatedRig(LAB, seed=6, clock=VirtualClock()) as rig:
            summary = run(rig, constant_voltage(rig.config, 24.0), 3.0)   # lose the ball
            assert summary["releases"][0]["cause"] == "lost"
            summary = run(rig, controller, 3.0)
        if controller is acting:
            # called every period but those that found the ball gone; reset at each release
            gone = sum(r["cause"] != "time" for r in summary["releases"])
            assert acting.resets == len(summary["releases"]) >= 1
            assert acting.calls == summary["periods"] - gone
    # the state is carried within a release and dropped at the next one
    assert predicting.starts.count(True) == len(summary["releases"])
    assert all(st is None for st, first in zip(predicting.states, predicting.starts) if first)
    assert predicting.states[1] == 0 and predicting.states[2] == 1


def _signalled_while_freed():
    """A SIGTERM whose handler runs inside a ``__del__``, where Python drops what it raises."""
    import gc

    from helpers import SignalledWhileFreed

    SignalledWhileFreed()
    gc.collect()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_sigterm_and_ctrl_c_write_what_ran_and_close_the_rig(tmp_path):
    for stop, reason, folder in ((lambda: os.kill(os.getpid(), signal.SIGTERM), "SIGTERM",
                                  tmp_path / "term"),
                                 (lambda: (_ for _ in ()).throw(KeyboardInterrupt), "Ctrl-C",
                                  tmp_path / "int"),
                                 # a SIGTERM Python drops inside a __del__: the next period's
                                 # check raises it
                                 (lambda: _signalled_while_freed(), "SIGTERM",
                                  tmp_path / "lost")):
        calls = []

        def controller(obs, stop=stop, calls=calls):
            calls.append(1)
            if len(calls) == 20:
                stop()
            return -0.35

        rig = SimulatedRig(LAB, seed=0, clock=VirtualClock(), **QUIET)
        with pytest.raises(KeyboardInterrupt):
            run(rig, controller, 5.0, log_dir=folder)
        assert not rig.running
        summary = json.loads((folder / "summary.json").read_text())
        # the stop in the 20th period's controller call, or at the 21st period's check
        assert summary["stopped"] == reason
        assert summary["periods"] == (20 if folder.name == "lost" else 19)
        track = read_track(folder / "release_001.csv")
        assert len(track) >= 15 and track.t[-1] <= 20 * T
    assert signal.getsignal(signal.SIGTERM) is not None   # the handler was put back


def test_bad_input_is_refused_with_the_allowed_range(tmp_path):
    with pytest.raises(ValueError, match="action_mode='voltage'"):
        SimulatedRig("SaddleTrap-v0", threaded=False)
    with pytest.raises(ValueError, match="frame_rate must be in"):
        SimulatedRig(LAB, frame_rate=0, threaded=False)
    with SimulatedRig(LAB, clock=VirtualClock(), threaded=False) as rig:
        with pytest.raises(ValueError, match=r"voltage must be in \[0, voltage_max = 24\]"):
            rig.write(25.0)
        with pytest.raises(ValueError, match="seconds must be in"):
            run(rig, lambda o: 0.0, -1.0)
        with pytest.raises(ValueError, match="period must be in"):
            run(rig, lambda o: 0.0, 1.0, period=0.0)
        with pytest.raises(TypeError, match="controller must have"):
            run(rig, 3, 1.0)
        with pytest.raises(ValueError, match="one finite number"):
            run(rig, lambda o: [0.0, 1.0], 1.0)
    (tmp_path / "summary.json").write_text("{}")
    with SimulatedRig(LAB, clock=VirtualClock(), threaded=False) as rig:
        with pytest.raises(FileExistsError, match="already holds a run"):
            run(rig, lambda o: 0.0, 1.0, log_dir=tmp_path)
    class Tuples:   # a rig giving plain tuples is fine; a time that is not a number is not
        def __init__(self, t):
            self.t, self.clock = t, VirtualClock()

        def read(self):
            return (self.t, 0.01, 0.0, 20.0, 0.0)

        def write(self, voltage):
            pass

        def release(self):
            pass

        def close(self):
            pass

    assert run(Tuples(-0.03), lambda o: 0.0, 0.1)["periods"] == 5
    with pytest.raises(ValueError, match="a frame's time t must be a finite number"):
        run(Tuples(math.nan), lambda o: 0.0, 0.1)
    obs = Observer(level_config(LAB))
    with pytest.raises(ValueError, match="need theta"):
        obs.push(Frame(0.0, 0.01, 0.0, 20.0))


@pytest.mark.slow
def test_in_real_time_a_constant_voltage_keeps_the_ball_and_misses_are_reported(tmp_path):
    # Wall-clock time at the Lab level's 20 ms period: the timings depend on the machine, so
    # only that they are counted and reported is asserted, and that the ball is kept.
    with SimulatedRig(LAB, seed=3, clock=MonotonicClock(), **QUIET) as rig:
        summary = run(rig, constant_voltage(rig.config, STEADY), 4.0, log_dir=tmp_path,
                      progress=print)
        lost = list(rig.lost)
        lag = rig.max_lag
    print(f"periods {summary['periods']}, misses {summary['misses']}, lateness "
          f"{summary['lateness_ms']}, cycle {summary['cycle_ms']}, physics lag {lag:.4f} s")
    assert lost == [] and [r["cause"] for r in summary["releases"]] == ["time"]
    assert summary["periods"] + summary["skipped_periods"] >= 190   # 4 s / 20 ms = 200
    assert isinstance(summary["misses"], int) and summary["lateness_ms"]["median"] is not None
    track = read_track(tmp_path / "release_001.csv")
    assert len(track) > 150 and np.all(np.hypot(track.x, track.y) < rig.config.rim_radius)


@pytest.mark.slow
def test_mpc_keeps_the_ball_on_the_simulated_rig():
    # The shipped model-predictive controller, passed in (saddle_env does not import agents),
    # through SB3's predict; on the virtual clock, so its compute time cannot make it late.
    from agents.control.mpc import ModelPredictiveController

    with SimulatedRig(LAB, seed=1, clock=VirtualClock()) as rig:
        summary = run(rig, ModelPredictiveController(rig.config), 5.0)
        lost = list(rig.lost)
    assert lost == [] and [r["cause"] for r in summary["releases"]] == ["time"]
    assert summary["periods"] == 250 and summary["misses"] == 0


@pytest.mark.slow
def test_an_exported_lab_policy_runs_on_the_simulated_rig(tmp_path):
    # saddle-export's folder of a (barely trained) Lab-level model, run by the torch-free
    # runtime through act(): what the loop gives it is what the model was trained on.
    sb3 = pytest.importorskip("stable_baselines3")
    pytest.importorskip("onnxruntime")
    from agents.evaluation.export import export_policy
    from saddle_env.deploy import Controller
    from saddle_env.envs import get_level
    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    model = sb3.PPO("MlpPolicy", SaddleTrapSB3VecEnv(num_envs=2, **get_level(LAB).options),
                    n_steps=8, batch_size=16, seed=0, policy_kwargs={"net_arch": [8, 8]},
                    device="cpu")
    path = tmp_path / "lab.zip"
    model.save(path)
    path.with_suffix(".json").write_text(json.dumps(
        {"algo": "ppo", "env_id": LAB, "env_kwargs": {}, "frame_stack": 1, "normalize": False}))
    controller = Controller.from_dir(export_policy(path, tmp_path / "exported"))
    assert controller.spec.layout["vx"] is None   # a camera: positions only
    seen = []

    class Recording:
        def reset(self):
            controller.reset()

        def act(self, obs):
            seen.append(np.array(obs))
            return controller.act(obs)

    with SimulatedRig(LAB, seed=0, clock=VirtualClock()) as rig:
        summary = run(rig, Recording(), 1.0, log_dir=tmp_path / "logs")
    assert summary["periods"] == 50 and len(seen) >= 49
    for obs in seen:   # the model's own answer to each observation the loop gave
        want, _ = model.predict(obs, deterministic=True)
        assert np.allclose(controller.predict(obs)[0], want, atol=1e-5)
    assert read_tracks(tmp_path / "logs")
