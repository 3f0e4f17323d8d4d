"""agents.benchmark.time_to_target (tiny budgets: the machinery, not learning) and the training
pieces it reads: the wall-clock evaluation log and short training episodes."""

import csv
import json

import pytest

pytest.importorskip("stable_baselines3")

from agents.benchmark import time_to_target as ttt  # noqa: E402


def test_first_time_and_median_time():
    curve = [{"wall_seconds": 10.0, "mean_trapping_time": 7.0},
             {"wall_seconds": 20.0, "mean_trapping_time": 8.0},
             {"wall_seconds": 30.0, "mean_trapping_time": 9.5}]
    assert ttt.first_time(curve, 8.0) == 20.0
    assert ttt.first_time(curve, 8.0, strict=True) == 30.0
    assert ttt.first_time(curve, 9.6) is None
    assert ttt.median_time([30.0, None, 10.0]) == 30.0
    assert ttt.median_time([None, None, 10.0]) is None


def test_the_runner_writes_curves_targets_and_the_figure(tmp_path):
    hyper = tmp_path / "ppo.yml"
    hyper.write_text("SaddleTrap-v0:\n  n_envs: 4\n  n_steps: 32\n  batch_size: 64\n"
                     "  n_epochs: 1\n  policy_kwargs: 'dict(net_arch=[16])'\n"
                     "  train_episode_steps: 10\n")
    out = tmp_path / "ttt"
    summary = ttt.run("SaddleTrap-v0", [0], str(hyper), out, label="tiny",
                      total_timesteps=256, eval_freq=128, eval_episodes=2, final_episodes=2,
                      max_episode_steps=20, log=lambda *_: None)
    for name in ("time_to_target.csv", "time_to_target.json", "time_to_target.png"):
        assert (out / name).is_file(), name
    rows = list(csv.DictReader(open(out / "time_to_target.csv")))
    assert {r["seed"] for r in rows} == {"0"}
    walls = [float(r["wall_seconds"]) for r in rows if r["seed"] == "0"]
    assert walls == sorted(walls) and walls[0] > 0
    saved = json.loads((out / "time_to_target.json").read_text())
    assert saved["targets"]["mpc"]["mean"] > 0 and len(saved["seeds"]) == 1
    assert set(saved["fresh_episodes"]["policies"]) >= {"best-const", "mpc"}
    assert summary["median_to_mpc_mean"] == saved["median_to_mpc_mean"]
    # Training episodes were cut at 10 steps; evaluation kept the full 20.
    run = out / "runs" / "tiny_seed0"
    lengths = [float(r["mean_trapping_time"]) for r in csv.DictReader(
        open(run / "evaluations_wall.csv"))]
    assert max(lengths) > 10 * 0.02


def test_the_runner_trains_the_algorithm_asked_for(tmp_path, monkeypatch):
    """--algo reaches the training settings (a fake back end writes the curve)."""
    seen = []

    def fake_train(settings):
        seen.append(settings.algo)
        run = tmp_path / "runs" / settings.run_name
        run.mkdir(parents=True)
        (run / "evaluations_wall.csv").write_text(
            "timesteps,wall_seconds,mean_return,mean_trapping_time\n100,1.5,10.0,0.4\n")
        from agents.training.selection import validation_set

        (run / "curve_episodes.json").write_text(json.dumps(validation_set(settings)))
        return run

    monkeypatch.setattr("agents.training.trainer.train", fake_train)
    ttt.main(["--env", "SaddleTrap-v0", "--algo", "sac", "--seeds", "3", "--label", "s",
              "--eval-episodes", "2", "--final-episodes", "0", "--max-episode-steps", "20",
              "--out", str(tmp_path)])
    assert seen == ["sac"]
    saved = json.loads((tmp_path / "time_to_target.json").read_text())
    assert saved["algo"] == "sac" and saved["seeds"][0]["best_validation"] == 0.4
    with pytest.raises(SystemExit):
        ttt.main(["--algo", "dqn"])


def test_train_episode_steps_is_checked():
    from agents.training.recipes import train_episode_steps

    assert train_episode_steps({}, 500) == 500
    assert train_episode_steps({"train_episode_steps": 150}, 500) == 150
    assert train_episode_steps({"train_episode_steps": 900}, 500) == 500
    with pytest.raises(ValueError, match="train_episode_steps"):
        train_episode_steps({"train_episode_steps": 0}, 500)


def test_distance_shaping_changes_training_rewards_only():
    import numpy as np

    from agents.training.backends.sb3 import make_vec_env
    from agents.training.shaping import check_shaping, shape
    from saddle_env.envs import EnvConfig

    config = EnvConfig()
    plain = make_vec_env(3, 0, config, 5)
    shaped = shape(make_vec_env(3, 0, config, 5), {"distance": 2.0}, config)
    passing = shape(make_vec_env(3, 0, config, 5), {"distance": 2.0}, config,
                    training=False)
    assert shape(plain, None, config) is plain
    for env in (plain, shaped, passing):
        env.reset()
    action = np.zeros((3, 1), np.float32)
    for _ in range(5):   # the last step ends every episode (time limit): terminal obs used
        o1, r1, d1, i1 = plain.step(action)
        _, r2, _, _ = shaped.step(action)
        _, r3, _, _ = passing.step(action)
        last = np.array([i1[k]["terminal_observation"] if d1[k] else o1[k] for k in range(3)])
        np.testing.assert_allclose(r2, r1 - 2.0 * (last[:, 0] ** 2 + last[:, 1] ** 2),
                                   rtol=1e-6)
        np.testing.assert_array_equal(r3, r1)
    assert d1.all()
    for bad in ({"distanse": 1.0}, {"distance": -1.0}, 3):
        with pytest.raises(ValueError, match="reward_shaping"):
            check_shaping(bad)


def test_reuse_reads_a_finished_run_instead_of_training_it_again(tmp_path, monkeypatch):
    hyper = tmp_path / "ppo.yml"
    hyper.write_text("SaddleTrap-v0:\n  n_envs: 4\n  n_steps: 32\n  batch_size: 64\n"
                     "  n_epochs: 1\n  policy_kwargs: 'dict(net_arch=[16])'\n")
    out = tmp_path / "ttt"
    kw = dict(total_timesteps=256, eval_freq=128, eval_episodes=2, final_episodes=0,
              max_episode_steps=20)
    first = ttt.run("SaddleTrap-v0", [0], str(hyper), out, label="tiny", log=lambda *_: None,
                    **kw)
    import agents.training.trainer

    def no_training(*_, **__):
        raise AssertionError("trained again")

    monkeypatch.setattr(agents.training.trainer, "train", no_training)
    said = []
    again = ttt.run("SaddleTrap-v0", [0], str(hyper), out, label="tiny", log=said.append,
                    reuse=True, **kw)
    assert any("reusing" in line for line in said)
    assert again["seeds"][0]["best_validation"] == first["seeds"][0]["best_validation"]
    assert again["seeds"][0]["timesteps"] == first["seeds"][0]["timesteps"]
    with pytest.raises(AssertionError, match="trained again"):   # without reuse: trains
        ttt.run("SaddleTrap-v0", [0], str(hyper), out, label="tiny", log=lambda *_: None, **kw)


def test_shorter_budgets_pick_what_the_selection_rule_kept_by_then(tmp_path):
    run = tmp_path / "r_seed4"
    (run / "checkpoints").mkdir(parents=True)
    (run / "evaluations_wall.csv").write_text(
        "timesteps,wall_seconds,mean_return,mean_trapping_time\n"
        "100,1.0,5.0,1.0\n200,2.0,7.0,2.0\n300,3.0,7.0,2.5\n400,4.0,6.0,1.5\n500,5.0,9.0,3.0\n")
    for steps in (100, 200, 300, 400, 500):
        (run / "checkpoints" / f"checkpoint_{steps}_steps.zip").write_bytes(b"")
    picks = ttt.shorter_budgets([run], [250, 450, 500], "r", [4])
    # ties go to the later evaluation; the wall time is the last evaluation's within B
    assert [(p["selected_at_steps"], p["wall_seconds"]) for p in picks.values()] == \
           [(200, 2.0), (300, 4.0), (500, 5.0)]
    assert list(picks) == ["r_seed4@250", "r_seed4@450", "r_seed4@500"]
    assert picks["r_seed4@450"]["model"].name == "checkpoint_300_steps.zip"
    (run / "checkpoints" / "checkpoint_300_steps.zip").unlink()
    with pytest.raises(ValueError, match="--save-freq must divide --eval-freq"):
        ttt.shorter_budgets([run], [450], "r", [4])
    with pytest.raises(ValueError, match="no evaluation within 50"):
        ttt.shorter_budgets([run], [50], "r", [4])
    with pytest.raises(ValueError, match="--budgets must be positive"):
        ttt.shorter_budgets([run], [0], "r", [4])


def test_shorter_budgets_with_reselection_pick_the_best_of_the_top_few_on_fresh_episodes(
        tmp_path, monkeypatch):
    """The trainer's rule on a shorter budget: the best three evaluations up to B, scored
    again on the seed's fresh episodes; the highest there wins (made-up scores)."""
    from agents.training import runs, selection

    run = tmp_path / "r_seed0"
    (run / "checkpoints").mkdir(parents=True)
    (run / "evaluations_wall.csv").write_text(
        "timesteps,wall_seconds,mean_return,mean_trapping_time\n"
        "100,1.0,5.0,1.0\n200,2.0,9.0,2.0\n300,3.0,8.0,2.5\n400,4.0,7.0,1.5\n500,5.0,9.5,3.0\n")
    for steps in (100, 200, 300, 400, 500):
        (run / "checkpoints" / f"checkpoint_{steps}_steps.zip").write_bytes(b"")
    settings = runs.TrainSettings(env_id="SaddleTrap-v0", eval_episodes=4, max_episode_steps=10,
                                  log_dir=str(tmp_path), run_name="r_seed0").validate()
    settings.open_run_folder()  # the run's config.json, which the reselection reads
    fresh = {200: 6.0, 300: 7.5, 400: 7.0}
    scored = []

    def fake_score(path, s, episodes):
        steps = int(path.stem.split("_")[1])
        scored.append((steps, episodes["seed"]))
        return {"mean_return": fresh[steps]}

    monkeypatch.setattr(selection, "score", fake_score)
    picks = ttt.shorter_budgets([run], [450], "r", [0], reselect=True)
    assert picks["r_seed0@450"]["selected_at_steps"] == 300
    assert sorted(scored) == [(200, selection.fresh_set(settings)["seed"]),
                              (300, selection.fresh_set(settings)["seed"]),
                              (400, selection.fresh_set(settings)["seed"])]
    # without reselection: the curve's latest maximum
    assert ttt.shorter_budgets([run], [450], "r", [0])["r_seed0@450"]["selected_at_steps"] == 200
