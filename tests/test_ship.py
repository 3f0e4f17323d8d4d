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


def test_the_remake_names_a_recipe_that_is_not_the_default_entry(tmp_path):
    run = _run(tmp_path / "r0", 3, 400.0)
    config = json.loads((run / "config.json").read_text())
    config.update(hyperparams="agents/hyperparams/ppo_gusty_v1.yml",
                  recipe_of="SaddleTrap-Capture-v0")
    (run / "config.json").write_text(json.dumps(config))
    side = json.loads(ship([run], "m", tmp_path / "models").with_suffix(".json").read_text())
    assert side["remake"] == ("python train.py --env SaddleTrap-Gusty-v0 --seed 3 --hyperparams "
                              "agents/hyperparams/ppo_gusty_v1.yml --recipe-of "
                              "SaddleTrap-Capture-v0")


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


def test_each_shipped_agent_names_the_recipe_it_was_trained_with():
    """A shipped sidecar's remake line reads the very entry whose hyperparameters it
    records: moving a level's entry (as the main job's move to Gusty did) must leave the
    shipped agent's recipe in a file its remake names."""
    import argparse
    import shlex
    from pathlib import Path

    from agents.recipes import load_hyperparams
    root = Path(__file__).resolve().parents[1]
    p = argparse.ArgumentParser()
    for flag in ("--env", "--seed", "--hyperparams", "--recipe-of"):
        p.add_argument(flag)
    checked = 0
    for path in sorted((root / "agents" / "models").glob("*.json")):
        side = json.loads(path.read_text())
        if "remake" not in side:
            continue
        ns = p.parse_args(shlex.split(side["remake"])[2:])
        assert ns.env == side["env_id"] and int(ns.seed) == side["seed"], path.name
        file = root / ns.hyperparams if ns.hyperparams else None
        entry = load_hyperparams(side["algo"], ns.recipe_of or ns.env, file)
        assert entry == side["hyperparams"], path.name
        checked += 1
    assert checked >= 4
