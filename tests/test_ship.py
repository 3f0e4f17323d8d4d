"""Shipping an agent: the best run by validation score, its sidecar and learning curve."""

import json

import pytest

from agents.benchmark.ship import ship


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
    assert side["chosen_among_seeds"].startswith("the highest validation score of 3 seeds")
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


def _remade(remake: str, hyper: dict):
    """The settings train.py reads from a remake line, the recipe ``hyper`` filled in."""
    import shlex

    from train import build_parser, settings_from_args
    settings = settings_from_args(build_parser().parse_args(shlex.split(remake)[2:]))
    return settings.with_recipe(hyper)


def test_the_remake_gives_the_back_end_and_every_setting_the_recipe_would_not(tmp_path):
    """A time-to-target run trains the SBX back end with its own budget and evaluation
    period: a remake line without them trains another network."""
    run = _run(tmp_path / "r0", 1, 480.0)
    hyper = {"n_envs": 64, "n_timesteps": 2.4e6, "learning_rate": 3e-4}
    config = {"seed": 1, "algo": "ppo", "backend": "sbx", "env_kwargs": {"air_force": 0.2},
              "hyperparams_used": hyper, "n_envs": 64, "total_timesteps": 3_000_000,
              "eval_freq": 150_000, "eval_episodes": 64, "max_episode_steps": 500,
              "torch_threads": 1}
    (run / "config.json").write_text(json.dumps(config))
    remake = json.loads(ship([run], "m", tmp_path / "models").with_suffix(".json")
                        .read_text())["remake"]
    assert remake == ("python train.py --env SaddleTrap-Gusty-v0 --seed 1 --backend sbx "
                      "--env-kwargs '{\"air_force\": 0.2}' --total-timesteps 3000000 "
                      "--eval-freq 150000")
    settings = _remade(remake, hyper)
    assert settings.backend == "sbx" and settings.env_kwargs == {"air_force": 0.2}
    for name in ("n_envs", "total_timesteps", "eval_freq", "eval_episodes",
                 "max_episode_steps", "torch_threads"):
        assert getattr(settings, name) == config[name], name
    # A run that took everything from its recipe remakes with the plain line.
    config.update(total_timesteps=2_400_000, eval_freq=120_000, env_kwargs={})
    (run / "config.json").write_text(json.dumps(config))
    remake = json.loads(ship([run], "m", tmp_path / "models").with_suffix(".json")
                        .read_text())["remake"]
    assert remake == "python train.py --env SaddleTrap-Gusty-v0 --seed 1 --backend sbx"
    assert _remade(remake, hyper).total_timesteps == 2_400_000


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
    shipped agent's recipe in a file its remake names. Read with train.py's own parser."""
    import shlex
    from pathlib import Path

    from agents.training.recipes import load_hyperparams
    from agents.training.trainer import backend
    from train import build_parser, settings_from_args
    root = Path(__file__).resolve().parents[1]
    checked = 0
    for path in sorted((root / "agents" / "models").glob("*.json")):
        side = json.loads(path.read_text())
        if "remake" not in side:
            continue
        settings = settings_from_args(build_parser().parse_args(shlex.split(side["remake"])[2:]))
        assert settings.env_id == side["env_id"] and settings.seed == side["seed"], path.name
        file = root / settings.hyperparams if settings.hyperparams else None
        entry = load_hyperparams(side["algo"], settings.recipe_of or settings.env_id,
                                 file or getattr(backend(settings), "RECIPES", None))
        assert entry == side["hyperparams"], path.name
        settings = settings.with_recipe(entry)
        # the budget it names, rounded up to whole rollouts (PPO stops after a rollout)
        rollout = settings.n_envs * entry.get("n_steps", 2048)
        assert 0 <= side["total_timesteps"] - settings.total_timesteps < rollout, path.name
        checked += 1
    assert checked >= 4
