"""saddle-fit (saddle_env.calibrate): synthetic tracks made by the environment with known
parameters are fitted back, intervals cover the truth, an unidentifiable parameter says so,
and the options it writes are accepted by gym.make, train.py and saddle-eval."""

import json
import math
import warnings
from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest

from saddle_env.calibrate import Track, write_track
from saddle_env.calibrate.cli import main
from saddle_env.calibrate.fit import FitWarning, fit_tracks
from saddle_env.calibrate.synthetic import synthetic_tracks

LAB = "SaddleTrap-Lab-v0"
R = 0.0265


@pytest.fixture(scope="module")
def lab_tracks():
    """Two 1-s releases on the Lab level at 60 fps, camera 30 ms late, 0.5 mm noise and the
    level's 0.25 mm pixels, random voltages held 0.25 s, the tachometer at 0.2 rad/s."""
    return synthetic_tracks(LAB, n_tracks=2, seconds=1.0, fps=60, R=R, obs_delay=0.03, seed=4)


def test_the_fit_recovers_latency_motor_and_drag_inside_their_intervals(lab_tracks):
    tracks, truth = lab_tracks
    start = replace(truth, obs_delay=0.0, motor_tau=0.4, motor_gain=1.5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FitWarning)   # the drag is loose on 2 s of data
        res = fit_tracks(tracks, start, ["obs_delay", "motor_tau", "motor_gain",
                                         "drag_quadratic"])
    true = {"obs_delay": 0.03, "motor_tau": truth.motor_tau, "motor_gain": truth.motor_gain,
            "drag_quadratic": truth.scene().drag_quadratic}
    for name, value in true.items():
        e = res.estimates[name]
        assert e.identifiable and e.low <= value <= e.high, (name, value, e)
        assert e.start == getattr(start, name) if name != "drag_quadratic" else True
    # the motor is pinned by the tachometer: tight intervals, not just wide ones
    assert res.estimates["motor_tau"].high - res.estimates["motor_tau"].low < 0.05
    assert res.estimates["obs_delay"].high - res.estimates["obs_delay"].low < 0.05
    # the residuals are the camera's noise (0.5 mm, plus pixel rounding), not a model misfit
    for t in res.tracks:
        assert 3e-4 < t["rms_m"] < 8e-4, t
    assert res.status == "converged" and 0.5 < res.sigma_scale < 2.0


def test_a_latency_with_a_constant_speed_and_no_angle_is_reported_unidentifiable():
    # the speed servo held at its start speed: the scene is the same at every moment in the
    # saddle's frame, so a latency is a turn of the saddle's unknown start angle
    tracks, truth = synthetic_tracks("SaddleTrap-v0", n_tracks=2, seconds=1.0, fps=60, R=R,
                                     obs_delay=0.03, seed=4, columns=("omega",),
                                     action_range=(0.0, 0.0), omega_noise=0.0)
    with pytest.warns(FitWarning, match="obs_delay is not identifiable"):
        res = fit_tracks(tracks, replace(truth, obs_delay=0.01), ["obs_delay"])
    e = res.estimates["obs_delay"]
    assert not e.identifiable and e.interval == (-math.inf, math.inf)
    assert "obs_delay" not in res.env_options     # no number for gym.make to trust
    assert res.as_dict()["estimates"]["obs_delay"]["high"] == "inf"
    # with the encoder's angle the same tracks pin it
    tracks, truth = synthetic_tracks("SaddleTrap-v0", n_tracks=2, seconds=1.0, fps=60, R=R,
                                     obs_delay=0.03, seed=4, columns=("omega", "theta"),
                                     action_range=(0.0, 0.0), omega_noise=0.0)
    res = fit_tracks(tracks, replace(truth, obs_delay=0.01), ["obs_delay"])
    e = res.estimates["obs_delay"]
    assert e.identifiable and e.low <= 0.03 <= e.high and e.high - e.low < 0.01


def test_the_written_options_are_accepted_by_gym_make_train_and_saddle_eval(tmp_path,
                                                                            lab_tracks, capsys):
    tracks, _ = lab_tracks
    # the tracker lost the ball on 8 frames of the first release and 5 frames of the second
    # are missing altogether (an uneven clock)
    t0 = tracks[0]
    x, y = t0.x.copy(), t0.y.copy()
    x[20:28] = y[20:28] = np.nan
    tracks = [Track(t0.t, x, y, omega=t0.omega, voltage=t0.voltage)]
    keep = np.ones(len(lab_tracks[0][1].t), bool)
    keep[[10, 11, 30, 41, 42]] = False
    t1 = lab_tracks[0][1]
    tracks.append(Track(t1.t[keep], t1.x[keep], t1.y[keep], omega=t1.omega[keep],
                        voltage=t1.voltage[keep]))
    for i, t in enumerate(tracks):
        write_track(tmp_path / "run" / f"release_{i}.csv", t)
    out = tmp_path / "fit"
    code = main([str(tmp_path / "run"), "--fit", "drag_quadratic,obs_delay", "--set", f"R={R}",
                 "--out", str(out), "--no-plot", "--quiet"])
    assert code == 0
    text = (out / "env_options.json").read_text()
    options = json.loads(text)
    assert {"drag_quadratic", "obs_delay", "R"} <= set(options)
    results = json.loads((out / "results.json").read_text())
    assert set(results["estimates"]) == {"drag_quadratic", "obs_delay"}
    assert [t["frames"] for t in results["tracks"]] == [len(tracks[0]) - 8, len(tracks[1])]
    assert all(3e-4 < t["rms_m"] < 8e-4 for t in results["tracks"])
    lo, hi = results["estimates"]["obs_delay"]["low"], results["estimates"]["obs_delay"]["high"]
    assert lo <= 0.03 <= hi
    assert "obs_delay" in capsys.readouterr().out
    from agents.cli_args import parse_env_kwargs, resolve_env
    kw = parse_env_kwargs([text])          # what train.py and saddle-eval do with --env-kwargs
    _, config = resolve_env(LAB, kw)
    assert config.obs_delay == options["obs_delay"] and config.ball_density is None
    assert config.scene().drag_quadratic == options["drag_quadratic"]
    env = gym.make(LAB, **kw)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    env.close()
    import train
    from agents.evaluation.evaluate import build_parser
    assert parse_env_kwargs(train.build_parser().parse_args(
        ["--env", LAB, "--env-kwargs", text]).env_kwargs) == kw
    assert parse_env_kwargs(build_parser().parse_args(
        ["--policy", "mpc", "--env", LAB, "--env-kwargs", text]).env_kwargs) == kw


@pytest.mark.parametrize("argv, message", [
    (["--fit", "dragg"], "unknown parameter(s) ['dragg']; the fittable parameters are"),
    (["--fit", "obs_delay", "--level", "SaddleTrap-Moon-v0"], "unknown level"),
    (["--fit", "mu"], "contact='coulomb' balls only"),
    (["--fit", "obs_delay", "--set", "R=-1"], "--set: R must"),
    (["--fit", "obs_delay", "--segment", "5"], "segment must be in [0.02, 2] s"),
    (["--fit", "obs_delay", "--drive", "omega"], "lacks"),
])
def test_bad_arguments_are_refused_naming_the_option_and_its_range(tmp_path, capsys, argv,
                                                                   message):
    t = np.arange(20) / 60
    track = Track(t, 0.01 * np.cos(9 * t), 0.01 * np.sin(9 * t), voltage=np.full(20, 8.0))
    write_track(tmp_path / "a.csv", track)
    with pytest.raises(SystemExit) as exc:
        main([str(tmp_path / "a.csv"), *argv, "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert not (tmp_path / "o").exists()


def test_the_synthetic_command_writes_tracks_that_read_back_and_their_truth(tmp_path, capsys):
    from saddle_env.calibrate import read_tracks
    from saddle_env.calibrate.synthetic import main as synthetic_main
    assert synthetic_main([str(tmp_path / "run"), "--tracks", "2", "--seconds", "0.3", "--fps",
                           "90", "--columns", "omega,voltage,theta", "--set", "R=0.0223",
                           "obs_delay=0.02"]) == 0
    tracks = read_tracks(tmp_path / "run")
    assert len(tracks) == 2 and tracks[0].channels == ("t", "x", "y", "omega", "voltage", "theta")
    assert np.allclose(np.diff(tracks[0].t), 1 / 90) and tracks[0].t[0] >= 0.02
    truth = json.loads((tmp_path / "run" / "truth.json").read_text())
    assert truth["R"] == 0.0223 and truth["obs_delay"] == 0.02 and truth["drag_quadratic"] > 0
    with pytest.raises(SystemExit):
        synthetic_main([str(tmp_path / "bad"), "--fps", "0.5"])
    assert "fps must be in [1, 10000]" in capsys.readouterr().err


def test_too_few_frames_are_refused_naming_the_file(tmp_path):
    t = np.arange(5) / 60
    track = Track(t, 0.01 * np.cos(9 * t), 0.01 * np.sin(9 * t), omega=np.full(5, 18.0),
                  source="short.csv")
    tracks, truth = synthetic_tracks("SaddleTrap-v0", n_tracks=1, seconds=0.2, fps=60, R=R,
                                     columns=("omega",))
    with pytest.raises(ValueError, match="short.csv: 5 tracked frames; a fit needs at least 6"):
        fit_tracks([tracks[0], track], truth, ["obs_delay"])


def test_an_interrupted_fit_reports_its_best_point(lab_tracks, monkeypatch):
    import saddle_env.calibrate.fit as fit_module

    def stopped(fun, x0, jac, **kw):   # Ctrl-C in the middle of the third iteration
        x = x0.copy()
        for _ in range(2):
            jac(x)
            x[0] += 0.01
            fun(x)
        raise KeyboardInterrupt

    monkeypatch.setattr(fit_module, "least_squares", stopped)
    tracks, truth = lab_tracks
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FitWarning)   # two iterations determine little
        res = fit_tracks(tracks, replace(truth, obs_delay=0.0), ["obs_delay"])
    assert res.status == "interrupted" and res.iterations == 2
    e = res.estimates["obs_delay"]
    assert e.value in (0.0, 0.01, 0.02) and math.isfinite(e.std) and res.env_options


@pytest.mark.slow
def test_95_percent_intervals_cover_the_truth_in_at_least_85_percent_of_20_data_sets():
    """20 data sets: 3 releases of 1.5 s on the Lab level, a frame rate drawn from 60-240 fps,
    a latency from 10-50 ms, a motor lag from 0.15-0.35 s, 0.5 mm camera noise on 0.25 mm
    pixels; the fit starts from the level's values."""
    rng = np.random.default_rng(2026)
    names = ("obs_delay", "motor_tau", "motor_gain", "drag_quadratic")
    hits = {n: 0 for n in names}
    n_sets = 20
    for k in range(n_sets):
        fps = float(rng.choice([60, 90, 120, 180, 240]))
        truth_kw = dict(obs_delay=float(rng.uniform(0.01, 0.05)),
                        motor_tau=float(rng.uniform(0.15, 0.35)))
        tracks, truth = synthetic_tracks(LAB, n_tracks=3, seconds=1.5, fps=fps, R=R,
                                         seed=100 + k, **truth_kw)
        start = replace(truth, obs_delay=0.03, motor_tau=0.25, motor_gain=1.875)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FitWarning)
            res = fit_tracks(tracks, start, names)
        true = {"obs_delay": truth.obs_delay, "motor_tau": truth.motor_tau,
                "motor_gain": truth.motor_gain, "drag_quadratic": truth.scene().drag_quadratic}
        line = []
        for n in names:
            e = res.estimates[n]
            hit = e.low <= true[n] <= e.high
            hits[n] += hit
            line.append(f"{n} {true[n]:.4g} in [{e.low:.4g}, {e.high:.4g}] {'ok' if hit else 'MISS'}")
        print(f"set {k} ({fps:g} fps): " + "; ".join(line), flush=True)
    total = sum(hits.values()) / (n_sets * len(names))
    print("coverage:", {n: f"{h}/{n_sets}" for n, h in hits.items()}, f"pooled {total:.1%}")
    assert total >= 0.85
    assert all(h >= 0.75 * n_sets for h in hits.values()), hits
