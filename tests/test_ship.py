"""Shipping an agent: the best run by validation score, its sidecar and learning curve."""

import json

import pytest

from agents.ship import ship


def _run(folder, seed, score, env_id="SaddleTrap-Gusty-v0", lr=3e-4):
    folder.mkdir()
    (folder / "selected_model.zip").write_bytes(f"model {seed}".encode())
    (folder / "selected_model.json").write_text(json.dumps(
        {"algo": "ppo", "env_id": env_id, "env_kwargs": {}, "seed": seed,
         "validation_mean_return": score, "selected_at_steps": 1000 * seed}))
    (folder / "config.json").write_text(json.dumps(
        {"seed": seed, "hyperparams_used": {"learning_rate": lr}}))
    (folder / "progress.csv").write_text(
        "time/total_timesteps,time/time_elapsed\n1000,2\n2000,4\n")
    (folder / "learning_curve.png").write_bytes(b"png")
    return folder


def test_ships_the_best_validation_score_with_every_run_recorded(tmp_path):
    runs = [_run(tmp_path / f"r{s}", s, score) for s, score in ((0, 400.0), (1, 450.0),
                                                                (2, 420.0))]
    out = ship(runs, "ppo_gusty", tmp_path / "models")
    assert out.read_bytes() == b"model 1"
    side = json.loads(out.with_suffix(".json").read_text())
    assert side["seed"] == 1 and side["env_id"] == "SaddleTrap-Gusty-v0"
    assert [r["seed"] for r in side["recipe_runs"]] == [0, 1, 2]
    assert side["total_timesteps"] == 2000 and side["steps_per_s"] == 500
    assert side["remake"] == "python train.py --env SaddleTrap-Gusty-v0 --seed 1"
    assert (tmp_path / "models" / "ppo_gusty_learning_curve.png").is_file()


def test_ties_go_to_the_later_seed_and_recipes_must_match(tmp_path):
    runs = [_run(tmp_path / "a", 0, 400.0), _run(tmp_path / "b", 1, 400.0)]
    assert ship(runs, "m", tmp_path / "models").read_bytes() == b"model 1"
    other = _run(tmp_path / "c", 2, 500.0, lr=1e-3)
    with pytest.raises(ValueError, match="one recipe"):
        ship(runs + [other], "m", tmp_path / "models")
    with pytest.raises(ValueError, match="not a finished training run"):
        ship([tmp_path / "missing"], "m", tmp_path / "models")


def test_the_warm_start_counts_in_the_wall_time_not_in_the_steps_per_second(tmp_path):
    run = _run(tmp_path / "r0", 0, 400.0)
    (run / "warm_start.json").write_text(json.dumps({"warm_start": "mpc", "seconds": 96.0}))
    side = json.loads(ship([run], "m", tmp_path / "models").with_suffix(".json").read_text())
    assert side["wall_time_s"] == 100.0 and side["warm_start_s"] == 96.0
    assert side["steps_per_s"] == 500            # RL's own rate: 2,000 steps in 4 s
